"""A person riding a vehicle (a ``<ride>`` stage: bus or taxi passengers, as in eclipse-sumo's
DRT and rail configs or OSM scenarios with public transport) travels inside that vehicle. SUMO
still lists it among the persons, at its vehicle's position; it must not become a pedestrian in
the ego's scene (the planner's risk and the collision check) or in a prediction dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
NET = ROOT / "networks" / "urban" / "urban.net.xml"

# the ego 30 m into W_in; v0 waits at the start of W_in for its rider; a walker on the same road
ROUTES = ('<routes><vType id="car" vClass="passenger"/><vType id="walker" vClass="pedestrian"/>'
          '<trip id="ego" type="car" depart="0" departPos="30" from="W_in" to="E_out"/>'
          '<trip id="v0" type="car" depart="triggered" from="W_in" to="E_out"/>'
          '<person id="rider" depart="0"><ride from="W_in" to="E_out" lines="v0"/></person>'
          '<person id="walker" type="walker" depart="0"><walk from="W_in" to="E_out"/></person></routes>')

pytestmark = [pytest.mark.sumo, pytest.mark.skipif(not NET.exists(), reason="bundled urban network missing")]


def _config(tmp_path: Path) -> Path:
    (tmp_path / "ride.rou.xml").write_text(ROUTES)
    cfg = tmp_path / "ride.sumocfg"
    cfg.write_text(f'<configuration><input><net-file value="{NET}"/><route-files value="ride.rou.xml"/></input>'
                   '<time><begin value="0"/><end value="60"/><step-length value="0.1"/></time></configuration>')
    return cfg


def test_the_ego_scene_has_the_vehicle_but_not_its_rider(tmp_path):
    import libsumo

    from sumo_ethics.sim.world import SumoWorld
    from sumo_ethics.types import RoadUserClass

    libsumo.start(["sumo", "-c", str(_config(tmp_path)), "--no-step-log", "--no-warnings"])
    try:
        libsumo.simulationStep()
        world = SumoWorld("ego", radius=100.0)
        world.takeover()
        for _ in range(20):
            world.step()
        raw = libsumo.vehicle.getContextSubscriptionResults("ego")  # what SUMO hands over
        snap = world.read()
        riding = libsumo.person.getVehicle("rider")
    finally:
        libsumo.close()
    assert riding == "v0" and "rider" in raw  # SUMO lists the rider among the persons in range
    ids = set(snap.others.ids)
    assert {"v0", "walker"} <= ids and "rider" not in ids
    assert snap.others.cls[list(snap.others.ids).index("walker")] == RoadUserClass.PEDESTRIAN


def test_a_dataset_records_no_rider_while_it_rides(tmp_path):
    from sumo_ethics.recording.build import RunSpec, _simulate

    rows, _ = _simulate(RunSpec(0, _config(tmp_path), seed=1, scale=1.0, sim_seconds=30.0))
    assert "rider" not in set(rows["agent_id"])
    walker = rows[rows["agent_id"] == "walker"]
    v0 = rows[rows["agent_id"] == "v0"]
    assert len(walker) > 100 and len(v0) > 100  # 0.1 s steps: both recorded nearly the whole run
    assert np.all(walker["speed"] < 3.0)  # a walk, not a ride
