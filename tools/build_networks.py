#!/usr/bin/env python3
"""Build the bundled SUMO networks and scenarios of sumo-ethics.

Run from anywhere::

    python tools/build_networks.py            # all networks and scenarios
    python tools/build_networks.py testbed    # only the named ones

For every network ``<name>`` the script writes plain-XML inputs into
``networks/<name>/`` (``<name>.nod.xml``, ``<name>.edg.xml``, ``<name>.con.xml``
and a ``<name>.netccfg`` netconvert configuration), runs netconvert (found
through ``sumo.SUMO_HOME``) with ``--offset.disable-normalization true`` so the
coordinates stay exactly as written here, and writes
``networks/<name>/<name>.net.xml``.  Then it writes ``scenarios/<scenario>/``
with ``<scenario>.sumocfg`` (step length 0.1 s, end 600 s, no seed: pass
``--seed`` on the command line) and ``<scenario>.rou.xml`` (vTypes, flows,
person flows).

The output is deterministic: the only run-dependent part of netconvert's output,
the "generated on <date>" header, is stripped, so rebuilding yields identical
files (idempotent).

Conventions used by all networks
--------------------------------
* Right-hand traffic, ``spreadType="right"`` (SUMO's default): the lanes of an
  edge lie to the right of the edge's geometry line, and for two-way roads the
  geometry line is the road centre line.
* Sidewalks are added with the edge attribute ``sidewalkWidth``.  A sidewalk is
  always lane index 0 of its edge, so on edges with a sidewalk the rightmost
  *road* lane has index 1.
* Turnarounds are disabled (``--no-turnarounds``).
* vType ids: ``car``, ``truck``, ``bus``, ``motorcycle``, ``bicycle``, ``ped``.
  Bicycles ride on the normal road lanes (no bike lanes anywhere).

Networks
--------
urban      one signalised 4-way junction ``C`` at (0, 0), arms of 200 m, 2 lanes
           per direction (3.2 m), 13.89 m/s, 2 m sidewalks, crossings on all
           four arms.  Edges ``{W,E,N,S}_in`` (towards C) / ``{W,E,N,S}_out``.
rural      two-lane rural road (one 3.5 m lane per direction) from x=0 to
           x=2000, 25 m/s, two gentle S-curves, then a 600 m village section
           (13.89 m/s, 1.5 m sidewalks) with a priority T-junction ``VJ`` at
           (1700, 0), a side street to the north and zebra crossings.
highway    one 3-lane carriageway (3.75 m, 33.33 m/s) eastbound from x=0 to
           x=2000, on-ramp with a 250 m acceleration lane, an off-ramp, and a
           local road with sidewalks feeding the on-ramp (pedestrians cross the
           ramp mouth and the local road there).
testbed    tiny 400 m straight for automated tests, see TESTBED below.
urban_grid 2x2 grid of signalised 4-way junctions ``J00`` (0, 0), ``J10``
           (500, 0), ``J01`` (0, 500), ``J11`` (500, 500), 300 m outer arms
           ``{W0,W1,E0,E1,S0,S1,N0,N1}_in/_out``, inner links ``J00_J10`` etc.,
           otherwise built like ``urban``.  Used by the dense benchmark scenario
           ``urban_grid`` (about 200 vehicles and 50 walking persons at once after
           a 300 s warm-up): 200 vehicles do not fit on the single ``urban``
           junction with 200 m arms without queues spilling back to the network
           boundary.  Note that ``person.getIDCount()`` also counts persons that
           are loaded but have not departed yet; count walking persons as departed
           minus arrived.

TESTBED (exact lane centre lines, read back from the built net)
--------------------------------------------------------------
Nodes ``W`` (0, 0), ``C`` (200, 0) (priority junction, zebra crossing), ``E``
(400, 0).  Eastbound edges ``main_0`` (W->C) and ``main_1`` (C->E), 2 road lanes
of 3.2 m plus a 2.0 m sidewalk; westbound edges ``opp_1`` (E->C) and ``opp_0``
(C->W), 1 road lane of 3.2 m plus a 2.0 m sidewalk.  Lane centre y values
(constant along x, the road is straight)::

    main_*_0  sidewalk (south)   y = -7.4
    main_*_1  right lane         y = -4.8
    main_*_2  left lane          y = -1.6
    opp_*_1   westbound lane     y = +1.6
    opp_*_0   sidewalk (north)   y = +4.2

The crossing ``:C_c0`` (4 m wide, priority to pedestrians) runs across all
three road lanes with its centre line at x = 200.0, from y = +3.2 to y = -6.4
(it covers 198 <= x <= 202).  The road lanes end at x = 198 (``main_0``) and
start at x = 202 (``main_1``); every normal lane is 198.0 m long, the internal
junction lanes ``:C_1_0`` / ``:C_1_1`` (eastbound) and ``:C_0_0`` (westbound) are 4 m.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

from sumo_ethics.sim.netbuild import PlainNet, attrs as _attrs, write_if_changed as _write

ROOT = Path(__file__).resolve().parent.parent
NETWORKS = ROOT / "networks"
SCENARIOS = ROOT / "scenarios"

STEP_LENGTH = 0.1
END = 600


# --------------------------------------------------------------------------- helpers
class Net(PlainNet):
    """A bundled network: built into ``networks/<name>/`` with its ``.netccfg``."""

    def build(self) -> Path:  # type: ignore[override]
        net = super().build(NETWORKS / self.name, config_file=True)
        if self.messages:
            print(f"[{self.name}] netconvert says:\n{self.messages}", file=sys.stderr)
        return net


# --------------------------------------------------------------------------- route files
VTYPES = {
    # id: attributes (SUMO defaults apply to everything not given)
    "car": dict(vClass="passenger", length=4.5, width=1.8, height=1.5, guiShape="passenger"),
    "truck": dict(vClass="truck", length=12.0, width=2.55, height=3.5, maxSpeed=25.0, guiShape="truck"),
    "bus": dict(vClass="bus", length=12.0, width=2.55, height=3.2, maxSpeed=25.0, guiShape="bus"),
    "motorcycle": dict(vClass="motorcycle", length=2.2, width=0.9, height=1.5, guiShape="motorcycle"),
    "bicycle": dict(vClass="bicycle", length=1.8, width=0.65, height=1.7, maxSpeed=6.0, guiShape="bicycle"),
    "ped": dict(vClass="pedestrian", length=0.3, width=0.5, height=1.75, guiShape="pedestrian"),
}


class Routes:
    def __init__(self, vtypes=tuple(VTYPES)):
        self.vtypes = list(vtypes)
        self.routes: list[tuple[str, list[str]]] = []
        self.flows: list[tuple[float, str]] = []  # (begin, xml) sorted by begin for SUMO
        self.persons: list[tuple[float, str]] = []

    def route(self, id, edges):
        self.routes.append((id, list(edges)))

    def flow(self, id, vtype, fr, to, per_hour, begin=0, end=END, **kw):
        """Random (Poisson) arrivals with the given mean rate."""
        if per_hour <= 0:
            return
        a = {
            "id": id, "type": vtype, "begin": begin, "end": end,
            "period": f"exp({per_hour / 3600:.6g})", "from": fr, "to": to,
            "departLane": "best", "departSpeed": "max", "departPos": "base",
        }
        a.update(kw)
        self.flows.append((begin, f"    <flow {_attrs(a)}/>\n"))

    def person_flow(self, id, fr, to, per_hour, begin=0, end=END, departPos="random", arrivalPos="random"):
        if per_hour <= 0:
            return
        a = {"id": id, "type": "ped", "begin": begin, "end": end,
             "period": f"exp({per_hour / 3600:.6g})", "departPos": departPos}
        w = {"from": fr, "to": to, "arrivalPos": arrivalPos}
        self.persons.append((begin, f"    <personFlow {_attrs(a)}>\n        <walk {_attrs(w)}/>\n    </personFlow>\n"))

    def xml(self) -> str:
        out = ["<routes xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" "
               "xsi:noNamespaceSchemaLocation=\"http://sumo.dlr.de/xsd/routes_file.xsd\">\n"]
        for t in self.vtypes:
            out.append(f"    <vType {_attrs({'id': t, **VTYPES[t]})}/>\n")
        for rid, edges in self.routes:
            out.append(f"    <route id=\"{rid}\" edges=\"{' '.join(edges)}\"/>\n")
        items = sorted(self.flows + self.persons, key=lambda x: x[0])  # stable sort
        out.extend(x for _, x in items)
        out.append("</routes>\n")
        return "".join(out)


def write_scenario(name: str, net: str, routes: Routes, end: int = END) -> Path:
    d = SCENARIOS / name
    _write(d / f"{name}.rou.xml", routes.xml())
    cfg = (
        "<configuration xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" "
        "xsi:noNamespaceSchemaLocation=\"http://sumo.dlr.de/xsd/sumoConfiguration.xsd\">\n"
        "    <input>\n"
        f"        <net-file value=\"../../networks/{net}/{net}.net.xml\"/>\n"
        f"        <route-files value=\"{name}.rou.xml\"/>\n"
        "    </input>\n"
        "    <time>\n"
        "        <begin value=\"0\"/>\n"
        f"        <end value=\"{end}\"/>\n"
        f"        <step-length value=\"{STEP_LENGTH}\"/>\n"
        "    </time>\n"
        "</configuration>\n"
    )
    path = d / f"{name}.sumocfg"
    _write(path, cfg)
    return path


# --------------------------------------------------------------------------- urban
URBAN_ARMS = {"W": (-1, 0), "E": (1, 0), "N": (0, 1), "S": (0, -1)}
# type shares of vehicle demand at urban junctions
URBAN_MIX = {"car": 0.80, "truck": 0.04, "bus": 0.03, "motorcycle": 0.06, "bicycle": 0.07}


def build_urban() -> None:
    net = Net("urban")
    net.node("C", 0, 0, "traffic_light")
    for arm, (dx, dy) in URBAN_ARMS.items():
        net.node(arm, 200 * dx, 200 * dy)
    road = dict(numLanes=2, speed=13.89, width=3.2, sidewalkWidth=2.0, priority=2)
    for arm in URBAN_ARMS:
        net.edge(f"{arm}_in", arm, "C", **road)
        net.edge(f"{arm}_out", "C", arm, **road)
    for arm in URBAN_ARMS:
        net.crossing("C", [f"{arm}_in", f"{arm}_out"])
    net.build()

    r = Routes()
    # vehicles per hour and approach; split: straight 50 %, right 25 %, left 25 %
    per_approach = 420
    turn = {"straight": 0.5, "right": 0.25, "left": 0.25}
    rel = _relations()
    for (a, b), kind in rel.items():
        for vt, share in URBAN_MIX.items():
            r.flow(f"{vt}_{a}_{b}", vt, f"{a}_in", f"{b}_out", per_approach * turn[kind] * share)
    for (a, b), kind in rel.items():
        r.person_flow(f"ped_{a}_{b}", f"{a}_in", f"{b}_out", 30 if kind == "straight" else 15)
    write_scenario("urban", "urban", r)


def _relations():
    order = ["N", "E", "S", "W"]  # clockwise
    rel = {}
    for i, a in enumerate(order):
        # coming from arm a (heading away from a): right turn goes to the arm
        # counter-clockwise of a, left turn to the arm clockwise of a
        rel[(a, order[(i + 2) % 4])] = "straight"
        rel[(a, order[(i - 1) % 4])] = "right"
        rel[(a, order[(i + 1) % 4])] = "left"
    return dict(sorted(rel.items()))


# --------------------------------------------------------------------------- rural
def _curve(x0, x1, amp, n=24):
    """Points of a half-sine bend y = amp * sin(pi * (x - x0) / (x1 - x0))."""
    return [(x0 + (x1 - x0) * i / n, amp * math.sin(math.pi * i / n)) for i in range(n + 1)]


def build_rural() -> None:
    net = Net("rural", {"opposites.guess": "true"})
    net.node("R0", 0, 0)
    net.node("R1", 800, 0)
    net.node("R2", 1400, 0)
    net.node("VJ", 1700, 0, "priority")
    net.node("R3", 2000, 0)
    net.node("VN", 1700, 150)
    rural = dict(numLanes=1, speed=25.0, width=3.5, priority=3, disallow="pedestrian")
    village = dict(numLanes=1, speed=13.89, width=3.25, sidewalkWidth=1.5, priority=3)
    # two gentle S-bends (radius about 1300 m and 900 m), then the straight village
    net.two_way("rural_e0", "rural_w0", "R0", "R1", shape=_curve(0, 800, 50), **rural)
    net.two_way("rural_e1", "rural_w1", "R1", "R2", shape=_curve(800, 1400, -40), **rural)
    net.two_way("village_e0", "village_w0", "R2", "VJ", **village)
    net.two_way("village_e1", "village_w1", "VJ", "R3", **village)
    net.two_way("side_out", "side_in", "VJ", "VN", numLanes=1, speed=13.89, width=3.0,
                sidewalkWidth=1.5, priority=1)
    # zebra crossings: across the main road just west of VJ and across the side street
    net.crossing("VJ", ["village_e0", "village_w0"], priority="true")
    net.crossing("VJ", ["side_in", "side_out"], priority="true")
    net.build()

    r = Routes(["car", "truck", "motorcycle", "bicycle", "ped"])
    through = [("rural_e0", "village_e1", 1.0), ("village_w1", "rural_w0", 1.0)]
    side = [("rural_e0", "side_out", 0.15), ("side_in", "rural_w0", 0.15),
            ("side_in", "village_e1", 0.05), ("village_w1", "side_out", 0.05)]
    mix = {"car": 300, "truck": 30, "motorcycle": 20}
    for fr, to, f in through + side:
        for vt, ph in mix.items():
            r.flow(f"{vt}_{fr}_{to}", vt, fr, to, ph * f)
    for fr, to in [("rural_e0", "village_e1"), ("village_w1", "rural_w0")]:
        r.flow(f"bicycle_{fr}_{to}", "bicycle", fr, to, 12)
    r.flow("bicycle_side_in_rural_w0", "bicycle", "side_in", "rural_w0", 6)
    # pedestrians in the village
    for fr, to, ph in [("village_e0", "village_w0", 40), ("village_w1", "village_e1", 30),
                       ("village_e0", "side_out", 30), ("side_in", "village_w0", 30),
                       ("village_w1", "side_out", 20)]:
        r.person_flow(f"ped_{fr}_{to}", fr, to, ph)
    write_scenario("rural", "rural", r)


# --------------------------------------------------------------------------- highway
def _bezier(p0, p1, p2, n=16):
    return [((1 - t) ** 2 * p0[0] + 2 * (1 - t) * t * p1[0] + t * t * p2[0],
             (1 - t) ** 2 * p0[1] + 2 * (1 - t) * t * p1[1] + t * t * p2[1])
            for t in (i / n for i in range(n + 1))]


def build_highway() -> None:
    net = Net("highway")
    net.node("H0", 0, 0)
    net.node("M", 800, 0)       # on-ramp merges: acceleration lane begins
    net.node("A", 1050, 0)      # acceleration lane ends
    net.node("D", 1600, 0)      # off-ramp diverges
    net.node("H3", 2000, 0)
    net.node("OX", 1900, -110)  # end of the off-ramp
    net.node("LW", 100, -150)
    net.node("LJ", 500, -150, "priority")
    net.node("LE", 900, -150)
    hw = dict(speed=33.33, width=3.75, priority=10, disallow="pedestrian bicycle")
    net.edge("hw_0", "H0", "M", numLanes=3, **hw)
    net.edge("hw_1", "M", "A", numLanes=4, **hw)
    net.edge("hw_2", "A", "D", numLanes=3, **hw)
    net.edge("hw_3", "D", "H3", numLanes=3, **hw)
    # ramps: quadratic Bezier curves; the on-ramp leaves the local road at about 65
    # degrees and meets the acceleration lane (centre y = -13.125) tangentially; the
    # off-ramp leaves lane 0 of hw_2 (centre y = -9.375) tangentially.
    ramp = dict(numLanes=1, speed=22.22, width=3.75, priority=5, disallow="pedestrian bicycle")
    net.edge("ramp_on", "LJ", "M", shape=_bezier((500, -150), (560, -13.125), (800, -13.125)), **ramp)
    net.edge("ramp_off", "D", "OX", shape=_bezier((1600, -9.375), (1750, -9.375), (1900, -110)), **ramp)
    loc = dict(numLanes=1, speed=13.89, width=3.25, sidewalkWidth=2.0, priority=3)
    net.two_way("loc_e0", "loc_w0", "LW", "LJ", **loc)
    net.two_way("loc_e1", "loc_w1", "LJ", "LE", **loc)
    # merge: the ramp feeds the acceleration lane (lane 0), which ends at A
    net.connection("ramp_on", "hw_1", 0, 0)
    for i in range(3):
        net.connection("hw_0", "hw_1", i, i + 1)
        net.connection("hw_1", "hw_2", i + 1, i)
        net.connection("hw_2", "hw_3", i, i)
    net.connection("hw_2", "ramp_off", 0, 0)
    # pedestrians: across the ramp mouth (north sidewalk) and across the local road
    net.crossing("LJ", ["ramp_on"], priority="true")
    net.crossing("LJ", ["loc_e0", "loc_w0"], priority="true")
    net.build()

    r = Routes(["car", "truck", "bus", "motorcycle", "bicycle", "ped"])
    for vt, ph in {"car": 1900, "truck": 300, "bus": 20, "motorcycle": 60}.items():
        r.flow(f"{vt}_hw_0_hw_3", vt, "hw_0", "hw_3", ph * 0.85)
        r.flow(f"{vt}_hw_0_ramp_off", vt, "hw_0", "ramp_off", ph * 0.15)
    for vt, ph in {"car": 300, "truck": 30, "motorcycle": 10}.items():
        r.flow(f"{vt}_loc_e0_hw_3", vt, "loc_e0", "hw_3", ph * 0.6)
        r.flow(f"{vt}_loc_w1_hw_3", vt, "loc_w1", "hw_3", ph * 0.4)
        r.flow(f"{vt}_loc_e0_loc_e1", vt, "loc_e0", "loc_e1", ph * 0.3)
        r.flow(f"{vt}_loc_w1_loc_w0", vt, "loc_w1", "loc_w0", ph * 0.3)
    r.flow("bicycle_loc_e0_loc_e1", "bicycle", "loc_e0", "loc_e1", 20)
    r.flow("bicycle_loc_w1_loc_w0", "bicycle", "loc_w1", "loc_w0", 20)
    for fr, to, ph in [("loc_w1", "loc_w0", 40), ("loc_w0", "loc_w1", 40),
                       ("loc_e0", "loc_w0", 20), ("loc_e0", "loc_w1", 20)]:
        r.person_flow(f"ped_{fr}_{to}", fr, to, ph)
    write_scenario("highway", "highway", r)


# --------------------------------------------------------------------------- testbed
def build_testbed() -> None:
    net = Net("testbed")
    net.node("W", 0, 0)
    net.node("C", 200, 0, "priority")
    net.node("E", 400, 0)
    main = dict(numLanes=2, speed=13.89, width=3.2, sidewalkWidth=2.0, priority=2)
    opp = dict(numLanes=1, speed=13.89, width=3.2, sidewalkWidth=2.0, priority=2)
    net.edge("main_0", "W", "C", **main)
    net.edge("main_1", "C", "E", **main)
    net.edge("opp_1", "E", "C", **opp)
    net.edge("opp_0", "C", "W", **opp)
    for i in (1, 2):
        net.connection("main_0", "main_1", i, i)
    net.crossing("C", ["main_0", "opp_0"], priority="true")
    net.build()

    r = Routes()
    r.route("r_main", ["main_0", "main_1"])
    r.route("r_opp", ["opp_1", "opp_0"])
    write_scenario("testbed", "testbed", r)
    readme = """# testbed network

