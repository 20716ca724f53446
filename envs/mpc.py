"""The switched MPC controller of Section 6.5.3 and its styles (``mpc``, ``bad``, ``careful``).

A controller on the overtake state, in physical units; ``envs.agents`` wraps it as an agent of
either environment (that is the one registry of drivers).

The MPC driver switches between three modes, as the dissertation's baseline
(tailgate for a while, overtake, return):

* ``tailgate``: follow the lead in the right lane at headway ``h_follow``;
* ``overtake``: move to the left-lane centre and drive ``pass_speedup`` faster than the lead;
* ``return``: once ``return_gap`` metres ahead of the lead, go back to the right lane.

Each step it solves, per axis, the MPC tracking problem over ``horizon`` steps
with the model (6.3) and box input bounds,
``min sum (z_k - z_ref)^2 + rho * u_k^2  s.t.  u in U``, which is a bounded
least-squares problem (solved exactly with scipy's BVLS). The longitudinal and
lateral dynamics are decoupled, so this is the same QP as the joint one.

``bad`` tailgates at 4 m (inside ``h_min``) and returns 2 m ahead; ``careful``
keeps 45 m and returns 35 m ahead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

from intention.params import OvertakeParams

LEFT_CENTRE, RIGHT_CENTRE = 1.8, 0.0


@dataclass(frozen=True)
class MPCStyle:
    h_follow: float = 15.0       # tailgating headway (m)
    tailgate_time: float = 4.0   # seconds in tailgate before overtaking
    pass_speedup: float = 5.0    # m/s faster than the lead while passing
    return_gap: float = 15.0     # m ahead of the lead before returning
    cruise_speed: float = 28.0   # after returning
    rho_long: float = 0.05
    rho_lat: float = 0.2


STYLES = {"mpc": MPCStyle(),
          "bad": MPCStyle(h_follow=4.0, tailgate_time=3.0, pass_speedup=3.0, return_gap=2.0,
                          rho_lat=0.02),
          "careful": MPCStyle(h_follow=45.0, tailgate_time=4.0, pass_speedup=4.0, return_gap=35.0,
                              rho_long=0.2, rho_lat=0.5)}


def _prediction(a: float, b: float, horizon: int):
    """z_k = a^k z_0 + sum_j a^(k-1-j) b u_j for k = 1..H: (Phi, Gamma)."""
    Phi = a ** np.arange(1, horizon + 1)
    Gamma = np.zeros((horizon, horizon))
    for k in range(horizon):
        for j in range(k + 1):
            Gamma[k, j] = a ** (k - j) * b
    return Phi, Gamma


class MPCDriver:
    """The switched MPC baseline (tailgate, overtake, return)."""

    def __init__(self, style: MPCStyle = MPCStyle(), params: OvertakeParams = OvertakeParams(),
                 horizon: int = 10):
        self.style, self.p, self.H = style, params, horizon
        self._long = _prediction(1 - params.b_e * params.dt, params.dt, horizon)
        self._lat = _prediction(1.0, params.dt, horizon)
        self.reset()

    def reset(self) -> None:
        self.mode = "tailgate"
        self.t = 0

    def _track(self, pred, z0, z_ref, rho, bounds):
        Phi, Gamma = pred
        A = np.vstack([Gamma, np.sqrt(rho) * np.eye(self.H)])
        b = np.concatenate([z_ref - Phi * z0, np.zeros(self.H)])
        return float(lsq_linear(A, b, bounds=bounds, method="bvls").x[0])

    def act(self, x) -> np.ndarray:
        """The input ``(a_ex, v_ey)`` in ``U_e`` for the overtake state ``x = (v_ex, y_e, h, v_Lx)``."""
        v, y, h, vl = x
        s = self.style
        self.t += 1
        if self.mode == "tailgate" and self.t * self.p.dt >= s.tailgate_time:
            self.mode = "overtake"
        if self.mode == "overtake" and h <= -s.return_gap:
            self.mode = "return"
        if self.mode == "tailgate":
            v_ref, y_ref = vl + 0.5 * (h - s.h_follow), RIGHT_CENTRE
        elif self.mode == "overtake":
            v_ref, y_ref = vl + s.pass_speedup, LEFT_CENTRE
        else:
            v_ref, y_ref = s.cruise_speed, RIGHT_CENTRE
        v_ref = float(np.clip(v_ref, 17.0, 35.0))  # a reference, not an input: inputs stay in U
        a = self._track(self._long, v, np.full(self.H, v_ref), s.rho_long, self.p.a_ex_bounds)
        vy = self._track(self._lat, y, np.full(self.H, y_ref), s.rho_lat, self.p.v_ey_bounds)
        return np.array([a, vy])
