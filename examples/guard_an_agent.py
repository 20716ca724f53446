"""The guardian around a highway-env agent that always asks FASTER; what it did is in info["guardian"]."""
import gymnasium as gym

from guardian import Guardian

for env_id in ("highway-v0", "guardian/HighwayOvertake-v0"):
    env = Guardian(gym.make(env_id, config={"action": {"type": "DiscreteMetaAction"}}))  # sets: cache or built
    obs, info = env.reset(seed=0)
    faster, overrides = env.unwrapped.action_type.actions_indexes["FASTER"], 0
    for step in range(1, 31):
        obs, reward, terminated, truncated, info = env.step(faster)  # a trained policy would act on obs
        g = info["guardian"]  # what the guardian did, and why
        overrides += g["safety_override"]
        if terminated or truncated:
            break
    print(env_id, f"steps={step} overridden={overrides} crashed={info['crashed']}", g["applied"], g["reasons"][:1])
