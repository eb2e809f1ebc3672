"""Multi-modal predictions: the risk integrates every mode by its weight (ethics.risk.assess_risk).

Scene (hand-checkable): two candidates drive +x at 10 m/s from the origin for 4 s, in lane
y = 0 and lane y = 3.5. Agent a0, a car parked at (30, 20): its main mode stays there (never
within 5 m of a candidate), its other mode pulls away towards -y at 20/3 m/s and crosses
y = 0 at x = 30 after 3 s, exactly when the y = 0 candidate is there. Agent a1, a pedestrian
at (60, -20): main mode stands, the other walks +y at 1.5 m/s from (25, -3) (crosses both lanes).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_ethics.config import EgoVehicle
from sumo_ethics.ethics.probability import ProbabilityConfig
from sumo_ethics.ethics.risk import RiskTerms, assess_risk
from sumo_ethics.geometry import Polyline
from sumo_ethics.contract import Scene
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
from sumo_ethics.predict.braking import apply_braking_prior, apply_lateral_prior
from sumo_ethics.record import decisions as rec
from sumo_ethics.contract import RoutePath
from sumo_ethics.types import AgentStates, Candidates, Observation, Prediction, RoadUserClass

DT = 0.1
T = 40
EGO_L, EGO_W, EGO_M = 4.508, 1.610, 1475.0
#: Origin's probability, with its threshold (p_min 1e-9) and Maximin (a step at p_min)
ORIGIN = ProbabilityConfig(method="origin")
P_MIN = ORIGIN.p_min
ARRAYS = ("ego_risk", "other_risk", "ego_harm_max", "other_harm_max", "vulnerable", "boundary_harm",
          "ego_harm_at", "other_harm_at", "rule_breaker", "p", "ego_harm", "other_harm")


def candidates() -> Candidates:
    t = (np.arange(T) + 1) * DT
    x = np.stack([10.0 * t, 10.0 * t])
    z = np.zeros((2, T))
    return Candidates(dt=DT, x=x, y=np.array([[0.0], [3.5]]) + z, yaw=z, speed=z + 10.0, accel=z, curvature=z,
                      s=x, d=np.array([[0.0], [3.5]]) + z, horizon=np.full(2, T * DT), valid=np.ones((2, T), bool))


AGENTS = AgentStates(ids=("a0", "a1"), x=np.array([30.0, 60.0]), y=np.array([20.0, -20.0]),
                     yaw=np.array([-math.pi / 2, math.pi / 2]), speed=np.zeros(2), accel=np.zeros(2),
                     length=np.array([4.5, 0.5]), width=np.array([1.8, 0.5]), mass=np.array([1500.0, 75.0]),
                     cls=np.array([RoadUserClass.CAR, RoadUserClass.PEDESTRIAN], np.int8))


def mode(start, velocity) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) constant-velocity mean from ``start`` [m] at ``velocity`` [m/s] and its (T,) yaw."""
    t = (np.arange(T) + 1) * DT
    v = np.asarray(velocity, float)
    return np.asarray(start, float) + t[:, None] * v, np.full(T, math.atan2(-1.0, 0.0) if v[1] < 0 else math.pi / 2)


def single(means_yaws) -> Prediction:
    mean = np.stack([m for m, _ in means_yaws])
    yaw = np.stack([y for _, y in means_yaws])
    return Prediction(AGENTS.ids, DT, mean, np.broadcast_to(0.05 * np.eye(2), (len(mean), T, 2, 2)), yaw)


STAYS = single([mode([30.0, 20.0], [0.0, 0.0]), mode([60.0, -20.0], [0.0, 0.0])])
MOVES = single([mode([30.0, 20.0], [0.0, -20.0 / 3.0]), mode([25.0, -3.0], [0.0, 1.5])])
W = np.array([[0.7, 0.3], [0.4, 0.6]])  # a0: stays 0.7 / pulls away 0.3; a1: stands 0.4 / walks 0.6


def risk(pred: Prediction) -> RiskTerms:
    """The scene was laid out for Origin's three-point score (its margins reach the pedestrian's
    path); the integration over modes under test does not depend on the method."""
    return assess_risk(candidates(), pred, AGENTS, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W,
                       prob_cfg=ORIGIN)


