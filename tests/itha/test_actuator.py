"""An ego that cannot brake at once (``itha.actuator``): its motion against a fine numerical integration, the set
with no actuator dynamics against the exact closed form, and invariance with a jerk bound and a delay."""
import dataclasses
import math

import numpy as np
import pytest

from itha.actuator import Actuator, ActuatedSet, RateLimitedSet, least_gap, motion
from itha.car_following import CarFollowingParams, MaximalSet, admissible_inputs, headway_floor

FINE = 1e-4


def integrate(v, a, segments, T):
    """The same motion by small steps (semi-implicit, a car at standstill waits for a positive acceleration):
    the referee of ``motion``. Returns the times and positions."""
    times, xs, t, x = [0.0], [0.0], 0.0, 0.0
    for duration, jerk, start in segments:
        if start is not None:
            a = start
        end = min(t + duration, T)
        while t < end - 1e-12:
            h = min(FINE, end - t)
            a_mid = a + jerk * h / 2
            v_new = v + a_mid * h
            if v_new < 0.0 or (v == 0.0 and a_mid <= 0.0):
                frac = v / (v - v_new) if v > 0 else 0.0
                x += v * h * frac / 2
                v_new = 0.0
            else:
                x += (v + v_new) / 2 * h
            v, a, t = v_new, a + jerk * h, t + h
            times.append(t)
            xs.append(x)
    return np.array(times), np.array(xs)


def position(pieces, t):
    for p in pieces:
        if t <= p.t1:
            return p.at(t)[0]
    return pieces[-1].at(t)[0]


def random_segments(rng):
    out = []
    for _ in range(rng.integers(1, 5)):
        start = rng.choice([None, rng.uniform(-8, 3)])
        out.append((rng.uniform(0.05, 1.0), rng.choice([0.0, rng.uniform(-20, 20)]), start))
    return out


def test_motion_matches_a_fine_integration():
    rng = np.random.default_rng(0)
    for _ in range(60):
        v, a = rng.uniform(0, 20), rng.uniform(-8, 3)
        segs = random_segments(rng)
        T = sum(d for d, _, _ in segs)
        pieces = motion(v, a, segs)
        times, xs = integrate(v, a, segs, T)
        for t, x in zip(times[::200], xs[::200]):
            assert position(pieces, t) == pytest.approx(x, abs=2e-3)


def test_least_gap_is_the_least_of_a_dense_grid():
    rng = np.random.default_rng(1)
    for _ in range(200):
        ego = motion(rng.uniform(0, 30), rng.uniform(-8, 3), random_segments(rng))
        lead = motion(rng.uniform(0, 30), rng.uniform(-8, 3), random_segments(rng))
        T, h = rng.uniform(0.1, 3.0), rng.uniform(0, 30)
        grid = np.linspace(0, T, 3001)
        dense = min(h + position(lead, t) - position(ego, t) for t in grid)
        m = least_gap(h, ego, lead, T)
        assert m <= dense + 1e-9
        assert m >= dense - 40 * (T / 3000) ** 2 - 1e-9   # jerk and acceleration bound any dip between points


def test_without_actuator_dynamics_the_set_is_the_exact_closed_form():
    p = CarFollowingParams(integration="exact", h_min=0.5, u_min=-8, d_min=-7, u_max=3, d_max=3)
    A, S, rng = ActuatedSet(p), MaximalSet(p), np.random.default_rng(2)
    for _ in range(300):
        v, vL, h = *rng.uniform(0, 30, 2), rng.uniform(0, 40)
        assert A.floor((v, h, vL, 0.0)) == pytest.approx(float(headway_floor(p, [v], [h], [vL])[0]), abs=1e-9)
        assert A.contains((v, h, vL, 0.0)) == S.contains([[v, h, vL]])[0]
        ours, theirs = A.admissible_commands((v, h, vL, 0.0)), admissible_inputs(S, (v, h, vL))
        assert len(ours) == len(theirs)
        for (a, b), (c, d) in zip(ours, theirs):
            assert a == c and b == pytest.approx(d, abs=1e-9)


