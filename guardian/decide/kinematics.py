"""How the ego's input maps to its next state: one class per kinematics the guardian supervises.

The ITHA part answers in next speeds and lane footprints; these classes turn such
answers into input constraints, exactly for the model that moves the ego.

* ``PointMassEgo``: the overtake ego of ``guardian/HighwayOvertake-v0`` (6.3):
  ``v+ = (1 - b_e dt) v + dt a_ex + dt w_ex`` and ``y+ = y + dt v_ey + dt w_ey``
  with ``w`` unknown in its box, so a next-speed interval ``[lo, hi]`` holds for
  every ``w_ex`` iff ``a_ex in [(lo - (1 - b_e dt) v)/dt - w_ex^min,
  (hi - (1 - b_e dt) v)/dt - w_ex^max]``.
* ``BicycleEgo``: highway-env's own vehicles: ``speed+ = speed + dt a`` and the
  position moves by ``dt speed (cos, sin)(heading + beta)``, ``beta =
  atan(tan(steering) / 2)``; the heading turns by ``dt speed sin(beta) / (L/2)``,
  on one straight road along x;
* ``RoadMapEgo``: the same bicycle on a road beyond one straight segment (``guardian.model.roads.RoadMap``):
  lanes that begin and end, on-ramps and exits; headings are measured against the lane's.

``guardian.decide.bicycle.BicycleGuardian`` reads the two bicycle classes through one interface that takes the
ego's state (``occupied``, ``candidates``, ``after``, ``path_lanes_of``, ...).
"""
from __future__ import annotations

import math

import numpy as np

from guardian.model.body import half_extents, lanes_overlapped
from guardian.model.roads import outline
from intention.params import OvertakeParams

ROUNDING = 1e-9  # input intervals are shrunk by this so that a rounded step stays inside


