"""The guardian: one gymnasium wrapper between any highway-env agent and the vehicle.

The wrapper decides nothing. Every simulation step (highway-env calls the ego's ``act(None)`` once
per simulation step, after the policy step's ``act(action)``) it reads the state (``guardian.sensing``),
asks the decision object, applies its answer to the vehicle and keeps the record:

* ``guardian/HighwayOvertake-v0``: ``guardian.pointmass.PointMassGuardian`` (the lead part of
  Chapter 6 composed with ITHA; the composed invariant set is explained there);
* the ``highway-v0`` family: ``guardian.bicycle.BicycleGuardian`` (ITHA for highway-env's bicycle).

Supervision is never lost silently: every ``step`` checks that the env's ego is the vehicle the
guardian is attached to; an ego that was reset or replaced behind the guardian's back (an inner
``Autoreset``, an env reset before wrapping, ``configure`` then reset) is re-attached, the road and
frequencies are read again and the record says so (``reattached``). Simulation steps the hook did
not see are counted (``unsupervised_steps``).

``info["guardian"]`` (the key is asserted free)::

    {"proposed": [a, lateral] | "LANE_LEFT" ...,  # the agent's action (decoded for continuous agents)
     "applied": [a, lateral] | "IDLE" ...,         # the input of the last simulation step; meta: the action
                                                   # executed over the policy step (applied_action's name)
     "applied_action": int | [float, ...],        # the policy step as an action of the env's space
     "applied_mean": [a, lateral], "applied_range": [[lo, hi], [lo, hi]],   # over the simulation steps
     "overridden": bool,               # any change to the agent's action
     "safety_override": bool,          # a change for safety (not only a clip to the model's bounds)
     "changed": "none" | "throttle" | "steering" | "both" | "lane_change" | "conflict" | "failsafe",
     "level": "composed" | "follower_dropped" | "conflict" | "failsafe",   # the worst of the step
     "reasons": [str, ...],
     "refused_lane_change": bool, "entered": [lane, ...],   # lanes begun this step (each checked, responsible)
     "lanes": [lane, ...],            # every lane the body was allowed to overlap (held, or entered responsibly)
     "active_set": "aggressive" | "cautious" | "bounded_velocity" | "itha",
     "valid_intentions": [str, ...], "identified": str | None,
     "in_invariant_set": bool,         # the state lay in the composed invariant set (first simulation step)
     "sim_steps": int, "clipped_steps": int, "model_clip_steps": int,
     "follower_dropped_steps": int, "conflict_steps": int,
     "failsafe_steps": int, "unsupervised_steps": int, "reattached": bool,
     "model_violations": {"ego": int, "lead": int, "traffic": int},
     "admissible_acceleration": [[lo, hi], ...],   # at the applied lateral input, last simulation step
     "admissible_lateral": [[lo, hi], ...]}        # at the applied acceleration (overtake scenarios)

and at reset ``{"enabled", "scenario", "action", "start_inside", "start_attempts"}``. With
``GuardianConfig.override_penalty``, a step with a safety override also has ``"penalty"`` (subtracted
from the reward).
"""
from __future__ import annotations

import os

import gymnasium as gym
import numpy as np
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.vehicle.controller import ControlledVehicle

from envs.highway_overtake import HighwayOvertakeEnv
from envs.vehicles import OvertakeEgo
from guardian.bicycle import BicycleGuardian
from guardian.config import GuardianConfig
from guardian.decision import LEVELS
from guardian.ego import BicycleEgo
from guardian.errors import ConfigError
from guardian.monitor import ModelMonitor
from guardian.pointmass import PointMassGuardian
from guardian.sensing import bicycle_state, read_road, road_scene

__all__ = ["Guardian", "GuardianConfig"]

LANE_CHANGES = ("LANE_LEFT", "LANE_RIGHT")
ACTION_TYPES = ("ContinuousAction", "DiscreteAction", "DiscreteMetaAction")


