"""The one registry of agents: every driver of every environment, for either action type.

Every agent is built as ``make_agent(name, env, rng)`` and called as ``agent(obs) -> action`` in the
environment's own action space: a highway-env ``DiscreteMetaAction``, ``ContinuousAction`` (the axes it
controls, normalised to ``[-1, 1]``) or ``DiscreteAction`` (the nearest point of its grid), or any other
``Box`` (``random`` and ``idle`` only).

* ``random``: uniform in the action space (meta: one of the five actions);
* ``reckless``: meta: changes lanes whenever it can, alternating sides, else FASTER;
  continuous: full throttle, steering hard to one side then the other (2 s each);
* ``idle``: IDLE, or zero acceleration and steering;
* ``merge``: wants onto the road that goes on: on a lane that ends (no lane begins where it ends: an
  on-ramp's) it asks for the lane on its left (meta ``LANE_LEFT``; continuous: steering towards that lane
  at full throttle), elsewhere full throttle keeping its lane (meta ``FASTER``);
* ``mpc``, ``bad``, ``careful``: the switched MPC drivers of Section 6.5.3 (``envs.mpc``) on the
  overtake state (``guardian/Overtake-v0`` or ``guardian/HighwayOvertake-v0``, continuous actions);
* adversaries (highway-env roads), trying to make the guardian fail: ``seek`` (drive at the nearest
  car), ``brake_check`` (cut in front of a car behind, then brake hard), ``oscillate`` (flip the
  lateral command every few steps at full throttle), ``hold`` (hold a random action 1-3 s), ``trap``
  (close up on the car ahead, swerve into a neighbouring lane when a car is level or closing there),
  ``line`` (ride a lane line at full throttle, the body's edge on it, so that lanes beginning beside it
  or closing in come under the body; meta: ask for the lane change on its side at every step).

With highway-env's ``MultiAgentAction`` every controlled car gets its own agent of the name, seeded from the
episode's generator in the controlled order, which sees its own car as the ego (``MultiAgent``).

``BASELINES`` are the four drivers of Section 6.5.3's experiment (``--agent all``); ``policy:PATH`` drives
with a stable-baselines3 policy file (``PolicyAgent``).
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from envs.mpc import STYLES, MPCDriver


@runtime_checkable
class Agent(Protocol):
    """A driver: called once per step with the observation, returns an action of the env's space."""

    def __call__(self, obs): ...


def _kind(env) -> str:
    """``DiscreteMetaAction``, ``ContinuousAction``, ``MultiAgentAction`` (highway-env) or ``Box`` (physical
    units)."""
    action_type = getattr(env.unwrapped, "action_type", None)
    return type(action_type).__name__ if action_type is not None else "Box"


def _meta_names(env) -> list:
    return list(env.unwrapped.action_type.actions.values())


def _continuous(env, throttle: float, steer: float):
    """An action at fractions ``throttle, steer`` in ``[-1, 1]`` of the env's continuous range: the axes the
    action type controls (highway-env's ``ContinuousAction``), or the nearest point of a ``DiscreteAction``
    grid (its index: the first axis varies slowest, as ``itertools.product``)."""
    kind = _kind(env)
    if kind in ("ContinuousAction", "DiscreteAction"):
        at = env.unwrapped.action_type
        values = [throttle] * at.longitudinal + [steer] * at.lateral
        if kind == "ContinuousAction":
            return np.array(values, dtype=np.float32)
        grid = np.linspace(-1.0, 1.0, at.actions_per_axis)
        index = 0
        for v in values:
            index = index * at.actions_per_axis + int(np.argmin(np.abs(grid - v)))
        return index
    space = env.action_space
    mid, half = (space.high + space.low) / 2, (space.high - space.low) / 2
    return (mid + half * np.array([throttle, steer])).astype(space.dtype)


class RandomAgent:
    def __init__(self, env, rng):
        self.space, self.rng, self.kind = env.action_space, rng, _kind(env)

    def __call__(self, obs):
        if hasattr(self.space, "n"):  # DiscreteMetaAction, DiscreteAction
            return int(self.rng.integers(self.space.n))
        return self.rng.uniform(self.space.low, self.space.high).astype(self.space.dtype)


