"""The lead car's intention models as PWA systems (dissertation (6.3)-(6.7)).

State ``x = [v_ex, y_e, h, v_Lx]``, ego input ``u_e = [a_ex, v_ey]``. Each
intention closes the loop around the lead car:

* aggressive (6.5): ``a_L = sat(K_A x) + w_Delta`` in the reaction zone ``|h| <= h_r``,
* cautious (6.7):   ``a_L = sat(K_C x + k_c v_L^des) + w_Delta`` in the zone,
* outside the zone both cruise: ``a_L = sat(K_des (v_L^des - v_L)) + w_Delta``,

where ``sat = max(min(., alpha_1), alpha_2)`` with the bounds (6.6) that keep
``v_L`` inside ``[v_L^min, v_L^max]``. The PWA pieces are the reaction zones
times the active term of the saturation. The bounded-velocity model lets the
lead car's next speed be anything in ``[v_L^min, v_L^max]``.

Closed-loop disturbances: ``w = [w_ex, w_ey, w_Lx, w_Delta]`` for the
intentions, ``w = [w_ex, w_ey, v_L(k+1)]`` for bounded velocity.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from intention.params import OvertakeParams
from rcis.polyhedron import Polyhedron
from rcis.pwa import PWAPiece, PWASystem

V, Y, H, VL = range(4)


@dataclass(frozen=True)
class Affine:
    """``k . x + k0`` on the overtake state."""

    k: np.ndarray
    k0: float

    def __call__(self, x) -> float:
        return float(self.k @ x + self.k0)

    def minus(self, other: "Affine") -> "Affine":
        return Affine(self.k - other.k, self.k0 - other.k0)


@dataclass(frozen=True)
class LeadPolicyPiece:
    """On ``domain`` the lead's nominal acceleration is the affine ``accel``."""

    domain: Polyhedron
    strict: np.ndarray
    accel: Affine
    label: str


@dataclass(frozen=True)
class IntentionModel:
    """An intention: its name, the lead's policy pieces and the closed-loop PWA system."""

    name: str
    params: OvertakeParams
    system: PWASystem
    policy: tuple  # LeadPolicyPiece, ...; empty for bounded velocity

    def nominal_lead_acceleration(self, x) -> float:
        """``sat(.)`` of (6.5)/(6.7) at x (undefined for bounded velocity)."""
        if not self.policy:
            raise ValueError("the bounded-velocity model has no lead policy")
        x = np.asarray(x, dtype=float)
        j = self.system.piece_index(x)
        return self.policy[j].accel(x)

    def lead_acceleration_interval(self, x) -> tuple[float, float]:
        """``I(x)``: the lead accelerations this intention allows at x."""
        p = self.params
        if not self.policy:
            # any next lead speed in [v_min, v_max]: solve (6.3) for a_L with w_Lx = 0
            keep = (1 - p.b_L * p.dt) * x[VL]
            return ((p.v_Lx_bounds[0] - keep) / p.dt, (p.v_Lx_bounds[1] - keep) / p.dt)
        a = self.nominal_lead_acceleration(x)
        return (a + p.w_delta_bounds[0], a + p.w_delta_bounds[1])


def _ego_matrices(p: OvertakeParams):
    dt = p.dt
    A = np.zeros((4, 4))
    A[V, V] = 1 - p.b_e * dt
    A[Y, Y] = 1.0
    A[H, H] = 1.0
    A[H, V] = -dt
    A[H, VL] = dt
    B = np.zeros((4, 2))
    B[V, 0] = dt
    B[Y, 1] = dt
    return A, B


def state_domain(p: OvertakeParams) -> Polyhedron:
    """``X = [v_min, v_max] x [y_min, y_max] x R x [v_L^min, v_L^max]``."""
    return Polyhedron.from_box([p.v_ex_bounds[0], p.y_e_bounds[0], -np.inf, p.v_Lx_bounds[0]],
                               [p.v_ex_bounds[1], p.y_e_bounds[1], np.inf, p.v_Lx_bounds[1]])


def input_set(p: OvertakeParams) -> Polyhedron:
    return Polyhedron.from_box([p.a_ex_bounds[0], p.v_ey_bounds[0]], [p.a_ex_bounds[1], p.v_ey_bounds[1]])


def lead_domain(p: OvertakeParams) -> Polyhedron:
    return Polyhedron.from_box([-np.inf, -np.inf, -np.inf, p.v_Lx_bounds[0]],
                               [np.inf, np.inf, np.inf, p.v_Lx_bounds[1]])


