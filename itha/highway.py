"""The multi-lane highway as an ITHA (Example 5, Appendix B) and the experiment of Section 7.4.1.

Global state per car (B.1): speed ``v``, position ``p`` along the road, lane
``ℓ`` (1 = rightmost). Each step ``p+ = p + dt v``, ``v+ = v + dt u``,
``ℓ+ = ℓ + u_τ`` with ``u_τ = +1`` (left), ``0`` (stay), ``-1`` (right).
The local car-following state of car i is (B.3): ``(v_i, p_L - p_i - length, v_L)``
for its nearest leader L on its lane (``p_L >= p_i``), or ``(v_i, inf, v_max)``.

Resolution. A car j that changes lanes triggers a reset on car i when it changes
who i follows at the next step: j = i, j leads i now and leaves, or j becomes
i's leader. This is Appendix B's ρ restricted to the agents that actually
change i's next local state (Appendix B's ρ also lists triggering cars that
leave i's lane far ahead of i's leader; their reset value equals i's own
dynamics, which self-safety covers), so Theorem 5 applies unchanged.

Responsibility (7.5) of a lane change by the ego E into lane ℓ*:

* E itself: for every car that can lead E at t+1, the reset state
  ``(v_E + dt u, gap, slowest lead speed)`` must be in the RCIS;
* every car that can get E as its leader at t+1 (behind E in ℓ*): its reset
  ``(v_c + dt u_c, gap, v_E + dt u)`` must be in the RCIS for every ``u_c``
  (the worst is the hardest acceleration), a lower bound on E's speed;
* every car behind E in E's lane that can lose E as its leader: for every car
  that can then lead it, the reset must be in the RCIS for every ``u_c``.

Which cars "can" lead or follow depends on ``ρ̂``:

* ``trivial`` (7.6): any other car may change lanes, so every car that can be
  in the lane at t+1 (from the lane or its neighbours) can lead or follow E,
  and every car behind can be exposed (all those in between may leave). As
  (7.5) reads, E also answers for a car that moves in behind it at the same
  time, although that car's own (7.5) covers it as well;
* ``ordered`` (Algorithm 1 with Example 8's order: ahead first, on ties the
  slower lane first): the cars before E in the order have announced their
  triggers; the cars after E yield (they must be responsible towards E), so
  only the actual leader and the nearest follower matter.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from itha.car_following import CarFollowingParams, admissible_inputs, speeds_to_inputs
from itha.idm import idm_acceleration as idm
from rcis.intervals import intersect_intervals

STAY, LEFT, RIGHT = "stay", "left", "right"
LANE_SHIFT = {STAY: 0, LEFT: 1, RIGHT: -1}
OVERAPPROXIMATIONS = ("trivial", "ordered")


@dataclass(frozen=True)
class HighwayParams:
    """Section 7.4.1's set-up; values the dissertation leaves open are documented choices."""

    car_following: CarFollowingParams = field(default_factory=CarFollowingParams)
    n_lanes: int = 5
    n_cars: int = 60                 # uncontrolled cars besides the ego
    car_length: float = 5.0
    road_window: tuple = (-80.0, 320.0)  # initial positions of the other cars (ego at 0)
    ego_lane: int = 3
    ego_speed: float = 10.0
    desired_speed: tuple = (3.0, 13.0)   # IDM desired speeds, uniform (open in the dissertation)
    v_nom: float = 15.0
    horizon: int = 25
    predicted_d: float = -10.0       # d̃ at the first step of (7.7); 0 afterwards
    idm_delta: float = 4.0
    idm_s0: float = 5.0
    idm_T: float = 1.5
    idm_a: float = 10.0
    idm_b: float = 10.0

    def __post_init__(self):
        if not 1 <= self.ego_lane <= self.n_lanes:
            raise ValueError(f"ego_lane {self.ego_lane} is not in 1..{self.n_lanes}")
        if self.horizon < 1:
            raise ValueError("horizon must be at least 1")


