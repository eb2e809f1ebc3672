"""Surrogate safety: conflicts measured from the simulation and fault for collisions.

:mod:`~sumo_ethics.safety.measures` holds the pure-numpy maths (box TTC, DRAC, box distance,
PET from footprint trails); :mod:`~sumo_ethics.safety.conflicts` turns the measures of every
step into conflict events (one ``conflicts.parquet`` row each); :mod:`~sumo_ethics.safety.fault`
says who caused a collision. Nothing here imports libsumo: the runner hands in snapshots.
"""
