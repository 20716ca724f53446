"""highway-env's state as snapshots for the model coverage (``guardian.decide.coverage``), and traffic blind to a
guarded car (``guardian.adapters.highway_env.blindness.traffic_blind_to``), once per simulation step.

With several guarded cars each has its own monitor (``observe(..., ego=vehicle)``); only one of them counts
the traffic (``watch_traffic``), so that sums over the cars count each car once. Cars queue on highway-env's
lane index for the reversing cover's bounds (a queue across a segment end counts against us).
"""
from __future__ import annotations

import numpy as np

from guardian.adapters.highway_env.blindness import traffic_blind_to
from guardian.decide.coverage import COUNTS, ModelCoverage, no_counts  # noqa: F401 (the counts' names)


class ModelMonitor(ModelCoverage):
    """``ModelCoverage`` told highway-env's state before each simulation step."""

    def snapshot(self, base, applied, ego=None) -> dict:
        ego = base.vehicle if ego is None else ego
        lead = getattr(base, "lead", None)
        others = [v for v in base.road.vehicles if v is not ego and v is not lead] if self.watch_traffic else []
        ids = np.fromiter((id(v) for v in others), dtype=np.int64, count=len(others))
        x_v = np.fromiter((c for v in others for c in (v.position[0], v.speed)), dtype=float,
                          count=2 * len(others)).reshape(-1, 2)
        lanes = [tuple(v.lane_index or ()) for v in others] if self.reversing.any_may(x_v[:, 1]) else []
        snap = {"traffic": (ids, x_v), "lanes": lanes, "applied": np.asarray(applied, float),
                "ego": (float(ego.position[0]), float(ego.speed), float(ego.heading))}
        if lead is not None:
            snap["x"] = base.overtake_state()
        return snap

    def observe(self, base, applied, ego=None) -> dict:
        """Counts for the transition that ended now; then remember the present with ``applied``.
        ``ego``: the guarded car this monitor watches (default: the env's ego)."""
        blind = traffic_blind_to(base.road, base.vehicle if ego is None else ego)
        return super().observe(self.snapshot(base, applied, ego), blind)