def test_actuator_declarations_are_checked():
    with pytest.raises(ValueError, match="held acceleration"):
        Actuator(lag=0.3)
    for bad in (-0.1, math.nan, math.inf, "0.3", True):
        with pytest.raises(ValueError, match="time constant"):
            Actuator(lag=bad, profile="hold")
    with pytest.raises(ValueError, match="no lag"):
        ActuatedSet(CarFollowingParams(integration="exact"), Actuator(lag=0.3, profile="hold"))
    with pytest.raises(ValueError, match="whole number of steps"):
        Actuator(delay=0.2)
    with pytest.raises(ValueError, match="jerk"):
        Actuator(jerk=0.0)
    with pytest.raises(ValueError, match="profile"):
        Actuator(jerk=10.0, profile="smooth")
    with pytest.raises(ValueError, match="exact"):
        ActuatedSet(CarFollowingParams())
    with pytest.raises(ValueError, match="5 numbers"):
        ActuatedSet(CarFollowingParams(integration="exact"), Actuator(delay=1)).floor((10, 20, 10, 0))


def edge_state(A, rng):
    """A state whose gap is 0 to 2 m above the least the set allows (some closing slowly)."""
    p = A.params
    v, vL = rng.uniform(0, 30, 2)
    if rng.uniform() < 0.4:
        vL = max(v - rng.uniform(0, 1.5), 0.0)
    a = rng.uniform(p.u_min, p.u_max)
    lo, hi = p.u_min, p.u_max
    queue, last = [], a
    for _ in range(A.actuator.delay):
        reach = A.actuator.jerk * p.dt
        last = rng.uniform(max(lo, last - reach), min(hi, last + reach))
        queue.append(last)
    base = A.floor((v, 0.0, vL, a, *queue))
    h = p.h_min - base + rng.choice([0.0, 1e-6, rng.uniform(0, 2)])
    return (v, h, vL, a, *queue)


EQUAL, STRONGER_EGO = dict(u_min=-8.0, d_min=-8.0, u_max=3.0, d_max=3.0), dict(u_min=-10.0, d_min=-5.0, u_max=3.0,
                                                                                  d_max=3.0)


@pytest.mark.parametrize("jerk,delay,bounds", [(10.0, 0, EQUAL), (5.0, 0, EQUAL), (10.0, 2, EQUAL), (math.inf, 1, EQUAL),
                                               (10.0, 0, STRONGER_EGO), (5.0, 1, STRONGER_EGO),
                                               (math.inf, 0, STRONGER_EGO), (10.0, 0, "hold"), (5.0, 2, "hold")])
def test_actuated_set_is_invariant_under_any_lead_within_its_bounds(jerk, delay, bounds):
    """Falsifier: from states at the set's edge, any admissible command, a lead whose acceleration changes five
    times a step within its bounds: the gap on a fine grid never goes below ``h_min`` and every next state has an
    admissible command again, for 15 steps."""
    profile = "hold" if bounds == "hold" else "ramp"   # "hold": the peer's vehicle, a rate-limited held acceleration
    p = CarFollowingParams(integration="exact", h_min=0.5, **(EQUAL if bounds == "hold" else bounds))
    A, rng = ActuatedSet(p, Actuator(jerk=jerk, delay=delay, profile=profile)), np.random.default_rng(4)
    tried = 0
    for _ in range(60):
        x = edge_state(A, rng)
        if not A.contains(x):
            continue
        tried += 1
        for _ in range(15):
            commands = A.admissible_commands(x)
            assert commands, f"no admissible command at {x}"
            lo, hi = commands[0]
            c = rng.choice([lo, hi, rng.uniform(lo, hi)])
            v, h, vL, a, *queue = x
            first = (queue + [c])[0]
            ego = motion(v, a, [A._step(a, first)])
            lead_accels = [rng.choice([p.d_min, p.d_max, rng.uniform(p.d_min, p.d_max)]) for _ in range(5)]
            lead = motion(vL, lead_accels[0], [(p.dt / 5, 0.0, acc) for acc in lead_accels])
            gaps = [h + position(lead, t) - position(ego, t) for t in np.linspace(0, p.dt, 21)]
            assert min(gaps) >= p.h_min - 1e-9
            ve = max(ego[-1].at(p.dt)[1], 0.0) if ego[-1].v or ego[-1].a or ego[-1].j else 0.0
            vl = max(lead[-1].at(p.dt)[1], 0.0) if lead[-1].v or lead[-1].a or lead[-1].j else 0.0
            x = (ve, gaps[-1], vl, first, *(queue + [c])[1:])
            assert A.contains(x), f"left the set at {x}"
    assert tried > 30


