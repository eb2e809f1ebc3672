"""Every road user of the simulation at each step, for the conflicts among all of them
(``[conflicts] everyone``, :mod:`sumo_ethics.safety.pairs`).

One context subscription per domain (vehicles, persons) around one junction, with a radius that
covers the whole network (its boundary plus ``MARGIN``), returns every vehicle and person in one
call per step, like the ego's own subscriptions (``sim.world``); persons riding a vehicle are left
out (they travel inside it): one call per domain instead of per-id getters (their cost:
docs/conflicts.md, "Conflicts among everyone").
"""

from __future__ import annotations

from sumo_ethics.sim.backend import sumo, tc
import numpy as np

from sumo_ethics.sim.frames import front_to_centre
from sumo_ethics.sim.world import SumoWorld
from sumo_ethics.types import AgentStates

_VEH_VARS = (tc.VAR_POSITION3D, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_TYPE)
_PER_VARS = (tc.VAR_POSITION3D, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_TYPE, tc.VAR_VEHICLE)
#: m beyond the network's boundary still covered (a vehicle moved a little off the road)
MARGIN = 200.0


class Everyone:
    """Reads every vehicle and person after each step; :meth:`read` -> (states sorted by id, z)."""

    def __init__(self, types: SumoWorld) -> None:
        self.types = types  # its vType cache: class, size and mass as the egos' scenes have them
        (x0, y0), (x1, y1) = sumo.simulation.getNetBoundary()
        self.junction = min(sumo.junction.getIDList())
        jx, jy = sumo.junction.getPosition(self.junction)
        radius = max(np.hypot(x - jx, y - jy) for x in (x0, x1) for y in (y0, y1)) + MARGIN
        js = sumo.junction
        js.subscribeContext(self.junction, tc.CMD_GET_VEHICLE_VARIABLE, radius, _VEH_VARS)
        js.subscribeContext(self.junction, tc.CMD_GET_PERSON_VARIABLE, radius, _PER_VARS)

    def read(self) -> tuple[AgentStates, np.ndarray]:
        """Every road user now (riders left out), sorted by id, and their elevation z (N,) [m]."""
        res = sumo.junction.getContextSubscriptionResults(self.junction)
        ids = sorted(k for k, r in res.items() if not r.get(tc.VAR_VEHICLE))
        if not ids:
            return AgentStates.empty(), np.empty(0)
        rows = [res[k] for k in ids]
        person = [tc.VAR_VEHICLE in r for r in rows]  # only persons are subscribed with it
        info = [self.types.type_info(r[tc.VAR_TYPE], p) for r, p in zip(rows, person)]
        num = np.array([(*r[tc.VAR_POSITION3D], r[tc.VAR_ANGLE], r[tc.VAR_SPEED], t.length, t.width, t.mass)
                        for r, t in zip(rows, info)], dtype=float).T.copy()
        fx, fy, z, angle, speed, length, width, mass = num
        x, y, yaw = front_to_centre(fx, fy, angle, length)
        states = AgentStates.trusted(tuple(ids), x, y, yaw, speed, np.zeros(len(ids)), length, width, mass,
                                     np.array([t.cls for t in info], dtype=np.int8),
                                     tuple(r[tc.VAR_TYPE] for r in rows))
        return states, z
