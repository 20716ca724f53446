"""On the straight highway-v0 family the guardian decides exactly as recorded: every applied input of seeded
episodes, bit for bit.

The fixture (``tests/support/data/highway_decisions.json``) is recorded by ``tests/support/highway_decisions.py``; see there.
"""
import json

import pytest

from highway_decisions import EPISODES, FIXTURE, record

RECORDED = json.loads(FIXTURE.read_text())


def test_the_fixture_covers_both_action_types_and_real_decisions():
    assert [tuple(e["episode"][:3]) for e in RECORDED] == [e[:3] for e in EPISODES]
    assert {e["episode"][2] for e in RECORDED} == {"meta", "continuous"}
    steps = [s for e in RECORDED for s in e["steps"]]
    assert any(s["refused_lane_change"] for s in steps) and any(s["failsafe_steps"] for s in steps)
    assert any(s["entered"] for s in steps) and any(s["overridden"] for s in steps)


@pytest.mark.parametrize("k", range(len(EPISODES)), ids=[f"{e[0]}-{e[1]}-{e[2]}" for e in EPISODES])
def test_decisions_are_unchanged_bit_for_bit(k):
    env_id, agent, action, config, seed = EPISODES[k]
    now = record(env_id, agent, action, config, seed)
    then = RECORDED[k]
    assert len(now["inputs"]) == len(then["inputs"])
    for i, (a, b) in enumerate(zip(now["inputs"], then["inputs"])):
        assert a == b, f"simulation step {i}: applied {a}, recorded {b}"  # exact floats (JSON round-trips repr)
    assert now["steps"] == then["steps"]
