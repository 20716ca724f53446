"""A driving stack that runs the guardian out of process: a highway-env episode where every decision is asked of
`guardian serve` (a scene session) and the vehicle applies the service's answer.

    python examples/drive_through_service.py                       # starts a service in this process
    python examples/drive_through_service.py --url http://127.0.0.1:8765 [--stream]

One env step is one simulation step (policy frequency = simulation frequency), so the stack decides every
simulation step as the gymnasium wrapper does. Each step it reads the ego and the other cars' bodies (here with
guardian's highway-env reader; another simulator reads its own), proposes an input (a reckless driver: full
throttle, weaving), sends both, and applies the input the service returns.
"""
import argparse
import math

import gymnasium as gym
import highway_env  # noqa: F401 - registers highway-v0
import numpy as np

from guardian.adapters.highway_env.road import read_road
from guardian.adapters.highway_env.scene import bicycle_state, road_scene
from guardian.client import GuardianClient
from guardian.client.bodies import guardian_body, step_body
from guardian.config import GuardianConfig

STEER = math.pi / 4  # the action's steering range, and the vehicle model's bound
ACCEL = 6.0          # the action's acceleration range: the model's bound (GuardianConfig.traffic_accel)


def drive(client, stream: bool, seed: int = 0, steps: int = 300) -> dict:
    env = gym.make("highway-v0", config={"action": {"type": "ContinuousAction", "acceleration_range": [-ACCEL, ACCEL],
                                                    "steering_range": [-STEER, STEER]},
                                         "simulation_frequency": 15, "policy_frequency": 15, "duration": 40})
    env.reset(seed=seed)
    base = env.unwrapped
    road, ego = read_road(base), base.vehicle
    vehicle = {"model": "bicycle", "length": ego.LENGTH, "width": ego.WIDTH, "dt": 1 / 15, "max_steering": STEER,
               "max_acceleration": ACCEL}
    overrides, reasons, crashed = 0, [], False
    with client.create_scene_session(road, vehicle, guardian_body(GuardianConfig())) as session:
        stepper = session.stream() if stream else session
        for t in range(steps):
            proposed = [ACCEL, 0.2 * math.sin(t / 8)]             # the driver: full throttle, weaving
            body = step_body(bicycle_state(base.vehicle, road), road_scene(base, road), proposed, road, ego.LENGTH)
            record = stepper.step(**body)                        # the guardian's answer, for this very state
            a, steering = record["applied"]
            overrides += record["safety_override"]
            if record["safety_override"] and len(reasons) < 3:
                reasons.append(f"t={t}: {record['reasons'][:1]}")
            _, _, terminated, truncated, info = env.step(np.array([a / ACCEL, steering / STEER]))
            crashed = bool(info["crashed"])
            if terminated or truncated:
                break
        if stream:
            stepper.close()
    env.close()
    return {"steps": t + 1, "safety_overrides": overrides, "crashed": crashed, "first_reasons": reasons}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--url", help="a running guardian service (default: start one in this process)")
    p.add_argument("--stream", action="store_true", help="step over the session's WebSocket stream")
    args = p.parse_args()
    if args.url:
        with GuardianClient(args.url) as client:
            print(drive(client, args.stream))
        return
    from guardian.service import ServiceConfig, ServiceThread
    from intention.library import build_library

    with ServiceThread(build_library(), ServiceConfig(port=0)) as service, GuardianClient(service.url) as client:
        print(drive(client, args.stream))


if __name__ == "__main__":
    main()
