"""rerun recordings of guarded SUMO episodes (viewer: ``rerun FILE.rrd``), in the road model's frame.

* ``road/lanes``: the lane lines (static); ``road/guarded``: the guarded bodies, green, amber on a step the guardian
  changed for safety, red on a fail-safe step, labelled with their names (``road/follow/labels``, in the followed
  frame: see ``guardian.recording.rerun.follow_labels``); ``road/traffic``: SUMO's cars, blue;
  ``road/shadows``: the shadow vehicles SUMO's drivers see (grey);
* ``inputs/<vehicle>/{acceleration,steering}/{proposed,applied}``: what each driver proposed and what was applied;
* ``events/override``: one line per safety override (time, vehicle, what changed, proposed -> applied, the reasons);
  ``events/crash``: each collision with its rule and fault; ``events/episode``.

Time is ``time`` (simulated seconds since the recording began; episodes follow each other). The road is seen from
``road/follow``, a frame at the first guarded vehicle's x at every step: the view shows 200 m around it whatever
step the viewer is on (it opens on the last), not the whole road, where 5 m cars would be specks.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from guardian.adapters.sumo.scene import corners
from guardian.recording.rerun import follow_labels, save_to

GREEN, AMBER, RED, BLUE, GREY = (40, 180, 60), (240, 170, 30), (220, 50, 50), (60, 120, 220), (150, 150, 150)
VIEW = 200.0  # [m] of road in view on opening


def _round(u) -> list:
    return [round(float(v), 3) for v in u]


class SumoRecorder:
    """Logs guarded SUMO episodes to ``path`` (a context manager: the file is flushed when the block ends)."""

    def __init__(self, path: Path, application_id: str = "guardian-sumo"):
        self.rec = rr.RecordingStream(application_id)
        self.path, self._saved, self.t0, self.t = Path(path), False, 0.0, 0.0
        self._marks: dict = {}
        self._followed = None   # the guarded vehicle the road view follows
        self._follow_x = 0.0    # where it was last

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start_episode(self, episode: str, frame, first) -> None:
        """A new episode on ``frame``'s road; ``first``: the first guarded body (the view opens on it)."""
        if not self._saved:
            save_to(self.rec, self.path, self._blueprint(first, frame))
            self._saved = True
        width, n = frame.lane_width, frame.n_lanes
        length = float(frame.length)
        lines = [[[0.0, (k - 0.5) * width], [length, (k - 0.5) * width]] for k in range(n + 1)]
        self.rec.log("road/lanes", rr.LineStrips2D(lines, colors=[(200, 200, 200)]), static=True)
        self.t0 = self.t
        self.rec.set_time("time", duration=self.t)
        self.rec.log("events/episode", rr.TextLog(f"{episode} starts"))

    def _blueprint(self, first, frame):
        import rerun.blueprint as rrb

        bounds = rrb.VisualBounds2D(x_range=[-VIEW / 4, 3 * VIEW / 4],
                                    y_range=[-frame.lane_width, frame.n_lanes * frame.lane_width])
        name = self._followed = first.name
        return rrb.Blueprint(rrb.Horizontal(
            rrb.Spatial2DView(origin="/road/follow", contents=["/road/**"],
                              name=f"road (y to the right of travel), following {name}", visual_bounds=bounds),
            rrb.Vertical(rrb.TimeSeriesView(origin=f"/inputs/{name}/acceleration", name=f"{name}: acceleration [m/s²]"),
                         rrb.TimeSeriesView(origin=f"/inputs/{name}/steering", name=f"{name}: steering [rad]"),
                         rrb.TextLogView(origin="/events", name="overrides, crashes, episodes"),
                         row_shares=[2, 2, 2]),
            column_shares=[3, 2]), collapse_panels=True)

    def step(self, t: float) -> None:
        """The time of what is logged next (``t``: seconds since the episode began)."""
        self.t = self.t0 + t
        self.rec.set_time("time", duration=self.t)

    def decision(self, name: str, proposed, applied, decision) -> None:
        """One guarded vehicle's proposal and applied input, and its override if any."""
        for axis, k in (("acceleration", 0), ("steering", 1)):
            self.rec.log(f"inputs/{name}/{axis}/proposed", rr.Scalars([float(proposed[k])]))
            self.rec.log(f"inputs/{name}/{axis}/applied", rr.Scalars([float(applied[k])]))
        if decision is None:
            self._marks[name] = GREEN
            return
        safety = decision.changed != "none" and not decision.clipped_to_model
        self._marks[name] = RED if decision.level == "failsafe" else (AMBER if safety else GREEN)
        if safety:
            self.rec.log("events/override", rr.TextLog(
                f"t={self.t - self.t0:.1f} s {name} ({decision.changed}): {_round(proposed)} -> {_round(applied)}: "
                + "; ".join(dict.fromkeys(decision.reasons)), level="WARN"))

    def bodies(self, guarded: list, traffic: list, shadows: list) -> None:
        """Every body of the step (``Sensed``, the road model's frame)."""
        def boxes(bs, colours, labels=None):  # rotated outlines (rerun's 2-D boxes do not rotate)
            outlines = [np.vstack([c, c[:1]]).tolist() for c in (corners(b) for b in bs)]
            return rr.LineStrips2D(outlines, colors=colours, labels=labels, radii=0.15)

        for b in guarded:
            if b.name == self._followed:
                self._follow_x = float(b.x)
                self.rec.log("road/follow", rr.Transform3D(translation=[self._follow_x, 0.0, 0.0]))
        self.rec.log("road/guarded", boxes(guarded, [self._marks.get(b.name, GREEN) for b in guarded]))
        follow_labels(self.rec, [(float(b.x) - self._follow_x, float(b.y), b.name) for b in guarded])
        self.rec.log("road/traffic", boxes(traffic, [BLUE] * len(traffic)))
        self.rec.log("road/shadows", boxes(shadows, [GREY] * len(shadows)))

    def crash(self, crash: dict) -> None:
        fault = f"{crash['culprit']} at fault" if crash["culprit"] else "no guarded vehicle at fault"
        self.rec.log("events/crash", rr.TextLog(
            f"t={self.t - self.t0:.1f} s {crash['vehicle']} and {crash['partner']} collide ({crash['rule']}): {fault}",
            level="ERROR"))

    def close(self) -> None:
        if self._saved:
            self.rec.flush()
