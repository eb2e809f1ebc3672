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


@pytest.mark.sumo
@pytest.mark.parametrize("hand", ["right", "left"])
def test_drivable_bounds_on_right_and_left_hand_networks(tmp_path, hand):
    """A 3-lane edge of 3.2 m lanes built right- and left-hand by netconvert (which numbers a
    left-hand edge's lanes from its left kerb). By hand: from the kerb lane the usable area reaches
    2 x 3.2 + 1.6 = 8.0 m towards the centre line and 1.6 m towards the kerb; from the middle lane
    4.8 m one way and 4.8 the other. The kerb is on the right on a right-hand network, on the left
    on a left-hand one."""
    from sumo_ethics.sim import session
    from sumo_ethics.sim.netbuild import PlainNet
    from sumo_ethics.sim.route import build_route_path

    net = PlainNet("wide", {"walkingareas": "false", **({"lefthand": "true"} if hand == "left" else {})})
    net.node("A", 0, 0, type="priority")
    net.node("B", 300, 0, type="priority")
    net.edge("f", "A", "B", numLanes=3, width=3.2, speed=13.89)
    net.build(tmp_path)
    cfg = tmp_path / "wide.sumocfg"
    cfg.write_text('<configuration><input><net-file value="wide.net.xml"/></input>'
                   '<time><begin value="0"/><end value="10"/></time></configuration>\n')
    session.start(session.read_scenario(cfg), 1, tmp_path / "err.log")
    try:
        from sumo_ethics.sim.backend import sumo

        ys = {i: sumo.lane.getShape(f"f_{i}")[0][1] for i in range(3)}
        kerb = min(ys, key=ys.get) if hand == "right" else max(ys, key=ys.get)  # lowest y: rightmost
        middle = 1
        r = build_route_path(("f",), f"f_{kerb}", "passenger")
        i = r.vertex_at(150.0)
        towards_kerb = -r.right[i] if hand == "right" else r.left[i]
        towards_centre = r.left[i] if hand == "right" else -r.right[i]
        assert towards_kerb == pytest.approx(1.6) and towards_centre == pytest.approx(8.0)
        m = build_route_path(("f",), f"f_{middle}", "passenger")
        assert (m.left[i], m.right[i]) == (pytest.approx(4.8), pytest.approx(-4.8))
    finally:
        session.close()
