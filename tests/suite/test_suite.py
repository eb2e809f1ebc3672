"""Scenario suite: deterministic generator, hazards firing at their triggers in real SUMO,
clear errors for bad hazard files and unknown planners."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from sumo_ethics.errors import ConfigError
from sumo_ethics.suite.spec import HazardSpec, load

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "scenarios" / "testbed" / "testbed.sumocfg"
SUITE = ROOT / "scenarios" / "suite"


# ---- generator ------------------------------------------------------------------------------
def _tree(d: Path) -> dict[str, bytes]:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.mark.sumo
def test_generator_is_deterministic_byte_for_byte(tmp_path):
    from sumo_ethics.suite.generate import generate

    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    generate(6, 7, a)
    generate(6, 7, b)
    generate(6, 8, c)
    ta, tb = _tree(a), _tree(b)
    assert ta.keys() == tb.keys() and len(ta) > 6 * 3
    assert all(ta[k] == tb[k] for k in ta), [k for k in ta if ta[k] != tb[k]]
    assert any(ta[k] != v for k, v in _tree(c).items() if k.endswith("hazards.json"))
    for f in sorted(a.glob("s*/hazards.json")):  # every file loads and names its own sumocfg
        spec = load(f)
        assert spec.sumocfg.is_file() and spec.hazards


def test_generator_prefix_does_not_depend_on_count(tmp_path):
    from sumo_ethics.suite.generate import scenario

    assert scenario(3, 2)[0].to_dict() == scenario(3, 2)[0].to_dict()
    assert scenario(3, 2)[0].to_dict() != scenario(3, 3)[0].to_dict()


# ---- bad input ------------------------------------------------------------------------------
GOOD = {"version": 1, "name": "x", "seed": 1, "ego": {"from": "main_0", "to": "main_1", "depart": 0, "end": 30},
        "hazards": [{"id": "h0", "type": "pedestrian", "anchor": {"edge": "main_1", "pos": 40},
                     "trigger": {"ttc": 1.5}}]}


def _bad(tmp_path: Path, data) -> Path:
    d = tmp_path / "x"
    d.mkdir(exist_ok=True)
    (d / "x.sumocfg").write_text("<configuration/>")
    (d / "hazards.json").write_text(data if isinstance(data, str) else json.dumps(data))
    return d


@pytest.mark.parametrize("mutate, message", [
    (lambda d: "{not json", "malformed JSON"),
    (lambda d: d["hazards"][0].update(type="meteor") or d, "unknown hazard type 'meteor'"),
    (lambda d: d["hazards"][0].update(trigger={}) or d, "exactly one of"),
    (lambda d: d["hazards"][0].update(trigger={"ttc": -1}) or d, "trigger.ttc must be in"),
    (lambda d: d["hazards"][0].update(params={"speeed": 2}) or d, "unknown key(s)"),
    (lambda d: d["hazards"][0].update(anchor={"pos": 3}) or d, "needs exactly one of edge"),
    (lambda d: d["ego"].update(depart=40) or d, "must be after depart"),
    (lambda d: d.pop("ego") and d, "lacks ego"),
    (lambda d: d["hazards"][0].update(params={"speed": 0}) or d, "params.speed must be positive"),
])
def test_invalid_hazard_file_is_a_clear_error(tmp_path, mutate, message):
    data = mutate(json.loads(json.dumps(GOOD)))
    with pytest.raises(ConfigError, match=None) as exc:
        load(_bad(tmp_path, data))
    assert message in str(exc.value)
    assert "hazards.json" in str(exc.value) or "hazard" in str(exc.value)


def test_missing_hazard_file_and_sumocfg(tmp_path):
    with pytest.raises(ConfigError, match="hazard file not found"):
        load(tmp_path / "nope")
    d = _bad(tmp_path, GOOD)
    (d / "x.sumocfg").unlink()
    with pytest.raises(ConfigError, match="missing beside the hazard file"):
        load(d)


def test_unknown_planner_is_a_clear_error():
    from sumo_ethics.suite.evaluate import parse_planner, parse_planners

    with pytest.raises(ConfigError, match="unknown planner 'nope'"):
        parse_planner("nope")
    with pytest.raises(ConfigError, match="unknown key"):
        parse_planner("fast=predictr=cv")
    with pytest.raises(ConfigError, match="unknown predictor"):
        parse_planner("fast=predictor=magic")
    with pytest.raises(ConfigError, match="unique"):
        parse_planners(["origin", "origin"])
    p = parse_planner("fast=predictor=cv;omega_u=0.3")
    assert p.name == "fast" and p.options["predictor"] == "cv" and p.options["omega_u"] == 0.3
    assert parse_planner("origin").options == {"weights": "ethical", "predictor": "cslstm", "omega_u": 0.0,
                                               "selection": "validity", "normalise": "in_range",
                                               "probability": "origin", "calibrated": False, "evasive": False,
                                               "lateral_onset": False}
    assert parse_planner("paper").options["selection"] == "cost"
    assert parse_planner("paper").options["calibrated"] is False  # as published: no covariance calibration
    # both published planners divide by everyone in range; a planner built on paper's options can change it
    assert parse_planner("paper").options["normalise"] == "in_range"
    assert parse_planner("scaled=normalise=at_risk").options["normalise"] == "at_risk"
    assert parse_planner("default").name == "ours" and parse_planner("ours").options == {}
    assert parse_planner("baseline").options is None


def test_a_planner_of_ones_own_can_build_on_ours():
    """NAME=key=value builds on paper's settings (attention predictor, Origin's probability, no
    calibration) unless it says base=ours (run's defaults: map predictor, shapes, calibrated)."""
    from sumo_ethics.settings import planner_config
    from sumo_ethics.suite.evaluate import parse_planner

    on_paper = planner_config(None, **parse_planner("mm=weights=maximin;omega_u=0").options)
    assert (on_paper.predictor, on_paper.probability.method, on_paper.calibrated) == ("attention", "origin", False)
    spec = parse_planner("mm=base=ours;weights=maximin;omega_u=0")
    on_ours = planner_config(None, **spec.options)
    assert (on_ours.predictor, on_ours.probability.method, on_ours.calibrated) == ("map", "shapes", True)
    assert on_ours.cost.weights.maximin == 100.0 and on_ours.cost.weights.bayes == 0.0
    assert on_ours.cost.omega_u == 0.0 and planner_config(None).cost.omega_u == 0.5
    assert spec.describe() == "base=ours;weights=maximin;omega_u=0"
    assert parse_planner("o=base=origin;omega_u=0.5").options["predictor"] == "cslstm"
    with pytest.raises(ConfigError, match="base must be origin, paper or ours"):
        parse_planner("q=base=baseline")


def test_cli_unknown_planner_exits_2(tmp_path, capsys):
    from sumo_ethics.cli_suite import evaluate_cmd

    import click

    @click.group()
    def g():
        pass

    g.add_command(evaluate_cmd)
    from sumo_ethics.errors import SumoEthicsError

    with pytest.raises(SumoEthicsError) as exc:
        g.main(["evaluate", str(tmp_path), "--planner", "nope"], standalone_mode=False)
    assert exc.value.exit_code == 2 and "unknown planner 'nope'" in str(exc.value)


# ---- hazards in real SUMO -------------------------------------------------------------------
HAZARDS = {
    "pedestrian": {"anchor": {"edge": "main_1", "pos": 40}, "trigger": {"ttc": 1.5}, "spawn": 30,
                   "params": {"occluder": True}},
    "emergency_stop": {"anchor": {"edge": "main_1", "pos": 60}, "trigger": {"distance": 25}, "spawn": 60},
    "red_light_runner": {"anchor": {"xy": [200, -3]}, "trigger": {"ttc": 3.0}},
    "oncoming_drift": {"anchor": {"edge": "main_1", "pos": 150}, "trigger": {"gap_ttc": 2.0}, "spawn": 150,
                       "params": {"lane_offset": 3.2}},
    "cut_in": {"anchor": {"edge": "main_1", "pos": 50}, "trigger": {"gap": 8.0}, "spawn": 60},
    "cyclist_swerve": {"anchor": {"edge": "main_1", "pos": 40}, "trigger": {"gap": 10.0}, "spawn": 60},
}
CLASS = {"pedestrian": "PEDESTRIAN", "cyclist_swerve": "BICYCLE"}


class Probe:
    """Wraps the hazard controller: records the injector's commanded actor pose each step and
    what the ego sees of the actor one step later."""

    def __init__(self, inner, injector):
        self.inner, self.injector = inner, injector
        self.name, self.needs_history = inner.name, False
        self.commanded: dict[float, tuple[float, float]] = {}
        self.seen: dict[float, tuple[float, float, int]] = {}

    def act(self, scene):
        for i, k in enumerate(scene.others.ids):
            if k == "hazard_h0":
                self.seen[round(scene.time, 3)] = (float(scene.others.x[i]), float(scene.others.y[i]),
                                                   int(scene.others.cls[i]))
        d = self.inner.act(scene)
        a = self.injector.states[0].actor
        if a is not None and a.added:
            self.commanded[round(scene.time + scene.dt, 3)] = (a.x, a.y)
        return d


@pytest.mark.sumo
@pytest.mark.parametrize("kind", sorted(HAZARDS))
def test_hazard_fires_at_its_trigger(kind, tmp_path):
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import make_controller, run
    from sumo_ethics.sim.hazards import HazardInjector
    from sumo_ethics.types import RoadUserClass

    spec = HazardSpec.parse("h", {"id": "h0", "type": kind, **HAZARDS[kind]})
    cfg = RunConfig(scenario=TESTBED, out=tmp_path / kind, seed=1, end=30.0, ego_from="main_0", ego_to="main_1",
                    controller="baseline", progress=False, stop_at_collision=False)
    inj = HazardInjector([spec])
    probe = Probe(make_controller(cfg), inj)
    run(cfg, controller=probe, hooks=(inj,))
    ev = {e["event"]: e for e in inj.events}
    assert "spawn" in ev and "trigger" in ev, inj.events
    t = ev["trigger"]
    v, dt = t["ego_speed"], 0.1
    front, anchor = t["ego_front_s"], t["anchor_s"]
    if kind == "red_light_runner":
        assert ev["spawn"]["time"] == t["time"]
    if spec.trigger_kind == "distance":
        value, step = anchor - front, v * dt
    elif spec.trigger_kind == "ttc":
        value, step = (anchor - front) / v, dt
    else:  # gap / gap_ttc: to the actor's rear along the path
        a = inj.states[0].actor
        gap = t["actor_s"] - a.length / 2 - front
        closing = v - t["actor_speed"]
        value, step = (gap, closing * dt) if spec.trigger_kind == "gap" else (gap / closing, dt)
    # fired at the first step the condition held: at most one step of closing past the threshold
    assert value <= spec.trigger_value + 1e-6
    assert value > spec.trigger_value - step - 0.05, (value, spec.trigger_value, step)
    # the actor is in SUMO where the injector put it, with the right class
    common = sorted(set(probe.commanded) & set(probe.seen))
    assert len(common) >= 5
    err = [math.hypot(probe.commanded[k][0] - probe.seen[k][0], probe.commanded[k][1] - probe.seen[k][1])
           for k in common]
    assert max(err) < 0.3, max(err)
    want = RoadUserClass[CLASS.get(kind, "CAR")]
    assert {probe.seen[k][2] for k in common} == {int(want)}
    # one step after the trigger: what the ego sees, else (an actor off every lane is outside the
    # ego's context subscription, e.g. the runner before it reaches the testbed's road) the pose sent
    at = probe.seen.get(round(t["time"] + dt, 3)) or probe.commanded.get(round(t["time"] + dt, 3))
    assert at is not None
    if kind == "pedestrian":  # at the kerb, beside the anchor, when triggered
        assert abs(at[0] - (202 + 40)) < 0.5 and at[1] < -6.0 + 0.5
    if kind == "red_light_runner":  # on the crossing line through the anchor, off to the left
        assert abs(at[0] - 200) < 0.5 and at[1] > 5.0


@pytest.mark.sumo
def test_parked_vehicle_stays_put_off_the_carriageway(tmp_path):
    import libsumo

    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import make_controller, run
    from sumo_ethics.sim.hazards import HazardInjector

    spec = HazardSpec.parse("h", {"id": "h0", "type": "parked", "anchor": {"edge": "main_1", "pos": 100}})
    cfg = RunConfig(scenario=TESTBED, out=tmp_path / "p", seed=1, end=25.0, ego_from="main_0", ego_to="main_1",
                    controller="baseline", progress=False, stop_at_collision=False)
    inj = HazardInjector([spec])
    lanes = set()

    class LaneProbe(Probe):
        def act(self, scene):
            if "hazard_h0" in scene.others.ids:
                lanes.add(libsumo.vehicle.getLaneID("hazard_h0"))
            return super().act(scene)

    probe = LaneProbe(make_controller(cfg), inj)
    run(cfg, controller=probe, hooks=(inj,))
    pts = np.array([p[:2] for p in probe.seen.values()])
    assert len(pts) > 10 and np.ptp(pts[:, 0]) < 0.05 and abs(pts[0, 0] - 302) < 0.5
    # SUMO files it on the sidewalk beside it (main_1_0), not on the lane its traffic drives in:
    # SUMO's car following ignores lateral offsets and would queue everyone behind it
    assert lanes == {"main_1_0"}


@pytest.mark.sumo
def test_hazard_vehicle_over_a_crosswalk_does_not_crash_sumo(tmp_path):
    """A narrow-street scenario of an earlier suite: the oncoming car, matched onto the junction's
    crossing when lane permissions were ignored, crashed SUMO 1.28 (segfault) at t = 48.4 s."""
    import subprocess
    import sys

    code = ("import json, sys; from sumo_ethics.suite.evaluate import run_one, parse_planner; "
            "print(json.dumps(run_one(sys.argv[1], parse_planner('baseline'), sys.argv[2])))")
    scen = Path(__file__).resolve().parents[1] / "data" / "sumo_crashes" / "s0095"
    r = subprocess.run([sys.executable, "-c", code, str(scen), str(tmp_path / "run")], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    row = json.loads(r.stdout.strip().splitlines()[-1])
    # the ego took over at t = 39.2 s: past the crash instant means more than 92 steps
    assert row["status"] in ("completed", "collision", "timeout") and row["steps"] > 92, row


def test_a_scenario_folder_is_a_suite_of_one():
    from sumo_ethics.suite.spec import load_suite

    specs = load_suite(SUITE / "s0027")
    assert [s.name for s in specs] == ["s0027"] and specs[0].folder == SUITE / "s0027"


@pytest.mark.sumo
def test_ctrl_c_stops_an_evaluation_without_tracebacks_and_resumes(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "networks").symlink_to(SUITE / "networks")
    for name in ("s0000", "s0001", "s0002"):
        (suite / name).symlink_to(SUITE / name)
    out = tmp_path / "ev"
    args = [sys.executable, "-m", "sumo_ethics.cli", "evaluate", str(suite), "--planner", "origin",
            "--planner", "baseline", "--workers", "2", "--quiet", "--out", str(out)]
    # SIGINT as in a terminal, also when pytest itself was started in the background (`pytest &`),
    # which leaves it ignored: Python then installs no Ctrl-C handler
    proc = subprocess.Popen(args, start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        runs = out / "runs" / "origin"
        if runs.exists() and any(runs.iterdir()):
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C: the evaluation and its run processes
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "Traceback" not in err and err.strip().splitlines()[-1].startswith("error:")
    r = subprocess.run(args + ["--resume"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    import pandas as pd

    res = pd.read_csv(out / "results.csv")
    assert len(res) == 6 and set(res.status) <= {"completed", "collision", "timeout"}
