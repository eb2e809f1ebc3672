"""Rebuild the shipped predictor weights: dataset -> train -> evaluate.

    python tools/train_shipped.py [--work DIR] [--stages dataset,long_red,heldout,train,evaluate] [--models map]
    python tools/train_shipped.py --work DIR --stages selection,select --candidate mine=mine.pt

Data: the bundled scenarios (scenarios/{urban,rural,highway,urban_grid}, seeds 1-7, 600 s,
anchors every 2 s, split by seed) and the first SUITE_TRAIN suite scenarios recorded with
their hazards (anchors every 0.4 s, split by scenario); the default also trains on the cyclists and
pedestrians of the long-red runs (stage "long_red"). Writes the weights to
sumo_ethics/predict/weights/<model>.pt (+ .json training logs).

Stages:
- "heldout" records a second dataset of scenarios never trained on (GAME configs of
  eclipse-sumo's tools/game, 3 seeds x 300 s, and suite scenarios s0100-s0139);
- "evaluate" writes prediction_eval.{csv,md} (test seeds/scenarios) and
  heldout/prediction_eval{,_by_scenario}.{csv,md} (the held-out dataset) there;
- "long_red" records WORK_long_red: urban_grid with lights whose reds hold 119 s (LONG_RED_FACTOR),
  seeds 1-7 x 600 s, for `train --extra-dataset` (its cyclists' and pedestrians' training samples;
  docs/predictor_seeds.md, "Long reds in the training data"; 5.8 min with one worker beside two trainings);
- "selection" records the selection dataset (SELECT_GAME x seeds 1-3 x 300 s and suite
  s0176-s0195: never trained on, not in the held-out table nor in the predictor study);
- "select" scores the shipped file and each --candidate by the rule of docs/predictor_seeds.md
  ("How a shipped file is chosen") into DIR_selection/selection_scores.csv.

``--models`` picks what is trained: "map" (the planner's default: the paper's attention with lanes,
feature version 1 + map version 5: the lights' switch times, blinkers, the pedestrians' lane after a
walking area, and the straight walk across a walking area) and "map_cslstm" (the same recipe without
the attention), both by default, and/or the ablation's "attention", "cslstm" (their shipped files were
trained on the version-1 dataset without map columns or suite runs: ``--stages dataset --no-suite`` and
then ``--models attention,cslstm`` rebuild them), and "map_cslstm_fast" (map_cslstm with a 5-step
decoder, map version 4, seed 2, 45 CPU-minutes: 49.1 min wall beside a second training, best epoch 30 of 30).

Wall time on this shared 2-core machine (one worker, one thread): dataset 19.0 min (14.2 min
with two workers, map version 4; deriving version-5 samples from it, ``sumo-ethics dataset --samples-from``, 65 s);
long-red dataset 2.5 min (two workers); training of the shipped map 50.8 min and map_cslstm 50.3 min, the two at once (45.0 CPU-minutes each,
best epoch 29 of both, cut by the budget);
held-out dataset 5.7 min, selection dataset 5.4 min (two workers); evaluation of the fourteen learned models and constant velocity about 12 min: about 130 min in all
with the two map models trained one after the other (``--parallel`` trains them at once: about 85 min).

    python tools/train_shipped.py --work /tmp/pred --stages dataset,long_red,train,heldout,evaluate --workers 1
"""

from __future__ import annotations

import argparse
import logging
import subprocess
import sys
import time
from pathlib import Path

from sumo_ethics.recording.long_red import LONG_RED_GROUPS, long_red_scenario

