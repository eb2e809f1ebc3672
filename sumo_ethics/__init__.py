"""sumo-ethics: ethical decision-making of automated vehicles inside SUMO."""

__version__ = "0.1.0"
