"""The Guardian on highway-env's roads beyond one straight segment (merge-v0, exit-v0, guardian/Merge-v0) and
with several guarded cars (MultiAgentAction): rollouts judged by the independent fault judge, unguarded
figures on the same seeds beside, one decision object per car, and the ordered announcements."""
import warnings
from dataclasses import replace

import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

import envs  # noqa: F401 - registers guardian/Merge-v0
from guardian.config import GuardianConfig
from guardian.errors import ConfigError
from guardian.evaluation.rollouts import Rollout, highway_rollouts
from guardian.wrappers.guardian import Guardian

warnings.filterwarnings("ignore", message=".*out of date.*")


# ---- one guarded car on merge-v0 and exit-v0, both action types ----------------------------------------
@pytest.mark.parametrize("env_id, action, seed, episodes", [
    ("merge-v0", "meta", 0, 2),                 # unguarded: the reckless ego cuts into main-road cars
    ("exit-v0", "meta", 0, 2),
    ("guardian/Merge-v0", "continuous", 2, 1),  # merge-v0's road and traffic; continuous (merge-v0 fails there)
])
def test_a_reckless_agent_crashes_unguarded_and_is_kept_safe_guarded(env_id, action, seed, episodes):
    free = highway_rollouts(Rollout(env_id, "reckless", action=action, guarded=False), episodes, seed)
    assert free["ego_at_fault_collisions"] > 0
    guarded = highway_rollouts(Rollout(env_id, "reckless", action=action), episodes, seed)
    assert guarded["collisions"] == 0 and guarded["ego_at_fault_collisions"] == 0
    assert guarded["unsupervised_steps"] == 0 and guarded["unchecked_entries"] == 0
    assert guarded["override_steps"] > 0 and guarded["model_violation_steps"] == 0


def test_a_continuous_agent_on_exit_v0_stays_on_the_road():
    """Turning gently right for 3 s, then holding the wheel straight: unguarded the body leaves the road
    (highway-env lets it), guarded every policy step ends with the body on the road."""
    def worst_depth(guardian):
        env = gym.make("exit-v0", config={"action": {"type": "ContinuousAction"}, "vehicles_count": 0})
        if guardian:
            env = Guardian(env)
        obs, _ = env.reset(seed=0)
        from guardian.model.roads import outline
        from guardian.adapters.highway_env.road import read_road

        road, worst = read_road(env.unwrapped), 0.0
        for t in range(18):
            obs, _, term, trunc, _ = env.step(np.array([0.0, 0.02 if t < 3 else 0.0], dtype=np.float32))
            v = env.unwrapped.vehicle
            xs, ys = outline([v.position[0]], [v.position[1]], [v.heading], v.LENGTH, v.WIDTH)
            worst = max(worst, float(np.max(road.depth(xs, ys))))
            if term or trunc:
                break
        return worst

    assert worst_depth(False) > 1.0
    assert worst_depth(True) == 0.0


@pytest.mark.parametrize("env_id", ["merge-v0", "merge-v1"])
def test_merge_v0_with_continuous_actions_is_refused_with_the_reason(env_id):
    with pytest.raises(ValueError, match=f"{env_id} fails with ContinuousAction.*guardian/Merge-v0"):
        highway_rollouts(Rollout(env_id, "random", action="continuous"), 1, 0)
    with pytest.raises(ValueError, match=f"{env_id} has one controlled car"):
        highway_rollouts(Rollout(env_id, "random", action="meta", controlled=2), 1, 0)


# ---- several guarded cars ------------------------------------------------------------------------------
def _multi(n=3, kind="DiscreteMetaAction", traffic="medium", overapprox="trivial", env_id="guardian/Merge-v0"):
    config = {"action": {"type": "MultiAgentAction", "action_config": {"type": kind}}, "controlled_vehicles": n}
    if env_id == "guardian/Merge-v0":
        config["traffic"] = traffic
    return Guardian(gym.make(env_id, config=config), None, GuardianConfig(overapprox=overapprox))


@pytest.mark.parametrize("kind", ["DiscreteMetaAction", "ContinuousAction"])
def test_every_controlled_car_has_its_own_guardian(kind):
    env = _multi(3, kind)
    _, info = env.reset(seed=1)
    base = env.unwrapped
    assert info["guardian"]["controlled"] == 3 and len(info["guardian"]["agents_start_inside"]) == 3
    cars = base.controlled_vehicles
    assert [c.vehicle for c in env.cars] == cars
    assert len({id(c.guard) for c in env.cars}) == 3 and len({id(c.monitor) for c in env.cars}) == 3
    assert len({id(c.guard.kin) for c in env.cars}) == 3
    _, _, _, _, info = env.step(env.action_space.sample())
    g = info["guardian"]
    assert len(g["agents"]) == 3 and g["controlled"] == 3
    assert all(r["sim_steps"] == base.config["simulation_frequency"] // base.config["policy_frequency"]
               for r in g["agents"])
    assert g["unsupervised_steps"] == 0
    assert len(g["applied_action"]) == 3
    env.close()


