"""The guarded cars and the hooks through which the wrapper decides every simulation step.

highway-env calls a vehicle's ``act(action)`` once per policy step (the agent's action) and ``act(None)``
once per simulation step after it. The wrapper replaces each guarded vehicle's ``act`` with a ``Hook``:
the agent's action goes to the vehicle's own ``act``; each simulation step goes to the scenario's
supervision (``guardian.adapters.highway_env.supervision``), which decides and applies.
"""
from __future__ import annotations

from guardian.adapters.highway_env.monitor import no_counts


class GuardedCar:
    """One guarded car: its vehicle, decision object and model monitor, the agent's last command, and what
    happened to it in the current policy step (``decisions``, ``refused_meta`` and the ITHA lane it named,
    ``refused_lane``, ``monitor_counts``)."""

    def __init__(self, index: int, vehicle, action_type, guard, monitor):
        self.index, self.vehicle, self.action_type = index, vehicle, action_type
        self.guard, self.monitor = guard, monitor
        self.original = vehicle.act
        self.agent_command = dict(vehicle.action)
        self.calls = 0   # simulation steps decided
        self.new_step()

    def new_step(self) -> None:
        """Forget the last policy step."""
        self.decisions, self.refused_meta, self.refused_lane = [], None, None
        self.monitor_counts = no_counts()

    def decided(self, base, decision) -> None:
        """Note one simulation step's decision and what the model monitor saw of it."""
        self.calls += 1
        self.decisions.append(decision)
        for k, n in self.monitor.observe(base, self._model_input(decision.applied), self.vehicle).items():
            self.monitor_counts[k] += n


    def _model_input(self, applied):
        """The input the model moves the car by: behind an actuator (``envs.actuator.Actuated``) the acceleration
        the actuator makes of the command (under a lag, part of the way to it)."""
        actuator = getattr(self.vehicle, "actuator", None)
        if actuator is None:
            return applied
        accel = actuator.follows(self.vehicle.applied_acceleration, float(applied[0]), self.monitor.dt)
        return [accel, *applied[1:]]


class Hook:
    """A guarded vehicle's ``act`` while supervised by ``guardian`` (the wrapper)."""

    def __init__(self, guardian, car: GuardedCar, supervise):
        self.guardian, self.car, self.supervise = guardian, car, supervise

    @property
    def original(self):
        return self.car.original

    def __call__(self, action=None):
        car = self.car
        if action is not None:  # the agent's action, decoded once per policy step
            car.original(action)
            car.agent_command = dict(car.vehicle.action)
            return
        self.supervise(car)


def hooked_by(vehicle, guardian) -> bool:
    """Is ``vehicle``'s ``act`` a hook of ``guardian``?"""
    hook = vehicle.__dict__.get("act")
    return isinstance(hook, Hook) and hook.guardian is guardian
