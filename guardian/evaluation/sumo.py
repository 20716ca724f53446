"""Guarded episodes in Eclipse SUMO: SUMO's own traffic, one or many guarded vehicles, counted by SUMO and a judge.

An episode: SUMO (libsumo, in process) runs the network and traffic of a ``SumoSetting`` for ``warmup`` seconds,
inserts the guarded vehicles, then every SUMO step reads the scene (``guardian.adapters.sumo.scene``), lets each
guarded vehicle's driver propose ``[acceleration, steering]``, has its own ``BicycleGuardian`` decide (or not,
unguarded), moves it by the model under the applied input, gives its body's other lanes shadows
(``guardian.adapters.sumo.shadows``: SUMO's drivers see a body over the line) and steps SUMO.

With several guarded vehicles each has its own guardian and driver and sees every other vehicle as traffic;
with ``GuardianConfig.overapprox = "ordered"`` they decide in Example 8's order (``itha.road.example8_order``:
ahead first, on ties the slower lane first), each told the lanes the vehicles before it announced they may
occupy during the step, as on highway-env.

**The traffic model is read from SUMO**: the hardest braking of any traffic vehicle type (its
``emergencyDecel``) becomes ``GuardianConfig.traffic_accel`` (and the guarded vehicles' acceleration bound, which
the car-following sets share). **Counted** (the rules, in docs/sumo.md, tested on hand-built cases):

- ``collisions``: a guarded vehicle's body overlaps another's (rotated rectangles), or SUMO reports a collision
  involving it (``sumo_collisions``, its own detection, counted apart; a shadow's are ``shadow_collisions``).
  Both vehicles leave the road there; with one guarded vehicle the episode ends. Each collision is one entry
  of ``crashes``.
- fault: ``guardian.evaluation.sumo_judge.at_fault`` on the bodies at contact, asked for the guarded vehicle
  (between two guarded vehicles, for the one listed first; ties go against it). A collision at fault counts
  after a start inside or outside by the start of the guarded vehicle at fault (``at_fault_after_inside``,
  ``at_fault_after_outside``); ``between_guarded`` counts collisions of two guarded vehicles.
- ``starts_outside``: guarded vehicles whose first decision found no self-safe acceleration
  (``in_invariant_set`` false).
- ``emergency_braking``, ``teleports``: SUMO's own counts of its traffic's emergency stops and teleports.
- ``ego_lane_unseen``: vehicle-steps where a lane a guarded body overlaps held neither the vehicle nor one of
  its shadows in SUMO after the step (the cars behind there did not see it).
- model coverage: ``ego_uncovered`` (SUMO did not put a guarded vehicle where the model said, more than 1 mm
  off) and ``traffic_uncovered`` (a traffic car's step outside the traffic model, by its cause: braking beyond
  ``traffic_accel`` (``traffic_uncovered_braking``), or a position update other than the Euler step ``x + v dt``
  of (7.3) (``traffic_uncovered_position``; SUMO's default Euler update moves a car by its *new* speed, so every
  step with a speed change counts); a step with both causes counts once in the total), with the worst excess of
  each.
- ``guarded_lost``: guarded vehicles SUMO removed before the road's end (never expected: counted against us).
- ``ego_speed_reset``: steps after which SUMO had a guarded vehicle at another speed than the model's (moved by
  position onto a junction's internal lane, SUMO stands it still: an instant stop in front of the traffic). The
  model's speed is restored at once (``setPreviousSpeed``) and the step is counted.
- ``actuator_clipped``: with an actuator (``SumoSetting.jerk``, ``SumoSetting.lag``: the model applies an
  acceleration held over the step, moved part of the way to the command under a lag and changed by at most ``jerk *
  dt`` from the last, the speed stopping at 0, and the guardian decides on ``itha.actuator.RateLimitedSet``),
  vehicle-steps whose command the jerk bound cut (``Actuator.response``; 0 by construction with the guardian; the
  unguarded drivers' clips are counted too). None without an actuator.
- ``lane_changes``: steps at which a guarded vehicle's centre moved to another lane; ``distance_m``: the guarded
  vehicles' distance along the road, summed.
- ``ramp_starts``: inserted guarded vehicles that started on the on-ramp (``SumoSetting.start``); ``merged``: of
  those, the ones whose centre reached a main lane of the corridor during the episode (one that never did was held
  on the ramp or the acceleration lane: safe, and counted, since it did not get where it was going).
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from guardian.adapters.sumo.connection import close_sumo, open_sumo
from guardian.adapters.sumo.scene import BicycleModel, Frame, ego_state, overlap, place, sensed_scene, traffic_of
from guardian.adapters.sumo.shadows import Shadows, is_shadow
from guardian.config import GuardianConfig
from guardian.decide.bicycle import BicycleGuardian
from guardian.decide.kinematics import BicycleEgo, RoadMapEgo
from guardian.evaluation.sumo_agents import agent_of
from guardian.evaluation.sumo_judge import Tracks, at_fault
from guardian.evaluation.sumo_setting import SumoSetting, guarded_names, insert_guarded, sumo_args, traffic_accel_of
from guardian.model.roads import RoadMap
from itha.road import example8_order

PLACEMENT_TOL = 1e-3  # [m] SUMO's placement of the guarded vehicle against the model's state
SPEED_TOL = 1e-6      # [m/s] SUMO's speed of the guarded vehicle against the model's (it takes the speed set)


@dataclass
class Guarded:
    """One guarded vehicle of an episode: its guardian and driver, the model's next state, its start."""

    name: str
    guard: object
    drive: object
    start_x: float
    expected: tuple | None = None
    start_inside: bool | None = None
    lane: int | None = None       # the slot of its centre at the last step (lane changes are counted on it)
    accel: float = 0.0            # the acceleration its actuator applied over the last step (with a jerk limit)


