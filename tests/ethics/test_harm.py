"""Harm model (METHOD.md section 1), checked against figures worked out by hand.

Logistic helper used in the comments: p = 1 / (1 + exp(z)) for the "exp(intercept - slope*dv)"
forms, and p = 1 / (1 + exp(-z)) for the protected area model.
"""

from __future__ import annotations

import numpy as np
import pytest

from sumo_ethics.ethics.harm import (
    CrashOutcome,
    HarmCoefficients,
    ImpactArea,
    MassModel,
    Party,
    crash_outcome,
    impact_area,
    leave_road_harm,
)
from sumo_ethics.types import RoadUserClass as C

PI = np.pi

# Car mass, 4.5 x 1.8 m:
#   footprint 4.5 * 1.8 = 8.1 m^2; ln 8.1 = 2.091864; * 0.8 = 1.673491; exp -> 5.330746
#   526.9 * 5.330746 = 2808.770; - 1333.5 = 1475.270 kg
CAR_MASS = 1475.270


def party(x=0.0, y=0.0, yaw=0.0, speed=0.0, mass=CAR_MASS, cls=C.CAR) -> Party:
    return Party(
        x=np.asarray(x, float), y=np.asarray(y, float), yaw=np.asarray(yaw, float),
        speed=np.asarray(speed, float), mass=np.asarray(mass, float), cls=np.asarray(int(cls)),
    )


# --------------------------------------------------------------------------- masses
def test_masses_of_each_class():
    mm = MassModel()
    cls = np.array([C.CAR, C.TRUCK, C.BUS, C.MOTORCYCLE, C.BICYCLE, C.PEDESTRIAN, C.OTHER, C.CAR])
    length = np.array([4.5, 12.0, 12.0, 2.2, 1.6, 0.215, 4.5, 2.5])
    width = np.array([1.8, 2.5, 2.5, 0.9, 0.65, 0.478, 1.8, 1.2])
    m = mm.mass(cls, length, width)
    # the last car is 2.5 x 1.2 = 3.0 m^2: 3^0.8 = 2.408; 526.9 * 2.408 - 1333.5 = -64.6 -> floor 500
    np.testing.assert_allclose(m, [CAR_MASS, 25000, 13000, 250, 90, 75, CAR_MASS, 500], atol=1e-3)
    # the ego model of METHOD.md (BMW 320i, 4.508 x 1.610 m, 1475 kg):
    # 4.508 * 1.610 = 7.25788 m^2; 7.25788^0.8 = exp(0.8 * 1.982088) = exp(1.585670) = 4.882563;
    # 526.9 * 4.882563 - 1333.5 = 2572.62 - 1333.5 = 1239.12 kg (the fit, not the real 1475 kg)
    np.testing.assert_allclose(mm.mass(C.CAR, 4.508, 1.610), 1239.12, atol=0.01)


def test_type_mass_preference():
    mm = MassModel()
    cls = np.array([C.CAR, C.CAR, C.CAR, C.CAR, C.TRUCK, C.BICYCLE, C.PEDESTRIAN, C.BUS])
    length = np.full(8, 4.5)
    width = np.full(8, 1.8)
    # type masses as given by the scenario (ethics.harm.vtype_mass: NaN where it gives none)
    tm = np.array([np.nan, 1500.0, 1300.0, 0.0, 18000.0, 10.0, 70.0, 12000.0])
    m = mm.mass(cls, length, width, tm)
    # NaN and 0 -> formula; given 1500 and 1300 used; truck/bus given masses used; vulnerable
    # classes keep their constants (SUMO excludes the rider)
    np.testing.assert_allclose(m, [CAR_MASS, 1500, 1300, CAR_MASS, 18000, 90, 75, 12000], atol=1e-3)
    assert MassModel(ignored_type_masses=(1500.0,)).mass(C.CAR, 4.5, 1.8, 1500.0) == pytest.approx(CAR_MASS)


