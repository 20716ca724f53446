"""One SUMO scenario (``SumoSetting``): the road, the traffic, the guarded vehicles' bodies, SUMO's command line and
files for it, and the guarded vehicles' insertion.

The routes name three vehicle types besides the traffic's: ``guarded`` (a vehicle the guardian moves: SUMO takes any
speed it is given), the shadows' (``guardian.adapters.sumo.shadows``) and ``sumo_driver``
(``guardian.evaluation.sumo_agents.DRIVER_TYPE``: a guarded vehicle SUMO's own driver drives, with the traffic's
car-following and lane-change models).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from guardian.adapters.sumo import network
from guardian.adapters.sumo.connection import parse_connection
from guardian.adapters.sumo.network import HighwayNet, Traffic
from guardian.adapters.sumo.scene import Frame
from guardian.adapters.sumo.shadows import SHADOW_TYPE
from guardian.errors import ConfigError
from guardian.evaluation.sumo_agents import DRIVER_TYPE
from itha.actuator import Actuator

EGO = "guarded"


@dataclass(frozen=True)
class SumoSetting:
    """One SUMO scenario: the road, the traffic, the step, how long, the guarded vehicle's body and steering."""

    net: HighwayNet = field(default_factory=HighwayNet)
    traffic: Traffic = field(default_factory=Traffic)
    step_length: float = 0.1
    warmup: float = 40.0
    seconds: float = 60.0
    ego_length: float = 5.0
    ego_width: float = 2.0
    max_steering: float = math.pi / 4
    depart_speed: float = 25.0
    guarded: int = 1            # guarded vehicles (each its own guardian and driver; every other vehicle is traffic)
    connection: str = "libsumo"  # libsumo, traci or HOST:PORT (guardian.adapters.sumo.connection)
    start: str = "main"          # where the guarded vehicle starts: on a main lane, or on the on-ramp (one vehicle)
    jerk: float | None = None    # the guarded vehicles' actuator changes their acceleration by at most this [m/s^3]
    lag: float | None = None     # and follows a command as a first-order lag of this time constant [s]

    def __post_init__(self):
        if self.guarded < 1:
            raise ConfigError(f"guarded must be >= 1, got {self.guarded}")
        parse_connection(self.connection)
        for name in ("step_length", "warmup", "seconds", "ego_length", "ego_width", "max_steering"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.max_steering >= math.pi / 2:
            raise ConfigError(f"max_steering must be below pi/2, got {self.max_steering}")
        if self.start not in ("main", "ramp"):
            raise ConfigError(f"start must be 'main' or 'ramp', got {self.start!r}")
        if self.jerk is not None and not (math.isfinite(self.jerk) and self.jerk > 0):
            raise ConfigError(f"jerk must be a positive finite number [m/s^3] (None: no limit), got {self.jerk}")
        if self.lag is not None and not (math.isfinite(self.lag) and self.lag > 0):
            raise ConfigError(f"lag must be a positive finite time constant [s] (None: no lag), got {self.lag}")
        try:
            self.actuator
        except ValueError as exc:   # what the actuator itself refuses (a lag beyond any vehicle's)
            raise ConfigError(str(exc)) from exc
        if self.start == "ramp" and not (self.net.ramp_at and self.guarded == 1):
            raise ConfigError("start 'ramp' needs a road with an on-ramp (ramp_at) and one guarded vehicle")

    @property
    def actuator(self) -> Actuator | None:
        """The guarded vehicles' actuator (held over a step; None: the acceleration may jump)."""
        if self.jerk is None and self.lag is None:
            return None
        return Actuator(jerk=math.inf if self.jerk is None else self.jerk, lag=self.lag or 0.0, profile="hold")


def traffic_accel_of(traci) -> float:
    """The hardest braking any traffic vehicle type allows (its emergencyDecel): the traffic model's bound."""
    decels = [traci.vehicletype.getEmergencyDecel(t) for t in traci.vehicletype.getIDList()
              if t not in (EGO, SHADOW_TYPE, DRIVER_TYPE) and not t.startswith("DEFAULT_")]
    return max(decels)


def sumo_args(setting: SumoSetting, folder: Path, seed: int) -> list:
    """SUMO's command line (without the binary) for ``setting`` with ``seed``; the network and routes it names are
    written into ``folder``."""
    net = network.build_network(setting.net, folder)
    body = (setting.ego_length, setting.ego_width, setting.traffic.emergency_decel)
    routes = network.write_routes(setting.traffic, [(EGO, *body), (SHADOW_TYPE, *body)], folder, setting.net,
                                  setting.warmup + setting.seconds + 10, drivers=[(DRIVER_TYPE, *body)])
    args = ["-n", str(net.resolve()), "-r", str(routes.resolve()), "--step-length", f"{setting.step_length:g}",
            "--seed", str(seed), "--collision.action", "warn", "--collision.mingap-factor", "0", "--no-step-log",
            "true", "--no-warnings", "true", "--duration-log.disable", "true", "--default.speeddev",
            f"{setting.traffic.speed_factor_dev:g}"]
    if setting.traffic.sublane:
        args += ["--lateral-resolution", f"{setting.traffic.lateral_resolution:g}"]
    if setting.guarded > 1:  # inserted at once: one that must wait does not hold up the others
        args += ["--eager-insert", "true"]
    return args


def write_scenario(setting: SumoSetting, folder: Path, seed: int = 0) -> Path:
    """The scenario's files in ``folder`` and ``folder``/guardian.sumocfg naming them, for a SUMO server
    (``sumo -c guardian.sumocfg --remote-port PORT``) that a ``HOST:PORT`` connection then reloads per episode."""
    import subprocess

    folder.mkdir(parents=True, exist_ok=True)
    cfg = (folder / "guardian.sumocfg").resolve()
    done = subprocess.run([str(network.sumo_home() / "bin" / "sumo"), *sumo_args(setting, folder, seed),
                           "--save-configuration", str(cfg)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ConfigError(f"sumo could not write {cfg}: {done.stderr.strip()[-500:]}")
    return cfg


def guarded_names(setting: SumoSetting) -> list:
    return [EGO] if setting.guarded == 1 else [f"{EGO}.{k}" for k in range(setting.guarded)]


def insert_guarded(traci, setting: SumoSetting, frame: Frame, rng: np.random.Generator) -> bool:
    """Insert the guarded vehicles at ``depart_speed`` (one on a random main lane at 25-45 % of the road, or on the
    on-ramp at 20-60 % of it, at most at the ramp's speed; several on free lanes, evenly spaced over 10-80 % of the
    road); False if SUMO found no room for all of them within 20 s."""
    names, length = guarded_names(setting), setting.net.length
    speed = setting.depart_speed
    for k, name in enumerate(names):
        if setting.start == "ramp":
            speed = min(speed, setting.net.ramp_speed)
            pos = float(rng.uniform(0.2, 0.6) * traci.lane.getLength(f"{setting.net.ramp}_0"))
            traci.vehicle.add(name, f"from_{setting.net.ramp}", typeID=EGO, departLane="0", departPos=f"{pos:g}",
                              departSpeed=f"{speed:g}")
            continue
        if len(names) == 1:
            index, pos = int(rng.integers(setting.net.lanes)), float(rng.uniform(0.25, 0.45) * length)
            edge, index = frame.lane_at(setting.net.lanes - 1 - index, pos)
            lane = str(index)
        else:
            pos = length * (0.1 + 0.7 * (k + 0.5) / len(names))
            edge, lane = frame.edge_at(pos), "free"
            if frame.lanes_of[edge] > setting.net.lanes:   # not on an acceleration lane: just after it
                pos, edge = frame.extent[edge][1] + 10.0 + k, frame.edges[frame.edges.index(edge) + 1]
        traci.vehicle.add(name, f"from_{edge}", typeID=EGO, departLane=lane,
                          departPos=f"{pos - frame.extent[edge][0]:g}", departSpeed=f"{speed:g}")
    for _ in range(200):
        traci.simulationStep()
        present = set(traci.vehicle.getIDList())
        for n in names:   # SUMO drives them until all are in: at their insertion speed (SUMO's checks on)
            if n in present:
                traci.vehicle.setSpeed(n, speed)
        if all(n in present for n in names):
            for n in names:
                traci.vehicle.setSpeedMode(n, 0)
                traci.vehicle.setLaneChangeMode(n, 0)
            return True
    return False
