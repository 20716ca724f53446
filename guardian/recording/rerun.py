"""rerun recordings (viewer: ``rerun FILE.rrd``): supervised rollouts (``GuardianRecorder``, every
environment), the ITHA highway experiment (``HighwayRecorder``) and HighD-format recordings.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import rerun as rr


def save_to(rec, path, blueprint) -> None:
    """Stream ``rec`` into the file ``path`` (its folder made if missing) with ``blueprint`` as the view."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    rec.save(str(path), default_blueprint=blueprint)


ROLLOUT_VIEW = 300.0   # [m] of road in view when a rollout recording opens (a road may be 20 km long)
PROPOSED, APPLIED, ADMISSIBLE = (220, 50, 50), (30, 30, 30), (40, 160, 60)


GUARDED, OVERRIDDEN, FAILSAFE = (40, 180, 60), (200, 40, 200), (220, 50, 50)
HELD, REFUSED = (40, 180, 60, 50), (220, 50, 50, 70)   # translucent: the lanes a guarded car holds, entries refused
LANE_AHEAD = 120.0   # [m] of each such lane drawn, from 10 m behind the guarded car


def override_mark(record: dict) -> tuple:
    """A guarded car's colour on the road for its step's record: green, magenta when the guardian overrode it for
    safety, red on a fail-safe step."""
    if record.get("level") == "failsafe" or record.get("failsafe_steps"):
        return FAILSAFE
    return OVERRIDDEN if record.get("overridden") and record.get("safety_override", True) else GUARDED


def follow_labels(rec, labelled) -> None:
    """``road/follow/labels``: each ``(x, y, name)`` (x from the followed car) as a label in the followed frame. The
    viewer draws a label where its entity's position lies in the view's own frame, ignoring the transform between
    (rerun 0.41): a label on a box under ``road/`` appeared a car's world x from the view's left edge, or not at
    all."""
    rec.log("road/follow/labels", rr.Points2D([[x, y] for x, y, _ in labelled], labels=[n for _, _, n in labelled],
                                              radii=0.05, colors=[(20, 20, 20)] * len(labelled)))


FLEET_SHOWN = 4   # guarded cars whose plots a recording of several opens on (every car's are in the file)
SLICE_GAPS = np.linspace(0.0, 120.0, 61)   # [m] where the set's slice is drawn
SLICE_VIEW = "the invariant set's slice: the ego's speed (up, m/s) against its gap (m) to the nearest car ahead"
OVERTAKE_SLICE_VIEW = ("the active set's slice at the lateral position and lead speed now: the ego's speed (up, m/s) "
                       "against the lead's distance ahead h (m)")
OVERTAKE_WINDOW = (np.array([0.0, -100.0]), np.array([45.0, 150.0]))   # (v_ex, h) drawn


def overtake_slice_of(guard, x) -> dict:
    """What a recording draws of the overtake guardian's active set at the overtake state ``x = (v_ex, y_e, h,
    v_Lx)`` (``PointMassGuardian``): each piece of the set whose box holds ``(y_e, v_Lx)``, sliced there, as a polygon
    in ``(v_ex, h)`` (``rcis.planar.polygon``, clipped to ``OVERTAKE_WINDOW``), and whether ``x`` is inside."""
    from rcis.planar import polygon

    name = guard.lead.active_set
    region = guard.lead.library.region(name)
    lower, upper = region.boxes()
    pieces = []
    for P, lo, hi in zip(region, lower, upper):
        if lo[1] <= x[1] <= hi[1] and lo[3] <= x[3] <= hi[3]:
            V = polygon(P.slice([1, 3], [x[1], x[3]]), OVERTAKE_WINDOW)
            if len(V):
                pieces.append(V)
    return {"set": name, "pieces": pieces, "inside": bool(region.contains(np.asarray(x, float)))}


def slice_of(guard, ego, leaders) -> dict | None:
    """What a recording draws of a guarded car's car-following set at its state now (``BicycleGuardian``): behind
    the nearest of ``leaders`` (``guardian.model.scene.Car``, the cars ahead in the lanes it holds), the highest
    speed the set allows at each gap of ``SLICE_GAPS`` and where the car is; None with no car ahead."""
    if not leaders:
        return None
    lead = min(leaders, key=lambda c: c.front - c.length - ego.front)
    gap = lead.front - lead.length - ego.front
    limits = guard.speed_limits(ego, SLICE_GAPS, max(lead.speed, 0.0))
    (own,) = guard.speed_limits(ego, [gap], max(lead.speed, 0.0))
    return {"lead": lead.name or "the car ahead", "lead_speed": lead.speed, "gap": gap, "speed": ego.speed,
            "inside": own is not None and ego.speed <= own + 1e-9,
            "edge": [(float(h), v) for h, v in zip(SLICE_GAPS, limits) if v is not None]}


