"""Harm: probability of a serious (MAIS 3+) injury to each party of a collision.

METHOD.md section 1; docs/method.md, "Harm". Crash geometry from the two parties' states just
before impact, closing speed split by momentum, then one of three logistic injury models per party:

- protected party hit by a protected party: ``1 / (1 + exp(-(b0 + b1 dv + c_area)))``
  with the party's own impact area (front / side / rear);
- protected party hit by a vulnerable road user: angle-free ``1 / (1 + exp(a0 - a1 dv))``;
- vulnerable party (pedestrian, bicycle, motorcycle: ``types.VULNERABLE``): ``1 / (1 + exp(u0 - u1 dv))``.

Leaving the road (:func:`leave_road_harm`) uses the angle-free model on the ego's speed.

The crash geometry and injury models (:func:`crash_outcome`, :func:`impact_area`,
:func:`leave_road_harm`, :meth:`MassModel.mass`) broadcast over arbitrary shapes, e.g. (K, N) or
(K, N, T), with no loops over their elements; :func:`vtype_mass` reads one vType's figures.
Units: metres, seconds, radians (yaw CCW from +x), kilograms.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from sumo_ethics.geometry import wrap_angle
from sumo_ethics.types import VULNERABLE, RoadUserClass

__all__ = [
    "HarmCoefficients",
    "MassModel",
    "SUMO_CLASS_MASS",
    "vtype_mass",
    "ImpactArea",
    "Party",
    "CrashOutcome",
    "impact_area",
    "crash_outcome",
    "leave_road_harm",
]


@dataclass(frozen=True)
class HarmCoefficients:
    """Logistic injury-model coefficients (Geisslinger et al. 2023, METHOD.md section 1).

    Protected, with impact area: ``p = 1 / (1 + exp(-(protected_intercept + protected_dv * dv + c)))``
    with c one of protected_front / protected_side / protected_rear.
    Angle-free protected: ``p = 1 / (1 + exp(angle_free_intercept - angle_free_dv * dv))``.
    Unprotected (VRU): ``p = 1 / (1 + exp(unprotected_intercept - unprotected_dv * dv))``.
    """

    protected_intercept: float = -4.457  # [-] log-odds at dv = 0, front impact
    protected_dv: float = 0.177  # [1/(m/s)] log-odds per m/s of the party's own delta-v
    protected_front: float = 0.0  # [-] log-odds offset, front impact
    protected_side: float = 0.244  # [-] log-odds offset, side impact
    protected_rear: float = -0.431  # [-] log-odds offset, rear impact
    angle_free_intercept: float = 4.591  # [-] p = 1/(1+exp(intercept - slope*dv))
    angle_free_dv: float = 0.185  # [1/(m/s)]
    unprotected_intercept: float = 3.164  # [-] p = 1/(1+exp(intercept - slope*dv))
    unprotected_dv: float = 0.288  # [1/(m/s)]

    def as_array(self) -> np.ndarray:
        """(9,) protected intercept, dv, front, side, rear; angle-free intercept, dv; unprotected
        intercept, dv (the order :func:`sumo_ethics.ethics.search.pair_harm` reads)."""
        return np.array([self.protected_intercept, self.protected_dv, self.protected_front, self.protected_side,
                         self.protected_rear, self.angle_free_intercept, self.angle_free_dv,
                         self.unprotected_intercept, self.unprotected_dv])

    def area_offset(self, area: np.ndarray) -> np.ndarray:
        """Log-odds offset [-] for an array of :class:`ImpactArea` ints."""
        table = np.array([self.protected_front, self.protected_side, self.protected_rear])
        return table[np.asarray(area, dtype=np.intp)]


@dataclass(frozen=True)
class MassModel:
    """Mass [kg] of a road user from its class and true size.

    CAR and OTHER: ``car_offset + car_factor * (length * width) ** car_exponent`` with
    length, width in m, floored at ``car_min`` (the fit goes negative below ~3.2 m^2 of
    footprint, e.g. -65 kg for a 2.5 x 1.2 m microcar, and falls under 500 kg below
    ~4.75 m^2; the floor keeps tiny vTypes physical). TRUCK, BUS, MOTORCYCLE, BICYCLE, PEDESTRIAN: the constants below, which
    include the rider for two-wheelers.

    A vType's own mass (``type_mass``, from :func:`vtype_mass`: NaN where the scenario gives
    none) is preferred for protected classes (CAR, TRUCK, BUS, OTHER) where finite, > 0 and not in
    ``ignored_type_masses`` (none by default: :func:`vtype_mass` has already told a given mass
    from SUMO's class default). Vulnerable classes always use the constants: SUMO's masses exclude
    the rider (bicycle 10 kg, moped 80 kg, motorcycle 200 kg) and pedestrians are 70 kg vs our 75.
    """

    car_offset: float = -1333.5  # [kg]
    car_factor: float = 526.9  # [kg / (m^2)^car_exponent]
    car_exponent: float = 0.8  # [-] applied to the footprint length * width [m^2]
    car_min: float = 500.0  # [kg] floor on the formula
    truck: float = 25000.0  # [kg]
    bus: float = 13000.0  # [kg]
    motorcycle: float = 250.0  # [kg] incl. rider
    bicycle: float = 90.0  # [kg] incl. rider
    pedestrian: float = 75.0  # [kg]
    ignored_type_masses: tuple[float, ...] = ()  # [kg] type masses treated as "not given"

    def mass(
        self,
        cls: np.ndarray,
        length: np.ndarray,
        width: np.ndarray,
        type_mass: np.ndarray | None = None,
    ) -> np.ndarray:
        """Mass [kg] of the broadcast shape.

        cls: RoadUserClass ints; length, width: true (not margin-inflated) size [m];
        type_mass: SUMO vType mass [kg] where known, NaN where not (None: all unknown).
        """
        cls = np.asarray(cls, dtype=np.intp)
        length = np.asarray(length, dtype=float)
        width = np.asarray(width, dtype=float)
        footprint = np.maximum(length * width, 0.0)
        car = np.maximum(self.car_offset + self.car_factor * footprint**self.car_exponent, self.car_min)
        per_class = np.array(
            [np.nan, self.truck, self.bus, self.motorcycle, self.bicycle, self.pedestrian, np.nan]
        )  # indexed by RoadUserClass; NaN = size formula
        assert len(per_class) == len(RoadUserClass)
        const = per_class[cls]
        m = np.where(np.isnan(const), car, const)
        if type_mass is not None:
            tm = np.asarray(type_mass, dtype=float)
            usable = np.isfinite(tm) & (tm > 0.0) & ~VULNERABLE[cls]
            for ignored in self.ignored_type_masses:  # a handful of constants, not agents
                usable &= tm != ignored
            m = np.where(usable, tm, m)
        return m


#: SUMO 1.28's default ``mass`` [kg] per vClass, measured with libsumo on vTypes that set only
#: ``vClass`` (tests/ethics/test_masses.py checks it against the running SUMO). A vClass not listed
#: (and a vType without a vClass) gets SUMO's passenger default, 1500 kg.
SUMO_CLASS_MASS: dict[str, float] = {
    "delivery": 5000.0, "emergency": 5000.0, "truck": 4500.0, "trailer": 13000.0, "bus": 12000.0,
    "coach": 25000.0, "tram": 37900.0, "rail_urban": 59000.0, "subway": 59000.0, "rail": 79500.0,
    "rail_electric": 83000.0, "rail_fast": 409000.0, "motorcycle": 200.0, "moped": 80.0, "bicycle": 10.0,
    "scooter": 10.0, "pedestrian": 70.0, "wheelchair": 90.0, "ship": 100000.0,
}
#: SUMO's mass for every vClass not in SUMO_CLASS_MASS [kg]
SUMO_DEFAULT_MASS = 1500.0


def vtype_mass(vclass: str, sumo_mass: float, param: str = "") -> float:
    """The mass [kg] a scenario gives a SUMO vType itself, NaN where it gives none.

    SUMO reports a mass for every vType and cannot say whether the scenario set it, so:

    1. a ``<param key="mass" value="..."/>`` of the vType (``param``, a positive number) is given;
    2. else a ``mass`` that differs from SUMO's default for the vType's vClass
       (:data:`SUMO_CLASS_MASS`) is given;
    3. else, for a vClass this project has no class mass for (RoadUserClass OTHER: rail, tram,
       ship, ...), SUMO's class default is used where it is not the generic 1500 kg: a tram's
       37,900 kg beats a car's size formula;
    4. else NaN: METHOD.md's class mass applies (:class:`MassModel`: truck 25,000 kg, bus 13,000 kg,
       a car and any other class from its footprint).

    So a mass attribute equal to SUMO's default for the class counts as not given; to state
    exactly that mass, use the param (rule 1).
    """
    try:
        explicit = float(param) if param else float("nan")
    except ValueError:
        explicit = float("nan")
    if np.isfinite(explicit) and explicit > 0.0:
        return explicit
    default = SUMO_CLASS_MASS.get(vclass, SUMO_DEFAULT_MASS)
    if sumo_mass != default:
        return float(sumo_mass)
    if RoadUserClass.from_vclass(vclass) is RoadUserClass.OTHER and default != SUMO_DEFAULT_MASS:
        return float(default)
    return float("nan")


class ImpactArea(enum.IntEnum):
    """Where a party is hit, relative to its own heading."""

    FRONT = 0
    SIDE = 1
    REAR = 2


@dataclass(frozen=True)
class Party:
    """One side of a collision; all fields broadcast against each other and the other party.

    x, y: centre [m]; yaw [rad]; speed [m/s] (>= 0); mass [kg]; cls: RoadUserClass ints.
    """

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    speed: np.ndarray
    mass: np.ndarray
    cls: np.ndarray


@dataclass(frozen=True)
class CrashOutcome:
    """Result of :func:`crash_outcome`; all arrays of the broadcast shape."""

    pdof: np.ndarray  # principal direction of force [rad], wrapped to (-pi, pi]
    delta_v: np.ndarray  # closing speed [m/s]
    dv_a: np.ndarray  # delta-v of party a [m/s], momentum split
    dv_b: np.ndarray  # delta-v of party b [m/s]
    area_a: np.ndarray  # ImpactArea ints of party a
    area_b: np.ndarray  # ImpactArea ints of party b
    harm_a: np.ndarray  # P(MAIS3+) of party a in [0, 1]
    harm_b: np.ndarray  # P(MAIS3+) of party b in [0, 1]


def impact_area(rel_angle: np.ndarray) -> np.ndarray:
    """ImpactArea ints from the other party's bearing relative to one's heading [rad].

    The angle is wrapped first; |a| < pi/4 front, pi/4 <= |a| <= 3pi/4 side, else rear.
    """
    a = np.abs(wrap_angle(rel_angle))
    return np.where(
        a < np.pi / 4, ImpactArea.FRONT, np.where(a <= 3 * np.pi / 4, ImpactArea.SIDE, ImpactArea.REAR)
    ).astype(np.int8)


def _logistic(z: np.ndarray) -> np.ndarray:
    """1 / (1 + exp(-z)), overflow-safe."""
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def crash_outcome(a: Party, b: Party, coeffs: HarmCoefficients = HarmCoefficients()) -> CrashOutcome:
    """Crash geometry and harm to both parties of a collision between a and b.

    pdof = wrap(yaw_b - yaw_a + pi). Closing speed is the norm of the relative velocity,
    |v_a - v_b|^2 = v_a^2 + v_b^2 - 2 v_a v_b cos(yaw_b - yaw_a)
                  = v_a^2 + v_b^2 + 2 v_a v_b cos(pdof)   (the + sign because pdof carries +pi):
    head-on at 10 + 10 m/s gives 20, 30 m/s into 10 m/s from behind gives 20.
    dv_a = m_b / (m_a + m_b) * delta_v and dv_b = m_a / (m_a + m_b) * delta_v.
    Impact area of a from wrap(atan2(y_b - y_a, x_b - x_a) - yaw_a), symmetric for b
    (coincident centres give bearing 0, i.e. front).
    Harm model per party: vulnerable party -> unprotected model; protected party against a
    vulnerable one -> angle-free model; protected against protected -> area model.
    """
    ya, yb = np.asarray(a.yaw, dtype=float), np.asarray(b.yaw, dtype=float)
    va, vb = np.asarray(a.speed, dtype=float), np.asarray(b.speed, dtype=float)
    ma, mb = np.asarray(a.mass, dtype=float), np.asarray(b.mass, dtype=float)
    pdof = wrap_angle(yb - ya + np.pi)
    delta_v = np.sqrt(np.maximum(0.0, va**2 + vb**2 + 2.0 * va * vb * np.cos(pdof)))
    dv_a = mb / (ma + mb) * delta_v
    dv_b = ma / (ma + mb) * delta_v

    dx = np.asarray(b.x, dtype=float) - np.asarray(a.x, dtype=float)
    dy = np.asarray(b.y, dtype=float) - np.asarray(a.y, dtype=float)
    area_a = impact_area(np.arctan2(dy, dx) - ya)
    area_b = impact_area(np.arctan2(-dy, -dx) - yb)

    vul_a = VULNERABLE[np.asarray(a.cls, dtype=np.intp)]
    vul_b = VULNERABLE[np.asarray(b.cls, dtype=np.intp)]

    def harm(dv: np.ndarray, area: np.ndarray, vul_self: np.ndarray, vul_other: np.ndarray) -> np.ndarray:
        unprotected = _logistic(coeffs.unprotected_dv * dv - coeffs.unprotected_intercept)
        angle_free = _logistic(coeffs.angle_free_dv * dv - coeffs.angle_free_intercept)
        with_area = _logistic(coeffs.protected_intercept + coeffs.protected_dv * dv + coeffs.area_offset(area))
        return np.where(vul_self, unprotected, np.where(vul_other, angle_free, with_area))

    shape = np.broadcast_shapes(pdof.shape, dx.shape, vul_a.shape, vul_b.shape, dv_a.shape)
    out = (
        pdof,
        delta_v,
        dv_a,
        dv_b,
        area_a,
        area_b,
        harm(dv_a, area_a, vul_a, vul_b),
        harm(dv_b, area_b, vul_b, vul_a),
    )
    return CrashOutcome(*(np.broadcast_to(v, shape) for v in out))


def leave_road_harm(speed: np.ndarray, coeffs: HarmCoefficients = HarmCoefficients()) -> np.ndarray:
    """Harm to the ego [P(MAIS3+)] of leaving the road at speed [m/s]: the angle-free model."""
    v = np.asarray(speed, dtype=float)
    return _logistic(coeffs.angle_free_dv * v - coeffs.angle_free_intercept)
