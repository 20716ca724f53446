"""Gymnasium environments of the product.

``guardian/Overtake-v0``: the two-car overtake scenario of Chapter 6 (dynamics (6.3)-(6.4),
the lead car driven by an intention model of ``intention.models``).
"""
import gymnasium

gymnasium.register(id="guardian/Overtake-v0", entry_point="envs.overtake:OvertakeEnv")
gymnasium.register(id="guardian/HighwayOvertake-v0", entry_point="envs.highway_overtake:HighwayOvertakeEnv")
