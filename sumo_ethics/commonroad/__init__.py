"""CommonRoad scenarios in SUMO: the importer (``importer``, needs the ``commonroad`` extra) and the
goal region check (``goal``, numpy and shapely only). The run side is ``sumo_ethics.sim.commonroad``."""
