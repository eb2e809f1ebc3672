"""Rebuild the shipped predictor weights: dataset -> train attention and CS-LSTM -> evaluate.

    python tools/train_shipped.py [--work DIR] [--stages dataset,train,evaluate] [--parallel]

Uses the bundled scenarios (scenarios/{urban,rural,highway,urban_grid}). Writes the
weights to sumo_ethics/predict/weights/{attention,cslstm}.pt (+ .json training logs) and
the evaluation table to sumo_ethics/predict/weights/evaluation.{csv,md}.
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "sumo_ethics" / "predict" / "weights"
SCENARIOS = ("urban", "rural", "highway", "urban_grid")
SEEDS = tuple(range(1, 8))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--work", default="/tmp/sumo_ethics_predict_data")
    ap.add_argument("--stages", default="dataset,train,evaluate")
    ap.add_argument("--parallel", action="store_true", help="train both models at once (one thread each)")
    ap.add_argument("--max-minutes", type=float, default=14.0)
    ap.add_argument("--max-wall-minutes", type=float, default=None)
    ap.add_argument("--out-dir", default=str(WEIGHTS), help="where weights and the evaluation go")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--model", default=None, help="(internal) train only this model")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    sys.path.insert(0, str(ROOT))
    from sumo_ethics.predict.commands import dataset_main, evaluate_main, train_main

    work = Path(args.work)
    stages = args.stages.split(",")
    if args.model:
        t0 = time.time()
        info = train_main(work, args.model, Path(args.out_dir) / f"{args.model}.pt", max_minutes=args.max_minutes,
                          max_wall_minutes=args.max_wall_minutes, progress=False)
        logging.info("%s: %.1f min, best epoch %s, val nll %.3f, %s", args.model, (time.time() - t0) / 60,
                     info["best_epoch"], info["best_val_nll"], info["stopped"])
        return
    if "dataset" in stages:
        scen = [ROOT / "scenarios" / s / f"{s}.sumocfg" for s in SCENARIOS]
        scen = [s for s in scen if s.exists()]
        t0 = time.time()
        dataset_main(scen, work, seeds=SEEDS, workers=args.workers)
        logging.info("dataset: %.1f min", (time.time() - t0) / 60)
    if "train" in stages:
        cmds = [[sys.executable, __file__, "--work", str(work), "--model", m, "--max-minutes", str(args.max_minutes),
                 "--out-dir", args.out_dir] + (["--max-wall-minutes", str(args.max_wall_minutes)] if args.max_wall_minutes else [])
                for m in ("attention", "cslstm")]
        if args.parallel:
            procs = [subprocess.Popen(c) for c in cmds]
            if any(p.wait() for p in procs):
                raise SystemExit("training failed")
        else:
            for c in cmds:
                subprocess.run(c, check=True)
    if "evaluate" in stages:
        out_dir = Path(args.out_dir)
        df = evaluate_main(work, out_dir, weights={"cslstm": out_dir / "cslstm.pt", "attention": out_dir / "attention.pt"})
        print(df.to_string())


if __name__ == "__main__":
    main()
