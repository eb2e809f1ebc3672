"""Masses in the harm model (issue 37): METHOD.md's class masses (truck 25,000 kg, bus 13,000,
motorcycle 250, bicycle 90, pedestrian 75, a car from its size) unless the scenario gives a vType
its own mass; a mass equal to SUMO's default for the vType's class counts as not given."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from sumo_ethics.config import RunConfig
from sumo_ethics.ethics.harm import SUMO_CLASS_MASS, SUMO_DEFAULT_MASS, MassModel, vtype_mass
from sumo_ethics.runner import run
from sumo_ethics.types import RoadUserClass as C

from conftest import TESTBED_NET, Scripted, write_scenario

# -1333.5 + 526.9 (4.5 x 1.8)^0.8 = 1475.27 kg (the tests' 4.5 x 1.8 m "car" vType)
CAR_MASS = 1475.27


@pytest.mark.parametrize("vclass, sumo_mass, param, want", [
    ("truck", 4500.0, "", math.nan),        # SUMO's truck default: not given
    ("truck", 18000.0, "", 18000.0),        # an explicit mass
    ("truck", 1500.0, "", 1500.0),          # explicit too: it differs from the truck default
    ("truck", 4500.0, "4500", 4500.0),      # the param states a mass equal to the default
    ("truck", 4500.0, "heavy", math.nan),   # a param that is no number is ignored
    ("passenger", 1500.0, "", math.nan),
    ("bus", 12000.0, "", math.nan),
    ("tram", 37900.0, "", 37900.0),         # no class mass of ours: SUMO's tram figure is kept
    ("aircraft", 1500.0, "", math.nan),     # ... but not SUMO's generic 1500 kg
])
def test_vtype_mass_rule(vclass, sumo_mass, param, want):
    got = vtype_mass(vclass, sumo_mass, param)
    assert (math.isnan(got) and math.isnan(want)) or got == want


def test_class_masses_where_the_type_gives_none():
    mm = MassModel()
    cls = np.array([C.TRUCK, C.TRUCK, C.BUS, C.CAR, C.BICYCLE, C.PEDESTRIAN, C.MOTORCYCLE])
    given = np.array([vtype_mass("truck", 4500.0), vtype_mass("trailer", 13000.0), vtype_mass("coach", 25000.0),
                      vtype_mass("passenger", 1500.0), vtype_mass("bicycle", 10.0), vtype_mass("pedestrian", 70.0),
                      vtype_mass("motorcycle", 200.0)])
    m = mm.mass(cls, np.array([7.1, 16.5, 14.0, 4.5, 1.6, 0.2, 2.2]), np.array([2.4, 2.55, 2.55, 1.8, 0.65, 0.5, 0.9]),
                given)
    np.testing.assert_allclose(m, [25000.0, 25000.0, 13000.0, CAR_MASS, 90.0, 75.0, 250.0], atol=0.01)


# ------------------------------------------------------------------ real SUMO
VTYPES = ("<vType id='lorry' vClass='truck'/><vType id='heavy' vClass='truck' mass='18000'/>"
          "<vType id='stated' vClass='truck' mass='4500'><param key='mass' value='4500'/></vType>"
          "<vType id='coach' vClass='coach'/><vType id='plain' length='4.5' width='1.8'/>"
          "<vType id='tram' vClass='tram'/>"
          + "".join(f"<vType id='probe_{c}' vClass='{c}'/>" for c in SUMO_CLASS_MASS)
          + "<vType id='probe_taxi' vClass='taxi'/><vType id='probe_custom1' vClass='custom1'/>")


@pytest.fixture
def sumo_types(tmp_path):
    import libsumo

    (tmp_path / "t.rou.xml").write_text(f"<routes>{VTYPES}</routes>\n")
    libsumo.start(["sumo", "-n", str(TESTBED_NET), "-r", str(tmp_path / "t.rou.xml"), "--no-step-log", "--no-warnings"])
    try:
        yield libsumo
    finally:
        libsumo.close()


@pytest.mark.sumo
def test_sumo_class_defaults_are_the_table(sumo_types):
    """The table of SUMO's class defaults holds for the SUMO in use (else 'not given' misreads)."""
    vt = sumo_types.vehicletype
    for c, m in SUMO_CLASS_MASS.items():
        assert vt.getMass(f"probe_{c}") == m, c
    assert vt.getMass("probe_taxi") == vt.getMass("probe_custom1") == SUMO_DEFAULT_MASS


@pytest.mark.sumo
def test_world_gives_default_types_the_class_mass_and_keeps_explicit_ones(sumo_types):
    from sumo_ethics.sim.world import SumoWorld

    w = SumoWorld("nobody", 80.0)
    assert w.type_info("lorry").mass == 25000.0      # SUMO gives it 4500 kg, its truck default
    assert w.type_info("heavy").mass == 18000.0      # mass="18000" in the vType
    assert w.type_info("stated").mass == 4500.0      # the param states the default on purpose
    assert w.type_info("coach").mass == 13000.0      # a coach is a bus: 13,000, not SUMO's 25,000
    assert w.type_info("tram").mass == 37900.0       # no class mass of ours: SUMO's
    assert w.type_info("plain").mass == pytest.approx(CAR_MASS, abs=0.01)  # no vClass: a car by its size
    assert w.type_info("probe_bicycle").mass == 90.0 and w.type_info("probe_pedestrian").mass == 75.0
    assert w.type_info("probe_motorcycle").mass == 250.0


@pytest.mark.sumo
def test_masses_used_are_in_the_collision_row(tmp_path):
    cfg = write_scenario(tmp_path / "s", """
      <vType id="lorry" vClass="truck" length="7.1" width="2.4"/>
      <vehicle id="parked" type="lorry" route="r_main" depart="0" departLane="2" departPos="124" departSpeed="0">
        <stop lane="main_0_2" endPos="124.5" duration="1000"/></vehicle>
      <vehicle id="ego" type="car" route="r_main" depart="0" departLane="2" departPos="20" departSpeed="10"/>""")
    out = tmp_path / "run"
    run(RunConfig(cfg, out, ego_id="ego", end=20, progress=False), controller=Scripted(10.0))
    coll = pd.read_parquet(out / "collisions.parquet")
    r = coll[coll.involves_ego].iloc[0]
    assert (r.id_b, r.class_b) == ("parked", "truck")
    assert r.mass_a == pytest.approx(CAR_MASS, abs=0.01) and r.mass_b == 25000.0
    # momentum split of a 10 m/s closing speed: the car takes 25000 / 26475.27 of it = 9.4428 m/s,
    # the truck 0.5572 m/s; front impact: 1 / (1 + exp(4.457 - 0.177 x 9.4428)) = 0.05811
    assert r.dv_a == pytest.approx(9.4428, abs=1e-3) and r.dv_b == pytest.approx(0.5572, abs=1e-3)
    assert r.harm_a == pytest.approx(0.05811, abs=1e-4)