def test_a_lead_braking_at_once_meets_the_unaware_guardian_and_never_the_actuated_one(benchmark_module):
    """``benchmarks/actuator_probe.py``: a jerk-limited ego (10 m/s^3) whose driver presses +1.5 m/s^2, a lead that
    brakes at -8 at once. The set that lets the acceleration jump is touched; the set that knows the actuator
    never goes below 1 mm."""
    bench = benchmark_module("actuator_probe")
    unaware, actuated = bench.probe("unaware", "jerk 10", 12, seed=3), bench.probe("actuated", "jerk 10", 12, seed=3)
    assert unaware["contacts"] > 0
    assert actuated["contacts"] == 0 and actuated["floor_deficits"] == 0
    assert actuated["steps_without_admissible_command"] == 0


# ---- the rate-limited set on (7.3)'s Euler step (itha.actuator.RateLimitedSet) ------------------------------
HE = CarFollowingParams(dt=1 / 15, v_max=30.0, h_min=5.0, u_min=-5.0, u_max=5.0, d_min=-5.0, d_max=5.0)


def euler_step(x, command, lead_accel, p=HE):
    """The world of ``envs.actuator.JerkLimit``: highway-env's Euler step, the speed stopping at 0."""
    v, h, vL, _ = x
    return (max(v + p.dt * command, 0.0), h + p.dt * (vL - v), min(max(vL + p.dt * lead_accel, 0.0), p.v_max), command)


def random_state(rng, p=HE):
    return (rng.uniform(0, p.v_max), rng.uniform(p.h_min, 90.0), rng.uniform(0, p.v_max), rng.uniform(p.u_min, p.u_max))


def test_rate_limited_without_a_jerk_bound_is_the_closed_form():
    S, M = RateLimitedSet(HE, Actuator(jerk=math.inf, profile="hold")), MaximalSet(HE)
    rng = np.random.default_rng(1)
    for _ in range(4000):
        v, h, vL, a = random_state(rng)
        h = rng.uniform(-5, 120)
        assert S.contains((v, h, vL, a)) == M.contains([[v, h, vL]])[0]


ACTUATORS = {"jerk 10": Actuator(jerk=10.0, profile="hold"), "jerk 5": Actuator(jerk=5.0, profile="hold"),
             "jerk 2": Actuator(jerk=2.0, profile="hold"), "lag 0.5 s": Actuator(lag=0.5, profile="hold"),
             "jerk 5, lag 0.3 s": Actuator(jerk=5.0, lag=0.3, profile="hold")}


