"""CommonRoad scenarios in SUMO: the importer (``importer``, needs the ``commonroad`` extra). The goal
region check is ``sumo_ethics.goal`` (numpy and shapely only); the run side is ``sumo_ethics.sim.commonroad_run``."""
