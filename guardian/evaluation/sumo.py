"""Guarded episodes in Eclipse SUMO: SUMO's own traffic, one guarded vehicle, counted by SUMO and by a judge.

An episode: SUMO (libsumo, in process) runs the network and traffic of a ``SumoSetting`` for ``warmup`` seconds,
inserts the guarded vehicle, then every SUMO step reads the scene (``guardian.adapters.sumo.scene``), lets an
agent propose ``[acceleration, steering]``, has ``BicycleGuardian`` decide (or not, unguarded), moves the vehicle
by the model under the applied input and steps SUMO.

**The traffic model is read from SUMO**: the hardest braking of any traffic vehicle type (its
``emergencyDecel``) becomes ``GuardianConfig.traffic_accel`` (and the ego's acceleration bound, which the
car-following sets share). **Counted** (the rules, in docs/sumo.md, tested on hand-built cases):

- ``collisions``: the guarded vehicle's body overlaps another's (rotated rectangles), or SUMO reports a collision
  involving it (``sumo_collisions``, its own detection, counted apart); the episode ends there.
- fault (``at_fault``), on the bodies at contact, first rule that decides: (1) a body that began to overlap a lane
  the other's body was in within ``ENTRY_WINDOW`` s before contact entered: the entrant is at fault, both: the
  guarded vehicle; (2) side contact: bodies alongside (overlapping along the road) at the observation before, the
  one that moved sideways towards the other faster than ``SIDEWAYS`` is at fault, both: the guarded vehicle; (3)
  rear-end: the body that was behind at the observation before the contact (a car passes 4 m in a step), unless
  the one ahead drives backwards. Ties go against the guarded vehicle.
- ``starts_outside``: the first decision found no self-safe acceleration (``in_invariant_set`` false): such
  episodes are counted apart (``at_fault_after_outside``), as on highway-env.
- ``emergency_braking``, ``teleports``: SUMO's own counts of its traffic's emergency stops and teleports.
- ``ego_lane_unseen``: steps SUMO kept the guarded vehicle on another lane than the one its body has just entered
  (``guardian.adapters.sumo.scene.sumo_slot``): SUMO's cars react to a vehicle on their own lane only, so the cars
  behind in the entered lane did not see it then (SUMO maps a moved vehicle to the lane of its centre).
- model coverage: ``ego_uncovered`` (SUMO did not put the vehicle where the model said, more than 1 mm off) and
  ``traffic_uncovered`` (a traffic car's step outside the traffic model: braking beyond ``traffic_accel``, or a
  position update other than the Euler step ``x + v dt`` of (7.3); SUMO's default Euler update moves a car by its
  *new* speed, so every step with a speed change counts), with the worst excess of each.
"""
from __future__ import annotations

import contextlib
import math
import sys
import tempfile
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from guardian.adapters.sumo import network
from guardian.adapters.sumo.network import HighwayNet, Traffic
from guardian.adapters.sumo.scene import BicycleModel, Frame, ego_state, overlap, place, scene, sumo_slot
from guardian.config import GuardianConfig
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.kinematics import BicycleEgo
from guardian.errors import ConfigError

