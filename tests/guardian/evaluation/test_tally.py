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