def test_a_lag_moves_the_held_acceleration_part_of_the_way():
    """The lag's step response sampled each step, within the jerk bound; ``asks`` inverts it on the reach."""
    dt, lag = 1 / 15, 0.5
    A = Actuator(lag=lag, profile="hold")
    assert A.follows(0.0, 1.0, dt) == pytest.approx(1 - math.exp(-dt / lag), abs=1e-15)
    a = 0.0
    for _ in range(15):   # one second of the command 1: the continuous lag's 1 - e^-2
        a = A.follows(a, 1.0, dt)
    assert a == pytest.approx(1 - math.exp(-1.0 / lag), abs=1e-12)
    assert Actuator(jerk=3.0, lag=0.05, profile="hold").follows(0.0, 5.0, dt) == pytest.approx(3.0 * dt)
    odd = Actuator(lag=0.010752144495215967, profile="hold")   # found by a helper: the blend rounded below u_min
    a = 0.0
    for _ in range(7):
        a = odd.follows(a, -6.0, dt)
        assert -6.0 <= a <= 0.0
    assert RateLimitedSet(dataclasses.replace(HE, u_min=-6.0, u_max=6.0, d_min=-6.0, d_max=6.0), odd).contains(
        (10.0, 100.0, 20.0, a))
    rng = np.random.default_rng(5)
    for act in ACTUATORS.values():
        for _ in range(500):
            last = rng.uniform(-5, 5)
            lo, hi = act.reach(last, -5.0, 5.0, dt)
            for end, bound in ((lo, -5.0), (hi, 5.0)):   # an end the lag sets is asked as U's bound itself
                if act.lag and act.lagged(last, bound, dt) == end:
                    assert act.asks(last, end, -5.0, 5.0, dt) == bound
            for target in (lo, hi, rng.uniform(lo, hi)):
                u = act.asks(last, target, -5.0, 5.0, dt)
                assert -5.0 <= u <= 5.0 and act.follows(last, u, dt) == pytest.approx(target, abs=1e-12)
                assert abs(act.lagged(last, u, dt) - act.follows(last, u, dt)) <= 1e-12   # never cut by the jerk
                assert min(last, u) <= act.lagged(last, u, dt) <= max(last, u)


@pytest.mark.parametrize("name", list(ACTUATORS))
def test_rate_limited_set_is_invariant_under_its_admissible_commands(name):
    """A falsifier: from states inside, any acceleration the bound set admits (and the hardest braking), asked of
    the actuator as a command (``Actuator.asks``) and applied as the world applies it (``Actuator.follows``),
    keeps the next state inside whatever the lead does within D, and the gap above h_min, for 60 steps."""
    act = ACTUATORS[name]
    S = RateLimitedSet(HE, act)
    rng = np.random.default_rng(2)
    runs = 0
    while runs < 150:
        x = random_state(rng)
        if not S.contains(x):
            continue
        runs += 1
        for _ in range(60):
            v, h, vL, a = x
            h_next, vL_worst = h + HE.dt * (vL - v), max(vL + HE.dt * HE.d_min, 0.0)
            bound = S.bound(v, a)
            speeds = bound.speed_intervals(h_next, vL_worst)
            assert speeds, f"no admissible command from {x}, a state inside"
            lo, hi = bound.commands
            top = speeds[0][1]
            c_hi = min(hi, (top - v) / HE.dt - 1e-9) if top > 0 else lo
            target = rng.choice([lo, c_hi, rng.uniform(lo, max(lo, c_hi))])
            assert lo <= target <= hi
            command = act.asks(a, target, HE.u_min, HE.u_max, HE.dt)
            assert HE.u_min <= command <= HE.u_max
            applied = act.follows(a, command, HE.dt)
            x = euler_step(x, applied, rng.choice([HE.d_min, HE.d_max, rng.uniform(HE.d_min, HE.d_max)]))
            assert x[1] >= HE.h_min - 1e-9 and S.contains(x), f"left the set at {x}"


@pytest.mark.parametrize("name", ["jerk 10", "jerk 5", "lag 0.5 s", "jerk 5, lag 0.3 s"])
def test_outside_the_rate_limited_set_the_hardest_braking_lead_wins(name):
    """Maximality: from a state outside (in the safe set), the lead braking at d_min brings the gap below h_min
    whatever commands the actuator follows; the set that lets the acceleration jump keeps some of these states,
    so it would be wrong here."""
    act = ACTUATORS[name]
    S, M = RateLimitedSet(HE, act), MaximalSet(HE)
    rng = np.random.default_rng(3)
    seen = kept_by_jump = 0
    while seen < 80:
        x = random_state(rng)
        if S.contains(x) or x[1] < HE.h_min:
            continue
        seen += 1
        kept_by_jump += bool(M.contains([x[:3]])[0])
        y = x
        for _ in range(2000):   # the best the ego can do: brake as hard as the actuator allows
            y = euler_step(y, act.follows(y[3], HE.u_min, HE.dt), HE.d_min)
            if y[1] < HE.h_min:
                break
        assert y[1] < HE.h_min, f"{x} is outside, yet the hardest braking kept h >= h_min"
    assert kept_by_jump > 0


