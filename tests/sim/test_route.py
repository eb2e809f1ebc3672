"""The lane-level reference path labels each stretch with the lane it lies on (real SUMO)."""

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TESTBED = ROOT / "scenarios" / "testbed" / "testbed.sumocfg"


@pytest.fixture()
def testbed(tmp_path):
    from sumo_ethics.sim import session

    session.start(session.read_scenario(TESTBED), 1, tmp_path / "err.log")
    yield
    session.close()


@pytest.mark.sumo
def test_lane_labels_change_at_the_lane_boundaries(testbed):
    from sumo_ethics.sim.route import build_route_path

    # main_0 ends at x = 198 m, the junction lane :C_1_1 runs to x = 202 m, then main_1 (the
    # road starts at x = 0, so arc length s equals x along this straight path)
    r = build_route_path(("main_0", "main_1"), "main_0_2", "passenger")
    lane = lambda s: r.lane_of_vertex[r.vertex_at(s)]  # noqa: E731
    assert lane(150.0) == lane(196.5) == "main_0_2"
    assert lane(199.5) == lane(200.5) == ":C_1_1"
    assert lane(203.5) == lane(300.0) == "main_1_2"
    # the whole of main_1 is main_1 (a one-segment shift once labelled all of it a junction)
    labels = {r.lane_of_vertex[i] for i in range(r.vertex_at(203.5), r.vertex_at(395.0) + 1)}
    assert labels == {"main_1_2"}


@pytest.mark.sumo
def test_lane_labels_are_the_lanes_own_strings(testbed):
    """One str object per lane, shared by its vertices (not one numpy.str_ per vertex: a fleet
    holds a route per ego driving, thousands of vertices each)."""
    from sumo_ethics.sim.route import build_route_path

    r = build_route_path(("main_0", "main_1"), "main_0_2", "passenger")
    labels = r.lane_of_vertex
    assert len(labels) == len(r.path.s) > 3
    assert all(type(k) is str for k in labels)
    assert len({id(k) for k in labels}) == len(set(labels)) == 3
