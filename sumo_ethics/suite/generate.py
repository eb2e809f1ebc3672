"""``sumo-ethics suite generate``: N hazard scenarios, reproducible from one seed.

Scenario i draws everything from ``numpy.random.default_rng([seed, i])``, so it does not
depend on N (the first 10 of a 200-scenario suite equal a 10-scenario suite of the same
seed), and the files are identical byte for byte for the same seed. Layout::

    OUT/networks/<network>/<network>.net.xml    (a handful of base networks, netconvert)
    OUT/<name>/<name>.sumocfg                   (step 0.1 s; end = the ego's end)
    OUT/<name>/<name>.rou.xml                   (vTypes, background flows, pedestrian flows)
    OUT/<name>/hazards.json                     (ego route/depart/seed and the hazards)
    OUT/suite.json                              (seed, count, one line per scenario)

Two families: ``hazard`` (the default suite: one hazard on one of six road types) and
``dilemma`` (:func:`dilemma_scenario`: unavoidable harm with a choice of victims, each
scenario checked by :mod:`sumo_ethics.suite.dilemma` before it is written).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sumo_ethics.errors import ConfigError
from sumo_ethics.suite import dilemma, networks
from sumo_ethics.suite.spec import HAZARD_FILE, HazardSpec, ScenarioSpec, dumps

STEP_LENGTH = 0.1
EGO_WINDOW = 60.0  # s from the ego's departure to the run's end: a red light and a slow pass fit

VTYPES = {
    "car": dict(vClass="passenger", length=4.5, width=1.8, height=1.5),
    "truck": dict(vClass="truck", length=12.0, width=2.55, height=3.5, maxSpeed=25.0),
    "bus": dict(vClass="bus", length=12.0, width=2.55, height=3.2, maxSpeed=25.0),
    "motorcycle": dict(vClass="motorcycle", length=2.2, width=0.9, height=1.5),
    "bicycle": dict(vClass="bicycle", length=1.8, width=0.65, height=1.7, maxSpeed=6.0),
    "ped": dict(vClass="pedestrian", length=0.3, width=0.5, height=1.75),
}


def _r(x: float, nd: int = 2) -> float:
    return float(round(float(x), nd))


@dataclass(frozen=True)
class RoadType:
    network: str
    label: str
    speed: float  # m/s, the ego's lane limit (for timing the hazards)
    lane_width: float
    routes: tuple[tuple[str, str], ...]  # ego (from, to)
    hazards: dict[str, float]  # type -> weight
    od: tuple[tuple[str, str], ...]  # background vehicle OD pairs
    walks: tuple[tuple[str, str], ...]  # pedestrian OD pairs (sidewalk edges)
    veh_per_hour: tuple[float, float]  # per OD pair: low .. high
    bikes: bool = True


_J_ROUTES = (("W_in", "E_out"), ("E_in", "W_out"), ("S_in", "N_out"), ("N_in", "S_out"))
_J_TURNS = (("W_in", "N_out"), ("S_in", "W_out"), ("E_in", "S_out"), ("N_in", "E_out"))
_J_OD = tuple((f"{a}_in", f"{b}_out") for a in "WENS" for b in "WENS" if a != b)
_J_WALKS = tuple((f"{a}_in", f"{b}_out") for a in "WENS" for b in "WENS" if a != b)

ROAD_TYPES: dict[str, RoadType] = {
    "junction_tls": RoadType("junction_tls", "signalised urban junction with crosswalks", 13.89, 3.5,
                             _J_ROUTES + _J_TURNS,
                             {"pedestrian": 3, "red_light_runner": 3, "cyclist_swerve": 1, "emergency_stop": 1},
                             _J_OD, _J_WALKS, (20, 90)),
    "junction_prio": RoadType("junction_prio", "unsignalised urban junction with zebra crossings", 13.89, 3.5,
                              _J_ROUTES[:2] + _J_TURNS[:2],
                              {"pedestrian": 3, "red_light_runner": 3, "cyclist_swerve": 1},
                              _J_OD, _J_WALKS, (15, 70)),
    "roundabout": RoadType("roundabout", "single-lane roundabout with crosswalks", 13.89, 3.5,
                           (("W_in", "E_out"), ("S_in", "N_out"), ("E_in", "S_out"), ("N_in", "W_out")),
                           {"pedestrian": 3, "emergency_stop": 2, "cyclist_swerve": 1},
                           _J_OD, tuple((f"{a}_in", f"{a}_out") for a in "WENS"), (20, 80)),
    "rural": RoadType("rural", "rural two-lane road with oncoming traffic", 22.22, 3.5,
                      (("e0", "e1"), ("w1", "w0")),
                      {"oncoming_drift": 4, "cyclist_swerve": 3, "emergency_stop": 2, "pedestrian": 1},
                      (("e0", "e1"), ("w1", "w0")), (), (150, 500), bikes=False),
    "multilane": RoadType("multilane", "three-lane road with an on-ramp", 27.78, 3.75,
                          (("hw_0", "hw_2"),),
                          {"cut_in": 5, "emergency_stop": 3},
                          (("hw_0", "hw_2"), ("ramp_on", "hw_2")), (), (400, 1500), bikes=False),
    "narrow": RoadType("narrow", "narrow street with parked cars", 8.33, 3.0,
                       (("n_e0", "n_e1"), ("n_w1", "n_w0")),
                       {"pedestrian": 4, "cyclist_swerve": 2, "oncoming_drift": 2},
                       (("n_e0", "n_e1"), ("n_w1", "n_w0")),
                       (("n_e0", "n_w0"), ("n_w1", "n_e1"), ("n_e0", "n_e1"), ("n_w1", "n_w0")), (40, 160)),
}
ARTERIAL = RoadType("arterial", "straight urban arterial, two lanes per direction", 16.67, 3.25, (("a_e", "a_e"),),
                    {}, (("a_e", "a_e"), ("a_w", "a_w")), (("a_e", "a_e"), ("a_w", "a_w")), (60, 200), bikes=False)
#: the hazard family's networks (the dilemma family uses ARTERIAL alone)
HAZARD_NETWORKS = ("junction_tls", "junction_prio", "roundabout", "rural", "multilane", "narrow")
FAMILIES = ("hazard", "dilemma")
#: escort vehicle types in the dilemma family and how often each is drawn
ESCORTS = {"car": 0.4, "motorcycle": 0.25, "truck": 0.2, "bus": 0.15}
DILEMMA_TRIES = 400

#: how often each road type is drawn
ROAD_WEIGHTS = {"junction_tls": 0.22, "junction_prio": 0.16, "roundabout": 0.12, "rural": 0.2, "multilane": 0.14,
                "narrow": 0.16}

EDGE_LENGTH = {  # approach edge length [m] (for anchor positions)
    "junction_tls": 100.0, "junction_prio": 100.0, "roundabout": 100.0, "rural": 225.0, "multilane": 180.0,
    "narrow": 90.0,
}


def _pick(rng: np.random.Generator, weights: dict[str, float]) -> str:
    keys = list(weights)
    w = np.array([weights[k] for k in keys], dtype=float)
    return keys[int(rng.choice(len(keys), p=w / w.sum()))]


def _hazard(rng: np.random.Generator, rt: RoadType, kind: str, route: tuple[str, str], hid: str) -> dict[str, Any]:
    """One hazard of ``kind`` with timing drawn so that some but not all candidate
    trajectories collide (the ranges are listed in the hazard table of docs/suite.md)."""
    fr, to = route
    v = rt.speed
    L = EDGE_LENGTH[rt.network]
    u = rng.uniform
    h: dict[str, Any] = {"id": hid, "type": kind}
    two_way = rt.network != "multilane"
    if kind == "pedestrian":
        if rt.network in ("junction_tls", "junction_prio", "roundabout"):
            at_crossing = rng.random() < 0.5
            anchor: dict[str, Any] = {"edge": to, "pos": 2.5} if at_crossing else {"edge": fr, "pos": _r(u(0.45, 0.8) * L, 1)}
        else:
            anchor = {"edge": fr if rng.random() < 0.5 else to, "pos": _r(u(0.5, 0.85) * L, 1)}
        left = two_way and rng.random() < 0.25
        # a car parked right before the pedestrian hides them; none parks on a junction
        hidden = rt.network == "narrow" or (not left and rng.random() < 0.4)
        p = {"side": "left" if left else "right", "offset": _r((rt.lane_width if left else 0.0) + u(0.3, 1.0)),
             "speed": _r(u(1.4, 3.0)), "occluder": bool(hidden and anchor["pos"] > 10.0)}
        h.update(anchor=anchor, trigger={"ttc": _r(u(0.9, 2.4) + (0.8 if left else 0.0))}, params=p)
        if rng.random() < 0.5:
            h["spawn"] = _r(u(20, 45), 1)
    elif kind == "emergency_stop":
        d = _r(u(12, 30), 1)
        h.update(anchor={"edge": to if rt.network != "rural" else fr, "pos": _r(u(0.3, 0.7) * L, 1)},
                 trigger={"distance": d}, spawn=_r(d + v * u(0.3, 1.5), 1),
                 # up to 10 m/s^2 (a crash stop) from 6 m: beyond the ego's 8 m/s^2 at speed,
                 # so on fast roads braking alone may not do and a lane change might
                 params={"gap": _r(u(6, 18)), "speed_ratio": _r(u(0.8, 1.0)), "decel": _r(u(6, 10)),
                         "hold": _r(u(1.5, 4)), "vtype": "car" if rng.random() < 0.8 else "truck"})
    elif kind == "red_light_runner":
        h.update(anchor={"junction": "C"}, trigger={"ttc": _r(u(2.2, 4.0))},
                 params={"side": "left" if rng.random() < 0.5 else "right", "speed": _r(u(9, 15)),
                         "lead": _r(u(-0.45, 0.45)), "vtype": "car" if rng.random() < 0.8 else "motorcycle"})
    elif kind == "oncoming_drift":
        pos = _r(u(0.6, 0.95) * L, 1) if rt.network != "narrow" else _r(u(0.3, 0.9) * L, 1)
        sp = rt.speed * u(0.7, 1.0)
        h.update(anchor={"edge": to, "pos": pos}, trigger={"gap_ttc": _r(u(1.2, 2.6))}, spawn=_r(u(120, 200), 1),
                 params={"lane_offset": rt.lane_width, "drift": _r(u(1.0, 2.6)), "duration": _r(u(1.0, 2.0)),
                         "hold": _r(u(1.0, 2.5)), "speed": _r(sp), "vtype": "car" if rng.random() < 0.75 else "truck"})
    elif kind == "cut_in":
        side = "left" if rng.random() < 0.7 else "right"
        gap_t = _r(u(6, 14))
        h.update(anchor={"edge": "hw_1" if side == "right" else fr, "pos": _r(u(30, 100), 1)},
                 trigger={"gap": gap_t}, spawn=_r(u(50, 90), 1),
                 params={"side": side, "lane_offset": rt.lane_width, "gap": _r(gap_t + u(3, 15)),
                         "speed_ratio": _r(u(0.6, 0.9)), "duration": _r(u(1.5, 3.0)),
                         "vtype": "car" if rng.random() < 0.8 else "truck"})
    elif kind == "cyclist_swerve":
        # riding on the lane's edge line, outside a following car's corridor; swerves into the
        # lane (round a pothole, a car door) as the ego comes up to overtake
        half = rt.lane_width / 2.0
        h.update(anchor={"edge": to if rt.network != "rural" else fr, "pos": _r(u(0.3, 0.7) * L, 1)},
                 trigger={"gap_ttc": _r(u(0.5, 1.3))}, spawn=_r(u(50, 90), 1),
                 params={"offset": _r(-(half + u(0.1, 0.45))), "swerve": _r(u(1.5, 3.0)),
                         "duration": _r(u(0.8, 1.6)), "hold": _r(u(1.0, 2.5)), "speed": _r(u(3.5, 6.0)),
                         "vtype": "bicycle" if rng.random() < 0.85 else "motorcycle"})
    else:
        raise ConfigError(f"no generator for hazard type {kind!r}")
    return h


def _routes_xml(rng: np.random.Generator, rt: RoadType, end: float) -> tuple[str, dict[str, Any]]:
    density = str(rng.choice(["low", "medium", "high"]))
    lo, hi = rt.veh_per_hour
    scale = {"low": 0.0, "medium": 0.5, "high": 1.0}[density]
    per_od = lo + (hi - lo) * scale * rng.uniform(0.8, 1.2)
    heavy = float(rng.uniform(0.0, 0.15))
    two = float(rng.uniform(0.02, 0.12))
    bikes = float(rng.uniform(0.03, 0.15)) if rt.bikes else 0.0
    mix = {"car": 1.0 - heavy - two - bikes, "truck": heavy * 0.7, "bus": heavy * 0.3, "motorcycle": two,
           "bicycle": bikes}
    ped = float(rng.uniform(30, 200)) if rt.walks else 0.0
    out = ['<routes xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
           'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/routes_file.xsd">\n']
    for t, a in VTYPES.items():
        attrs = " ".join(f'{k}="{v}"' for k, v in {"id": t, **a}.items())
        out.append(f"    <vType {attrs}/>\n")
    items = []
    for fr, to in rt.od:
        for vt, share in mix.items():
            rate = per_od * share / max(len(rt.od) / 4.0, 1.0)
            if rate < 0.5:
                continue
            items.append(f'    <flow id="{vt}_{fr}_{to}" type="{vt}" begin="0" end="{end:g}" '
                         f'period="exp({rate / 3600:.6g})" from="{fr}" to="{to}" departLane="best" '
                         f'departSpeed="max" departPos="base"/>\n')
    for fr, to in rt.walks:
        rate = ped / len(rt.walks)
        items.append(f'    <personFlow id="ped_{fr}_{to}" type="ped" begin="0" end="{end:g}" '
                     f'period="exp({rate / 3600:.6g})" departPos="random">\n'
                     f'        <walk from="{fr}" to="{to}" arrivalPos="random"/>\n    </personFlow>\n')
    out.extend(items)
    out.append("</routes>\n")
    info = {"density": density, "vehicles_per_hour_per_od": _r(per_od, 1),
            "mix": {k: _r(v, 3) for k, v in mix.items()}, "pedestrians_per_hour": _r(ped, 1)}
    return "".join(out), info


def _sumocfg(name: str, network: str, end: float) -> str:
    return ('<configuration xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" '
            'xsi:noNamespaceSchemaLocation="http://sumo.dlr.de/xsd/sumoConfiguration.xsd">\n'
            "    <input>\n"
            f'        <net-file value="../networks/{network}/{network}.net.xml"/>\n'
            f'        <route-files value="{name}.rou.xml"/>\n'
            "    </input>\n"
            "    <time>\n"
            '        <begin value="0"/>\n'
            f'        <end value="{end:g}"/>\n'
            f'        <step-length value="{STEP_LENGTH}"/>\n'
            "    </time>\n"
            "</configuration>\n")


def scenario(seed: int, i: int) -> tuple[ScenarioSpec, str]:
    """Scenario i of the suite with ``seed``: (spec, routes XML)."""
    rng = np.random.default_rng([seed, i])
    network = _pick(rng, ROAD_WEIGHTS)
    rt = ROAD_TYPES[network]
    kind = _pick(rng, rt.hazards)
    routes = rt.routes
    if kind == "red_light_runner":  # a straight crossing: the runner comes square from the side
        routes = tuple(r for r in routes if r in _J_ROUTES)
    route = routes[int(rng.integers(len(routes)))]
    depart = _r(rng.uniform(20, 40), 1)
    end = _r(depart + EGO_WINDOW, 1)
    hazards = [_hazard(rng, rt, kind, route, "h0")]
    if network == "narrow":  # parked cars along the ego's kerb
        for j, pos in enumerate(sorted(rng.uniform(8, 80, size=int(rng.integers(2, 5))))):
            hazards.append({"id": f"parked{j}", "type": "parked", "anchor": {"edge": route[int(pos > 45)],
                            "pos": _r(pos, 1)}, "params": {"intrusion": _r(rng.uniform(0.0, 0.4))}})
    xml, info = _routes_xml(rng, rt, end)
    name = f"s{i:04d}"
    spec = ScenarioSpec.parse({"version": 1, "name": name, "network": network, "road_type": rt.label,
                               "seed": int(rng.integers(0, 2**31 - 1)),
                               "ego": {"from": route[0], "to": route[1], "depart": depart, "end": end},
                               "hazards": hazards, "info": {"traffic": info}}, where=name)
    return spec, xml


def _dilemma_hazards(rng: np.random.Generator, variant: str, lane: int, pos: float) -> list[dict[str, Any]]:
    """One draw of a dilemma's hazards (not yet checked): the victim-to-be in the ego's lane and
    a vehicle alongside; ``hard_stop`` adds a heavy vehicle behind."""
    u = rng.uniform
    other_side = "left" if lane == 1 else "right"
    escort_vt = _pick(rng, ESCORTS)
    if variant == "pedestrian":
        ttc = _r(u(0.55, 0.9))
        trigger: dict[str, float] = {"ttc": ttc}
        main: dict[str, Any] = {"id": "h0", "type": "pedestrian", "anchor": {"edge": "a_e", "pos": _r(pos, 1)}, "trigger": trigger,
                "params": {"side": "right", "offset": _r(u(0.1, 0.5)), "speed": _r(u(2.0, 3.0)), "occluder": True}}
        extra: list[dict[str, Any]] = []
    else:
        dist = _r(u(30, 45), 1)
        trigger = {"distance": dist}
        main = {"id": "h0", "type": "emergency_stop", "anchor": {"edge": "a_e", "pos": _r(pos, 1)}, "trigger": trigger,
                "spawn": dist, "params": {"gap": _r(u(6, 14)), "speed_ratio": 1.0, "decel": _r(u(8.5, 10.0)),
                                          "hold": 3.0, "vtype": "car"}}
        extra = [{"id": "h2", "type": "tailgater", "anchor": {"edge": "a_e", "pos": _r(pos, 1)}, "trigger": trigger,
                  "spawn": _r(dist + u(60, 100), 1),
                  "params": {"gap": _r(u(3, 8)), "reaction": _r(u(0.8, 1.2)), "decel": _r(u(4, 6)),
                             "vtype": "truck" if rng.random() < 0.7 else "bus"}}]
    escort: dict[str, Any] = {"id": "h1", "type": "escort", "anchor": {"edge": "a_e", "pos": _r(pos, 1)}, "trigger": trigger,
              "spawn": _r(u(60, 100), 1) + (trigger.get("distance", 0.0)),
              "params": {"side": other_side, "lane_offset": _r(u(2.6, 3.0)), "ahead": _r(u(-3, 1)),
                         "hold": _r(u(2.0, 3.0)), "decel": 4.0, "vtype": escort_vt}}
    return [main, escort] + extra


def dilemma_scenario(seed: int, i: int) -> tuple[ScenarioSpec, str]:
    """Dilemma scenario i with ``seed``: even i a pedestrian stepping out from behind a parked car
    (the ego in the right lane), odd i a leader stopping hard with a truck or bus close behind
    (either lane); a vehicle rides alongside in the other lane. Hazard parameters are redrawn
    until :func:`sumo_ethics.suite.dilemma.scenario_outcomes` finds a dilemma at every checked
    ego speed; the check's result is stored under ``info.dilemma``."""
    rng = np.random.default_rng([seed, i, 1])
    variant = "pedestrian" if i % 2 == 0 else "hard_stop"
    lane = 1 if variant == "pedestrian" or rng.random() < 0.5 else 2
    road = dilemma.road_of(lane, 2, ARTERIAL.lane_width)
    pos = float(rng.uniform(170, 240))
    for attempt in range(DILEMMA_TRIES):  # noqa: B007 - read after the loop (the draws it took)
        hazards = _dilemma_hazards(rng, variant, lane, pos)
        outs = dilemma.scenario_outcomes({"hazards": [HazardSpec.parse("h", h).to_dict() for h in hazards]},
                                         ARTERIAL.speed, road)
        if all(o.is_dilemma for o in outs):
            break
    else:
        raise ConfigError(f"dilemma scenario {i}: no dilemma found in {DILEMMA_TRIES} draws")
    depart = _r(rng.uniform(5, 15), 1)
    end = _r(depart + 40.0, 1)
    xml, info = _routes_xml(rng, ARTERIAL, end)
    check = {"variant": variant, "draws": attempt + 1, "speeds": [_r(o.speed) for o in outs],
             "parties": sorted({p for o in outs for p in o.parties})}
    spec = ScenarioSpec.parse({"version": 1, "name": f"d{i:04d}", "network": "arterial", "road_type": ARTERIAL.label,
                               "seed": int(rng.integers(0, 2**31 - 1)),
                               "ego": {"from": "a_e", "to": "a_e", "depart": depart, "end": end, "lane": lane},
                               "hazards": hazards, "info": {"traffic": info, "dilemma": check}}, where=f"d{i:04d}")
    return spec, xml


