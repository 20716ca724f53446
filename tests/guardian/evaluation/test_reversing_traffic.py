"""Traffic that drives backwards: highway-env lets its cars reverse (``Vehicle.MIN_SPEED = -40``; IDM brakes
into reverse when it stands inside its desired gap), the traffic model (speeds in ``[0, v_max]``) does not.
The guardian covers a car that may be reversing before it looks again (``GuardianConfig.reversing``: seen driving
backwards, or slower than ``traffic_accel * reverse_horizon``) ``reverse_reach`` metres further back and in the
lanes beside its own; the monitor counts the steps where a car backed up further than that."""
import warnings
from types import SimpleNamespace

import gymnasium as gym
import highway_env  # noqa: F401 - registers highway-v0
import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

import envs  # noqa: F401 - registers guardian/Merge-v0
from guardian.config import GuardianConfig
from guardian.adapters.highway_env.monitor import ModelMonitor
from guardian.evaluation.rollouts import Rollout, highway_rollouts
from guardian.model.roads import Road
from guardian.model.reversing import ReversingCover
from guardian.adapters.highway_env.scene import road_scene
from guardian.wrappers.guardian import Guardian

SIM_DT = 1 / 15   # highway-v0's simulation step [s]


class Reverser(Vehicle):
    """Backs up from ``speed`` < 0 and comes to rest after at most ``distance`` metres, easing off evenly."""

    def __init__(self, road, position, speed: float, distance: float):
        super().__init__(road, position, speed=speed)
        self.ease = speed ** 2 / (2 * (distance - abs(speed) * SIM_DT))   # Euler's sum stays below distance
        self.backed = 0.0

    def step(self, dt):
        a = min(self.ease, -self.speed / dt) if self.speed < 0 else 0.0
        self.action = {"steering": 0.0, "acceleration": a}
        self.backed -= min(self.speed, 0.0) * dt
        super().step(dt)


def _highway(config: GuardianConfig | None):
    env = gym.make("highway-v0", config={"lanes_count": 2, "vehicles_count": 0, "duration": 12,
                                         "action": {"type": "ContinuousAction"}})
    return Guardian(env, None, config or GuardianConfig()) if config is not None else env


def _episode(env, rng, queue: bool = False) -> tuple:
    """The ego, full throttle, approaches a car that already backs towards it (``queue``: behind a car
    that backs up too, the nearer one by up to ``reverse_reach`` more); (crashed, start inside, metres the
    nearer car backed up)."""
    base, ego = _ego_at_start(env, rng)
    reach = GuardianConfig().reverse_reach
    fastest = -6.0 if queue else -2.5   # a queue backs up further: fast enough to pass one reach in the episode
    gap = float(rng.uniform(12.0, 42.0)) + reach * (2 if queue else 1)   # beyond the rear it keeps room behind
    speed, distance = float(rng.uniform(fastest, -0.5)), float(rng.uniform(1.0, reach))
    car = Reverser(base.road, [ego.position[0] + ego.LENGTH + gap, 0.0], speed, distance)
    base.road.vehicles = [ego, car]
    if queue:   # the same start, eased off less: it backs up at least as fast as its leader, never into it
        car.ease = speed ** 2 / (2 * (distance + float(rng.uniform(0.5, reach)) - abs(speed) * SIM_DT))
        base.road.vehicles.append(Reverser(base.road, [car.position[0] + car.LENGTH + 3.0, 0.0], speed, distance))
    return _full_throttle(env, ego, car)


def _ego_at_start(env, rng) -> tuple:
    """A fresh episode with the ego at x = 100 m in lane 0, heading along, at 5-20 m/s; (the env's base, the ego)."""
    env.reset(seed=int(rng.integers(1 << 30)))
    base = env.unwrapped
    ego = base.vehicle
    ego.position = np.array([100.0, 0.0])
    ego.heading, ego.speed = 0.0, float(rng.uniform(5.0, 20.0))
    return base, ego


