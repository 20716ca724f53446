"""The experiment of Section 7.4.1: a responsible ego among IDM traffic (7.8) on a multi-lane highway.

The ego picks its triggering choice and input by (7.7) (``itha.controller``) among the
responsible ones (``itha.responsibility``); the other cars follow IDM (``itha.idm``) and keep
their lanes. Every over-approximation ρ̂ sees the same random traffic.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from itha.car_following import CarFollowingParams
from itha.controller import choose
from itha.idm import idm_acceleration
from itha.responsibility import OVERAPPROXIMATIONS, EgoSupervisor
from itha.road import STAY, HighwayParams, example8_order, leaders, local_state, local_states, step_global


def clip_input(cf: CarFollowingParams, v: float, a: float) -> float:
    """Keep an acceleration in U and the next speed in [0, v_max]."""
    a = min(max(a, cf.u_min), cf.u_max)
    return min(max(a, -v / cf.dt), (cf.v_max - v) / cf.dt)


@dataclass
class HighwayEpisode:
    distance: float
    unsafe_steps: int
    lane_changes: int
    collisions: int
    infeasible_steps: int
    frames: list = field(default_factory=list)


def initial_traffic(prm: HighwayParams, S, rng: np.random.Generator):
    """Random cars (positions, lanes, IDM desired speeds) with every local state in the RCIS."""
    p, v, lane, desired = [0.0], [prm.ego_speed], [prm.ego_lane], [prm.v_nom]
    tries = 0
    while len(p) < prm.n_cars + 1:
        tries += 1
        if tries > 10000:
            raise RuntimeError("could not place the cars inside the invariant set; lower n_cars")
        vd = float(rng.uniform(*prm.desired_speed))
        cand = (float(rng.uniform(*prm.road_window)), vd, int(rng.integers(1, prm.n_lanes + 1)))
        P, V, Ln = p + [cand[0]], v + [cand[1]], lane + [cand[2]]
        if S.contains(local_states(prm, P, V, Ln)).all():
            p, v, lane, desired = P, V, Ln, desired + [vd]
    return p, v, lane, desired


def run_highway_episode(prm: HighwayParams, S, overapprox: str, steps: int, rng: np.random.Generator,
                        record: bool = False) -> HighwayEpisode:
    cf = prm.car_following
    p, v, lane, desired = initial_traffic(prm, S, rng)
    sup = EgoSupervisor(prm, S, overapprox)
    n = len(p)
    unsafe = lane_changes = collisions = infeasible = 0
    frames = []
    for t in range(steps):
        # Cars ahead of the ego in the order announce their triggers (IDM traffic keeps its lane).
        order = example8_order(p, lane)
        announced = {k: STAY for k in order[:order.index(0)]}
        verdicts = sup.choices(p, v, lane, 0, announced)
        pick = choose(verdicts, v[0], prm)
        if pick is None:  # cannot happen inside the RCIS (Theorem 5, statement 1); counted if it does
            infeasible += 1
            pick = (STAY, clip_input(cf, v[0], cf.u_min), math.nan)
        trig, u_ego, _ = pick
        old_leaders = leaders(p, lane)
        acc = [u_ego]
        for i in range(1, n):
            _, gap, vl = local_state(prm, p, v, lane, i, old_leaders[i])
            a = idm_acceleration(v[i], gap, vl, desired[i], prm.idm_a, prm.idm_b, prm.idm_s0, prm.idm_T, prm.idm_delta)
            acc.append(clip_input(cf, v[i], a))
        if record:
            frames.append({"t": t, "p": list(p), "v": list(v), "lane": list(lane), "trigger": trig,
                           "u": u_ego, "verdicts": [(vd.trigger, bool(vd.inputs), vd.reason) for vd in verdicts]})
        p, v, lane = step_global(prm, p, v, lane, acc, [trig] + [STAY] * (n - 1))
        lane_changes += trig != STAY
        new_leaders = leaders(p, lane)
        X = local_states(prm, p, v, lane, new_leaders)
        inside = S.contains(X)
        triggered = [i for i in range(n) if trig != STAY and new_leaders[i] != old_leaders[i]]
        unsafe += (not inside[0]) + sum(1 for i in triggered if i != 0 and not inside[i])
        collisions += int(np.sum(X[:, 1] < 0))
    return HighwayEpisode(p[0], unsafe, lane_changes, collisions, infeasible, frames)


def highway_experiment(runs: int, steps: int, seed: int, S, prm: HighwayParams = HighwayParams(),
                       overapproxes=OVERAPPROXIMATIONS, progress=None) -> dict:
    """Section 7.4.1: the same random traffic for each over-approximation.

    Parameters
    ----------
    runs, steps : int
        Episodes and steps per episode.
    seed : int
        Run r is seeded with ``[seed, r]``; every over-approximation sees the same traffic.
    S : CarFollowingSet
        The car-following set the supervisors use.
    prm : HighwayParams
    overapproxes : tuple of str
        ``trivial`` and/or ``ordered``.
    progress : callable, optional
        ``progress(overapproximation, done, total)``.

    Returns
    -------
    dict
        Per over-approximation: ``distance_mean, unsafe_steps, lane_changes, collisions,
        infeasible_steps`` and the per-episode ``distances``.
    """
    out = {}
    for oa in overapproxes:
        eps = []
        for r in range(runs):
            eps.append(run_highway_episode(prm, S, oa, steps, np.random.default_rng([seed, r])))
            if progress:
                progress(oa, r + 1, runs)
        out[oa] = {"distance_mean": float(np.mean([e.distance for e in eps])),
                   "unsafe_steps": int(sum(e.unsafe_steps for e in eps)),
                   "lane_changes": int(sum(e.lane_changes for e in eps)),
                   "collisions": int(sum(e.collisions for e in eps)),
                   "infeasible_steps": int(sum(e.infeasible_steps for e in eps)),
                   "distances": [round(e.distance, 3) for e in eps]}
    return out
