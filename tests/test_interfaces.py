"""The declared interfaces: every implementation answers its Protocol."""
from envs.drivers import DRIVERS, Driver, make_driver
from guardian.supervisor import IntentionAwareGuardian, Supervisor
from itha.car_following import CarFollowingParams, CarFollowingSet, MaximalSet, load_or_build


def test_car_following_sets_drivers_and_the_supervisor_answer_their_protocols(library, tmp_path):
    p = CarFollowingParams()
    assert isinstance(MaximalSet(p), CarFollowingSet)
    assert isinstance(load_or_build(p, cache_dir=tmp_path), CarFollowingSet)
    assert all(isinstance(make_driver(name), Driver) for name in DRIVERS)
    assert isinstance(IntentionAwareGuardian(library), Supervisor)
    assert not isinstance(object(), Supervisor)