class PointMassEgo:
    """The ego of (6.3); lateral coordinates in units of ``y_e`` (lane k's centre at ``2 k y_left``).

    ``stops_at_zero``: the speed is clipped at 0 after each step (a car held by its brake does not
    reverse; ``guardian/HighwayOvertake-v0``); a next-speed interval reaching 0 then needs no lower
    bound on the input.
    """

    def __init__(self, params: OvertakeParams, half_width: float, n_lanes: int, stops_at_zero: bool = False):
        self.p = params
        self.half_width = half_width          # the ego's half width in units of y_e
        self.lane_width = 2 * params.left_lane_y
        self.n_lanes = n_lanes                # k = 0 is the right lane (ITHA lane 1)
        self.stops_at_zero = stops_at_zero

    def accel_for_speeds(self, v: float, speeds) -> list:
        p = self.p
        keep = (1 - p.b_e * p.dt) * v
        out = []
        for lo, hi in speeds:
            a_lo = (lo - keep) / p.dt - p.w_ex_bounds[0] + ROUNDING
            if self.stops_at_zero and lo <= 0.0:
                a_lo = p.a_ex_bounds[0]
            a_hi = (hi - keep) / p.dt - p.w_ex_bounds[1] - ROUNDING
            a_lo, a_hi = max(a_lo, p.a_ex_bounds[0]), min(a_hi, p.a_ex_bounds[1])
            if a_lo <= a_hi:
                out.append((a_lo, a_hi))
        return out

    def lanes_at(self, y: float) -> frozenset:
        """ITHA lanes (1 = right) the ego's body overlaps at lateral position ``y``."""
        ks = lanes_overlapped(y - self.half_width, y + self.half_width, self.n_lanes, self.lane_width)
        return frozenset(k + 1 for k in ks)

    def centre(self, lane: int) -> float:
        """``y_e`` of ITHA ``lane``'s centre."""
        return (lane - 1) * self.lane_width

    def lanes_with(self, y: float, v_ey: float, w_ey: float) -> frozenset:
        """Lanes the body overlaps after one step with lateral input ``v_ey`` and disturbance ``w_ey``."""
        centre = y + self.p.dt * (v_ey + w_ey)
        return frozenset(k + 1 for k in lanes_overlapped(centre - self.half_width, centre + self.half_width,
                                                          self.n_lanes, self.lane_width))

    def next_lanes(self, y: float, v_ey: float) -> frozenset:
        """Lanes the body may overlap after one step with lateral input ``v_ey`` (any ``w_ey``): the body
        moves less than its width across the noise's box, so its two corners sweep every lane between."""
        return frozenset().union(*(self.lanes_with(y, v_ey, w) for w in self.p.w_ey_bounds))

    def may_stay_in(self, y: float, v_ey: float, lanes: frozenset) -> bool:
        """Can the body overlap exactly ``lanes`` after one step with ``v_ey``, for some ``w_ey``? (The
        lanes overlapped move monotonically with ``w_ey``, so its box's corners decide.)"""
        return any(self.lanes_with(y, v_ey, w) == lanes for w in self.p.w_ey_bounds)

    def lateral_partition(self, y: float) -> list:
        """``U_e``'s lateral range cut where the lanes the body may overlap next step change.

        Returns ``[(lo, hi, lanes), ...]``: for every ``v_ey`` in ``[lo, hi]`` and every ``w_ey`` the
        body overlaps only ``lanes`` (ITHA numbers) next step. Ends move ``ROUNDING`` inwards from
        each cut, so a rounded step stays on its side.
        """
        p = self.p
        lo_u, hi_u = p.v_ey_bounds
        cuts = set()
        for k in range(self.n_lanes + 1):  # lane borders, and the outer road edges
            border = (k - 0.5) * self.lane_width
            for w in p.w_ey_bounds:
                for side in (-self.half_width, self.half_width):
                    v = (border - side - y) / p.dt - w
                    if lo_u < v < hi_u:
                        cuts.add(v)
        ends = [lo_u, *sorted(cuts), hi_u]
        out = []
        for a, b in zip(ends, ends[1:]):
            lo = a if a == lo_u else a + ROUNDING
            hi = b if b == hi_u else b - ROUNDING
            if lo <= hi:
                out.append((lo, hi, self.next_lanes(y, (lo + hi) / 2)))
        return out

    def lateral_keep_out(self, y: float, lane: int) -> tuple[float, float]:
        """Lateral inputs that keep the body out of ITHA ``lane`` next step, for every ``w_ey``."""
        p = self.p
        k = lane - 1
        lo, hi = p.v_ey_bounds
        if (k - 0.5) * self.lane_width >= y:  # the lane is to the left (larger y)
            hi = min(hi, ((k - 0.5) * self.lane_width - self.half_width - y) / p.dt - p.w_ey_bounds[1] - ROUNDING)
        else:
            lo = max(lo, ((k + 0.5) * self.lane_width + self.half_width - y) / p.dt - p.w_ey_bounds[0] + ROUNDING)
        return lo, hi

    def lateral_within(self, y: float, y_lo: float, y_hi: float) -> tuple[float, float]:
        """Lateral inputs keeping ``y+`` in ``[y_lo, y_hi]`` for every ``w_ey`` (clipped to ``U_e``)."""
        p = self.p
        lo = max(p.v_ey_bounds[0], (y_lo - y) / p.dt - p.w_ey_bounds[0] + ROUNDING)
        hi = min(p.v_ey_bounds[1], (y_hi - y) / p.dt - p.w_ey_bounds[1] - ROUNDING)
        return lo, hi


