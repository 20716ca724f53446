"""The ITHA part of the guardian: self-safety (7.4) and responsibility (7.5) against traffic.

A plain decision object (no simulator): it receives a ``Scene`` — the ego and the
other cars as ITHA agents (front-bumper position along the road, speed, the lanes
each occupies, length; lane 1 is the rightmost) — and answers in the ego's *next
speed*, so that each ego kinematics (``guardian.decide.kinematics``) converts the answer to its
own input exactly:

* ``self_safe_speeds``: next speeds keeping the ego in the car-following RCIS with
  respect to the nearest car ahead in every lane it occupies (7.4), and to every car ahead whose body
  overlaps that car's along the road (``Scene.leaders``); towards a car *at risk*
  (``at_risk``: it has crashed, or it may crash into the car it follows) the ego keeps to where
  it can stop behind that car standing still after this step, ``wreck_margin`` further back;
* ``follower_speeds``: next speeds keeping the nearest car behind in a lane the ego
  is entering (and any car behind whose body overlaps it along the road) in its RCIS whatever
  that car does (the ego answers for it while the entry lasts, as a reset does in ITHA);
* ``entry``: whether entering a lane is ρ̂-responsible (Definition 22, via
  ``itha.responsibility.EgoSupervisor``), with the next speeds that make it so.

A car that is changing lanes occupies both lanes. Under the ordered ρ̂ the cars that announce (other
guarded cars: each is where it is, or where it has announced it goes, and those after the ego in
Example 8's order yield) are exact; every other car is over-approximated as the trivial ρ̂ does.

Wrecks. The car-following set (7.3) assumes the car ahead brakes by at most ``d_min``; a car that
runs into the car it follows stops faster (highway-env takes a crashed car's speed down by ``v`` m/s^2,
HighwayOvertake's traffic stops at once) and is pushed back by the impact. The traffic model does not
say the other cars stay out of each other, so the guardian flags the cars that might not
(``at_risk``) and treats each as able to stop at once: a crashed car; a car outside the
car-following set behind a car it follows in some lane (``Scene.leads_of``); a car that cannot
stop behind a car at risk (the same rule, one car further back). A car that follows safely a car that is not at risk
is trusted to stay out of it: what remains (a car inside its set that brakes too late) is counted as
the traffic model violation it is.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

from guardian.model.scene import Car, Scene  # noqa: F401 (the scene the decisions read)
from itha.car_following import CarFollowingParams, MaximalSet
from itha.responsibility import EgoSupervisor, far_enough
from itha.road import LEFT, RIGHT, HighwayParams
from rcis.intervals import intersect_intervals


@dataclass(frozen=True)
class EntryVerdict:
    lane: int
    responsible: bool
    speeds: list        # next ego speeds that keep the entry responsible
    reason: str


def _gap(follower: Car, lead: Car) -> float:
    """Bumper-to-bumper headway of (7.3) from ``follower`` to ``lead`` (fronts along the lane)."""
    return lead.front - lead.length - follower.front


def _gap_after_step(p: CarFollowingParams, follower: Car, lead: Car) -> float:
    """The headway after one step with both cars at their speeds now (the lead's clipped to ``v_max``)."""
    return _gap(follower, lead) + p.dt * (min(lead.speed, p.v_max) - follower.speed)


class TrafficSupervisor:
    """Self-safety and responsibility of the ego among traffic (Chapter 7) for one set of bounds."""

    def __init__(self, params: CarFollowingParams, others: CarFollowingParams | None = None,
                 overapprox: str = "trivial", wreck_margin: float = 0.0):
        """``params``: the ego's bounds (its braking ``u_min``, its leaders' ``d_min``); ``others``: the
        traffic's (their braking and acceleration, their leaders' — possibly the ego's — braking);
        ``wreck_margin`` [m]: how far an impact may push a car at risk back (``GuardianConfig``)."""
        if params.exact or (others is not None and others.exact):
            raise ValueError("the traffic rules move every car by (7.3)'s Euler step; exact integration is not "
                             "implemented there")
        self.params = params
        self.others = params if others is None else others
        self.S = MaximalSet(params)
        self.S_others = self.S if others is None else MaximalSet(self.others)
        self.overapprox = overapprox
        self.wreck_margin = float(wreck_margin)
        self.far = far_enough(self.S_others)   # a car this far behind the one it follows needs no verdict of it
        self._risk = (None, {})   # (the scene's cars, {id(car): why it is at risk}) for the last scene

    def with_ego_set(self, S) -> "TrafficSupervisor":
        """This supervisor with the ego's own set replaced by ``S`` (anything answering ``speed_intervals(h+,
        v_L+)`` in next ego speeds: an actuated ego's set bound to its state now,
        ``itha.actuator.RateLimitedSet.bound``); the traffic's set and its verdicts are shared."""
        out = copy.copy(self)
        out.S = S
        return out

    def _speed_range(self) -> list:
        """The ego's next speeds with no car ahead: ``[0, v_max]`` for (7.3); an actuated ego's set narrows them to
        what it reaches and can still hold below ``v_max``."""
        return self.S.speed_intervals(math.inf, self.params.v_max)

    def self_safe_speeds(self, scene: Scene) -> tuple[list, str]:
        """Next ego speeds that are self-safe (7.4) against the nearest car ahead in each occupied lane."""
        allowed = self._speed_range()
        for lane, car, speeds in self.leader_speeds(scene):
            allowed = intersect_intervals(allowed, speeds)
            if not allowed:
                risk = self.at_risk(scene, car)
                return [], f"too close to {car.name or 'the car'} ahead in lane {lane}" + (
                    f" (at risk of a crash: {risk})" if risk else "")
        return allowed, ""

    def leader_speeds(self, scene: Scene) -> list:
        """``[(lane, car, next ego speeds self-safe towards it), ...]`` for each car ahead that no other car
        hides in each lane the ego occupies (``Scene.leaders``: the nearest, and any whose body overlaps it
        along the road): the parts of ``self_safe_speeds``, to say which car limits the ego."""
        p, ego = self.params, scene.ego
        out = []
        for lane in sorted(ego.lanes):
            for c in scene.leaders(lane):
                h_next = _gap_after_step(p, ego, c)
                if self.at_risk(scene, c):  # it may stand still from its next position on, pushed back
                    out.append((lane, c, self.S.speed_intervals(h_next - self.wreck_margin, 0.0)))
                else:
                    out.append((lane, c, self.S.speed_intervals(h_next, float(p.worst_lead_speed(min(c.speed, p.v_max))))))
        return out

    def at_risk(self, scene: Scene, car: Car) -> str:
        """Why ``car`` may stop faster than the traffic model allows ("" when it may not): it has
        crashed, or in some lane it is outside the car-following set behind the car it follows, or it
        cannot stop behind that car when that car is at risk (see the module docstring)."""
        memo = self._verdicts(scene, car)
        if id(car) not in memo:
            self._resolve(scene, car, memo)
        return memo[id(car)]

    def _verdicts(self, scene: Scene, car: Car) -> dict:
        """Where the verdicts of ``scene``'s cars are kept. A car at or ahead of the ego follows only cars strictly
        ahead of it, never the ego's own body, so its verdict is the same in every guarded car's scene that shares
        the road's index (``Scene.index``): it is kept there, for every supervisor with these bounds."""
        if scene.index is not None and car.front >= scene.ego.front:
            return scene.index.verdicts.setdefault((self.others, self.wreck_margin), {})
        cars, memo = self._risk
        if cars is not scene.others:
            memo = {}
            self._risk = (scene.others, memo)
        return memo

    def _resolve(self, scene: Scene, car: Car, memo: dict) -> None:
        """``memo`` filled for ``car`` and the cars its verdict needed, in the order the rule asks for them
        (``_verdict`` yields each car it follows whose verdict it needs). An explicit stack rather than recursion:
        a queue of hundreds of cars in one lane is deeper than Python's recursion limit. The chain ends, since a
        car follows only cars whose fronts are strictly ahead."""
        stack, answer = [(car, self._verdict(scene, car))], None
        while stack:
            c, steps = stack[-1]
            try:
                needed = steps.send(answer)
            except StopIteration as done:
                memo[id(c)] = answer = done.value
                stack.pop()
                continue
            if id(needed) in memo:
                answer = memo[id(needed)]
            else:
                stack.append((needed, self._verdict(scene, needed)))
                answer = None

    def _verdict(self, scene: Scene, car: Car):
        """Why ``car`` is at risk ("" when it is not), as a generator: it yields each car it follows whose own
        verdict it needs and is sent that verdict back; its return value is the verdict."""
        if car.fixed:
            return ""
        p, name = self.others, car.name or "the car"
        if car.crashed:
            return f"{name} has crashed"
        if not 0 <= car.speed <= p.v_max:
            return f"{name} drives at {car.speed:.2f} m/s, outside the traffic model's [0, {p.v_max:g}] m/s"
        far = self.far
        for lane in sorted(car.lanes):
            for lead in scene.leads_of(car, lane):
                if _gap(car, lead) >= far and _gap_after_step(p, car, lead) - self.wreck_margin >= far \
                        and max(p.next_speed(car.speed, p.u_min), 0.0) <= p.v_max:
                    continue   # it can stop behind this car whatever that car is: its verdict is not needed
                if (yield lead):
                    h_next = _gap_after_step(p, car, lead) - self.wreck_margin
                    v_next = max(p.next_speed(car.speed, p.u_min), 0.0)
                    if not self.S_others.contains([[v_next, h_next, 0.0]])[0]:
                        return f"{name} cannot stop behind {lead.name or 'the car'} in lane {lane}, which is at risk"
                elif not self.S_others.contains([[car.speed, _gap(car, lead), max(min(lead.speed, p.v_max), 0.0)]])[0]:
                    return f"{name} is outside its car-following set behind {lead.name or 'the car'} in lane {lane}"
        return ""

    def follower_speeds(self, scene: Scene, lane: int, ego_progress_min: float | None = None) -> tuple[list, str]:
        """Next ego speeds keeping each car behind in ``lane`` that no other hides (``Scene.followers``: the
        nearest, and any whose body overlaps it along the road) in its RCIS, whatever it does.

        ``ego_progress_min`` is the least distance the ego covers this step (default ``dt v``).
        """
        p, ego = self.others, scene.ego
        speeds = self._speed_range()
        progress = p.dt * ego.speed if ego_progress_min is None else ego_progress_min
        for car in scene.followers(lane):
            gap = (ego.front + progress) - ego.length - (car.front + p.dt * car.speed)
            v_fast = min(car.speed + p.dt * p.u_max, p.v_max)
            speeds = intersect_intervals(speeds, self.S_others.lead_speed_intervals(v_fast, gap))
            if not speeds:
                return [], f"{car.name or 'the car'} behind in lane {lane} cannot stay safe"
        return speeds, ""

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
        for follower in scene.followers(lane):
            if follower.blind:
                return EntryVerdict(lane, False, [], f"{follower.name} behind in lane {lane} does not see the ego "
                                                     f"(highway-env's v0 search ends at its lane segment): it would "
                                                     f"not brake")
        index, own = scene.lane_index, scene.own
        reach = self._entry_reach(index, ego)
        picked = range(len(index.cars)) if reach is None else index.near(ego.front, reach, own)
        p, v, ln, lengths = [ego.front], [min(ego.speed, self.params.v_max)], [home], [ego.length]
        labels, silent = [0], set()
        for i in picked:
            c = index.cars[i]
            if c is own:
                continue
            at = index.flat_position(i, own)
            for n, k in enumerate(sorted(c.lanes)):
                if not c.announces:
                    silent.add(len(p))
                p.append(c.front)
                v.append(min(max(c.speed, 0.0), self.params.v_max))
                ln.append(k)
                lengths.append(c.length)
                labels.append(at + n)
        prm = HighwayParams(car_following=self.params, n_lanes=scene.n_lanes, n_cars=len(p) - 1,
                            car_length=ego.length, ego_lane=home)
        sup = EgoSupervisor(prm, self.S, self.overapprox, others_invariant=self.S_others)
        speeds, reason = sup.lane_change_speeds(p, v, ln, 0, LEFT if lane > home else RIGHT, {}, lengths, silent,
                                                labels)
        return EntryVerdict(lane, bool(speeds), speeds, reason)

    def _entry_reach(self, index, ego: Car) -> float | None:
        """How far from the ego's front a car can take part in an entry's verdict (7.5): ``far_enough`` beyond any
        gap the rules weigh, a body and a step of travel each way, doubled (a car that hides a nearer one lies
        between it and the ego); None (every car is read) where the ego's set has no such distance, or where the
        ego's top speed is above the traffic's (the rules then judge a car's speed outside the traffic's set however
        far it is)."""
        free = max(far_enough(self.S), far_enough(self.S_others))
        if math.isinf(free) or self.params.v_max > self.others.v_max:
            return None   # (the second: speeds clipped to the ego's top speed may lie beyond the traffic's set)
        travel = self.params.dt * (self.params.v_max + abs(ego.speed)) + self.others.dt * self.others.v_max
        return 2.0 * (free + max(index.longest, ego.length) + travel) + 10.0

