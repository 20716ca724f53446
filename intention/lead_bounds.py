"""Interval bounds of the lead's next speed under an intention model (6.3)-(6.7).

Kept out of ``intention.models`` on purpose: the cached sets are keyed by the source of every module
``intention.library`` imports, and this module shapes no set (``guardian.decide.lead_following`` uses it).
"""
from __future__ import annotations

import numpy as np

from intention.models import H, VL, Affine, IntentionModel, _policy_in_zone, _saturation_terms, _zones


def next_lead_speed_bounds(model: IntentionModel, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the lead's next speed ``v_L(k+1)`` over the state boxes ``[lo, hi]`` (rows of 4).

    (6.3) closed by the intention's policy: ``v_L+ = (1 - b_L dt) v_L + dt (sat(.) + w_Delta + w_Lx)``
    with ``sat = max(min(phi, *alpha_1), *alpha_2)`` of (6.5)-(6.7). Adding ``(1 - b_L dt) v_L`` to each
    term of ``sat`` keeps the max-min (it is monotone), so each term becomes one affine function of the
    state whose range over a box is exact; the lead's own speed then appears once per term, which
    keeps the bounds tight under repetition. A box that meets several zones of ``h`` takes the hull of
    their policies. The bounded-velocity model gives ``[v_L^min, v_L^max]``. The bounds contain every
    ``v_L+`` the closed-loop ``PWASystem`` reaches from the box (``tests/guardian/decide/test_lead_following.py``).
    """
    p = model.params
    lo, hi = np.atleast_2d(np.asarray(lo, float)), np.atleast_2d(np.asarray(hi, float))
    if not model.policy:
        n = len(lo)
        return np.full(n, p.v_Lx_bounds[0]), np.full(n, p.v_Lx_bounds[1])
    keep, dt = 1 - p.b_L * p.dt, p.dt
    e_vl = np.eye(4)[VL]

    def speed_term(t: Affine):
        k, k0 = keep * e_vl + dt * t.k, dt * t.k0
        return (k0 + lo @ np.maximum(k, 0) + hi @ np.minimum(k, 0),
                k0 + hi @ np.maximum(k, 0) + lo @ np.minimum(k, 0))

    upper, lower = _saturation_terms(p)
    h_lo, h_hi = lo[:, H], hi[:, H]
    meets = {"zone": (h_lo <= p.h_r) & (h_hi >= -p.h_r), "ahead": h_hi > p.h_r, "behind": h_lo < -p.h_r}
    out_lo, out_hi = np.full(len(lo), np.inf), np.full(len(lo), -np.inf)
    for _, zone in _zones(p):
        terms = [speed_term(t) for t in [_policy_in_zone(p, model.name, zone)] + upper]
        floors = [speed_term(t) for t in lower]
        z_lo = np.maximum.reduce([np.minimum.reduce([t[0] for t in terms])] + [f[0] for f in floors])
        z_hi = np.maximum.reduce([np.minimum.reduce([t[1] for t in terms])] + [f[1] for f in floors])
        m = meets[zone]
        out_lo[m], out_hi[m] = np.minimum(out_lo[m], z_lo[m]), np.maximum(out_hi[m], z_hi[m])
    w_lo = dt * (p.w_delta_bounds[0] + p.w_Lx_bounds[0])
    w_hi = dt * (p.w_delta_bounds[1] + p.w_Lx_bounds[1])
    return out_lo + w_lo, out_hi + w_hi
