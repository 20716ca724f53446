"""``guardian/HighwayOvertake-v0``: the overtake scenario of Chapter 6 inside highway-env.

Built from highway-env's parts (road network of straight lanes, vehicle classes,
observation and action types, renderer, ``default_config``): the ego drives
behind a lead car in the right lane; the lead is driven by the aggressive or
cautious intention model of ``intention.models`` — the same definitions the RCIS
library and the estimator use —, and IDM/MOBIL traffic drives on the other
lanes, some of it coming from behind in the left lane.

The model drives, with one addition: the ego's speed is clipped at 0 after each step (a car held
by its brake stays stopped; (6.3) has additive noise and would creep or reverse at standstill). The
dissertation's safe set keeps ``v_ex >= 16``, where the clip never acts; with traffic the ego must be
able to wait behind the lead, so the default parameters (``OvertakeParams.among_traffic()``) let
``v_ex`` fall to 0. One step is one sampling period of (6.3) (``dt = 0.1 s``:
``simulation_frequency = policy_frequency = 10``). Each step the environment
reads the overtake state ``x = [v_ex, y_e, h, v_Lx]`` from the vehicles (``h`` is
the lead's position minus the ego's, centre to centre), draws the disturbance
``w = [w_ex, w_ey, w_Lx, w_Delta]`` (random, or adversarial as in
``Overtake-v0``), computes ``x+ = f(x, u_e, w)`` with the intention model's own
``PWASystem.step``, and moves the ego and the lead to it; traffic moves as (7.3)
(``envs.vehicles``). Lateral units: one unit of ``y_e`` is ``lateral_scale``
metres (default 2: the dissertation's lanes are 1.8 units apart, ours 3.6 m), so
the safe set's ``y_e >= 0.9`` puts 1.8 m between the two cars' centre lines — the
width of a car.

An episode terminates when the ego crashes or the pair leaves the safe set (6.8),
and is truncated after ``duration`` seconds.
"""
from __future__ import annotations

import os

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.envs.common.observation import ObservationType
from highway_env.road.lane import LineType, StraightLane
from highway_env.road.road import Road, RoadNetwork

from envs.overtake import DISTURBANCE_MODES, draw_disturbance, sample_initial_state
from envs.vehicles import IntentionLead, OvertakeEgo, PointMassIDM
from guardian.errors import ConfigError
from intention.models import intention_models, safe_set
from intention.params import OvertakeParams

INTENTIONS = ("aggressive", "cautious")
LEAD_DEPARTURES = ("hardest", "random", "brake", "stop")  # what a lead that leaves its model does (config lead_departure)
OVERTAKE_STATE = "OvertakeState"  # the observation type ``x = [v_ex, y_e, h, v_Lx]`` (float64)


class OvertakeStateObservation(ObservationType):
    """The overtake state ``x = [v_ex, y_e, h, v_Lx]`` of (6.3) as the observation."""

    def space(self) -> spaces.Space:
        return spaces.Box(-np.inf, np.inf, shape=(4,), dtype=np.float64)

    def observe(self) -> np.ndarray:
        return self.env.overtake_state()
SUPPORTED_ACTIONS = ("ContinuousAction", "DiscreteAction", "DiscreteMetaAction")
# highway-env's observation types this env offers (``MultiAgentObservation``: one tuple entry, the ego's)
OBSERVATIONS = ("Kinematics", "OccupancyGrid", "TimeToCollision", "LidarObservation", "GrayscaleObservation",
                "AttributesObservation", "MultiAgentObservation", "TupleObservation", OVERTAKE_STATE)
REFUSED_OBSERVATIONS = {"KinematicsGoal": "it observes a goal (parking-v0's); this scenario has none",
                        "ExitObservation": "it observes exit-v0's exit lane; this road has none"}
ATTRIBUTES = ("state",)  # what AttributesObservation may read: the overtake state x


