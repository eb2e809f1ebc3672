"""explain names the hard constraint that kept an alternative from being chosen (issue 41)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from sumo_ethics.analysis.explain import excluded_note
from sumo_ethics.plan.ethical import EthicalPlanner, PlannerConfig, exclusion_codes
from sumo_ethics.record import decisions as rec

from sumo_ethics.plan import synthetic  # the synthetic straight road, no SUMO


def test_codes_by_hand():
    legal = np.array([True, False, True, False, True])
    on_road = np.array([True, True, False, False, True])
    overlap = np.array([False, False, False, False, True])
    # a legal on-road candidate exists: red first, then the road edge; the envelope narrows "cost" only
    assert exclusion_codes(legal, on_road, overlap, "cost").tolist() == [0, 1, 2, 1, 3]
    assert exclusion_codes(legal, on_road, overlap, "validity").tolist() == [0, 1, 2, 1, 0]
    # nobody keeps the stop line: the red excludes no one, the road edge still does
    assert exclusion_codes(np.zeros(3, bool), np.array([True, False, True]), np.zeros(3, bool), "cost").tolist() == [0, 2, 0]
    # everyone enters an envelope: the envelope excludes no one
    assert exclusion_codes(np.ones(2, bool), np.ones(2, bool), np.ones(2, bool), "cost").tolist() == [0, 0]
    # evasive candidates (the last two) are held back while a plain one stays out of every envelope,
    # and weighed once none does; the envelope's code comes first
    ev = np.array([False, False, True, True])
    assert exclusion_codes(np.ones(4, bool), np.ones(4, bool), np.array([True, False, True, False]), "cost",
                           ev).tolist() == [3, 0, 3, 4]
    assert exclusion_codes(np.ones(4, bool), np.ones(4, bool), np.array([True, True, True, False]), "cost",
                           ev).tolist() == [3, 3, 3, 0]


def test_a_red_light_exclusion_is_recorded_and_named(tmp_path):
    sc = synthetic.scene(3)
    stop = sc.s + 25.0  # a red stop line 25 m ahead of the ego's centre, at 12 m/s
    sc = replace(sc, stop_s=stop)
    d = EthicalPlanner(PlannerConfig(predictor="cv")).act(sc)
    tr = d.trace
    crosses = np.any(tr.candidates.valid & (tr.candidates.s + float(sc.ego.length[0]) / 2 > stop), axis=1)
    assert crosses.any() and not crosses.all()
    assert np.array_equal(tr.excluded == 1, crosses)  # exactly the candidates whose front passes the line
    assert tr.excluded[tr.chosen] == 0
    rec.write(rec.step_path(tmp_path, 1), rec.encode(tr, 1, 0.0, 0.1))
    back = rec.load(tmp_path, 1)
    k = int(np.flatnonzero(crosses)[0])
    assert np.array_equal(back.excluded, tr.excluded)
    assert excluded_note(back, k) == "\nexcluded: crosses a red/yellow stop line"
    assert excluded_note(back, tr.chosen) == "" and excluded_note(replace(back, excluded=None), k) == ""