ROOT = Path(__file__).resolve().parents[1]
WEIGHTS = ROOT / "sumo_ethics" / "predict" / "weights"
SCENARIOS = ("urban", "rural", "highway", "urban_grid")
SEEDS = tuple(range(1, 8))
SUITE_TRAIN = 100  # suite scenarios s0000..s0099 go into the dataset; s0100.. stay held out
SUITE_HELDOUT = 40  # s0100..s0139 are the held-out suite scenarios of the evaluation
GAME = ("cross", "square", "grid6", "corridor", "fkk_in", "ramp")  # eclipse-sumo tools/game configs
#: the selection dataset (docs/predictor_seeds.md, "How a shipped file is chosen"): never trained on and
#: kept apart from the reported held-out scenarios and the predictor study's suite s0140..s0175: these
#: tools/game configs and suite s0176..s0195
SELECT_GAME = ("fokr_bs_demo", "A10KW")  # bs3d cannot start in plain sumo (its gui-only osg-view)
SUITE_SELECT_FIRST, SUITE_SELECT = 176, 20
#: per-model train_main options (others: defaults). map (the paper's attention over neighbours, plus lanes;
#: the planner's default) and map_cslstm (the same without the attention) share one recipe: every agent
#: encoded once in its own frame, 3 trajectory modes, a 64-state decoder, pedestrians with one mode; seed 0
#: of map version 5 (the straight walk across a walking area) with a 45 CPU-minute budget, a moving average
#: of the weights (decay 0.999) and the long-red runs' cyclists and pedestrians ("extra": stage long_red's
#: dataset, LONG_RED_GROUPS). map's file is the one the selection rule chose (docs/predictor_seeds.md,
#: "Attention with the default's recipe"), map_cslstm's the default before it ("Long reds in the training data").
#: Earlier files kept in the weights folder, evaluated beside the shipped models: map_v1 (map per target as
#: CS-LSTM with one mode, map version 1, 20 CPU-minutes: {"nbr_frame": "target", "modes": 1} on a version-1
#: dataset), map_cslstm_v8 (map_cslstm
#: without the long-red runs: train it with {"extra": None}), map_cslstm_v7 (without those and without the
#: moving average: {"extra": None, "ema": None}), map_cslstm_v6 (map
#: version 4, seed 2, 45 CPU-minutes: train it with {"map_version": 4, "seed": 2}), map_cslstm_v5 (map
#: version 3, seed 0, 45 CPU-minutes: train it with {"map_version": 3, "seed": 0}; a version-4 dataset
#: gives a version-3 model bit for bit the inputs of the version-3 dataset, models.batch_to_tensors),
#: map_cslstm_v4 (map version 1, seed 2, 20 CPU-minutes), map_cslstm_v3 (the same with the last mode
#: constant velocity), map_cslstm_v2 (3 free modes, a 128-state decoder, seed 0) and map_cslstm_1mode (one mode)
PREVIOUS = ("map_v1", "map_cslstm_v8", "map_cslstm_v7", "map_cslstm_v6", "map_cslstm_v5", "map_cslstm_v4", "map_cslstm_v3",
            "map_cslstm_v2", "map_cslstm_1mode")
_RECIPE = {"hazard_repeat": 4, "nbr_frame": "agent", "modes": 3, "seed": 0, "ema": 0.999, "extra": "long_red"}
TRAIN = {"map": dict(_RECIPE), "map_cslstm": dict(_RECIPE)}
#: CPU-minute training budget per model (--max-minutes overrides it): the default model (map version 3,
#: seed 0) was still improving when 20 minutes stopped it; 45 minutes is the shipped files' (map version 5,
#: seed 0, the moving average: map best epoch 29 and map_cslstm best epoch 29, both cut by the budget, 51 and
#: 50 min wall beside a second training)
BUDGET_DEFAULT = 20.0
BUDGET = {"map": 45.0, "map_cslstm": 45.0, "map_cslstm_fast": 45.0}
#: shipped files that are not a model kind's default: name -> (kind, train_main options). map_cslstm_fast
#: is map_cslstm with a 5-step decoder (each step emits 0.8 s), 17 % faster at run time, for users who
#: need the speed; the selection rule kept the default (docs/predictor_seeds.md, "Fewer decoder steps")
VARIANTS = {"map_cslstm_fast": ("map_cslstm", {**TRAIN["map_cslstm"], "seed": 2, "map_version": 4, "dec_steps": 5, "ema": None,
                                              "extra": None})}


