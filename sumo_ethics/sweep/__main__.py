"""``python -m sumo_ethics.sweep RUNS_DIR`` with a run spec (JSON) on stdin: one isolated run
(how :func:`~sumo_ethics.sweep.executors.execute_run_isolated` runs a grid point on Dask)."""

import sys

from sumo_ethics.sweep.executors import main_one

sys.exit(main_one())
