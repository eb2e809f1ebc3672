"""Risk terms (METHOD.md section 1) and the cost J_origin / J_utility / J_risk (section 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_ethics.ethics.cost import PRESETS, TERMS, CostConfig, PrincipleWeights, UtilityMode, score
from sumo_ethics.ethics.harm import HarmCoefficients, Party, crash_outcome, leave_road_harm
from sumo_ethics.ethics.probability import EthicsConfigError, collision_probability
from sumo_ethics.ethics.risk import RiskTerms, assess_risk, boundary_harm
from sumo_ethics.types import AgentStates, Candidates, Prediction, RoadUserClass

DT = 0.1
EGO_L, EGO_W, EGO_M = 4.508, 1.610, 1475.0


def candidates(x, y, yaw, speed, d=None, valid=None) -> Candidates:
    x = np.asarray(x, float)
    shape = x.shape
    full = lambda v: np.broadcast_to(np.asarray(v, float), shape).copy()  # noqa: E731
    z = np.zeros(shape)
    return Candidates(
        dt=DT, x=x, y=full(y), yaw=full(yaw), speed=full(speed), accel=z, curvature=z, s=z,
        d=z if d is None else full(d), horizon=np.full(shape[0], shape[1] * DT),
        valid=np.ones(shape, bool) if valid is None else np.asarray(valid, bool),
    )


def risk_terms(ego_risk, other_risk, ego_harm_max, other_harm_max, boundary, vulnerable=None, T=3) -> RiskTerms:
    return RiskTerms.from_risks(ego_risk, other_risk, ego_harm_max, other_harm_max, boundary, vulnerable, T)


# ------------------------------------------------------------------ the toy case, by hand
# 2 candidates x 2 agents, T = 3 (step 3 invalid, its values must be ignored).
TOY_CAND = candidates(
    x=np.zeros((2, 3)), y=0.0, yaw=0.0,
    speed=[[10.0, 12.0, 99.0], [8.0, 8.0, 99.0]],
    d=[[0.0, -1.0, 99.0], [-2.0, -2.0, 99.0]],
    valid=[[True, True, False], [True, True, False]],
)
TOY_RISK = risk_terms(
    ego_risk=[[0.10, 0.00], [0.02, 0.04]],
    other_risk=[[0.30, 0.00], [0.02, 0.01]],
    ego_harm_max=[[0.5, 0.0], [0.2, 0.4]],
    other_harm_max=[[0.6, 0.0], [0.1, 0.1]],
    boundary=[0.0, 0.5],
    vulnerable=[False, True],
)


def test_toy_case_every_term_by_hand():
    c = score(TOY_CAND, TOY_RISK, CostConfig(), desired_speed=10.0).terms
    # sums: ego 0.10 | 0.06, other 0.30 | 0.03, boundary 0 | 0.5
    # Bayes = (ego + other + boundary) / (2N = 4): 0.40 / 4 = 0.1 | 0.59 / 4 = 0.1475
    np.testing.assert_allclose(c["bayes"], [0.1, 0.1475])
    # Equality = sum |ego - other| / N: (0.2 + 0) / 2 = 0.1 | (0 + 0.03) / 2 = 0.015
    np.testing.assert_allclose(c["equality"], [0.1, 0.015])
    # Maximin = (max harm)^10: max(0.5, 0, 0.6, 0, 0) = 0.6 -> 0.0060466176 | max(.2, .4, .1, .1, .5) = 0.5 -> 0.0009765625
    np.testing.assert_allclose(c["max_harm"], [0.6, 0.5])
    np.testing.assert_allclose(c["maximin"], [0.0060466176, 0.0009765625])
    # Ego = sum ego risk + boundary: 0.1 | 0.06 + 0.5 = 0.56
    np.testing.assert_allclose(c["ego"], [0.1, 0.56])
    # progress = |10 - mean(10, 12)| = 1 | |10 - mean(8, 8)| = 2 (the invalid 99 ignored)
    np.testing.assert_allclose(c["progress"], [1.0, 2.0])
    # lateral = mean |d| = 0.5 | 2
    np.testing.assert_allclose(c["lateral"], [0.5, 2.0])
    # J_origin (ethical) = 250 * 33.3 * (B + E + M) + 1 * progress + 10 * lateral
    #   = 8325 * 0.2060466176 + 1 + 5 = 1715.33809152 + 6 = 1721.33809152
    #   | 8325 * 0.1634765625 + 2 + 20 = 1360.9423828125 + 22 = 1382.9423828125
    np.testing.assert_allclose(c["j_origin"], [1721.33809152, 1382.9423828125])
    # J(s) = 0.40 | 0.59; candidate mean 0.495: candidate 0 below -> J_utility 0, candidate 1 ->
    # utility_scale x 0.59 = 1e4 x 0.59 = 5900
    np.testing.assert_allclose(c["j_total_risk"], [0.40, 0.59])
    np.testing.assert_allclose(c["j_mean"], [0.495, 0.495])
    np.testing.assert_allclose(c["j_utility"], [0.0, 5900.0])
    # J_risk = 1 * J_origin + 0.5 * J_utility (the default w_u) = 1721.33809152 | 1382.9423828125 + 2950
    # = 4332.9423828125: the utility term turns the choice to candidate 0
    np.testing.assert_allclose(c["j_risk"], [1721.33809152, 4332.9423828125])
    # VRU risk: agent 1 is vulnerable: other_risk[:, 1] = 0 | 0.01
    np.testing.assert_allclose(c["vru_risk_sum"], [0.0, 0.01])
    # ex-ante risk maxima over parties: ego max(0.10, 0) | max(0.02, 0.04); third party 0.30 | 0.02;
    # VRU (agent 1 only) 0 | 0.01
    np.testing.assert_allclose(c["ego_risk_max"], [0.10, 0.04])
    np.testing.assert_allclose(c["other_risk_max"], [0.30, 0.02])
    np.testing.assert_allclose(c["vru_risk_max"], [0.0, 0.01])
    # nobody flagged as a rule breaker: responsibility = other risk / N = 0.30 / 2 | 0.03 / 2
    np.testing.assert_allclose(c["responsibility"], [0.15, 0.015])
    assert set(TERMS) == set(c)


def test_toy_case_feasible_pool_literal_mode_and_presets():
    # Only candidate 0 feasible: J_mean = 0.40, candidate 0 sits on the mean (not penalised), 1 is above.
    c = score(TOY_CAND, TOY_RISK, CostConfig(), 10.0, feasible=np.array([True, False])).terms
    np.testing.assert_allclose(c["j_mean"], [0.40, 0.40])
    np.testing.assert_allclose(c["j_utility"], [0.0, 5900.0])
    # Literal: J_mean = J / (N + 1) = 0.40 / 3 | 0.59 / 3, always below J > 0 -> J_utility = J.
    lit = score(TOY_CAND, TOY_RISK, CostConfig(utility=UtilityMode.LITERAL), 10.0).terms
    np.testing.assert_allclose(lit["j_mean"], [0.40 / 3, 0.59 / 3])
    np.testing.assert_allclose(lit["j_utility"], [4000.0, 5900.0])
    # "standard": principles 0 -> J_origin = progress + 10 lateral = 1 + 5 = 6 | 2 + 20 = 22.
    std = score(TOY_CAND, TOY_RISK, CostConfig(weights="standard"), 10.0).terms
    np.testing.assert_allclose(std["j_origin"], [6.0, 22.0])
    # "ego": 250 * 100 * Ego + ... = 25000 * 0.1 + 6 = 2506 | 25000 * 0.56 + 22 = 14022.
    ego = score(TOY_CAND, TOY_RISK, CostConfig(weights=PrincipleWeights.preset("ego")), 10.0).terms
    np.testing.assert_allclose(ego["j_origin"], [2506.0, 14022.0])
    # omega_o = 0: J_risk = 0.5 * 1e4 * J_utility = 0 | 2950.
    only_u = score(TOY_CAND, TOY_RISK, CostConfig(omega_o=0.0, omega_u=0.5), 10.0)
    np.testing.assert_allclose(only_u.total, [0.0, 2950.0])
    assert only_u.row(1)["j_risk"] == pytest.approx(2950.0)
    # "bayes": 250 * 100 * B + 6 = 2506 | 25000 * 0.1475 + 22 = 3709.5;
    # "maximin": 25000 * 0.6^10 + 6 = 157.16544 | 25000 * 0.5^10 + 22 = 46.4140625
    bay = score(TOY_CAND, TOY_RISK, CostConfig(weights="bayes"), 10.0).terms
    np.testing.assert_allclose(bay["j_origin"], [2506.0, 3709.5])
    mm = score(TOY_CAND, TOY_RISK, CostConfig(weights="maximin"), 10.0).terms
    np.testing.assert_allclose(mm["j_origin"], [157.16544, 46.4140625])


def test_responsibility_counts_only_risk_on_rule_abiding_parties():
    # agent 0 broke a rule: only agent 1's risk counts: 0 / 2 | 0.01 / 2 = 0.005
    r = risk_terms(TOY_RISK.ego_risk, TOY_RISK.other_risk, TOY_RISK.ego_harm_max, TOY_RISK.other_harm_max,
                   [0.0, 0.5], [False, True])
    r = RiskTerms.from_risks(r.ego_risk, r.other_risk, r.ego_harm_max, r.other_harm_max, r.boundary_harm,
                             r.vulnerable, 3, rule_breaker=[True, False])
    w = PrincipleWeights(bayes=0.0, equality=0.0, maximin=0.0, responsibility=100.0)
    c = score(TOY_CAND, r, CostConfig(weights=w), 10.0).terms
    np.testing.assert_allclose(c["responsibility"], [0.0, 0.005])
    # J_origin = 250 * 100 * R + progress + 10 lateral = 0 + 6 | 125 + 22
    np.testing.assert_allclose(c["j_origin"], [6.0, 147.0])


def test_no_agents_gives_boundary_terms_only():
    cand = candidates(np.zeros((2, 3)), 0.0, 0.0, 10.0)
    r = risk_terms(np.zeros((2, 0)), np.zeros((2, 0)), np.zeros((2, 0)), np.zeros((2, 0)), [0.0, 0.25])
    c = score(cand, r, CostConfig(), 10.0).terms
    np.testing.assert_allclose(c["bayes"], [0.0, 0.25])
    np.testing.assert_allclose(c["equality"], [0.0, 0.0])
    np.testing.assert_allclose(c["maximin"], [0.0, 0.25**10])
    np.testing.assert_allclose(c["ego"], [0.0, 0.25])
    np.testing.assert_allclose(c["j_total_risk"], [0.0, 0.25])
    # Literal with N = 0: N_r = 1, J_mean = J -> never above -> J_utility = 0.
    lit = score(cand, r, CostConfig(utility="literal"), 10.0).terms
    np.testing.assert_allclose(lit["j_utility"], [0.0, 0.0])


def random_risk(rng: np.random.Generator, K: int, N: int) -> RiskTerms:
    er = rng.random((K, N)) * (rng.random((K, N)) < 0.3)
    orr = rng.random((K, N)) * (er > 0)
    return risk_terms(er, orr, np.minimum(er * 2, 1), np.minimum(orr * 2, 1), rng.random(K) * (rng.random(K) < 0.1))


def test_utility_zero_below_mean_and_argmin_never_above_mean():
    rng = np.random.default_rng(11)
    cfg = CostConfig(omega_o=0.0, omega_u=1.0)
    for _ in range(200):
        K, N = int(rng.integers(1, 40)), int(rng.integers(0, 6))
        cand = candidates(np.zeros((K, 4)), 0.0, 0.0, rng.uniform(0, 20, (K, 4)))
        risk = random_risk(rng, K, N)
        feasible = rng.random(K) < 0.6
        c = score(cand, risk, cfg, 10.0, feasible=feasible)
        J, Jm, Ju = c.terms["j_total_risk"], c.terms["j_mean"], c.terms["j_utility"]
        pool = feasible if feasible.any() else np.ones(K, bool)
        assert np.allclose(Jm, J[pool].mean())
        np.testing.assert_array_equal(Ju, np.where(J > Jm * (1 + 1e-9), 1e4 * J, 0.0))
        best = np.flatnonzero(pool)[np.argmin(c.total[pool])]
        assert J[best] <= J[pool].mean() * (1 + 1e-9)


def test_tied_candidates_are_not_penalised_by_rounding():
    # mean(0.1, 0.1, 0.1) rounds to 0.10000000000000002 > 0.1 or below it depending on the sum order.
    cand = candidates(np.zeros((3, 2)), 0.0, 0.0, 10.0)
    risk = risk_terms(np.full((3, 1), 0.1), np.zeros((3, 1)), np.zeros((3, 1)), np.zeros((3, 1)), np.zeros(3))
    np.testing.assert_array_equal(score(cand, risk, CostConfig(), 10.0).terms["j_utility"], 0.0)


# ------------------------------------------------------------------ configs
def test_unknown_preset_lists_the_known_ones():
    with pytest.raises(ValueError, match="known presets: bayes, ego, ethical, maximin, responsible, standard"):
        PrincipleWeights.preset("utilitarian")
    with pytest.raises(ValueError, match="known presets"):
        CostConfig(weights="nope")
    assert PrincipleWeights.preset("ethical") == PRESETS["ethical"] == PrincipleWeights()


@pytest.mark.parametrize("field", ["bayes", "equality", "maximin", "ego", "risk", "velocity", "lateral"])
@pytest.mark.parametrize("value", [-1.0, float("nan"), float("inf")])
def test_weights_reject_negative_and_nan(field, value):
    with pytest.raises(ValueError, match=f"PrincipleWeights.{field} must be a non-negative finite number"):
        PrincipleWeights(**{field: value})


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"omega_o": -0.1}, "omega_o"),
        ({"omega_u": float("nan")}, "omega_u"),
        ({"maximin_exponent": 0.0}, "maximin_exponent"),
        ({"utility": "mean"}, "candidate_mean, literal"),
        ({"desired_speed": -3.0}, "desired_speed"),
        ({"weights": 3}, "weights"),
    ],
)
def test_cost_config_rejects_nonsense(kwargs, match):
    with pytest.raises(ValueError, match=match):
        CostConfig(**kwargs)


def test_score_needs_a_desired_speed():
    with pytest.raises(ValueError, match="desired_speed"):
        score(TOY_CAND, TOY_RISK, CostConfig())
    assert score(TOY_CAND, TOY_RISK, CostConfig(desired_speed=10.0)).total.shape == (2,)


# ------------------------------------------------------------------ risk terms
def agents_and_prediction(xy, yaw, speed, cls, length, width, mass, T):
    """Agents moving at constant velocity along their yaw; covariance 0.05 I."""
    xy, yaw, speed = np.atleast_2d(np.asarray(xy, float)), np.asarray(yaw, float), np.asarray(speed, float)
    n = len(yaw)
    ids = tuple(f"a{i}" for i in range(n))
    agents = AgentStates(
        ids=ids, x=xy[:, 0], y=xy[:, 1], yaw=yaw, speed=speed, accel=np.zeros(n),
        length=np.asarray(length, float), width=np.asarray(width, float), mass=np.asarray(mass, float),
        cls=np.asarray(cls, np.int8),
    )
    t = (np.arange(T) + 1) * DT
    heading = np.stack([np.cos(yaw), np.sin(yaw)], -1)
    mean = xy[:, None] + (speed[:, None] * t)[..., None] * heading[:, None]
    pred = Prediction(ids=ids, dt=DT, mean=mean, cov=np.broadcast_to(0.05 * np.eye(2), (n, T, 2, 2)),
                      yaw=np.broadcast_to(yaw[:, None], (n, T)))
    return agents, pred


def test_assess_risk_matches_dense_probability_times_harm():
    T = 40
    t = (np.arange(T) + 1) * DT
    # Two candidates driving +x at 10 m/s: one in lane y = 0, one at y = 3.5.
    cand = candidates(np.stack([10 * t, 10 * t]), np.array([[0.0], [3.5]]), 0.0, 10.0)
    # A car coming head-on in lane 0 at 5 m/s, and a pedestrian crossing at x = 25 towards y = 3.5.
    agents, pred = agents_and_prediction(
        xy=[[40.0, 0.0], [25.0, 1.0]], yaw=[math.pi, math.pi / 2], speed=[5.0, 1.5],
        cls=[RoadUserClass.CAR, RoadUserClass.PEDESTRIAN], length=[4.5, 0.5], width=[1.8, 0.5],
        mass=[1500.0, 75.0], T=T,
    )
    r = assess_risk(cand, pred, agents, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W)
    p = collision_probability(cand, pred, agents.length, agents.width, EGO_L, EGO_W)
    np.testing.assert_array_equal(r.p, p)
    # Dense reference harm on every (k, n, t), agent speed 5 | 1.5 m/s exactly (constant velocity).
    ego = Party(cand.x[:, None], cand.y[:, None], cand.yaw[:, None], cand.speed[:, None], np.asarray(EGO_M), np.asarray(0))
    oth = Party(pred.mean[None, ..., 0], pred.mean[None, ..., 1], pred.yaw[None], np.array([5.0, 1.5])[None, :, None],
                agents.mass[None, :, None], agents.cls[None, :, None])
    ref = crash_outcome(ego, oth, HarmCoefficients())
    on = p > 0
    np.testing.assert_allclose(r.ego_harm[on], ref.harm_a[on], rtol=1e-9)
    np.testing.assert_allclose(r.other_harm[on], ref.harm_b[on], rtol=1e-9)
    assert np.all(r.ego_harm[~on] == 0) and np.all(r.other_harm[~on] == 0)
    np.testing.assert_allclose(r.ego_risk, (p * ref.harm_a).max(axis=2), rtol=1e-9)
    np.testing.assert_allclose(r.other_risk, (p * ref.harm_b).max(axis=2), rtol=1e-9)
    np.testing.assert_allclose(r.other_harm_max, np.where(on, ref.harm_b, 0).max(axis=2), rtol=1e-9)
    np.testing.assert_array_equal(r.vulnerable, [False, True])
    # The car (closing at 15 m/s, dv 7.5 m/s each, front: harm ~0.04) threatens only candidate 0;
    # the pedestrian (hit at ~10 m/s: harm ~0.40) only candidate 1.
    assert r.ego_risk[0, 0] > 0.01 and r.ego_risk[1, 0] == 0 and r.other_risk[0, 1] == 0
    # Crossing at right angles: closing speed sqrt(10^2 + 1.5^2) = 10.1119, pedestrian's share m_e / (m_e + 75).
    dv_ped = math.hypot(10.0, 1.5) * EGO_M / (EGO_M + 75.0)
    assert r.other_harm_max[1, 1] == pytest.approx(1 / (1 + math.exp(3.164 - 0.288 * dv_ped)), rel=1e-6)
    # So the ethical cost prefers the (mild) car crash to hitting the pedestrian, and books VRU risk.
    c = score(cand, r, CostConfig(), desired_speed=10.0).terms
    assert c["j_risk"][1] > c["j_risk"][0]
    assert c["vru_risk_sum"][0] == 0 and c["vru_risk_sum"][1] == pytest.approx(r.other_risk[1, 1])
    np.testing.assert_array_equal(c["j_utility"] > 0, [False, True])


def test_assess_risk_without_agents_and_boundary_harm():
    T = 10
    cand = candidates(np.zeros((3, T)), 0.0, 0.0, np.array([[5.0], [10.0], [20.0]]) + np.zeros(T))
    agents = AgentStates.empty()
    pred = Prediction(ids=(), dt=DT, mean=np.zeros((0, T, 2)), cov=np.zeros((0, T, 2, 2)), yaw=np.zeros((0, T)))
    off = np.array([False, True, True])
    r = assess_risk(cand, pred, agents, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W, off_road=off)
    assert r.p.shape == r.ego_harm.shape == (3, 0, T) and r.ego_risk.shape == (3, 0)
    np.testing.assert_allclose(r.boundary_harm, [0.0, leave_road_harm(10.0), leave_road_harm(20.0)])
    # (K, T): the speed at the first off-road step.
    speed = np.tile(np.arange(T, dtype=float), (3, 1))
    cand2 = candidates(np.zeros((3, T)), 0.0, 0.0, speed)
    off2 = np.zeros((3, T), bool)
    off2[1, 4:] = True
    off2[2, 7] = True
    np.testing.assert_allclose(boundary_harm(cand2, off2), [0.0, leave_road_harm(4.0), leave_road_harm(7.0)])
    c = score(cand, r, CostConfig(), 10.0).terms
    np.testing.assert_allclose(c["ego"], r.boundary_harm)
    with pytest.raises(ValueError, match="same agents"):
        other_agents, _ = agents_and_prediction([[0.0, 0.0]], [0.0], [1.0], [0], [4.5], [1.8], [1500.0], T)
        assess_risk(cand, pred, other_agents, EGO_M, RoadUserClass.CAR, EGO_L, EGO_W)


# ------------------------------------------------------------------ normalise: in_range | at_risk
def _one_risk(n_agents: int, extra_at_risk: tuple[int, ...] = ()) -> RiskTerms:
    """2 candidates x n_agents: both put ego risk 0.02 and other risk 0.02 on agent 0 and nothing on
    anyone else; candidate 1 also comes within a non-zero collision probability (no harm) of the
    agents ``extra_at_risk``."""
    from sumo_ethics.ethics.probability import SparseProbability

    er = np.zeros((2, n_agents))
    er[:, 0] = 0.02
    k = np.array([0, 1] + [1] * len(extra_at_risk))
    n = np.array([0, 0, *extra_at_risk])
    z = np.zeros(len(k))
    return RiskTerms(ego_risk=er, other_risk=er.copy(), ego_harm_max=np.zeros((2, n_agents)),
                     other_harm_max=np.zeros((2, n_agents)), vulnerable=np.zeros(n_agents, bool),
                     boundary_harm=np.zeros(2), sparse=SparseProbability(k, n, np.zeros(len(k), int), z + 0.1,
                                                                         (2, n_agents, 3)),
                     ego_harm_at=z, other_harm_at=z)


def test_the_same_risk_costs_the_same_under_at_risk_whatever_the_traffic():
    cand = candidates(x=np.zeros((2, 3)), y=0.0, yaw=0.0, speed=10.0)  # no progress or lateral cost
    # "bayes": 250 x 100 x B, B = (0.02 + 0.02) / (2N).
    # in_range, 1 road user around: N = 1, B = 0.02 -> 500; with 20: N = 20, B = 0.001 -> 25
    one = score(cand, _one_risk(1), CostConfig(weights="bayes"), 10.0).terms
    twenty = score(cand, _one_risk(20), CostConfig(weights="bayes"), 10.0).terms
    np.testing.assert_allclose(one["j_origin"], [500.0, 500.0])
    np.testing.assert_allclose(twenty["j_origin"], [25.0, 25.0])
    np.testing.assert_array_equal(twenty["n_norm"], [20.0, 20.0])
    # at_risk: only agent 0 is at risk, N = 1 -> 500 with 1 or with 20 road users around
    for n in (1, 20):
        c = score(cand, _one_risk(n), CostConfig(weights="bayes", normalise="at_risk"), 10.0).terms
        np.testing.assert_allclose(c["j_origin"], [500.0, 500.0])
        np.testing.assert_array_equal(c["n_norm"], [1.0, 1.0])
    # candidate 1 also comes near agents 3 and 7 (P > 0, no harm): N = 3, B = 0.04 / 6 -> 166.67
    c = score(cand, _one_risk(20, (3, 7)), CostConfig(weights="bayes", normalise="at_risk"), 10.0).terms
    np.testing.assert_array_equal(c["n_norm"], [1.0, 3.0])
    np.testing.assert_allclose(c["j_origin"], [500.0, 166.666667], rtol=1e-8)


def test_at_risk_divides_equality_and_responsibility_too_but_not_ego_or_maximin():
    # one candidate, 20 agents; ego risk 0.03 and other risk 0.01 against agent 0 alone
    er, orr = np.zeros((1, 20)), np.zeros((1, 20))
    er[0, 0], orr[0, 0] = 0.03, 0.01
    risk = risk_terms(er, orr, np.full((1, 20), 0.0), np.full((1, 20), 0.0), [0.0])
    cand = candidates(x=np.zeros((1, 3)), y=0.0, yaw=0.0, speed=10.0)
    wide = score(cand, risk, CostConfig(), 10.0).terms
    near = score(cand, risk, CostConfig(normalise="at_risk"), 10.0).terms
    # equality |0.03 - 0.01| / N: 0.02 / 20 = 0.001 | 0.02 / 1; responsibility 0.01 / 20 | 0.01
    assert (wide["equality"][0], near["equality"][0]) == pytest.approx((0.001, 0.02))
    assert (wide["responsibility"][0], near["responsibility"][0]) == pytest.approx((0.0005, 0.01))
    # ego = 0.03 and maximin = 0 ** 10 either way
    assert wide["ego"][0] == near["ego"][0] == pytest.approx(0.03)
    assert wide["maximin"][0] == near["maximin"][0] == 0.0


def test_at_risk_with_nobody_at_risk_divides_by_one():
    # 2 agents, no risk, boundary harm 0.4: in_range B = 0.4 / 4 = 0.1; at_risk B = 0.4 / 2 = 0.2;
    # no agents at all: in_range B = b = 0.4 (Origin's), at_risk 0.4 / 2 = 0.2
    cand = candidates(x=np.zeros((1, 3)), y=0.0, yaw=0.0, speed=10.0)
    for n, want in ((2, (0.1, 0.2)), (0, (0.4, 0.2))):
        risk = risk_terms(np.zeros((1, n)), np.zeros((1, n)), np.zeros((1, n)), np.zeros((1, n)), [0.4])
        got = tuple(score(cand, risk, CostConfig(normalise=m), 10.0).terms["bayes"][0] for m in ("in_range", "at_risk"))
        assert got == pytest.approx(want)


def test_normalise_setting_from_toml_and_sweep_and_its_errors():
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.settings import planner_config
    from sumo_ethics.sweep.grid import parse_set

    assert planner_config({"normalise": "at_risk"}).cost.normalise == "at_risk"
    assert planner_config({}).cost.normalise == "in_range"
    assert parse_set(["normalise=in_range,at_risk"]) == {"normalise": ["in_range", "at_risk"]}
    with pytest.raises(ConfigError, match="^normalise must be one of in_range, at_risk, got 'everyone'$"):
        planner_config({"normalise": "everyone"})


# ------------------------------------------------------------------ presets on one price level
# one candidate standing still on its lane (no progress or lateral cost at v_desired = 0), one other
# party; both at risk r = 0.01 with harm 0.1 (Maximin: 0.1 ** 10 = 1e-10, no price per unit of r)
LEVEL_CAND = candidates(x=np.zeros((1, 3)), y=0.0, yaw=0.0, speed=np.zeros((1, 3)))
LEVEL_RISK = risk_terms(ego_risk=[[0.01]], other_risk=[[0.01]], ego_harm_max=[[0.1]], other_harm_max=[[0.1]],
                        boundary=[0.0])


@pytest.mark.parametrize(("preset", "preset_price", "scale"), [
    # per unit of r before w_risk = 250: Bayes 2r / 2 = r, Equality 0, Ego r, Responsibility r
    ("ego", 100.0, 1.0),                       # 100 r
    ("bayes", 100.0, 1.0),                     # 100 r
    ("ethical", 33.3, 100.0 / 33.3),           # 33.3 r (+ Maximin's 33.3e-10): a third of ego's
    ("responsible", 66.6, 100.0 / 66.6),       # 33.3 r + 33.3 r
])
def test_presets_on_one_price_level(preset, preset_price, scale):
    """price = "equal": the collision that harms the ego and one other party alike costs every preset
    that prices risk linearly what it costs "ego": 250 x 100 x 0.01 = 250 (by hand, above), up to
    Maximin's 250 x scale x 33.3 x 1e-10; the default price level keeps Origin's presets."""
    maximin = PrincipleWeights.preset(preset).maximin * 1e-10
    as_given = score(LEVEL_CAND, LEVEL_RISK, CostConfig(weights=preset), desired_speed=0.0).terms
    assert as_given["j_origin"][0] == pytest.approx(250.0 * (preset_price * 0.01 + maximin), rel=1e-12)
    level = CostConfig(weights=preset, price="equal")
    assert level.principle_scale == pytest.approx(scale, rel=1e-12)
    equal = score(LEVEL_CAND, LEVEL_RISK, level, desired_speed=0.0).terms
    assert equal["j_origin"][0] == pytest.approx(250.0 + 250.0 * scale * maximin, rel=1e-12)
    # every principle's own value unchanged: only their weighted sum is scaled
    for name in ("bayes", "equality", "maximin", "ego", "responsibility"):
        assert equal[name][0] == as_given[name][0]


def test_price_level_keeps_maximin_alone_and_refuses_unknown_levels():
    assert CostConfig(weights="maximin", price="equal").principle_scale == 1.0  # no linear price to level
    assert CostConfig(weights="standard", price="equal").principle_scale == 1.0
    with pytest.raises(EthicsConfigError, match="price must be one of preset, equal"):
        CostConfig(price="same")


def test_price_level_from_a_planner_table():
    """[planner] price = "equal" (TOML, or sweep --set price=equal) reaches the cost; a wrong one is one line."""
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.settings import planner_config

    assert planner_config({"price": "equal"}).cost.principle_scale == pytest.approx(100.0 / 33.3)
    assert planner_config({}).cost.principle_scale == 1.0
    with pytest.raises(ConfigError, match="price must be one of"):
        planner_config({"price": "cheap"})
