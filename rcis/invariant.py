"""Robust controlled invariant sets by the iterations of Section 2.5.1.

* ``inside_out``: from a seed RCIS ``C_0``, ``C_{k+1} = Pre(Γ_k) ∩ Q_safe`` and
  ``Γ_{k+1} = Γ_k ∪ C_{k+1}`` (2.11 grown from the inside). Every ``Γ_k`` is an
  RCIS, so the iteration may stop at any time.
* ``outside_in``: ``C_0 = Q_safe``, ``C_{k+1} = Pre(C_k) ∩ Q_safe`` until a fixed
  point (2.11). Only the fixed point is an RCIS.

Pre of a union is under-approximated by the union of the Pre of its pieces
(sound for both iterations: a fixed point ``C ⊆ Pre_under(C) ⊆ Pre(C)`` is
invariant). Inside-out only takes the Pre of the pieces added last
(the others' Pre was taken before and is already covered), drops candidates
that the union already covers, and merges pairs of pieces whose union is convex.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Callable

from rcis.polyhedron import Polyhedron
from rcis.pwa import PRE_MARGIN, PWASystem
from rcis.region import SLIVER_EPS, Region, merge_convex
from rcis.tolerances import FIXED_POINT_EPS  # noqa: F401 (re-exported)

Progress = Callable[[dict], None]


@dataclass
class InvariantResult:
    region: Region
    iterations: int
    converged: bool
    seconds: float
    history: list = field(default_factory=list)  # one dict per iteration


def stderr_progress(label: str) -> Progress:
    """A progress callback that prints one line per iteration to stderr."""
    def report(info: dict) -> None:
        print(f"[{label}] iteration {info['iteration']}: +{info['new']} pieces, "
              f"{info['pieces']} in all, {info['seconds']:.1f} s", file=sys.stderr, flush=True)
    return report


COVER_BUDGET = 64  # fragments the coverage search may visit before keeping a candidate


def _pre_within(system: PWASystem, targets, safe: Region, merge: bool,
                margin: float = PRE_MARGIN) -> list[Polyhedron]:
    """Pre of each target inside each safe piece; pieces of one group merged when convex."""
    out = []
    for T in targets:
        for S in safe.pieces:
            group = system.pre(T, within=S, margin=margin)
            out.extend(merge_convex(group) if merge else group)
    return out


def _fattest_first(pieces):
    return sorted(pieces, key=lambda P: -P.chebyshev_ball().radius)


def _not_covered(candidates, pieces, dim, eps, budget):
    """Candidates (fattest first) that neither the pieces nor earlier candidates cover."""
    new = []
    for cand in _fattest_first(candidates):
        if not Region(pieces + new, dim).covers(cand, eps, budget):
            new.append(cand.minimal())
    return new


def _without_contained(old, new):
    """Old pieces that no single new piece contains."""
    new = Region(new, old[0].dim) if old else None
    return [Q for Q in old
            if not any(N.contains_polyhedron(Q, tol=0.0) for N in new.pieces_whose_box_holds(Q, 0.0))]


def inside_out(system: PWASystem, seed: Region, safe: Region, max_iterations: int = 50,
               merge: bool = True, progress: Progress | None = None,
               eps: float = SLIVER_EPS, cover_budget: int = COVER_BUDGET, observe=None) -> InvariantResult:
    """Grow the seed RCIS by robust Pre inside the safe set until nothing new appears (inside-out, 2.11).

    Parameters
    ----------
    system : PWASystem
        The dynamics ``x+ = A_j x + B_j u + c_j + E_j w``.
    seed : Region
        An RCIS to start from (every iterate contains it, so every iterate is an RCIS).
    safe : Region
        The safe set; every iterate stays inside it.
    max_iterations : int
        Stop after this many iterations even if new pieces still appear.
    merge, progress, eps, cover_budget
        Convex merging of pieces, a per-iteration callback, the sliver size, and the coverage search budget.
    observe : callable, optional
        ``observe(iteration, region)`` after each iteration, with the RCIS so far (e.g. to measure it).

    Returns
    -------
    InvariantResult
        The region, the iterations run, whether nothing new appeared (converged), seconds, per-iteration history.
    """
    t0 = time.perf_counter()
    pieces = list(seed.pieces)
    frontier = list(seed.pieces)
    history = []
    converged = False
    k = 0
    for k in range(1, max_iterations + 1):
        candidates = _pre_within(system, frontier, safe, merge)
        frontier = _not_covered(candidates, pieces, seed.dim, eps, cover_budget)
        if merge:
            frontier = merge_convex(frontier)
        pieces = _without_contained(pieces, frontier) + frontier
        info = {"iteration": k, "new": len(frontier), "pieces": len(pieces),
                "seconds": time.perf_counter() - t0}
        history.append(info)
        if progress:
            progress(info)
        if observe:
            observe(k, Region(pieces, seed.dim))
        if not frontier:
            converged = True
            break
    return InvariantResult(Region(pieces, seed.dim), k, converged, time.perf_counter() - t0, history)




def outside_in(system: PWASystem, safe: Region, max_iterations: int = 50,
               progress: Progress | None = None, eps: float = FIXED_POINT_EPS,
               margin: float = PRE_MARGIN) -> InvariantResult:
    """``C_{k+1} = Pre(C_k) ∩ Q_safe`` from ``C_0 = Q_safe`` until ``C_k ⊆ C_{k+1}``.

    Only a converged result is an RCIS (then ``C_k ⊆ Pre(C_k)``). Because Pre
    keeps a robustness margin, iterates that approach a tight boundary (where
    a single input barely works) shrink by about that margin each step and do
    not converge: the result then says ``converged=False`` and is only an
    outer estimate, not an invariant set.

    ``margin=0`` drops the erosion (Pre then is exact up to rounding); use it
    with a safe set tightened by more than the rounding, so that a fixed point
    that is invariant up to rounding still keeps the untightened safe set.

    Parameters
    ----------
    system : PWASystem
    safe : Region
        ``Q_safe``.
    max_iterations : int
    progress : callable, optional
        Called with one dict per iteration.
    eps : float
        ``C_k ⊆ C_{k+1}`` is tested to this (``FIXED_POINT_EPS``).
    margin : float
        Pre's erosion (``PRE_MARGIN``).

    Returns
    -------
    InvariantResult
        ``region, iterations, converged, seconds, history``; an RCIS only when ``converged``.
    """
    t0 = time.perf_counter()
    current = safe
    history = []
    converged = False
    k = 0
    for k in range(1, max_iterations + 1):
        candidates = _pre_within(system, current.pieces, safe, merge=True, margin=margin)
        nxt = Region(_not_covered(candidates, [], safe.dim, SLIVER_EPS, COVER_BUDGET), safe.dim)
        info = {"iteration": k, "new": len(nxt), "pieces": len(nxt), "seconds": time.perf_counter() - t0}
        history.append(info)
        if progress:
            progress(info)
        if current.is_subset_of(nxt, eps):
            converged = True  # C_k ⊆ Pre(C_k) ∩ Q_safe: C_k itself is the RCIS
            break
        current = nxt
    return InvariantResult(current, k, converged, time.perf_counter() - t0, history)
