"""No non-finite number reaches the cost (issue 37): a prediction with NaN in it falls back to
constant velocity for that agent, counted; a non-finite total is never chosen.

Scene: a straight road along +x, the ego at x = 10 m at 10 m/s; agent "a" a car 30 m ahead at
8 m/s, agent "b" a car at (60, 3.5) at 5 m/s, both heading +x.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from conftest import straight_road_scene
from sumo_ethics.config import EgoVehicle
from sumo_ethics.ethics.cost import CostConfig, score
from sumo_ethics.ethics.risk import RiskTerms
from sumo_ethics.contract import Scene
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig, select
from sumo_ethics.predict.constant_velocity import ConstantVelocityPredictor, replace_non_finite
from sumo_ethics.types import AgentStates, Candidates, Observation, Prediction

DT = 0.1


def agents() -> AgentStates:
    return AgentStates(ids=("a", "b"), x=np.array([40.0, 60.0]), y=np.array([0.0, 3.5]), yaw=np.zeros(2),
                       speed=np.array([8.0, 5.0]), accel=np.zeros(2), length=np.full(2, 4.5),
                       width=np.full(2, 1.8), mass=np.full(2, 1500.0), cls=np.zeros(2, np.int8))


def scene() -> Scene:
    others = agents()
    hist = np.stack([others.xy - np.array([[0.8, 0.0], [0.5, 0.0]]) * i for i in range(5)][::-1], axis=1)
    return straight_road_scene(others, hist, dt=DT)


class Broken:
    """Constant velocity, with agent "b"'s prediction spoilt by ``spoil`` (None: left as it is)."""

    kind = "broken"

    def __init__(self, spoil=None) -> None:
        self.spoil = spoil

    def predict(self, obs: Observation, horizon_steps: int, dt: float) -> Prediction:
        p = ConstantVelocityPredictor().predict(obs, horizon_steps, dt)
        if self.spoil is None:
            return p
        mean, cov, yaw = p.mean.copy(), p.cov.copy(), p.yaw.copy()
        self.spoil(mean, cov, yaw)
        return Prediction(p.ids, p.dt, mean, cov, yaw)


def nan_mean(mean, cov, yaw):
    mean[1, 7:, :] = np.nan


def nan_cov(mean, cov, yaw):
    cov[1, 3] = np.nan


def inf_yaw(mean, cov, yaw):
    yaw[1, -1] = np.inf


def test_fallback_replaces_only_the_broken_agent_with_constant_velocity():
    obs = scene().history
    spoilt = Broken(nan_mean).predict(obs, 40, DT)
    fixed, n = replace_non_finite(spoilt, obs, 40, DT)
    assert n == 1
    # agent b by hand: from (60, 3.5) at 5 m/s along +x, after 1.0 s (step index 9) at (65, 3.5);
    # sigma_lon = 0.1 + 0.5 * 1.0 = 0.6 m, sigma_lat = 0.1 + 0.15 * 1.0 = 0.25 m (heading +x)
    np.testing.assert_allclose(fixed.mean[1, 9], [65.0, 3.5])
    np.testing.assert_allclose(fixed.cov[1, 9], [[0.36, 0.0], [0.0, 0.0625]], atol=1e-12)
    assert np.all(fixed.yaw[1] == 0.0)
    # agent a is left exactly as it was: after 4.0 s at 40 + 8 * 4 = 72 m
    np.testing.assert_array_equal(fixed.mean[0], spoilt.mean[0])
    assert fixed.mean[0, -1, 0] == pytest.approx(72.0)
    # a finite prediction comes back as it was, no agent counted
    clean = Broken().predict(obs, 40, DT)
    same, n0 = replace_non_finite(clean, obs, 40, DT)
    assert n0 == 0 and same is clean


def test_a_nan_in_an_unlikely_mode_also_falls_back_and_its_weights_become_one_zero():
    obs = scene().history
    main = Broken().predict(obs, 40, DT)
    alt = Broken(nan_cov).predict(obs, 40, DT)
    pred = Prediction(main.ids, DT, main.mean, main.cov, main.yaw, (alt,), np.array([[0.7, 0.3], [0.9, 0.1]]))
    fixed, n = replace_non_finite(pred, obs, 40, DT)
    assert n == 1
    np.testing.assert_array_equal(fixed.weight, [[0.7, 0.3], [1.0, 0.0]])
    assert np.isfinite(fixed.alternatives[0].cov).all()