def car_root(car: int | None) -> str:
    """Where a guarded car's series live: ``/`` with one guarded car, ``/cars/car_K/`` with several."""
    return "/" if car is None else f"/cars/car_{car}/"


def _input_plots(car: int | None) -> list:
    """One plot per unit of a guarded car's inputs: proposed, applied and admissible."""
    import rerun.blueprint as rrb

    root, who = car_root(car), "" if car is None else f"car {car}: "
    return [rrb.TimeSeriesView(origin="/", contents=[f"{root}inputs/{k}/throttle" for k in ("proposed", "applied")]
                               + [f"{root}admissible/acceleration/**"],
                               name=f"{who}acceleration [m/s²]: proposed (red), applied (black), admissible (green)"),
            rrb.TimeSeriesView(origin="/", contents=[f"{root}inputs/{k}/steering" for k in ("proposed", "applied")]
                               + [f"{root}admissible/steering/**"],
                               name=f"{who}steering: proposed (red), applied (black), admissible (green)")]


def rollout_blueprint(base, overtake: bool, cars: int = 1):
    """A rollout recording's layout: the road seen from ``road/follow`` (a frame that moves along with the ego, so
    the view shows ``ROLLOUT_VIEW`` m around the ego at every step; the viewer would otherwise fit the whole road,
    kilometres, and show no car); one plot per unit (acceleration, steering, the lead's valid intentions on the
    overtake scenarios) and the events. With several guarded ``cars`` the view follows car 0, and each of the first
    ``FLEET_SHOWN`` cars has its plots as tabs."""
    import rerun.blueprint as rrb

    ys = [float(lane.start[1]) + side * lane.width for _from in base.road.network.graph.values()
          for group in _from.values() for lane in group for side in (-0.5, 0.5)]
    bounds = rrb.VisualBounds2D(x_range=[-ROLLOUT_VIEW / 4, 3 * ROLLOUT_VIEW / 4],
                                y_range=[min(ys) - 2.0, max(ys) + 2.0])
    if cars == 1:
        plots = _input_plots(None)
    else:
        plots = [rrb.Tabs(*_input_plots(k), active_tab=0) for k in range(min(cars, FLEET_SHOWN))]
    road = rrb.Spatial2DView(origin="/road/follow", contents=["/road/**"], name=(
        "road (ego green, lead amber, traffic blue; ego magenta when overridden, red on fail-safe), following the ego"
        if cars == 1 else "road (guarded cars green, magenta when overridden, red on fail-safe; traffic blue), "
                          "following car 0"), visual_bounds=bounds)
    if overtake:   # the active set's slice below the road
        road = rrb.Vertical(road, rrb.Spatial2DView(
            origin="/slice", name=OVERTAKE_SLICE_VIEW,
            visual_bounds=rrb.VisualBounds2D(x_range=[-60.0, 120.0], y_range=[-45.0, 5.0])), row_shares=[3, 2])
    else:   # highway-env's roads: the car-following set's slice below the road
        road = rrb.Vertical(road, rrb.Spatial2DView(
            origin="/slice", name=SLICE_VIEW + (" (car 0)" if cars > 1 else ""),
            visual_bounds=rrb.VisualBounds2D(x_range=[-5.0, SLICE_GAPS[-1] + 5.0], y_range=[-45.0, 5.0])),
            row_shares=[3, 2])
    if overtake:
        plots.append(rrb.TimeSeriesView(origin="/intention", name="the lead's valid intentions"))
        plots.append(rrb.TextLogView(origin="/", contents=["/guardian/active_set", "/intention/log"],
                                     name="the active set (each step) and the intentions' changes"))
    return rrb.Blueprint(rrb.Horizontal(
        road,
        rrb.Vertical(*plots, rrb.TextLogView(origin="/events", name="overrides and events"),
                     row_shares=[2] * len(plots) + [1]),
        column_shares=[3, 2]), collapse_panels=True)


DECIMAL = re.compile(r"-?\d+\.\d+")


def _reasons(reasons) -> str:
    """The step's reasons, each kind once: the simulation steps of a policy step repeat a reason with other numbers
    ("next speed at most 28.80 m/s", "... 28.40 m/s"); the first is kept, with how often it came."""
    kinds: dict = {}
    for r in reasons:
        kind = DECIMAL.sub("#", r)   # decimals vary from step to step; car and lane numbers do not
        first, n = kinds.get(kind, (r, 0))
        kinds[kind] = (first, n + 1)
    return "; ".join(first + (f" (x{n})" if n > 1 else "") for first, n in kinds.values())