def run_episode(setting: SumoSetting, agent: str, seed: int, guarded: bool = True,
                config: GuardianConfig | None = None, folder: Path | None = None, ask=None, recorder=None) -> dict:
    """One episode; its counts (the module's docstring says each one's rule).

    ``ask(guard, road)``: a decision object to use instead of ``guard`` (its ``step`` the same), e.g. a
    ``guardian.client.shadow.Shadow`` that also asks a service session every step; its ``tally`` (steps asked,
    disagreements) is reported as ``service_steps`` and ``service_disagreements``, and its ``session`` closed.
    ``folder``: where the scenario's files are written (a temporary folder by default; with a ``HOST:PORT``
    connection, a folder the server reads at the same path). ``recorder``: a
    ``guardian.recording.sumo.SumoRecorder`` the episode is logged to."""
    rng = np.random.default_rng([seed, 1])
    with tempfile.TemporaryDirectory() as tmp:
        folder = folder or Path(tmp)
        traci = open_sumo(setting.connection, sumo_args(setting, folder, seed))
        try:
            return _episode(traci, setting, agent, rng, guarded, config, ask, recorder, f"{agent} seed {seed}")
        finally:
            close_sumo(setting.connection, traci)


def _episode(traci, setting: SumoSetting, agent: str, rng, guarded: bool, config, ask=None, recorder=None,
             label: str = "") -> dict:
    dt = setting.step_length
    for _ in range(round(setting.warmup / dt)):
        traci.simulationStep()
    frame = Frame(traci, setting.net.corridor, setting.net.ramp, setting.net.exit)
    accel = traffic_accel_of(traci)
    # SUMO's vehicles never drive backwards: the cover for reversing traffic waits for a negative speed
    config = replace(config or GuardianConfig(), traffic_accel=accel, reverse_horizon=0.0)
    out = {"steps": 0, "vehicle_steps": 0, "collisions": 0, "sumo_collisions": 0, "shadow_collisions": 0,
           "between_guarded": 0, "at_fault": 0, "at_fault_after_inside": 0, "at_fault_after_outside": 0, "crashes": [],
           "guarded": setting.guarded, "starts_outside": 0, "start_inside": None, "overrides": 0,
           "safety_overrides": 0, "failsafe_steps": 0, "lane_changes": 0, "ego_uncovered": 0, "ego_worst_m": 0.0, "ego_lane_unseen": 0,
           "guarded_lost": 0, "ego_speed_reset": 0, "traffic_car_steps": 0, "traffic_uncovered": 0,
           "traffic_uncovered_braking": 0, "traffic_uncovered_position": 0, "traffic_braking_excess": 0.0,
           "traffic_progress_excess_m": 0.0, "emergency_braking": 0, "teleports": 0, "distance_m": 0.0,
           "ramp_starts": 0, "merged": 0, "actuator_clipped": None if setting.actuator is None else 0,
           "inserted": insert_guarded(traci, setting, frame, rng), "traffic_accel": accel, "step_length": dt}
    out["ramp_starts"] = int(out["inserted"] and setting.start == "ramp")
    if out["inserted"]:
        _Episode(traci, setting, frame, config, guarded, out, recorder).run(agent, rng, ask, label)
    return out