# ---- global state -> local states (B.2, B.3) ---------------------------------------
def leader(p, lane, i: int, lane_of_i=None, exclude=()) -> int:
    """(B.2): the nearest car ahead of i (``p_j >= p_i``) on ``lane_of_i`` (default: i's lane); -1 if none."""
    li = lane[i] if lane_of_i is None else lane_of_i
    best, best_p = -1, math.inf
    for j in range(len(p)):
        if j == i or j in exclude or lane[j] != li:
            continue
        if p[i] <= p[j] < best_p:
            best, best_p = j, p[j]
    return best


def leaders(p, lane) -> list[int]:
    """(B.2) for every car."""
    return [leader(p, lane, i) for i in range(len(p))]


def local_state(params: HighwayParams, p, v, lane, i: int, L: int | None = None):
    """(B.3) for car i (``L``: its leader, if already known)."""
    cf = params.car_following
    L = leader(p, lane, i) if L is None else L
    if L < 0:
        return (v[i], math.inf, cf.v_max)
    return (v[i], p[L] - p[i] - params.car_length, v[L])


def local_states(params: HighwayParams, p, v, lane, lead=None) -> np.ndarray:
    lead = leaders(p, lane) if lead is None else lead
    return np.array([local_state(params, p, v, lane, i, lead[i]) for i in range(len(p))])


def step_global(params: HighwayParams, p, v, lane, inputs, triggers):
    """(B.1): one step of every car's global state."""
    dt = params.car_following.dt
    return ([p[k] + dt * v[k] for k in range(len(p))], [v[k] + dt * inputs[k] for k in range(len(p))],
            [lane[k] + LANE_SHIFT[triggers[k]] for k in range(len(p))])


def resolution(params: HighwayParams, p, v, lane, triggers) -> list[frozenset]:
    """ρ_i for every car: the lane-changing cars that change whom i follows at the next step.

    Car j (τ_j ≠ stay) is in ρ_i if j = i, or if i's leader at t+1 differs from the one it would have
    had had j kept its lane (j leaves in front of i, or moves in front of it).
    """
    zeros = [0.0] * len(p)
    pn, _, ln = step_global(params, p, v, lane, zeros, triggers)
    rho = []
    for i in range(len(p)):
        actual = leader(pn, ln, i)
        s = set()
        for j, tau in enumerate(triggers):
            if tau == STAY:
                continue
            if j == i:
                s.add(j)
                continue
            counterfactual = list(ln)
            counterfactual[j] = lane[j]
            if leader(pn, counterfactual, i) != actual:
                s.add(j)
        rho.append(frozenset(s))
    return rho


def reset_state(params: HighwayParams, p, v, lane, inputs, triggers, i: int):
    """``R_i``: car i's local state after the step (the leader's new speed uses its input)."""
    pn, vn, ln = step_global(params, p, v, lane, inputs, triggers)
    return local_state(params, pn, vn, ln, i)


def example8_order(p, lane) -> list[int]:
    """Example 8's order (as SPEC.md fixes it): ahead first; aligned cars, slower (lower) lane first."""
    return sorted(range(len(p)), key=lambda i: (-p[i], lane[i], i))


# ---- the ego's responsibility-sensitive input sets -----------------------------------
@dataclass
class ChoiceVerdict:
    """What one triggering choice allows and why."""

    trigger: str
    inputs: list            # feasible ego inputs (intervals); [] if the choice is not allowed
    reason: str = ""        # the first constraint that emptied it


