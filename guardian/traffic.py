"""The ITHA part of the guardian: self-safety (7.4) and responsibility (7.5) against traffic.

A plain decision object (no simulator): it receives a ``Scene`` — the ego and the
other cars as ITHA agents (front-bumper position along the road, speed, the lanes
each occupies, length; lane 1 is the rightmost) — and answers in the ego's *next
speed*, so that each ego kinematics (``guardian.ego``) converts the answer to its
own input exactly:

* ``self_safe_speeds``: next speeds keeping the ego in the car-following RCIS with
  respect to the nearest car ahead in every lane it occupies (7.4);
* ``follower_speeds``: next speeds keeping the nearest car behind in a lane the ego
  is entering in its RCIS whatever that car does (the ego answers for it while the
  entry lasts, as a reset does in ITHA);
* ``entry``: whether entering a lane is ρ̂-responsible (Definition 22, via
  ``itha.responsibility.EgoSupervisor``), with the next speeds that make it so.

A car that is changing lanes occupies both lanes. Under the ordered ρ̂ the cars that announce (other
guarded cars: each is where it is, or where it has announced it goes, and those after the ego in
Example 8's order yield) are exact; every other car is over-approximated as the trivial ρ̂ does.
"""
from __future__ import annotations

from dataclasses import dataclass

from guardian.scene import Car, Scene  # noqa: F401 (the scene the decisions read)
from itha.car_following import CarFollowingParams, MaximalSet
from itha.responsibility import EgoSupervisor
from itha.road import LEFT, RIGHT, HighwayParams
from rcis.intervals import intersect_intervals


@dataclass(frozen=True)
class EntryVerdict:
    lane: int
    responsible: bool
    speeds: list        # next ego speeds that keep the entry responsible
    reason: str


class TrafficSupervisor:
    """Self-safety and responsibility of the ego among traffic (Chapter 7) for one set of bounds."""

    def __init__(self, params: CarFollowingParams, others: CarFollowingParams | None = None,
                 overapprox: str = "trivial"):
        """``params``: the ego's bounds (its braking ``u_min``, its leaders' ``d_min``); ``others``: the
        traffic's (their braking and acceleration, their leaders' — possibly the ego's — braking)."""
        self.params = params
        self.others = params if others is None else others
        self.S = MaximalSet(params)
        self.S_others = self.S if others is None else MaximalSet(self.others)
        self.overapprox = overapprox

    def _speed_range(self) -> list:
        return [(0.0, self.params.v_max)]

    def leader(self, scene: Scene, lane: int):
        return scene.leader(lane)

    def follower(self, scene: Scene, lane: int):
        return scene.follower(lane)

    def self_safe_speeds(self, scene: Scene) -> tuple[list, str]:
        """Next ego speeds that are self-safe (7.4) against the nearest car ahead in each occupied lane."""
        allowed = self._speed_range()
        for lane, car, speeds in self.leader_speeds(scene):
            allowed = intersect_intervals(allowed, speeds)
            if not allowed:
                return [], f"too close to {car.name or 'the car'} ahead in lane {lane}"
        return allowed, ""

    def leader_speeds(self, scene: Scene) -> list:
        """``[(lane, car, next ego speeds self-safe towards it), ...]`` for the nearest car ahead in each
        lane the ego occupies (the parts of ``self_safe_speeds``, to say which car limits the ego)."""
        p, ego = self.params, scene.ego
        out = []
        for lane in sorted(ego.lanes):
            car = self.leader(scene, lane)
            if car is None:
                continue
            gap = car.front - car.length - ego.front
            h_next = gap + p.dt * (min(car.speed, p.v_max) - ego.speed)
            out.append((lane, car, self.S.speed_intervals(h_next, float(p.worst_lead_speed(min(car.speed, p.v_max))))))
        return out

    def follower_speeds(self, scene: Scene, lane: int, ego_progress_min: float | None = None) -> tuple[list, str]:
        """Next ego speeds keeping the nearest car behind in ``lane`` in its RCIS, whatever it does.

        ``ego_progress_min`` is the least distance the ego covers this step (default ``dt v``).
        """
        p, ego = self.others, scene.ego
        car = self.follower(scene, lane)
        if car is None:
            return self._speed_range(), ""
        progress = p.dt * ego.speed if ego_progress_min is None else ego_progress_min
        gap = (ego.front + progress) - ego.length - (car.front + p.dt * car.speed)
        v_fast = min(car.speed + p.dt * p.u_max, p.v_max)
        speeds = self.S_others.lead_speed_intervals(v_fast, gap)
        return speeds, "" if speeds else f"{car.name or 'the car'} behind in lane {lane} cannot stay safe"

    def entry(self, scene: Scene, lane: int) -> EntryVerdict:
        """Is entering ``lane`` from the ego's (single) current lane ρ̂-responsible (7.5)?"""
        ego = scene.ego
        if len(ego.lanes) != 1:
            raise ValueError(f"entry is decided from one lane; the ego occupies {sorted(ego.lanes)}")
        (home,) = ego.lanes
        if not 1 <= lane <= scene.n_lanes:
            return EntryVerdict(lane, False, [], "no such lane")
        if abs(lane - home) != 1:
            raise ValueError(f"lane {lane} is not next to lane {home}")
        p, v, ln, lengths = [ego.front], [min(ego.speed, self.params.v_max)], [home], [ego.length]
        silent = set()
        for c in scene.others:
            for k in sorted(c.lanes):
                if not c.announces:
                    silent.add(len(p))
                p.append(c.front)
                v.append(min(max(c.speed, 0.0), self.params.v_max))
                ln.append(k)
                lengths.append(c.length)
        prm = HighwayParams(car_following=self.params, n_lanes=scene.n_lanes, n_cars=len(p) - 1,
                            car_length=ego.length, ego_lane=home)
        sup = EgoSupervisor(prm, self.S, self.overapprox, others_invariant=self.S_others)
        speeds, reason = sup.lane_change_speeds(p, v, ln, 0, LEFT if lane > home else RIGHT, {}, lengths, silent)
        return EntryVerdict(lane, bool(speeds), speeds, reason)

