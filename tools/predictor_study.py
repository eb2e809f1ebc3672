"""Table 1 per predictor, and the planner's braking/lateral priors off and on, on suite
scenarios that no predictor was trained or evaluated on.

    python tools/predictor_study.py [--first 140] [--count 20] [--workers 1] [--out runs/predictor_study] [--resume]

Planners (the paper's planner, only the predictor or the priors changed): cv, cslstm,
attention, map (attention + lanes, 3 trajectory modes, pedestrians with one mode, map version 5, a
moving average of the weights, the long-red runs' cyclists and pedestrians in training: the
default), map_v1 (the one-mode map file with map version 1 shipped before, models/superseded/map_v1.pt),
map_cslstm (the same recipe and seed as map without the attention: the default before),
map_cslstm_fast (map version 4 with a 5-step decoder, models/superseded/map_cslstm_fast.pt),
map_cslstm_v8 (map_cslstm without the long-red runs, the default before, models/superseded/map_cslstm_v8.pt),
map_cslstm_v7 (without the moving average too, the default before that, models/superseded/map_cslstm_v7.pt),
map_cslstm_v6 (map version 4, the default before that,
models/superseded/map_cslstm_v6.pt), map_cslstm_v5 (map version 3, the default before those,
models/superseded/map_cslstm_v5.pt), map_cslstm_v4 (map version 1, the default before that,
models/superseded/map_cslstm_v4.pt), map_cslstm_v3 (with the last mode constant velocity, the default
before that, models/superseded/map_cslstm_v3.pt), map_cslstm_v2 (3 free modes, a 128-state decoder, the
default before), map_cslstm_1mode (the one-mode map_cslstm before that,
models/superseded/map_cslstm_1mode.pt) and map_nopriors (the default with braking_prior =
lateral_prior = 0). The paired columns compare each planner with map (the default; the first
planner when --planner leaves it out).
Scenarios s<first>..s<first+count-1> of scenarios/suite (tools/train_shipped.py trains on
s0000-s0099 and evaluates prediction on s0100-s0139). Writes the suite's table1.md,
paired.csv and results.csv to --out.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

WEIGHTS = ROOT / "sumo_ethics" / "predict" / "weights"
OLD = ROOT / "models" / "superseded"  # the files that left the package (models/superseded/README.md)
PLANNERS = (
    "cv=predictor=cv",
    "cslstm=predictor=cslstm",
    "attention=predictor=attention",
    "map=predictor=map",
    f"map_v1=predictor=map;predictor_weights={OLD / 'map_v1.pt'}",
    "map_cslstm=predictor=map_cslstm",
    f"map_cslstm_fast=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_fast.pt'}",
    f"map_cslstm_v8=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v8.pt'}",
    f"map_cslstm_v7=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v7.pt'}",
    f"map_cslstm_v6=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v6.pt'}",
    f"map_cslstm_v5=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v5.pt'}",
    f"map_cslstm_v4=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v4.pt'}",
    f"map_cslstm_v3=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v3.pt'}",
    f"map_cslstm_v2=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_v2.pt'}",
    f"map_cslstm_1mode=predictor=map_cslstm;predictor_weights={OLD / 'map_cslstm_1mode.pt'}",
    "map_nopriors=predictor=map;braking_prior=0;lateral_prior=0",
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--first", type=int, default=140)
    ap.add_argument("--count", type=int, default=20)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "runs" / "predictor_study"))
    ap.add_argument("--planner", action="append", help="override the planner list (NAME=key=value;...)")
    ap.add_argument("--resume", action="store_true", help="keep finished runs found in --out")
    args = ap.parse_args()
    from sumo_ethics.suite.evaluate import parse_planners, run_suite, write_outputs
    from sumo_ethics.suite.spec import load_suite

    suite = ROOT / "scenarios" / "suite"
    specs = load_suite(suite)[args.first: args.first + args.count]
    planners = parse_planners(args.planner or PLANNERS)
    out = Path(args.out)
    t0 = time.perf_counter()
    reference = "map" if any(p.name == "map" for p in planners) else planners[0].name
    rows = run_suite([s.folder for s in specs], planners, out, args.workers, None, args.resume)
    names = [s.folder.name for s in specs]
    meta = {"suite": f"scenarios/suite {names[0]}-{names[-1]}" if names else str(suite), "scenarios": len(names),
            "scenario_names": names, "workers": args.workers,
            "wall_s": time.perf_counter() - t0, "planners": {p.name: p.describe() for p in planners},
            "reference": reference}
    write_outputs(rows, planners, out, reference, meta)
    print((out / "table1.md").read_text())
    print(json.dumps({"wall_s": round(meta["wall_s"], 1), "scenarios": len(specs)}))


if __name__ == "__main__":
    main()