def _shown(value) -> str:
    """An input as a person reads it: numbers to 3 decimals, a meta action by its name."""
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_shown(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


def _series_styles(rec, car: int | None = None) -> None:
    """Each series its colour and name, the same in both plots (of guarded car ``car`` when there are several)."""
    root = car_root(car)[1:]
    for axis in ("throttle", "steering"):
        rec.log(f"{root}inputs/proposed/{axis}", rr.SeriesLines(colors=[PROPOSED], names=["proposed"]), static=True)
        rec.log(f"{root}inputs/applied/{axis}", rr.SeriesLines(colors=[APPLIED], names=["applied"]), static=True)
    for axis in ("acceleration", "steering"):
        for side in ("low", "high"):
            rec.log(f"{root}admissible/{axis}/{side}",
                    rr.SeriesLines(colors=[ADMISSIBLE], names=[f"admissible {side}"]), static=True)


def run_blueprint(series: tuple[str, ...], road_name: str = "road"):
    """The layout a rollout recording opens with: the road left; the inputs beside their admissible
    range, and the events, right."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial2DView(origin="/road", name=road_name),
        rrb.Vertical(rrb.TimeSeriesView(origin="/", contents=[f"{s}/**" for s in series],
                                        name="inputs: proposed, applied, admissible range"),
                     rrb.TextLogView(origin="/events", name="overrides and events"), row_shares=[3, 1]),
        column_shares=[3, 2]), collapse_panels=True)


class _Closing:
    """Recorders close (flush the .rrd) when a ``with`` block ends, on an exception too."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_entities(path: Path) -> dict:
    """``{entity_path: number of rows}`` of an .rrd file (used by tests and checks)."""
    from rerun.chunk import RrdReader

    counts: dict = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        counts[chunk.entity_path] = counts.get(chunk.entity_path, 0) + chunk.num_rows
    return counts


def read_texts(path: Path, entity: str) -> list[str]:
    from rerun.chunk import RrdReader

    texts = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path == entity:
            col = chunk.to_record_batch().column("TextLog:text")
            texts.extend(t for row in col.to_pylist() for t in (row or []))
    return texts


# ---- the multi-lane highway (ITHA) -------------------------------------------------------------
HIGHWAY_LANE_WIDTH = 4.0


class HighwayRecorder(_Closing):
    """A highway run: lanes, every car, the ego's triggering decision, verdicts and overrides.

    * ``road/lanes`` lane markings (static), ``road/cars`` the traffic and ``road/ego`` the ego
      as boxes (x along the road, y = lane centre; lane 1 is the rightmost, drawn lowest)
    * ``ego/trigger`` (text), ``ego/acceleration`` (scalar)
    * ``verdicts/{stay,left,right}`` 1 if allowed (self-safe, responsible), 0 if not, with the
      reason in ``events/verdicts``; ``events/override`` for refused lane changes and clipped
      accelerations
    """

    def __init__(self, path: Path, n_lanes: int, application_id: str = "guardian-highway"):
        self.rec = rr.RecordingStream(application_id)
        save_to(self.rec, path, run_blueprint(("/ego",)))
        self.path = Path(path)
        self.n_lanes = n_lanes
        self.step_index = 0
        ys = [(k - 0.5) * HIGHWAY_LANE_WIDTH for k in range(1, n_lanes + 2)]
        self.rec.log("road/lanes", rr.LineStrips2D([[[-200.0, y - HIGHWAY_LANE_WIDTH],
                                                     [20000.0, y - HIGHWAY_LANE_WIDTH]] for y in ys]),
                     static=True)

    def _y(self, lane_number: float) -> float:
        return (lane_number - 1) * HIGHWAY_LANE_WIDTH

    def log_frame(self, p, lane, ego: int, trigger: str, accel: float, verdicts, overridden: str = "",
                  length: float = 5.0) -> None:
        rec = self.rec
        rec.set_time("step", sequence=self.step_index)
        others = [k for k in range(len(p)) if k != ego]
        rec.log("road/cars", rr.Boxes2D(centers=[[p[k], self._y(lane[k])] for k in others],
                                        half_sizes=[[length / 2, 1.0]] * len(others)))
        rec.log("road/ego", rr.Boxes2D(centers=[[p[ego], self._y(lane[ego])]], half_sizes=[[length / 2, 1.0]],
                                       labels=["ego"]))
        rec.log("ego/trigger", rr.TextLog(trigger))
        rec.log("ego/acceleration", rr.Scalars([float(accel)]))
        reasons = []
        for trig, ok, why in verdicts:
            rec.log(f"verdicts/{trig}", rr.Scalars([1.0 if ok else 0.0]))
            if not ok and why and why != "no such lane":
                reasons.append(f"{trig}: {why}")
        if reasons:
            rec.log("events/verdicts", rr.TextLog("; ".join(reasons)))
        if overridden:
            rec.log("events/override", rr.TextLog(overridden, level="WARN"))
        self.step_index += 1

    def log_itha_frames(self, frames) -> None:
        for fr in frames:
            self.log_frame(fr["p"], fr["lane"], 0, fr["trigger"], fr["u"], fr["verdicts"])

    def log(self, env, episode: int, t: int, proposed: str, guardian_info: dict) -> None:
        """One highway-env policy step (``highway_rollouts(recorder=...)``)."""
        base = env.unwrapped
        ego = base.vehicle
        vehicles = [ego] + [v for v in base.road.vehicles if v is not ego]
        n_lanes = self.n_lanes
        p = [float(v.position[0]) for v in vehicles]
        lane = [n_lanes - float(v.position[1]) / HIGHWAY_LANE_WIDTH for v in vehicles]
        g = guardian_info or {}
        note = ""
        if g.get("refused"):
            note = f"episode {episode} step {t}: {g['proposed']} refused ({g['reason']})"
        elif g.get("clipped_steps"):
            note = f"episode {episode} step {t}: acceleration clipped in {g['clipped_steps']} simulation steps"
        self.log_frame(p, lane, 0, g.get("applied", proposed), float(ego.action.get("acceleration", 0.0)), [],
                       note, ego.LENGTH)

    def close(self) -> None:
        self.rec.flush()


# ---- HighD-format recordings ------------------------------------------------------------------------
HIGHD_SHOWN = 4   # vehicles whose series a HighD recording opens on (every vehicle's are in the file)


def highd_blueprint(shown=()):
    """The layout a HighD recording opens with: the road on the left; right, for each vehicle of ``shown`` (the
    vehicles the events name first) tabs of one plot per unit, opening on its input against its admissible input
    (then its speed, its gap), and the events. A plot of every vehicle (931 series on a sample) reads as nothing, and
    gaps of 100 m on the inputs' axis squash them; the others stay in the file, a click away."""
    import rerun.blueprint as rrb

    def tabs(v):
        return rrb.Tabs(
            rrb.TimeSeriesView(origin=f"/vehicles/{v}", name=f"vehicle {v}: input, admissible input [m/s²]",
                               contents=[f"/vehicles/{v}/input", f"/vehicles/{v}/admissible/**"]),
            rrb.TimeSeriesView(origin=f"/vehicles/{v}", name=f"vehicle {v}: speed [m/s]",
                               contents=[f"/vehicles/{v}/speed"]),
            rrb.TimeSeriesView(origin=f"/vehicles/{v}", name=f"vehicle {v}: gap [m]", contents=[f"/vehicles/{v}/gap"]),
            active_tab=0)

    plots = [tabs(v) for v in list(shown)[:HIGHD_SHOWN]]
    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial2DView(origin="/road", name="road (image coordinates, red = not self-safe, amber = lane change not "
                                               "responsible)"),
        rrb.Vertical(*plots, rrb.TextLogView(origin="/events", name="overrides and lane changes"),
                     row_shares=[2] * len(plots) + [2]),
        column_shares=[3, 2]), collapse_panels=True)


