"""docs/extending.md's cost term and step hook sections (issue 58): its code blocks, run as written. The comfort term is
registered, scored to the values worked out by hand, weighted by CostConfig.term_weights and
[planner.terms], recorded and drawn; at weight 0 it changes no decision. The step hook runs in a
short SUMO run and logs what steps.parquet holds."""

from __future__ import annotations

import json
import re
import sys

import numpy as np
import pandas as pd
import pytest

from conftest import ROOT, straight_road_scene
from sumo_ethics.ethics import terms as term_registry
from sumo_ethics.ethics.cost import CostConfig, score
from sumo_ethics.types import AgentStates, Candidates

DOC = ROOT / "docs" / "extending.md"


def _section() -> str:
    """The page's cost term and step hook sections."""
    text = DOC.read_text(encoding="utf-8")
    return text[text.index("## A cost term"):]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def blocks(lang: str) -> list[str]:
    """The doc's fenced code blocks in ``lang``, in order."""
    return re.findall(rf"```{lang}\n(.*?)```", _section(), flags=re.S)


@pytest.fixture
def jerk_term():
    """The doc's first block run: the comfort term registered (removed again afterwards)."""
    names = {t.name for t in term_registry.cost_terms()}
    ns: dict = {}
    try:
        exec(blocks("python")[0], ns)  # noqa: S102 - the documentation's own example
        yield ns
    finally:
        for t in term_registry.cost_terms():
            if t.name not in names:
                term_registry.unregister(t.name)
    assert {t.name for t in term_registry.cost_terms()} == names


def tiny() -> tuple[Candidates, object]:
    """Two candidates of three steps, 0.1 s apart; no road user in range. Accelerations: candidate 0
    0, 1, 1 m/s^2 (all valid); candidate 1 0, 2, 2 with its last step invalid."""
    from sumo_ethics.ethics.risk import RiskTerms

    def risk_terms(ego, other, ego_max, other_max, boundary, vulnerable=None, T=3):
        return RiskTerms.from_risks(ego, other, ego_max, other_max, boundary, vulnerable, T)

    accel = np.array([[0.0, 1.0, 1.0], [0.0, 2.0, 2.0]])
    z = np.zeros((2, 3))
    valid = np.array([[True, True, True], [True, True, False]])
    cand = Candidates(dt=0.1, x=z, y=z, yaw=z, speed=np.full((2, 3), 10.0), accel=accel, curvature=z, s=z, d=z,
                      horizon=np.full(2, 0.3), valid=valid)
    risk = risk_terms(np.zeros((2, 0)), np.zeros((2, 0)), np.zeros((2, 0)), np.zeros((2, 0)), [0.0, 0.0], T=3)
    return cand, risk


def test_the_term_is_registered_and_scores_what_a_person_computes(jerk_term):
    assert term_registry.term("jerk") is jerk_term["JERK"]
    assert [t.name for t in term_registry.cost_terms()][-1] == "jerk"  # after the built-in ones
    cand, risk = tiny()
    plain = score(cand, risk, CostConfig(), desired_speed=10.0)
    weighted = score(cand, risk, CostConfig(term_weights={"jerk": 0.01}), desired_speed=10.0)
    # by hand: jerks (a_t - a_{t-1}) / 0.1 s = 0, 10, 0 m/s^3 -> mean of squares 100 / 3;
    # candidate 1: 0, 20 (and its invalid third step) -> (0 + 400) / 2 valid steps = 200
    np.testing.assert_allclose(weighted.terms["jerk"], [100.0 / 3.0, 200.0])
    np.testing.assert_array_equal(plain.terms["jerk"], weighted.terms["jerk"])
    # J_origin gains 0.01 x jerk; omega_o = 1, so J_risk and the total gain the same (J_utility is 0 here)
    np.testing.assert_allclose(weighted.terms["j_origin"] - plain.terms["j_origin"], [1.0 / 3.0, 2.0])
    np.testing.assert_allclose(weighted.total - plain.total, [1.0 / 3.0, 2.0])
    # the breakdown keeps the built-in terms first, in their order; a row (steps.parquet's cost_*) has it
    assert list(weighted.terms)[:-1] == list(score(cand, risk, CostConfig(), desired_speed=10.0).terms)[:-1]
    assert weighted.row(0)["jerk"] == pytest.approx(100.0 / 3.0)


def test_the_docs_weight_settings(jerk_term):
    from sumo_ethics.settings import planner_config

    ns = dict(jerk_term)
    exec(blocks("python")[1], ns)  # noqa: S102
    assert ns["planner"].cost.term_weights == {"jerk": 0.01}
    table = tomllib.loads(blocks("toml")[0])
    assert planner_config({"terms": table["planner"]["terms"]}).cost.term_weights == {"jerk": 0.01}


def test_terms_table_takes_only_registered_keys():
    from sumo_ethics.errors import ConfigError
    from sumo_ethics.settings import planner_config

    with pytest.raises(ConfigError, match=r"\[planner.terms\]"):
        planner_config({"terms": {"jerk": 0.01}})  # not registered here


