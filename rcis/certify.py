"""A falsifier for robust controlled invariance (2.9).

It samples states of each piece of C — interior points (hit-and-run), boundary
points (ends of random chords) and vertices (LP optima of random costs) —,
computes ``S(x)`` at each, and checks:

1. ``S(x)`` is non-empty;
2. for several admissible inputs (polygon vertices, centroids, random points),
   every successor under every vertex of the disturbance set (which includes
   the intention's external-input variability) lies in C.

The successors come from ``PWASystem.step`` semantics, independent of the
projection code that built C. When the vertex successors all lie in one convex
piece, the whole successor polytope does; when they lie in C but in different
pieces, the state is counted as ``split`` (not a counterexample, not a proof).
Unbounded coordinates are sampled inside ``window``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rcis import _kernels
from rcis.admissible import AdmissibleInputs
from rcis.lp import InequalityLP
from rcis.parallel import Jobs
from rcis.polyhedron import Polyhedron
from rcis.pwa import PWASystem
from rcis.region import Region
from rcis.tolerances import MEMBERSHIP_TOL  # noqa: F401 (re-exported)



@dataclass
class Counterexample:
    state: list
    input: list | None
    successor: list | None
    reason: str


@dataclass
class FalsifierReport:
    samples: int = 0
    inputs_checked: int = 0
    split: int = 0
    counterexamples: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"samples": self.samples, "inputs_checked": self.inputs_checked,
                "split_successor_sets": self.split, "counterexamples": len(self.counterexamples),
                "first_counterexamples": [c.__dict__ for c in self.counterexamples[:5]]}


class _PieceSampler:
    """Hit-and-run, chord ends and LP vertices of one piece, clipped to a window."""

    def __init__(self, P: Polyhedron, window: Polyhedron, rng):
        self.P = P.intersect(window).minimal()
        ball = self.P.chebyshev_ball()
        if ball.radius <= 0:
            raise ValueError("piece has no interior inside the sampling window")
        self.x = ball.center
        self.rng = rng
        self._lp = InequalityLP(self.P.A, self.P.b)

    def _chord(self, d):
        Ad = self.P.A @ d
        slack = self.P.b - self.P.A @ self.x
        with np.errstate(divide="ignore"):
            t = slack / Ad
        hi = np.min(t[Ad > 1e-14], initial=np.inf)
        lo = np.max(t[Ad < -1e-14], initial=-np.inf)
        return max(lo, -1e6), min(hi, 1e6)

    def interior(self):
        d = self.rng.normal(size=self.x.size)
        d /= np.linalg.norm(d)
        lo, hi = self._chord(d)
        self.x = self.x + self.rng.uniform(lo, hi) * d
        return self.x.copy()

    def boundary(self):
        d = self.rng.normal(size=self.x.size)
        d /= np.linalg.norm(d)
        lo, hi = self._chord(d)
        return self.x + hi * d

    def vertex(self):
        res = self._lp.maximize(self.rng.normal(size=self.x.size))
        return res.x if res.status == "optimal" else self.interior()


def _candidate_inputs(verts, counts, nonempty, rng, count: int):
    """A polygon's centroid and one of its vertices, then random convex combinations (S(x)'s polygons
    as the clipping kernel returns them: ``verts[p, :counts[p]]`` for p in ``nonempty``)."""
    p = nonempty[rng.integers(len(nonempty))]
    P = verts[p, :counts[p]]
    picks = [P.mean(axis=0), P[rng.integers(len(P))]]
    while len(picks) < count:
        q = nonempty[rng.integers(len(nonempty))]
        Q = verts[q, :counts[q]]
        w = rng.dirichlet(np.ones(len(Q)))
        picks.append(w @ Q)
    return picks[:count]


def falsify(system: PWASystem, invariant: Region, samples: int, seed=0,
            window: Polyhedron | None = None, inputs_per_state: int = 3,
            admissible: AdmissibleInputs | None = None, progress=None) -> FalsifierReport:
    """Search for states of ``invariant`` that are not robustly controlled invariant.

    Parameters
    ----------
    system : PWASystem
        The dynamics the set was computed for.
    invariant : Region
        The candidate RCIS.
    samples : int
        States drawn (interior, boundary and vertices of the pieces, inside ``window``).
    seed : int or sequence of int
        Random seed (``numpy.random.default_rng``'s).
    window : Polyhedron, optional
        Where states are drawn (sets unbounded in some coordinate need one).
    inputs_per_state : int
        Admissible inputs tried per state, each against every vertex of the disturbance set.
    admissible : AdmissibleInputs, optional
        ``S(x)`` of the set (built when not given).
    progress : callable, optional
        ``progress(done, total)``.

    Returns
    -------
    FalsifierReport
        The counterexamples (a state, an input and a disturbance whose successor leaves the set), and counts.
    """
    rng = np.random.default_rng(seed)
    adm = admissible or AdmissibleInputs(system, invariant)
    if window is None:
        window = Polyhedron.from_box(np.full(system.n_x, -1e3), np.full(system.n_x, 1e3))
    samplers = [_PieceSampler(P, window, rng) for P in invariant.pieces]
    W_vertices = [p.W.generators()[0] for p in system.pieces]
    report = FalsifierReport()
    kinds = ("interior", "boundary", "vertex")
    A, b, starts = invariant.stacked()
    k = 0
    while report.samples < samples:
        sampler = samplers[k % len(samplers)]
        k += 1
        kind = kinds[rng.choice(3, p=[0.5, 0.35, 0.15])]
        x = getattr(sampler, kind)()
        if _kernels.first_piece(A, b, starts, x, MEMBERSHIP_TOL) < 0:
            continue  # a chord end rounded outside: not a state of C, draw another
        report.samples += 1
        if progress and report.samples % max(1, samples // 20) == 0:
            progress(report.samples, samples)
        query = adm.at(x)
        verts, counts = query.clipped()
        nonempty = np.flatnonzero(counts)
        if not len(nonempty):
            report.counterexamples.append(Counterexample(x.tolist(), None, None, "S(x) is empty"))
            continue
        j = query.piece
        piece = system.pieces[j]
        for u in _candidate_inputs(verts, counts, nonempty, rng, inputs_per_state):
            report.inputs_checked += 1
            successors = piece.image(x, u) + W_vertices[j] @ piece.E.T
            owners = _common_piece(invariant, successors)
            if owners is not None:
                continue
            inside = invariant.contains(successors, MEMBERSHIP_TOL)
            if not np.all(inside):
                bad = successors[np.flatnonzero(~inside)[0]]
                report.counterexamples.append(
                    Counterexample(x.tolist(), u.tolist(), bad.tolist(), "successor leaves C"))
                break
            report.split += 1
    return report


def falsify_all(jobs: dict, workers: int = 1, progress=None, parts: int = 1) -> dict:
    """``falsify(**job)`` for every named job, in up to ``workers`` processes.

    Parameters
    ----------
    jobs : dict of str to dict
        Keyword arguments of ``falsify`` per name (without ``progress``); with several workers they
        start in this order, so put the largest first.
    workers : int
        Processes; 1 runs the jobs one after another in this process.
    progress : callable, optional
        ``progress(name, done, total)``.
    parts : int
        Each job is drawn as this many independent parts (``samples`` shared out, part k seeded with
        ``[seed, k]``) whose reports are added up, so one large set can keep every worker busy. The
        reports depend on ``parts``, never on ``workers``; ``parts=1`` is ``falsify`` itself.

    Returns
    -------
    dict of str to FalsifierReport
        The same reports whatever ``workers`` is (each part seeds its own generator).
    """
    pieces = _split(jobs, parts)
    done = {}

    def report(key, n, total_of_key):
        done[key] = n
        if progress:
            name = key[0]
            progress(name, sum(v for k, v in done.items() if k[0] == name), jobs[name]["samples"])

    if workers <= 1 or len(pieces) <= 1:
        results = {key: falsify(**job, progress=lambda n, t, key=key: report(key, n, t))
                   for key, job in pieces.items()}
        return _merge(jobs, results)
    import multiprocessing

    queue = multiprocessing.get_context().Queue()
    with Jobs(min(workers, len(pieces)), initializer=_set_progress_queue, initargs=(queue,)) as pool:
        running = {key: pool.submit(_falsify_reporting, job, key) for key, job in pieces.items()}
        results = {}
        for key, rep in pool.as_completed(running, poll=0.2, idle=lambda: _drain(queue, report)):
            results[key] = rep
        _drain(queue, report)
        return _merge(jobs, {key: results[key] for key in pieces})  # the serial order


def _drain(queue, report) -> None:
    import queue as queues

    while True:
        try:
            report(*queue.get_nowait())
        except queues.Empty:
            return


def _split(jobs: dict, parts: int) -> dict:
    """``{(name, k): job}``: each job's samples shared out over ``parts`` seeds ``[seed, k]``."""
    if parts <= 1:
        return {(name, 0): job for name, job in jobs.items()}
    out = {}
    for name, job in jobs.items():
        share = np.diff(np.linspace(0, job["samples"], parts + 1).round().astype(int))
        for k, n in enumerate(share):
            if n > 0:
                out[(name, k)] = {**job, "samples": int(n), "seed": [job.get("seed", 0), k]}
    return out


def _merge(jobs: dict, results: dict) -> dict:
    merged = {}
    for name in jobs:
        total = FalsifierReport()
        for key in sorted(k for k in results if k[0] == name):
            r = results[key]
            total.samples += r.samples
            total.inputs_checked += r.inputs_checked
            total.split += r.split
            total.counterexamples.extend(r.counterexamples)
        merged[name] = total
    return merged


_PROGRESS_QUEUE = None  # in a worker of falsify_all: where progress goes


def _set_progress_queue(queue) -> None:
    global _PROGRESS_QUEUE
    _PROGRESS_QUEUE = queue


def _falsify_reporting(job: dict, key) -> FalsifierReport:
    return falsify(**job, progress=lambda done, total: _PROGRESS_QUEUE.put((key, done, total)))


def _common_piece(region: Region, points: np.ndarray):
    A, b, starts = region.stacked()
    p = _kernels.first_piece_holding_all(A, b, starts, np.ascontiguousarray(points), MEMBERSHIP_TOL)
    return None if p < 0 else int(p)
