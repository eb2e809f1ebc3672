"""The predictor chain through the command line: dataset -> train -> evaluate-predictor."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch

from sumo_ethics.cli import main
from sumo_ethics.predict import LSTMPredictor

from conftest import SCENARIOS

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parents[2]


def test_dataset_train_evaluate_chain(tmp_path, capsys, monkeypatch):
    data = tmp_path / "data"
    assert main(["dataset", str(SCENARIOS / "urban" / "urban.sumocfg"), "--seeds", "1-4", "--sim-seconds", "90",
                 "--out", str(data)]) == 0
    traj = pd.read_parquet(data / "trajectories.parquet")
    assert {0, 5} <= set(traj["cls"])  # cars and pedestrians
    split = json.loads((data / "split.json").read_text())["split"]
    seeds = {k: set(v) for k, v in split.items()}
    assert set(seeds) == {"train", "val", "test"} and all(seeds.values())
    assert sum(len(v) for v in seeds.values()) == len(set().union(*seeds.values())) == 4  # split by seed
    weights = tmp_path / "w.pt"
    assert main(["train", str(data), "--model", "cslstm", "--out", str(weights), "--max-minutes", "0.05"]) == 0
    assert LSTMPredictor.from_file(weights, kind="cslstm").kind == "cslstm"
    # the default model (map: attention with lanes) encodes every agent in its own frame: trains on
    # the samples' nbr_yaw; map_cslstm gets the same recipe
    weights = tmp_path / "mc.pt"
    assert main(["train", str(data), "--out", str(weights), "--max-minutes", "0.05"]) == 0
    default = LSTMPredictor.from_file(weights, kind="map").model
    assert default.nbr_frame == "agent" and default.modes == 3  # as shipped
    assert main(["train", str(data), "--model", "map_cslstm", "--out", str(tmp_path / "cs.pt"), "--max-minutes", "0.05"]) == 0
    cs = LSTMPredictor.from_file(tmp_path / "cs.pt", kind="map_cslstm").model
    assert (cs.nbr_frame, cs.modes, cs.dec_size, cs.single_mode_groups) == ("agent", 3, 64, (2,))
    assert (default.dec_size, default.cv_mode, default.single_mode_groups) == (64, False, (2,))  # pedestrians: one mode
    assert default.map_version == 5 and default.n_scalars == 10  # the dataset's map features
    # a model of an earlier map version from the same dataset (as map_cslstm_v5, version 3);
    # a later one than the dataset's is refused in one line
    v3 = tmp_path / "v3.pt"
    assert main(["train", str(data), "--out", str(v3), "--max-minutes", "0.05", "--map-version", "3"]) == 0
    assert LSTMPredictor.from_file(v3).model.map_version == 3
    capsys.readouterr()
    assert main(["train", str(data), "--out", str(tmp_path / "v6.pt"), "--max-minutes", "0.05", "--map-version", "6"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "has map version 5, so a model of it reads 1 to 5" in err
    assert not (tmp_path / "v6.pt").exists()
    assert main(["train", str(data), "--model", "cslstm", "--out", str(tmp_path / "c.pt"), "--map-version", "3"]) == 2
    assert "cslstm reads no map" in capsys.readouterr().err
    # a two-mode model trains (winner-takes-all warm-up, then the mixture NLL) and is evaluated
    modes2 = tmp_path / "m2.pt"
    assert main(["train", str(data), "--out", str(modes2), "--max-minutes", "0.05", "--modes", "2"]) == 0
    assert LSTMPredictor.from_file(modes2).model.modes == 2
    # --ema: the file holds the moving average of the weights as they were after each optimiser step
    # (the first step's weights, then e = d e + (1 - d) w) up to the end of the best epoch
    from torch.optim import swa_utils

    after_step = []
    real_update = swa_utils.AveragedModel.update_parameters

    def record(self, model):
        after_step.append(model.output.weight.detach().clone())
        return real_update(self, model)

    monkeypatch.setattr(swa_utils.AveragedModel, "update_parameters", record)
    ema = tmp_path / "ema.pt"
    assert main(["train", str(data), "--out", str(ema), "--max-minutes", "0.05", "--ema", "0.5"]) == 0
    log = json.loads(ema.with_suffix(".json").read_text())
    assert log["config"]["ema"] == 0.5
    steps = min(len(after_step), (log["best_epoch"] + 1) * -(-log["n_train"] // 128))
    by_hand = after_step[0]
    for w in after_step[1:steps]:
        by_hand = 0.5 * by_hand + 0.5 * w
    written = LSTMPredictor.from_file(ema).model.output.weight.detach()
    assert steps >= 2 and not torch.equal(written, after_step[steps - 1])  # an average, not the last weights
    torch.testing.assert_close(written, by_hand, rtol=1e-5, atol=1e-7)
    capsys.readouterr()
    assert main(["train", str(data), "--out", str(tmp_path / "e2.pt"), "--max-minutes", "0.05", "--ema", "1"]) == 2
    assert "--ema needs a decay between 0 and 1" in capsys.readouterr().err
    # --extra-dataset: another dataset's training samples of the given classes join the training
    # samples (here this dataset's own training pedestrians, a second time); validation is unchanged
    more = tmp_path / "more.pt"
    assert main(["train", str(data), "--out", str(more), "--max-minutes", "0.05", "--extra-dataset", str(data),
                 "--extra-groups", "pedestrian"]) == 0
    samples = np.load(data / "samples.npz")
    peds = int(((samples["split"] == 0) & (samples["tgt_group"] == 2)).sum())
    logs = [json.loads(p.with_suffix(".json").read_text()) for p in (tmp_path / "mc.pt", more)]
    assert peds > 0 and logs[1]["n_train"] == logs[0]["n_train"] + peds and logs[1]["n_val"] == logs[0]["n_val"]
    assert logs[1]["config"]["extra_groups"] == [2] and logs[1]["config"]["extra_dataset"] == str(data)
    capsys.readouterr()
    assert main(["train", str(data), "--out", str(tmp_path / "x.pt"), "--extra-dataset", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{tmp_path} is not a prediction dataset" in err and not (tmp_path / "x.pt").exists()
    # the options can be switched (and are kept in the training log as trained)
    plain = tmp_path / "plain.pt"
    assert main(["train", str(data), "--out", str(plain), "--max-minutes", "0.05", "--decoder-size", "32",
                 "--decoder-steps", "5", "--cv-mode", "--all-modes-pedestrians"]) == 0
    m = LSTMPredictor.from_file(plain).model
    assert (m.modes, m.dec_size, m.dec_steps, m.cv_mode, m.single_mode_groups) == (3, 32, 5, True, ())
    cfg = json.loads(plain.with_suffix(".json").read_text())["config"]
    assert (cfg["dec"], cfg["dec_steps"], cfg["cv_mode"], cfg["single_mode_groups"]) == (32, 5, True, [])
    # Ctrl-C in the third epoch: the best epoch so far (1, the first of the NLL) is written, the
    # command says so in its one line and exits 130; before an NLL epoch ends nothing is written
    from sumo_ethics.predict import train as train_mod

    calls = []

    def validate_then_ctrl_c(*a, **k):
        calls.append(1)
        if len(calls) == stop_at:
            raise interrupt
        return real_validate(*a, **k)

    real_validate = train_mod.validate
    monkeypatch.setattr(train_mod, "validate", validate_then_ctrl_c)
    kept = tmp_path / "kept.pt"
    stop_at, interrupt = 3, KeyboardInterrupt
    capsys.readouterr()
    assert main(["train", str(data), "--model", "cslstm", "--out", str(kept), "--max-minutes", "5"]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    log = json.loads(kept.with_suffix(".json").read_text())
    assert (log["stopped"], log["best_epoch"], len(log["history"])) == ("interrupted (Ctrl-C)", 1, 2)
    assert len(err) == 1 and err[0] == (f"error: interrupted; the best epoch so far (1, validation NLL "
                                        f"{log['best_val_nll']:.3f}) is written to {kept}")
    assert LSTMPredictor.from_file(kept).model.kind == "cslstm" and not list(tmp_path.glob("*.part"))
    # SIGTERM (errors.Terminated, raised by the handler sigterm_as_interrupt installs) likewise, exit
    # 143; --out exists now (kept.pt), and a cut-short training never replaces it: it goes beside it
    from sumo_ethics.errors import Terminated

    calls.clear()
    interrupt = Terminated
    before = kept.read_bytes(), kept.with_suffix(".json").read_bytes()
    assert main(["train", str(data), "--model", "cslstm", "--out", str(kept), "--max-minutes", "5"]) == 143
    assert (kept.read_bytes(), kept.with_suffix(".json").read_bytes()) == before
    beside = tmp_path / "kept.interrupted.pt"
    log = json.loads(beside.with_suffix(".json").read_text())
    assert log["stopped"] == "interrupted (SIGTERM)" and LSTMPredictor.from_file(beside).model.kind == "cslstm"
    assert capsys.readouterr().err.strip() == (f"error: terminated (SIGTERM); the best epoch so far (1, validation NLL "
                                               f"{log['best_val_nll']:.3f}) is written to {beside}")
    from sumo_ethics.predict.train import interrupted_path

    assert interrupted_path(kept) == tmp_path / "kept.interrupted-2.pt"  # the next free name
    calls.clear()
    interrupt = KeyboardInterrupt
    stop_at = 2  # in the first NLL epoch
    assert main(["train", str(data), "--model", "cslstm", "--out", str(tmp_path / "none.pt"), "--max-minutes", "5"]) == 130
    assert capsys.readouterr().err.strip() == "error: interrupted" and not (tmp_path / "none.pt").exists()
    monkeypatch.setattr(train_mod, "validate", real_validate)
    # stay modes for pedestrians and cyclists while they stand: pedestrians leave the one-mode groups
    stay = tmp_path / "stay.pt"
    assert main(["train", str(data), "--out", str(stay), "--max-minutes", "0.05", "--stay-mode-pedestrians",
                 "--stay-mode-cyclists", "--stay-speed", "0.5"]) == 0
    m = LSTMPredictor.from_file(stay).model
    assert (m.stay_mode_groups, m.single_mode_groups, m.stay_speed) == ((1, 2), (), 0.5)
    assert main(["evaluate-predictor", str(data), "--out", str(tmp_path / "eval")]) == 0
    table = pd.read_csv(tmp_path / "eval" / "prediction_eval.csv")
    assert {"constant_velocity", "cslstm", "attention", "map", "map_cslstm"} <= set(table["model"])
    assert {"ade", "min_ade", "fde", "nll", "rmse_1s", "rmse_4s"} <= set(table.columns)
    assert main(["evaluate-predictor", str(data), "--out", str(tmp_path / "eval2"), "--model", f"two={modes2}"]) == 0
    two = pd.read_csv(tmp_path / "eval2" / "prediction_eval.csv").set_index(["model", "group"])
    assert np.isfinite(two.loc[("two", "all"), "nll"]) and two.loc[("two", "all"), "min_ade"] <= two.loc[("two", "all"), "ade"]
    assert {"vehicle:standing", "vehicle:moving"} <= set(table["group"])
    # --calibrated: a row with the shipped calibration beside the weights, the same means (same ADE)
    from sumo_ethics.predict.predictor import default_weights

    assert main(["evaluate-predictor", str(data), "--out", str(tmp_path / "evalc"), "--model",
                 f"map={default_weights('map')}", "--calibrated"]) == 0
    cal = pd.read_csv(tmp_path / "evalc" / "prediction_eval.csv").set_index(["model", "group"])
    assert cal.loc[("map_calibrated", "all"), "ade"] == cal.loc[("map", "all"), "ade"]
    assert cal.loc[("map_calibrated", "all"), "nll"] != cal.loc[("map", "all"), "nll"]
    # every sample (a dataset never trained on): also a table per scenario and class; one scenario
    # here, so its rows are the classes' rows of the main table
    assert main(["evaluate-predictor", str(data), "--out", str(tmp_path / "eval3"), "--split", "all"]) == 0
    full = pd.read_csv(tmp_path / "eval3" / "prediction_eval.csv").set_index(["model", "group"])
    by = pd.read_csv(tmp_path / "eval3" / "prediction_eval_by_scenario.csv")
    assert set(by["scenario"]) == {"urban"} and {"vehicle", "pedestrian"} <= set(by["group"])
    for _, row in by.iterrows():
        assert row["n"] == full.loc[(row["model"], row["group"]), "n"]
        assert row["ade"] == pytest.approx(full.loc[(row["model"], row["group"]), "ade"], rel=1e-12)
    assert "| urban | vehicle |" in (tmp_path / "eval3" / "prediction_eval_by_scenario.md").read_text()
    # the ratios with their run-bootstrap intervals: each ratio is that of the table's two ADEs
    ci = pd.read_csv(tmp_path / "eval3" / "prediction_eval_ci.csv")
    assert {("attention", "cslstm"), ("map", "map_cslstm"), ("map_cslstm", "constant_velocity")} <= set(
        zip(ci["model"], ci["reference"]))
    for _, row in ci[ci["group"].isin(["vehicle", "pedestrian", "all"])].iterrows():
        want = full.loc[(row["model"], row["group"]), "ade"] / full.loc[(row["reference"], row["group"]), "ade"]
        assert row["ratio"] == pytest.approx(want, rel=1e-9) and row["lo"] <= row["ratio"] <= row["hi"]
    assert "95 % interval" in (tmp_path / "eval3" / "prediction_eval_ci.md").read_text()
    one = ci.set_index(["model", "reference", "group"])["ratio"]  # one scenario: its rows are the classes' rows
    assert one.loc[("map_cslstm", "constant_velocity", "urban/vehicle")] == one.loc[("map_cslstm", "constant_velocity", "vehicle")]
    # the breakdown of tools/prediction_breakdown.py on the same samples (the shipped default): its "all"
    # row is the table's vehicle row; the closest mode is never further than the most likely one
    from sumo_ethics.predict.breakdown import breakdown

    br = breakdown(data, "vehicle", ["urban"]).set_index("subset")
    assert br.loc["all", "n"] == full.loc[("map", "vehicle"), "n"]
    for col, model in (("constant velocity", "constant_velocity"), ("map", "map"), ("map min_ade", "map")):
        metric = "min_ade" if col.endswith("min_ade") else "ade"
        assert br.loc["all", col] == pytest.approx(full.loc[(model, "vehicle"), metric], rel=1e-6)
    assert (br["map min_ade"] <= br["map"] + 1e-12).all()
    # --v5-row: a map version-4 file (the shipped 5-step one) also reads version 5's row 0 of the
    # pedestrians on a walking area; a version-5 file (trained above) reads it anyway: no such column
    v4 = Path(__file__).resolve().parents[2] / "models" / "superseded" / "map_cslstm_fast.pt"
    peds = breakdown(data, "pedestrian", None, models={"v4": str(v4), "new": str(weights)}, v5_row=True).set_index("subset")
    assert "v4, v5 row" in peds.columns and "new, v5 row" not in peds.columns
    assert peds.loc["on a walking area", "n"] >= 20 and peds.loc["on a walking area", "v4, v5 row"] != \
        peds.loc["on a walking area", "v4"]
    # samples derived again from the recorded trajectories, without simulating: the same arrays
    assert main(["dataset", "--samples-from", str(data), "--out", str(tmp_path / "data2")]) == 0
    with np.load(data / "samples.npz") as a, np.load(tmp_path / "data2" / "samples.npz") as b:
        assert sorted(a.files) == sorted(b.files) and all(np.array_equal(a[k], b[k]) for k in a.files)
    assert main(["dataset", "--samples-from", str(data), "--out", str(data)]) == 2
    assert "must be a new folder" in capsys.readouterr().err


def test_train_refuses_mode_options_without_modes(tmp_path, capsys):
    for args in (["--modes", "1", "--cv-mode"], ["--model", "cslstm", "--one-mode-pedestrians"]):
        assert main(["train", str(tmp_path), "--out", str(tmp_path / "w.pt"), *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "need --modes 2 or more" in err[0]
    assert not (tmp_path / "w.pt").exists()


def test_train_refuses_a_stay_speed_without_a_stay_mode(tmp_path, capsys):
    for args, why in ((["--stay-speed", "0.5"], "--stay-speed needs --stay-mode-pedestrians or --stay-mode-cyclists"),
                      (["--stay-mode-cyclists", "--stay-speed", "-1"], "--stay-speed must be positive"),
                      (["--pedestrian-speed-scale", "1.4", "0.8"], "--pedestrian-speed-scale needs 0 < LO <= HI"),
                      (["--pedestrian-speed-scale", "0", "1.2"], "--pedestrian-speed-scale needs 0 < LO <= HI"),
                      (["--extra-groups", "pedestrian"], "--extra-groups needs --extra-dataset"),
                      (["--extra-dataset", str(tmp_path), "--extra-groups", "bikes"],
                       "--extra-groups 'bikes': give classes out of vehicle, cyclist, pedestrian")):
        assert main(["train", str(tmp_path), "--out", str(tmp_path / "w.pt"), *args]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0]
    assert not (tmp_path / "w.pt").exists()


def test_train_rejects_a_folder_that_is_no_dataset(tmp_path, capsys):
    assert main(["train", str(tmp_path), "--out", str(tmp_path / "w.pt")]) == 2
    assert "is not a prediction dataset" in capsys.readouterr().err


def test_dataset_refuses_too_few_seeds_before_touching_disk(tmp_path, capsys):
    out = tmp_path / "data"
    assert main(["dataset", str(SCENARIOS / "urban" / "urban.sumocfg"), "--seeds", "1-2", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at least 3 seeds" in err[0]
    assert not out.exists()


def test_dataset_refuses_a_scenario_sumo_cannot_start_before_simulating_any(tmp_path, capsys):
    """A config with an option plain sumo lacks (eclipse-sumo's tools/game/bs3d.sumocfg has the
    gui-only osg-view): one line with SUMO's reason and exit 2, before the good scenario is run."""
    bad = tmp_path / "gui.sumocfg"
    urban = SCENARIOS / "urban"
    net = (urban / "../../networks/urban/urban.net.xml").resolve()
    bad.write_text(f"""<configuration><input><net-file value="{net}"/></input>
<gui_only><osg-view value="true"/></gui_only></configuration>""")
    out = tmp_path / "data"
    assert main(["dataset", str(urban / "urban.sumocfg"), str(bad), "--seeds", "1-3", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "gui.sumocfg" in err[0] and "osg-view" in err[0]
    assert not out.exists()


def test_dataset_reports_a_scenario_that_crashes_sumo_in_one_line(tmp_path, capsys):
    """A malformed network makes SUMO itself crash (segfault) while loading: the check before the
    runs reports it in one line, exit 2, instead of waiting forever for the dead worker."""
    (tmp_path / "b.net.xml").write_text("<net>broken")
    cfg = tmp_path / "b.sumocfg"
    cfg.write_text('<configuration><input><net-file value="b.net.xml"/></input></configuration>')
    out = tmp_path / "data"
    assert main(["dataset", str(cfg), "--seeds", "1-3", "--sim-seconds", "20", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "crashed while loading" in err[0] and "b.sumocfg" in err[0]
    assert not out.exists()


def test_runs_in_fresh_processes_come_as_they_finish_and_a_crash_is_named():
    """The dataset's runs (processes.run_each): each (job, result) as soon as it finishes, not held
    back behind a longer job started before it (a stopped build keeps every finished run); a process
    that dies mid-run (SUMO crashing after a good start) is named instead of waited for forever."""
    import os
    import time

    from sumo_ethics.errors import SimulationError
    from sumo_ethics.processes import run_each

    def crashed(job: int, why: str):
        raise SimulationError(f"SUMO crashed while simulating job {job} ({why})")

    assert sorted(run_each(abs, [-3, 1, -2], 2, on_crash=crashed)) == [(-3, 3), (-2, 2), (1, 1)]
    # two workers: the 6 s job starts first, the two short ones finish (one after the other) before it
    assert [job for job, _ in run_each(time.sleep, [6.0, 0.1, 0.2], 2, on_crash=crashed)] == [0.1, 0.2, 6.0]
    with pytest.raises(SimulationError, match=r"SUMO crashed while simulating job 7 \(run process died \(exit code 7\)\)"):
        list(run_each(os._exit, [7], 2, on_crash=crashed))  # the process dies: exit code 7
    with pytest.raises(ValueError, match="invalid literal for int"):  # a worker's own exception, raised here
        list(run_each(int, ["12", "x"], 1, on_crash=crashed))


def test_dataset_writes_nothing_next_to_the_scenario(tmp_path):
    """The scenario's own outputs (an output option, a detector dump in an additional file, as
    eclipse-sumo's tools/game configs have) go to a scratch folder, not next to the scenario."""
    urban = SCENARIOS / "urban"
    net = (urban / "../../networks/urban/urban.net.xml").resolve()
    scen = tmp_path / "scen"
    scen.mkdir()
    (scen / "dump.add.xml").write_text('<add><edgeData id="d" file="dump.xml"/></add>')
    (scen / "s.sumocfg").write_text(f"""<configuration><input><net-file value="{net}"/>
<route-files value="{(urban / 'urban.rou.xml').resolve()}"/><additional-files value="dump.add.xml"/></input>
<output><tripinfo-output value="trips.xml"/></output></configuration>""")
    before = sorted(p.name for p in scen.iterdir())
    assert main(["dataset", str(scen / "s.sumocfg"), "--seeds", "1-3", "--sim-seconds", "30",
                 "--out", str(tmp_path / "data")]) == 0
    assert sorted(p.name for p in scen.iterdir()) == before == ["dump.add.xml", "s.sumocfg"]


def test_samples_from_never_overwrites_a_folder(tmp_path, capsys):
    src = tmp_path / "old"
    src.mkdir()
    for name in ("trajectories.parquet", "lane_graphs.pkl", "split.json"):
        (src / name).write_text("x")
    out = tmp_path / "new"
    out.mkdir()
    (out / "samples.npz").write_text("keep me")
    assert main(["dataset", "--samples-from", str(src), "--out", str(out)]) == 2
    assert "is not an empty folder" in capsys.readouterr().err
    assert (out / "samples.npz").read_text() == "keep me"


def test_dataset_never_overwrites_a_dataset_and_refuses_too_short_runs(tmp_path, capsys):
    # a folder holding a dataset is refused before anything is simulated; nothing is touched
    out = tmp_path / "data"
    out.mkdir()
    (out / "samples.npz").write_text("keep me")
    cfg = str(SCENARIOS / "urban" / "urban.sumocfg")
    assert main(["dataset", cfg, "--seeds", "1-3", "--sim-seconds", "60", "--out", str(out)]) == 2
    assert "is not an empty folder" in capsys.readouterr().err
    assert (out / "samples.npz").read_text() == "keep me"
    # 2 s of simulation cannot give a sample (3 s of history + 4 s ahead): refused in one line
    short = tmp_path / "short"
    assert main(["dataset", cfg, "--seeds", "1-3", "--sim-seconds", "2", "--out", str(short)]) == 2
    assert "at least 10 s" in capsys.readouterr().err and not short.exists()


def test_weights_file_with_the_constant_velocity_predictor_is_refused(tmp_path, capsys):
    from sumo_ethics.predict.predictor import default_weights

    out = tmp_path / "run"
    assert main(["run", str(SCENARIOS / "urban" / "urban.sumocfg"), "--predictor", "cv", "--predictor-weights",
                 str(default_weights("map")), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'cv' (constant velocity) has none" in err[0]
    assert not (out / "steps.parquet").exists()
