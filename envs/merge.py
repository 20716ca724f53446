"""``guardian/Merge-v0``: highway-env's on-ramp merge (``merge-v0``'s road) for both action types and many
controlled cars.

highway-env's ``merge-v0`` spawns one controlled car and computes its reward from a discrete action
(``MergeEnv._rewards``: ``action in [0, 2]``), so it fails with ``ContinuousAction`` and cannot hold
several guarded cars. This env is ``merge-v0``'s road (two main lanes, an on-ramp whose parallel part
ends at an obstacle) with:

* ``traffic: "merge-v0"`` (the default): ``merge-v0``'s own cars (the ego on the right main lane at
  30 m/s, three IDM cars on the main road, one merging from the ramp) and its end (the ego past
  x = 370), with one controlled car;
* ``traffic: "easy" | "medium" | "hard"``: the traffic modes of the on-ramp merging reference
  (Chen et al., *Deep multi-agent reinforcement learning for highway on-ramp merging in mixed traffic*,
  github.com/DongChen06/MARL_CAVs, ``merge_env_v1.py``: easy 1-3, medium 2-4, hard 3-5 uncontrolled
  IDM cars; speeds 25-27 m/s; positions on spawn points with +-1.5 m of noise; half of the cars of each
  kind on the ramp; the reference runs 20 s at 5 Hz: ``benchmarks/bench_multiagent.py`` sets that, on the
  command line ``--env-config duration=20 --env-config policy_frequency=5``). ``controlled_vehicles`` cars are controlled (the reference's CAVs,
  whose number it draws per mode; here it is the experiment's N). The reference's road has one main
  lane; this one has ``merge-v0``'s two, so the main-road spawn points are on both lanes (every 40 m
  from 10 m, as the reference's), and the ramp's every 30 m from 5 m (the reference's are 40 m apart
  from 5 m; 30 m leaves room for 8 guarded cars among 5 others) on the ramp's own lanes;
* a reward that takes both action types (``merge-v0``'s, of the first controlled car; a lane change is
  a change of lane index for continuous actions), and ``duration`` [s] after which an episode is
  truncated (``merge-v0`` itself has none: an agent that stops would never end it).

Traffic finds the car ahead and behind across lane segments (highway-env's
``neighbour_vehicles_connected_lanes``, what its ``merge-v1`` sets): with ``merge-v0``'s search a car near
a segment's end does not see a car on the next segment, brakes for it too late and changes lanes in front
of it (docs/roads.md). ``neighbour_vehicles_connected_lanes: False`` gives ``merge-v0``'s search back.

Episodes end (terminated) when a controlled car crashes, or in the ``merge-v0`` traffic when the ego has
passed x = 370 as there.
"""
from __future__ import annotations

import numpy as np
from highway_env import utils
from highway_env.envs.merge_env import MergeEnv

TRAFFIC_MODES = {"easy": (1, 3), "medium": (2, 4), "hard": (3, 5)}   # uncontrolled cars, drawn uniformly
MAIN_SPAWN = tuple(range(10, 211, 40))       # [m] on each main lane
RAMP_SPAWN = tuple(range(5, 216, 30))        # [m] along the ramp (its approach, then its sine part)