class EgoSupervisor:
    """Self-safe and ρ̂-responsible input sets of the ego for each triggering choice."""

    def __init__(self, params: HighwayParams, invariant, overapprox: str = "ordered", others_invariant=None):
        """``invariant`` is the ego's RCIS; ``others_invariant`` (default: the same) the other cars',
        whose parameters also give their acceleration bound ``u_max``."""
        if overapprox not in OVERAPPROXIMATIONS:
            raise ValueError(f"unknown over-approximation {overapprox!r}; choose from {OVERAPPROXIMATIONS}")
        self.params = params
        self.S = invariant
        self.S_others = invariant if others_invariant is None else others_invariant
        self.overapprox = overapprox

    def choices(self, p, v, lane, ego: int = 0, next_lanes=None) -> list[ChoiceVerdict]:
        """Verdicts for stay, left, right. ``next_lanes[k]`` are the triggers announced by cars before
        the ego in the order (ordered ρ̂); cars absent from it have not decided."""
        out = [ChoiceVerdict(STAY, admissible_inputs(self.S, local_state(self.params, p, v, lane, ego)))]
        if not out[0].inputs:
            out[0].reason = "no self-safe input (state outside the invariant set)"
        for trig in (LEFT, RIGHT):
            out.append(self.lane_change(p, v, lane, ego, trig, next_lanes or {}))
        return out

    def lane_change(self, p, v, lane, ego, trig, announced, lengths=None) -> ChoiceVerdict:
        """Is the ego's lane change ``trig`` ρ̂-responsible, and with which inputs?

        ``p`` are front-bumper positions along the direction of travel; ``lengths`` the cars'
        lengths (default: ``car_length`` for all); ``announced`` maps car index to its trigger for
        the cars before the ego in the order (ordered ρ̂).
        """
        speeds, reason = self.lane_change_speeds(p, v, lane, ego, trig, announced, lengths)
        if not speeds:
            return ChoiceVerdict(trig, [], reason)
        inputs = [iv for lo, hi in speeds for iv in speeds_to_inputs(self.params.car_following, v[ego], [(lo, hi)])]
        return ChoiceVerdict(trig, inputs, "" if inputs else "no input of U reaches a responsible speed")

    def lane_change_speeds(self, p, v, lane, ego, trig, announced, lengths=None):
        """The ego's next speeds that make the lane change ``trig`` ρ̂-responsible, and why none do.

        Speeds rather than inputs, so that an ego whose input maps to its next speed otherwise
        than (7.3) (drag, noise) converts them exactly. Returns ``(intervals, reason)``.
        """
        prm, cf = self.params, self.params.car_following
        target = lane[ego] + LANE_SHIFT[trig]
        if not 1 <= target <= prm.n_lanes:
            return [], "no such lane"
        dt, n = cf.dt, len(p)
        lengths = [prm.car_length] * n if lengths is None else lengths
        pn = [p[k] + dt * v[k] for k in range(n)]
        trivial = self.overapprox == "trivial"
        allowed = [(0.0, cf.v_max)]

        def may_be_in(k, ln):
            """Can car k be on lane ln at t+1 (under ρ̂)?"""
            if k in announced:
                return lane[k] + LANE_SHIFT[announced[k]] == ln
            if trivial:
                return abs(lane[k] - ln) <= 1
            return lane[k] == ln  # later cars yield: they stay as far as E is concerned

        # 1. the ego's own reset: every car that can lead it in the target lane.
        leads = [k for k in range(n) if k != ego and pn[k] >= pn[ego] and may_be_in(k, target)]
        if not trivial:
            leads = sorted(leads, key=lambda k: pn[k])[:1]
        for k in leads:
            speeds = self.S.speed_intervals(pn[k] - lengths[k] - pn[ego], float(cf.worst_lead_speed(v[k])))
            allowed = intersect_intervals(allowed, speeds)
            if not allowed:
                return [], f"ego too close to car {k} ahead in lane {target}"
        # 2. cars that can get the ego as leader: in the target lane behind it at t+1.
        followers = [k for k in range(n) if k != ego and pn[k] < pn[ego] and may_be_in(k, target)]
        if not trivial:
            followers = sorted(followers, key=lambda k: -pn[k])[:1]
        So, co = self.S_others, self.S_others.params
        for k in followers:
            v_fast = min(v[k] + dt * co.u_max, co.v_max)
            allowed = intersect_intervals(allowed, So.lead_speed_intervals(v_fast, pn[ego] - lengths[ego] - pn[k]))
            if not allowed:
                return [], f"car {k} behind in lane {target} could not stay safe"
        # 3. cars behind the ego in its lane that lose it as their leader.
        old = lane[ego]
        behind = [k for k in range(n) if k != ego and pn[k] < pn[ego] and may_be_in(k, old)]
        if not trivial:
            behind = sorted(behind, key=lambda k: -pn[k])[:1]
        for c in behind:
            v_fast = min(v[c] + dt * co.u_max, co.v_max)
            new_leads = [k for k in range(n) if k not in (ego, c) and pn[k] >= pn[ego] and may_be_in(k, old)]
            if not trivial:
                new_leads = sorted(new_leads, key=lambda k: pn[k])[:1]
            for k in new_leads:
                x = (v_fast, pn[k] - lengths[k] - pn[c], float(co.worst_lead_speed(v[k])))
                if not So.contains(np.array([x]))[0]:
                    return [], f"car {c} behind in lane {old} would be exposed to car {k}"
        return allowed, ""