class BicycleEgo:
    """highway-env's kinematic bicycle (``Vehicle.step``); lanes are ``lane_width`` apart, lane 0 at y = 0."""

    MAX_HEADING = 0.3     # [rad] the lateral guard keeps |heading| below this (so one step can stop sideways motion)
    CANDIDATES = 41       # steering angles tried when the proposed one is refused
    RECOVERY_STEPS = 60   # steps a straightening may take (a bound; headings below MAX_HEADING need few)
    LATERAL_MARGIN = 0.05  # [m] the body is widened by this when its path is checked against lane borders
    PATHS_KEPT = 1_000     # paths remembered (a decision asks for each more than once)

    def __init__(self, dt: float, accel: float, length: float, width: float, lane_width: float, n_lanes: int,
                 max_steering: float):
        self.dt, self.accel = dt, accel
        self.length, self.width = length, width
        self.lane_width, self.n_lanes = lane_width, n_lanes
        self.max_steering = max_steering

    def accel_for_speeds(self, v: float, speeds, bounds: tuple | None = None) -> list:
        """Accelerations giving a next speed in ``speeds``, within ``bounds`` (default ``±accel``).

        With ``bounds`` (an actuator's reach) the speed stops at 0, and the reach's lowest command is taken
        exactly where its next speed (``max(v + dt lower, 0)``, the arithmetic of the actuated set's own queries)
        lies in an interval: near the set's edge the hardest braking may be the one command left, and the
        interval of next speeds it leaves can be narrower than the rounding shrink of the others."""
        lower, upper = (-self.accel, self.accel) if bounds is None else bounds
        lowest = None if bounds is None else max(v + self.dt * lower, 0.0)
        out = []
        for lo, hi in speeds:
            a_lo = max((lo - v) / self.dt + ROUNDING, lower)
            a_hi = min((hi - v) / self.dt - ROUNDING, upper)
            if lowest is not None and lo <= lowest <= hi:
                a_lo, a_hi = lower, max(a_hi, lower)
            if a_lo <= a_hi:
                out.append((a_lo, a_hi))
        return out

    def half_extent(self, heading: float) -> float:
        """Half the lateral reach of the body at ``heading``."""
        return half_extents(self.length, self.width, heading)[1]

    def lanes_at(self, y: float, heading: float) -> frozenset:
        """highway-env lane ids (0 = leftmost) the body overlaps."""
        r = self.half_extent(heading)
        return lanes_overlapped(y - r, y + r, self.n_lanes, self.lane_width)

    def off_road(self, y: float, heading: float) -> bool:
        r = self.half_extent(heading)
        return y - r < -self.lane_width / 2 or y + r > (self.n_lanes - 0.5) * self.lane_width

    def predict(self, y: float, heading: float, speed: float, steering: float) -> tuple[float, float]:
        """``(y+, heading+)`` after one ``Vehicle.step`` with ``steering``."""
        beta = math.atan(0.5 * math.tan(steering))
        y_next = y + self.dt * speed * math.sin(heading + beta)
        return y_next, heading + self.dt * speed * math.sin(beta) / (self.length / 2)

    def swept_lanes(self, y: float, heading: float, speed: float) -> frozenset:
        """Lanes the body (widened by ``LATERAL_MARGIN``) overlaps now or after moving on at its velocity
        for one step: highway-env's collision test extrapolates every body by ``velocity * dt`` and
        crashes bodies that would meet."""
        r = self.half_extent(heading) + self.LATERAL_MARGIN
        dy = self.dt * speed * math.sin(heading)
        return lanes_overlapped(min(y, y + dy) - r, max(y, y + dy) + r, self.n_lanes, self.lane_width)

    def off_road_depth(self, y: float, heading: float) -> float:
        """How far [m] the body reaches beyond the road's edges (0 on the road)."""
        r = self.half_extent(heading)
        return max(0.0, -self.lane_width / 2 - (y - r), y + r - (self.n_lanes - 0.5) * self.lane_width)

    def straightening(self, heading: float, speed: float) -> float:
        """The steering that brings the heading to 0 in one step, or as near as the steering limit allows."""
        if speed <= 0 or abs(heading) >= math.pi / 2:
            return 0.0
        sin_beta = -heading * (self.length / 2) / (self.dt * speed)
        beta_max = math.atan(0.5 * math.tan(self.max_steering))
        beta = math.asin(max(-math.sin(beta_max), min(math.sin(beta_max), sin_beta)))
        return float(min(max(math.atan(2 * math.tan(beta)), -self.max_steering), self.max_steering))

    def path(self, y: float, heading: float, speed: float, steering: float, speed_step: float = 0.0) -> list:
        """``[(y, heading, speed), ...]`` after one step with ``steering`` and then the straightening
        steering until the heading is (nearly) 0: the horizon the bicycle needs to undo its heading.
        The speed changes by ``speed_step`` per step (kept at or above 0). Remembered: a decision asks for each
        path more than once (the lanes it sweeps, then its reach across the road)."""
        return self._remembered((y, heading, speed, steering, speed_step),
                                lambda: self._straight_path(y, heading, speed, steering, speed_step))

    def _remembered(self, key: tuple, compute) -> list:
        """A path ``compute()`` gives, remembered under ``key`` (at most ``PATHS_KEPT``; then it starts again)."""
        memo = self.__dict__.setdefault("_paths", {})
        if key not in memo:
            if len(memo) > self.PATHS_KEPT:
                memo.clear()
            memo[key] = compute()
        return list(memo[key])

    def _straight_path(self, y: float, heading: float, speed: float, steering: float, speed_step: float) -> list:
        states = [(*self.predict(y, heading, speed, steering), max(speed + speed_step, 0.0))]
        for _ in range(self.RECOVERY_STEPS):
            y1, h1, v1 = states[-1]
            if abs(h1) < 1e-6:
                break
            states.append((*self.predict(y1, h1, v1, self.straightening(h1, v1)), max(v1 + speed_step, 0.0)))
        return states

    def path_lanes(self, y: float, heading: float, speed: float, steering: float) -> tuple[frozenset, float]:
        """Lanes the (swept) body overlaps along ``path`` and how far it reaches beyond the road there,
        for the speed rising or falling as fast as it can (the sideways distance grows with speed)."""
        lanes, depth = set(), 0.0
        for step in (self.dt * self.accel, -self.dt * self.accel):
            for y1, h1, v1 in self.path(y, heading, speed, steering, step):
                lanes |= self.swept_lanes(y1, h1, v1)
                depth = max(depth, self.off_road_depth(y1, h1))
        return frozenset(lanes), depth

    def min_progress(self, speed: float, heading: float) -> float:
        """The least distance along the road one step can cover (any steering)."""
        beta_max = math.atan(0.5 * math.tan(self.max_steering))
        return self.dt * speed * math.cos(min(abs(heading) + beta_max, math.pi / 2))

    def steering_candidates(self, proposed: float, heading: float):
        """The proposed steering first, then the one that stops sideways motion, then a grid by distance (the rest
        made only when the proposal is refused)."""
        yield proposed
        straight = math.atan(2 * math.tan(-heading)) if abs(heading) < math.pi / 2 else 0.0
        grid = np.linspace(-self.max_steering, self.max_steering, self.CANDIDATES)
        yield from sorted([float(s) for s in grid] + [float(np.clip(straight, -self.max_steering, self.max_steering))],
                          key=lambda s: abs(s - proposed))

    # ---- the interface BicycleGuardian reads (states are guardian.model.scene.EgoState) -------------------
    def occupied(self, ego) -> frozenset:
        """Lanes (highway-env ids) the body, widened by ``LATERAL_MARGIN``, overlaps now."""
        return self.swept_lanes(ego.y, ego.heading, 0.0)

    def body_lanes(self, ego) -> frozenset:
        """Lanes the body itself overlaps now."""
        return self.lanes_at(ego.y, ego.heading)

    def lane_here(self, lane: int, ego) -> bool:
        """Is there a lane ``lane`` beside the ego here?"""
        return 0 <= lane < self.n_lanes

    def candidates(self, ego, proposed: float):
        return self.steering_candidates(proposed, ego.heading)

    def after(self, ego, steering: float):
        """The lateral state after one step with ``steering``."""
        return self.predict(ego.y, ego.heading, ego.speed, steering)

    def turns_too_far(self, ego, nxt) -> bool:
        """Does the heading after the step exceed ``MAX_HEADING`` (and grow)?"""
        return abs(nxt[1]) > self.MAX_HEADING and abs(nxt[1]) > abs(ego.heading)

    def lanes_after(self, ego, nxt) -> frozenset:
        return self.swept_lanes(nxt[0], nxt[1], ego.speed)

    def path_lanes_of(self, ego, steering: float) -> tuple[frozenset, float]:
        return self.path_lanes(ego.y, ego.heading, ego.speed, steering)

    def path_across_of(self, ego, steering: float) -> tuple[list, float]:
        """Where the body reaches across the road (widened by ``LATERAL_MARGIN``, swept over each step) now and
        along ``path`` at both speed extremes: ``([(y_lo, y_hi), ...], seconds the path lasts)``."""
        states = [(ego.y, ego.heading, ego.speed)]
        steps = 0
        for step in (self.dt * self.accel, -self.dt * self.accel):
            path = self.path(ego.y, ego.heading, ego.speed, steering, step)
            states += path
            steps = max(steps, len(path))
        return [self._across(y, h, v) for y, h, v in states], steps * self.dt

    def _across(self, y: float, heading: float, speed: float) -> tuple:
        r = self.half_extent(heading) + self.LATERAL_MARGIN
        dy = self.dt * speed * math.sin(heading)
        return min(y, y + dy) - r, max(y, y + dy) + r

    def depth_of(self, ego) -> float:
        return self.off_road_depth(ego.y, ego.heading)

    def recovery(self, ego) -> float:
        """The fail-safe steering: straighten along the lane."""
        return self.straightening(ego.heading, ego.speed)

    def progress_of(self, ego) -> float:
        return self.min_progress(ego.speed, ego.heading)