# --------------------------------------------------------------------------- impact area
def test_impact_area_bins_and_wrap():
    a = np.array([0.0, 0.7, -0.7, PI / 4, 1.5, -1.5, 3 * PI / 4, 2.5, PI, -PI, 2 * PI - 0.1, -2 * PI + 0.2])
    exp = [0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 0, 0]
    np.testing.assert_array_equal(impact_area(a), exp)
    assert ImpactArea.FRONT == 0 and ImpactArea.SIDE == 1 and ImpactArea.REAR == 2


# --------------------------------------------------------------------------- crashes
def test_car_into_standing_pedestrian():
    # car yaw 0 at 10 m/s, pedestrian 2 m ahead, standing (speed 0, yaw pi/2)
    # delta_v = sqrt(10^2 + 0 + 0) = 10
    # dv_ped = 1475.270 / (1475.270 + 75) * 10 = 1475.270 / 1550.270 * 10 = 9.516213
    # dv_car = 75 / 1550.270 * 10 = 0.483787
    # ped (unprotected): 3.164 - 0.288 * 9.516213 = 3.164 - 2.740669 = 0.423331
    #   exp(0.423331) = 1.527039 -> 1 / 2.527039 = 0.3957
    # car (angle-free, hit a VRU): 4.591 - 0.185 * 0.483787 = 4.591 - 0.089501 = 4.501499
    #   exp(4.501499) = 90.1522 -> 1 / 91.1522 = 0.0110
    car = party(speed=10.0)
    ped = party(x=2.0, yaw=PI / 2, speed=0.0, mass=75.0, cls=C.PEDESTRIAN)
    o = crash_outcome(car, ped)
    np.testing.assert_allclose(o.delta_v, 10.0)
    np.testing.assert_allclose([o.dv_a, o.dv_b], [0.483787, 9.516213], atol=1e-6)
    np.testing.assert_allclose(o.harm_b, 0.3957, atol=5e-5)
    np.testing.assert_allclose(o.harm_a, 0.0110, atol=5e-5)
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.010971, 0.395720], atol=1e-6)
    # swapping the parties swaps the outcome
    s = crash_outcome(ped, car)
    np.testing.assert_allclose([s.harm_a, s.harm_b], [o.harm_b, o.harm_a])


def test_rear_end_equal_mass():
    # a: 20 m/s yaw 0 at x = 0; b: 10 m/s yaw 0 at x = 4.5 (ahead); equal masses
    # pdof = wrap(0 - 0 + pi) = pi; delta_v = sqrt(400 + 100 + 2*20*10*cos(pi)) = sqrt(100) = 10
    # dv_a = dv_b = 10 / 2 = 5
    # a is hit at the front (b at bearing 0), b at the rear (a at bearing pi)
    # a: z = -4.457 + 0.177*5 + 0 = -3.572; exp(3.572) = 35.588 -> 1 / 36.588 = 0.0273
    # b: z = -4.457 + 0.885 - 0.431 = -4.003; exp(4.003) = 54.762 -> 1 / 55.762 = 0.0179
    o = crash_outcome(party(speed=20.0), party(x=4.5, speed=10.0))
    np.testing.assert_allclose(o.pdof, PI)
    np.testing.assert_allclose(o.delta_v, 10.0)
    np.testing.assert_allclose([o.dv_a, o.dv_b], [5.0, 5.0])
    assert o.area_a == ImpactArea.FRONT and o.area_b == ImpactArea.REAR
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.0273, 0.0179], atol=5e-5)
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.027332, 0.017933], atol=1e-6)
    # the brief's sanity check: 30 m/s into 10 m/s from behind closes at 20
    np.testing.assert_allclose(crash_outcome(party(speed=30.0), party(x=4.5, speed=10.0)).delta_v, 20.0)


