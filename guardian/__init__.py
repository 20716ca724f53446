"""guardian: a correct-by-construction safety supervisor for highway driving.

The front door in Python::

    import gymnasium as gym
    import highway_env  # noqa: F401 (registers highway-v0, ...)
    from guardian import Guardian

    env = Guardian(gym.make("highway-fast-v0"))     # or "guardian/HighwayOvertake-v0", "guardian/Overtake-v0"
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    info["guardian"]                                 # what the guardian did, and why

``Guardian`` and ``GuardianConfig`` are imported on first use (they bring highway-env); the error
types (``ConfigError``, ...) are ``guardian.errors``'.
"""
from guardian.errors import ConfigError, HighDFormatError, LPError, ServiceError, StaleCacheError

__version__ = "0.1.0"
__all__ = ["Guardian", "GuardianConfig", "ConfigError", "HighDFormatError", "LPError", "ServiceError",
           "StaleCacheError"]


def __getattr__(name: str):
    if name in ("Guardian", "GuardianConfig"):
        import envs  # noqa: F401 - registers guardian/Overtake-v0 and guardian/HighwayOvertake-v0
        from guardian.wrappers import guardian as wrapper

        return getattr(wrapper, name)
    raise AttributeError(f"module 'guardian' has no attribute {name!r}")