def test_rate_limited_set_refuses_what_it_does_not_model():
    with pytest.raises(ValueError, match="exact"):
        RateLimitedSet(CarFollowingParams(integration="exact"), Actuator(jerk=10, profile="hold"))
    with pytest.raises(ValueError, match="v_L, a, q_1..q_1"):
        RateLimitedSet(HE, Actuator(jerk=10, delay=1, profile="hold")).contains((10, 20, 10, 0))
    with pytest.raises(ValueError, match="queues 1"):
        RateLimitedSet(HE, Actuator(jerk=10, delay=1, profile="hold")).bound(10, 0)
    with pytest.raises(ValueError, match="hold"):
        RateLimitedSet(HE, Actuator(jerk=10))
    with pytest.raises(ValueError, match="beyond 60 s"):
        Actuator(lag=61.0, profile="hold")
    with pytest.raises(ValueError, match="would not end"):
        RateLimitedSet(dataclasses.replace(HE, dt=1e-9), Actuator(lag=60.0, profile="hold"))


# ---- a reaction delay on (7.3)'s Euler step --------------------------------------------------------------------
DELAYED = {"jerk 10, delay 1": Actuator(jerk=10.0, delay=1, profile="hold"),
           "lag 0.3 s, delay 3": Actuator(lag=0.3, delay=3, profile="hold"),
           "jerk 5, lag 0.2 s, delay 2": Actuator(jerk=5.0, lag=0.2, delay=2, profile="hold")}


def delayed_step(x, applied, lead_accel, p=HE):
    """The world with a delay: the front of the queue is applied, ``applied`` joins its back."""
    v, h, vL, _, *queue = x
    now, queue = (queue + [applied])[0], (queue + [applied])[1:]
    return (max(v + p.dt * now, 0.0), h + p.dt * (vL - v), min(max(vL + p.dt * lead_accel, 0.0), p.v_max), now, *queue)


def random_queued_state(act: Actuator, rng, p=HE):
    """A state whose queue the actuator could have made (each acceleration within reach of the one before)."""
    a = rng.uniform(p.u_min, p.u_max)
    queue, last = [], a
    for _ in range(act.delay):
        last = act.follows(last, rng.uniform(p.u_min, p.u_max), p.dt)
        queue.append(last)
    return (rng.uniform(0, p.v_max), rng.uniform(p.h_min, 120.0), rng.uniform(0, p.v_max), a, *queue)


def test_without_a_delay_the_queue_is_empty_and_the_set_is_the_same():
    rng = np.random.default_rng(7)
    for act in ACTUATORS.values():
        S = RateLimitedSet(HE, act)
        for _ in range(300):
            x = random_state(rng)
            assert S.bound(x[0], x[3]).reference == x[0] and S.bound(x[0], x[3], ()).queue == ()


@pytest.mark.parametrize("name", list(DELAYED))
def test_the_delayed_set_is_invariant_under_its_admissible_commands(name):
    """A falsifier: from states inside, any acceleration the bound set admits for the back of the queue (asked as a
    command, applied as the world applies it), whatever the lead does within D, keeps the state inside and the gap
    above h_min for 60 steps."""
    act = DELAYED[name]
    S = RateLimitedSet(HE, act)
    rng = np.random.default_rng(8)
    runs = 0
    while runs < 120:
        x = random_queued_state(act, rng)
        if not S.contains(x):
            continue
        runs += 1
        for _ in range(60):
            v, h, vL, a, *queue = x
            bound = S.bound(v, a, queue)
            speeds = bound.speed_intervals(h + HE.dt * (vL - v), max(vL + HE.dt * HE.d_min, 0.0))
            assert speeds, f"no admissible command from {x}, a state inside"
            lo, hi = bound.commands
            top = speeds[0][1]
            c_hi = min(hi, (top - bound.reference) / HE.dt - 1e-9) if top > 0 else lo
            target = rng.choice([lo, c_hi, rng.uniform(lo, max(lo, c_hi))])
            u = act.asks(queue[-1], target, HE.u_min, HE.u_max, HE.dt)
            x = delayed_step(x, act.follows(queue[-1], u, HE.dt),
                             rng.choice([HE.d_min, HE.d_max, rng.uniform(HE.d_min, HE.d_max)]))
            assert x[1] >= HE.h_min - 1e-9 and S.contains(x), f"left the set at {x}"