# ---- the ego's receding-horizon controller (7.7) ---------------------------------------
def tracking_cost(v1: float, v_nom: float, horizon: int, dt: float, u_min: float, u_max: float) -> float:
    """Optimal value of ``Σ_{t=1}^{H} (v_t - v_nom)^2`` given ``v_1`` and ``u in [u_min, u_max]`` afterwards.

    The speed is an integrator with a box input, so moving towards ``v_nom`` as
    fast as possible reaches the closest reachable speed at every step at once.
    """
    cost, v = 0.0, v1
    for _ in range(horizon):
        cost += (v - v_nom) ** 2
        v += dt * min(max((v_nom - v) / dt, u_min), u_max)
    return cost


def best_input(intervals, v: float, prm: HighwayParams):
    """The QP of (7.7) for one triggering choice: ``(u_0, cost)``, or None if infeasible.

    The cost only depends on the speeds, and the (7.7) constraints at the first
    step are the feasible intervals; the cost is convex in ``v_1``, so the
    optimum is the feasible input closest to ``(v_nom - v) / dt``.
    """
    if not intervals:
        return None
    cf = prm.car_following
    want = (prm.v_nom - v) / cf.dt
    best = None
    for lo, hi in intervals:
        u = min(max(want, lo), hi)
        c = tracking_cost(v + cf.dt * u, prm.v_nom, prm.horizon, cf.dt, cf.u_min, cf.u_max)
        if best is None or c < best[1] - 1e-12:
            best = (u, c)
    return best


def choose(verdicts, v: float, prm: HighwayParams):
    """Best feasible triggering choice: lowest cost; ties keep the lane (then left, then right)."""
    best = None
    for vd in verdicts:
        sol = best_input(vd.inputs, v, prm)
        if sol is not None and (best is None or sol[1] < best[2] - 1e-9):
            best = (vd.trigger, sol[0], sol[1])
    return best


# ---- IDM traffic (7.8) -----------------------------------------------------------------
def idm_acceleration(prm: HighwayParams, v: float, gap: float, v_lead: float, v_desired: float) -> float:
    """IDM (7.8) with the highway's parameters (``itha.idm``)."""
    return idm(v, gap, v_lead, v_desired, prm.idm_a, prm.idm_b, prm.idm_s0, prm.idm_T, prm.idm_delta)


def clip_input(cf: CarFollowingParams, v: float, a: float) -> float:
    """Keep an acceleration in U and the next speed in [0, v_max]."""
    a = min(max(a, cf.u_min), cf.u_max)
    return min(max(a, -v / cf.dt), (cf.v_max - v) / cf.dt)


# ---- the experiment of Section 7.4.1 ----------------------------------------------------
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
            acc.append(clip_input(cf, v[i], idm_acceleration(prm, v[i], gap, vl, desired[i])))
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