def test_each_guarded_car_sees_the_others_as_traffic():
    """Car 0's decision object is asked about a scene holding cars 1 and 2 (and the IDM cars), as guarded
    cars that announce; its own car is not in it."""
    from guardian.adapters.highway_env.scene import road_scene

    env = _multi(3)
    env.reset(seed=1)
    base = env.unwrapped
    car = env.cars[0]
    scene = road_scene(base, env.road, ego=car.vehicle, guarded=env.supervision.guarded)
    names = {c.name for c in scene.others}
    idx = {base.road.vehicles.index(v) for v in base.controlled_vehicles}
    me = base.road.vehicles.index(car.vehicle)
    assert f"car {me}" not in names and {f"car {k}" for k in idx - {me}} <= names
    assert {c.name for c in scene.others if c.announces} == {f"car {k}" for k in idx - {me}}
    env.close()


@pytest.mark.parametrize("overapprox", ["trivial", "ordered"])
def test_random_guarded_cars_do_not_crash_into_each_other_or_at_their_fault(overapprox):
    r = highway_rollouts(Rollout("guardian/Merge-v0", "random", action="meta", controlled=4,
                                 env_config={"traffic": "hard", "duration": 10, "policy_frequency": 5},
                                 config=GuardianConfig(overapprox=overapprox)), 3, 0)
    assert r["guarded_cars"] == 4 and len(r["agents"]) == 4
    assert r["guarded_pair_collisions"] == 0 and r["ego_at_fault_collisions"] == 0 and r["collisions"] == 0
    assert r["unsupervised_steps"] == 0 and r["unchecked_entries"] == 0
    assert sum(a["override_steps"] for a in r["agents"]) == r["override_steps"]


def test_unguarded_random_cars_do_crash_on_the_same_seeds():
    r = highway_rollouts(Rollout("guardian/Merge-v0", "random", action="meta", controlled=4, guarded=False,
                                 env_config={"traffic": "hard", "duration": 10, "policy_frequency": 5}), 3, 0)
    assert r["ego_at_fault_collisions"] > 0


def _two_cars_beside_a_free_middle_lane(overapprox):
    """highway-v0, three lanes, no traffic: guarded car 0 in lane 0 and car 1 in lane 2, level; both ask for
    lane 1 at once."""
    env = gym.make("highway-v0", config={"lanes_count": 3, "vehicles_count": 0, "controlled_vehicles": 2,
                                         "action": {"type": "MultiAgentAction",
                                                    "action_config": {"type": "DiscreteMetaAction"}}})
    env = Guardian(env, None, GuardianConfig(overapprox=overapprox))
    env.reset(seed=0)
    base = env.unwrapped
    for v, lane, x in zip(base.controlled_vehicles, (0, 2), (100.0, 100.5)):
        v.position = np.array([x, 4.0 * lane])
        v.heading, v.speed = 0.0, 25.0
        v.lane_index = v.target_lane_index = ("0", "1", lane)
        v.lane = base.road.network.get_lane(v.lane_index)
    names = base.action_type.agents_action_types[0].actions_indexes
    _, _, _, _, info = env.step((names["LANE_RIGHT"], names["LANE_LEFT"]))
    return [r["refused_lane_change"] for r in info["guardian"]["agents"]], info["guardian"]


def test_ordered_lets_one_of_two_cars_announce_the_lane_both_want():
    """Example 8: trivially each must assume the other may enter the middle lane beside it, so both lane
    changes are refused; ordered, the first in the order announces and enters, the second knows it and yields."""
    trivial, _ = _two_cars_beside_a_free_middle_lane("trivial")
    assert trivial == [True, True]
    ordered, g = _two_cars_beside_a_free_middle_lane("ordered")
    assert g["order"] == [1, 0]              # car 1 is 0.5 m ahead: it announces first
    assert ordered == [True, False]


def test_idm_cars_announce_nothing():
    from guardian.adapters.highway_env.scene import road_scene

    env = _multi(2, overapprox="ordered")
    env.reset(seed=3)
    base = env.unwrapped
    scene = road_scene(base, env.road, ego=env.cars[0].vehicle, guarded=env.supervision.guarded)
    other = base.road.vehicles.index(env.cars[1].vehicle)
    assert [c.name for c in scene.others if c.announces] == [f"car {other}"]
    idm = {f"car {k}" for k, v in enumerate(base.road.vehicles) if v not in base.controlled_vehicles}
    assert idm and idm <= {c.name for c in scene.others if not c.announces}
    env.close()


def test_mixed_or_unsupported_action_types_are_refused():
    env = gym.make("highway-v0", config={"controlled_vehicles": 2, "action": {
        "type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction", "lateral": False}}})
    with pytest.raises(ConfigError, match="five meta actions"):
        Guardian(env)


def test_several_controlled_cars_need_a_traffic_mode_on_guarded_merge():
    with pytest.raises(ValueError, match="traffic easy, medium or hard"):
        gym.make("guardian/Merge-v0", config={"controlled_vehicles": 2}).reset(seed=0)