ENTRY_WINDOW = 3.0   # [s]
SIDEWAYS = 0.25      # [m/s] lateral speed below this is lane keeping (the same as highway-env's judge)
EGO = "guarded"
AGENTS = ("random", "reckless", "seek")
PLACEMENT_TOL = 1e-3  # [m] SUMO's placement of the guarded vehicle against the model's state


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

    def __post_init__(self):
        for name in ("step_length", "warmup", "seconds", "ego_length", "ego_width", "max_steering"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.max_steering >= math.pi / 2:
            raise ConfigError(f"max_steering must be below pi/2, got {self.max_steering}")


@dataclass
class Tracks:
    """When each body began to overlap each lane (the entry rule), and each body at the last two observations (the
    side rule)."""

    lanes: dict = field(default_factory=dict)      # name -> slots now
    entered: dict = field(default_factory=dict)    # name -> {slot: time of the last entry}
    seen: dict = field(default_factory=dict)       # name -> [(time, body) before, (time, body) now]

    def see(self, name: str, slots: frozenset, t: float, body=None) -> None:
        before = self.lanes.get(name)
        if before is not None:
            for k in slots - before:
                self.entered.setdefault(name, {})[k] = t
        self.lanes[name] = slots
        self.seen[name] = [*self.seen.get(name, [])[-1:], (t, body)]

    def entered_lane_of(self, name: str, other: str, t: float) -> bool:
        """Did ``name``'s body begin to overlap a lane ``other``'s body is in within ``ENTRY_WINDOW`` s?"""
        theirs = self.lanes.get(other, frozenset())
        return any(k in theirs and t - when <= ENTRY_WINDOW + 1e-9 for k, when in self.entered.get(name, {}).items())

    def before(self, name: str):
        """``(time, body)`` at the observation before the last, or None."""
        seen = self.seen.get(name, [])
        return seen[0] if len(seen) == 2 and seen[0][1] is not None else None


def _sideways(tracks: Tracks, me, other) -> bool | None:
    """The side rule: were the bodies alongside at the observation before (overlapping along the road)? Then
    True if ``me`` moved sideways towards ``other`` faster than ``SIDEWAYS`` (or both did), False if only ``other``
    did; None when they were not alongside or neither moved sideways."""
    a, b = tracks.before(me.name), tracks.before(other.name)
    if a is None or b is None or a[0] != b[0]:
        return None
    (t0, m0), (_, o0) = a, b
    dt = tracks.seen[me.name][-1][0] - t0
    if dt <= 0 or abs(m0.x - o0.x) >= (m0.length + o0.length) / 2:
        return None
    towards = math.copysign(1.0, o0.y - m0.y)
    mine, theirs = (me.y - m0.y) / dt * towards > SIDEWAYS, (other.y - o0.y) / dt * -towards > SIDEWAYS
    return True if mine else (False if theirs else None)


def at_fault(ego, partner, tracks: Tracks, t: float) -> tuple[bool, str]:
    """Is the guarded vehicle (``ego``, a ``Sensed`` body) at fault for touching ``partner``? With the rule that
    decided: entry, then side contact, then rear-end (highway-env's judge's order)."""
    ego_entered = tracks.entered_lane_of(ego.name, partner.name, t)
    partner_entered = tracks.entered_lane_of(partner.name, ego.name, t)
    if ego_entered or partner_entered:
        return ego_entered, "entry"
    side = _sideways(tracks, ego, partner)
    if side is not None:
        return side, "side"
    e0, p0 = tracks.before(ego.name), tracks.before(partner.name)
    if e0 is not None and p0 is not None and e0[0] == p0[0]:
        ego_x, partner_x = e0[1].x, p0[1].x   # who was behind before they touched (a step is up to 4 m)
    else:
        ego_x, partner_x = ego.x, partner.x
    if ego_x <= partner_x:
        return partner.speed >= 0, "rear-end"
    return ego.speed < 0, "rear-end"


def agent_of(name: str, setting: SumoSetting, rng: np.random.Generator):
    """A driver proposing ``[acceleration, steering]`` from the ego's body and the others' bodies."""
    if name not in AGENTS:
        raise ConfigError(f"agent must be one of {', '.join(AGENTS)}, got {name!r}")
    amax, smax = setting.traffic.emergency_decel, setting.max_steering
    held = {"u": (0.0, 0.0), "left": 0}

    def random_agent(ego, others, t):
        if held["left"] <= 0:
            held["u"] = (float(rng.uniform(-amax, amax)), float(rng.uniform(-0.05, 0.05)))
            held["left"] = int(rng.integers(5, 20))
        held["left"] -= 1
        return held["u"]

    def reckless(ego, others, t):
        return amax, float(np.clip(0.05 * math.sin(t / 1.5) - 0.5 * ego.heading, -smax, smax))

    def seek(ego, others, t):
        ahead = [b for b in others if 0 < b.x - ego.x < 80]
        if not ahead:
            return amax, -0.5 * ego.heading
        target = min(ahead, key=lambda b: math.dist((b.x, b.y), (ego.x, ego.y)))
        bearing = math.atan2(target.y - ego.y, target.x - ego.x) - ego.heading
        return amax, float(np.clip(0.3 * bearing, -0.05, 0.05))

    return {"random": random_agent, "reckless": reckless, "seek": seek}[name]


def traffic_accel_of(traci) -> float:
    """The hardest braking any traffic vehicle type allows (its emergencyDecel): the traffic model's bound."""
    decels = [traci.vehicletype.getEmergencyDecel(t) for t in traci.vehicletype.getIDList()
              if t != EGO and not t.startswith("DEFAULT_")]
    return max(decels)


def _start(setting: SumoSetting, folder: Path, seed: int):
    try:
        with contextlib.redirect_stdout(sys.stderr):  # libsumo prints its warnings (pyarrow's version) on stdout
            import libsumo as traci
    except ImportError:
        raise ConfigError("libsumo is not installed: pip install 'guardian[sumo]'") from None
    net = network.build_network(setting.net, folder)
    routes = network.write_routes(setting.traffic, [(EGO, setting.ego_length, setting.ego_width,
                                                    setting.traffic.emergency_decel)], folder, setting.net.edge,
                                  setting.warmup + setting.seconds + 10)
    args = ["sumo", "-n", str(net), "-r", str(routes), "--step-length", f"{setting.step_length:g}", "--seed",
            str(seed), "--collision.action", "warn", "--collision.mingap-factor", "0", "--no-step-log", "true",
            "--no-warnings", "true", "--duration-log.disable", "true", "--default.speeddev",
            f"{setting.traffic.speed_factor_dev:g}"]
    if setting.traffic.sublane:
        args += ["--lateral-resolution", f"{setting.traffic.lateral_resolution:g}"]
    traci.start(args)
    return traci


def _insert(traci, setting: SumoSetting, rng: np.random.Generator) -> bool:
    lane = int(rng.integers(setting.net.lanes))
    pos = float(rng.uniform(0.25, 0.45) * setting.net.length)
    traci.vehicle.add(EGO, "main", typeID=EGO, departLane=str(lane), departPos=f"{pos:g}",
                      departSpeed=f"{setting.depart_speed:g}")
    for _ in range(200):
        traci.simulationStep()
        if EGO in traci.vehicle.getIDList():
            traci.vehicle.setSpeedMode(EGO, 0)
            traci.vehicle.setLaneChangeMode(EGO, 0)
            return True
    return False


def run_episode(setting: SumoSetting, agent: str, seed: int, guarded: bool = True,
                config: GuardianConfig | None = None, folder: Path | None = None, ask=None) -> dict:
    """One episode; its counts (the module's docstring says each one's rule).

    ``ask(guard, road)``: a decision object to use instead of ``guard`` (its ``step`` the same), e.g. a
    ``guardian.client.shadow.Shadow`` that also asks a service session every step; its ``tally`` (steps asked,
    disagreements) is reported as ``service_steps`` and ``service_disagreements``, and its ``session`` closed."""
    rng = np.random.default_rng([seed, 1])
    with tempfile.TemporaryDirectory() as tmp:
        folder = folder or Path(tmp)
        traci = _start(setting, folder, seed)
        try:
            return _episode(traci, setting, agent, rng, guarded, config, ask)
        finally:
            traci.close()


def _episode(traci, setting: SumoSetting, agent: str, rng, guarded: bool, config, ask=None) -> dict:
    dt = setting.step_length
    for _ in range(round(setting.warmup / dt)):
        traci.simulationStep()
    frame = Frame(traci, setting.net.edge)
    accel = traffic_accel_of(traci)
    config = replace(config or GuardianConfig(), traffic_accel=accel)
    kin = BicycleEgo(dt, accel, setting.ego_length, setting.ego_width, frame.lane_width, frame.n_lanes,
                     setting.max_steering)
    guard, model = BicycleGuardian(kin, config, meta=False), BicycleModel(setting.ego_length, dt)
    if ask is not None and guarded:
        guard = ask(guard, frame.road)
    drive = agent_of(agent, setting, rng)
    out = {"steps": 0, "collisions": 0, "sumo_collisions": 0, "at_fault": 0, "fault_rule": None, "partner": None,
           "start_inside": None, "overrides": 0, "safety_overrides": 0, "failsafe_steps": 0, "ego_uncovered": 0,
           "ego_worst_m": 0.0, "ego_lane_unseen": 0, "traffic_car_steps": 0, "traffic_uncovered": 0, "traffic_braking_excess": 0.0,
           "traffic_progress_excess_m": 0.0, "emergency_braking": 0, "teleports": 0, "distance_m": 0.0,
           "inserted": _insert(traci, setting, rng), "traffic_accel": accel, "step_length": dt}
    if not out["inserted"]:
        return out
    tracks, prev, expected, t0 = Tracks(), {}, None, traci.simulation.getTime()
    start = frame.body(traci, EGO)
    start_x, slot = start.x, frame.road.nearest_slot(start.x, start.y)
    slots = frame.road.body_slots(start.x, start.y, start.heading, start.length, start.width)
    for k in range(round(setting.seconds / dt)):
        t = traci.simulation.getTime() - t0
        ids = [v for v in traci.vehicle.getIDList() if v != EGO]
        ego = frame.body(traci, EGO)
        others = [frame.body(traci, v) for v in ids]
        if expected is not None:
            off = math.dist((ego.x, ego.y), expected[:2])
            out["ego_worst_m"] = max(out["ego_worst_m"], off)
            out["ego_uncovered"] += off > PLACEMENT_TOL
        _traffic_coverage(out, prev, others, accel, dt)
        prev = {b.name: b for b in others}
        for b in [ego, *others]:
            tracks.see(b.name, frame.road.body_slots(b.x, b.y, b.heading, b.length, b.width), t, b)
        touching = [b for b in others if overlap(ego, b)]
        sumo_hit = [c for c in traci.simulation.getCollisions() if EGO in (c.collider, c.victim)]
        out["sumo_collisions"] += bool(sumo_hit)
        if touching or sumo_hit:
            partner = touching[0] if touching else next(
                b for b in others if b.name in (sumo_hit[0].collider, sumo_hit[0].victim))
            fault, rule = at_fault(ego, partner, tracks, t)
            out.update(collisions=1, at_fault=int(fault), fault_rule=rule, partner=partner.name)
            break
        proposed = drive(ego, others, t)
        state = ego_state(ego)
        if guarded:
            applied, d = guard.step(state, scene(frame, ego, others, config.reverse_reach, kin.LATERAL_MARGIN),
                                    proposed)
            if out["start_inside"] is None:
                out["start_inside"] = bool(d.in_invariant_set)
            out["overrides"] += d.changed != "none"
            out["safety_overrides"] += d.changed != "none" and not d.clipped_to_model
            out["failsafe_steps"] += d.level == "failsafe"
        else:
            applied = (float(np.clip(proposed[0], -accel, accel)),
                       float(np.clip(proposed[1], -setting.max_steering, setting.max_steering)))
            if out["start_inside"] is None:
                _, d = guard.step(state, scene(frame, ego, others, config.reverse_reach, kin.LATERAL_MARGIN),
                                  proposed)
                out["start_inside"] = bool(d.in_invariant_set)
        expected = model.step(ego.x, ego.y, ego.heading, ego.speed, float(applied[0]), float(applied[1]))
        now = frame.road.body_slots(expected[0], expected[1], expected[2], setting.ego_length, setting.ego_width)
        slot, slots = sumo_slot(frame, now, slot, slots), now
        place(traci, frame, EGO, *expected, slot)
        traci.simulationStep()
        out["steps"] = k + 1
        if EGO in traci.vehicle.getIDList():
            out["ego_lane_unseen"] += frame.slot(traci.vehicle.getLaneIndex(EGO)) != slot
        out["emergency_braking"] += traci.simulation.getEmergencyStoppingVehiclesNumber()
        out["teleports"] += traci.simulation.getStartingTeleportNumber()
        if EGO not in traci.vehicle.getIDList() or expected[0] > setting.net.length - 50:
            break
    out["distance_m"] = (expected[0] if expected is not None else start_x) - start_x
    tally = getattr(guard, "tally", None)
    if tally is not None:
        out["service_steps"], out["service_disagreements"] = tally.steps, len(tally.disagreements)
        guard.session.close()
    return out


def _traffic_coverage(out: dict, prev: dict, others: list, accel: float, dt: float) -> None:
    seen = [(prev[b.name], b) for b in others if b.name in prev]
    out["traffic_car_steps"] += len(seen)
    for b0, b1 in seen:
        a = (b1.speed - b0.speed) / dt
        progress = (b1.x - b0.x) - dt * b0.speed
        braking_excess = -accel - a
        out["traffic_braking_excess"] = max(out["traffic_braking_excess"], braking_excess)
        out["traffic_progress_excess_m"] = max(out["traffic_progress_excess_m"], abs(progress))
        out["traffic_uncovered"] += braking_excess > 1e-6 or abs(progress) > 1e-6


def summary(results: list) -> dict:
    """The episodes' totals; collisions after starts outside apart."""
    inserted = [r for r in results if r["inserted"]]
    inside = [r for r in inserted if r["start_inside"]]
    total = {k: sum(r[k] for r in inserted) for k in ("steps", "collisions", "sumo_collisions", "at_fault",
                                                       "overrides", "safety_overrides", "failsafe_steps",
                                                       "ego_uncovered", "ego_lane_unseen", "traffic_car_steps", "traffic_uncovered",
                                                       "emergency_braking", "teleports")}
    return {"episodes": len(results), "not_inserted": len(results) - len(inserted),
            "starts_outside": len(inserted) - len(inside), **total,
            "at_fault_after_inside": sum(r["at_fault"] for r in inside),
            "at_fault_after_outside": sum(r["at_fault"] for r in inserted if not r["start_inside"]),
            "ego_worst_m": max((r["ego_worst_m"] for r in inserted), default=0.0),
            "traffic_braking_excess": max((r["traffic_braking_excess"] for r in inserted), default=0.0),
            "traffic_progress_excess_m": max((r["traffic_progress_excess_m"] for r in inserted), default=0.0),
            "hours": sum(r["steps"] * r["step_length"] for r in inserted) / 3600,
            **({"service_steps": sum(r.get("service_steps", 0) for r in inserted),
                "service_disagreements": sum(r.get("service_disagreements", 0) for r in inserted)}
               if any("service_steps" in r for r in inserted) else {})}


def setting_dict(setting: SumoSetting) -> dict:
    return asdict(setting)
