"""Parameters of the overtake scenario (dissertation Section 6.3, Table 6.1, SPEC.md part A).

Table 6.1 has sign typos; SPEC.md fixes them: ``a_L^min = -3``, ``w_Delta^min = -0.1``,
``v_L^des = 30 m/s``, ``h_r = 60 m``, ``h_min = 10 m``.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

STATE_NAMES = ("v_ex", "y_e", "h", "v_Lx")
INPUT_NAMES = ("a_ex", "v_ey")


@dataclass(frozen=True)
class OvertakeParams:
    dt: float = 0.1                     # sampling time (s)
    b_e: float = 0.1                    # ego drag coefficient (6.3)
    b_L: float = 0.1                    # lead drag coefficient (6.3)
    a_ex_bounds: tuple = (-3.0, 3.0)    # U_e, longitudinal acceleration (m/s^2)
    v_ey_bounds: tuple = (-1.8, 1.8)    # U_e, lateral velocity (m/s)
    a_L_bounds: tuple = (-3.0, 3.0)     # U_o, lead acceleration (m/s^2)
    w_ex_bounds: tuple = (-0.15, 0.15)  # process noise on ego speed
    w_ey_bounds: tuple = (-0.09, 0.09)  # process noise on ego lateral position
    w_Lx_bounds: tuple = (-0.05, 0.05)  # process noise on lead speed
    w_delta_bounds: tuple = (-0.1, 0.1)  # variability within an intention (6.5)
    v_ex_bounds: tuple = (16.0, 36.0)   # ego speed limits (safe set 6.8)
    y_e_bounds: tuple = (-0.9, 2.7)     # lane-keeping bounds (safe set 6.8)
    v_Lx_bounds: tuple = (0.0, 33.5)    # lead speed bounds (domain X)
    h_min: float = 10.0                 # minimum headway while in the right lane (6.8)
    h_r: float = 60.0                   # reaction zone |h| <= h_r
    v_L_des: float = 30.0               # cruise speed of the lead car outside the zone
    K_des: float = 1.0
    K_A: tuple = (1.0, 0.0, 0.0, -1.0)  # aggressive: match the ego's speed
    K_C: tuple = (0.0, -0.1, 0.1, -0.01)  # cautious
    k_c: float = 0.01
    left_lane_y: float = 0.9            # y_e >= this is the left lane (C_left, Prop. 20)

    @classmethod
    def among_traffic(cls, **changes) -> "OvertakeParams":
        """Table 6.1 with the ego's speed floor at 0: the ego may wait behind the lead for as long as
        traffic takes the left lane (the dissertation's ``v_ex >= 16`` assumes a free left lane)."""
        return cls(**{"v_ex_bounds": (0.0, cls.v_ex_bounds[1]), **changes})

    def as_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "OvertakeParams":
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"OvertakeParams: unknown fields {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})
