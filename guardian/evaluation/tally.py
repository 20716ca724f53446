"""The counts of a highway-env rollout, each by a written rule (``HighwayTally.result``)."""
from __future__ import annotations

import numpy as np

from envs.highway_overtake import HighwayOvertakeEnv
from guardian.adapters.highway_env.checks import controlled_vehicles, multi_agent
from guardian.adapters.highway_env.monitor import ModelMonitor
from guardian.adapters.highway_env.road import read_road
from guardian.adapters.highway_env.scene import road_scene
from guardian.decide.overtake import PointMassGuardian
from guardian.decide.traffic import TrafficSupervisor
from guardian.evaluation.episodes import Observer
from guardian.evaluation.judge import FaultJudge, body_lanes
from guardian.model.roads import RoadMap
from intention.estimator import IntentionEstimator
from intention.models import intention_models, unclip_standstill
from itha.actuator import RateLimitedSet
from itha.car_following import CarFollowingParams

COUNTS = ("episodes", "steps", "collisions", "ego_at_fault_collisions", "starts_outside",
          "collisions_after_outside_starts", "ego_at_fault_after_outside_starts", "safety_violations",
          "override_steps", "model_clip_steps", "refused_lane_changes", "clipped_sim_steps", "lane_changes",
          "model_violation_steps", "traffic_model_violation_steps", "traffic_blind_steps",
          "traffic_reversing_uncovered_steps", "follower_dropped_steps",
          "conflict_steps",
          "failsafe_steps", "unchecked_entries", "reversing_steps", "unsupervised_steps", "reattachments",
          "episodes_cut", "actuator_clipped_steps")
MULTI_COUNTS = ("guarded_pair_collisions", "merges", "on_ending_lane")
CAR_COUNTS = ("collisions", "at_fault_collisions", "lane_changes", "override_steps", "refused_lane_changes",
              "merges", "on_ending_lane")


