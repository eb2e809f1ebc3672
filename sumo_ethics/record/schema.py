"""Column names and types of every output table, defined once."""

from __future__ import annotations

import pyarrow as pa

#: one row per collision event (party a is the ego whenever the ego is involved)
COLLISIONS = pa.schema([
    ("event", pa.int32()),          # running number in this run
    ("time", pa.float64()),         # s, simulation time of the first detection
    ("step", pa.int32()),           # ego step index of the first detection
    ("involves_ego", pa.bool_()),
    ("detector", pa.string()),      # geometry | sumo | both
    ("sumo_type", pa.string()),     # SUMO's collision type, empty when only the geometry found it
    ("id_a", pa.string()), ("id_b", pa.string()),
    ("class_a", pa.string()), ("class_b", pa.string()),  # RoadUserClass labels
    ("type_a", pa.string()), ("type_b", pa.string()),    # SUMO vType ids
    ("x_a", pa.float64()), ("y_a", pa.float64()), ("x_b", pa.float64()), ("y_b", pa.float64()),  # m, centres
    ("speed_a", pa.float64()), ("speed_b", pa.float64()),  # m/s, just before impact
    ("yaw_a", pa.float64()), ("yaw_b", pa.float64()),      # rad, CCW from +x
    ("mass_a", pa.float64()), ("mass_b", pa.float64()),    # kg
    ("delta_v", pa.float64()),                             # m/s, closing speed
    ("dv_a", pa.float64()), ("dv_b", pa.float64()),        # m/s, momentum split
    ("area_a", pa.string()), ("area_b", pa.string()),      # front | side | rear
    ("harm_a", pa.float64()), ("harm_b", pa.float64()),    # P(MAIS 3+)
    ("harm_ego", pa.float64()),          # harm booked to the ego (0 unless involves_ego)
    ("harm_third_party", pa.float64()),  # harm booked to the other party of an ego collision
    ("harm_vru", pa.float64()),          # the part of harm_third_party that hit a VRU
    ("fault", pa.string()),              # ego | other | shared | unknown (sumo_ethics.safety.fault)
    ("fault_reason", pa.string()),       # the rule that decided it
])

#: one row per conflict event between the ego (party a) and another road user (b)
#: (sumo_ethics.safety.conflicts); the state columns are those of the event's worst step
CONFLICTS = pa.schema([
    ("event", pa.int32()),          # running number in this run
    ("id_a", pa.string()), ("id_b", pa.string()),
    ("class_a", pa.string()), ("class_b", pa.string()),  # RoadUserClass labels
    ("type_b", pa.string()),        # SUMO vType id of b
    ("start", pa.float64()), ("end", pa.float64()),  # s, first and last step in conflict
    ("step_start", pa.int32()),     # ego step of the start
    ("n_steps", pa.int32()),        # steps in conflict
    ("min_ttc", pa.float64()),      # s, box TTC at constant velocity (NaN: never on a collision course)
    ("min_pet", pa.float64()),      # s, post-encroachment time where the paths cross (NaN: none)
    ("max_drac", pa.float64()),     # m/s^2, |v_rel| / (2 TTC) (0: no collision course; contact excluded)
    ("min_distance", pa.float64()), # m, box to box
    ("ttc_below", pa.bool_()), ("pet_below", pa.bool_()),  # which threshold the event fell below
    ("contact", pa.bool_()),        # the boxes overlapped at a step (a collision)
    ("speed_a", pa.float64()), ("speed_b", pa.float64()),  # m/s, at the worst step
    ("x_a", pa.float64()), ("y_a", pa.float64()), ("x_b", pa.float64()), ("y_b", pa.float64()),  # m, centres
    ("time_worst", pa.float64()),   # s, the worst step: min TTC, else min PET
])

#: one row per conflict event between two road users neither of which is an ego (``[conflicts]
#: everyone``, sumo_ethics.safety.pairs): the columns of CONFLICTS and the vType of a; party a is
#: the one whose class comes first (car ... pedestrian, other), then by id
CONFLICTS_OTHERS = CONFLICTS.insert(CONFLICTS.get_field_index("type_b"), pa.field("type_a", pa.string()))

#: one row per ego step, after the step
STEPS_BASE = pa.schema([
    ("step", pa.int32()),
    ("time", pa.float64()),        # s
    ("x", pa.float64()), ("y", pa.float64()),  # m, ego centre as SUMO placed it
    ("yaw", pa.float64()),         # rad
    ("speed", pa.float64()),       # m/s, the ego's speed the run uses: the commanded one (sim.world.SumoWorld.read)
    ("speed_cmd", pa.float64()),   # m/s, as commanded
    ("speed_sumo", pa.float64()),  # m/s, as SUMO reports it (0 at some junction entries of a moved ego)
    ("accel", pa.float64()),       # m/s^2, change of ``speed`` over the step
    ("s", pa.float64()),           # m, arc length along the route
    ("d", pa.float64()),           # m, lateral offset from the route's lane centre (left +)
    ("lane", pa.string()),         # SUMO lane id ("" when off the network)
    ("n_neighbours", pa.int32()),
    ("n_vru", pa.int32()),
    ("min_distance", pa.float64()),  # m, centre distance to the nearest neighbour (NaN if none)
    ("stop_s", pa.float64()),  # m, arc length of the red/yellow stop line the ego had ahead (NaN if none)
])

#: one row per ego step: wall-clock timings [ms] (apart from steps so those stay bit-identical)
TIMINGS_BASE = pa.schema([
    ("step", pa.int32()),
    ("read_ms", pa.float64()),
    ("controller_ms", pa.float64()),
    ("sumo_ms", pa.float64()),
    ("collision_ms", pa.float64()),
    ("record_ms", pa.float64()),  # the ego's Frenet position and this step's output rows (not the
                                  # chunk written every 2 simulated seconds, about 1 ms)
])
