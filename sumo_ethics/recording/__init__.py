"""Training data recorded from SUMO for the predictors: :mod:`build` runs the simulations (one libsumo
run per fresh process, :func:`sumo_ethics.processes.run_each`) and keeps each finished run (:mod:`runstore`); the samples
themselves are made in :mod:`sumo_ethics.predict.samples` (no SUMO). Above the runner: it drives
the suite scenarios through :mod:`sumo_ethics.suite.traffic`."""