def _full_throttle(env, ego, car) -> tuple:
    """12 policy steps of full throttle, or until a crash; (crashed, start inside, metres ``car`` backed up)."""
    inside = env.starts_inside()[0]
    for _ in range(12):
        env.step(np.array([1.0, 0.0]))
        if ego.crashed:
            break
    return ego.crashed, inside, car.backed


def test_a_guarded_car_never_reaches_a_car_that_backs_up_within_the_reach():
    """A falsifier: random speeds, gaps and reversals of at most ``reverse_reach``; from every start inside the
    guardian's sets the ego, asking full throttle, never touches the reversing car. Without the cover
    (``reverse_reach = 0``: the car taken to stand where it is after the step) the same draws crash."""
    inside_runs, crashes_bare = _falsify(_episode, GuardianConfig(reverse_reach=0.0), seed=7)
    assert inside_runs >= 15 and crashes_bare > 0


def _falsify(episode, weaker: GuardianConfig, seed: int, draws: int = 30) -> tuple:
    """``draws`` episodes with the default cover (no contact from a start inside, no reversal beyond the reach),
    each drawn again with ``weaker``; (starts inside, contacts from a start inside with ``weaker``)."""
    rng = np.random.default_rng(seed)
    covered, bare = _highway(GuardianConfig()), _highway(weaker)
    inside_runs = crashes_bare = 0
    for _ in range(draws):
        state = rng.bit_generator.state
        crashed, inside, backed = episode(covered, rng)
        assert backed <= GuardianConfig().reverse_reach
        if inside:
            inside_runs += 1
            assert not crashed
        rng.bit_generator.state = state
        crashed, inside, _ = episode(bare, rng)
        crashes_bare += crashed and inside
    return inside_runs, crashes_bare


class Creeper(Vehicle):
    """Creeps forward at ``speed`` > 0, brakes at the traffic's bound (6 m/s^2) into reverse until ``-back_speed``,
    then eases off to rest after backing up at most ``distance`` metres in all: IDM at standstill inside its gap."""

    def __init__(self, road, position, speed: float, back_speed: float, distance: float):
        super().__init__(road, position, speed=speed)
        self.back_speed, self.distance, self.ease, self.backed = back_speed, distance, None, 0.0

    def step(self, dt):
        if self.ease is None and self.speed > -self.back_speed:
            a = -6.0
        else:
            if self.ease is None:
                self.ease = self.speed ** 2 / (2 * (self.distance - self.backed - abs(self.speed) * dt))
            a = min(self.ease, -self.speed / dt) if self.speed < 0 else 0.0
        self.action = {"steering": 0.0, "acceleration": a}
        self.backed -= min(self.speed, 0.0) * dt
        super().step(dt)


def _creeping_episode(env, rng) -> tuple:
    """The ego, full throttle, approaches a car creeping forward that brakes into reverse at once; (crashed,
    start inside, metres the car backed up)."""
    base, ego = _ego_at_start(env, rng)
    reach = GuardianConfig().reverse_reach
    gap = float(rng.uniform(12.0, 42.0)) + reach
    car = Creeper(base.road, [ego.position[0] + ego.LENGTH + gap, 0.0], float(rng.uniform(0.1, 5.9)),
                  float(rng.uniform(0.5, 3.0)), float(rng.uniform(2.0, reach)))
    base.road.vehicles = [ego, car]
    return _full_throttle(env, ego, car)


def test_a_guarded_car_never_reaches_a_creeping_car_that_brakes_into_reverse():
    """A falsifier: a car creeping forward (0.1-5.9 m/s, slower than ``traffic_accel * reverse_horizon``) brakes
    into reverse and backs up at most ``reverse_reach``; from every start inside the ego, asking full throttle,
    never touches it. With the cover only for cars seen driving backwards (``reverse_horizon = 0``, as highway-env
    seed 41 of LineHuggingIDM found: a car seen at 0.73 m/s backed 2.8 m into the guarded car) the draws crash."""
    inside_runs, crashes_late = _falsify(_creeping_episode, GuardianConfig(reverse_horizon=0.0), seed=5)
    assert inside_runs >= 15 and crashes_late > 0


