"""The ethical cost decides unavoidable harms: static dilemmas by hand, responsibility, w_u,
selection rules, the dilemma family's unavoidability, and the recorded ex-ante risk."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.ethics.cost import CostConfig, PrincipleWeights, score
from sumo_ethics.ethics.harm import Party, crash_outcome
from sumo_ethics.ethics.risk import RiskTerms
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig, select
from sumo_ethics.sim.rules import heading_error, outside_lane
from sumo_ethics.suite.dilemma import CHECK_SPEEDS, check, road_of, scenario_outcomes
from sumo_ethics.types import Candidates

ROOT = Path(__file__).resolve().parents[2]
DILEMMAS = ROOT / "scenarios" / "dilemmas"


def two_candidates(speed_a: float, speed_b: float, d_b: float) -> Candidates:
    """A: straight on at speed_a; B: at speed_b, offset d_b to the left (T = 2 steps)."""
    z = np.zeros((2, 2))
    return Candidates(dt=0.1, x=z, y=z, yaw=z, speed=np.array([[speed_a] * 2, [speed_b] * 2]), accel=z, curvature=z,
                      s=z, d=np.array([[0.0, 0.0], [d_b, d_b]]), horizon=np.full(2, 0.2), valid=np.ones((2, 2), bool))


def planner(**kw) -> EthicalPlanner:
    return EthicalPlanner(PlannerConfig(predictor="cv", **kw))


def choose(p: EthicalPlanner, cost, overlap=(True, True)) -> int:
    ov = np.array(overlap)
    n = len(ov)
    ones = np.ones(n, bool)
    classes = [~ov & ones, ~ov, ~ov, ones]
    _, j, _ = p.choose(cost, classes, p.cfg.envelope * ov, ones, ones, np.where(ov, 5, 40), 40, np.zeros(n))
    return j


# ---- a static two-option dilemma, by hand ------------------------------------------------------------
# A brakes to 10 m/s and hits a pedestrian head-on; B keeps 12 m/s and swerves 3.25 m left into a
# car in the next lane going 10 m/s, meeting it at 0.5 rad. Collision probability 1 in both.
#   A: dv = 10, dv_ego = 75 / 1550 x 10 = 0.4839: ego (angle-free) 1 / (1 + exp(4.591 - 0.185 x 0.4839))
#      = 1 / (1 + 90.15) = 0.01097; pedestrian dv_p = 1475 / 1550 x 10 = 9.516:
#      1 / (1 + exp(3.164 - 0.288 x 9.516)) = 1 / (1 + 1.527) = 0.3957.
#   B: dv = sqrt(12^2 + 10^2 + 2 x 12 x 10 cos(pi - 0.5)) = 5.778, 2.889 each (equal masses), both
#      side impacts: 1 / (1 + exp(4.457 - 0.177 x 2.889 - 0.244)) = 1 / (1 + 40.50) = 0.02409.
H_EGO_A, H_PED = 0.01097, 0.3957
H_CAR = 0.02409


def test_hand_harms_match_the_harm_model():
    ego = Party(x=np.array(0.0), y=np.array(0.0), yaw=np.array(0.0), speed=np.array(10.0), mass=np.array(1475.0),
                cls=np.array(0))
    ped = Party(x=np.array(2.0), y=np.array(0.0), yaw=np.array(np.pi / 2), speed=np.array(0.0), mass=np.array(75.0),
                cls=np.array(5))
    a = crash_outcome(ego, ped)
    assert float(a.harm_a) == pytest.approx(H_EGO_A, abs=1e-5) and float(a.harm_b) == pytest.approx(H_PED, abs=1e-4)
    ego_b = Party(x=np.array(0.0), y=np.array(0.0), yaw=np.array(0.5), speed=np.array(12.0), mass=np.array(1475.0),
                  cls=np.array(0))
    car = Party(x=np.array(0.0), y=np.array(2.0), yaw=np.array(0.0), speed=np.array(10.0), mass=np.array(1475.0),
                cls=np.array(0))
    b = crash_outcome(ego_b, car)
    assert float(b.harm_a) == pytest.approx(H_CAR, abs=1e-5) and float(b.harm_b) == pytest.approx(H_CAR, abs=1e-5)


def dilemma_risk() -> RiskTerms:
    # parties: 0 the pedestrian (VRU), 1 the car; risk = P x harm with P = 1
    return RiskTerms.from_risks(ego_risk=[[H_EGO_A, 0.0], [0.0, H_CAR]], other_risk=[[H_PED, 0.0], [0.0, H_CAR]],
                                ego_harm_max=[[H_EGO_A, 0.0], [0.0, H_CAR]], other_harm_max=[[H_PED, 0.0], [0.0, H_CAR]],
                                boundary_harm=[0.0, 0.0], vulnerable=[True, False], T=2)


def test_static_dilemma_bayes_spares_the_pedestrian_ego_spares_the_ego():
    cand = two_candidates(10.0, 12.0, 3.25)
    # "bayes" (100 x Bayes): 250 x 100 x (ego + other) / (2N = 4) + |v_des - v| + 10 |d|, v_des = 12:
    #   A: 6250 x (0.01097 + 0.3957) + 2 = 2543.7;  B: 6250 x 2 x 0.02409 + 0 + 32.5 = 333.6 -> B
    bay = score(cand, dilemma_risk(), CostConfig(weights="bayes", omega_u=0.0), desired_speed=12.0)
    np.testing.assert_allclose(bay.terms["j_origin"], [2543.69, 333.63], atol=0.05)
    # "ego" (100 x Ego): 25000 x ego risk + progress + lateral:
    #   A: 25000 x 0.01097 + 2 = 276.25;  B: 25000 x 0.02409 + 32.5 = 634.75 -> A
    ego = score(cand, dilemma_risk(), CostConfig(weights="ego", omega_u=0.0), desired_speed=12.0)
    np.testing.assert_allclose(ego.terms["j_origin"], [276.25, 634.75], atol=0.05)
    # both options enter someone's envelope: the cost, not time to collision, decides
    assert choose(planner(cost=CostConfig(weights="bayes", omega_u=0.0)), bay) == 1  # the car: lower total harm
    assert choose(planner(cost=CostConfig(weights="ego", omega_u=0.0)), ego) == 0  # the pedestrian: lower ego harm
    # the recorded ex-ante risk per class of each option
    assert bay.row(0)["vru_risk_sum"] == pytest.approx(H_PED) and bay.row(1)["vru_risk_sum"] == 0.0
    assert bay.row(1)["ego_risk_max"] == pytest.approx(H_CAR) and bay.row(0)["other_risk_max"] == pytest.approx(H_PED)


def test_earlier_ttc_rule_ignores_the_ethics():
    # validity_ttc keeps the latest-entering candidates first: with A entering at step 9 and B at 5,
    # A wins whatever the weights say; "cost" lets Bayes pick B.
    cand = two_candidates(10.0, 12.0, 3.25)
    bay = score(cand, dilemma_risk(), CostConfig(weights="bayes", omega_u=0.0), desired_speed=12.0)
    classes = [np.zeros(2, bool)] * 3 + [np.ones(2, bool)]
    j, c = select(classes, bay.total, np.array([9, 5]), 40, np.zeros(2))
    assert (j, c) == (0, 3)
    assert select(classes, bay.total)[0] == 1  # Origin's validity rule: lowest cost in the class


def test_responsibility_moves_risk_onto_the_rule_breaker():
    # two options with the same risk 0.05 on one party each; B is 1 m/s slower (progress 1 vs 0).
    # Party 0 ran a red light. Without responsibility: A (progress 0) costs 250 x 33.3 x (B + E)
    # the same as B, so A wins by progress. With responsibility 100, A puts its risk on the
    # rule-abiding party 1... here A risks party 1 (abiding) and B risks party 0 (breaker):
    #   R_A = 0.05 / 2 = 0.025 -> +250 x 100 x 0.025 = 625;  R_B = 0 -> B wins.
    cand = two_candidates(12.0, 11.0, 0.0)
    r = RiskTerms.from_risks(ego_risk=[[0.0, 0.0], [0.0, 0.0]], other_risk=[[0.0, 0.05], [0.05, 0.0]],
                             ego_harm_max=np.zeros((2, 2)), other_harm_max=[[0.0, 0.2], [0.2, 0.0]],
                             boundary_harm=[0.0, 0.0], T=2, rule_breaker=[True, False])
    plain = score(cand, r, CostConfig(omega_u=0.0), desired_speed=12.0)
    assert plain.total[1] - plain.total[0] == pytest.approx(1.0)  # only progress differs
    assert choose(planner(cost=CostConfig(omega_u=0.0)), plain) == 0
    w = PrincipleWeights(responsibility=100.0)
    resp = score(cand, r, CostConfig(weights=w, omega_u=0.0), desired_speed=12.0)
    np.testing.assert_allclose(resp.terms["responsibility"], [0.025, 0.0])
    assert resp.total[0] - resp.total[1] == pytest.approx(625.0 - 1.0)
    assert choose(planner(cost=CostConfig(weights=w, omega_u=0.0)), resp) == 1


def test_utility_weight_moves_the_choice_within_its_range():
    # Three options; A is fastest but riskiest. J = 0.02 | 0.005 | 0.002 (third parties only),
    # candidate mean 0.009: only A is above it, J_utility(A) = 1e4 x 0.02 = 200.
    # J_origin (ethical, N = 1): 250 x 33.3 x (J / 2 + J) + progress = 12487.5 J + progress:
    #   A: 249.75 + 0 | B: 62.44 + 4 | C: 24.98 + 8 -> without w_u, C (32.98).
    # Make progress count more: v_des 12, speeds 12 | 8 | 4 and 'standard'-like risk weight 1:
    cand = Candidates(dt=0.1, x=np.zeros((3, 2)), y=np.zeros((3, 2)), yaw=np.zeros((3, 2)),
                      speed=np.array([[12.0] * 2, [8.0] * 2, [4.0] * 2]), accel=np.zeros((3, 2)),
                      curvature=np.zeros((3, 2)), s=np.zeros((3, 2)), d=np.zeros((3, 2)), horizon=np.full(3, 0.2),
                      valid=np.ones((3, 2), bool))
    r = RiskTerms.from_risks(ego_risk=np.zeros((3, 1)), other_risk=[[0.02], [0.005], [0.002]],
                             ego_harm_max=np.zeros((3, 1)), other_harm_max=[[0.3], [0.3], [0.3]],
                             boundary_harm=np.zeros(3), T=2)
    w = PrincipleWeights(bayes=0.0, equality=0.0, maximin=0.0, risk=1.0)
    # J_origin = progress: 0 | 4 | 8. J_utility(A) = 200 -> A costs 200 w_u: B wins once 200 w_u > 4,
    # i.e. from w_u = 0.02; no w_u moves it on to C (B and C are not above the mean).
    picks = {wu: choose(planner(cost=CostConfig(weights=w, omega_u=wu)),
                        score(cand, r, CostConfig(weights=w, omega_u=wu), desired_speed=12.0), (False,) * 3)
             for wu in (0.0, 0.01, 0.03, 0.5, 1.0)}
    assert picks == {0.0: 0, 0.01: 0, 0.03: 1, 0.5: 1, 1.0: 1}


# ---- the rule ------------------------------------------------------------------------------------------
def test_rule_clauses_by_hand():
    assert heading_error(np.pi - 0.1, -np.pi + 0.1) == pytest.approx(0.2)  # wrapped
    assert heading_error(0.0, np.pi) == pytest.approx(np.pi)
    # a 1.8 m car in a 3.25 m lane may sit up to (3.25 - 1.8) / 2 + 0.5 = 1.225 m off centre
    assert not outside_lane(1.2, 3.25, 1.8) and outside_lane(1.25, 3.25, 1.8)


# ---- the dilemma family --------------------------------------------------------------------------------
def test_pedestrian_in_front_with_no_neighbour_is_avoidable_by_swerving():
    # without the car alongside, swerving left avoids everyone: no dilemma (the check can say no)
    road = road_of(1, 2, 3.25)
    ped = {"id": "h0", "type": "pedestrian", "params": {"side": "right", "offset": 0.3, "speed": 2.0, "occluder": True,
                                                        "vtype": "ped"}}
    alone = check([ped], 0.7 * 16.67, 16.67, road)
    assert not alone.unavoidable
    esc = {"id": "h1", "type": "escort", "params": {"side": "left", "lane_offset": 2.8, "ahead": -1.0, "hold": 2.5,
                                                    "decel": 4.0, "vtype": "truck"}}
    both = check([ped, esc], 0.7 * 16.67, 16.67, road)
    assert both.unavoidable and {"h0", "h1"} <= set(both.parties)


def test_every_committed_dilemma_is_unavoidable_with_a_choice_of_victims():
    files = sorted(DILEMMAS.glob("*/hazards.json"))
    assert len(files) >= 50
    for f in files:
        spec = json.loads(f.read_text())
        outs = scenario_outcomes(spec, 16.67, road_of(spec["ego"]["lane"], 2, 3.25))
        assert [o.speed for o in outs] == pytest.approx([c * 16.67 for c in CHECK_SPEEDS])
        assert all(o.unavoidable for o in outs), f.parent.name
        assert all(len(o.parties) >= 2 for o in outs), f.parent.name


def test_dilemma_generation_is_reproducible(tmp_path):
    from sumo_ethics.suite.generate import dilemma_scenario

    a, xml_a = dilemma_scenario(2025, 3)
    b, xml_b = dilemma_scenario(2025, 3)
    assert a.to_dict() == b.to_dict() and xml_a == xml_b
    assert json.loads((DILEMMAS / "d0003" / "hazards.json").read_text()) == a.to_dict()


# ---- a real run: the recorded ex-ante risk is the chosen candidate's ----------------------------------
@pytest.mark.sumo
def test_recorded_exante_risk_equals_the_chosen_candidates_risk_terms(tmp_path, monkeypatch):
    import sumo_ethics.plan.ethical as ethical
    from sumo_ethics.runner import run
    from sumo_ethics.sim.hazards import HazardInjector
    from sumo_ethics.suite.spec import load

    seen: list[tuple[RiskTerms, int]] = []
    last: dict[str, RiskTerms] = {}
    real = ethical.assess_risk

    def spy(*a, **k):
        last["r"] = real(*a, **k)
        return last["r"]

    monkeypatch.setattr(ethical, "assess_risk", spy)

    class Probe(EthicalPlanner):
        def choose(self, *a, **k):
            total, j, cls = super().choose(*a, **k)
            seen.append((last["r"], j))
            return total, j, cls

    spec = load(DILEMMAS / "d0000")
    pcfg = PlannerConfig(predictor="cv")
    cfg = spec.run_config(tmp_path / "run", pcfg)
    summary = run(cfg, controller=Probe(pcfg), hooks=(HazardInjector(spec.hazards),))
    steps = pd.read_parquet(tmp_path / "run" / "steps.parquet").dropna(subset=["cost_ego_risk_sum"])
    assert len(steps) == len(seen) > 50
    risky = 0
    for (r, j), row in zip(seen, steps.itertuples()):
        vru = r.other_risk[j] * r.vulnerable
        want = (r.ego_risk[j].sum(), r.other_risk[j].sum(), vru.sum(), r.ego_risk[j].max(initial=0.0),
                r.other_risk[j].max(initial=0.0), vru.max(initial=0.0))
        got = (row.cost_ego_risk_sum, row.cost_other_risk_sum, row.cost_vru_risk_sum, row.cost_ego_risk_max,
               row.cost_other_risk_max, row.cost_vru_risk_max)
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=0.0)
        risky += want[1] > 0
    assert risky > 0  # the pedestrian dilemma shows up in the ex-ante risk
    assert summary.data["status"] == "collision"  # unavoidable by construction


@pytest.mark.sumo
def test_red_light_clause_in_sumo(tmp_path):
    """Vehicles that ignore the signal cross the suite's signalised junction every 7 s: each one
    is a rule breaker on the junction exactly when its link showed red as it entered, and only
    there (not on its approach, where it keeps its lane)."""
    import libsumo

    from sumo_ethics.sim import session
    from sumo_ethics.sim.rules import RuleMonitor
    from sumo_ethics.types import AgentStates

    net = ROOT / "scenarios" / "suite" / "networks" / "junction_tls" / "junction_tls.net.xml"
    (tmp_path / "r.rou.xml").write_text(
        '<routes><vType id="car" vClass="passenger" length="4.5" width="1.8"/>'
        + "".join(f'<vehicle id="v{i}" type="car" depart="{7 * i}" departSpeed="10"><route edges="N_in S_out"/></vehicle>'
                  for i in range(12)) + "</routes>")
    cfg = tmp_path / "t.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{net}"/><route-files value="r.rou.xml"/></input>'
                   '<time><end value="100"/><step-length value="0.1"/></time></configuration>')
    session.start(session.read_scenario(cfg), 1, tmp_path / "err.log")
    try:
        mon, entered, flagged_at_entry, flagged_outside = RuleMonitor(), {}, {}, 0
        last_lane: dict[str, str] = {}
        while libsumo.simulation.getTime() < 95:
            libsumo.simulationStep()
            ids = tuple(libsumo.vehicle.getIDList())
            for v in libsumo.simulation.getDepartedIDList():
                libsumo.vehicle.setSpeedMode(v, 0)  # ignores lights and everything else
            if not ids:
                continue
            xy = np.array([libsumo.vehicle.getPosition(v) for v in ids])
            yaw = np.radians(90.0 - np.array([libsumo.vehicle.getAngle(v) for v in ids]))
            n = len(ids)
            agents = AgentStates(ids, xy[:, 0], xy[:, 1], yaw, np.full(n, 10.0), np.zeros(n), np.full(n, 4.5),
                                 np.full(n, 1.8), np.full(n, 1500.0), np.zeros(n, dtype=np.int8))
            breakers = mon.breakers(agents)
            for v in ids:
                lane = libsumo.vehicle.getLaneID(v)
                before = last_lane.get(v, "")
                if lane.startswith(":") and before and not before.startswith(":"):
                    state = next(link[5] for link in libsumo.lane.getLinks(before) if link[4] == lane)
                    entered[v] = state
                    flagged_at_entry[v] = v in breakers
                elif not lane.startswith(":"):
                    flagged_outside += v in breakers
                last_lane[v] = lane
    finally:
        session.close()
    assert flagged_outside == 0
    assert {s for s in entered.values()} >= {"r", "G"} or {s for s in entered.values()} >= {"r", "g"}
    for v, state in entered.items():
        assert flagged_at_entry[v] == (state in "rR"), (v, state)