def _log_vehicle_series(rec, data, params) -> None:
    """``vehicles/ID/{speed,gap,input,admissible/low,admissible/high}`` on the ``frame`` timeline.

    The admissible interval is the self-safe input set (7.4) of the closed-form car-following set
    (its hull when it is a union); absent where it is empty or there is no leader.
    """
    from itha.car_following import MaximalSet, admissible_inputs

    S = MaximalSet(params)
    n = len(data.v)
    low, high = np.full(n, np.nan), np.full(n, np.nan)
    for k in range(n):
        if np.isfinite(data.h[k]) and 0 <= data.v[k] <= params.v_max and 0 <= data.vL[k] <= params.v_max:
            iv = admissible_inputs(S, (float(data.v[k]), float(data.h[k]), float(data.vL[k])))
            if iv:
                low[k], high[k] = min(a for a, _ in iv), max(b for _, b in iv)
    order = np.lexsort((data.frame, data.vehicle))
    vehicles, frames = data.vehicle[order], data.frame[order]
    series = {"speed": data.v[order], "gap": data.h[order], "input": data.u[order],
              "admissible/low": low[order], "admissible/high": high[order]}
    starts = np.flatnonzero(np.r_[True, vehicles[1:] != vehicles[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(vehicles)]):
        vid = int(vehicles[a])
        for name, values in series.items():
            vals = values[a:b]
            keep = np.isfinite(vals)
            if keep.any():
                rec.send_columns(f"vehicles/{vid}/{name}", indexes=[rr.TimeColumn("frame", sequence=frames[a:b][keep])],
                                 columns=rr.Scalars.columns(scalars=vals[keep]))


def log_highd_recording(path: Path, folder: Path, recording_id: int, params, overrides_of, judge=None,
                        frame_step: int = 1) -> dict:
    """One recording: lane markings, every vehicle per frame (red where its input is not self-safe, amber where its
    lane change is not ρ̂-responsible), per-vehicle time series of speed, gap, input and the admissible input
    interval, and the events; it opens with ``highd_blueprint``.

    ``overrides_of(data)`` returns a boolean per data point of ``guardian.highd.convert.to_itha``; those vehicles
    are drawn red and listed in ``events/override``. ``judge(event, overapprox)`` returns the inputs that make a
    lane change ρ̂-responsible (None: outside the state space); each lane change of the recording (held out or
    not) is then listed in ``events/lane_change`` with its recorded input against the responsible inputs of the
    trivial and the ordered ρ̂, as a warning when the recorded input is not among them. ``frame_step``: every k-th
    frame, as the replay saw them (``guardian.highd.reader.subsample``).
    """
    from guardian.highd.convert import to_itha
    from guardian.highd.reader import read_recording, subsample

    rec_data = subsample(read_recording(folder, recording_id), frame_step)
    data = to_itha(rec_data)
    over = overrides_of(data)
    flagged = {(int(v), int(f)) for v, f in zip(data.vehicle[over], data.frame[over])}
    verdicts = [(e, _lane_change_verdict(e, judge)) for e in data.lane_changes]
    refused = {(e.vehicle, e.frame) for e, (_, bad) in verdicts if bad}
    rec = rr.RecordingStream("guardian-highd")
    named = [e.vehicle for e, (_, bad) in verdicts if bad] + [int(v) for v in data.vehicle[over]]
    named += [e.vehicle for e in data.lane_changes] + [int(v) for v in data.vehicle[:1]]
    save_to(rec, path, highd_blueprint(dict.fromkeys(named)))
    _log_vehicle_series(rec, data, params)
    length = 450.0
    marks = rec_data.upper_markings + rec_data.lower_markings
    rec.log("road/markings", rr.LineStrips2D([[[0.0, m], [length, m]] for m in marks]), static=True)
    t = rec_data.tracks
    for frame, rows in t.groupby("frame", sort=True):
        rec.set_time("frame", sequence=int(frame))
        ids = rows["id"].to_numpy()
        red = np.array([(int(i), int(frame)) in flagged for i in ids])
        amber = np.array([(int(i), int(frame)) in refused for i in ids])
        centers = np.column_stack([rows["x"] + rows["width"] / 2, rows["y"] + rows["height"] / 2])
        half = np.column_stack([rows["width"] / 2, rows["height"] / 2])
        colors = np.where(red[:, None], [[230, 40, 40]], np.where(amber[:, None], [[240, 170, 30]], [[60, 120, 220]]))
        rec.log("road/vehicles", rr.Boxes2D(centers=centers, half_sizes=half, colors=colors,
                                            labels=[str(i) for i in ids]))
        for i in ids[red]:
            rec.log("events/override", rr.TextLog(f"frame {frame}: vehicle {i} input not self-safe", level="WARN"))
    for e, (text, bad) in verdicts:
        rec.set_time("frame", sequence=e.frame)
        rec.log("events/lane_change", rr.TextLog(text, level="WARN" if bad else "INFO"))
    rec.flush()
    return {"frames": int(t["frame"].nunique()), "overrides": int(over.sum()), "lane_changes": len(verdicts),
            "lane_changes_not_responsible": len(refused), "path": str(path)}


def _ranges(inputs) -> str:
    return " ∪ ".join(f"[{lo:.2f}, {hi:.2f}]" for lo, hi in inputs) if inputs else "none"


def _lane_change_verdict(e, judge) -> tuple[str, bool]:
    """The event's line and whether its recorded input is not responsible under some ρ̂."""
    head = f"frame {e.frame}: vehicle {e.vehicle} changes {e.trigger}"
    if judge is None:
        return head, False
    parts, bad = [], False
    for overapprox in ("trivial", "ordered"):
        inputs = judge(e, overapprox)
        if inputs is None:
            parts.append(f"{overapprox}: a speed outside the state space, not responsible")
            bad = True
            continue
        ok = any(lo <= e.u <= hi for lo, hi in inputs)
        bad |= not ok
        parts.append(f"{overapprox}: responsible inputs {_ranges(inputs)} m/s^2, "
                     f"{'responsible' if ok else 'NOT responsible'}")
    return f"{head}; recorded input {e.u:+.2f} m/s^2; " + "; ".join(parts), bad


# ---- highway-env environments under the Guardian ----------------------------------------------------
class GuardianRecorder(_Closing):
    """Rollouts of ``guardian.wrappers.guardian.Guardian`` on a highway-env environment, in simulator coordinates.

    * ``road/lanes`` lane markings (static, from the env's road); ``road/ego``, ``road/lead`` and
      ``road/traffic`` the vehicles as boxes on the ``step`` timeline (x along the road, y down as in
      highway-env's renderer; a guarded car magenta on a step the guardian overrode for safety, red on a fail-safe
      step, ``override_mark``); ``road/follow`` a frame at the ego's x that the road view is seen from, and
      ``road/follow/labels`` the names ("ego", "lead", "car K") in that frame. ``slice`` (highway-env's roads,
      guarded): the car-following set's slice at the state now (``slice_of``): ``slice/edge`` the highest speed the
      set allows at each gap behind the nearest car ahead at that car's speed (and, with an actuator, the ego's
      acceleration), ``slice/ego`` where the ego is (green inside, red outside), ``slice/h_min`` the least gap;
      speed is drawn upwards (negative y). On the overtake scenarios ``slice/set`` is the active set sliced at the
      lateral position and lead speed now (``overtake_slice_of``: each piece that holds them, a polygon in
      ``(v_ex, h)``) and ``slice/ego`` the state in it. With several
      guarded cars (``--controlled N``): ``road/guarded`` the cars labelled ``car K``, the view follows car 0, and
      each car's series below are under ``cars/car_K/`` (its events name it)
    * ``inputs/{proposed,applied}/{throttle,steering}`` time series (continuous and meta agents alike:
      the decoded inputs of the last simulation step)
    * ``admissible/acceleration/{low,high}`` the composed admissible acceleration at the applied
      lateral input; ``admissible/steering/{low,high}`` the admissible lateral input at the applied
      acceleration (overtake scenarios, as Fig. 6.5)
    * ``intention/valid_count`` and ``intention/log`` the lead's valid intentions and their changes;
      ``guardian/active_set`` (text)
    * ``events/override`` one entry per step the guardian changed for safety (the tally's ``override_steps``), with
      the reasons (each once); ``events/model_clip`` the steps whose only change was a clip to the model's bounds;
      ``events/episode``. The text names the ``step`` timeline's value, then the episode and its own step
    """

    def __init__(self, path: Path, application_id: str = "guardian-highway-env"):
        self.rec = rr.RecordingStream(application_id)
        self.path = Path(path)
        self.step_index = 0
        self._valid = None
        self._lanes_logged = False

    def start_episode(self, env, episode: int) -> None:
        base = env.unwrapped
        if not self._lanes_logged:   # the file begins with the first episode, its view on the ego's start
            cars = len(getattr(base, "controlled_vehicles", ()) or ()) or 1
            save_to(self.rec, self.path, rollout_blueprint(base, getattr(base, "lead", None) is not None, cars))
            for car in ([None] if cars == 1 else range(cars)):
                _series_styles(self.rec, car)
            strips = []
            for _from in base.road.network.graph.values():
                for group in _from.values():
                    for lane in group:
                        for side in (-0.5, 0.5):
                            y = float(lane.start[1]) + side * lane.width
                            strips.append([[float(lane.start[0]), y], [float(lane.end[0]), y]])
            self.rec.log("road/lanes", rr.LineStrips2D(strips), static=True)
            self._lanes_logged = True
        self._valid = None
        self.rec.set_time("step", sequence=self.step_index)
        self.rec.log("events/episode", rr.TextLog(f"episode {episode} starts"))

    def log(self, env, episode: int, t: int, record: dict) -> None:
        base = env.unwrapped
        rec = self.rec
        rec.set_time("step", sequence=self.step_index)
        g = record or {}
        fleet = "agents" in g
        ego, lead = base.vehicle, getattr(base, "lead", None)
        guarded = list(base.controlled_vehicles) if fleet else [ego]

        def boxes(vs, colours):
            return rr.Boxes2D(centers=[[float(v.position[0]), float(v.position[1])] for v in vs],
                              half_sizes=[[v.LENGTH / 2, v.WIDTH / 2] for v in vs], colors=colours)

        follow = float(guarded[0].position[0])
        rec.log("road/follow", rr.Transform3D(translation=[follow, 0.0, 0.0]))
        named = list(zip(guarded, [f"car {k}" for k in range(len(guarded))] if fleet else ["ego"]))
        marks = [override_mark(r) for r in (g["agents"] if fleet else [g])]
        rec.log("road/guarded" if fleet else "road/ego", boxes(guarded, marks))
        if lead is not None:
            rec.log("road/lead", boxes([lead], [(230, 150, 30)]))
            named.append((lead, "lead"))
        follow_labels(rec, [(float(v.position[0]) - follow, float(v.position[1]), name) for v, name in named])
        traffic = [v for v in base.road.vehicles if not any(v is c for c in guarded) and v is not lead]
        rec.log("road/traffic", boxes(traffic, [(60, 120, 220)] * len(traffic)))
        for car, r in (enumerate(g["agents"]) if fleet else [(None, g)]):
            self._inputs(car, r)
            self._override(car, r, episode, t)
        if g and lead is None:
            self._slice(env, (g["agents"][0] if fleet else g))
            self._lanes(env, (g["agents"][0] if fleet else g))
        elif g and not fleet:
            self._overtake_slice(env)
        if g and not fleet:
            rec.log("guardian/active_set", rr.TextLog(str(g.get("active_set"))))
            valid = tuple(g.get("valid_intentions", []))
            if lead is not None:
                rec.log("intention/valid_count", rr.Scalars([float(len(valid))]))
                if valid != self._valid:
                    rec.log("intention/log", rr.TextLog(f"valid intentions: {', '.join(valid) or 'none'}; "
                                                        f"active set {g.get('active_set')}"))
                    self._valid = valid
        self.step_index += 1

    def _slice(self, env, record: dict) -> None:
        """The set's slice of the first guarded car at its state now (``slice_of``)."""
        from guardian.adapters.highway_env.scene import bicycle_state
        from guardian.decide.bicycle import BicycleGuardian

        cars, supervision = env.get_wrapper_attr("cars"), env.get_wrapper_attr("supervision")
        if not cars or not isinstance(cars[0].guard, BicycleGuardian):
            return
        vehicle, base = cars[0].vehicle, env.unwrapped
        lanes = frozenset(record.get("lanes") or ())
        scene = supervision.scene(base, lanes, ego=vehicle, guarded=supervision.guarded).with_ego_lanes(lanes)
        drawn = slice_of(cars[0].guard, bicycle_state(vehicle, supervision.road),
                         [c for lane in sorted(lanes) for c in scene.leaders(lane)])
        if drawn is None:
            self.rec.log("slice", rr.Clear(recursive=True))
            self.rec.log("slice/ego", rr.Points2D([[SLICE_GAPS[-1] / 2, -20.0]], radii=0.1, colors=[APPLIED],
                                                  labels=["no car ahead in the lanes it holds: only the top speed binds"]))
            return
        shown = min(drawn["gap"], float(SLICE_GAPS[-1]))
        h_min, top = cars[0].guard.config.h_min, float(SLICE_GAPS[-1])
        self.rec.log("slice/h_min", rr.LineStrips2D([[[h_min, 0.0], [h_min, -45.0]]], colors=[FAILSAFE],
                                                    labels=[f"h_min {h_min:g} m"]))
        self._slice_axes(0.0, top, "gap")
        self.rec.log("slice/edge", rr.LineStrips2D([[[h, -v] for h, v in drawn["edge"]]], colors=[ADMISSIBLE]))
        self.rec.log("slice/ego", rr.Points2D([[shown, -drawn["speed"]]], radii=1.2,
                                              colors=[GUARDED if drawn["inside"] else FAILSAFE],
                                              labels=[f"ego {drawn['speed']:.1f} m/s, {drawn['gap']:.1f} m behind "
                                                      f"{drawn['lead']} at {drawn['lead_speed']:.1f} m/s"]))

    def _overtake_slice(self, env) -> None:
        """The overtake guardian's active set sliced at the state now (``overtake_slice_of``)."""
        from guardian.decide.overtake import PointMassGuardian

        cars = env.get_wrapper_attr("cars")
        if not cars or not isinstance(cars[0].guard, PointMassGuardian):
            return
        x = env.unwrapped.overtake_state()
        drawn = overtake_slice_of(cars[0].guard, x)
        self.rec.log("slice/set", rr.LineStrips2D([[[h, -v] for v, h in np.vstack([V, V[:1]])] for V in drawn["pieces"]],
                                                  colors=[ADMISSIBLE] * len(drawn["pieces"])))
        self.rec.log("slice/ego", rr.Points2D([[float(x[2]), -float(x[0])]], radii=1.2,
                                              colors=[GUARDED if drawn["inside"] else FAILSAFE],
                                              labels=[f"ego {x[0]:.1f} m/s, lead {x[2]:.1f} m ahead at {x[3]:.1f} m/s; "
                                                      f"{drawn['set']}: {len(drawn['pieces'])} pieces here"]))
        self._slice_axes(-60.0, 120.0, "h")

    def _slice_axes(self, left: float, right: float, distance: str) -> None:
        """The slice view's axes: the distance from ``left`` to ``right`` [m] along x, the speed 0-40 m/s upwards."""
        ticks = [([0.0, 0.0], "0"), ([right, 0.0], f"{distance} {right:g} m")] + (
            [([left, 0.0], f"{left:g} m")] if left < 0 else []) + [([0.0, -20.0], "20 m/s"), ([0.0, -40.0], "40 m/s")]
        self.rec.log("slice/axes", rr.LineStrips2D([[[left, 0.0], [right, 0.0]], [[0.0, 0.0], [0.0, -40.0]]],
                                                   colors=[APPLIED]), static=True)
        self.rec.log("slice/ticks", rr.Points2D([p for p, _ in ticks], radii=0.3, colors=[APPLIED] * len(ticks),
                                                labels=[name for _, name in ticks]), static=True)

    def _lanes(self, env, record: dict) -> None:
        """On a straight road: the lanes the first guarded car holds (green) and those whose entry the guardian
        refused during the step (red: an entry judged not responsible, a meta lane change refused), 120 m of each ahead of it, in the followed frame (``road/follow/held``,
        ``road/follow/refused``)."""
        from guardian.model.roads import Road

        cars, road = env.get_wrapper_attr("cars"), env.get_wrapper_attr("supervision").road
        if not cars or not isinstance(road, Road):
            return
        refused = sorted({lane for d in cars[0].decisions for lane in d.refused}
                         | ({cars[0].refused_lane} if cars[0].refused_lane is not None else set()))
        for name, lanes, colour in (("held", record.get("lanes") or [], HELD), ("refused", refused, REFUSED)):
            slots = [road.numbering.slot(lane) for lane in lanes if 1 <= lane <= road.n_lanes]
            self.rec.log(f"road/follow/{name}", rr.Boxes2D(
                centers=[[LANE_AHEAD / 2 - 10.0, k * road.lane_width] for k in slots],
                half_sizes=[[LANE_AHEAD / 2, road.lane_width / 2 - 0.2]] * len(slots), colors=[colour] * len(slots),
                labels=[f"lane {lane} {name}" for lane in lanes if 1 <= lane <= road.n_lanes], draw_order=1.0))

    def _inputs(self, car: int | None, g: dict) -> None:
        """One guarded car's proposed and applied inputs and its admissible bands."""
        root = car_root(car)[1:]
        for kind in ("proposed", "applied"):
            u = g.get(f"{kind}_input") or (g.get(kind) if isinstance(g.get(kind), list) else None)
            if u:
                self.rec.log(f"{root}inputs/{kind}/throttle", rr.Scalars([float(u[0])]))
                self.rec.log(f"{root}inputs/{kind}/steering", rr.Scalars([float(u[1])]))
        for axis, key in (("acceleration", "admissible_acceleration"), ("steering", "admissible_lateral")):
            band = g.get(key) or []
            if band:
                self.rec.log(f"{root}admissible/{axis}/low", rr.Scalars([min(r[0] for r in band)]))
                self.rec.log(f"{root}admissible/{axis}/high", rr.Scalars([max(r[1] for r in band)]))

    def _override(self, car: int | None, g: dict, episode: int, t: int) -> None:
        """An event for a step the guardian changed (a safety override, or only a clip to the model's bounds)."""
        if not g.get("overridden"):
            return
        safety = bool(g.get("safety_override", True))
        reasons = _reasons(g.get("reasons", []))
        who = "" if car is None else f"car {car}, "
        self.rec.log("events/override" if safety else "events/model_clip", rr.TextLog(
            f"step {self.step_index} ({who}episode {episode}, its step {t}; {g.get('changed')}): "
            f"{_shown(g.get('proposed'))} -> {_shown(g.get('applied'))}" + (f"; {reasons}" if reasons else ""),
            level="WARN" if safety else "INFO"))

    def close(self) -> None:
        if not self._lanes_logged:   # no episode began: the file still exists, with the plain layout
            save_to(self.rec, self.path, run_blueprint(("/inputs", "/admissible", "/intention")))
        self.rec.flush()