def test_head_on():
    # yaw 0 and pi, both 10 m/s: pdof = wrap(pi + pi) = 0; delta_v = sqrt(100 + 100 + 200) = 20
    # dv = 10 each, both front: z = -4.457 + 1.77 = -2.687; exp(2.687) = 14.6875 -> 1/15.6875 = 0.0637
    o = crash_outcome(party(speed=10.0), party(x=4.5, yaw=PI, speed=10.0))
    np.testing.assert_allclose(o.pdof, 0.0, atol=1e-12)
    np.testing.assert_allclose(o.delta_v, 20.0)
    np.testing.assert_allclose([o.dv_a, o.dv_b], [10.0, 10.0])
    assert o.area_a == ImpactArea.FRONT and o.area_b == ImpactArea.FRONT
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.063745, 0.063745], atol=1e-6)


def test_t_bone_side_vs_front():
    # a: yaw 0, 10 m/s at (0, 0); b: yaw pi/2 (crossing northwards), 10 m/s at (3, 0); equal mass
    # pdof = wrap(pi/2 + pi) = -pi/2; cos = 0 -> delta_v = sqrt(200) = 14.1421; dv = 7.0711 each
    # a sees b at bearing 0 -> front; b sees a at atan2(0, -3) - pi/2 = pi/2 -> side
    # a: z = -4.457 + 0.177*7.0711 = -4.457 + 1.251579 = -3.205421; exp(3.205421) = 24.6659 -> 0.0390
    # b: z = -3.205421 + 0.244 = -2.961421; exp(2.961421) = 19.3254 -> 1/20.3254 = 0.0492
    o = crash_outcome(party(speed=10.0), party(x=3.0, yaw=PI / 2, speed=10.0))
    np.testing.assert_allclose(o.pdof, -PI / 2)
    np.testing.assert_allclose(o.delta_v, np.sqrt(200.0))
    assert o.area_a == ImpactArea.FRONT and o.area_b == ImpactArea.SIDE
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.038962, 0.049199], atol=1e-6)


@pytest.mark.parametrize("yaw_b", [-PI + 0.1, PI + 0.1])
def test_wrap_around_not_misfiled_as_rear(yaw_b):
    # nearly head-on: b 5 m ahead with yaw pi + 0.1 (== -pi + 0.1). b's bearing of a is
    # atan2(0, -5) - yaw_b = pi - (-pi + 0.1) = 2pi - 0.1 = 6.183 rad: unwrapped that is
    # > 3pi/4 and Origin files it as REAR; wrapped it is -0.1 -> FRONT.
    # pdof = wrap(yaw_b + pi) = 0.1; delta_v = sqrt(100 + 100 + 200 cos 0.1) = sqrt(399.0008) = 19.9750
    # dv = 9.98750 each; front: z = -4.457 + 0.177*9.98750 = -2.689212; exp(2.689212) = 14.72007 -> 1/15.72007 = 0.063613
    # (misfiled as rear it would be 1/(1 + exp(3.120212)) = 1/23.65118 = 0.042281)
    o = crash_outcome(party(speed=10.0), party(x=5.0, yaw=yaw_b, speed=10.0))
    np.testing.assert_allclose(o.pdof, 0.1, atol=1e-12)
    np.testing.assert_allclose(o.delta_v, 19.975005, atol=1e-6)
    assert o.area_a == ImpactArea.FRONT and o.area_b == ImpactArea.FRONT
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.063613, 0.063613], atol=1e-6)