class HighwayTally(Observer):
    """Counts of a highway-env rollout, each by a written rule (see ``result``).

    Parameters
    ----------
    env : gymnasium.Env
        The rollout's environment (wrapped in the ``Guardian`` when ``guardian``).
    guardian : bool
        The env is guarded.
    config : GuardianConfig
        The run's configuration: the bounds the counts are taken with (the guardian's own, or those it
        would have had).
    library : intention.library.OvertakeLibrary, optional
        The overtake sets (an unguarded overtake run's starts are judged by them).
    recorder : optional
        Told of every step (``guardian.recording.rerun.GuardianRecorder``).
    """

    def __init__(self, env, guardian: bool, config, library=None, recorder=None):
        self.overtake = isinstance(env.unwrapped, HighwayOvertakeEnv)
        self.guardian, self.config, self.recorder = guardian, config, recorder
        self.library, self._aside = library, None
        self.estimator = None
        if self.overtake:
            self._watch_the_lead(env)
        self.totals = {k: 0 for k in COUNTS}
        self.totals["crashes"] = []
        self.totals["cut_episodes"] = []
        if self.overtake:
            self.totals.update(wrong_identifications=0, safe_set_exits=0, collisions_after_safe_set_exit=0,
                               ego_at_fault_after_safe_set_exit=0, lead_departures=0)
        self.identify, self.distance, self.monitor_worst = [], 0.0, {}
        self.per_car = None          # per controlled car (several): CAR_COUNTS and distance
        self.multi = False
        self.actuated = False        # the world fits an actuator (envs.actuator.JerkLimit): its clips are counted

    def _watch_the_lead(self, env) -> None:
        models = intention_models(env.unwrapped.params)
        candidates = {n: models[n] for n in ("aggressive", "cautious")}
        self.estimator = IntentionEstimator(candidates, horizon=self.config.horizon)
        self.monitor = None
        if not self.guardian:  # the guardian's own monitor counts when it is there
            g = self.config
            self.monitor = ModelMonitor(env.unwrapped.params.dt, (-g.traffic_accel, g.traffic_accel), g.v_max,
                                        env.unwrapped.params, candidates, ego_stops_at_zero=True,
                                        reversing=g.reversing)

    def start_episode(self, env, episode, obs) -> None:
        base = env.unwrapped
        if self.estimator is not None:
            self.estimator.reset()
        if self.overtake and self.monitor is not None:
            self.monitor.reset()
        if self.recorder is not None:
            self.recorder.start_episode(env, episode)
        self.episode, self.t = episode, 0
        self.exited = self.departed = False
        self.road = read_road(base)
        self.on_map = isinstance(self.road, RoadMap)
        self.cars = controlled_vehicles(base)
        self.last_blind = [None] * len(self.cars)
        self.multi = multi_agent(base)
        if self.multi and self.per_car is None:
            self.per_car = [dict({k: 0 for k in CAR_COUNTS}, distance=0.0) for _ in self.cars]
        self.x0 = [self._along(v) for v in self.cars]
        self.ending = {slot for slot, _ in self.road.ends} if self.on_map else set()
        self.began_ending = [self._slot(v) in self.ending for v in self.cars]
        self.judge = FaultJudge.for_env(base, 1.0 / base.config["policy_frequency"])
        self.judge.start(base, self.cars)
        self.slots = [self._body_slots(v) for v in self.cars] if self.on_map else None
        self.checkers = None if self.overtake else [_SelfSafetyCheck(base, self.road, v, self.multi, self.config)
                                                     for v in self.cars]
        self.inside = self._start_inside(env, base)
        self.totals["starts_outside"] += int(not self.inside)

    def _along(self, v) -> float:
        """Position along the road (along the lane's chain on a RoadMap)."""
        x = float(v.position[0])
        return self.road.longitudinal(v.lane_index, x, float(v.position[1])) if self.on_map else x

    def _slot(self, v) -> int:
        return self.road.slot_of(v.lane_index) if self.on_map else v.lane_index[2]

    def _body_slots(self, v) -> frozenset:
        return self.road.body_slots(float(v.position[0]), float(v.position[1]), float(v.heading), v.LENGTH, v.WIDTH)

    def _start_inside(self, env, base) -> bool:
        """The guardian's own test; without it, the same sets' test on a guardian built aside."""
        if self.guardian:
            return bool(env.get_wrapper_attr("start_inside")())
        if self.overtake:
            if self._aside is None:
                self._aside = PointMassGuardian(self.library, self.road.n_lanes,
                                                base.vehicle.WIDTH / 2 / base.config["lateral_scale"],
                                                int(base.config["traffic_count"]) > 0, self.config)
            return bool(self._aside.inside(base.overtake_state(), road_scene(base, self.road)))
        return all(c.inside(base) for c in self.checkers)

    def before_step(self, env, obs, action) -> None:
        self.lanes_before = [self._slot(v) for v in self.cars]

    def after_step(self, env, obs, action, info) -> None:
        base, totals = env.unwrapped, self.totals
        self.t += 1
        g = info.get("guardian")
        records = (g["agents"] if self.multi else [g]) if g else [None] * len(self.cars)
        totals["steps"] += 1
        if "actuator" in info:
            self.actuated = True
            totals["actuator_clipped_steps"] += info["actuator"]["clipped_steps"]
        for i, (v, r) in enumerate(zip(self.cars, records)):
            changed = int(self._slot(v) != self.lanes_before[i])
            totals["lane_changes"] += changed
            _count_step(totals, r)
            if r and r["model_violations"]["traffic_blind"]:
                self.last_blind[i] = self.t
            if self.multi:
                self.per_car[i]["lane_changes"] += changed
                if r:
                    self.per_car[i]["override_steps"] += int(r["safety_override"])
                    self.per_car[i]["refused_lane_changes"] += int(r["refused_lane_change"])
        if g:
            totals["reattachments"] += int(g["reattached"])
        entries_before = [len(e) for e in self.judge.car_entries]
        crashes = self.judge.observe_all(base)
        for i, (v, r) in enumerate(zip(self.cars, records)):
            if self.on_map:  # entries into slots (the judge's lines are not the guardian's lanes)
                now = self._body_slots(v)
                entered = [self.road.numbering.itha(k) for k in now - self.slots[i]]
                self.slots[i] = now
            else:
                entered = [self.road.numbering.itha(lane) for _, lane in self.judge.car_entries[i][entries_before[i]:]]
            if r is not None:
                held = set(r["lanes"]) | set(r["entered"])
                totals["unchecked_entries"] += sum(lane not in held for lane in entered)
            totals["reversing_steps"] += int(v.speed < -1e-9)
        if self.overtake:
            tr = base.last_transition
            self.estimator.update(tr["state"], tr["input"], unclip_standstill(base.params, tr["state"], tr["input"],
                                                                              tr["next_state"]))
            if self.monitor is not None:
                totals["model_violation_steps"] += int(sum(self.monitor.overtake_transition(
                    tr["state"], tr["input"], tr["next_state"])) > 0)
            totals["safety_violations"] += int(info["unsafe"])
            totals["safe_set_exits"] += int(info["unsafe"] and not self.exited)
            totals["lead_departures"] += int(info["lead_departed"] and not self.departed)
            self.exited, self.departed = self.exited or info["unsafe"], self.departed or info["lead_departed"]
        else:
            totals["safety_violations"] += sum(not c.inside(base) for c in self.checkers)
        if self.recorder is not None:
            self.recorder.log(env, self.episode, self.t, g)
        for crash in crashes:
            self._count_crash(crash, records[crash.car] or {})

    def _count_crash(self, crash, g: dict) -> None:
        totals = self.totals
        totals["collisions"] += 1
        at_fault = crash.guarded_at_fault
        if self.inside:
            totals["ego_at_fault_collisions"] += int(at_fault)
        else:
            totals["collisions_after_outside_starts"] += 1
            totals["ego_at_fault_after_outside_starts"] += int(at_fault)
        row = {"episode": self.episode, "step": self.t, "fault": crash.fault, "rule": crash.rule,
               "partner": crash.partner, "start_inside": self.inside,
               "level": g.get("level"), "reasons": g.get("reasons", [])}
        if self.overtake:
            row.update(after_safe_set_exit=self.exited, lead_departed=self.departed)
            totals["collisions_after_safe_set_exit"] += int(self.exited)
            totals["ego_at_fault_after_safe_set_exit"] += int(self.exited and at_fault)
        if self.guardian:
            blind = self.last_blind[crash.car]
            row["steps_since_traffic_blind"] = None if blind is None else self.t - blind
        if self.multi:
            row.update({"car": crash.car, "partner_car": crash.partner_car})
            totals["guarded_pair_collisions"] = totals.get("guarded_pair_collisions", 0) + int(
                crash.partner_car is not None)
            for i in {crash.car} | ({crash.partner_car} if crash.partner_car is not None else set()):
                self.per_car[i]["collisions"] += 1
            blamed = crash.car if crash.fault == "ego" else crash.partner_car
            if blamed is not None:
                self.per_car[blamed]["at_fault_collisions"] += 1
        totals["crashes"].append(row)

    def cut_episode(self, env, episode) -> None:
        self.totals["episodes_cut"] += 1
        self.totals["cut_episodes"].append(episode)

    def end_episode(self, env, episode) -> None:
        base = env.unwrapped
        if self.estimator is not None and self.estimator.identified_at is not None:
            self.identify.append(self.estimator.identified_at)
            self.totals["wrong_identifications"] += int(self.estimator.valid != [base.model.name])
        for i, v in enumerate(self.cars):
            d = self._along(v) - self.x0[i]
            merged = self.began_ending[i] and self._slot(v) not in self.ending
            self.distance += d / len(self.cars)
            if self.on_map:
                self.totals["merges"] = self.totals.get("merges", 0) + int(merged)
                self.totals["on_ending_lane"] = self.totals.get("on_ending_lane", 0) + int(self.began_ending[i])
            if self.multi:
                self.per_car[i]["distance"] += d
                self.per_car[i]["merges"] += int(merged)
                self.per_car[i]["on_ending_lane"] += int(self.began_ending[i])
        if self.guardian:
            for car in env.get_wrapper_attr("cars"):
                for k, v in car.monitor.worst.items():
                    self.monitor_worst[k] = max(self.monitor_worst.get(k, 0.0), v)

    def close(self) -> None:
        if self.recorder is not None:
            self.recorder.close()

    def result(self, episodes: int) -> dict:
        """The counts, each by its rule.

        * ``collisions``: crashes of guarded cars (highway-env's crash flag, which also fires on its
          one-step extrapolation of the bodies); with one ego, episodes whose ego crashed; with several
          controlled cars, a crash between two of them counts once. ``ego_at_fault_collisions``: of those in
          episodes starting inside the guardian's invariant sets (every guarded car's start), the ones
          ``guardian.evaluation.judge.FaultJudge`` gives to a guarded car (the one judged, or a guarded partner); crashes
          after a start outside are counted apart (``collisions_after_outside_starts``,
          ``ego_at_fault_after_outside_starts``). ``starts_outside``: episodes whose start lay outside the
          sets for some guarded car (with the guardian, its own test; without, self-safety towards the cars
          ahead).
        * ``safety_violations``: steps ending outside the safe set (6.8) (HighwayOvertake) or with no
          self-safe input left (highway-env roads; per guarded car), with or without the guardian.
        * HighwayOvertake: ``safe_set_exits``: episodes whose state left the safe set (6.8) (the episode ends
          there unless the env's ``terminate_when_unsafe`` is false); ``collisions_after_safe_set_exit`` and
          ``ego_at_fault_after_safe_set_exit``: collisions in an episode after its exit (each crash row says
          ``after_safe_set_exit``), whatever the start; ``lead_departures``: episodes whose lead left its
          intention model (the env's ``lead_departure``; crash rows say ``lead_departed``).
        * ``unchecked_entries``: lanes a guarded car's body began to overlap in a step whose record lists the
          lane neither among the lanes the guardian held the car in at the step's start nor among the
          entries it checked and found responsible during the step (``guardian.wrappers.record.allowed_lanes``; on
          roads beyond one straight segment: slots of ``guardian.model.roads``, the body unwidened).
        * ``traffic_blind_steps``: policy steps in which some traffic car did not see a guarded car its
          model has it react to (``guardian.adapters.highway_env.blindness.traffic_blind_to``: highway-env's v0 roads search one
          lane segment; per guarded car); each crash row's ``steps_since_traffic_blind`` counts the policy
          steps since the crashed car's last such step (None: none this episode). Guarded runs only.
        * ``traffic_reversing_uncovered_steps``: policy steps in which some traffic car had backed up further
          than the guardian covers (``GuardianConfig.reversing``; ``guardian.adapters.highway_env.monitor``). Guarded runs only.
        * ``reversing_steps``: steps ending with a negative speed (per guarded car). ``unsupervised_steps``:
          simulation steps the guardian's hook did not see. ``reattachments``: steps at which the
          guardian found the ego reset or replaced behind its back.
        * ``override_steps``: policy steps the guardian changed for safety; ``model_clip_steps``:
          simulation steps whose only change was a clip to the model's bounds (highway-env's top speed);
          ``clipped_sim_steps``, ``refused_lane_changes``, ``follower_dropped_steps``, ``conflict_steps``,
          ``failsafe_steps``: from ``info["guardian"]``; ``lane_changes``: policy
          steps whose lane index (slot) changed; ``distance_mean``: mean distance along the road per episode
          and guarded car. With several guarded cars every per-step count is summed over the cars.
        * On roads beyond one straight segment: ``on_ending_lane``: guarded cars that began an episode on a
          lane that ends (an on-ramp's); ``merges``: those of them on a lane that goes on at the episode's end.
        * ``actuator_clipped_steps``: simulation steps in which a controlled car's actuator could not follow the
          acceleration it was given (``envs.actuator.JerkLimit``; None without one). With the guardian it asks only
          for what the actuator reaches: a nonzero count is a defect.
        * ``episodes_cut``: episodes the env had not ended (no crash, no time limit) when the rollout's time cap
          (``Rollout.max_seconds``) stopped them; ``cut_episodes`` lists them. What would have happened after
          the cap is not seen: a cut episode is never counted as safe, it is counted apart.
        * With several controlled cars: ``guarded_cars``, ``guarded_pair_collisions`` (crashes between two
          guarded cars) and ``agents``: per car (in highway-env's controlled order) its collisions,
          at-fault collisions, lane changes, overrides, refusals, merges and mean distance.
        """
        totals = self.totals
        totals["episodes"] = episodes
        totals["distance_mean"] = self.distance / episodes
        if not self.actuated:
            totals["actuator_clipped_steps"] = None
        if not self.guardian:  # measured only by the guardian's monitor (and, on HighwayOvertake, from the env)
            for k in ("traffic_model_violation_steps", "traffic_blind_steps", "traffic_reversing_uncovered_steps"):
                totals[k] = None
            if not self.overtake:
                totals["model_violation_steps"] = None
            for k in ("unchecked_entries", "unsupervised_steps", "reattachments",
          "episodes_cut"):
                totals[k] = None
        if self.guardian:
            totals["traffic_model_worst"] = {k: round(v, 6) for k, v in self.monitor_worst.items()}
        if self.overtake:
            ident = self.identify
            totals["mean_steps_to_identify_intention"] = float(np.mean(ident)) if ident else None
            totals["identified_fraction"] = len(ident) / episodes
        if self.multi:
            totals["guarded_cars"] = len(self.per_car)
            totals.setdefault("guarded_pair_collisions", 0)
            totals["agents"] = [dict({k: c[k] for k in CAR_COUNTS}, distance_mean=c["distance"] / episodes)
                                for c in self.per_car]
        return totals