class GuardedMergeEnv(MergeEnv):
    """``merge-v0``'s road for both action types and ``controlled_vehicles`` cars (module docstring)."""

    @classmethod
    def default_config(cls) -> dict:
        cfg = super().default_config()
        cfg.update({"traffic": "merge-v0", "controlled_vehicles": 1, "duration": 40,
                    "neighbour_vehicles_connected_lanes": True})
        return cfg

    def _reset(self) -> None:
        traffic = self.config["traffic"]
        if traffic != "merge-v0" and traffic not in TRAFFIC_MODES:
            raise ValueError(f"guardian/Merge-v0: config 'traffic' {traffic!r} is not one of "
                             f"merge-v0, {', '.join(TRAFFIC_MODES)}")
        n = int(self.config["controlled_vehicles"])
        if n < 1:
            raise ValueError(f"guardian/Merge-v0: config 'controlled_vehicles' must be at least 1, got {n}")
        if traffic == "merge-v0" and n != 1:
            raise ValueError("guardian/Merge-v0: the 'merge-v0' traffic has one controlled car; choose traffic "
                             "easy, medium or hard for several")
        self._lanes_before = None
        super()._reset()

    def _make_vehicles(self) -> None:
        if self.config["traffic"] == "merge-v0":
            super()._make_vehicles()
            self.controlled_vehicles = [self.vehicle]
            return
        road, rng = self.road, self.np_random
        n = int(self.config["controlled_vehicles"])
        lo, hi = TRAFFIC_MODES[self.config["traffic"]]
        n_hdv = int(rng.integers(lo, hi + 1))
        main = [(lane, x) for lane in (0, 1) for x in MAIN_SPAWN]
        ramp = list(RAMP_SPAWN)
        on_ramp = [n - n // 2, n_hdv - n_hdv // 2]   # as the reference: the larger half on the ramp
        on_main = [n // 2, n_hdv // 2]
        if sum(on_ramp) > len(ramp) or sum(on_main) > len(main):
            raise ValueError(f"guardian/Merge-v0: {n} controlled and {n_hdv} other cars do not fit the spawn points")
        main_picks = [main[k] for k in rng.choice(len(main), sum(on_main), replace=False)]
        ramp_picks = [ramp[k] for k in rng.choice(len(ramp), sum(on_ramp), replace=False)]
        other = utils.class_from_path(self.config["other_vehicles_type"])
        self.controlled_vehicles = []

        def spawn(cls, where, controlled):
            speed = 25.0 + 2.0 * rng.uniform()
            noise = 3.0 * rng.uniform() - 1.5
            if where[0] == "ramp":
                s = where[1] + noise
                lane = road.network.get_lane(("j", "k", 0)) if s <= 150 else road.network.get_lane(("k", "b", 0))
                position = lane.position(s if s <= 150 else s - 150, 0.0)
                heading = lane.heading_at(s if s <= 150 else s - 150)
            else:
                lane = road.network.get_lane(("a", "b", where[0]))
                position, heading = lane.position(where[1] + noise, 0.0), 0.0
            v = cls(road, position, heading=heading, speed=speed)
            road.vehicles.append(v)
            if controlled:
                self.controlled_vehicles.append(v)

        places = [("main",) + p for p in main_picks]
        for i in range(on_main[0]):
            spawn(self.action_type.vehicle_class, (places[i][1], places[i][2]), True)
        for i in range(on_ramp[0]):
            spawn(self.action_type.vehicle_class, ("ramp", ramp_picks[i]), True)
        for i in range(on_main[0], on_main[0] + on_main[1]):
            spawn(other, (places[i][1], places[i][2]), False)
        for i in range(on_ramp[0], on_ramp[0] + on_ramp[1]):
            spawn(other, ("ramp", ramp_picks[i]), False)

    def _rewards(self, action) -> dict:
        if isinstance(action, tuple):  # several controlled cars: the first car's
            action = action[0]
        if np.ndim(action) == 0:
            changed = int(action) in (0, 2)
        else:  # a continuous action: a change of lane index
            lane = self.vehicle.lane_index[2]
            changed = self._lanes_before is not None and lane != self._lanes_before
            self._lanes_before = lane
        out = super()._rewards(0)
        out["lane_change_reward"] = changed
        return out

    def _is_terminated(self) -> bool:
        crashed = any(v.crashed for v in self.controlled_vehicles)
        if self.config["traffic"] == "merge-v0":
            return crashed or bool(self.vehicle.position[0] > 370)
        return crashed

    def _is_truncated(self) -> bool:
        return self.time >= self.config["duration"]
