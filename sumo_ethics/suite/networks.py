"""The suite's base networks, written as plain XML and built with netconvert.

Seven small networks, each reused by many scenarios (demand and hazards vary per scenario):

==============  ===========================================================================
junction_tls    signalised 4-way junction ``C`` at (0, 0), arms of 100 m, one 3.5 m lane per
                direction, 13.89 m/s, 2 m sidewalks, crosswalks on all arms
junction_prio   the same junction unsignalised: W-E is the priority road, zebra crossings
roundabout      4-arm single-lane roundabout (ring radius 22 m), arms of 100 m, crosswalks
rural           450 m two-lane rural road (3.5 m lanes, 22.22 m/s, one gentle bend)
multilane       3-lane carriageway (3.75 m, 27.78 m/s), 500 m, on-ramp with acceleration lane
narrow          180 m narrow street (3.0 m lanes, 8.33 m/s, 1.5 m sidewalks), parked cars
arterial        320 m straight urban arterial, two 3.25 m lanes per direction, 16.67 m/s,
                2 m sidewalks (the dilemma family)
==============  ===========================================================================

Built with :class:`sumo_ethics.sim.netbuild.PlainNet` (also the builder of the bundled networks).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from sumo_ethics.sim.netbuild import PlainNet


ARMS = {"W": (-1, 0), "E": (1, 0), "N": (0, 1), "S": (0, -1)}
ARM = 100.0


def _junction(name: str, signalised: bool) -> PlainNet:
    net = PlainNet(name)
    net.node("C", 0, 0, "traffic_light" if signalised else "priority")
    for a, (dx, dy) in ARMS.items():
        net.node(a, ARM * dx, ARM * dy)
    for a in ARMS:
        prio = 3 if signalised or a in "WE" else 1
        road: dict[str, Any] = dict(numLanes=1, speed=13.89, width=3.5, sidewalkWidth=2.0, priority=prio)
        net.edge(f"{a}_in", a, "C", **road)
        net.edge(f"{a}_out", "C", a, **road)
    for a in ARMS:
        net.crossing("C", [f"{a}_in", f"{a}_out"], priority=None if signalised else "true")
    return net


def _roundabout() -> PlainNet:
    net = PlainNet("roundabout")
    r = 22.0
    ring = {"E": 0.0, "N": 90.0, "W": 180.0, "S": 270.0}
    for a, deg in ring.items():
        net.node(f"R{a}", r * math.cos(math.radians(deg)), r * math.sin(math.radians(deg)), "priority")
        dx, dy = ARMS[a]
        net.node(a, (ARM + r) * dx, (ARM + r) * dy)
    order = ["E", "N", "W", "S"]  # counter-clockwise (right-hand traffic)
    for i, a in enumerate(order):
        b = order[(i + 1) % 4]
        d0, d1 = ring[a], ring[a] + 90.0
        arc = [(r * math.cos(math.radians(d0 + (d1 - d0) * k / 8)), r * math.sin(math.radians(d0 + (d1 - d0) * k / 8)))
               for k in range(9)]
        net.edge(f"ring_{a}{b}", f"R{a}", f"R{b}", shape=arc, numLanes=1, speed=8.33, width=4.0, priority=4,
                 disallow="pedestrian")
    for a in ARMS:
        road: dict[str, Any] = dict(numLanes=1, speed=13.89, width=3.5, sidewalkWidth=2.0, priority=2)
        net.edge(f"{a}_in", a, f"R{a}", **road)
        net.edge(f"{a}_out", f"R{a}", a, **road)
        net.crossing(f"R{a}", [f"{a}_in", f"{a}_out"], priority="true")
    return net


def _rural() -> PlainNet:
    net = PlainNet("rural")
    net.node("R0", 0, 0)
    net.node("R1", 225, 0, "priority")
    net.node("R2", 450, 0)
    bend = [(225 + 225 * k / 12, 18 * math.sin(math.pi * k / 12)) for k in range(13)]
    road: dict[str, Any] = dict(numLanes=1, speed=22.22, width=3.5, priority=3)  # no sidewalk: people walk on the road
    net.two_way("e0", "w0", "R0", "R1", **road)
    net.two_way("e1", "w1", "R1", "R2", shape=bend, **road)
    return net


def _multilane() -> PlainNet:
    net = PlainNet("multilane")
    net.node("H0", 0, 0)
    net.node("M", 180, 0)
    net.node("A", 300, 0)
    net.node("H3", 500, 0)
    net.node("RS", 0, -70)
    hw: dict[str, Any] = dict(speed=27.78, width=3.75, priority=10, disallow="pedestrian bicycle")
    net.edge("hw_0", "H0", "M", numLanes=3, **hw)
    net.edge("hw_1", "M", "A", numLanes=4, **hw)
    net.edge("hw_2", "A", "H3", numLanes=3, **hw)
    ramp = [(0, -70), (90, -60), (140, -20), (180, -13.125)]
    net.edge("ramp_on", "RS", "M", shape=ramp, numLanes=1, speed=22.22, width=3.75, priority=5,
             disallow="pedestrian bicycle")
    net.connection("ramp_on", "hw_1", 0, 0)
    for i in range(3):
        net.connection("hw_0", "hw_1", i, i + 1)
        net.connection("hw_1", "hw_2", i + 1, i)
    return net


def _narrow() -> PlainNet:
    net = PlainNet("narrow")
    net.node("N0", 0, 0)
    net.node("N1", 90, 0, "priority")
    net.node("N2", 180, 0)
    road: dict[str, Any] = dict(numLanes=1, speed=8.33, width=3.0, sidewalkWidth=1.5, priority=2)
    net.two_way("n_e0", "n_w0", "N0", "N1", **road)
    net.two_way("n_e1", "n_w1", "N1", "N2", **road)
    net.crossing("N1", ["n_e0", "n_w0"], priority="true")
    return net


def _arterial() -> PlainNet:
    """A straight urban arterial: two 3.25 m lanes per direction at 16.67 m/s with 2 m sidewalks."""
    net = PlainNet("arterial")
    net.node("A0", 0, 0)
    net.node("A1", 320, 0)
    road: dict[str, Any] = dict(numLanes=2, speed=16.67, width=3.25, sidewalkWidth=2.0, priority=3)
    net.two_way("a_e", "a_w", "A0", "A1", **road)
    return net


BUILDERS = {
    "junction_tls": lambda: _junction("junction_tls", True),
    "junction_prio": lambda: _junction("junction_prio", False),
    "roundabout": _roundabout,
    "rural": _rural,
    "multilane": _multilane,
    "narrow": _narrow,
    "arterial": _arterial,
}


def build_all(folder: Path, names: tuple[str, ...] | None = None) -> dict[str, Path]:
    """Build the base networks ``names`` (default: every one) into ``folder/<name>/<name>.net.xml``."""
    return {name: make().build(folder / name) for name, make in BUILDERS.items() if names is None or name in names}