class _SelfSafetyCheck:
    """Whether a guarded car has a self-safe input (7.4) towards the cars ahead in its lanes (and, on a
    ``RoadMap``, its lane's end)."""

    def __init__(self, base, road, car, multi: bool, config):
        c = config
        self.dt = 1.0 / base.config["simulation_frequency"]
        self.road, self.accel, self.reversing = road, c.traffic_accel, c.reversing
        self.car = base.vehicle if car is None else car
        self.actuator = getattr(self.car, "actuator", None)
        self.guarded = frozenset(id(v) for v in controlled_vehicles(base)) if multi else frozenset()
        params = CarFollowingParams(dt=self.dt, v_max=c.v_max, h_min=c.h_min, u_min=-c.traffic_accel,
                                    u_max=c.traffic_accel, d_min=-c.traffic_accel, d_max=c.traffic_accel)
        self.traffic = TrafficSupervisor(params, wreck_margin=c.wreck_margin)
        self.ego_set = None if self.actuator is None else RateLimitedSet(params, self.actuator)

    def inside(self, base) -> bool:
        ego = self.car
        if isinstance(self.road, RoadMap):
            lanes = self.road.body_slots(float(ego.position[0]), float(ego.position[1]), float(ego.heading),
                                         ego.LENGTH, ego.WIDTH) or {self.road.slot_of(ego.lane_index)}
        else:
            lanes = body_lanes(ego, self.road.lane_width, self.road.n_lanes) or {ego.lane_index[2]}
        scene = road_scene(base, self.road, self.road.numbering.itha_set(lanes), ego=ego, guarded=self.guarded,
                           reversing=self.reversing)
        v = float(ego.speed)
        if self.ego_set is not None:   # the speeds the actuator reaches, the set bound to the car's state
            bound = self.ego_set.bound(v, float(ego.applied_acceleration))
            speeds, _ = self.traffic.with_ego_set(bound).self_safe_speeds(scene)
            return bool(speeds)
        speeds, _ = self.traffic.self_safe_speeds(scene)
        reach = self.accel * self.dt
        return any(max(lo, v - reach) <= min(hi, v + reach) for lo, hi in speeds)


def _count_step(totals: dict, g: dict | None) -> None:
    if not g:
        return
    totals["override_steps"] += int(g["safety_override"])
    totals["model_clip_steps"] += g["model_clip_steps"]
    totals["refused_lane_changes"] += int(g["refused_lane_change"])
    totals["clipped_sim_steps"] += g["clipped_steps"]
    mv = g["model_violations"]
    totals["model_violation_steps"] += int(mv["ego"] + mv["lead"] > 0)
    totals["traffic_model_violation_steps"] += int(mv["traffic"] > 0)
    totals["traffic_blind_steps"] += int(mv["traffic_blind"] > 0)
    totals["traffic_reversing_uncovered_steps"] += int(mv["traffic_reversing_uncovered"] > 0)
    for k in ("follower_dropped_steps", "conflict_steps", "failsafe_steps", "unsupervised_steps"):
        totals[k] += g[k]