@pytest.mark.parametrize("name", list(DELAYED))
def test_outside_the_delayed_set_the_hardest_braking_loses_h_min_or_passes_the_top_speed(name):
    """Maximality: from a state outside, the queue and then the hardest braking either lose h_min behind the lead
    braking at d_min or take the speed past v_max (the set keeps the speed within the model's range)."""
    act = DELAYED[name]
    S = RateLimitedSet(HE, act)
    rng = np.random.default_rng(9)
    seen = 0
    while seen < 60:
        x = random_queued_state(act, rng)
        if S.contains(x) or x[1] < HE.h_min:
            continue
        seen += 1
        y, lost = x, False
        for _ in range(3000):
            y = delayed_step(y, act.follows(y[-1], HE.u_min, HE.dt), HE.d_min)
            lost = y[1] < HE.h_min or y[0] > HE.v_max
            if lost:
                break
        assert lost, f"{x} is outside, yet the hardest braking kept h >= h_min and v <= v_max"


def test_a_guardian_that_ignores_the_delay_loses_h_min():
    """The ego asks full throttle; a guardian bound to the actuator without its delay (the queue ignored) picks the
    command as if it acted at once; the world applies it three steps late: the lead braking at d_min wins. The
    delayed set's own choice keeps h_min from the same starts."""
    act = DELAYED["lag 0.3 s, delay 3"]
    S, blind = RateLimitedSet(HE, act), RateLimitedSet(HE, dataclasses.replace(act, delay=0))
    rng = np.random.default_rng(10)
    least = {"delayed": math.inf, "blind": math.inf}
    for _ in range(40):
        x0 = (rng.uniform(15, 28), rng.uniform(30, 60), rng.uniform(15, 28), 0.0, 0.0, 0.0, 0.0)
        if not S.contains(x0):
            continue
        brake_at = rng.integers(0, 60)
        for who in least:
            x = x0
            for t in range(200):
                v, h, vL, a, *queue = x
                h_next, vL_next = h + HE.dt * (vL - v), max(vL + HE.dt * HE.d_min, 0.0)
                bound = S.bound(v, a, queue) if who == "delayed" else blind.bound(v, queue[-1])
                speeds = bound.speed_intervals(h_next, vL_next)
                lo, hi = bound.commands
                target = lo if not speeds else min(hi, (speeds[0][1] - bound.reference) / HE.dt - 1e-9)
                u = act.asks(queue[-1], max(target, lo), HE.u_min, HE.u_max, HE.dt)
                x = delayed_step(x, act.follows(queue[-1], u, HE.dt),
                                 HE.d_min if t >= brake_at else rng.uniform(-1, 1))
                least[who] = min(least[who], x[1])
    assert least["delayed"] >= HE.h_min - 1e-9 and least["blind"] < HE.h_min - 0.1, least


def test_the_guardian_refuses_a_delay_by_name():
    from guardian.config import GuardianConfig
    from guardian.decide.bicycle import BicycleGuardian
    from guardian.decide.kinematics import BicycleEgo

    kin = BicycleEgo(HE.dt, 6.0, 5.0, 2.0, 4.0, 3, math.pi / 4)
    with pytest.raises(ValueError, match="reaction delay is not supervised yet"):
        BicycleGuardian(kin, GuardianConfig(), False, Actuator(jerk=5.0, delay=1, profile="hold"))