def test_behind_a_queue_that_backs_up_the_reach_adds_up(monkeypatch):
    """The same falsifier behind two cars that reverse, the nearer one backing up to ``reverse_reach`` more
    than its leader: no contact from a start inside; with one reach per car (no queue rule) the draws crash."""
    import guardian.model.reversing as reversing

    def outcomes(seed):
        rng, covered = np.random.default_rng(seed), _highway(GuardianConfig())
        runs = [_episode(covered, rng, queue=True) for _ in range(30)]
        return [crashed for crashed, inside, _ in runs if inside]

    with_queue = outcomes(11)
    assert len(with_queue) >= 15 and not any(with_queue)
    monkeypatch.setattr(reversing.ReversingCover, "reaches", lambda self, fronts, speeds, lanes:
                        [self.reach if self.may_reverse(s) else 0.0 for s in speeds])
    assert any(outcomes(11))


def test_a_reversing_car_is_taken_longer_and_in_the_lanes_beside_it():
    env = _highway(None)
    env.reset(seed=0)
    base = env.unwrapped
    road = Road(2, 4.0)
    for speed, lanes, length in ((-1.0, {1, 2}, 5.0 + 3.0), (1.0, {2}, 5.0)):
        car = Vehicle(base.road, [150.0, 0.0], speed=speed)
        base.road.vehicles = [base.vehicle, car]
        (seen,) = road_scene(base, road, reversing=ReversingCover(3.0)).others
        assert (set(seen.lanes), seen.length) == (lanes, length)
    (seen,) = road_scene(base, road, reversing=ReversingCover(3.0, below=2.0)).others   # creeping: may reverse soon
    assert (set(seen.lanes), seen.length) == ({2}, 8.0)   # longer, and swings only once it drives backwards
    base.road.vehicles = [base.vehicle, Vehicle(base.road, [150.0, 0.0], speed=-1.0),
                          Vehicle(base.road, [140.0, 0.0], speed=-1.0)]
    assert [c.length for c in road_scene(base, road, reversing=ReversingCover(3.0)).others] == [8.0, 11.0]   # a queue


def _monitor(reach, *cars):
    monitor = ModelMonitor(0.1, (-6.0, 6.0), 40.0, watch_traffic=True, reversing=ReversingCover(reach))
    monitor._bicycle_fits = lambda prev, now: True
    ego = SimpleNamespace(position=np.zeros(2), speed=0.0, heading=0.0, lane_index=("a", "b", 1))
    return monitor, SimpleNamespace(vehicle=ego, road=SimpleNamespace(vehicles=[ego, *cars]))


def _car(x, lane=0):
    return SimpleNamespace(position=np.array([x, 0.0]), speed=0.0, heading=0.0, lane_index=("a", "b", lane))


def test_the_monitor_counts_the_steps_a_car_backs_up_beyond_the_reach():
    car = _car(50.0)
    monitor, base = _monitor(0.5, car)
    seen = []
    for speed in [-1.0] * 8 + [0.0] + [-1.0] * 3:
        car.speed = speed
        seen.append(monitor.observe(base, [0.0, 0.0])["traffic_reversing_uncovered"])
        car.position[0] += speed * 0.1
    # 0.1 m per step at -1 m/s: more than 0.5 m behind where it was first seen reversing from the 7th step
    # of the first reversal on; a step seen at standstill ends it, and the next reversal starts afresh
    assert seen == [0, 0, 0, 0, 0, 0, 1, 1, 0, 0, 0, 0]
    assert monitor.totals["traffic_reversing_uncovered"] == 2


