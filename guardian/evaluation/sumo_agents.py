"""The drivers a guarded SUMO vehicle may have: each proposes ``[acceleration, steering]`` every step from its own body
and the others' bodies (``guardian.model.sensing.Sensed``, the road model's frame).

* ``random``: a random acceleration and a small steering, each held for 5-20 steps;
* ``reckless``: full throttle, weaving;
* ``seek``: full throttle, steering at the nearest body ahead;
* ``sumo``: SUMO's own driver with its checks off (``sumo_driver``).
"""
from __future__ import annotations

import math

import numpy as np

from guardian.errors import ConfigError
from guardian.model.roads import RoadMap

AGENTS = ("random", "reckless", "seek", "sumo")
DRIVER_TYPE = "sumo_driver"   # the vehicle type of a guarded vehicle SUMO's driver drives (the traffic's models)
LCA_LEFT, LCA_RIGHT = 2, 4                 # SUMO's lane-change state: the direction it wants
LCA_WISHES = 8 | 16 | 32 | 64              # why: strategic, cooperative, speed gain, keep right
LEADER_RANGE = 200.0                       # [m] how far ahead SUMO's driver looks for its leader
STEER_LIMIT = 0.1                          # [rad] the lane keeper's largest steering


def agent_of(name: str, setting, rng: np.random.Generator, traci=None, vehicle: str | None = None, frame=None):
    """A driver proposing ``[acceleration, steering]``; ``setting`` (a ``SumoSetting``) gives its bounds. ``sumo``
    needs the connection, the guarded vehicle's id and the road's ``Frame`` (``traci``, ``vehicle``, ``frame``)."""
    if name not in AGENTS:
        raise ConfigError(f"agent must be one of {', '.join(AGENTS)}, got {name!r}")
    if name == "sumo":
        return sumo_driver(traci, vehicle, setting, frame, rng)
    amax, smax = setting.traffic.emergency_decel, setting.max_steering
    held = {"u": (0.0, 0.0), "left": 0}

    def random_agent(ego, others, t):
        if held["left"] <= 0:
            held["u"] = (float(rng.uniform(-amax, amax)), float(rng.uniform(-0.05, 0.05)))
            held["left"] = int(rng.integers(5, 20))
        held["left"] -= 1
        return held["u"]

    def reckless(ego, others, t):
        return amax, float(np.clip(0.05 * math.sin(t / 1.5) - 0.5 * ego.heading, -smax, smax))

    def seek(ego, others, t):
        ahead = [b for b in others if 0 < b.x - ego.x < 80]
        if not ahead:
            return amax, -0.5 * ego.heading
        target = min(ahead, key=lambda b: math.dist((b.x, b.y), (ego.x, ego.y)))
        bearing = math.atan2(target.y - ego.y, target.x - ego.x) - ego.heading
        return amax, float(np.clip(0.3 * bearing, -0.05, 0.05))

    return {"random": random_agent, "reckless": reckless, "seek": seek}[name]


def sumo_driver(traci, vehicle: str, setting, frame, rng: np.random.Generator):
    """SUMO's own driver with its checks off, driving guarded vehicle ``vehicle`` (given the traffic's vehicle type:
    its car-following and lane-change models and parameters, without dawdling).

    The acceleration is what SUMO's car-following model chooses towards the leader SUMO sees in the vehicle's lane
    (``vehicle.getFollowSpeed``), up to its desired speed (the traffic's top speed times a speed factor drawn as
    SUMO draws the traffic's) and its acceleration bound. A lane change begins whenever SUMO's lane-change model
    (LC2013, or SL2015 with sublanes) wants one (``vehicle.getLaneChangeState``: left or right, for a strategic,
    cooperative, speed-gain or keep-right reason), **blocked or not**: the gap checks SUMO makes before it changes
    lanes are off. A lane keeper steers towards the target lane's centre line."""
    if traci is None or vehicle is None or frame is None:
        raise ConfigError("the sumo agent drives a vehicle in a running SUMO: give traci, vehicle and frame")
    road = frame.road
    t, dt, amax = setting.traffic, setting.step_length, setting.traffic.emergency_decel
    traci.vehicle.setType(vehicle, DRIVER_TYPE)
    desired = t.max_speed * float(np.clip(rng.normal(1.0, t.speed_factor_dev), 0.8, 1.2))
    plan = {"target": None}

    def acceleration(speed: float) -> float:
        v_next = min(desired, speed + t.accel * dt)
        leader = traci.vehicle.getLeader(vehicle, LEADER_RANGE)
        if leader and leader[0]:
            lid, gap = leader
            v_next = min(v_next, traci.vehicle.getFollowSpeed(vehicle, speed, max(gap, 0.0), traci.vehicle.getSpeed(lid),
                                                              traci.vehicle.getDecel(lid), lid))
        return float(np.clip((v_next - speed) / dt, -amax, amax))

    def wished(slot: int, x: float):
        for direction, bit, side in ((1, LCA_LEFT, -1), (-1, LCA_RIGHT, 1)):   # slots count from the left
            state = traci.vehicle.getLaneChangeState(vehicle, direction)[0]
            if state & bit and state & LCA_WISHES and frame.on_corridor(slot + side, x):
                return slot + side
        return None

    def drive(ego, others, time):
        if isinstance(road, RoadMap) and road.on_branch(ego.x, ego.y) is not None:   # a ramp or an exit: follow it
            plan["target"] = None
            steer = road.lane_heading(ego.x, ego.y) - ego.heading
            return acceleration(ego.speed), float(np.clip(steer, -STEER_LIMIT, STEER_LIMIT))
        slot = road.nearest_slot(ego.x, ego.y)
        target = plan["target"]
        if target is None or (target == slot and abs(ego.y - frame.centre_y(slot)) < 0.2):
            target = plan["target"] = wished(slot, ego.x)
        y_goal = frame.centre_y(slot if target is None else target)
        heading_goal = math.atan2(y_goal - ego.y, max(15.0, 2.0 * ego.speed))
        steer = float(np.clip(heading_goal - ego.heading, -STEER_LIMIT, STEER_LIMIT))
        return acceleration(ego.speed), steer

    return drive

