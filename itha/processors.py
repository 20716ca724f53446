"""Parallel processors on a server farm (Example 4) and the experiment of Section 7.4.2.

Processor i holds ``x_i`` jobs; ``u_i in {0, -1}`` (idle or finish one job),
external jobs ``d_i in {0, 1, 2}`` arrive unless ``x_i >= n_throttle`` (then they
are rejected), and ``x_i >= n_overflow`` is a failure. Processor i may recruit
any subset of its neighbours in an undirected graph, sending each one job.

Reset (7.2): ``R_i = max(0, x_i - |τ_i| + u_i + |S ∖ {i}| + d_i)`` where S is the
set of agents triggering i. A recruiter triggers a reset on itself too (its
queue loses ``|τ_i|`` jobs), so ``i ∈ ρ_i`` iff ``τ_i ≠ ∅``; this keeps
Assumption 2 and gives the recruiter's own queue the reset of (7.2). Incoming
jobs obey the throttle in resets as in ``f_i`` (the protocol blocks them).

The invariant set is ``X_c = {0, ..., n_overflow - 1}`` (the maximal one).

Each processor greedily solves (7.9): finish a job if it has one, then recruit
as many neighbours as it may (fewest jobs first) without going below
``keep_jobs`` (default 1; (7.9) literally is 0, which lets a recruiter hand
away its last job and idle the next step: with 0, ordered accepts fewer jobs
than trivial, see the README), under one of three resolution estimates:

* ``trivial`` (A): any neighbour of j may recruit j at the same time (7.6);
* ``under`` (B): nobody else recruits j (an under-approximation: unsafe);
* ``ordered`` (C): Algorithm 1 with the order 1 ≻ 2 ≻ ...: the earlier
  processors' recruitments are known, the later ones yield.

A recruiter does not know the recruited processor's input, incoming jobs or (for
``trivial`` and ``under``) its recruitments: it assumes the worst (idle, two
jobs unless throttled, nothing sent away).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from itha.core import ITHA, Agent

ESTIMATES = ("trivial", "under", "ordered")


@dataclass(frozen=True)
class ProcessorParams:
    """Section 7.4.2's values as defaults."""

    n_agents: int = 10
    n_throttle: int = 3
    n_overflow: int = 5
    jobs: tuple = (0, 1, 2)
    edge_threshold: float = 0.1  # an edge is kept when a uniform sample is >= this
    initial_max: int = 4         # initial queues are uniform in {0, ..., initial_max}
    keep_jobs: int = 1           # a recruiter keeps this many jobs to work on (0 = (7.9) literally)

    def __post_init__(self):
        if not 0 < self.n_throttle < self.n_overflow:
            raise ValueError(f"need 0 < n_throttle < n_overflow, got {self.n_throttle}, {self.n_overflow}")
        if self.initial_max >= self.n_overflow:
            raise ValueError("initial queues must lie in the invariant set {x < n_overflow}")

    @property
    def max_jobs(self) -> int:
        return max(self.jobs)

    def incoming(self, x: int, d: int) -> int:
        """External jobs accepted at queue length x (the throttle blocks them)."""
        return d if x < self.n_throttle else 0

    def worst_incoming(self, x: int) -> int:
        return self.max_jobs if x < self.n_throttle else 0

    def in_invariant(self, x: int) -> bool:
        return 0 <= x <= self.n_overflow - 1


def random_graph(n: int, threshold: float, rng: np.random.Generator) -> list[set[int]]:
    """Undirected graph: edge {i, j} kept when a uniform sample is >= threshold."""
    nbrs = [set() for _ in range(n)]
    for i, j in itertools.combinations(range(n), 2):
        if rng.uniform() >= threshold:
            nbrs[i].add(j)
            nbrs[j].add(i)
    return nbrs


def reset_value(p: ProcessorParams, x: int, sent: int, u: int, recruiters: int, d: int) -> int:
    """(7.2) with the throttle on incoming jobs."""
    return max(0, x - sent + u + recruiters + p.incoming(x, d))


def transition(p: ProcessorParams, x, u, taus, d) -> list[int]:
    """One step of (7.1c) for all processors."""
    n = len(x)
    recruiters = [0] * n
    for k, tau in enumerate(taus):
        for j in tau:
            recruiters[j] += 1
    nxt = []
    for i in range(n):
        if recruiters[i] or taus[i]:
            nxt.append(reset_value(p, x[i], len(taus[i]), u[i], recruiters[i], d[i]))
        else:
            nxt.append(x[i] + u[i] + p.incoming(x[i], d[i]))
    return nxt


def _worst_reset(p: ProcessorParams, x_j: int, known_sent: int, recruiters: int) -> int:
    """Largest queue j can be reset to: idle, worst arrivals, only the known jobs sent."""
    return max(0, x_j - known_sent + recruiters + p.worst_incoming(x_j))