def with_modes(main: Prediction, alts: tuple[Prediction, ...], weight: np.ndarray) -> Prediction:
    return Prediction(main.ids, main.dt, main.mean, main.cov, main.yaw, alts, weight)


def test_scene_preconditions():
    # the main modes come nowhere near a candidate; the other modes do, for both candidates and agents
    assert risk(STAYS).sparse.p.size == 0
    r = risk(MOVES)
    assert (r.ego_risk > 0).all() and (r.other_harm_max > 0).all()
    # every entry stays above p_min when scaled by its weight (so no entry is dropped below)
    assert (r.sparse.p * W[r.sparse.n, 1] >= P_MIN).all()


@pytest.mark.parametrize("pred", [STAYS, MOVES])
def test_single_mode_with_unit_weight_is_bit_identical(pred):
    a = risk(pred)
    b = risk(Prediction(pred.ids, pred.dt, pred.mean, pred.cov, pred.yaw, (), np.ones((2, 1))))
    for name in ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y), name
    for name in ("k", "n", "t", "p"):
        assert np.array_equal(getattr(a.sparse, name), getattr(b.sparse, name)), name
    assert a.shape == b.shape == (2, 2, T)


def test_only_the_unlikely_mode_crosses_risk_is_its_weight_times_its_risk():
    alone = risk(MOVES)
    r = risk(with_modes(STAYS, (MOVES,), W))
    w = W[:, 1]  # per agent: 0.3 for a0, 0.6 for a1
    np.testing.assert_allclose(r.ego_risk, w * alone.ego_risk, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.other_risk, w * alone.other_risk, rtol=0, atol=1e-12)
    np.testing.assert_allclose(r.p, w[None, :, None] * alone.p, rtol=0, atol=1e-12)
    # Maximin sees the harm of the possible collision at full size, not weighted
    assert np.array_equal(r.ego_harm_max, alone.ego_harm_max)
    assert np.array_equal(r.other_harm_max, alone.other_harm_max)
    # entries: the same (k, n, t), the harms there exactly those of the crossing mode
    for name in ("k", "n", "t"):
        assert np.array_equal(getattr(r.sparse, name), getattr(alone.sparse, name)), name
    assert np.array_equal(r.ego_harm_at, alone.ego_harm_at) and np.array_equal(r.other_harm_at, alone.other_harm_at)
    # the order of the modes does not matter (the crossing one as the main mode)
    swapped = risk(with_modes(MOVES, (STAYS,), W[:, ::-1]))
    np.testing.assert_allclose(swapped.ego_risk, r.ego_risk, rtol=0, atol=1e-12)


def test_two_identical_modes_equal_the_single_mode():
    alone = risk(MOVES)
    r = risk(with_modes(MOVES, (MOVES,), W))
    for name in ("ego_risk", "other_risk", "p", "ego_harm", "other_harm"):
        np.testing.assert_allclose(getattr(r, name), getattr(alone, name), rtol=0, atol=1e-12, err_msg=name)
    assert np.array_equal(r.ego_harm_max, alone.ego_harm_max)
    for name in ("k", "n", "t"):
        assert np.array_equal(getattr(r.sparse, name), getattr(alone.sparse, name)), name


