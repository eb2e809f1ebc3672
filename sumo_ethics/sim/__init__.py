"""The SUMO adapter: the only code that imports libsumo and sumolib (session, scene reading, ego
insertion and actuation, reference paths, lanes, rules, hazards, the prediction recorder).

Nothing is imported here, so ``import sumo_ethics.sim.scenario`` stays free of libsumo."""
