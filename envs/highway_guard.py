"""The ITHA guardian between any agent and highway-env's ``highway-v0`` family.

The wrapper maps the simulator's vehicles to ITHA global states every
simulation step (position along the road, speed, lane; ITHA lane 1 is the
rightmost) and

* refuses a lane change (meta action ``LANE_LEFT``/``LANE_RIGHT``) that is not
  ρ̂-responsible (Definition 22, ``itha.highway.EgoSupervisor``) and replaces it
  by ``IDLE``;
* clips the ego's acceleration, at every simulation step, to the self-safe
  interval (7.4) of the car-following RCIS for the simulator's step
  ``dt = 1 / simulation_frequency``.

Lane changes in highway-env take many simulation steps, while ITHA resets are
instantaneous. The guardian accounts for it as follows: a lane change is
accepted only if it is responsible at the step it starts; while it lasts, the
ego is treated as occupying both lanes, so its acceleration must be self-safe
with respect to the nearest car ahead in either lane and must keep the
nearest car behind in the target lane in the RCIS whatever that car does (a
lower bound on the ego's speed). A vehicle of the traffic that is itself
changing lanes is likewise placed in both of its lanes. No new lane change
starts while one is under way. If the two bounds ever conflict, the guardian
brakes (the leader comes first) and says so in ``info``.

``info["guardian"]`` reports the proposed and applied meta action, whether the
lane change was refused and why, how many simulation steps had their
acceleration clipped, and the model assumptions seen violated (a vehicle
braking harder than the disturbance bound, e.g. after a crash).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from rcis.admissible import nearest_in_intervals
from itha.car_following import CarFollowingParams, MaximalSet, admissible_inputs, speeds_to_inputs
from itha.highway import LEFT, RIGHT, EgoSupervisor, HighwayParams, intersect_intervals

LANE_CHANGE_ACTIONS = {"LANE_LEFT": LEFT, "LANE_RIGHT": RIGHT}


@dataclass(frozen=True)
class HighwayGuardConfig:
    """The RCIS parameters for highway-env (its vehicles' limits as defaults)."""

    h_min: float = 2.0          # m, bumper to bumper
    v_max: float = 40.0         # highway-env's Vehicle.MAX_SPEED
    accel: float = 6.0          # |a| bound of the ego and of the traffic (IDMVehicle.ACC_MAX)
    overapprox: str = "trivial"  # highway-env traffic does not announce lane changes


def _lane_number(lane_id: int, n_lanes: int) -> int:
    """highway-env lane 0 is the leftmost; ITHA lane 1 is the rightmost."""
    return n_lanes - lane_id


class HighwayGuardianWrapper(gym.Wrapper):
    """Supervises the ego of a highway-env environment with a ``DiscreteMetaAction`` space."""

    def __init__(self, env, config: HighwayGuardConfig = HighwayGuardConfig()):
        super().__init__(env)
        base = env.unwrapped
        if type(base.action_type).__name__ != "DiscreteMetaAction":
            raise ValueError(f"HighwayGuardianWrapper needs a DiscreteMetaAction space, "
                             f"got {type(base.action_type).__name__}")
        self.config = config
        dt = 1.0 / base.config["simulation_frequency"]
        self.cf = CarFollowingParams(dt=dt, v_max=config.v_max, h_min=config.h_min, u_min=-config.accel,
                                     u_max=config.accel, d_min=-config.accel, d_max=config.accel)
        self.S = MaximalSet(self.cf)
        self._step_stats = None

    # ---- the simulator's state as ITHA global states ----------------------------------
    def _road_state(self):
        base = self.env.unwrapped
        ego = base.vehicle
        n_lanes = len(base.road.network.graph[ego.lane_index[0]][ego.lane_index[1]])
        p, v, lane, owner = [], [], [], []
        for veh in [ego] + [x for x in base.road.vehicles if x is not ego]:
            lanes = {veh.lane_index[2], veh.target_lane_index[2]} if veh is not ego else {veh.lane_index[2]}
            for lid in sorted(lanes):
                p.append(float(veh.position[0]))
                v.append(min(max(float(veh.speed), 0.0), self.cf.v_max))
                lane.append(_lane_number(lid, n_lanes))
                owner.append(veh)
        return p, v, lane, owner, n_lanes

    def _ego_changing(self) -> bool:
        ego = self.env.unwrapped.vehicle
        return ego.lane_index[2] != ego.target_lane_index[2]

    # ---- the per-step acceleration guard --------------------------------------------------
    def _acceleration_interval(self):
        base = self.env.unwrapped
        ego = base.vehicle
        p, v, lane, owner, n_lanes = self._road_state()
        length = ego.LENGTH
        occupied = {_lane_number(ego.lane_index[2], n_lanes), _lane_number(ego.target_lane_index[2], n_lanes)}
        allowed = speeds_to_inputs(self.cf, v[0], [(0.0, self.cf.v_max)])
        for ln in occupied:  # the nearest car ahead in each occupied lane
            ahead = [k for k in range(1, len(p)) if lane[k] == ln and p[k] >= p[0]]
            if ahead:
                k = min(ahead, key=lambda j: p[j])
                x = (v[0], p[k] - p[0] - length, v[k])
                allowed = intersect_intervals(allowed, admissible_inputs(self.S, x))
        if self._ego_changing():  # keep the follower in the target lane safe whatever it does
            tl = _lane_number(ego.target_lane_index[2], n_lanes)
            behind = [k for k in range(1, len(p)) if lane[k] == tl and p[k] < p[0]]
            if behind:
                k = max(behind, key=lambda j: p[j])
                dt = self.cf.dt
                gap = (p[0] + dt * v[0]) - (p[k] + dt * v[k]) - length
                speeds = self.S.lead_speed_intervals(min(v[k] + dt * self.cf.u_max, self.cf.v_max), gap)
                follower_ok = intersect_intervals(allowed, speeds_to_inputs(self.cf, v[0], speeds))
                if follower_ok:
                    allowed = follower_ok
                else:
                    self._step_stats["conflicts"] += 1
        return allowed

    def _guarded_act(self, original):
        def act(action=None):
            original(action)
            ego = self.env.unwrapped.vehicle
            a = float(ego.action["acceleration"])
            allowed = self._acceleration_interval()
            if not allowed:
                self._step_stats["outside_set"] += 1
                a_new = self.cf.u_min
            else:
                a_new = nearest_in_intervals(allowed, a)
            ego.action["acceleration"] = a_new
            if action is None:  # the per-simulation-step call (the meta-action call precedes it)
                self._step_stats["sim_steps"] += 1
                self._step_stats["clipped_steps"] += abs(a_new - a) > 1e-9
            self._check_assumptions()
        return act

    def _check_assumptions(self):
        base = self.env.unwrapped
        for veh in base.road.vehicles:
            if veh is base.vehicle:
                continue
            a = float(getattr(veh, "action", {}).get("acceleration", 0.0))
            if a < self.cf.d_min - 1e-9 or veh.speed < 0 or veh.speed > self.cf.v_max:
                self._step_stats["model_violations"] += 1

    # ---- gym API ------------------------------------------------------------------------------
    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        ego = self.env.unwrapped.vehicle
        ego.act = self._guarded_act(ego.act)
        info["guardian"] = {"enabled": True}
        return obs, info

    def step(self, action):
        base = self.env.unwrapped
        names = base.action_type.actions
        proposed = names[int(action)]
        applied, reason = proposed, ""
        if proposed in LANE_CHANGE_ACTIONS:
            if self._ego_changing():
                applied, reason = "IDLE", "a lane change is already under way"
            else:
                ok, why = self._lane_change_responsible(LANE_CHANGE_ACTIONS[proposed])
                if not ok:
                    applied, reason = "IDLE", why
        self._step_stats = {"sim_steps": 0, "clipped_steps": 0, "conflicts": 0, "outside_set": 0,
                            "model_violations": 0}
        obs, reward, terminated, truncated, info = self.env.step(base.action_type.actions_indexes[applied])
        info["guardian"] = {"proposed": proposed, "applied": applied, "refused": applied != proposed,
                            "reason": reason, **self._step_stats,
                            "overridden": applied != proposed or self._step_stats["clipped_steps"] > 0}
        return obs, reward, terminated, truncated, info

    def _lane_change_responsible(self, trig):
        p, v, lane, owner, n_lanes = self._road_state()
        prm = HighwayParams(car_following=self.cf, n_lanes=n_lanes, n_cars=len(p) - 1,
                            car_length=self.env.unwrapped.vehicle.LENGTH, ego_lane=lane[0])
        sup = EgoSupervisor(prm, self.S, self.config.overapprox)
        verdict = sup.lane_change(p, v, lane, 0, trig, {})
        return bool(verdict.inputs), verdict.reason


# ---- agents and collision fault ------------------------------------------------------------------
class RandomAgent:
    def __init__(self, n_actions: int, rng: np.random.Generator):
        self.n, self.rng = n_actions, rng

    def __call__(self, obs, names) -> int:
        return int(self.rng.integers(self.n))


class RecklessAgent:
    """Changes lanes whenever it can, alternating sides, and asks to go faster otherwise."""

    def __init__(self, n_actions: int, rng: np.random.Generator):
        self.t, self.rng = 0, rng

    def __call__(self, obs, names) -> int:
        self.t += 1
        pick = ("LANE_LEFT", "LANE_RIGHT", "FASTER")[self.t % 3] if self.rng.uniform() < 0.9 else "FASTER"
        return names.index(pick)


class IdleAgent:
    def __init__(self, n_actions: int, rng: np.random.Generator):
        pass

    def __call__(self, obs, names) -> int:
        return names.index("IDLE")


AGENTS = {"random": RandomAgent, "reckless": RecklessAgent, "idle": IdleAgent}


def collision_fault(env) -> str | None:
    """None if the ego has not crashed; else "ego" or "other" (who hit whom).

    The ego is at fault if the other car is ahead of it (it rear-ended it) or if
    the ego was changing lanes towards the other car's lane.
    """
    base = env.unwrapped
    ego = base.vehicle
    if not ego.crashed:
        return None
    others = [v for v in base.road.vehicles if v is not ego and v.crashed]
    if not others:
        return "ego"  # crashed into an object
    other = min(others, key=lambda o: np.linalg.norm(o.position - ego.position))
    if other.position[0] > ego.position[0]:
        return "ego"
    if ego.lane_index[2] != ego.target_lane_index[2] and \
            other.lane_index[2] in (ego.target_lane_index[2], other.target_lane_index[2]):
        return "ego"
    return "other"


def highway_rollouts(env_id: str, agent: str, episodes: int, seed: int, guardian: bool = True,
                     config: HighwayGuardConfig = HighwayGuardConfig(), env_config: dict | None = None,
                     progress=None, recorder=None) -> dict:
    """Seeded episodes of one agent in a highway-env environment, with or without the guardian."""
    import highway_env  # noqa: F401 - registers the environments

    if agent not in AGENTS:
        raise ValueError(f"unknown agent {agent!r}; choose from {sorted(AGENTS)}")
    env = gym.make(env_id, config=env_config or {})
    if guardian:
        env = HighwayGuardianWrapper(env, config)
    names = list(env.unwrapped.action_type.actions.values()) if isinstance(
        env.unwrapped.action_type.actions, dict) else list(env.unwrapped.action_type.actions)
    totals = {"episodes": episodes, "steps": 0, "collisions": 0, "ego_at_fault_collisions": 0,
              "override_steps": 0, "refused_lane_changes": 0, "clipped_sim_steps": 0, "lane_changes": 0,
              "distance_mean": 0.0, "model_violation_steps": 0, "conflict_sim_steps": 0, "crashes": []}
    distance = 0.0
    for ep in range(episodes):
        obs, info = env.reset(seed=seed + ep)
        pol = AGENTS[agent](len(names), np.random.default_rng([seed, ep]))
        x0 = float(env.unwrapped.vehicle.position[0])
        done = False
        t = 0
        while not done:
            a = pol(obs, names)
            lane_before = env.unwrapped.vehicle.target_lane_index[2]
            obs, r, term, trunc, info = env.step(a)
            t += 1
            totals["steps"] += 1
            g = info.get("guardian", {})
            totals["override_steps"] += int(bool(g.get("overridden")))
            totals["refused_lane_changes"] += int(bool(g.get("refused")) and names[a] in LANE_CHANGE_ACTIONS)
            totals["clipped_sim_steps"] += g.get("clipped_steps", 0)
            totals["model_violation_steps"] += int(g.get("model_violations", 0) > 0)
            totals["conflict_sim_steps"] += g.get("conflicts", 0)
            totals["lane_changes"] += int(env.unwrapped.vehicle.target_lane_index[2] != lane_before)
            if recorder is not None:
                recorder.log(env, ep, t, names[a], g)
            fault = collision_fault(env)
            if fault:
                totals["collisions"] += 1
                totals["ego_at_fault_collisions"] += int(fault == "ego")
                totals["crashes"].append({"episode": ep, "step": t, "fault": fault,
                                          "model_violations": g.get("model_violations", 0)})
            done = term or trunc
        distance += float(env.unwrapped.vehicle.position[0]) - x0
        if progress:
            progress(ep + 1, episodes)
    totals["distance_mean"] = distance / episodes
    env.close()
    return totals
