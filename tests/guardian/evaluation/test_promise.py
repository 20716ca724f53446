"""The promise, row by row: every way the guardian was once seen to break it, replayed.

Each test reproduces a setting where the guardian let the ego cause a crash, entered a lane unchecked,
reversed, ran unsupervised or miscounted, and checks it no longer does. The decisions themselves are
tested on hand-built scenes in tests/guardian/decide/test_pointmass_guardian.py and tests/guardian/decide/test_bicycle_guardian.py; the
campaign over thousands of episodes is `guardian falsify` (docs/guardian.md).
"""
import gymnasium as gym
import highway_env  # noqa: F401
import numpy as np
import pytest

import envs  # noqa: F401
from guardian.evaluation.rollouts import OVERTAKE_ENV, Rollout, highway_env_config, highway_rollouts
from guardian.wrappers.guardian import Guardian

PROMISE = ("ego_at_fault_collisions", "unchecked_entries", "reversing_steps", "unsupervised_steps")


def _kept(r: dict) -> bool:
    return all(r[k] == 0 for k in PROMISE)


def test_random_agent_behind_an_aggressive_lead_among_traffic(traffic_library):
    """Catches: 16 of 244 episodes crashed, all caused by the ego (a leftward override into a fast car)."""
    r = highway_rollouts(Rollout(OVERTAKE_ENV, "random", library=traffic_library, intention="aggressive"), 6, 100)
    assert _kept(r) and r["safety_violations"] == 0


def test_adversarial_noise_entries_refused_are_never_booked_responsible(traffic_library):
    """Catches: 14 of 112 crashed; an entry refused in the record was booked as responsible by the ledger."""
    r = highway_rollouts(Rollout(OVERTAKE_ENV, "random", library=traffic_library, intention="aggressive",
                                 disturbance="adversarial"), 4, 2000)
    assert _kept(r) and r["safety_violations"] == 0


def test_three_lanes_twelve_cars_six_from_behind(traffic_library):
    """Catches: collisions with 12 cars on 3 lanes and with 6 cars starting behind."""
    r = highway_rollouts(Rollout(OVERTAKE_ENV, "reckless", library=traffic_library, intention="aggressive",
                                 traffic=12, env_config={"lanes_count": 3, "traffic_from_behind": 6}), 3, 7)
    assert _kept(r) and r["safety_violations"] == 0



def test_a_seeking_agent_on_the_lane_line_stays_in_the_safe_set(traffic_library):
    """Catches (found by `guardian falsify`): the seek agent, 12 fast cars from behind, 3 lanes; the guardian kept
    full throttle by steering along the lane line, where the noise decides whether the body touches the
    left lane, and the ego left the safe set (6.8) behind the lead at step 116."""
    r = highway_rollouts(Rollout(OVERTAKE_ENV, "seek", library=traffic_library, intention="aggressive",
                                 action="continuous", traffic=12,
                                 env_config={"lanes_count": 3, "observation": {"type": "OvertakeState"},
                                     "traffic_from_behind": 6, "traffic_speed_range": [30.0, 38.0]}), 1, 200001)
    assert _kept(r) and r["safety_violations"] == 0 and r["steps"] == 300

def test_among_traffic_the_ego_may_wait_behind_the_lead():
    """Catches: with the dissertation's v_ex >= 16 the ego had to overtake into traffic; now the scenario's
    default parameters let it stop, and the guardian refuses the old floor with traffic."""
    env = gym.make(OVERTAKE_ENV)
    assert env.unwrapped.params.v_ex_bounds[0] == 0.0 and env.unwrapped.config["traffic_count"] > 0


def test_a_car_cutting_in_ahead_is_braked_for(traffic_library):
    """Catches: the guardian held the agent's full throttle for 3.8 s into a car that cut in 29 m ahead,
    8 m/s slower. Here a car cuts into the ego's left lane 29 m ahead while the agent floors it."""
    cfg = highway_env_config(Rollout(OVERTAKE_ENV, "", library=traffic_library, intention="cautious", traffic=1,
                                     env_config={"lanes_count": 3, "traffic_from_behind": 0, "duration": 8}))
    env = Guardian(gym.make(OVERTAKE_ENV, config=cfg), traffic_library)
    env.reset(seed=0)
    base = env.unwrapped
    ego, car = base.vehicle, base.road.vehicles[2]
    ego.position = np.array([ego.position[0], ego.y_of(1.8)])  # the ego drives in the left lane
    ego.speed = 25.0
    base.lead.position = np.array([ego.position[0] - 40.0, base.lead.position[1]])
    car.position = np.array([ego.position[0] + 29.0, ego.position[1]])
    car.speed = car.target_speed = 17.0
    for v in (ego, base.lead, car):
        v.on_state_update()
    car.target_lane_index = car.lane_index
    done = False
    while not done:
        _, _, term, trunc, info = env.step(np.array([1.0, 0.0]))
        assert not ego.crashed
        done = term or trunc
    assert info["guardian"]["overridden"] or ego.speed <= 17.5