class RecklessAgent:
    SWITCH_STEPS = 20  # continuous: steering side changes every this many steps

    def __init__(self, env, rng):
        self.env, self.rng, self.kind, self.t = env, rng, _kind(env), 0

    def __call__(self, obs):
        self.t += 1
        if self.kind == "DiscreteMetaAction":
            names = _meta_names(self.env)
            pick = ("LANE_LEFT", "LANE_RIGHT", "FASTER")[self.t % 3] if self.rng.uniform() < 0.9 else "FASTER"
            return names.index(pick)
        side = 1.0 if (self.t // self.SWITCH_STEPS) % 2 == 0 else -1.0
        return _continuous(self.env, 1.0, side)


class IdleAgent:
    def __init__(self, env, rng):
        self.env, self.kind = env, _kind(env)

    def __call__(self, obs):
        if self.kind == "DiscreteMetaAction":
            return _meta_names(self.env).index("IDLE")
        if self.kind in ("ContinuousAction", "DiscreteAction"):
            return _continuous(self.env, 0.0, 0.0)
        return np.clip(np.zeros(2), self.env.action_space.low, self.env.action_space.high).astype(
            self.env.action_space.dtype)


class MPCAgent:
    """A switched MPC driver of ``envs.mpc`` on the overtake state, in the env's continuous action."""

    def __init__(self, env, rng, style):
        base = env.unwrapped
        if not (_kind(env) == "ContinuousAction" and hasattr(base, "overtake_state")):
            raise ValueError("the MPC drivers drive guardian/Overtake-v0 or guardian/HighwayOvertake-v0 "
                             "with continuous actions")
        self.base = base
        self.driver = MPCDriver(style, base.params)
        self.driver.reset()
        at = base.action_type
        self.ranges = (np.asarray(at.acceleration_range, float), np.asarray(at.steering_range, float))

    def __call__(self, obs):
        u = self.driver.act(self.base.overtake_state())
        out = [2 * (u[k] - r[0]) / (r[1] - r[0]) - 1 for k, r in enumerate(self.ranges)]
        return np.clip(np.array(out, dtype=np.float32), -1.0, 1.0)


# ---- adversarial agents: they try to make the guardian fail ---------------------------------------------
class _Road:
    """What the adversaries read: the ego, the other cars (the lead too), lanes as highway-env ids."""

    def __init__(self, env):
        self.env, self.base = env, env.unwrapped
        self.kind = _kind(env)
        self.overtake = hasattr(self.base, "overtake_state")

    @property
    def ego(self):
        return self.base.vehicle

    def others(self):
        return [v for v in self.base.road.vehicles if v is not self.ego]

    def n_lanes(self) -> int:
        """Lanes of the ego's road segment (highway-env's ``lanes_count`` on one straight road)."""
        if self.overtake:
            return int(self.base.config["lanes_count"])
        _from, _to, _ = self.ego.lane_index
        return len(self.base.road.network.graph[_from][_to])

    def lane(self, v=None) -> int:
        return (v or self.ego).lane_index[2]

    def nearest(self, ahead_only: bool = False):
        ego = self.ego
        cars = [v for v in self.others() if not ahead_only or v.position[0] > ego.position[0]]
        return min(cars, key=lambda v: float(np.linalg.norm(v.position - ego.position)), default=None)

    def lateral_towards(self, lane: int) -> float:
        """A lateral command in ``[-1, 1]`` (the env's continuous scale) moving the ego to ``lane``'s centre."""
        ego = self.ego
        if not self.overtake:  # a lane of the ego's segment (roads whose segments differ in lanes)
            lane = min(max(lane, 0), self.n_lanes() - 1)
        y_target = self.base.road.network.get_lane(("0", "1", lane) if self.overtake else
                                                   ego.lane_index[:2] + (lane,)).position(ego.position[0], 0)[1]
        dy = float(y_target - ego.position[1])
        if self.overtake:  # v_ey in units of y_e per second, positive to the left (smaller simulator y)
            return float(np.clip(-dy / 1.0, -1.0, 1.0))
        return float(np.clip(0.15 * dy - 1.5 * float(ego.heading), -1.0, 1.0))

    def meta(self, name: str) -> int:
        return _meta_names(self.env).index(name)

    def lane_change_to(self, lane: int):
        """The meta action towards ``lane`` (IDLE when there)."""
        if lane < self.lane():
            return self.meta("LANE_LEFT")
        if lane > self.lane():
            return self.meta("LANE_RIGHT")
        return self.meta("IDLE")

    def act(self, throttle: float, lane: int, meta_longitudinal: str = "FASTER"):
        """Throttle in ``[-1, 1]`` towards ``lane``: continuous, or the meta action that moves there."""
        if self.kind == "DiscreteMetaAction":
            if lane != self.lane():
                return self.lane_change_to(lane)
            return self.meta(meta_longitudinal)
        return _continuous(self.env, throttle, self.lateral_towards(lane))


class SeekAgent:
    """Drives at the nearest car: its lane, full throttle."""

    def __init__(self, env, rng):
        self.road = _Road(env)

    def __call__(self, obs):
        target = self.road.nearest()
        lane = self.road.lane(target) if target is not None else self.road.lane()
        return self.road.act(1.0, lane)


class BrakeCheckAgent:
    """Cuts in front of the nearest car behind in a neighbouring lane, then brakes hard for 2 s."""

    BRAKE_SECONDS = 2.0

    def __init__(self, env, rng):
        self.road, self.rng = _Road(env), rng
        self.brake_left, self.target = 0, None
        self.hz = float(env.unwrapped.config["policy_frequency"])

    def __call__(self, obs):
        road = self.road
        if self.brake_left > 0:
            self.brake_left -= 1
            return road.act(-1.0, road.lane(), "SLOWER")
        if self.target is not None and road.lane() == self.target:
            self.target, self.brake_left = None, int(self.BRAKE_SECONDS * self.hz)
            return road.act(-1.0, road.lane(), "SLOWER")
        if self.target is None:
            ego, best = road.ego, None
            for v in road.others():
                if abs(road.lane(v) - road.lane()) == 1 and v.position[0] < ego.position[0]:
                    if best is None or v.position[0] > best.position[0]:
                        best = v
            self.target = road.lane(best) if best is not None else None
        return road.act(1.0, self.target if self.target is not None else road.lane())


class OscillateAgent:
    """Full throttle, the lateral command flipping side every few steps."""

    def __init__(self, env, rng):
        self.road, self.rng, self.t = _Road(env), rng, 0
        self.period = int(rng.integers(2, 9))

    def __call__(self, obs):
        self.t += 1
        side = 1.0 if (self.t // self.period) % 2 == 0 else -1.0
        if self.road.kind == "DiscreteMetaAction":
            return self.road.meta("LANE_LEFT" if side > 0 else "LANE_RIGHT")
        return _continuous(self.road.env, 1.0, side)


class HoldAgent:
    """Holds a random action for a random 1-3 s, then draws another."""

    def __init__(self, env, rng):
        self.random = RandomAgent(env, rng)
        self.rng, self.left, self.action = rng, 0, None
        self.hz = float(env.unwrapped.config["policy_frequency"])

    def __call__(self, obs):
        if self.left <= 0:
            self.action = self.random(obs)
            self.left = int(self.rng.uniform(1.0, 3.0) * self.hz)
        self.left -= 1
        return self.action


class TrapAgent:
    """Closes up on the car ahead in its lane at full throttle; swerves into a neighbouring lane when a
    car is level with it or closing from behind there (behind the lead: the trap of the overtake)."""

    def __init__(self, env, rng):
        self.road = _Road(env)

    def __call__(self, obs):
        road, ego = self.road, self.road.ego
        for v in road.others():
            lane = road.lane(v)
            dx = float(v.position[0] - ego.position[0])
            if abs(lane - road.lane()) == 1 and -25.0 < dx < 5.0:
                return road.act(1.0, lane)
        return road.act(1.0, road.lane())


class MergeAgent:
    """Onto the road that goes on (module docstring)."""

    def __init__(self, env, rng):
        self.env, self.base, self.kind = env, env.unwrapped, _kind(env)

    def _lane_ends(self, index) -> bool:
        """No lane of the network begins where this lane ends."""
        network = self.base.road.network
        lane = network.get_lane(index)
        end = lane.position(lane.length, 0.0)
        return not any(np.hypot(*(other.position(0.0, 0.0) - end)) < 1e-6
                       for tos in network.graph.values() for group in tos.values() for other in group)

    def __call__(self, obs):
        ego = self.base.vehicle
        index = ego.lane_index
        left = index[:2] + (index[2] - 1,)
        wants = index[2] > 0 and self._lane_ends(index)
        if self.kind == "DiscreteMetaAction":
            return _meta_names(self.env).index("LANE_LEFT" if wants else "FASTER")
        lane = self.base.road.network.get_lane(left if wants else index)
        s, r = lane.local_coordinates(ego.position)
        steer = float(np.clip(-0.15 * r - 1.5 * (float(ego.heading) - float(lane.heading_at(s))), -1.0, 1.0))
        return _continuous(self.env, 1.0, steer)


class LineAgent:
    """Rides a lane line: full throttle, steering the body's edge onto the line between its lane and the
    next one on its side (right or left, drawn per episode), on whatever lane it is on."""

    def __init__(self, env, rng):
        self.road = _Road(env)
        self.side = 1.0 if rng.uniform() < 0.5 else -1.0  # +1: right (larger highway-env y)

    def __call__(self, obs):
        road = self.road
        if road.kind == "DiscreteMetaAction":
            return road.meta("LANE_RIGHT" if self.side > 0 else "LANE_LEFT")
        ego, base = road.ego, road.base
        lane = ego.lane
        s, r = lane.local_coordinates(ego.position)
        v, step = max(float(ego.speed), 1.0), 1.0 / float(base.config["policy_frequency"])
        gap = self.side * (lane.width_at(s) - ego.WIDTH) / 2 - r  # to the line, sideways
        want = lane.heading_at(s) + float(np.clip(np.arctan2(gap, 2 * v * step), -0.3, 0.3))
        turn = (want - float(ego.heading) + np.pi) % (2 * np.pi) - np.pi
        beta = np.arcsin(np.clip(turn * ego.LENGTH / 2 / (v * step), -0.99, 0.99))
        steering = np.arctan(2 * np.tan(beta)) / max(abs(b) for b in base.action_type.steering_range)
        return _continuous(road.env, 1.0, float(np.clip(steering, -1.0, 1.0)))


class _CarEnv:
    """What one controlled car's agent sees of a multi-agent env: its own action space and type, its own car
    as the ego; everything else is the env's."""

    def __init__(self, env, index: int):
        self.action_space = env.action_space[index]
        self.unwrapped = _CarBase(env.unwrapped, index)


class _CarBase:
    def __init__(self, base, index: int):
        self._base, self._index = base, index

    @property
    def action_type(self):
        return self._base.action_type.agents_action_types[self._index]

    @property
    def vehicle(self):
        return self._base.controlled_vehicles[self._index]

    def __getattr__(self, name):
        return getattr(self._base, name)


class MultiAgent:
    """One agent per controlled car of a ``MultiAgentAction`` env; their actions as the env's tuple."""

    def __init__(self, name: str, env, rng, algo=None):
        n = len(env.unwrapped.action_type.agents_action_types)
        self.agents = [make_agent(name, _CarEnv(env, i), np.random.default_rng(rng.integers(2 ** 63)), algo)
                       for i in range(n)]

    def __call__(self, obs):
        return tuple(agent(obs) for agent in self.agents)


def _mpc(style: str):
    return lambda env, rng: MPCAgent(env, rng, STYLES[style])


_FACTORIES = {"random": RandomAgent, "reckless": RecklessAgent, "idle": IdleAgent, "merge": MergeAgent,
              **{name: _mpc(name) for name in STYLES},
              "seek": SeekAgent, "brake_check": BrakeCheckAgent, "oscillate": OscillateAgent, "hold": HoldAgent,
              "trap": TrapAgent, "line": LineAgent}
AGENTS = tuple(_FACTORIES)
BASELINES = ("mpc", "bad", "careful", "random")
ADVERSARIES = ("seek", "brake_check", "oscillate", "hold", "trap", "line")  # need a highway-env road


def _algorithm_of(data: dict) -> str | None:
    """The stable-baselines3 algorithm of a saved model's data: its policy class's module names it
    (``stable_baselines3.<algo>.policies``; DDPG's are TD3's, which loads it alike), except PPO's and A2C's,
    which share ``stable_baselines3.common.policies``: PPO saves its ``clip_range``, A2C has none."""
    module = getattr(data.get("policy_class"), "__module__", "") or ""
    parts = module.split(".")
    if len(parts) < 2 or parts[0] != "stable_baselines3":
        return None
    if parts[1] == "common":
        return "PPO" if "clip_range" in data else "A2C"
    return parts[1]


class PolicyAgent:
    """A stable-baselines3 policy file (``policy:PATH``), acting deterministically on the observation.

    Parameters
    ----------
    env : gymnasium.Env
        The env it drives; its action space must be the policy's.
    rng : numpy.random.Generator
        Unused (the policy is deterministic); kept for the registry's calling convention.
    path : str
        The ``.zip`` saved by stable-baselines3.
    algo : str, optional
        The algorithm (``DQN``, ``PPO``, ...); by default read from the file.
    """

    _loaded: dict = {}

    def __init__(self, env, rng, path: str, algo: str | None = None):
        self.model = self.load(path, algo)
        if self.model.action_space != env.action_space:
            raise ValueError(f"the policy {path} acts in {self.model.action_space}, the env in {env.action_space}")
        if self.model.observation_space != env.observation_space:
            raise ValueError(f"the policy {path} observes {self.model.observation_space}, the env gives "
                             f"{env.observation_space} (its config's 'observation' differs)")

    @classmethod
    def load(cls, path: str, algo: str | None = None):
        from pathlib import Path

        file = Path(path)
        if not file.is_file():
            raise ValueError(f"no policy file {path}")
        key = (str(file.resolve()), file.stat().st_mtime_ns, algo)
        if key not in cls._loaded:
            try:
                import stable_baselines3
                from stable_baselines3.common.save_util import load_from_zip_file
            except ImportError:
                raise ValueError("a --policy needs stable-baselines3: pip install 'guardian[rl]'") from None
            if algo is None:
                algo = _algorithm_of(load_from_zip_file(file, device="cpu")[0])
                if algo is None:
                    raise ValueError(f"cannot tell the algorithm of {path}; name it (--algo DQN, PPO, ...)")
            model_class = getattr(stable_baselines3, algo.upper(), None)
            if model_class is None:
                raise ValueError(f"stable-baselines3 has no algorithm {algo!r}")
            cls._loaded[key] = model_class.load(file, device="cpu")
        return cls._loaded[key]

    def __call__(self, obs):
        action, _ = self.model.predict(obs, deterministic=True)
        return action.item() if getattr(action, "shape", None) == () else action


def make_agent(name: str, env, rng: np.random.Generator, algo: str | None = None) -> Agent:
    """The agent ``name`` for ``env``.

    Parameters
    ----------
    name : str
        One of ``AGENTS``, or ``policy:PATH`` (a stable-baselines3 policy file, ``PolicyAgent``).
    env : gymnasium.Env
        The environment it drives (wrappers allowed); its action space decides the action's form.
    rng : numpy.random.Generator
        The agent's own randomness (the rollout seeds it per episode).
    algo : str, optional
        The algorithm of a ``policy:PATH`` file (default: read from it).

    Returns
    -------
    Agent
        A callable ``agent(obs) -> action``.
    """
    if _kind(env) == "MultiAgentAction":
        if name.startswith("policy:"):
            raise ValueError("a policy file drives one car; MultiAgentAction envs take the registry's agents")
        return MultiAgent(name, env, rng, algo)
    if name.startswith("policy:"):
        return PolicyAgent(env, rng, name.partition(":")[2], algo)
    if name not in _FACTORIES:
        raise ValueError(f"unknown agent {name!r}; choose from {', '.join(AGENTS)}")
    if name in ADVERSARIES and getattr(env.unwrapped, "road", None) is None:
        raise ValueError(f"the adversaries ({', '.join(ADVERSARIES)}) drive highway-env roads "
                         f"(guardian/HighwayOvertake-v0, the highway-v0 family), not {env.unwrapped.__class__.__name__}")
    return _FACTORIES[name](env, rng)