def test_two_crossing_modes_are_an_expectation_over_the_modes():
    # a0 pulls away at 20/3 m/s (crossing at 3 s) or at 5 m/s (at 4 s): both modes hit somewhere
    slow = single([mode([30.0, 20.0], [0.0, -5.0]), mode([25.0, -3.0], [0.0, 1.0])])
    a, b = risk(MOVES), risk(slow)
    assert (a.sparse.p * W[a.sparse.n, 0] >= P_MIN).all() and (b.sparse.p * W[b.sparse.n, 1] >= P_MIN).all()
    r = risk(with_modes(MOVES, (slow,), W))
    w0, w1 = W[:, 0], W[:, 1]
    # risk: sum_m w_m max_t p_m h_m; Maximin harm: the larger of the two modes'
    np.testing.assert_allclose(r.ego_risk, w0 * a.ego_risk + w1 * b.ego_risk, rtol=1e-12, atol=0)
    np.testing.assert_allclose(r.other_risk, w0 * a.other_risk + w1 * b.other_risk, rtol=1e-12, atol=0)
    assert np.array_equal(r.other_harm_max, np.maximum(a.other_harm_max, b.other_harm_max))
    # per step: marginal p, and p x harm = the expected risk of the step
    wd0, wd1 = w0[None, :, None], w1[None, :, None]
    np.testing.assert_allclose(r.p, wd0 * a.p + wd1 * b.p, rtol=1e-12, atol=0)
    expected = wd0 * a.p * a.ego_harm + wd1 * b.p * b.ego_harm
    np.testing.assert_allclose(r.p * r.ego_harm, expected, rtol=1e-12, atol=1e-15)
    # unique, sorted entries: both modes meet candidate 0 at some common steps
    key = (r.sparse.k * 2 + r.sparse.n) * T + r.sparse.t
    assert (np.diff(key) > 0).all()
    assert len(key) < len(a.sparse.p) + len(b.sparse.p)


def test_a_negligible_mode_counts_nowhere():
    # weight 1e-12: w p <= 1e-12 < p_min = 1e-9 at every entry, so not even Maximin sees it
    w = np.array([[1.0 - 1e-12, 1e-12], [1.0 - 1e-12, 1e-12]])
    r = risk(with_modes(STAYS, (MOVES,), w))
    assert r.sparse.p.size == 0
    assert not r.ego_risk.any() and not r.other_risk.any() and not r.ego_harm_max.any() and not r.other_harm_max.any()


def test_a_mode_of_weight_zero_for_one_agent_is_skipped_for_it_only():
    # a1 is a one-mode pedestrian (its walking mode has weight 0); a0 keeps stays 0.7 / pulls away 0.3
    w = np.array([[0.7, 0.3], [1.0, 0.0]])
    r = risk(with_modes(STAYS, (MOVES,), w))
    m = risk(MOVES)
    # only a0's pulling away counts: 0.3 times its single-mode risk, nothing for a1
    np.testing.assert_allclose(r.ego_risk[:, 0], 0.3 * m.ego_risk[:, 0], rtol=1e-12)
    np.testing.assert_allclose(r.other_risk[:, 0], 0.3 * m.other_risk[:, 0], rtol=1e-12)
    np.testing.assert_array_equal(r.ego_harm_max[:, 0], m.ego_harm_max[:, 0])
    assert not r.ego_risk[:, 1].any() and not r.other_harm_max[:, 1].any() and (r.sparse.n == 0).all()
    # a0's entries are those of its mode, with p weighted by 0.3
    a0 = m.sparse.n == 0
    np.testing.assert_array_equal(r.sparse.t, m.sparse.t[a0])
    np.testing.assert_allclose(r.sparse.p, 0.3 * m.sparse.p[a0], rtol=1e-12)
    # the other way round: a0's mode is skipped, a1 (row 1) keeps 0.6 of its walking mode, so the
    # entries assessed for a1 alone must come back as agent 1's, sorted by (k, n, t)
    r = risk(with_modes(STAYS, (MOVES,), np.array([[1.0, 0.0], [0.4, 0.6]])))
    a1 = m.sparse.n == 1
    assert r.sparse.p.size > 0 and (r.sparse.n == 1).all()
    np.testing.assert_array_equal(r.sparse.k, m.sparse.k[a1])
    np.testing.assert_array_equal(r.sparse.t, m.sparse.t[a1])
    np.testing.assert_allclose(r.sparse.p, 0.6 * m.sparse.p[a1], rtol=1e-12)
    np.testing.assert_allclose(r.ego_risk[:, 1], 0.6 * m.ego_risk[:, 1], rtol=1e-12)
    assert not r.ego_risk[:, 0].any()


def test_no_agents_with_several_modes():
    empty = AgentStates.empty()
    none = Prediction((), DT, np.zeros((0, T, 2)), np.zeros((0, T, 2, 2)), np.zeros((0, T)))
    two = with_modes(none, (none,), np.zeros((0, 2)))
    r = assess_risk(candidates(), two, empty, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W)
    assert r.ego_risk.shape == (2, 0) and r.sparse.p.size == 0