@pytest.mark.parametrize("leader_reverses, counted", [(True, 0), (False, 1)])
def test_a_car_behind_a_car_that_reverses_too_may_back_up_further(leader_reverses, counted):
    """A queue that reverses backs up link by link: the second car's reach adds its leader's."""
    cover = ReversingCover(4.0)
    assert cover.reaches([30.0, 20.0, 10.0, 5.0], [-1.0, -1.0, 2.0, -1.0], [1, 1, 1, 1]) == [4.0, 8.0, 0.0, 4.0]
    assert cover.reaches([30.0, 20.0], [-1.0, -1.0], [1, 2]) == [4.0, 4.0]   # other lanes: no queue
    creeping = ReversingCover(4.0, below=3.0)   # the car at 2 m/s may reverse soon, behind a car that reverses;
    assert creeping.reaches([30.0, 20.0, 10.0, 5.0], [-1.0, -1.0, 2.0, -1.0], [1, 1, 1, 1]) == [4.0, 8.0, 12.0, 4.0]
    assert creeping.reaches([30.0, 20.0], [0.0, 1.0], [1, 1]) == [4.0, 4.0]   # a slow queue: one reach each
    leader, follower = _car(60.0), _car(50.0)
    monitor, base = _monitor(0.5, leader, follower)
    seen = []
    for _ in range(8):   # the follower backs up 0.7 m: within 0.5 m + its leader's 0.5 m while the leader reverses
        leader.speed, follower.speed = (-0.5 if leader_reverses else 0.0), -1.0
        seen.append(monitor.observe(base, [0.0, 0.0])["traffic_reversing_uncovered"])
        for c in (leader, follower):
            c.position[0] += c.speed * 0.1
    assert sum(seen) == counted * 2


@pytest.mark.parametrize("seed, density, overapprox, episode", [
    (0, "medium", "trivial", 245), (250, "easy", "trivial", 184), (250, "easy", "ordered", 184),
    (500, "medium", "trivial", 151), (500, "hard", "trivial", 46), (500, "hard", "ordered", 166),
    (750, "hard", "ordered", 141),
])
def test_the_at_fault_crashes_with_reversing_traffic_at_the_ramps_end_are_covered(seed, density, overapprox, episode):
    """The seven collisions the judge gave a guarded car in 6,000 episodes with four guarded cars on
    guardian/Merge-v0 (benchmarks/bench_multiagent.py): each with an IDM car backing up at the on-ramp's
    end, its body swinging into the main lane beside a guarded car that had just merged (or backing into
    a guarded car standing behind it). The same episodes now end with no collision at a guarded car's fault."""
    config = {"duration": 20, "policy_frequency": 5, "traffic": density,
              "observation": {"type": "AttributesObservation", "attributes": ["time"]}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        r = highway_rollouts(Rollout("guardian/Merge-v0", "merge", action="meta", controlled=4, env_config=config,
                                     config=GuardianConfig(overapprox=overapprox)), 1, seed, first_episode=episode)
    assert r["ego_at_fault_collisions"] + r["ego_at_fault_after_outside_starts"] == 0, r["crashes"]
    assert r["unchecked_entries"] == 0 and r["traffic_reversing_uncovered_steps"] == 0


def test_highway_envs_idm_backs_up_within_the_default_reach(benchmark_module):
    """highway-env's own IDMVehicle, behind a standing car in its lane and beside a standing car that its
    neighbour search takes as ahead (``benchmarks/idm_reversal.py``'s two families, around their worst starts),
    never backs up further than the default reach; the old 8 m did not cover the car beside."""
    bench = benchmark_module("idm_reversal")
    behind = [bench.longest_reversal(gap, speed) for gap in (0.0, 1.0, 3.0) for speed in (0.0, 2.0, 5.0)]
    beside = [bench.longest_reversal(gap, speed, beside=True) for gap in (0.2, 0.4, 1.0, 3.0) for speed in (0.0, 2.0, 4.0)]
    longest = max(r for r in behind + beside if r is not None)
    assert longest <= GuardianConfig().reverse_reach
    assert max(r for r in beside if r is not None) > 8.0