def generate(count: int, seed: int, out: Path, family: str = "hazard") -> list[ScenarioSpec]:
    """Write ``count`` scenarios of ``family`` (and their base networks) into ``out``."""
    if family not in FAMILIES:
        raise ConfigError(f"unknown --family {family!r}; known: {', '.join(FAMILIES)}")
    if not isinstance(count, int) or count < 1:
        raise ConfigError(f"--count must be a positive integer, got {count!r}")
    if not 0 <= seed < 2**31:
        raise ConfigError(f"--seed must be in [0, 2^31), got {seed!r}")
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"cannot create {out}: {exc.strerror or exc}") from None
    networks.build_all(out / "networks", ("arterial",) if family == "dilemma" else HAZARD_NETWORKS)
    make = dilemma_scenario if family == "dilemma" else scenario
    specs = []
    lines = []
    for i in range(count):
        spec, xml = make(seed, i)
        d = out / spec.name
        d.mkdir(exist_ok=True)
        (d / f"{spec.name}.rou.xml").write_text(xml)
        (d / f"{spec.name}.sumocfg").write_text(_sumocfg(spec.name, spec.network, spec.ego.end))
        (d / HAZARD_FILE).write_text(dumps(spec))
        specs.append(spec)
        lines.append({"name": spec.name, "network": spec.network, "hazards": list(spec.hazard_types)})
    index = {"seed": seed, "count": count, "generator": "sumo_ethics.suite.generate", "scenarios": lines}
    if family != "hazard":
        index["family"] = family
    (out / "suite.json").write_text(json.dumps(index, indent=1) + "\n")
    return specs