# ---- the tally's rules on hand-built cases -------------------------------------------------------------------
def _tally_env(n=2):
    env = gym.make("guardian/Merge-v0", config={"traffic": "easy", "controlled_vehicles": n, "action": {
        "type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction"}}})
    env.reset(seed=0)
    return env


def _place(base, v, index, x):
    lane = base.road.network.get_lane(index)
    v.position = np.array(lane.position(x, 0.0), float)
    v.heading = float(lane.heading_at(x))
    v.lane_index = v.target_lane_index = index
    v.lane = lane


def test_merges_count_cars_that_began_on_a_lane_that_ends_and_finished_on_one_that_goes_on():
    from guardian.evaluation.tally import HighwayTally

    env = _tally_env(2)
    base = env.unwrapped
    a, b = base.controlled_vehicles
    _place(base, a, ("b", "c", 2), 20.0)   # on the ramp's parallel part (it ends at x = 310)
    _place(base, b, ("b", "c", 2), 50.0)
    tally = HighwayTally(env, False, GuardianConfig())
    tally.start_episode(env, 0, None)
    _place(base, a, ("b", "c", 1), 60.0)   # a reached the main road; b stayed on the ramp
    tally.end_episode(env, 0)
    r = tally.result(1)
    assert (r["merges"], r["on_ending_lane"]) == (1, 2)
    assert [(c["merges"], c["on_ending_lane"]) for c in r["agents"]] == [(1, 1), (0, 1)]
    assert r["agents"][0]["distance_mean"] == pytest.approx(40.0)
    env.close()


def test_a_crash_between_two_guarded_cars_counts_once_and_against_the_one_blamed():
    from guardian.evaluation.judge import Crash
    from guardian.evaluation.tally import HighwayTally

    env = _tally_env(2)
    tally = HighwayTally(env, False, GuardianConfig())
    tally.start_episode(env, 0, None)
    tally._count_crash(Crash(3, "other", "entry", "car 1", car=0, partner_car=1), {})
    r = tally.result(1)
    assert r["collisions"] == 1 and r["guarded_pair_collisions"] == 1
    assert r["ego_at_fault_collisions"] + r["ego_at_fault_after_outside_starts"] == 1
    assert [(c["collisions"], c["at_fault_collisions"]) for c in r["agents"]] == [(1, 0), (1, 1)]
    env.close()


@pytest.mark.parametrize("env_id, action, seed, episode", [
    ("merge-v0", "meta", 0, 147),                     # an IDM car changed lanes in front of the ego unseen
    ("guardian/Merge-v0", "continuous", 250, 176),    # a follower on the previous segment did not brake
    ("guardian/Merge-v0", "continuous", 500, 182),
])
def test_the_at_fault_crashes_found_on_merge_roads_with_traffic_that_did_not_see_the_ego_are_covered(
        env_id, action, seed, episode):
    """The three collisions the judge gave a guarded car in 1,000-episode runs with highway-env's v0 search
    (a car sees only its own lane segment): each came right after steps in which a traffic car missed the
    ego. The guardian now treats such a car as one that neither brakes for the ego nor weighs it when
    changing lanes (``guardian.adapters.highway_env.blindness.blind_to``): the same episodes, blind steps and
    all, end without a collision; with the connected search (merge-v1's, guardian/Merge-v0's default) nobody is blind."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        blind = Rollout(env_id, "random", action=action, env_config={"neighbour_vehicles_connected_lanes": False})
        r = highway_rollouts(blind, 1, seed, first_episode=episode)
        if env_id == "merge-v0":  # guardian/Merge-v0's default search is the connected one: its own test
            seen = highway_rollouts(replace(blind, env_config={"neighbour_vehicles_connected_lanes": True}), 1, seed,
                                    first_episode=episode)
            assert seen["collisions"] == 0 and seen["traffic_blind_steps"] == 0
    assert r["traffic_blind_steps"] > 0 and r["collisions"] == 0


def test_guarded_merge_traffic_sees_across_lane_segments_by_default():
    """guardian/Merge-v0 sets highway-env's connected-lane search (merge-v1's); False gives merge-v0's back."""
    for config, expected in (({}, True), ({"neighbour_vehicles_connected_lanes": False}, False)):
        env = gym.make("guardian/Merge-v0", config=config)
        env.reset(seed=0)
        assert env.unwrapped.road.neighbour_vehicles_connected_lanes is expected
        env.close()


@pytest.mark.parametrize("episode", [128, 183])
def test_the_unchecked_entries_found_riding_the_ramps_border_are_gone(episode):
    """``guardian rollout --env guardian/Merge-v0 --action continuous --agent reckless --seed 0`` (250
    episodes) counted three entries without a responsibility check: the reckless agent rode the line
    between slots 1 and 2 (the body a hair off the road's edge) until the ramp's lane came under the
    body; the guardian then took the touched lane as held and let full right steering into it unjudged
    (episode 128), or the body was left overlapping it (183). Now the body keeps the margin from the
    road's edge and a touched lane is judged as an entry: the same episodes count none."""
    r = highway_rollouts(Rollout("guardian/Merge-v0", "reckless", action="continuous"), 1, 0, first_episode=episode)
    assert r["unchecked_entries"] == 0 and r["collisions"] == 0