def record_never_trained(game: tuple[str, ...], first: int, count: int, out: Path, workers: int, what: str) -> None:
    """A dataset of scenarios never trained on: the tools/game configs ``game`` (seeds 1-3 x 300 s)
    and suite scenarios ``first``..``first + count - 1``, written to ``out``. A game config missing
    from the installed SUMO stops it (scores of datasets with other scenarios do not compare)."""
    import sumo

    from sumo_ethics.recording.build import dataset_main

    configs = [Path(sumo.SUMO_HOME) / "tools" / "game" / f"{g}.sumocfg" for g in game]
    missing = [c.name for c in configs if not c.exists()]
    if missing:
        raise SystemExit(f"{what} dataset: {', '.join(missing)} not in this SUMO's tools/game")
    suite = sorted((ROOT / "scenarios" / "suite").glob("s[0-9]*"))[first:first + count]
    t0 = time.time()
    dataset_main(configs, out, seeds=(1, 2, 3), sim_seconds=300.0, workers=workers, suite=suite)
    logging.info("%s dataset: %.1f min", what, (time.time() - t0) / 60)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--work", default="/tmp/sumo_ethics_predict_data")
    ap.add_argument("--stages", default="dataset,long_red,train,evaluate")
    ap.add_argument("--parallel", action="store_true", help="train both models at once (one thread each)")
    ap.add_argument("--max-minutes", type=float, default=None,
                    help=f"CPU-time budget per model [min] (default: {BUDGET} for these, {BUDGET_DEFAULT} for the others)")
    ap.add_argument("--max-wall-minutes", type=float, default=None)
    ap.add_argument("--out-dir", default=str(WEIGHTS), help="where weights and the evaluation go")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--model", default=None, help="(internal) train only this model")
    ap.add_argument("--models", default="map,map_cslstm",
                    help="comma-separated models to train (map, map_cslstm, attention, cslstm, map_cslstm_fast)")
    ap.add_argument("--no-suite", action="store_true", help="dataset without the suite's hazard runs")
    ap.add_argument("--candidate", action="append", default=[], metavar="NAME=FILE",
                    help="stage select: a weights file to score beside the shipped default, map (repeatable)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s")
    sys.path.insert(0, str(ROOT))
    from sumo_ethics.predict.commands import evaluate_main, train_main
    from sumo_ethics.recording.build import dataset_main

    work = Path(args.work)
    stages = args.stages.split(",")
    if args.model:
        t0 = time.time()
        minutes = args.max_minutes or BUDGET.get(args.model, BUDGET_DEFAULT)
        kind, options = VARIANTS.get(args.model, (args.model, dict(TRAIN.get(args.model, {}))))
        extra = options.pop("extra", None)
        if extra is not None:  # another dataset's cyclists and pedestrians (stage long_red)
            from sumo_ethics.predict.features import GROUP_NAMES

            options.update(extra_dataset=Path(f"{work}_{extra}"),
                           extra_groups=tuple(GROUP_NAMES.index(g) for g in LONG_RED_GROUPS))
            if not (options["extra_dataset"] / "samples.npz").is_file():
                raise SystemExit(f"{args.model}: no {options['extra_dataset']}: run --stages long_red first")
        info = train_main(work, kind, Path(args.out_dir) / f"{args.model}.pt", max_minutes=minutes,
                          max_wall_minutes=args.max_wall_minutes, progress=False, **options)
        logging.info("%s: %.1f min, best epoch %s, val nll %.3f, %s", args.model, (time.time() - t0) / 60,
                     info["best_epoch"], info["best_val_nll"], info["stopped"])
        return
    if "dataset" in stages:
        scen = [ROOT / "scenarios" / s / f"{s}.sumocfg" for s in SCENARIOS]
        scen = [s for s in scen if s.exists()]
        t0 = time.time()
        suite = [] if args.no_suite else sorted((ROOT / "scenarios" / "suite").glob("s[0-9]*"))[:SUITE_TRAIN]
        dataset_main(scen, work, seeds=SEEDS, workers=args.workers, suite=suite)
        logging.info("dataset: %.1f min", (time.time() - t0) / 60)
    # before training: the default trains on its cyclists and pedestrians as well
    if "long_red" in stages:
        t0 = time.time()
        cfg = long_red_scenario(Path(str(work) + "_long_red_scenario"), ROOT / "networks" / "urban_grid" / "urban_grid.net.xml",
                                ROOT / "scenarios" / "urban_grid" / "urban_grid.rou.xml")
        dataset_main([cfg], Path(str(work) + "_long_red"), seeds=SEEDS, workers=args.workers)
        logging.info("long-red dataset: %.1f min", (time.time() - t0) / 60)
    if "train" in stages:
        budget = (["--max-minutes", str(args.max_minutes)] if args.max_minutes else []) + (
            ["--max-wall-minutes", str(args.max_wall_minutes)] if args.max_wall_minutes else [])
        cmds = [[sys.executable, __file__, "--work", str(work), "--model", m, "--out-dir", args.out_dir] + budget
                for m in args.models.split(",")]
        if args.parallel:
            procs = [subprocess.Popen(c) for c in cmds]
            if any(p.wait() for p in procs):
                raise SystemExit("training failed")
        else:
            for c in cmds:
                subprocess.run(c, check=True)
    heldout = Path(str(work) + "_heldout")
    if "heldout" in stages:
        # never trained on: eclipse-sumo's tools/game scenarios (vehicles only) and the suite
        # scenarios after the first SUITE_TRAIN (all their hazard kinds, pedestrians included)
        record_never_trained(GAME, SUITE_TRAIN, SUITE_HELDOUT, heldout, args.workers, "held-out")
    selection = Path(str(work) + "_selection")
    if "selection" in stages:
        record_never_trained(SELECT_GAME, SUITE_SELECT_FIRST, SUITE_SELECT, selection, args.workers, "selection")
    if "select" in stages:
        from sumo_ethics.predict.accuracy import evaluate, selection_scores

        weights = {"map (shipped)": Path(args.out_dir) / "map.pt"}
        bad = [c for c in args.candidate if "=" not in c or not Path(c.split("=", 1)[1]).is_file()]
        if bad:
            raise SystemExit(f"--candidate {bad[0]!r}: give NAME=FILE with an existing weights file")
        weights.update(dict(c.split("=", 1) for c in args.candidate))
        tables = {"val": evaluate(work, None, weights=weights, max_samples=None, split="val"),
                  "selection": evaluate(selection, None, weights=weights, max_samples=None, split="all")}
        scores = selection_scores(tables)
        vehicle = tables["val"][tables["val"]["group"] == "vehicle"].set_index("model")["nll"]
        scores.insert(len(scores.columns) - 1, "val:vehicle NLL", vehicle.reindex(scores.index))
        scores.to_csv(selection / "selection_scores.csv")
        print(scores.round(4).to_string())
    if "evaluate" in stages:
        out_dir = Path(args.out_dir)
        from sumo_ethics.predict.models import KINDS

        names = KINDS + tuple(VARIANTS) + PREVIOUS
        weights = {m: out_dir / f"{m}.pt" for m in names if (out_dir / f"{m}.pt").is_file()}
        df = evaluate_main(work, out_dir, weights=weights)
        print(df.to_string())
        if (heldout / "samples.npz").is_file():
            df = evaluate_main(heldout, out_dir / "heldout", weights=weights, split="all", calibration_dataset=work,
                               title="Scenarios never trained on (tools/game and held-out suite scenarios)")
            print(df.to_string())


if __name__ == "__main__":
    main()