def _successor_box(p: OvertakeParams):
    inf = np.inf
    return (np.array([-inf, -inf, -inf, p.v_Lx_bounds[0]]), np.array([inf, inf, inf, p.v_Lx_bounds[1]]))


def _saturation_terms(p: OvertakeParams):
    """The affine terms of alpha_1 (upper, a min) and alpha_2 (lower, a max) in (6.6)."""
    dt, keep = p.dt, 1 - p.b_L * p.dt
    w_hi = p.w_delta_bounds[1] + p.w_Lx_bounds[1]
    w_lo = p.w_delta_bounds[0] + p.w_Lx_bounds[0]
    e_vl = np.eye(4)[VL]
    upper = [Affine(np.zeros(4), p.a_L_bounds[1] - w_hi),
             Affine(-keep / dt * e_vl, p.v_Lx_bounds[1] / dt - w_hi)]
    lower = [Affine(np.zeros(4), p.a_L_bounds[0] - w_lo),
             Affine(-keep / dt * e_vl, p.v_Lx_bounds[0] / dt - w_lo)]
    return upper, lower


def _saturation_pieces(phi: Affine, upper, lower):
    """Pieces of ``max(min(phi, *upper), *lower)``: (rows 'f <= 0' as Affines, active term, name)."""
    pieces = [([phi.minus(u) for u in upper] + [l.minus(phi) for l in lower], phi, "linear")]
    for i, u in enumerate(upper):
        rows = [u.minus(phi)] + [u.minus(o) for o in upper if o is not u] + [l.minus(u) for l in lower]
        pieces.append((rows, u, f"upper{i}"))
    for k, l in enumerate(lower):
        others = [o.minus(l) for o in lower if o is not l]
        # l is the max when l >= min(phi, *upper): a union, one piece per argument of the min
        for j, t in enumerate([phi] + upper):
            pieces.append(([t.minus(l)] + others, l, f"lower{k}/{j}"))
    return pieces


def _zones(p: OvertakeParams):
    """(rows as (a, b, strict) on h, policy name): reaction zone closed, the rest open."""
    e_h = np.eye(4)[H]
    return [([(e_h, p.h_r, False), (-e_h, p.h_r, False)], "zone"),
            ([(-e_h, -p.h_r, True)], "ahead"),     # h > h_r: the lead is far ahead
            ([(e_h, -p.h_r, True)], "behind")]     # h < -h_r: the lead is far behind


def _policy_in_zone(p: OvertakeParams, kind: str, zone: str) -> Affine:
    if zone != "zone":
        return Affine(-p.K_des * np.eye(4)[VL], p.K_des * p.v_L_des)
    if kind == "aggressive":
        return Affine(np.array(p.K_A, dtype=float), 0.0)
    return Affine(np.array(p.K_C, dtype=float), p.k_c * p.v_L_des)


def _lead_policy(p: OvertakeParams, kind: str) -> list[LeadPolicyPiece]:
    upper, lower = _saturation_terms(p)
    dom0 = lead_domain(p)
    pieces = []
    for zone_rows, zone in _zones(p):
        phi = _policy_in_zone(p, kind, zone)
        for rows, active, sat_name in _saturation_pieces(phi, upper, lower):
            rows = [(a, b, s) for a, b, s in zone_rows] + [(r.k, -r.k0, False) for r in rows]
            constant = [np.linalg.norm(a) < 1e-12 for a, _, _ in rows]
            if any(c and b < 0 for c, (_, b, _) in zip(constant, rows)):
                continue  # a constant row 0 <= b < 0: this saturation term is never active
            rows = [r for r, c in zip(rows, constant) if not c]
            domain = Polyhedron(np.vstack([a for a, _, _ in rows] + [dom0.A]),
                                np.concatenate([[b for _, b, _ in rows], dom0.b]))
            if domain.chebyshev_ball().radius <= 1e-9:
                continue
            strict = np.array([s for _, _, s in rows] + [False] * dom0.n_constraints, dtype=bool)
            pieces.append(LeadPolicyPiece(domain, strict, active, f"{zone}/{sat_name}"))
    return pieces