@pytest.mark.slow
def test_highway_fast_random_continuous_agents_of_the_reported_run():
    """Catches: 3 collisions in 30 episodes, one at the ego's fault (steering checked one step ahead) and one
    from highway-env's extrapolating crash test with the bodies still apart."""
    r = highway_rollouts(Rollout("highway-fast-v0", "random", action="continuous"), 30, 0)
    assert _kept(r)


def test_starts_no_guardian_can_save_are_counted_apart():
    """Catches: crashes at steps 1-2 from a start 5 m behind a car counted as the guardian's failures."""
    r = highway_rollouts(Rollout("highway-fast-v0", "reckless", action="meta",
                                 env_config={"vehicles_density": 2.5, "policy_frequency": 1}), 12, 0)
    crashes = r["crashes"]
    assert r["starts_outside"] > 0 and _kept(r)
    assert r["ego_at_fault_collisions"] == sum(c["fault"] == "ego" and c["start_inside"] for c in crashes)
    assert r["ego_at_fault_after_outside_starts"] == sum(c["fault"] == "ego" and not c["start_inside"] for c in crashes)
    assert r["collisions_after_outside_starts"] == sum(not c["start_inside"] for c in crashes)


def test_exits_from_the_safe_set_are_counted_with_the_guardian_too(traffic_library, monkeypatch):
    """Catches: safety_violations counted only without the guardian. A forced exit is counted with it."""
    from envs.highway_overtake import HighwayOvertakeEnv

    real = HighwayOvertakeEnv.left_safe_set
    calls = {"n": 0}

    def sometimes(self):
        calls["n"] += 1
        return calls["n"] == 5 or real(self)

    monkeypatch.setattr(HighwayOvertakeEnv, "left_safe_set", sometimes)
    r = highway_rollouts(Rollout(OVERTAKE_ENV, "idle", library=traffic_library, env_config={"duration": 2}), 1, 0)
    assert r["safety_violations"] == 1


def test_a_pile_up_ahead_is_not_run_into():
    """Was (the campaign, seed 283008): two IDM cars ahead crash, the car between runs into the wreck and
    stops faster than the traffic model allows; the ego, on the self-safety boundary behind it, touched
    it (at its fault). Those cars tailgate from the start: they are at risk of a crash, and the ego keeps
    room to stop behind a car that may stop at once."""
    r = highway_rollouts(Rollout("highway-v0", "trap", action="meta",
                                 env_config={"duration": 15, "vehicles_density": 2.5}), 1, 283008)
    assert r["collisions"] == 0 and r["ego_at_fault_collisions"] == 0


def test_a_car_cutting_into_the_egos_side_is_judged_at_contact():
    """Was (the campaign, seed 20023, 1 Hz): an IDM car beside the ego cuts into its lane and hits it; the
    crash then slides the ego over its lane line before the policy step ends. Judged at the step's end,
    both had entered each other's lane and the ego was at fault; at contact only the IDM car had."""
    r = highway_rollouts(Rollout("highway-v0", "trap", action="continuous",
                                 env_config={"duration": 15, "vehicles_density": 2.5}), 1, 20023)
    assert r["starts_outside"] == 0 and r["collisions"] == 1
    assert [(c["fault"], c["rule"]) for c in r["crashes"]] == [("other", "entry")]


HUGGING = {"other_vehicles_type": "envs.vehicles.LineHuggingIDM", "simulation_frequency": 15, "vehicles_density": 2.0}


@pytest.mark.parametrize("action, episode", [("continuous", 31), ("continuous", 32), ("meta", 8), ("continuous", 9)])
def test_traffic_whose_body_lies_over_a_lane_line_is_kept_clear_of(action, episode):
    """Catches: IDM traffic keeping its centre 1.6 m off its lane's centre (its body 0.6 m over the line, its
    lane index unchanged). Reading lanes from lane indices, the guardian let the ego run into such a car from
    beside or behind (episodes 31, 32, meta 8, all starting inside); with lanes from bodies alone it still
    steered sideways within its own lane into one alongside (episode 9)."""
    r = highway_rollouts(Rollout("highway-fast-v0", "seek", action=action, env_config=HUGGING), 1, 0,
                         first_episode=episode)
    assert r["starts_outside"] == 0 and r["ego_at_fault_collisions"] == 0, r["crashes"]