class RoadMapEgo(BicycleEgo):
    """highway-env's bicycle on a ``guardian.model.roads.RoadMap``: lanes are slots (highway-env ids of the
    corridor, 0 = leftmost), present where the map says; on a branch (an on-ramp's approach, an exit's
    curve) headings are measured against the branch's. The body must stay on the road (every point of its
    outline in some lane's strip); the straightening aligns the heading with the lane's a step ahead.
    The ego state's ``x`` is the world position of the body's centre."""

    def __init__(self, dt: float, accel: float, length: float, width: float, road, max_steering: float):
        super().__init__(dt, accel, length, width, road.lane_width, road.n_lanes, max_steering)
        self.road = road

    # ---- geometry along a path ----------------------------------------------------------------------
    def _step(self, x: float, y: float, h: float, v: float, steering: float) -> tuple:
        beta = math.atan(0.5 * math.tan(steering))
        return (x + self.dt * v * math.cos(h + beta), y + self.dt * v * math.sin(h + beta),
                h + self.dt * v * math.sin(beta) / (self.length / 2))

    def _relative(self, x: float, y: float, h: float) -> float:
        """Heading against the lane's at the point (wrapped to (-pi, pi])."""
        d = h - self.road.lane_heading(x, y)
        return (d + math.pi) % (2 * math.pi) - math.pi

    def _recover(self, x: float, y: float, h: float, v: float) -> float:
        """The steering that brings the heading to the lane's a step ahead, as near as the limit allows."""
        if v <= 0:
            return 0.0
        ahead = self.road.lane_heading(x + self.dt * v * math.cos(h), y + self.dt * v * math.sin(h))
        d = (ahead - h + math.pi) % (2 * math.pi) - math.pi
        if abs(d) >= math.pi / 2:
            return 0.0
        sin_beta = d * (self.length / 2) / (self.dt * v)
        beta_max = math.atan(0.5 * math.tan(self.max_steering))
        beta = math.asin(max(-math.sin(beta_max), min(math.sin(beta_max), sin_beta)))
        return float(min(max(math.atan(2 * math.tan(beta)), -self.max_steering), self.max_steering))

    def _path(self, x, y, h, v, steering, speed_step) -> list:
        """``[(x, y, heading, speed), ...]`` after one step with ``steering``, then the recovery steering until
        the heading is (nearly) the lane's (remembered: a decision asks for each path more than once)."""
        return self._remembered((x, y, h, v, steering, speed_step),
                                lambda: self._one_path(x, y, h, v, steering, speed_step))

    def _one_path(self, x, y, h, v, steering, speed_step) -> list:
        states = [(*self._step(x, y, h, v, steering), max(v + speed_step, 0.0))]
        for _ in range(self.RECOVERY_STEPS):
            x1, y1, h1, v1 = states[-1]
            if abs(self._relative(x1, y1, h1)) < 1e-6:
                break
            states.append((*self._step(x1, y1, h1, v1, self._recover(x1, y1, h1, v1)), max(v1 + speed_step, 0.0)))
        return states

    def _slots(self, xs, ys, hs, vs=None) -> frozenset:
        """Slots the bodies (widened, swept by their velocity over a step when ``vs`` is given) overlap."""
        xs, ys, hs = np.asarray(xs, float), np.asarray(ys, float), np.asarray(hs, float)
        dx = dy = 0.0
        if vs is not None:
            vs = np.asarray(vs, float)
            dx, dy = self.dt * vs * np.cos(hs), self.dt * vs * np.sin(hs)
        return self.road.body_slots(xs, ys, hs, self.length, self.width, self.LATERAL_MARGIN, dx, dy)

    def _depth(self, xs, ys, hs) -> float:
        """How far the body, widened by ``LATERAL_MARGIN`` (as against lane borders), reaches off the road: a
        body kept at depth 0 stays that far inside the road's edges, so a lane that begins beyond an edge
        (an on-ramp's parallel part, an exit lane) does not begin under it."""
        m = 2 * self.LATERAL_MARGIN
        px, py = outline(xs, ys, hs, self.length + m, self.width + m)
        d = self.road.depth(px, py)
        return float(np.max(d)) if d.size else 0.0

    # ---- the interface BicycleGuardian reads -----------------------------------------------------------
    def occupied(self, ego) -> frozenset:
        return self._slots([ego.x], [ego.y], [ego.heading])

    def body_lanes(self, ego) -> frozenset:
        return self.road.body_slots(ego.x, ego.y, ego.heading, self.length, self.width)

    def lane_here(self, lane: int, ego) -> bool:
        if self.road.on_branch(ego.x, ego.y) is not None:
            return lane == ego.lane  # nothing beside a ramp's approach or an exit's curve
        return self.road.slot_at(lane, ego.x)

    def candidates(self, ego, proposed: float):
        yield proposed
        rel = self._relative(ego.x, ego.y, ego.heading)
        straight = math.atan(2 * math.tan(-rel)) if abs(rel) < math.pi / 2 else 0.0
        grid = np.linspace(-self.max_steering, self.max_steering, self.CANDIDATES)
        yield from sorted([float(s) for s in grid] + [float(np.clip(straight, -self.max_steering, self.max_steering)),
                                                     self._recover(ego.x, ego.y, ego.heading, ego.speed)],
                          key=lambda s: abs(s - proposed))

    def after(self, ego, steering: float):
        return self._step(ego.x, ego.y, ego.heading, ego.speed, steering)

    def turns_too_far(self, ego, nxt) -> bool:
        rel = abs(self._relative(*nxt))
        return rel > self.MAX_HEADING and rel > abs(self._relative(ego.x, ego.y, ego.heading))

    def lanes_after(self, ego, nxt) -> frozenset:
        return self._slots([nxt[0]], [nxt[1]], [nxt[2]], [ego.speed])

    def path_lanes_of(self, ego, steering: float) -> tuple[frozenset, float]:
        states = []
        for step in (self.dt * self.accel, -self.dt * self.accel):
            states += self._path(ego.x, ego.y, ego.heading, ego.speed, steering, step)
        xs, ys, hs, vs = (np.array(c) for c in zip(*states))
        return self._slots(xs, ys, hs, vs), self._depth(xs, ys, hs)

    def path_across_of(self, ego, steering: float) -> tuple[list, float]:
        """As ``BicycleEgo.path_across_of``, in world y (corridor lanes run along +x)."""
        states = [(ego.x, ego.y, ego.heading, ego.speed)]
        steps = 0
        for step in (self.dt * self.accel, -self.dt * self.accel):
            path = self._path(ego.x, ego.y, ego.heading, ego.speed, steering, step)
            states += path
            steps = max(steps, len(path))
        return [self._across(y, h, v) for _, y, h, v in states], steps * self.dt

    def depth_of(self, ego) -> float:
        return self._depth([ego.x], [ego.y], [ego.heading])

    def recovery(self, ego) -> float:
        return self._recover(ego.x, ego.y, ego.heading, ego.speed)

    def progress_of(self, ego) -> float:
        return self.min_progress(ego.speed, self._relative(ego.x, ego.y, ego.heading))
