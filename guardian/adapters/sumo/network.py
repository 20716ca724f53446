"""The SUMO scenario a guarded run drives in: a road network built by ``netconvert`` and SUMO's own traffic.

``HighwayNet`` is a straight multi-lane highway along ``+x`` (one edge, ``lanes`` lanes of ``lane_width``);
``Traffic`` is SUMO's traffic on it: one vehicle type (car-following model Krauss, IDM or EIDM; lane-change
model LC2013, or SL2015 with the sublane model) and a flow. Both are frozen dataclasses whose defaults are
this project's choices (SUMO's own defaults where it has them). ``write_scenario`` writes the network, the
routes and the vehicle types into a folder (the network once per ``HighwayNet``, keyed by its fields).

The traffic's bounds are what the guardian's traffic model must cover: ``Traffic.emergency_decel`` is the
hardest any SUMO car brakes (SUMO never decelerates a car harder, even to avoid a collision), and
``Traffic.max_speed_lat`` its fastest lateral motion (the sublane model).
"""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
from dataclasses import asdict, dataclass
from pathlib import Path

from guardian.errors import ConfigError

SUMO_EXTRA = "pip install 'guardian[sumo]'"
CAR_FOLLOWING = ("Krauss", "IDM", "EIDM")
LANE_CHANGE = ("LC2013", "SL2015")
EXTERNAL_SPEED_FACTOR = 1.9   # vehicles moved by the guardian: SUMO refuses an insertion above lane speed x factor (< 2)


def sumo_home() -> Path:
    """The SUMO installation of the ``eclipse-sumo`` package (its binaries and data)."""
    try:
        import sumo
    except ImportError:
        raise ConfigError(f"SUMO is not installed: {SUMO_EXTRA}") from None
    return Path(sumo.SUMO_HOME)


@dataclass(frozen=True)
class HighwayNet:
    """A straight highway: ``lanes`` lanes of ``lane_width`` m over ``length`` m, speed limit ``speed`` m/s."""

    lanes: int = 3
    length: float = 3000.0
    lane_width: float = 3.5
    speed: float = 40.0

    def __post_init__(self):
        if not 1 <= self.lanes <= 16:
            raise ConfigError(f"lanes must be 1..16, got {self.lanes}")
        for name in ("length", "lane_width", "speed"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")

    @property
    def edge(self) -> str:
        return "highway"

    def key(self) -> str:
        return hashlib.sha256(json.dumps(asdict(self), sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Traffic:
    """SUMO's traffic: one vehicle type and a flow entering at the road's start.

    ``sigma``: the driver imperfection (Krauss, EIDM); ``tau``: the desired time headway [s]; ``sublane``:
    SL2015 with ``lateral_resolution`` m sublanes (cars drift inside and across lanes) instead of LC2013."""

    car_following: str = "Krauss"
    sublane: bool = False
    vehicles_per_hour: float = 3000.0
    accel: float = 2.6
    decel: float = 4.5
    emergency_decel: float = 6.0
    sigma: float = 0.5
    tau: float = 1.0
    length: float = 5.0
    width: float = 1.8
    max_speed: float = 36.0
    speed_factor_dev: float = 0.1
    max_speed_lat: float = 1.0
    lateral_resolution: float = 0.8

    def __post_init__(self):
        if self.car_following not in CAR_FOLLOWING:
            raise ConfigError(f"car_following must be one of {', '.join(CAR_FOLLOWING)}, got {self.car_following!r}")
        for name in ("vehicles_per_hour", "accel", "decel", "emergency_decel", "tau", "length", "width",
                     "max_speed", "max_speed_lat", "lateral_resolution"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0 <= self.sigma <= 1:
            raise ConfigError(f"sigma must be in [0, 1], got {self.sigma}")
        if self.emergency_decel < self.decel:
            raise ConfigError(f"emergency_decel ({self.emergency_decel}) below decel ({self.decel}): SUMO "
                              "would brake harder than its emergency bound")

    @property
    def lane_change(self) -> str:
        return "SL2015" if self.sublane else "LC2013"


def _net_files(net: HighwayNet, folder: Path) -> tuple[Path, Path]:
    nodes, edges = folder / "highway.nod.xml", folder / "highway.edg.xml"
    nodes.write_text(f'<nodes>\n  <node id="start" x="0" y="0"/>\n  <node id="end" x="{net.length:g}" y="0"/>\n'
                     "</nodes>\n")
    edges.write_text(f'<edges>\n  <edge id="{net.edge}" from="start" to="end" numLanes="{net.lanes}" '
                     f'speed="{net.speed:g}" width="{net.lane_width:g}"/>\n</edges>\n')
    return nodes, edges


def build_network(net: HighwayNet, folder: Path) -> Path:
    """``folder``/highway-KEY.net.xml for ``net``, built by netconvert unless it is there already."""
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"highway-{net.key()}.net.xml"
    if out.exists():
        return out
    nodes, edges = _net_files(net, folder)
    tmp = out.with_suffix(f".{os.getpid()}.tmp.xml")
    done = subprocess.run([str(sumo_home() / "bin" / "netconvert"), "--node-files", str(nodes), "--edge-files",
                           str(edges), "--no-turnarounds", "true", "-o", str(tmp)], capture_output=True, text=True,
                          check=False)
    if done.returncode != 0:
        raise ConfigError(f"netconvert failed on {edges}: {done.stderr.strip()[-500:]}")
    tmp.replace(out)
    return out


def vtype_xml(type_id: str, t: Traffic) -> str:
    model = {"Krauss": 'carFollowModel="Krauss"', "IDM": 'carFollowModel="IDM"', "EIDM": 'carFollowModel="EIDM"'}
    return (f'<vType id="{type_id}" {model[t.car_following]} laneChangeModel="{t.lane_change}" accel="{t.accel:g}" '
            f'decel="{t.decel:g}" emergencyDecel="{t.emergency_decel:g}" apparentDecel="{t.decel:g}" '
            f'sigma="{t.sigma:g}" tau="{t.tau:g}" length="{t.length:g}" width="{t.width:g}" '
            f'maxSpeed="{t.max_speed:g}" speedDev="{t.speed_factor_dev:g}" maxSpeedLat="{t.max_speed_lat:g}"/>')


def write_routes(t: Traffic, ego_types: list, folder: Path, edge: str, seconds: float) -> Path:
    """The routes file: SUMO's flow of ``t`` and the guarded vehicles' types (``(id, length, width, accel)``; their
    speed factor is high so that SUMO takes any speed they are given, even on insertion)."""
    egos = "\n".join(f'  <vType id="{tid}" length="{length:g}" width="{width:g}" accel="{accel:g}" decel="{accel:g}" '
                     f'emergencyDecel="{accel:g}" sigma="0" maxSpeed="100" speedFactor="{EXTERNAL_SPEED_FACTOR:g}" speedDev="0"/>'
                     for tid, length, width, accel in ego_types)
    text = (f"<routes>\n  {vtype_xml('traffic', t)}\n{egos}\n  <route id=\"main\" edges=\"{edge}\"/>\n"
            f'  <flow id="traffic" type="traffic" route="main" begin="0" end="{seconds:g}" '
            f'vehsPerHour="{t.vehicles_per_hour:g}" departLane="random" departSpeed="desired" departPos="base"/>\n'
            "</routes>\n")
    out = folder / "routes.rou.xml"
    out.write_text(text)
    return out