def test_vulnerable_pairs_and_car_vs_motorcycle():
    # bicycle (90 kg, 5 m/s) into standing pedestrian (75 kg): both unprotected
    # delta_v = 5; dv_bike = 75/165 * 5 = 2.272727; dv_ped = 90/165 * 5 = 2.727273
    # bike: 3.164 - 0.288*2.272727 = 2.509455; exp = 12.29822 -> 1/13.29822 = 0.075198
    # ped:  3.164 - 0.288*2.727273 = 2.378545; exp = 10.78920 -> 1/11.78920 = 0.084823
    o = crash_outcome(party(speed=5.0, mass=90.0, cls=C.BICYCLE), party(x=1.0, mass=75.0, cls=C.PEDESTRIAN))
    np.testing.assert_allclose([o.harm_a, o.harm_b], [0.075198, 0.084823], atol=1e-6)
    # a truck hit by a motorcycle uses the angle-free model whatever the impact area
    coeffs = HarmCoefficients()
    truck = party(yaw=0.0, speed=0.0, mass=25000.0, cls=C.TRUCK)
    moto_rear = party(x=-5.0, speed=10.0, mass=250.0, cls=C.MOTORCYCLE)  # hits the truck's rear
    moto_side = party(y=-5.0, yaw=PI / 2, speed=10.0, mass=250.0, cls=C.MOTORCYCLE)
    r, s = crash_outcome(truck, moto_rear, coeffs), crash_outcome(truck, moto_side, coeffs)
    assert r.area_a == ImpactArea.REAR and s.area_a == ImpactArea.SIDE
    np.testing.assert_allclose(r.harm_a, s.harm_a)  # same dv (250/25250 * 10), no area term


def test_broadcasting_knt():
    K, N, T = 4, 3, 5
    rng = np.random.default_rng(0)
    ego = Party(
        x=rng.uniform(-5, 5, (K, 1, T)), y=rng.uniform(-5, 5, (K, 1, T)), yaw=rng.uniform(-PI, PI, (K, 1, T)),
        speed=rng.uniform(0, 20, (K, 1, T)), mass=np.asarray(CAR_MASS), cls=np.asarray(int(C.CAR)),
    )
    cls = np.array([C.CAR, C.PEDESTRIAN, C.TRUCK])[:, None]  # (N, 1)
    other = Party(
        x=rng.uniform(-5, 5, (N, T)), y=rng.uniform(-5, 5, (N, T)), yaw=rng.uniform(-PI, PI, (N, T)),
        speed=rng.uniform(0, 20, (N, T)), mass=MassModel().mass(cls, np.array([[4.5], [0.2], [12.0]]), 2.0), cls=cls,
    )
    o = crash_outcome(ego, other)
    assert isinstance(o, CrashOutcome)
    for v in (o.pdof, o.delta_v, o.dv_a, o.dv_b, o.area_a, o.area_b, o.harm_a, o.harm_b):
        assert v.shape == (K, N, T)
    assert np.all((o.harm_a >= 0) & (o.harm_a <= 1) & (o.harm_b >= 0) & (o.harm_b <= 1))
    assert np.all((o.pdof > -PI) & (o.pdof <= PI))
    # element-wise agreement with scalar calls
    for k, n, t in [(0, 0, 0), (3, 1, 4), (2, 2, 2)]:
        e1 = Party(ego.x[k, 0, t], ego.y[k, 0, t], ego.yaw[k, 0, t], ego.speed[k, 0, t], ego.mass, ego.cls)
        o1 = Party(other.x[n, t], other.y[n, t], other.yaw[n, t], other.speed[n, t], other.mass[n, 0], other.cls[n, 0])
        s = crash_outcome(e1, o1)
        for f in ("delta_v", "dv_a", "dv_b", "area_a", "area_b", "harm_a", "harm_b"):
            np.testing.assert_allclose(getattr(s, f), getattr(o, f)[k, n, t])


def test_leave_road_harm():
    # v = 0:  1 / (1 + exp(4.591)) = 1 / (1 + 98.5930) = 0.010041
    # v = 20: 4.591 - 0.185*20 = 0.891; exp(0.891) = 2.437566 -> 1 / 3.437566 = 0.290904
    np.testing.assert_allclose(leave_road_harm(np.array([0.0, 20.0])), [0.010041, 0.290904], atol=1e-6)
    assert leave_road_harm(np.zeros((2, 3))).shape == (2, 3)