def _scene():
    others = AgentStates(ids=("a",), x=np.array([40.0]), y=np.array([0.0]), yaw=np.zeros(1), speed=np.array([8.0]),
                         accel=np.zeros(1), length=np.full(1, 4.5), width=np.full(1, 1.8), mass=np.full(1, 1500.0),
                         cls=np.zeros(1, np.int8))
    hist = np.stack([others.xy - np.array([[0.8, 0.0]]) * i for i in range(5)][::-1], axis=1)
    return straight_road_scene(others, hist)


def test_weight_zero_leaves_the_decision_as_it_was(jerk_term):
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig

    with_term = EthicalPlanner(PlannerConfig(predictor="cv")).act(_scene())
    term_registry.unregister("jerk")
    without = EthicalPlanner(PlannerConfig(predictor="cv")).act(_scene())
    exec(blocks("python")[0], {})  # noqa: S102 - registered again, for the fixture to remove
    assert with_term.command == without.command and with_term.trace.chosen == without.trace.chosen
    info = dict(with_term.info)
    assert np.isfinite(info.pop("cost_jerk"))
    assert list(info) == list(without.info) and info == without.info  # every other number, bit for bit
    np.testing.assert_array_equal(with_term.trace.selection, without.trace.selection)
    # weighted, it is part of the choice: the chosen candidate's total grows by its weighted jerk
    weighted = EthicalPlanner(PlannerConfig(cost=CostConfig(term_weights={"jerk": 1e3}), predictor="cv")).act(_scene())
    assert weighted.info["cost_jerk"] <= with_term.info["cost_jerk"]


def test_the_term_is_recorded_and_explained(jerk_term, tmp_path):
    """The decision's file keeps the term, and explain's panel has its row, weighted by the run's
    term_weights from config.json."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sumo_ethics.analysis.explain import cost_panel, panel_rows
    from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig
    from sumo_ethics.record import decisions as rec

    d = EthicalPlanner(PlannerConfig(cost=CostConfig(term_weights={"jerk": 0.01}), predictor="cv")).act(_scene())
    arrays = rec.encode(d.trace, step=1, time=0.0, dt=0.1)
    assert "jerk" in arrays["term_names"].tolist()
    rows = [name for name, _, _ in panel_rows()]
    assert rows.index("jerk") == rows.index("lateral") + 1  # among the J_origin terms
    rec.write(rec.step_path(tmp_path, 1), arrays)
    recorded = rec.load(tmp_path, 1)
    assert recorded.terms["jerk"][recorded.chosen] == pytest.approx(d.info["cost_jerk"], rel=1e-6)  # float32
    fig, ax = plt.subplots()
    cost_panel(ax, recorded, None, {"risk": 250.0, "velocity": 1.0, "lateral": 10.0, "jerk": 0.01})
    cells = [c.get_text().get_text() for c in ax.tables[0].get_celld().values()]
    assert "comfort (mean jerk^2) x 0.01" in cells
    plt.close(fig)


URBAN_NET = ROOT / "networks" / "urban" / "urban.net.xml"


@pytest.mark.sumo
def test_the_docs_hook_logs_every_step_in_a_short_run(tmp_path):
    """The doc's hook and run block in a real run: the baseline ego on the urban network's eastern
    approach, 90 m before the signal, which shows red for the first 45 s: it stops there once."""
    folder = tmp_path / "scenario"
    folder.mkdir()
    (folder / "t.rou.xml").write_text('<routes><vType id="car" vClass="passenger" length="4.5" width="1.8"/>'
                                      '<route id="r" edges="E_in W_out"/>'
                                      '<vehicle id="ego" type="car" route="r" depart="0" departPos="100" '
                                      'departLane="1"/></routes>\n')
    cfg = folder / "t.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{URBAN_NET}"/><route-files value="t.rou.xml"/></input>'
                   '<time><end value="30"/><step-length value="0.1"/></time></configuration>\n')
    out = tmp_path / "run"
    ns: dict = {"SCENARIO": cfg, "OUT": out}
    exec(blocks("python")[2], ns)  # noqa: S102 - the hook class
    exec(blocks("python")[3], ns)  # noqa: S102 - the run
    hook, summary = ns["hook"], ns["summary"]
    steps = pd.read_parquet(out / "steps.parquet")
    assert len(hook.speeds) == len(steps) > 100
    assert [v for _, v in hook.speeds] == steps["speed"].tolist()
    assert [t for t, _ in hook.speeds] == steps["time"].tolist()
    standing = ((steps["speed"] < 0.1) & steps["stop_s"].notna()).to_numpy()
    want = int(standing[0]) + int((standing[1:] & ~standing[:-1]).sum())
    assert want == 1  # it came to a stand at the red light once, and stood there
    assert summary.data["red_light_stops"] == hook.stops == want
    assert json.loads((out / "summary.json").read_text())["red_light_stops"] == want