Tiny network for automated tests, built by `python tools/build_networks.py testbed`
(coordinates as written, no offset).

* Nodes: `W` (0, 0), `C` (200, 0) priority junction with a zebra crossing, `E` (400, 0).
* Eastbound: `main_0` (W->C) and `main_1` (C->E), lanes 198.0 m each, two 3.2 m road
  lanes plus a 2.0 m sidewalk, 13.89 m/s. Route `r_main` = `main_0 main_1`.
* Westbound: `opp_1` (E->C) and `opp_0` (C->W), one 3.2 m road lane plus a 2.0 m
  sidewalk. Route `r_opp` = `opp_1 opp_0`.

Lane centre lines (y is constant along x):

| lane | what | y |
|---|---|---|
| `main_0_0`, `main_1_0` | south sidewalk | -7.4 |
| `main_0_1`, `main_1_1` | eastbound right lane | -4.8 |
| `main_0_2`, `main_1_2` | eastbound left lane | -1.6 |
| `opp_1_1`, `opp_0_1` | westbound lane | +1.6 |
| `opp_1_0`, `opp_0_0` | north sidewalk | +4.2 |

Sidewalks are lane index 0; road lanes start at index 1.

Crossing `:C_c0` (4 m wide, pedestrians have priority over vehicles): centre line
x = 200.0 from y = +3.2 (north) to y = -6.4 (south), covering 198 <= x <= 202 and all
three road lanes; it is reached from the walking areas `:C_w0` (north, next to
`opp_*_0`) and `:C_w1` (south, next to `main_*_0`). The road lanes of `main_0`/`opp_0`
end/start at x = 198 and those of `main_1`/`opp_1` at x = 202; the internal junction
lanes in between are `:C_1_0`, `:C_1_1` (eastbound, lanes 1 and 2) and `:C_0_0`
(westbound), 4 m each.

