"""Who caused an ego collision, from what the simulation knows: :func:`fault`.

The rules, first match wins (``fault`` in ego | other | shared | unknown, ``fault_reason`` the
rule's sentence):

1. the ego was standing (speed below ``STANDING`` just before impact): ``other``, "ego standing,
   struck" (a pedestrian or cyclist: "<class> entered the standing ego's box");
2. the other road user was breaking a traffic rule (red light, wrong way, outside its lane:
   :mod:`sumo_ethics.sim.rules`, known only where the controller runs the rule monitor, i.e.
   the planner): ``other`` (``shared`` if the ego also entered at red, rule 3);
3. the ego entered a junction at red within ``RED_MEMORY`` seconds: ``ego``;
4. the ego was struck at its rear: braking no harder than its limit (or not braking) ``other``,
   "struck from behind while braking within the limit"; braking harder ``shared``;
5. the ego moved into a standing road user: ``ego``;
6. the ego's chosen candidate entered a road user's predicted envelope (the planner's
   ``cost_envelope`` > 0 at the last decision): ``ego``;
7. the ego's front struck the other's rear: ``ego``;
8. otherwise ``unknown`` ("both moving, no rule decides").

Collisions between other road users get ``unknown`` ("the ego was not involved").
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sumo_ethics.types import RoadUserClass

#: m/s, below this a road user counts as standing
STANDING = 0.1
#: s, an ego that entered a junction at red is held responsible for this long
RED_MEMORY = 5.0
#: m/s^2, braking up to this much beyond the limit still counts as within it (one step's rounding)
DECEL_TOLERANCE = 0.05

FAULTS = ("ego", "other", "shared", "unknown")


@dataclass(frozen=True)
class FaultContext:
    """What the run knows beyond the two parties' states at the step of an ego collision.

    ego_accel: the ego's speed change over the step into the impact [m/s^2];
    decel_limit: the ego's braking limit [m/s^2, positive]; rule_breakers: ids of road users
    breaking a traffic rule this step; ego_ran_red: the ego entered a junction at red within
    RED_MEMORY s; ego_in_envelope: the ego's chosen candidate entered a road user's predicted
    envelope (None: the controller does not say).
    """

    ego_accel: float = 0.0
    decel_limit: float = 8.0
    rule_breakers: frozenset[str] = field(default_factory=frozenset)
    ego_ran_red: bool = False
    ego_in_envelope: bool | None = None

    @classmethod
    def of_step(cls, info: dict[str, float], speed_before: float, speed_after: float, dt: float,
                decel_limit: float, rule_breakers: frozenset[str], time: float, ran_red_at: float) -> "FaultContext":
        """The context of the ego step into ``time`` [s]: its speeds before and after [m/s] over dt [s],
        the decision's ``info`` (``cost_envelope`` > 0: its candidate entered an envelope) and when the
        ego last entered a junction at red (``ran_red_at``, -inf never)."""
        envelope = info.get("cost_envelope")
        return cls(ego_accel=(speed_after - speed_before) / dt, decel_limit=decel_limit, rule_breakers=rule_breakers,
                   ego_ran_red=time - ran_red_at <= RED_MEMORY,
                   ego_in_envelope=None if envelope is None else bool(envelope > 0))


def fault(ego_speed: float, area_ego: str, other_id: str, other_cls: int, other_speed: float, area_other: str,
          ctx: FaultContext | None = None) -> tuple[str, str]:
    """(fault, reason) of an ego collision (the rules in the module docstring).

    ego_speed, other_speed: just before impact [m/s]; area_ego, area_other: where each was hit
    ("front", "side", "rear", :class:`sumo_ethics.ethics.harm.ImpactArea` names); other_cls: a
    RoadUserClass value.
    """
    ctx = ctx or FaultContext()
    cls = RoadUserClass(int(other_cls))
    if ego_speed < STANDING:
        if cls in (RoadUserClass.PEDESTRIAN, RoadUserClass.BICYCLE):
            return "other", f"{cls.label} entered the standing ego's box"
        return "other", "ego standing, struck"
    if other_id in ctx.rule_breakers and ctx.ego_ran_red:
        return "shared", "both broke a traffic rule"
    if other_id in ctx.rule_breakers:
        return "other", "other broke a traffic rule (red light, wrong way or outside its lane)"
    if ctx.ego_ran_red:
        return "ego", "ego entered the junction at red"
    if area_ego == "rear":
        if ctx.ego_accel >= -ctx.decel_limit - DECEL_TOLERANCE:
            return "other", "struck from behind while braking within the limit"
        return "shared", "struck from behind after braking harder than the limit"
    if other_speed < STANDING:
        return "ego", f"ego moved into a standing {cls.label}"
    if ctx.ego_in_envelope:
        return "ego", "the ego's chosen candidate entered a predicted envelope"
    if area_ego == "front" and area_other == "rear":
        return "ego", f"ego struck the {cls.label} from behind"
    return "unknown", "both moving, no rule decides"