class _Episode:
    """The state of one inserted episode: the guarded vehicles, their shadows, the judge's tracks, the counts."""

    def __init__(self, traci, setting: SumoSetting, frame: Frame, config: GuardianConfig, guarded: bool, out: dict,
                 recorder=None):
        self.traci, self.setting, self.frame, self.config, self.guarded, self.out = traci, setting, frame, config, guarded, out
        self.recorder = recorder
        if isinstance(frame.road, RoadMap):
            self.kin = RoadMapEgo(setting.step_length, config.traffic_accel, setting.ego_length, setting.ego_width,
                                  frame.road, setting.max_steering)
        else:
            self.kin = BicycleEgo(setting.step_length, config.traffic_accel, setting.ego_length, setting.ego_width,
                                  frame.lane_width, frame.n_lanes, setting.max_steering)
        self.model = BicycleModel(setting.ego_length, setting.step_length)
        self.actuator = setting.actuator
        self.shadows, self.tracks, self.prev = Shadows(frame), Tracks(), {}
        self.cars: list = []
        self.left: list = []     # guarded vehicles that left the road or crashed (their tallies are kept)
        self.merged: set = set()  # guarded vehicles that started on the ramp and reached a main lane

    def run(self, agent: str, rng, ask, label: str = "") -> None:
        traci, setting, dt = self.traci, self.setting, self.setting.step_length
        single = setting.guarded == 1
        for name in guarded_names(setting):
            guard = BicycleGuardian(self.kin, self.config, meta=False, actuator=self.actuator)
            if ask is not None and self.guarded:
                guard = ask(guard, self.frame.road)
            own = rng if single else np.random.default_rng([int(rng.integers(1 << 31))])  # one driver each
            driver = agent_of(agent, setting, own, traci=traci, vehicle=name, frame=self.frame)
            self.cars.append(Guarded(name, guard, driver, self.frame.body(traci, name).x))
        t0 = traci.simulation.getTime()
        if self.recorder is not None:
            self.recorder.start_episode(label, self.frame, self.frame.body(traci, self.cars[0].name))
        for k in range(round(setting.seconds / dt)):
            t = traci.simulation.getTime() - t0
            bodies = {v: self.frame.body(traci, v) for v in traci.vehicle.getIDList() if not is_shadow(v)}
            if self.recorder is not None:
                self._record(t, bodies)
            self._observe(bodies, t)
            self._crashes(bodies, t)
            if not self.cars:
                break
            self._decide(bodies, t)
            traci.simulationStep()
            self.out["steps"], self.out["vehicle_steps"] = k + 1, self.out["vehicle_steps"] + len(self.cars)
            self._after_step()
            if not self.cars:
                break
        self._close()

    def _record(self, t: float, bodies: dict) -> None:
        names = {c.name for c in self.cars}
        shadows = [self.frame.body(self.traci, v) for v in self.traci.vehicle.getIDList() if is_shadow(v)]
        self.recorder.step(t)
        self.recorder.bodies([b for v, b in bodies.items() if v in names],
                             [b for v, b in bodies.items() if v not in names], shadows)

    def _observe(self, bodies: dict, t: float) -> None:
        names = {c.name for c in self.cars}
        traffic = [b for v, b in bodies.items() if v not in names]
        _traffic_coverage(self.out, self.prev, traffic, self.config.traffic_accel, self.setting.step_length)
        self.prev = {b.name: b for b in traffic}
        for b in bodies.values():
            self.tracks.see(b.name, self.frame.road.body_slots(b.x, b.y, b.heading, b.length, b.width), t, b)
        for car in self.cars:
            me = bodies.get(car.name)
            if car.expected is not None and me is not None:
                off = math.dist((me.x, me.y), car.expected[:2])
                self.out["ego_worst_m"] = max(self.out["ego_worst_m"], off)
                self.out["ego_uncovered"] += off > PLACEMENT_TOL

    def _crashes(self, bodies: dict, t: float) -> None:
        """Each guarded vehicle touching another body (or in a collision SUMO reports): counted; both leave."""
        reported = self.traci.simulation.getCollisions()
        self.out["shadow_collisions"] += sum(is_shadow(c.collider) or is_shadow(c.victim) for c in reported)
        gone = set()
        for car in list(self.cars):
            me = bodies.get(car.name)
            if me is None or car.name in gone:
                continue
            touching = [b for v, b in bodies.items() if v != car.name and v not in gone and overlap(me, b)]
            hit = [c for c in reported if car.name in (c.collider, c.victim)]
            hit_others = [c.victim if c.collider == car.name else c.collider for c in hit]
            hit_others = [v for v in hit_others if v in bodies and v not in gone]
            if not (touching or hit_others):
                continue
            partner = touching[0] if touching else bodies[hit_others[0]]
            gone |= {car.name, partner.name}
            self._count_crash(car, partner, bool(hit), t)
        for name in gone:
            self._leave(name)

    def _count_crash(self, car: Guarded, partner, by_sumo: bool, t: float) -> None:
        bodies_fault, rule = at_fault(self.tracks.seen[car.name][-1][1], partner, self.tracks, t)
        other = next((c for c in self.cars if c.name == partner.name), None)
        culprit = car if bodies_fault else other
        inside = None if culprit is None else culprit.start_inside is not False   # unknown: counted as inside
        out = self.out
        out["collisions"] += 1
        out["sumo_collisions"] += by_sumo
        out["between_guarded"] += other is not None
        if culprit is not None:
            out["at_fault"] += 1
            out["at_fault_after_inside" if inside else "at_fault_after_outside"] += 1
        out["crashes"].append({"vehicle": car.name, "partner": partner.name, "rule": rule, "at_fault":
                               culprit is not None, "culprit": culprit.name if culprit else None,
                               "start_inside": inside, "between_guarded": other is not None, "step": out["steps"],
                               "by_sumo": by_sumo})
        if self.recorder is not None:
            self.recorder.crash(out["crashes"][-1])

    def _leave(self, name: str) -> None:
        """Remove vehicle ``name`` (and, if guarded, its shadows) from SUMO and from the episode."""
        if name in self.traci.vehicle.getIDList():
            self.traci.vehicle.remove(name)
        self.shadows.drop(self.traci, name)
        for car in [c for c in self.cars if c.name == name]:
            self.cars.remove(car)
            self.left.append(car)

    def _decide(self, bodies: dict, t: float) -> None:
        """Every guarded vehicle's step (in Example 8's order under the ordered over-approximation)."""
        names = {c.name for c in self.cars}
        announced, ordered = {}, self.config.overapprox == "ordered" and len(self.cars) > 1
        order = range(len(self.cars))
        if ordered:
            numbering = self.frame.road.numbering
            order = example8_order([bodies[c.name].front for c in self.cars],
                                   [numbering.itha(bodies[c.name].own) for c in self.cars])
        # every body read once; each guarded vehicle's scene is the road without its own body (guardian.model.sensing.
        # Traffic), the other guarded vehicles announcing (in the ordered case, the lanes they announced so far)
        readings = {v: b if v not in names else replace(b, announces=True, announced=frozenset())
                    for v, b in bodies.items()}
        traffic = traffic_of(self.frame, list(readings.values()), self.config.reversing, self.kin.LATERAL_MARGIN)
        for i in order:
            car = self.cars[i]
            patched = [replace(readings[v], announced=lanes) for v, lanes in announced.items() if lanes]
            seen = sensed_scene(traffic, bodies[car.name], patched)
            d = self._step(car, bodies[car.name], seen, t)
            if ordered:  # where this vehicle may be during the step, for the vehicles after it
                announced[car.name] = frozenset(d.lanes) | frozenset(d.touched)

    def _step(self, car: Guarded, me, seen, t: float):
        """One guarded vehicle: propose, decide (or not), move by the model, tell SUMO, place its shadows."""
        out, kin, setting = self.out, self.kin, self.setting
        proposed = car.drive(me, list(seen.sensed), t)
        state = ego_state(me) if self.actuator is None else replace(ego_state(me), acceleration=car.accel)
        if self.guarded:
            applied, d = car.guard.step(state, seen, proposed)
            out["overrides"] += d.changed != "none"
            out["safety_overrides"] += d.changed != "none" and not d.clipped_to_model
            out["failsafe_steps"] += d.level == "failsafe"
        else:
            applied = (float(np.clip(proposed[0], -kin.accel, kin.accel)),
                       float(np.clip(proposed[1], -setting.max_steering, setting.max_steering)))
            d = car.guard.step(state, seen, proposed)[1]   # asked only for the start and the announcement
        if car.start_inside is None:
            car.start_inside = bool(d.in_invariant_set)
        if self.recorder is not None:
            self.recorder.decision(car.name, proposed, applied, d if self.guarded else None)
        a = float(applied[0])
        if self.actuator is not None:   # the lag's response, within jerk * dt of the last; the speed stops at 0
            a, cut = self.actuator.response(car.accel, a, setting.step_length)
            out["actuator_clipped"] += cut
            car.accel = a
        car.expected = self.model.step(me.x, me.y, me.heading, me.speed, a, float(applied[1]))
        if self.actuator is not None and car.expected[3] < 0.0 <= me.speed:
            car.expected = (*car.expected[:3], 0.0)
        x, y, heading, speed = car.expected
        own = place(self.traci, self.frame, car.name, x, y, heading, speed)
        slots = self.frame.road.body_slots(x, y, heading, me.length, me.width)
        self.shadows.update(self.traci, car.name, x, y, heading, speed, me.length, slots, own)
        return d

    def _after_step(self) -> None:
        traci, out, road = self.traci, self.out, self.frame.road
        present = set(traci.vehicle.getIDList())
        out["emergency_braking"] += traci.simulation.getEmergencyStoppingVehiclesNumber()
        out["teleports"] += traci.simulation.getStartingTeleportNumber()
        for car in list(self.cars):
            if car.name not in present:
                out["guarded_lost"] += 1
                self._leave(car.name)
                continue
            x, y, heading, speed = car.expected
            if abs(traci.vehicle.getSpeed(car.name) - speed) > SPEED_TOL:
                # SUMO set a speed of its own (moved by position onto a junction's internal lane, it stands the
                # vehicle still): the model's is restored before anyone reads it, and the step is counted
                traci.vehicle.setPreviousSpeed(car.name, speed)
                out["ego_speed_reset"] += 1
            lane = road.nearest_slot(x, y)
            out["lane_changes"] += car.lane is not None and lane != car.lane
            car.lane = lane
            if self.setting.start == "ramp" and lane < self.setting.net.lanes and self.frame.on_corridor(lane, x):
                self.merged.add(car.name)
            body = road.body_slots(x, y, heading, self.setting.ego_length, self.setting.ego_width)
            out["ego_lane_unseen"] += not body <= self.shadows.lanes_seen(traci, car.name)
            if self.frame.leaving(x, y):   # at the road's end, or the end of the exit it took: leaves
                self._leave(car.name)

    def _close(self) -> None:
        out, cars = self.out, self.left + self.cars
        starts = [c.start_inside for c in cars if c.start_inside is not None]
        out["starts_outside"] = starts.count(False)
        out["merged"] = len(self.merged)
        out["start_inside"] = all(starts) if starts else None
        out["distance_m"] = float(sum((c.expected[0] if c.expected else c.start_x) - c.start_x for c in cars))
        tallies = [c.guard.tally for c in cars if getattr(c.guard, "tally", None) is not None]
        if tallies:
            out["service_steps"] = sum(t.steps for t in tallies)
            out["service_disagreements"] = sum(len(t.disagreements) for t in tallies)
            for c in cars:
                c.guard.session.close()

