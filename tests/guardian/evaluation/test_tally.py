"""The tally counts by the run's own configuration (``HighwayTally(env, guarded, config)``)."""
import warnings

from guardian.config import GuardianConfig
from guardian.evaluation.rollouts import Rollout, highway_rollouts

warnings.filterwarnings("ignore", message=".*out of date.*")


def test_the_tally_counts_with_the_runs_own_configuration():
    """The same unguarded episodes (no guardian steers them) counted with the default bounds and with a
    guardian's that keeps 10 m and brakes at 4 m/s^2: the tighter sets hold fewer starts and leave more steps
    without a self-safe input. Counted with the defaults whatever the run's bounds, both would be equal."""
    kw = dict(guarded=False, action="meta", env_config={"vehicles_density": 2.0, "duration": 20})
    loose = highway_rollouts(Rollout("highway-fast-v0", "seek", **kw), 10, 0)
    tight = highway_rollouts(Rollout("highway-fast-v0", "seek", config=GuardianConfig(h_min=10.0, traffic_accel=4.0),
                                     **kw), 10, 0)
    assert tight["steps"] == loose["steps"] and tight["collisions"] == loose["collisions"]
    assert tight["starts_outside"] > loose["starts_outside"]
    assert tight["safety_violations"] > loose["safety_violations"]


def test_crashes_after_a_safe_set_exit_are_counted_and_marked(traffic_library):
    """A lead that stands still at once after 0.5 s, an unguarded ego that keeps its lane at full throttle, and
    episodes that go on past the safe-set exit: every crash comes after the exit and is counted so; the same
    run ending at the exit (the default) never sees a crash."""
    departure = {"lead_departure": {"after": 0.5, "behaviour": "stop"}, "traffic_count": 0, "traffic_from_behind": 0}
    on = highway_rollouts(Rollout("guardian/HighwayOvertake-v0", "bad", guarded=False, library=traffic_library,
                                  env_config={**departure, "terminate_when_unsafe": False}), 3, 0)
    assert on["lead_departures"] == on["safe_set_exits"] == 3 and on["collisions"] >= 1, on
    assert on["collisions_after_safe_set_exit"] == on["collisions"]
    assert on["ego_at_fault_after_safe_set_exit"] == on["ego_at_fault_collisions"] + on["ego_at_fault_after_outside_starts"]
    assert all(c["after_safe_set_exit"] and c["lead_departed"] for c in on["crashes"])
    ended = highway_rollouts(Rollout("guardian/HighwayOvertake-v0", "bad", guarded=False, library=traffic_library,
                                     env_config=departure), 3, 0)
    assert ended["safe_set_exits"] == 3 and ended["collisions"] == 0


def test_an_episode_the_env_does_not_end_is_cut_at_the_time_cap_and_counted():
    """merge-v0 never ends an episode by time, so a car the guardian holds would hang a run: the rollout stops
    an episode at ``max_seconds`` of simulated time and counts it cut. Here the env's own limit (40 s) lies
    beyond a 3 s cap: every episode without a crash is cut, after 3 policy steps, and listed."""
    r = highway_rollouts(Rollout("highway-fast-v0", "random", action="meta", env_config={"duration": 40},
                                 max_seconds=3.0), 4, 0)
    crashed = {c["episode"] for c in r["crashes"]}
    assert r["episodes_cut"] == 4 - len(crashed) > 0
    assert set(r["cut_episodes"]) == set(range(4)) - crashed
    assert r["steps"] <= 3 * 4
    uncapped = highway_rollouts(Rollout("highway-fast-v0", "random", action="meta", env_config={"duration": 3}), 4, 0)
    assert uncapped["episodes_cut"] == 0 and uncapped["steps"] == r["steps"]
