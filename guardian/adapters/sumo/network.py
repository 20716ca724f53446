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
    """A straight highway: ``lanes`` lanes of ``lane_width`` m over ``length`` m, speed limit ``speed`` m/s; with
    ``ramp_at`` > 0 an on-ramp joins there: a one-lane ramp of ``ramp_length`` m, ``ramp_offset`` m to the right of
    the acceleration lane where it starts, leads into an acceleration lane of ``accel_lane`` m on the right that
    ends (its cars must change lanes before its end); with ``exit_at`` > 0 (instead) a deceleration lane of
    ``accel_lane`` m begins there on the right and leaves the road as a one-lane exit of ``ramp_length`` m, bending
    ``ramp_offset`` m away to the right."""

    lanes: int = 3
    length: float = 3000.0
    lane_width: float = 3.5
    speed: float = 40.0
    ramp_at: float = 0.0
    accel_lane: float = 250.0
    ramp_length: float = 250.0
    ramp_offset: float = 20.0
    ramp_speed: float = 30.0
    exit_at: float = 0.0

    def __post_init__(self):
        if not 1 <= self.lanes <= 16:
            raise ConfigError(f"lanes must be 1..16, got {self.lanes}")
        for name in ("length", "lane_width", "speed", "accel_lane", "ramp_length", "ramp_speed"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.ramp_at and not (self.ramp_length + 10 <= self.ramp_at <= self.length - self.accel_lane - 200):
            raise ConfigError(f"ramp_at must leave the ramp ({self.ramp_length:g} m) before it and the acceleration "
                              f"lane and 200 m of road after it on a {self.length:g} m road, got {self.ramp_at:g}")
        if self.exit_at and self.ramp_at:
            raise ConfigError("a road has an on-ramp (ramp_at) or an exit (exit_at), not both")
        if self.exit_at and not (200 <= self.exit_at <= self.length - self.accel_lane - 200):
            raise ConfigError(f"exit_at must leave 200 m of road before it and after its deceleration lane on a "
                              f"{self.length:g} m road, got {self.exit_at:g}")
        if self.ramp_offset < 0:
            raise ConfigError(f"ramp_offset must be >= 0, got {self.ramp_offset}")

    @classmethod
    def of_road(cls, road: str, **kw) -> HighwayNet:
        """The ``straight`` highway, or one with an on-ramp (``merge``) or an exit (``exit``) a third of the way along."""
        length = kw.get("length", cls.length)
        at = {"straight": {}, "merge": {"ramp_at": length / 3}, "exit": {"exit_at": length / 3}}[road]
        return cls(**kw, **at)

    @property
    def corridor(self) -> tuple:
        """The edges along ``+x``, in order (every one's lanes aligned on the left)."""
        if self.ramp_at:
            return ("in", "acc", "out")
        return ("in", "dec", "out") if self.exit_at else ("highway",)

    @property
    def ramp(self) -> str | None:
        return "ramp" if self.ramp_at else None

    @property
    def exit(self) -> str | None:
        return "exit" if self.exit_at else None

    @property
    def edge(self) -> str:
        return self.corridor[0]

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
    ramp_vehicles_per_hour: float = 600.0   # on the on-ramp, when the road has one

    def __post_init__(self):
        if self.car_following not in CAR_FOLLOWING:
            raise ConfigError(f"car_following must be one of {', '.join(CAR_FOLLOWING)}, got {self.car_following!r}")
        for name in ("vehicles_per_hour", "accel", "decel", "emergency_decel", "tau", "length", "width",
                     "max_speed", "max_speed_lat", "lateral_resolution", "ramp_vehicles_per_hour"):
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


def _net_files(net: HighwayNet, folder: Path) -> list:
    """netconvert's inputs for ``net``: nodes and edges (and, with a ramp, the lanes' connections)."""
    nodes, edges = folder / "highway.nod.xml", folder / "highway.edg.xml"
    lane = f'speed="{net.speed:g}" width="{net.lane_width:g}"'
    if not net.ramp_at and not net.exit_at:
        nodes.write_text(f'<nodes>\n  <node id="start" x="0" y="0"/>\n  <node id="end" x="{net.length:g}" y="0"/>\n'
                         "</nodes>\n")
        edges.write_text(f'<edges>\n  <edge id="{net.edge}" from="start" to="end" numLanes="{net.lanes}" {lane}/>\n'
                         "</edges>\n")
        return ["--node-files", str(nodes), "--edge-files", str(edges)]
    a = net.ramp_at or net.exit_at
    b, w, n = a + net.accel_lane, net.lane_width, net.lanes
    y_added = -(n + 0.5) * w   # the added lane's centre line (SUMO's y; the road's left edge at y = 0)
    mid = "acc" if net.ramp_at else "dec"
    side = (a - net.ramp_length if net.ramp_at else b + net.ramp_length, y_added - net.ramp_offset)  # the far end
    nodes.write_text(f'<nodes>\n  <node id="start" x="0" y="0"/>\n  <node id="merge" x="{a:g}" y="0"/>\n'
                     f'  <node id="drop" x="{b:g}" y="0"/>\n  <node id="end" x="{net.length:g}" y="0"/>\n'
                     f'  <node id="side" x="{side[0]:g}" y="{side[1]:g}"/>\n</nodes>\n')
    ramp = (f'  <edge id="ramp" from="side" to="merge" numLanes="1" speed="{net.ramp_speed:g}" width="{w:g}" '
            f'spreadType="center" shape="{side[0]:g},{side[1]:g} {a:g},{y_added:g}"/>\n') if net.ramp_at else \
           (f'  <edge id="exit" from="drop" to="side" numLanes="1" speed="{net.ramp_speed:g}" width="{w:g}" '
            f'spreadType="center" shape="{b:g},{y_added:g} {side[0]:g},{side[1]:g}"/>\n')
    edges.write_text(
        f'<edges>\n  <edge id="in" from="start" to="merge" numLanes="{n}" {lane}/>\n'
        f'  <edge id="{mid}" from="merge" to="drop" numLanes="{n + 1}" {lane}/>\n'
        f'  <edge id="out" from="drop" to="end" numLanes="{n}" {lane}/>\n{ramp}</edges>\n')
    links = [("in", mid, k, k + 1) for k in range(n)] + [(mid, "out", k + 1, k) for k in range(n)]
    # an on-ramp leads into the acceleration lane, which leads nowhere (it ends); the deceleration lane is entered
    # by changing lanes and leads only into the exit
    links += [("ramp", mid, 0, 0)] if net.ramp_at else [(mid, "exit", 0, 0)]
    connections = folder / "highway.con.xml"
    connections.write_text("<connections>\n" + "".join(
        f'  <connection from="{f}" to="{t}" fromLane="{i}" toLane="{j}"/>\n' for f, t, i, j in links) + "</connections>\n")
    return ["--node-files", str(nodes), "--edge-files", str(edges), "--connection-files", str(connections),
            "--offset.disable-normalization", "true"]


def build_network(net: HighwayNet, folder: Path) -> Path:
    """``folder``/highway-KEY.net.xml for ``net``, built by netconvert unless it is there already."""
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"highway-{net.key()}.net.xml"
    if out.exists():
        return out
    inputs = _net_files(net, folder)
    tmp = out.with_suffix(f".{os.getpid()}.tmp.xml")
    done = subprocess.run([str(sumo_home() / "bin" / "netconvert"), *inputs, "--no-turnarounds", "true", "-o", str(tmp)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ConfigError(f"netconvert failed on {folder}: {done.stderr.strip()[-500:]}")
    tmp.replace(out)
    return out


CAR_FOLLOWING_XML = {"Krauss": 'carFollowModel="Krauss"', "IDM": 'carFollowModel="IDM"', "EIDM": 'carFollowModel="EIDM"'}


def vtype_xml(type_id: str, t: Traffic) -> str:
    return (f'<vType id="{type_id}" {CAR_FOLLOWING_XML[t.car_following]} laneChangeModel="{t.lane_change}" accel="{t.accel:g}" '
            f'decel="{t.decel:g}" emergencyDecel="{t.emergency_decel:g}" apparentDecel="{t.decel:g}" '
            f'sigma="{t.sigma:g}" tau="{t.tau:g}" length="{t.length:g}" width="{t.width:g}" '
            f'maxSpeed="{t.max_speed:g}" speedDev="{t.speed_factor_dev:g}" maxSpeedLat="{t.max_speed_lat:g}"/>')


def write_routes(t: Traffic, ego_types: list, folder: Path, net: HighwayNet, seconds: float, drivers=()) -> Path:
    """The routes file: SUMO's flows of ``t`` (the main road's; with a ramp, the ramp's too) and the guarded vehicles'
    types (``(id, length, width, accel)``; their speed factor is high so that SUMO takes any speed they are given,
    even on insertion); ``drivers``: types alike that carry the traffic's car-following and lane-change models and
    parameters (no dawdling), for a guarded vehicle SUMO's own driver drives. Route ``from_E`` runs from corridor
    edge ``E`` to the road's end (vehicles the guardian moves are inserted on the edge where they start)."""
    external = f'maxSpeed="100" speedFactor="{EXTERNAL_SPEED_FACTOR:g}" speedDev="0"'
    egos = "\n".join(f'  <vType id="{tid}" length="{length:g}" width="{width:g}" accel="{accel:g}" decel="{accel:g}" '
                     f'emergencyDecel="{accel:g}" sigma="0" {external}/>' for tid, length, width, accel in ego_types)
    egos += "".join(f'\n  <vType id="{tid}" {CAR_FOLLOWING_XML[t.car_following]} laneChangeModel="{t.lane_change}" '
                    f'length="{length:g}" width="{width:g}" accel="{t.accel:g}" decel="{t.decel:g}" '
                    f'emergencyDecel="{accel:g}" apparentDecel="{t.decel:g}" sigma="0" tau="{t.tau:g}" '
                    f'maxSpeedLat="{t.max_speed_lat:g}" {external}/>' for tid, length, width, accel in drivers)
    corridor = net.corridor
    routes = "".join(f'  <route id="from_{e}" edges="{" ".join(corridor[k:])}"/>\n' for k, e in enumerate(corridor))
    flows = (f'  <flow id="traffic" type="traffic" route="from_{corridor[0]}" begin="0" end="{seconds:g}" '
             f'vehsPerHour="{t.vehicles_per_hour:g}" departLane="random" departSpeed="desired" departPos="base"/>\n')
    if net.ramp:
        routes += f'  <route id="from_ramp" edges="ramp {" ".join(corridor[1:])}"/>\n'
        flows += (f'  <flow id="ramp" type="traffic" route="from_ramp" begin="0" end="{seconds:g}" '
                  f'vehsPerHour="{t.ramp_vehicles_per_hour:g}" departLane="0" departSpeed="desired" departPos="base"/>\n')
    if net.exit:   # cars that leave by the exit (as many per hour as an on-ramp brings)
        routes += f'  <route id="to_exit" edges="{corridor[0]} {corridor[1]} exit"/>\n'
        flows += (f'  <flow id="exiting" type="traffic" route="to_exit" begin="0" end="{seconds:g}" '
                  f'vehsPerHour="{t.ramp_vehicles_per_hour:g}" departLane="random" departSpeed="desired" '
                  'departPos="base"/>\n')
    text = f"<routes>\n  {vtype_xml('traffic', t)}\n{egos}\n{routes}{flows}</routes>\n"
    out = folder / "routes.rou.xml"
    out.write_text(text)
    return out