def _traffic_coverage(out: dict, prev: dict, others: list, accel: float, dt: float) -> None:
    seen = [(prev[b.name], b) for b in others if b.name in prev]
    out["traffic_car_steps"] += len(seen)
    for b0, b1 in seen:
        a = (b1.speed - b0.speed) / dt
        progress = (b1.front - b0.front) - dt * b0.speed   # along the lane's chain (the ramp's too)
        braking_excess = -accel - a
        out["traffic_braking_excess"] = max(out["traffic_braking_excess"], braking_excess)
        out["traffic_progress_excess_m"] = max(out["traffic_progress_excess_m"], abs(progress))
        braked, moved = braking_excess > 1e-6, abs(progress) > 1e-6
        out["traffic_uncovered"] += braked or moved
        out["traffic_uncovered_braking"] += braked
        out["traffic_uncovered_position"] += moved


SUMMED = ("steps", "vehicle_steps", "collisions", "sumo_collisions", "shadow_collisions", "between_guarded", "at_fault",
          "at_fault_after_inside", "at_fault_after_outside", "starts_outside", "overrides", "safety_overrides",
          "lane_changes",
          "failsafe_steps", "ego_uncovered", "ego_speed_reset", "ego_lane_unseen", "guarded_lost", "traffic_car_steps",
          "traffic_uncovered", "traffic_uncovered_braking", "traffic_uncovered_position", "emergency_braking",
          "teleports", "distance_m", "ramp_starts", "merged")