def _action_kind(base) -> str:
    """``DiscreteMetaAction`` or ``ContinuousAction`` (highway-env's ``DiscreteAction`` is a grid of the
    latter; either may control one axis only, the env then holds the other at 0)."""
    kind = type(base.action_type).__name__
    if kind not in ACTION_TYPES:
        raise ConfigError(f"Guardian: config 'action.type' {kind!r} cannot be supervised; use one of {ACTION_TYPES}")
    if kind == "DiscreteMetaAction" and list(base.action_type.actions.values()) != \
            ["LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER"]:
        raise ConfigError("Guardian: config 'action' must offer all five meta actions "
                          "('longitudinal' and 'lateral' true)")
    return "DiscreteMetaAction" if kind == "DiscreteMetaAction" else "ContinuousAction"


class _Hook:
    """The ego's ``act`` while supervised: the agent's action goes to the vehicle's own ``act``; every
    simulation step (``act(None)``) the guardian then decides."""

    def __init__(self, guardian: "Guardian", original):
        self.guardian, self.original = guardian, original

    def __call__(self, action=None):
        self.guardian._act(self.original, action)


class Guardian(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Supervises the ego of ``guardian/Overtake-v0``, ``guardian/HighwayOvertake-v0`` or a
    ``highway-v0``-family environment.

    Parameters
    ----------
    env : gymnasium.Env
        The environment (possibly wrapped); its ``unwrapped`` is a highway-env ``AbstractEnv``.
    library : intention.library.OvertakeLibrary, optional
        The overtake RCIS library (the lead part of the overtake scenarios); by default it is loaded
        from the set cache, or built there, for the env's parameters. Unused elsewhere.
    config : GuardianConfig, optional
    """

    def __init__(self, env: gym.Env, library=None, config: GuardianConfig | None = None):
        # recorded as given (env.spec): the library's sets are read-only and large, the config is frozen
        gym.utils.RecordConstructorArgs.__init__(self, library=library, config=config, _disable_deepcopy=True)
        super().__init__(env)
        config = GuardianConfig() if config is None else config
        base = env.unwrapped
        if not isinstance(base, AbstractEnv):
            raise ConfigError(f"Guardian: {type(base).__name__} is not a highway-env environment")
        if not isinstance(config, GuardianConfig):
            raise ConfigError(f"Guardian: config must be a GuardianConfig, got {type(config).__name__}")
        if getattr(env, "render_mode", None) == "rgb_array":  # SDL's offscreen driver: no display looked for
            os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
        self.config = config
        self.scenario = "overtake" if isinstance(base, HighwayOvertakeEnv) else "highway"
        if self.scenario == "overtake":
            if library is None:
                from intention.library import build_library

                library = build_library(params=base.params)
            if library.params != base.params:
                raise ConfigError("Guardian: the library was computed for other OvertakeParams than the env's "
                                  "config 'params'; rebuild it with the env's parameters")
        self.library = library
        self.kind = _action_kind(base)
        self._attached = None       # the ego vehicle the hook sits on
        self._geometry = None       # what the decision object was built for
        self.guard = None
        self._decisions = []
        self._monitor_counts = {"ego": 0, "lead": 0, "traffic": 0}
        self._calls = 0
        self._last_record = None
        if self.scenario == "overtake" or base.road is not None:
            self._build(base)  # refuse a bad road, library or configuration now, not at the first reset

    # ---- attaching to the ego ------------------------------------------------------------------------
    def _build(self, base) -> None:
        """The decision object and monitor for the env's road, frequencies and action type (re-read)."""
        self.kind = _action_kind(base)
        self.road = read_road(base)
        self.dt = 1.0 / base.config["simulation_frequency"]
        c = self.config
        if self.scenario == "overtake":
            p = base.params
            traffic = int(base.config["traffic_count"]) > 0
            key = (self.road, self.dt, traffic, base.config["lateral_scale"])
            if key != self._geometry:
                try:
                    self.guard = PointMassGuardian(self.library, self.road.n_lanes,
                                                   OvertakeEgo.WIDTH / 2 / base.config["lateral_scale"], traffic, c)
                except ValueError as exc:
                    raise ConfigError(f"Guardian: {exc}") from None
                self.monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max, p,
                                            {n: self.library.models[n] for n in ("aggressive", "cautious")},
                                            ego_stops_at_zero=True)
        elif base.vehicle is not None:
            ego = base.vehicle
            max_steer = float(getattr(ego, "MAX_STEERING_ANGLE", np.pi / 3))
            if self.kind == "ContinuousAction":
                max_steer = float(max(abs(s) for s in base.action_type.steering_range))
            key = (self.road, self.dt, self.kind, max_steer, ego.LENGTH, ego.WIDTH)
            if key != self._geometry:
                kin = BicycleEgo(self.dt, c.traffic_accel, ego.LENGTH, ego.WIDTH, self.road.lane_width,
                                 self.road.n_lanes, max_steer)
                self.guard = BicycleGuardian(kin, c, meta=self.kind == "DiscreteMetaAction")
                self.monitor = ModelMonitor(self.dt, (-c.traffic_accel, c.traffic_accel), c.v_max,
                                            ego_kinematics=kin)
        else:
            return  # no ego yet (before the first reset): the road alone was checked
        self._geometry = key

    def _attach(self, base) -> None:
        if base.vehicle is None:
            raise RuntimeError("Guardian: the env has no ego vehicle; call reset() first")
        self._build(base)
        ego = base.vehicle
        ego.act = _Hook(self, ego.act)
        self._agent_command = dict(ego.action)
        self._attached = ego
        self.guard.reset()
        self.monitor.reset()

    def _is_attached(self, base) -> bool:
        ego = base.vehicle
        return ego is not None and ego is self._attached and isinstance(ego.__dict__.get("act"), _Hook) \
            and ego.__dict__["act"].guardian is self

    def start_inside(self) -> bool:
        """Does the present state lie in the guardian's invariant sets (a start it can keep safe)?"""
        base = self.env.unwrapped
        if self.scenario == "overtake":
            return bool(self.guard.inside(base.overtake_state(), road_scene(base, self.road)))
        ego = base.vehicle
        state = bicycle_state(ego)
        lanes = {self.road.itha_lane(i) for i in (set(self.guard.kin.lanes_at(state.y, state.heading)) or {state.lane})}
        speeds, _ = self.guard.traffic.self_safe_speeds(road_scene(base, self.road, lanes))
        return bool(self.guard.kin.accel_for_speeds(state.speed, speeds))

    # ---- gym API --------------------------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        """Reset the env and attach to its ego.

        ``options={"safe_start": True}`` (or ``GuardianConfig.resample_unsafe_start``) draws the start
        again, up to ``start_attempts`` times, until it lies in the guardian's invariant sets; the
        other options go to the env.
        """
        options = dict(options or {})
        resample = bool(options.pop("safe_start", self.config.resample_unsafe_start))
        attempts = 0
        while True:
            attempts += 1
            obs, info = self.env.reset(seed=seed if attempts == 1 else None, options=options or None)
            base = self.env.unwrapped
            self._attach(base)
            inside = self.start_inside()
            if inside or not resample:
                break
            if attempts >= self.config.start_attempts:
                raise RuntimeError(f"Guardian.reset: no start inside the invariant sets in {attempts} attempts")
        self._last_record = None
        assert "guardian" not in info
        info["guardian"] = {"enabled": True, "scenario": self.scenario, "action": self.kind,
                            "start_inside": inside, "start_attempts": attempts}
        return obs, info

    def step(self, action):
        """Supervise ``action`` for one policy step and pass it on.

        Parameters
        ----------
        action
            The agent's action, in the env's action space.

        Returns
        -------
        tuple
            The env's ``(obs, reward, terminated, truncated, info)``; ``info["guardian"]`` holds what
            the guardian did (see the module docstring).
        """
        base = self.env.unwrapped
        reattached = not self._is_attached(base)
        if reattached:
            self._attach(base)
        self._decisions, self._step_notes = [], []
        self._refused_meta = None
        self._monitor_counts = {"ego": 0, "lead": 0, "traffic": 0}
        proposed, applied_action = self._policy_level(base, action)
        frames_before, calls_before, ego_before = base.steps, self._calls, base.vehicle
        obs, reward, terminated, truncated, info = self.env.step(applied_action)
        frames = base.steps - frames_before if base.vehicle is ego_before else 0
        unsupervised = max(frames - (self._calls - calls_before), 0)
        if base.vehicle is not ego_before:  # an inner wrapper reset the env instead of stepping it
            self._attach(base)
            reattached = True
            self._step_notes.append("the env was reset inside the step; re-attached to the new ego")
        if reattached and base.vehicle is ego_before:
            self._step_notes.append("the ego was reset or replaced behind the guardian's back (or before it "
                                    "wrapped the env); re-attached")
        assert "guardian" not in info
        info["guardian"] = record = self._record(base, proposed, reattached, unsupervised)
        if self.config.override_penalty and record["safety_override"]:
            reward -= self.config.override_penalty
            record["penalty"] = self.config.override_penalty
        return obs, reward, terminated, truncated, info

    def _policy_level(self, base, action):
        """Meta lane changes on highway-v0 are decided here, once per policy step."""
        if self.kind != "DiscreteMetaAction":
            return np.asarray(action, dtype=float).tolist(), action
        names = base.action_type.actions
        proposed = names[int(action)]
        if self.scenario == "highway" and proposed in LANE_CHANGES:
            state = bicycle_state(base.vehicle)
            target = state.lane + (-1 if proposed == "LANE_LEFT" else 1)
            scene = road_scene(base, self.road)
            ok, reason = self.guard.policy_lane_change(state, scene, target)
            if not ok:
                self._refused_meta = f"lane change refused: {reason}"
                return proposed, base.action_type.actions_indexes["IDLE"]
        return proposed, action

    # ---- the per-simulation-step supervision ------------------------------------------------------------
    def _act(self, original, action) -> None:
        base = self.env.unwrapped
        ego = base.vehicle
        if action is not None:  # the agent's action, decoded once per policy step
            original(action)
            self._agent_command = dict(ego.action)
            return
        if not isinstance(ego, (ControlledVehicle, OvertakeEgo)):
            ego.action = dict(self._agent_command)  # a plain Vehicle keeps the last command
        original(None)
        if self.scenario == "overtake":
            decision = self._supervise_overtake(base, ego)
        else:
            decision = self._supervise_highway(base, ego, original)
        self._calls += 1
        self._decisions.append(decision)
        for k, n in self.monitor.observe(base, decision.applied).items():
            self._monitor_counts[k] += n

    def _supervise_overtake(self, base, ego):
        u = ego.input.copy()
        applied, decision = self.guard.step(base.overtake_state(), road_scene(base, self.road), u)
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        if decision.refused and ego.meta is not None:
            ego.keep_lane()  # a meta agent's lane change is abandoned
        return decision

    def _supervise_highway(self, base, ego, original):
        proposed = (float(ego.action["acceleration"]), float(ego.action["steering"]))
        state = bicycle_state(ego)
        applied, decision = self.guard.step(state, road_scene(base, self.road), proposed)
        if decision.refused and self.kind == "DiscreteMetaAction":
            ego.target_lane_index = ego.lane_index  # abandon the lane change, steer back
            original(None)
            applied = np.array([applied[0], float(ego.action["steering"])])
            decision.applied = applied.tolist()
        ego.action = {"acceleration": float(applied[0]), "steering": float(applied[1])}
        return decision

    # ---- rendering -------------------------------------------------------------------------------
    def render(self):
        """highway-env's frame with the guardian's panel below it (``rgb_array``); other modes unchanged."""
        frame = self.env.render()
        if not isinstance(frame, np.ndarray):
            return frame
        from guardian.panel import with_panel

        base = self.env.unwrapped
        a = self.config.traffic_accel if self.scenario == "highway" else base.params.a_ex_bounds[1]
        return with_panel(frame, self._last_record or {"active_set": "-", "reasons": ["episode start"]}, (-a, a))

    # ---- info --------------------------------------------------------------------------------------
    def _applied_action(self, base, proposed, ds, inputs):
        """What the vehicle did over the policy step, as an action of the env's own space (so a learner
        can relabel what it proposed): the meta action executed (a refused lane change is ``IDLE``, an
        acceleration held below the proposal ``SLOWER``), or the mean applied input in the action's
        normalised coordinates (a ``DiscreteAction``: the nearest of its grid)."""
        at = base.action_type
        if self.kind == "DiscreteMetaAction":
            name = "IDLE" if self._refused_meta or any(d.refused for d in ds) else proposed
            if any(d.applied[0] < d.proposed[0] - 1e-9 and not d.clipped_to_model for d in ds):
                name = "SLOWER"
            return int(at.actions_indexes[name])
        if not len(ds):
            return None
        mean = inputs.mean(axis=0)
        axes = [(0, at.acceleration_range)] * at.longitudinal + [(1, at.steering_range)] * at.lateral
        unit = np.array([np.clip(2 * (mean[k] - lo) / (hi - lo) - 1, -1.0, 1.0) for k, (lo, hi) in axes])
        if type(at).__name__ == "DiscreteAction":
            grid = np.linspace(-1.0, 1.0, at.actions_per_axis)
            index = 0
            for value in unit:  # itertools.product's order: the first axis varies slowest
                index = index * at.actions_per_axis + int(np.argmin(np.abs(grid - value)))
            return index
        return unit.astype(np.float32).tolist()

    def _record(self, base, proposed, reattached: bool, unsupervised: int) -> dict:
        ds = self._decisions
        last = ds[-1] if ds else None
        reasons = list(self._step_notes)
        if self._refused_meta:
            reasons.append(self._refused_meta)
        for d in ds:
            for r in d.reasons:
                if r not in reasons:
                    reasons.append(r)
        if unsupervised:
            reasons.append(f"{unsupervised} simulation steps ran without the guardian")
        level = max((LEVELS.index(d.level) for d in ds), default=0)
        changed = "none"
        for d in ds:
            if d.changed != "none":
                changed = d.changed
        refused = bool(self._refused_meta) or any(d.refused for d in ds)
        if refused and changed in ("none", "steering"):
            changed = "lane_change" if self.kind == "DiscreteMetaAction" else changed
        inputs = np.array([d.applied for d in ds], dtype=float).reshape(-1, 2)
        applied_action = self._applied_action(base, proposed, ds, inputs)
        applied = proposed
        if self.kind == "DiscreteMetaAction":  # the meta action executed over the whole policy step
            applied = base.action_type.actions[applied_action]
        elif last is not None:
            applied = last.applied
            proposed = last.proposed
        clipped = sum(d.changed != "none" for d in ds)
        model_clips = sum(d.changed != "none" and d.clipped_to_model for d in ds)
        safety = bool(clipped - model_clips or refused)
        lead = getattr(self.guard, "lead", None)
        out = {"proposed": proposed, "applied": applied, "applied_action": applied_action,
               "applied_mean": inputs.mean(axis=0).tolist() if len(ds) else [],
               "applied_range": [[float(inputs[:, k].min()), float(inputs[:, k].max())] for k in range(2)]
               if len(ds) else [],
               "overridden": bool(clipped or refused), "safety_override": safety, "changed": changed,
               "level": LEVELS[level],
               "reasons": reasons, "refused_lane_change": refused,
               "entered": sorted({lane for d in ds for lane in d.entered}),
               "lanes": sorted({lane for d in ds for lane in d.lanes}),
               "active_set": last.active_set if last else "itha",
               "valid_intentions": list(lead.estimator.valid) if lead else [],
               "identified": lead.identified if lead else None,
               "in_invariant_set": bool(ds[0].in_invariant_set) if ds else True,
               "admissible_acceleration": last.admissible_acceleration if last else [],
               "admissible_lateral": last.admissible_lateral if last else [],
               "sim_steps": len(ds), "clipped_steps": clipped, "model_clip_steps": model_clips,
               "follower_dropped_steps": sum(d.level == "follower_dropped" for d in ds),
               "conflict_steps": sum(d.level == "conflict" for d in ds),
               "failsafe_steps": sum(d.level == "failsafe" for d in ds),
               "unsupervised_steps": unsupervised, "reattached": reattached,
               "model_violations": dict(self._monitor_counts)}
        if self.kind == "DiscreteMetaAction":
            out["proposed_input"] = last.proposed if last else None
            out["applied_input"] = last.applied if last else None
        self._last_record = dict(out, proposed_input=last.proposed if last else None,
                                 applied_input=last.applied if last else None)
        return out
