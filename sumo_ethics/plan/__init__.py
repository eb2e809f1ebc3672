"""Ego controllers: the scene goes in, a command for the next step comes out."""