OPTIONAL = ("actuator_clipped",)   # None where not measured (no jerk limit); summed where measured


def summary(results: list) -> dict:
    """The episodes' totals; a collision at fault counts after a start inside or outside by the start of the guarded
    vehicle at fault; ``hours`` of guarded driving (vehicle-steps)."""
    inserted = [r for r in results if r["inserted"]]
    total = {k: sum(r[k] for r in inserted) for k in SUMMED}
    for k in OPTIONAL:
        measured = [r[k] for r in inserted if r.get(k) is not None]
        total[k] = sum(measured) if measured else None
    return {"episodes": len(results), "not_inserted": len(results) - len(inserted), **total,
            "ego_worst_m": max((r["ego_worst_m"] for r in inserted), default=0.0),
            "traffic_braking_excess": max((r["traffic_braking_excess"] for r in inserted), default=0.0),
            "traffic_progress_excess_m": max((r["traffic_progress_excess_m"] for r in inserted), default=0.0),
            "hours": sum(r["vehicle_steps"] * r["step_length"] for r in inserted) / 3600,
            **({"service_steps": sum(r.get("service_steps", 0) for r in inserted),
                "service_disagreements": sum(r.get("service_disagreements", 0) for r in inserted)}
               if any("service_steps" in r for r in inserted) else {})}