Scenario `scenarios/testbed/testbed.sumocfg`: vTypes `car` (passenger, 4.5 x 1.8 m),
`truck`, `bus`, `motorcycle`, `bicycle`, `ped`; routes `r_main`, `r_opp`; no demand
(tests add vehicles and persons through libsumo).
"""
    _write(NETWORKS / "testbed" / "README.md", readme)


# --------------------------------------------------------------------------- urban grid
GRID_SPACING = 500  # distance between the signalised junctions
GRID_ARM = 300  # length of the outer arms


def build_urban_grid() -> None:
    net = Net("urban_grid")
    s, a = GRID_SPACING, GRID_ARM
    J = {(i, j): f"J{i}{j}" for i in (0, 1) for j in (0, 1)}
    for (i, j), n in J.items():
        net.node(n, i * s, j * s, "traffic_light")
    # outer nodes: two per junction, named after the side of the grid
    outer = {}
    for (i, j), n in J.items():
        ox = -a if i == 0 else s + a
        oy = -a if j == 0 else s + a
        wx = "W" if i == 0 else "E"
        sy = "S" if j == 0 else "N"
        outer[f"{wx}{j}"] = (n, (ox, j * s))
        outer[f"{sy}{i}"] = (n, (i * s, oy))
    for o, (_, (x, y)) in sorted(outer.items()):
        net.node(o, x, y)
    road = dict(numLanes=2, speed=13.89, width=3.2, sidewalkWidth=2.0, priority=2)
    arms = {n: [] for n in J.values()}
    for o, (n, _) in sorted(outer.items()):
        net.edge(f"{o}_in", o, n, **road)
        net.edge(f"{o}_out", n, o, **road)
        arms[n].append((f"{o}_in", f"{o}_out"))
    for a_, b_ in [("J00", "J10"), ("J01", "J11"), ("J00", "J01"), ("J10", "J11")]:
        net.edge(f"{a_}_{b_}", a_, b_, **road)
        net.edge(f"{b_}_{a_}", b_, a_, **road)
        arms[a_].append((f"{b_}_{a_}", f"{a_}_{b_}"))
        arms[b_].append((f"{a_}_{b_}", f"{b_}_{a_}"))
    for n in sorted(arms):
        for e_in, e_out in arms[n]:
            net.crossing(n, [e_in, e_out])
    net.build()

    r = Routes()
    ids = sorted(outer)
    veh_per_hour = 4500  # all vehicle types together, spread over all OD pairs
    # OD pairs between different outer arms; pairs at the same junction are kept but
    # weighted less (short trips)
    pairs = [(o, d) for o in ids for d in ids if o != d]
    w = {p: (0.2 if outer[p[0]][0] == outer[p[1]][0] else 1.0) for p in pairs}
    tot = sum(w.values())
    for (o, d) in pairs:
        for vt, share in URBAN_MIX.items():
            r.flow(f"{vt}_{o}_{d}", vt, f"{o}_in", f"{d}_out", veh_per_hour * share * w[(o, d)] / tot)
    # pedestrians walk between two arms of the same junction (so walks take a few
    # minutes and the number walking levels off after warm-up)
    ped_per_hour = 600
    ppairs = [(n, a_, b_) for n in sorted(arms) for a_ in arms[n] for b_ in arms[n] if a_ != b_]
    for _n, (a_in, _), (_, b_out) in ppairs:
        r.person_flow(f"ped_{a_in}_{b_out}", a_in, b_out, ped_per_hour / len(ppairs))
    write_scenario("urban_grid", "urban_grid", r)


BUILDERS = {
    "urban": build_urban,
    "rural": build_rural,
    "highway": build_highway,
    "testbed": build_testbed,
    "urban_grid": build_urban_grid,
}


def main(argv: list[str] | None = None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", metavar="NETWORK", help=f"networks to build (default: all of {', '.join(BUILDERS)})")
    names = ap.parse_args(argv).names or list(BUILDERS)
    for name in names:
        if name not in BUILDERS:
            print(f"unknown network {name!r}; choose from {', '.join(BUILDERS)}", file=sys.stderr)
            return 2
        BUILDERS[name]()
        print(f"built {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