def _closed_loop(p: OvertakeParams, policy: list[LeadPolicyPiece], name: str) -> PWASystem:
    A0, B = _ego_matrices(p)
    dt = p.dt
    E = np.zeros((4, 4))
    E[V, 0] = dt
    E[Y, 1] = dt
    E[VL, 2] = dt
    E[VL, 3] = dt
    W = Polyhedron.from_box([p.w_ex_bounds[0], p.w_ey_bounds[0], p.w_Lx_bounds[0], p.w_delta_bounds[0]],
                            [p.w_ex_bounds[1], p.w_ey_bounds[1], p.w_Lx_bounds[1], p.w_delta_bounds[1]])
    pieces = []
    for lp in policy:
        A = A0.copy()
        A[VL, VL] = 1 - p.b_L * dt
        A[VL] += dt * lp.accel.k
        c = np.zeros(4)
        c[VL] = dt * lp.accel.k0
        pieces.append(PWAPiece(lp.domain, A, B, c, E, W, lp.strict, lp.label))
    return PWASystem(pieces, input_set(p), state_domain(p), _successor_box(p), name)


def aggressive(p: OvertakeParams = OvertakeParams()) -> IntentionModel:
    policy = _lead_policy(p, "aggressive")
    return IntentionModel("aggressive", p, _closed_loop(p, policy, "aggressive"), tuple(policy))


def cautious(p: OvertakeParams = OvertakeParams()) -> IntentionModel:
    policy = _lead_policy(p, "cautious")
    return IntentionModel("cautious", p, _closed_loop(p, policy, "cautious"), tuple(policy))


def bounded_velocity(p: OvertakeParams = OvertakeParams()) -> IntentionModel:
    """The lead's next speed is anything in ``[v_L^min, v_L^max]`` (Section 6.3.2.3)."""
    A, B = _ego_matrices(p)
    dt = p.dt
    E = np.zeros((4, 3))
    E[V, 0] = dt
    E[Y, 1] = dt
    E[VL, 2] = 1.0
    W = Polyhedron.from_box([p.w_ex_bounds[0], p.w_ey_bounds[0], p.v_Lx_bounds[0]],
                            [p.w_ex_bounds[1], p.w_ey_bounds[1], p.v_Lx_bounds[1]])
    piece = PWAPiece(lead_domain(p), A, B, np.zeros(4), E, W, None, "bounded")
    system = PWASystem([piece], input_set(p), state_domain(p), _successor_box(p), "bounded_velocity")
    return IntentionModel("bounded_velocity", p, system, ())


def intention_models(p: OvertakeParams = OvertakeParams()) -> dict[str, IntentionModel]:
    return {"bounded_velocity": bounded_velocity(p), "aggressive": aggressive(p), "cautious": cautious(p)}


def safe_set(p: OvertakeParams = OvertakeParams()):
    """``X_safe`` (6.8) as a union: behind, ahead, or in the left lane; within X."""
    from rcis.region import Region

    X = state_domain(p)
    e_h, e_y = np.eye(4)[H], np.eye(4)[Y]
    pieces = [X.intersect(Polyhedron([-e_h], [-p.h_min])),     # h >= h_min
              X.intersect(Polyhedron([e_h], [-p.h_min])),      # h <= -h_min
              X.intersect(Polyhedron([-e_y], [-p.left_lane_y]))]  # y >= |y_min|
    return Region([P.minimal() for P in pieces], 4)


def left_lane(p: OvertakeParams = OvertakeParams()):
    """``C_left`` of Proposition 20: the left-lane states of X."""
    from rcis.region import Region

    X = state_domain(p)
    return Region([X.intersect(Polyhedron([-np.eye(4)[Y]], [-p.left_lane_y])).minimal()], 4)


def unclip_standstill(p: OvertakeParams, x, u, x_next) -> np.ndarray:
    """``x_next`` with a speed clipped at standstill replaced by the speed (6.3) gives nearest to it.

    ``guardian/HighwayOvertake-v0`` stops the ego at ``v_ex = 0`` (a car held by its brake does not
    reverse), which (6.3) does not model; the intention estimator judges transitions by (6.3). The
    ego's rows say nothing about the lead's intention, so a clipped step is handed over with the
    model's speed for the ego noise nearest to it: the lead's rows are unchanged.
    """
    x, u, x_next = (np.asarray(a, dtype=float) for a in (x, u, x_next))
    if x_next[V] != 0.0:
        return x_next
    keep = (1 - p.b_e * p.dt) * x[V] + p.dt * u[0]
    w = min(max(-keep / p.dt, p.w_ex_bounds[0]), p.w_ex_bounds[1])
    out = x_next.copy()
    out[V] = keep + p.dt * w
    return out