# ------------------------------------------------------------------ the priors keep the modes
def _braking(accel: float) -> AgentStates:
    return AgentStates(ids=("b",), x=np.zeros(1), y=np.zeros(1), yaw=np.zeros(1), speed=np.full(1, 10.0),
                       accel=np.full(1, accel), length=np.full(1, 4.5), width=np.full(1, 1.8),
                       mass=np.full(1, 1500.0), cls=np.zeros(1, np.int8))


def test_braking_prior_caps_every_mode_and_keeps_the_weights():
    t = np.array([0.5, 1.0, 1.5, 2.0])  # step i at (i + 1) dt, dt = 0.5 s
    straight = Prediction(("b",), 0.5, np.stack([10.0 * t, 0 * t], -1)[None], np.zeros((1, 4, 2, 2)), np.zeros((1, 4)))
    left = Prediction(("b",), 0.5, np.stack([0 * t, 10.0 * t], -1)[None], np.zeros((1, 4, 2, 2)), np.zeros((1, 4)))
    pred = with_modes(straight, (left,), np.array([[0.8, 0.2]]))
    out = apply_braking_prior(pred, _braking(-5.0), threshold=3.0)
    # 10 m/s at -5 m/s^2: 10 t - 2.5 t^2 along each mode's own path
    assert out.mean[0, :, 0] == pytest.approx([4.375, 7.5, 9.375, 10.0])
    assert out.alternatives[0].mean[0, :, 1] == pytest.approx([4.375, 7.5, 9.375, 10.0])
    assert out.n_modes == 2 and np.array_equal(out.weight, pred.weight)
    lat = apply_lateral_prior(pred, _braking(0.0))
    assert lat.n_modes == 2 and np.array_equal(lat.weight, pred.weight)
    # a single mode with unit weight keeps its weight too
    unit = apply_braking_prior(Prediction(("b",), 0.5, straight.mean, straight.cov, straight.yaw, (), np.ones((1, 1))),
                               _braking(-5.0))
    assert unit.weight is not None and unit.mean[0, -1, 0] == pytest.approx(10.0)


# ------------------------------------------------------------------ the planner with two modes
class TwoModes:
    """A predictor for the planner: the leader keeps straight on (0.6) or turns right on a 10 m
    circle (0.4), both at its current speed."""

    kind = "two-modes"

    def __init__(self) -> None:
        self.calls = 0

    def predict(self, obs: Observation, horizon_steps: int, dt: float) -> Prediction:
        self.calls += 1
        cur = obs.current
        t = (np.arange(horizon_steps) + 1) * dt
        n = len(cur)
        cov = np.broadcast_to(0.05 * np.eye(2), (n, horizon_steps, 2, 2))
        ahead = cur.xy[:, None, :] + (cur.speed[:, None] * t)[..., None] * np.array([1.0, 0.0])
        turn = cur.speed[:, None] * t / 10.0  # (N, T) angle turned [rad]
        right = cur.xy[:, None, :] + 10.0 * np.stack([np.sin(turn), np.cos(turn) - 1.0], -1)
        main = Prediction(cur.ids, dt, ahead, cov, np.zeros((n, horizon_steps)))
        alt = Prediction(cur.ids, dt, right, cov, -turn)
        return Prediction(cur.ids, dt, main.mean, main.cov, main.yaw, (alt,), np.tile([0.6, 0.4], (n, 1)))


