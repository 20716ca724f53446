"""Car following for an ego that cannot brake at once: a jerk bound and a reaction delay in the set.

(7.3) lets the ego's acceleration jump to any value of ``U`` from one step to the next. A real actuator
cannot: its acceleration changes by at most ``jerk`` m/s^3, and a command may act only ``delay`` steps after it
is given. ``Actuator`` declares both; ``ActuatedSet`` is the maximal robust controlled invariant set of the
car-following agent with that actuator, the cars moved exactly (``CarFollowingParams(integration="exact")``).

State ``(v, h, v_L, a, q_1, ..., q_n)``: ego speed, gap, lead speed, the ego's acceleration now and the
``n = delay`` accelerations already commanded (``q_1`` is reached at the end of this step). A command ``c`` is
the acceleration the ego reaches ``n + 1`` steps on, within ``U`` and within ``jerk dt`` of the one before it.
Over a step the acceleration either ramps linearly from the last commanded value to the new one
(``profile="ramp"``: jerk held over a step) or jumps to the new one at the step's start and holds it
(``profile="hold"``: a rate limit on the held acceleration, the vehicle of CommonRoad's ACC falsification suite);
with ``jerk = inf`` both are the jump, so ``Actuator()`` is the exact model itself (tested).

Why the set is ``{floor >= h_min}``, ``floor`` the least gap over all time when the ego goes through its queue
and then brakes as hard as it can (each command ``jerk dt`` below the last down to ``u_min``, held to
standstill) while the
lead brakes at ``d_min`` from now: any admissible command sequence gives the ego an acceleration at least
this one's at every instant, hence a speed and a position at least these (a car that stops stays, unless its
acceleration turns positive); any lead within its bounds is at every instant at least as far as the one braking
hardest. So a state outside fails whatever the ego does, and from a state inside the braking command keeps the
next state inside (its floor continues the same trajectory). Admissible commands keep the next state inside
and, without delay, the gap through the step; more throttle is worse at every instant, so they are one
interval ``[c_min, c*]``.

The gap between two cars of piecewise-polynomial motion is evaluated exactly: the cars' motion is cut where
either changes jerk, stops or starts; on each piece the relative speed is a quadratic, and the gap's least
value is at a piece's end or at a root of it.

The ego's speed is not bounded above here (a speed limit is the driver's business, not the gap's); the lead's
speed needs no bound either.

``lag`` (a first-order time constant ``tau``) is modelled as a digital controller sees it: the acceleration held
over a step moves towards the command by the share ``1 - exp(-dt / tau)`` of the way (the lag's step response
sampled at the step's end, then held), within the jerk bound (``Actuator.follows``). The map from the last
acceleration and the command to the next is monotone in both, which is all the sets' arguments need; the
sets on (7.3)'s Euler step (``RateLimitedSet``) take it. A continuous lag brakes exponentially inside a step, and
``ActuatedSet`` (exact integration) refuses a lag by name: its least gap would need a transcendental root.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from itha import _kernels
from itha.car_following import INNER, SPEED_BISECTIONS, CarFollowingParams

BISECTIONS = 60
INF = math.inf
PROFILES = ("ramp", "hold")
CUT_ROUNDING = 1e-9   # [m/s^2] see Actuator.response
LAG_MAX = 60.0        # [s] a longer time constant is no vehicle's actuator (and its set's braking barely ends)


@dataclass(frozen=True)
class Actuator:
    """What the ego's actuator can do: ``|da/dt| <= jerk`` [m/s^3] (``profile``: ramped over a step, or a held
    acceleration whose step-to-step change is at most ``jerk dt``); a command acts ``delay`` steps after it is
    given; ``lag`` [s] a first-order time constant, sampled and held over each step (profile "hold" only)."""

    jerk: float = INF
    delay: int = 0
    lag: float = 0.0
    profile: str = "ramp"   # over a step: "ramp" from the last command to the new one, or "hold" the new one

    def __post_init__(self):
        if not self.jerk > 0:
            raise ValueError(f"Actuator.jerk must be positive (inf: none), got {self.jerk}")
        if not (isinstance(self.delay, int) and self.delay >= 0):
            raise ValueError(f"Actuator.delay is a whole number of steps >= 0, got {self.delay!r}")
        if self.profile not in PROFILES:
            raise ValueError(f"Actuator.profile must be one of {PROFILES}, got {self.profile!r}")
        if isinstance(self.lag, bool) or not (isinstance(self.lag, (int, float)) and math.isfinite(self.lag)
                                               and self.lag >= 0):
            raise ValueError(f"Actuator.lag is a time constant [s] >= 0 (0: none), got {self.lag!r}")
        if self.lag > LAG_MAX:
            raise ValueError(f"Actuator.lag {self.lag:g} s is beyond {LAG_MAX:g} s: no vehicle's actuator lags so long")
        if self.lag and self.profile != "hold":
            raise ValueError("Actuator.lag is modelled on a held acceleration (sampled each step): declare "
                             "Actuator(lag=..., profile=\"hold\"); a ramp under a lag is not modelled")

    def keep(self, dt: float) -> float:
        """The share of the last acceleration a step of ``dt`` keeps under the lag: ``exp(-dt / lag)`` (0: none)."""
        return math.exp(-dt / self.lag) if self.lag else 0.0

    def lagged(self, last: float, asked: float, dt: float) -> float:
        """Where the lag alone takes the acceleration in a step (``asked`` itself without a lag)."""
        if not self.lag:
            return asked
        keep = self.keep(dt)
        blend = keep * last + (1.0 - keep) * asked   # the floor kernel's own arithmetic (_kernels.floor_rate_limited)
        return min(max(blend, min(last, asked)), max(last, asked))   # never beyond either end by rounding

    def follows(self, last: float, asked: float, dt: float) -> float:
        """The acceleration a held-profile actuator applies over a step of ``dt`` when asked for ``asked`` after
        applying ``last``: the lag's response (``asked`` itself without a lag) limited to within ``jerk dt`` of
        ``last`` (the worlds' rule: highway-env's ``envs.actuator.Actuated``, the SUMO episodes' model)."""
        return self.response(last, asked, dt)[0]

    def response(self, last: float, asked: float, dt: float) -> tuple[float, bool]:
        """``(follows(last, asked, dt), cut)``: ``cut`` says whether the jerk bound cut the command (the lag's
        response to it, with a lag). Under a lag a cut within ``CUT_ROUNDING`` is the inverted lag's rounding
        (``asks``), not a cut: the worlds count the rest."""
        fall = self.jerk * dt
        lagged = self.lagged(last, asked, dt)
        applied = min(max(lagged, last - fall), last + fall)
        return applied, applied != lagged and (not self.lag or abs(applied - lagged) > CUT_ROUNDING)

    def reach(self, last: float, u_min: float, u_max: float, dt: float) -> tuple[float, float]:
        """The accelerations the actuator can apply over the next step, commands within ``[u_min, u_max]``."""
        if not self.lag:
            fall = self.jerk * dt
            return max(u_min, last - fall), min(u_max, last + fall)
        return self.follows(last, u_min, dt), self.follows(last, u_max, dt)

    def asks(self, last: float, target: float, u_min: float, u_max: float, dt: float) -> float:
        """The command within ``[u_min, u_max]`` that makes the actuator apply ``target`` (a value of ``reach``):
        ``target`` itself without a lag; with one, the lag inverted. Where the lag's response to ``u_min``
        (``u_max``) is the reach's end, the end asks ``u_min`` (``u_max``) exactly: the hardest braking is then the
        hardest command. Where the jerk bound is the end, the end asks the command whose response is the bound (a
        harder one would be clipped by the jerk bound)."""
        if not self.lag:
            return target
        if target <= self.lagged(last, u_min, dt):
            return u_min
        if target >= self.lagged(last, u_max, dt):
            return u_max
        keep = self.keep(dt)
        return min(max((target - keep * last) / (1.0 - keep), u_min), u_max)


# ---- piecewise-polynomial motion -------------------------------------------------------------------
@dataclass(frozen=True)
class Piece:
    """Motion with constant jerk from ``t0`` to ``t1``: ``x(t0 + s) = x + v s + a s^2/2 + j s^3/6``."""

    t0: float
    t1: float
    x: float
    v: float
    a: float
    j: float

    def at(self, t: float) -> tuple[float, float, float]:
        s = t - self.t0
        return (self.x + s * (self.v + s * (self.a / 2 + s * self.j / 6)), self.v + s * (self.a + s * self.j / 2),
                self.a + s * self.j)


def _roots(c0: float, c1: float, c2: float, upto: float) -> list[float]:
    """The roots of ``c0 + c1 s + c2 s^2`` in ``(0, upto)``."""
    if c2 == 0.0:
        roots = [-c0 / c1] if c1 != 0.0 else []
    else:
        disc = c1 * c1 - 4 * c2 * c0
        if disc < 0:
            return []
        q = -0.5 * (c1 + math.copysign(math.sqrt(disc), c1))
        roots = [q / c2] + ([c0 / q] if q != 0.0 else [])
    return sorted(r for r in roots if 0.0 < r < upto)


def _first_root(c0: float, c1: float, c2: float, upto: float) -> float:
    roots = _roots(c0, c1, c2, upto)
    return roots[0] if roots else INF


def motion(v: float, a: float, segments) -> list[Piece]:
    """The pieces of a car's motion from speed ``v >= 0`` and acceleration ``a`` through ``segments``:
    ``(duration, jerk, start)`` each (``start``: the acceleration jumps to it at the segment's start; None:
    it goes on from where it is). The last duration may be inf. A car whose speed reaches 0 stands (its
    acceleration goes on changing) until its acceleration turns positive."""
    out, t, x = [], 0.0, 0.0
    for duration, jerk, start in segments:
        if start is not None:
            a = start
        end = t + duration
        while t < end:
            left = end - t
            standing = v <= 0.0 and (a < 0.0 or (a == 0.0 and jerk <= 0.0))
            if standing:
                s = -a / jerk if jerk > 0.0 else INF     # when the acceleration turns positive
                s = min(s, left)
                out.append(Piece(t, t + s, x, 0.0, 0.0, 0.0))
                v, a = 0.0, (0.0 if s < left else a + jerk * s) if math.isfinite(s) else a
            else:
                v = max(v, 0.0)
                s = min(_first_root(v, a, jerk / 2, left), left)   # speed back to 0
                piece = Piece(t, t + s, x, v, a, jerk)
                out.append(piece)
                if math.isfinite(s):
                    x, v, a = piece.at(t + s)
                    v = 0.0 if s < left else max(v, 0.0)
            if not math.isfinite(s):
                return out
            t += s
    return out


def _locate(pieces: list[Piece], t: float) -> Piece:
    for p in pieces:
        if t <= p.t1:
            return p
    return pieces[-1]


def least_gap(h: float, ego: list[Piece], lead: list[Piece], horizon: float) -> float:
    """``min over 0 <= t <= horizon`` of ``h + x_lead(t) - x_ego(t)``, exactly (see the module docstring)."""
    cuts = sorted({0.0, horizon} | {p.t0 for p in ego + lead if p.t0 < horizon}
                  | {p.t1 for p in ego + lead if p.t1 < horizon})
    best = INF

    def gap(t):
        return h + _locate(lead, t).at(t)[0] - _locate(ego, t).at(t)[0]

    for t0, t1 in zip(cuts, cuts[1:]):
        best = min(best, gap(t0), gap(t1))
        mid = (t0 + t1) / 2
        pe, pl = _locate(ego, mid), _locate(lead, mid)   # the pieces that cover (t0, t1)
        _, ve, ae = pe.at(t0)
        _, vl, al = pl.at(t0)
        for r in _roots(vl - ve, al - ae, (pl.j - pe.j) / 2, t1 - t0):
            best = min(best, gap(t0 + r))
    return best


def _rest_time(pieces: list[Piece]) -> float:
    """When the car's last piece starts (it then stands, or moves on the same polynomial)."""
    return pieces[-1].t0


# ---- the set ------------------------------------------------------------------------------------------
class _Queued:
    """A car-following set whose state carries the acceleration now and the ``delay`` accelerations queued."""

    actuator: Actuator

    @property
    def state_size(self) -> int:
        return 4 + self.actuator.delay

    def _check(self, x) -> tuple:
        x = tuple(float(c) for c in x)
        if len(x) != self.state_size:
            raise ValueError(f"the state is (v, h, v_L, a, q_1..q_{self.actuator.delay}): {self.state_size} numbers, "
                             f"got {len(x)}")
        return x


class ActuatedSet(_Queued):
    """The maximal RCIS of the car-following agent whose ego has ``actuator`` (see the module docstring)."""

    kind = "actuated"

    def __init__(self, params: CarFollowingParams, actuator: Actuator = Actuator()):
        if not params.exact:
            raise ValueError("an actuator's dynamics are integrated exactly: use CarFollowingParams(integration="
                             "\"exact\")")
        if actuator.lag:
            raise ValueError("ActuatedSet has no lag: a continuous lag brakes exponentially within a step and the "
                             "least gap has no closed form; a lag is modelled on (7.3)'s Euler step (RateLimitedSet)")
        self.params, self.actuator = params, actuator

    def _step(self, start: float, end: float) -> tuple:
        """One step's segment from acceleration ``start`` to the commanded ``end``."""
        dt, act = self.params.dt, self.actuator
        return (dt, 0.0, end) if math.isinf(act.jerk) or act.profile == "hold" else (dt, (end - start) / dt, None)

    def _braking(self, a: float) -> list:
        """From acceleration ``a``: the hardest command sequence (each ``jerk dt`` below the last, down to
        ``u_min``), the acceleration ramping over each step as the actuator does, held to standstill."""
        p, jerk = self.params, self.actuator.jerk
        if math.isinf(jerk):
            return [(INF, 0.0, p.u_min)]
        out = []
        while a > p.u_min:
            target = max(p.u_min, a - jerk * p.dt)
            out.append(self._step(a, target))
            a = target
        return out + [(INF, 0.0, None)]

    def _queue_segments(self, a: float, queue) -> list:
        out, prev = [], a
        for q in queue:
            out.append(self._step(prev, q))
            prev = q
        return out

    def ego_braking(self, x) -> list[Piece]:
        v, _, _, a, *queue = self._check(x)
        return motion(v, a, self._queue_segments(a, queue) + self._braking(queue[-1] if queue else a))

    def lead_braking(self, vL: float) -> list[Piece]:
        return motion(vL, self.params.d_min, [(INF, 0.0, None)])

    def floor(self, x) -> float:
        """The least gap over all time, the ego braking as hard as its actuator allows after its queue, the lead
        at ``d_min`` from now."""
        v, h, vL, *_ = self._check(x)
        ego, lead = self.ego_braking(x), self.lead_braking(vL)
        return least_gap(h, ego, lead, max(_rest_time(ego), _rest_time(lead)) + 1.0)

    def contains(self, x) -> bool:
        v, h, vL, a, *queue = self._check(x)
        p = self.params
        if not (v >= 0 and vL >= 0 and all(p.u_min <= q <= p.u_max for q in (a, *queue))):
            return False
        return math.isinf(h) or self.floor(x) >= p.h_min - INNER   # membership allows rounding (INNER)

    def command_bounds(self, x) -> tuple[float, float]:
        """The commands the actuator accepts: within ``U`` and within ``jerk dt`` of the last commanded value."""
        _, _, _, a, *queue = self._check(x)
        last, p, reach = (queue[-1] if queue else a), self.params, self.actuator.jerk * self.params.dt
        return max(p.u_min, last - reach), min(p.u_max, last + reach)

    def next_state(self, x, command: float, lead_accel: float) -> tuple:
        """The state a step on with ``command`` given and the lead holding ``lead_accel`` (exact)."""
        v, h, vL, a, *queue = self._check(x)
        first = (queue + [command])[0]
        ego = motion(v, a, [self._step(a, first), (INF, 0.0, None)])
        lead = motion(vL, lead_accel, [(INF, 0.0, None)])
        dt = self.params.dt
        xe, ve, _ = _locate(ego, dt).at(dt)
        xl, vl, _ = _locate(lead, dt).at(dt)
        return (max(ve, 0.0), h + xl - xe, max(vl, 0.0), first, *(queue + [command])[1:])

    def keeps(self, x, command: float, threshold: float) -> bool:
        """``command`` keeps the next state's floor, and without delay the gap through the step, at or above
        ``threshold`` whatever the lead does."""
        v, h, vL, a, *queue = self._check(x)
        nxt = self.next_state(x, command, self.params.d_min)
        if not queue:
            ego = motion(v, a, [self._step(a, command)])
            if least_gap(h, ego, self.lead_braking(vL), self.params.dt) < threshold:
                return False
        return math.isinf(nxt[1]) or self.floor(nxt) >= threshold

    def admissible_commands(self, x) -> list[tuple[float, float]]:
        """Self-safe commands: ``[c_min, c*]``, or ``[]`` where none is (the state is outside the set)."""
        if not self.contains(x):
            return []
        lo, hi = self.command_bounds(x)
        threshold = self.params.h_min + INNER
        if self.keeps(x, hi, threshold):
            return [(lo, hi)]
        if not self.keeps(x, lo, threshold):
            return [(lo, lo)]    # from a state inside, braking continues the floor's trajectory (rounding aside)
        good, bad = lo, hi
        for _ in range(BISECTIONS):
            mid = 0.5 * (good + bad)
            good, bad = (mid, bad) if self.keeps(x, mid, threshold) else (good, mid)
        return [(lo, good)]


# ---- the same on (7.3)'s Euler step --------------------------------------------------------------------
class RateLimitedSet(_Queued):
    """The maximal RCIS of (7.3), Euler step and all, for an ego whose acceleration changes by at most
    ``jerk dt`` from one step to the next and, under a lag, only part of the way to the command (and whose speed
    must stay within ``v_max`` while it brakes): the world of a simulator that moves its cars by Euler steps
    (highway-env) with such an actuator (``envs.actuator.Actuated``).

    State ``(v, h, v_L, a)``, ``a`` the acceleration applied over the last step. An applied acceleration ``c`` in
    ``reach(a)`` (``Actuator.reach``: ``[a - jerk dt, a + jerk dt] ∩ U`` without a lag, the lag's response to the
    commands of ``U`` with one) gives ``v+ = max(v + dt c, 0)`` (the ego stops, never
    reverses), ``h+ = h + dt (v_L - v)``, ``v_L+ = max(v_L + dt d, 0)``, ``a+ = c``. The set is
    ``{floor >= h_min}`` with ``floor`` the least step-end gap while the ego's acceleration falls as fast as the
    actuator lets it (the command ``u_min`` every step) and the lead brakes at ``d_min``
    (``_kernels.floor_rate_limited``); the argument is
    ``ActuatedSet``'s (every admissible command sequence keeps the ego's acceleration, speed and position at
    least these, every lead at least as far as the one braking hardest: ``Actuator.follows`` is monotone in the
    last acceleration and the command). The next gap does not depend on the
    command, so the set bound to the ego's speed and acceleration now (``bound``) answers ``(7.4)`` in next
    speeds, as ``MaximalSet.speed_intervals`` does, and the traffic rules take it unchanged. ``jerk = inf`` is
    (7.3) itself (tested against ``MaximalSet``).

    With a reaction delay of ``n`` steps the state is ``(v, h, v_L, a, q_1..q_n)``, the ``q`` the accelerations the
    delay has fixed (``q_1`` applied over the coming step), and a command's acceleration ``c`` (within
    ``reach(q_n)``) is applied after them; the floor steps through the queue, then brakes. Bound to the state
    (``bound(v, a, queue)``) it answers in the speed ``c`` gives when it acts, ``max(v_n + dt c, 0)`` with ``v_n``
    the speed after the queue (``RateLimitedEgo.reference``). The traffic rules do not take that yet: the
    constraints other cars' sets put on the ego bind its physical next speed, which the queue fixes (the guardian
    refuses a delay by name).
    """

    kind = "rate-limited"

    def __init__(self, params: CarFollowingParams, actuator: Actuator):
        if params.exact or params.has_drag:
            raise ValueError("RateLimitedSet is (7.3)'s Euler step without drag; for exact integration use "
                             "ActuatedSet")
        if actuator.profile != "hold":
            raise ValueError("over an Euler step the acceleration is held: declare Actuator(profile=\"hold\")")
        self.params, self.actuator = params, actuator
        self.fall, self.keep = actuator.jerk * params.dt, actuator.keep(params.dt)
        if self.keep > 1.0 - 1e-9:
            raise ValueError(f"a lag of {actuator.lag:g} s at a step of {params.dt:g} s moves the acceleration less "
                             "than 1e-9 of the way a step: the set's braking would not end")

    def reach(self, a: float) -> tuple[float, float]:
        """The accelerations the actuator can apply next from acceleration ``a`` (commands within ``U``)."""
        p = self.params
        return self.actuator.reach(a, p.u_min, p.u_max, p.dt)

    def floor(self, x) -> float:
        """The least step-end gap while the ego goes through its queued accelerations and then brakes as hard as its
        actuator lets it, the lead braking at ``d_min`` from now (``-inf`` where a speed passes ``v_max``)."""
        v, h, vL, a, *queue = self._check(x)
        p = self.params
        least = h
        for q in queue:   # the queued accelerations, stepped as the kernel steps its own
            if v > p.v_max:
                return -INF
            h += p.dt * (vL - v)
            least = min(least, h)
            a, v, vL = q, max(v + p.dt * q, 0.0), max(vL - p.lead_step, 0.0)
        return min(least, _kernels.floor_rate_limited(self.fall, self.keep, p.u_min, p.lead_step, p.dt, p.v_max, v, h,
                                                      vL, a))

    def contains(self, x) -> bool:
        v, h, vL, a, *queue = self._check(x)
        p = self.params
        if not (0 <= v <= p.v_max and all(p.u_min <= q <= p.u_max for q in (a, *queue))):
            return False
        if h == INF:      # no car ahead: only the top speed binds
            vL = 0.0
        elif not 0 <= vL <= p.v_max:
            return False
        return self.floor((v, h, vL, a, *queue)) >= p.h_min - INNER   # rounding allowed (INNER)

    def speed_limit(self, h: float, vL: float, a: float, queue=()) -> float | None:
        """The highest ego speed ``v`` with ``(v, h, vL, a, *queue)`` in the set (it falls with ``v``): the set's
        slice at ``(vL, a, queue)`` is ``v <= speed_limit(h)``; None where not even standing is inside."""
        p = self.params
        if not self.contains((0.0, h, vL, a, *queue)):
            return None
        if self.contains((p.v_max, h, vL, a, *queue)):
            return p.v_max
        lo, hi = 0.0, p.v_max
        for _ in range(SPEED_BISECTIONS):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if self.contains((mid, h, vL, a, *queue)) else (lo, mid)
        return lo

    def bound(self, v: float, a: float, queue=()) -> "RateLimitedEgo":
        """The set seen from an ego at speed ``v`` with acceleration ``a`` now and ``queue`` the accelerations its
        delay has already fixed (``q_1`` applied over the coming step)."""
        return RateLimitedEgo(self, float(v), float(a), tuple(float(q) for q in queue))


class RateLimitedEgo:
    """``RateLimitedSet`` bound to the ego's speed and acceleration now: ``speed_intervals(h+, v_L+)`` are the
    next speeds the actuator reaches that keep ``(v+, h+, v_L+, a+)`` in the set (``a+`` the command that gives
    ``v+``; every command that stops the ego is as good as another), as ``MaximalSet.speed_intervals`` gives them
    for (7.3). With an infinite gap (no car ahead) only the top speed binds. With a delay the speeds are those the
    command gives when it acts, after the queued accelerations (``reference`` is the speed it acts from)."""

    kind = "rate-limited"

    def __init__(self, S: RateLimitedSet, v: float, a: float, queue: tuple = ()):
        if len(queue) != S.actuator.delay:
            raise ValueError(f"the actuator's delay queues {S.actuator.delay} accelerations, got {len(queue)}")
        self.S, self.v, self.a, self.queue = S, v, a, queue
        self.params = p = S.params
        self.commands = S.reach(queue[-1] if queue else a)
        self.reference = v   # the speed the command acts from: after the queued accelerations
        for q in queue:
            self.reference = max(self.reference + p.dt * q, 0.0)
        self._answers = {}   # (h, vL) -> speeds: a decision asks the free road and each leader several times

    def next_speed(self, command: float) -> float:
        """The speed ``command`` gives when it acts (next step without a delay; after the queue with one)."""
        return max(self.reference + self.params.dt * command, 0.0)

    def _safe(self, command: float, h: float, vL: float) -> bool:
        p, queue = self.params, self.queue
        if not queue:
            return _kernels.floor_rate_limited(self.S.fall, self.S.keep, p.u_min, p.lead_step, p.dt, p.v_max,
                                               self.next_speed(command), h, vL, command) >= p.h_min + INNER
        v1 = max(self.v + p.dt * queue[0], 0.0)
        return self.S.floor((v1, h, vL, queue[0], *queue[1:], command)) >= p.h_min + INNER

    def _highest_safe(self, lo: float, hi: float, h: float, vL: float) -> float:
        """The last safe command of ``[lo, hi]`` (``lo`` safe, ``hi`` not): the floor falls with the command."""
        p = self.params
        if not self.queue:
            return _kernels.highest_safe_command(self.S.fall, self.S.keep, p.u_min, p.lead_step, p.dt, p.v_max, self.v,
                                                 h, vL, lo, hi, p.h_min + INNER, SPEED_BISECTIONS)
        for _ in range(SPEED_BISECTIONS):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if self._safe(mid, h, vL) else (lo, mid)
        return lo

    def speed_intervals(self, h: float, vL: float) -> list[tuple[float, float]]:
        key = (h, vL)
        if key not in self._answers:
            self._answers[key] = self._speed_intervals(h, vL)
        return list(self._answers[key])

    def _speed_intervals(self, h: float, vL: float) -> list[tuple[float, float]]:
        p = self.params
        lo, hi = self.commands
        if lo > hi:
            return []
        top = hi
        if h == INF:       # no car ahead: only the top speed binds
            vL = 0.0
        elif not 0 <= vL <= p.v_max:
            return []
        if not self._safe(lo, h, vL):
            return []
        if not self._safe(hi, h, vL):
            top = self._highest_safe(lo, hi, h, vL)
        low, high = self.next_speed(lo), min(self.next_speed(top), p.v_max)
        return [(low, high)] if low <= high else []
