"""The multi-lane highway as an ITHA (Example 5, Appendix B): global state, local states, resolution.

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

Example 8's order (ahead first, on ties the slower lane first) is the order in
which the ordered over-approximation ρ̂ lets cars announce their triggers
(``itha.responsibility``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from itha.car_following import CarFollowingParams

STAY, LEFT, RIGHT = "stay", "left", "right"
LANE_SHIFT = {STAY: 0, LEFT: 1, RIGHT: -1}


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