def decide(p: ProcessorParams, i: int, x, d_i: int, nbrs, estimate: str,
           recruited_by=None, sent=None):
    """Processor i's greedy solution of (7.9): ``(u_i, τ_i)``.

    ``recruited_by[j]`` / ``sent[j]`` are what the earlier processors decided
    (ordered estimate only; None for the others).
    """
    u = -1 if x[i] >= 1 else 0
    arrivals = p.incoming(x[i], d_i)
    room = max(0, x[i] + u + arrivals - p.keep_jobs)  # jobs i sends without starving itself
    tau: set[int] = set()
    for j in sorted(nbrs[i], key=lambda k: (x[k], k)):
        if len(tau) >= room:
            break
        if estimate == "trivial":
            worst = _worst_reset(p, x[j], 0, len(nbrs[j]))
        elif estimate == "under":
            worst = _worst_reset(p, x[j], 0, 1)
        else:
            worst = _worst_reset(p, x[j], len(sent[j]) if sent[j] is not None else 0,
                                 len(recruited_by[j]) + 1)
        if p.in_invariant(worst):
            tau.add(j)
    # (7.5) for i itself: its own reset with every recruitment of i the estimate allows.
    while tau:
        incoming = {"trivial": len(nbrs[i]), "under": 0,
                    "ordered": len(recruited_by[i]) if recruited_by is not None else 0}[estimate]
        if p.in_invariant(max(0, x[i] - len(tau) + u + incoming + arrivals)):
            break
        tau.remove(max(tau, key=lambda k: (x[k], k)))
    return u, frozenset(tau)


def run_episode(p: ProcessorParams, estimate: str, steps: int, rng: np.random.Generator) -> dict:
    """One run: random graph, initial queues and arrivals; greedy (7.9) for every processor."""
    if estimate not in ESTIMATES:
        raise ValueError(f"unknown estimate {estimate!r}; choose from {ESTIMATES}")
    n = p.n_agents
    nbrs = random_graph(n, p.edge_threshold, rng)
    x = [int(v) for v in rng.integers(0, p.initial_max + 1, size=n)]
    accepted = violations = recruitments = 0
    for _ in range(steps):
        d = [int(v) for v in rng.choice(p.jobs, size=n)]
        if estimate == "ordered":
            recruited_by = [set() for _ in range(n)]
            sent = [None] * n
            us, taus = [0] * n, [frozenset()] * n
            for i in range(n):  # order 1 > 2 > ... : each sees the earlier decisions
                us[i], taus[i] = decide(p, i, x, d[i], nbrs, estimate, recruited_by, sent)
                sent[i] = taus[i]
                for j in taus[i]:
                    recruited_by[j].add(i)
        else:
            decisions = [decide(p, i, x, d[i], nbrs, estimate) for i in range(n)]
            us = [u for u, _ in decisions]
            taus = [t for _, t in decisions]
        accepted += sum(p.incoming(x[i], d[i]) for i in range(n))
        recruitments += sum(len(t) for t in taus)
        x = transition(p, x, us, taus, d)
        violations += sum(not p.in_invariant(v) for v in x)
    return {"accepted_jobs": accepted, "violations": violations, "recruitments": recruitments}


def processors_experiment(runs: int, steps: int, seed: int, p: ProcessorParams = ProcessorParams(),
                          estimates=ESTIMATES, progress=None) -> dict:
    """Section 7.4.2: the same graphs, queues and arrivals for every estimate.

    Parameters
    ----------
    runs, steps : int
        Episodes and steps per episode.
    seed : int
        Run r is seeded with ``[seed, r]``.
    p : ProcessorParams
    estimates : tuple of str
        The over-approximations of the incoming load to compare.
    progress : callable, optional
        ``progress(estimate, done, total)``.

    Returns
    -------
    dict
        Per estimate: ``accepted_jobs_mean, violations_mean, recruitments_mean, runs, steps`` and the
        per-episode rows.
    """
    out = {}
    for est in estimates:
        rows = []
        for r in range(runs):
            rows.append(run_episode(p, est, steps, np.random.default_rng([seed, r])))
            if progress:
                progress(est, r + 1, runs)
        out[est] = {
            "accepted_jobs_mean": float(np.mean([row["accepted_jobs"] for row in rows])),
            "violations_mean": float(np.mean([row["violations"] for row in rows])),
            "recruitments_mean": float(np.mean([row["recruitments"] for row in rows])),
            "runs": runs, "steps": steps,
        }
    return out


# ---- the same system as a general ITHA (for the property tests of Theorem 5) ------------
def as_itha(p: ProcessorParams, nbrs) -> ITHA:
    """The processors as ``itha.core`` agents (exact, enumerable; for small graphs)."""
    def make(i):
        def inputs(x):
            return [0, -1] if x >= 1 else [0]

        def successors(t, x, u):
            return sorted({x + u + p.incoming(x, d) for d in p.jobs})

        def triggers(t, x):
            out = list(nbrs[i])
            return [frozenset(c) for r in range(len(out) + 1) for c in itertools.combinations(sorted(out), r)]

        def reset(t, k, x, u, S, ctx):
            sent = len(ctx["triggers"][k])
            return sorted({reset_value(p, x, sent, u, len(S - {k}), d) for d in p.jobs})

        return Agent(name=f"P{i}", inputs=inputs, successors=successors, triggers=triggers,
                     null=frozenset(), reset=reset, invariant=p.in_invariant)

    def resolution(t, states, triggers):
        n = len(states)
        return [frozenset({k for k in range(n) if i in triggers[k]} | ({i} if triggers[i] else set()))
                for i in range(n)]

    return ITHA([make(i) for i in range(len(nbrs))], resolution)