def _scene() -> Scene:
    path = Polyline.from_points(np.array([[0.0, 0.0], [500.0, 0.0]]))
    route = RoutePath(edges=("e",), path=path, lane_of_vertex=("e_0", "e_0"), speed_limit=np.full(2, 14.0),
                      left=np.full(2, 5.25), right=np.full(2, -1.75), links=())
    ego = AgentStates(ids=("ego",), x=np.array([10.0]), y=np.zeros(1), yaw=np.zeros(1), speed=np.full(1, 10.0),
                      accel=np.zeros(1), length=np.full(1, EGO_L), width=np.full(1, EGO_W), mass=np.full(1, EGO_M),
                      cls=np.zeros(1, np.int8))
    # a leader 20 m ahead braking hard from 6 m/s: it stands after 3 m (the braking prior)
    lead = AgentStates(ids=("lead",), x=np.array([30.0]), y=np.zeros(1), yaw=np.zeros(1), speed=np.full(1, 6.0),
                       accel=np.full(1, -6.0), length=np.full(1, 4.5), width=np.full(1, 1.8),
                       mass=np.full(1, 1500.0), cls=np.zeros(1, np.int8))
    hist = np.stack([lead.xy[0] - np.array([0.6 * i, 0.0]) for i in range(5)][::-1])[None]
    obs = Observation(time=0.0, dt=DT, history=hist, valid=np.ones((1, 5), bool), current=lead, ego=ego)
    return Scene(time=0.0, dt=DT, ego=ego, others=lead, route=route, s=10.0, d=0.0, stop_s=None,
                 vehicle=EgoVehicle(), history=obs)


def test_planner_runs_on_two_modes_and_the_priors_keep_them(tmp_path):
    fake = TwoModes()
    planner = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=fake)
    decision = planner.act(_scene())
    assert fake.calls == 1
    trace = decision.trace
    pred = trace.prediction
    assert pred.n_modes == 2 and np.array_equal(pred.weight, [[0.6, 0.4]])
    # the braking prior capped both modes at v^2 / (2 |a|) = 36 / 12 = 3 m, each along its own
    # path: 3 m straight on, or 0.3 rad round the circle: (30 + 10 sin 0.3, -10 (1 - cos 0.3))
    # (the lateral prior leaves both: one is aligned with the leader, the other turns)
    turned = [30.0 + 10.0 * math.sin(0.3), -10.0 * (1.0 - math.cos(0.3))]
    assert pred.mean[0, -1] == pytest.approx([33.0, 0.0])
    assert pred.alternatives[0].mean[0, -1] == pytest.approx(turned, abs=1e-3)
    assert np.isfinite(trace.risk).all() and np.isfinite(trace.selection).all()
    # the recorded decision keeps the weights and the other mode's path; explain can draw it
    rec.write(rec.step_path(tmp_path, 1), rec.encode(trace, 1, 0.0, DT))
    d = rec.load(tmp_path, 1)
    np.testing.assert_allclose(d.pred_weight, [[0.6, 0.4]])
    np.testing.assert_allclose(d.pred_alt_mean[0, 0, -1], turned, atol=1e-3)
    np.testing.assert_allclose(d.pred_mean[0, -1], [33.0, 0.0], atol=1e-4)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sumo_ethics.analysis.drawing import draw_agents

    from dataclasses import replace

    # the other mode is drawn dotted; a mode of weight 0 (a one-mode pedestrian's) is not drawn
    for weight, dotted in (([[0.6, 0.4]], 1), ([[1.0, 0.0]], 0)):
        fig, ax = plt.subplots()
        assert draw_agents(ax, replace(d, pred_weight=np.array(weight))) == ["car"]
        assert sum(line.get_linestyle() == ":" for line in ax.get_lines()) == dotted
        plt.close(fig)
    # probability labels at the paths' ends: the two ends are 0.45 m apart, so only the likelier
    # mode is labelled; 10 m apart, both are
    for shift, labels in ((0.0, ["60%"]), (10.0, ["60%", "40%"])):
        fig, ax = plt.subplots()
        draw_agents(ax, replace(d, pred_alt_mean=d.pred_alt_mean + np.array([0.0, shift])))
        assert [t.get_text() for t in ax.texts] == labels
        plt.close(fig)


def test_single_mode_recording_has_no_mode_arrays(tmp_path):
    class One(TwoModes):
        def predict(self, obs, horizon_steps, dt):
            return super().predict(obs, horizon_steps, dt).single()

    trace = EthicalPlanner(PlannerConfig(predictor="cv"), predictor=One()).act(_scene()).trace
    arrays = rec.encode(trace, 1, 0.0, DT)
    assert "pred_weight" not in arrays and "pred_alt_mean" not in arrays
    rec.write(rec.step_path(tmp_path, 1), arrays)
    d = rec.load(tmp_path, 1)
    assert d.pred_weight is None and d.pred_alt_mean is None