class HighwayOvertakeEnv(AbstractEnv):
    """The overtake scenario on a highway-env road (see the module docstring).

    Parameters (``config``, on top of highway-env's ``AbstractEnv`` keys)
    ----------
    intention : "aggressive" | "cautious"
        The lead's intention model (6.5) / (6.7).
    disturbance : "random" | "adversarial"
    lanes_count : int >= 2
        The ego and the lead start in the rightmost lane; (6.8) keeps the ego in the two rightmost.
    traffic_count, traffic_from_behind : int
        IDM/MOBIL cars on the other lanes; ``traffic_from_behind`` of them start behind the ego in
        the left lane, faster than it.
    params : OvertakeParams
        The scenario's parameters (Table 6.1); ``1 / params.dt`` must be both frequencies.
    """

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        p = OvertakeParams.among_traffic()
        config.update({
            "observation": {"type": "Kinematics"},
            "action": {"type": "ContinuousAction", "acceleration_range": list(p.a_ex_bounds),
                       "steering_range": list(p.v_ey_bounds)},  # [m/s^2], [units of y_e per s]
            "simulation_frequency": 10,      # [Hz] = 1 / dt of (6.3)
            "policy_frequency": 10,          # [Hz]
            "duration": 30,                  # [s]
            "lanes_count": 2,
            "lateral_scale": 2.0,            # [m per unit of y_e]; lanes are 1.8 * lateral_scale wide
            "intention": "cautious",
            "disturbance": "random",
            "traffic_count": 4,
            "traffic_from_behind": 2,
            "traffic_speed_range": [26.0, 33.0],  # [m/s] traffic's initial and desired speeds
            "target_speeds": [18.0, 22.0, 26.0, 30.0, 34.0],  # [m/s] meta actions FASTER / SLOWER
            "initial_box": [[20.0, -0.2, 25.0, 15.0], [30.0, 0.2, 60.0, 25.0]],  # x0: ego behind, right lane
            "initial_region": None,          # an rcis.Region x0 must lie in (e.g. C_bnd)
            "lead_departure": None,          # {"after": s, "behaviour": ..., "decel": m/s^2}: the lead leaves its model
            "terminate_when_unsafe": True,   # end the episode when the state leaves the safe set (6.8)
            "params": p,
            "screen_width": 900,             # [px]
            "screen_height": 160,            # [px]
            "scaling": 6.0,                  # [px/m]
            "centering_position": [0.35, 0.5],
        })
        return config

    def __init__(self, config: dict | None = None, render_mode: str | None = None):
        self.lead = None
        self.last_transition = None
        self.lead_off_model = False
        if render_mode == "rgb_array":  # SDL's offscreen driver: no display is looked for (and no XDG_RUNTIME_DIR
            os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")  # error); "dummy" would stop highway-env drawing
        super().__init__(config, render_mode)

    def update_metadata(self, video_real_time_ratio: float = 1) -> None:
        """``render_fps`` = the policy frequency: videos play at the real rate (highway-env's default, 2, doubles it)."""
        super().update_metadata(video_real_time_ratio)

    def configure(self, config: dict | None) -> None:
        """highway-env's layered config, then checked: unknown keys and unsupported values are refused."""
        unknown = set(config or {}) - set(self.default_config())
        if unknown:
            raise ConfigError(f"HighwayOvertake: unknown config keys {sorted(unknown)}")
        super().configure(config)
        self._validate()
        self.params = self.config["params"]
        self.model = intention_models(self.params)[self.config["intention"]]
        self.safe = safe_set(self.params)

    def _validate(self) -> None:
        c, p = self.config, self.config["params"]
        if not isinstance(p, OvertakeParams):
            raise ConfigError(f"HighwayOvertake: config 'params' must be an OvertakeParams, got {type(p).__name__}")
        if c["intention"] not in INTENTIONS:
            raise ConfigError(f"HighwayOvertake: config 'intention' must be one of {INTENTIONS}, got {c['intention']!r}")
        if c["disturbance"] not in DISTURBANCE_MODES:
            raise ConfigError(f"HighwayOvertake: config 'disturbance' must be one of {DISTURBANCE_MODES}, "
                              f"got {c['disturbance']!r}")
        hz = 1.0 / p.dt
        for key in ("simulation_frequency", "policy_frequency"):
            if abs(c[key] - hz) > 1e-9:
                raise ConfigError(f"HighwayOvertake: config {key!r} is {c[key]}, but the sets are computed for "
                                  f"dt = {p.dt} s: use {hz:g}")
        if int(c["lanes_count"]) < 2:
            raise ConfigError(f"HighwayOvertake: config 'lanes_count' must be at least 2, got {c['lanes_count']}")
        if not (0 <= c["traffic_from_behind"] <= c["traffic_count"]):
            raise ConfigError("HighwayOvertake: config 'traffic_from_behind' must be between 0 and 'traffic_count'")
        self._validate_departure(c["lead_departure"], p)
        if not isinstance(c["terminate_when_unsafe"], bool):
            raise ConfigError(f"HighwayOvertake: config 'terminate_when_unsafe' must be true or false, got "
                              f"{c['terminate_when_unsafe']!r}")
        self._validate_observation(c["observation"], top=True)
        action = c["action"]
        kind = action.get("type")
        if kind not in SUPPORTED_ACTIONS:
            raise ConfigError(f"HighwayOvertake: config 'action.type' {kind!r} is not supported; "
                              f"use one of {SUPPORTED_ACTIONS}")
        if kind in ("ContinuousAction", "DiscreteAction"):  # the ranges default to U_e; an axis not controlled is 0
            for key, bounds in (("acceleration_range", p.a_ex_bounds), ("steering_range", p.v_ey_bounds)):
                lo, hi = action.setdefault(key, list(bounds))
                if lo < bounds[0] or hi > bounds[1]:
                    raise ConfigError(f"HighwayOvertake: config 'action.{key}' is {action.get(key)}; it must lie "
                                      f"in U_e = {list(bounds)} (the model's input bounds)")

    @staticmethod
    def _validate_departure(d, p) -> None:
        if d is None:
            return
        if not isinstance(d, dict) or set(d) - {"after", "behaviour", "decel"} or not {"after", "behaviour"} <= set(d):
            raise ConfigError("HighwayOvertake: config 'lead_departure' must be null or {\"after\": seconds, "
                              f"\"behaviour\": one of {LEAD_DEPARTURES}[, \"decel\": m/s^2 for brake]}}, got {d!r}")
        if d["behaviour"] not in LEAD_DEPARTURES:
            raise ConfigError(f"HighwayOvertake: config 'lead_departure.behaviour' must be one of {LEAD_DEPARTURES}, "
                              f"got {d['behaviour']!r}")
        if not (isinstance(d["after"], (int, float)) and d["after"] >= 0):
            raise ConfigError(f"HighwayOvertake: config 'lead_departure.after' must be a number of seconds >= 0, "
                              f"got {d['after']!r}")
        if ("decel" in d) != (d["behaviour"] == "brake"):
            raise ConfigError("HighwayOvertake: config 'lead_departure.decel' is given with (and only with) "
                              "behaviour 'brake'")
        if "decel" in d and not (isinstance(d["decel"], (int, float)) and d["decel"] > 0):
            raise ConfigError(f"HighwayOvertake: config 'lead_departure.decel' must be > 0, got {d['decel']!r}")

    def _validate_observation(self, obs: dict, top: bool) -> None:
        kind = obs.get("type")
        if kind in REFUSED_OBSERVATIONS:
            raise ConfigError(f"HighwayOvertake: config 'observation.type' {kind!r} is not supported: "
                              f"{REFUSED_OBSERVATIONS[kind]}")
        if kind not in OBSERVATIONS or (kind == OVERTAKE_STATE and not top):
            raise ConfigError(f"HighwayOvertake: config 'observation.type' {kind!r} is not supported; use one of "
                              f"{OBSERVATIONS} ({OVERTAKE_STATE!r} only as the observation itself)")
        if kind == "AttributesObservation":
            wrong = [a for a in obs.get("attributes", []) if a not in ATTRIBUTES]
            if wrong or not obs.get("attributes"):
                raise ConfigError(f"HighwayOvertake: config 'observation.attributes' {obs.get('attributes')!r}: "
                                  f"the attributes this env offers are {list(ATTRIBUTES)} (the overtake state x)")
        if kind == "MultiAgentObservation":
            self._validate_observation(obs.get("observation_config", {}), top=False)
        if kind == "TupleObservation":
            for inner in obs.get("observation_configs", []):
                self._validate_observation(inner, top=False)

    def define_spaces(self) -> None:
        """highway-env's observation and action types, and ``OvertakeState`` (the state ``x`` itself)."""
        if self.config["observation"].get("type") != OVERTAKE_STATE:
            return super().define_spaces()
        kept, self.config["observation"] = self.config["observation"], {"type": "Kinematics"}
        super().define_spaces()
        self.config["observation"] = kept
        self.observation_type = OvertakeStateObservation(self)
        self.observation_space = self.observation_type.space()

    # ---- scene ----------------------------------------------------------------------------
    @property
    def dt(self) -> float:
        return self.params.dt

    @property
    def lane_width(self) -> float:
        return 2 * self.params.left_lane_y * self.config["lateral_scale"]

    @property
    def right_lane(self) -> int:
        return int(self.config["lanes_count"]) - 1

    def _reset(self) -> None:
        self.lead_off_model = False
        self._create_road()
        self._create_vehicles()

    def _create_road(self) -> None:
        n, w = int(self.config["lanes_count"]), self.lane_width
        net = RoadNetwork()
        for k in range(n):
            lines = (LineType.CONTINUOUS_LINE if k == 0 else LineType.STRIPED,
                     LineType.CONTINUOUS_LINE if k == n - 1 else LineType.NONE)
            net.add_lane("0", "1", StraightLane([0.0, k * w], [20_000.0, k * w], width=w, line_types=lines,
                                                speed_limit=PointMassIDM.MAX_SPEED))
        self.road = Road(network=net, np_random=self.np_random, record_history=self.config["show_trajectories"])

    def _create_vehicles(self) -> None:
        c, p = self.config, self.params
        x0 = sample_initial_state(c["initial_box"], c["initial_region"], self.np_random, "HighwayOvertake")
        v, y, h, vl = x0
        y_origin = self.right_lane * self.lane_width
        ego = OvertakeEgo(self.road, [100.0, 0.0], v, p, y_origin, c["lateral_scale"], c["target_speeds"])
        ego.position[1] = ego.y_of(y)
        ego.on_state_update()
        self.lead = IntentionLead(self.road, [100.0 + h, y_origin], vl)
        self.road.vehicles.extend([ego, self.lead])
        self.controlled_vehicles = [ego]
        self._create_traffic(ego)
        self.last_transition = None

    def _create_traffic(self, ego) -> None:
        c, rng = self.config, self.np_random
        lo, hi = c["traffic_speed_range"]
        other_lanes = list(range(self.right_lane))
        left = self.right_lane - 1
        forbidden = frozenset({self.right_lane})
        for k in range(int(c["traffic_count"])):
            behind = k < c["traffic_from_behind"]
            lane = left if behind else int(rng.choice(other_lanes))
            x = ego.position[0] - rng.uniform(60.0, 160.0) * (k + 1) if behind else \
                ego.position[0] + rng.uniform(80.0, 140.0) * (k - c["traffic_from_behind"] + 1)
            speed = float(rng.uniform(lo, hi))
            car = PointMassIDM(self.road, [x, lane * self.lane_width], 0.0, speed,
                               target_lane_index=("0", "1", lane), target_speed=speed)
            car.forbidden_lanes = forbidden
            car.randomize_behavior()
            self.road.vehicles.append(car)

    # ---- the model's state and step ---------------------------------------------------------
    def overtake_state(self) -> np.ndarray:
        """``x = [v_ex, y_e, h, v_Lx]`` read from the vehicles."""
        ego = self.vehicle
        return np.array([ego.speed, ego.y_e, self.lead.position[0] - ego.position[0], self.lead.speed])

    @property
    def state(self) -> np.ndarray:
        """The overtake state ``x`` as an attribute (``AttributesObservation`` with ``attributes: ["state"]``)."""
        return self.overtake_state()

    def _simulate(self, action=None) -> None:
        if action is not None and not self.config["manual_control"]:
            self.action_type.act(action)
        self.road.act()  # traffic decides; the ego's act(None) is where a supervisor acts
        x = self.overtake_state()
        u = self.vehicle.input
        w = draw_disturbance(self.params, self.config["disturbance"], x, self.np_random)
        x_next = self.model.system.step(x, u, w)
        x_next[0] = max(x_next[0], 0.0)  # a car held by its brake stays stopped: it never reverses
        self.lead_off_model = self.lead_off_model or self.lead_departed
        if self.lead_off_model:
            x_next[3] = self._departed_lead_speed(float(x[3]))
        self.vehicle.stage(x_next[0], x_next[1])
        self.lead.stage(x_next[3])
        self.road.step(self.dt)
        self.steps += 1
        self.last_transition = {"state": x, "input": u, "disturbance": w, "next_state": x_next}
        self._automatic_rendering()

    @property
    def lead_departed(self) -> bool:
        """Is the lead's next transition outside its intention model (config ``lead_departure``: from ``after``
        seconds on)? ``info["lead_departed"]``: was this step's?"""
        d = self.config["lead_departure"]
        return d is not None and self.steps * self.dt >= d["after"] - 1e-9

    def _departed_lead_speed(self, v: float) -> float:
        """The lead's next speed once it has left its model: ``hardest`` brakes at ``a_L^min`` (the traffic
        bound), ``random`` draws an acceleration in ``U_o`` each step (within the bounds, no model), ``brake``
        brakes at ``decel`` (beyond the bound when above 3 m/s^2), ``stop`` stands at once (beyond every
        bound); never below 0."""
        d, p = self.config["lead_departure"], self.params
        accel = {"hardest": lambda: p.a_L_bounds[0], "random": lambda: self.np_random.uniform(*p.a_L_bounds),
                 "brake": lambda: -d.get("decel", 0.0), "stop": lambda: -np.inf}[d["behaviour"]]()
        return float(min(max(v + self.dt * accel, 0.0), p.v_Lx_bounds[1]))

    # ---- outcome ---------------------------------------------------------------------------------
    def left_safe_set(self) -> bool:
        return not bool(self.safe.contains(self.overtake_state()))

    def _reward(self, action) -> float:
        return float(self.vehicle.speed * self.dt / 36.0) - (10.0 if self._is_terminated() else 0.0)

    def _is_terminated(self) -> bool:
        return bool(self.vehicle.crashed or (self.config["terminate_when_unsafe"] and self.left_safe_set()))

    def _is_truncated(self) -> bool:
        return self.time >= self.config["duration"]

    def _info(self, obs, action=None) -> dict:
        info = super()._info(obs, action)
        info.update({"intention": self.model.name, "overtake_state": self.overtake_state().tolist(),
                     "unsafe": self.left_safe_set(), "lead_departed": self.lead_off_model})
        if self.last_transition is not None:
            info["disturbance"] = self.last_transition["disturbance"].tolist()
        return info


class OvertakeEnv(HighwayOvertakeEnv):
    """``guardian/Overtake-v0``: the two cars of Section 6.5, HighwayOvertake with only what differs.

    No traffic, the dissertation's parameters (Table 6.1: ``v_ex >= 16``) and the overtake state
    ``x = [v_ex, y_e, h, v_Lx]`` as the observation; actions are highway-env's ``ContinuousAction`` on
    ``U_e`` (or meta actions), the dynamics, disturbances, termination and reward those of
    HighwayOvertake (the model itself, so the states are those of (6.3)-(6.7)).
    """

    @classmethod
    def default_config(cls) -> dict:
        config = super().default_config()
        config.update({"observation": {"type": OVERTAKE_STATE}, "traffic_count": 0, "traffic_from_behind": 0,
                       "params": OvertakeParams()})
        return config

