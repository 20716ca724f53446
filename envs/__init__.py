"""Gymnasium environments of the product.

``guardian/HighwayOvertake-v0``: the overtake scenario of Chapter 6 on a highway-env road, with traffic;
``guardian/Overtake-v0``: the same scenario with the two cars alone (Section 6.5's setting: no traffic,
the dissertation's parameters, the overtake state as the observation);
``guardian/Merge-v0``: highway-env's on-ramp merge (``merge-v0``'s road) for both action types and many
controlled cars, with the on-ramp merging reference's traffic modes (``envs.merge``).
"""
import gymnasium

gymnasium.register(id="guardian/Overtake-v0", entry_point="envs.highway_overtake:OvertakeEnv")
gymnasium.register(id="guardian/HighwayOvertake-v0", entry_point="envs.highway_overtake:HighwayOvertakeEnv")
gymnasium.register(id="guardian/Merge-v0", entry_point="envs.merge:GuardedMergeEnv")