@pytest.mark.parametrize("spoil", [nan_mean, nan_cov, inf_yaw])
def test_planner_uses_the_fallback_counts_it_and_chooses_a_finite_total(spoil):
    broken = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=Broken(spoil)).act(scene())
    honest = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=Broken()).act(scene())
    assert broken.info["n_fallback"] == 1.0 and honest.info["n_fallback"] == 0.0
    assert np.isfinite(broken.info["cost_selection"]) and np.isfinite(broken.info["cost_j_risk"])
    assert np.isfinite(broken.trace.selection).all() and np.isfinite(broken.trace.prediction.cov).all()
    # the stub's sound predictions are constant velocity too, so the fallback restores them exactly:
    # the same candidate at the same cost as with the honest predictor
    assert broken.trace.chosen == honest.trace.chosen
    assert broken.info["cost_selection"] == honest.info["cost_selection"]
    assert broken.command == honest.command


def test_validity_selection_never_chooses_nan():
    every = [np.ones(3, bool)]
    # np.argmin would pick index 0 (the NaN); the lowest finite total is 1.0 at index 2
    assert select(every, np.array([np.nan, 2.0, 1.0])) == (2, 0)
    # the best class holds only a NaN: the next class decides
    assert select([np.array([True, False, False]), every[0]], np.array([np.nan, 2.0, 1.0])) == (2, 1)
    assert select(every, np.array([np.nan, np.inf, np.nan])) == (-1, 1)


def test_cost_selection_never_chooses_nan_and_brakes_when_nothing_is_finite():
    p = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=Broken())
    ones, steps = np.ones(3, bool), 40
    args = ([ones], np.zeros(3), ones, ones, np.full(3, steps), steps, np.zeros(3))
    total, j, _ = p.choose(SimpleNamespace(total=np.array([np.nan, 5.0, 7.0])), *args)
    assert j == 1
    _, j, _ = p.choose(SimpleNamespace(total=np.array([np.nan, np.nan, np.inf])), *args)
    assert j == -1


def test_planner_brakes_when_every_total_is_nan(monkeypatch):
    import sumo_ethics.plan.ethical as eth

    real = eth.score

    def nan_score(*a, **k):
        c = real(*a, **k)
        return SimpleNamespace(total=np.full_like(c.total, np.nan), terms=c.terms, row=c.row)

    monkeypatch.setattr(eth, "score", nan_score)
    d = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=Broken(nan_mean)).act(scene())
    # the emergency brake: 10 m/s - max_decel * 0.1 s
    assert d.info["validity"] == 4.0 and d.info["n_fallback"] == 1.0
    assert d.command.speed == pytest.approx(10.0 - EgoVehicle().max_decel * DT)


def test_one_nan_j_does_not_switch_j_utility_off_for_the_others():
    # 3 candidates, 1 agent: J = 0.1, 0.3, NaN; J_mean over the finite two = 0.2, so the 0.3
    # candidate pays 1e4 * 0.3 = 3000 and the 0.1 one nothing
    K = 3
    z = np.zeros((K, 2))
    cand = Candidates(dt=DT, x=z, y=z, yaw=z, speed=z, accel=z, curvature=z, s=z, d=z,
                      horizon=np.full(K, 0.2), valid=np.ones((K, 2), bool))
    risk = RiskTerms.from_risks(np.array([[0.05], [0.15], [np.nan]]), np.array([[0.05], [0.15], [0.0]]),
                                np.full((K, 1), 0.5), np.full((K, 1), 0.5), np.zeros(K), None, 2)
    c = score(cand, risk, CostConfig(), desired_speed=0.0).terms
    assert c["j_mean"][0] == pytest.approx(0.2)
    np.testing.assert_allclose(c["j_utility"][:2], [0.0, 3000.0])


@pytest.mark.sumo
def test_run_sums_the_fallbacks_in_its_summary(tmp_path):
    import json

    import pandas as pd

    from conftest import write_scenario
    from sumo_ethics.config import RunConfig
    from sumo_ethics.runner import run

    def spoil_all(mean, cov, yaw):
        mean[:, 5:] = np.nan

    cfg = write_scenario(tmp_path / "scenario", """
      <vehicle id="parked" type="car" route="r_main" depart="0" departLane="1" departPos="80" departSpeed="0">
        <stop lane="main_0_1" endPos="80.5" duration="1000"/></vehicle>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="1" departPos="20" departSpeed="5"/>""")
    out = tmp_path / "run"
    planner = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=Broken(spoil_all))
    run(RunConfig(cfg, out, ego_id="ego", end=3, progress=False), controller=planner)
    steps = pd.read_parquet(out / "steps.parquet")
    summary = json.loads((out / "summary.json").read_text())
    # the parked car is the one neighbour, spoilt and replaced at every step the ego planned
    assert (steps.n_fallback == 1.0).all() and len(steps) >= 20
    assert summary["n_fallback"] == len(steps)
    assert np.isfinite(steps.cost_selection).all()
    # N of the principles (normalise in_range, the default): the one road user in range
    assert (steps.cost_n_norm == 1.0).all()
