"""The guardian's settings: one frozen dataclass, highway-env's limits as defaults."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

from guardian.errors import ConfigError
from guardian.model.reversing import ReversingCover

CONFLICT_CHOICES = ("lead", "traffic")
OVERAPPROXIMATIONS = ("trivial", "ordered")
REVERSE_REACH = 21.0   # [m] GuardianConfig.reverse_reach's default (benchmarks/idm_reversal.py: 20.19 m at most)


@dataclass(frozen=True)
class GuardianConfig:
    """Bounds of the traffic part and choices of the lead part.

    Attributes
    ----------
    h_min : float
        [m] bumper-to-bumper headway kept to traffic (2 m covers a lane-changing leader's lost
        progress, at most ``θ_max / 2`` times its sideways travel: 0.6 m at 0.3 rad over a 4 m lane).
    v_max : float
        [m/s] the traffic's top speed (highway-env's ``Vehicle.MAX_SPEED``).
    traffic_accel : float
        [m/s^2] ``|a|`` of the traffic (``IDMVehicle.ACC_MAX``): their braking and acceleration bound,
        and highway-env's ego's.
    wreck_margin : float
        [m] how far an impact may push a car back beyond where it stands still: the guardian keeps
        this much more room behind a car at risk of a crash (``guardian.decide.traffic``; docs/guardian.md
        "Wrecks" has the measurement behind the default).
    reverse_reach : float
        [m] how far a car seen driving backwards may still back up: highway-env lets traffic reverse
        (``Vehicle.MIN_SPEED = -40``; IDM brakes into reverse when it stands inside its desired gap), which
        the traffic model (speeds in ``[0, v_max]``) does not. The guardian takes a reversing car's rear
        this much further back and the car into the lanes beside its own (its steering swings a reversing
        body); a reversal that goes further is counted (``guardian.adapters.highway_env.monitor``; docs/guardian.md "Reversing
        traffic" has the measurement behind the default).
    reverse_horizon : float
        [s] a car slower than ``traffic_accel * reverse_horizon`` may be driving backwards within this time and
        is covered as one that does (``guardian.model.reversing.ReversingCover``; 0: only a car seen driving
        backwards). The default is highway-env's policy period and the time a lane change commits the ego to
        a lane (docs/guardian.md "Reversing traffic").
    overapprox : str
        ``trivial`` (highway-env traffic announces no lane change) or ``ordered``.
    use_intention : bool
        Lead part: switch to ``C_a`` / ``C_c`` once identified (Theorem 4).
    horizon : int
        Lead part: the estimator's window N.
    priority : tuple
        Which input the override changes first (0: throttle, 1: steering).
    resample_unsafe_start : bool
        At reset, draw the start again (up to ``start_attempts`` times) until it lies in the guardian's
        invariant sets; otherwise such a start is only reported (``info["guardian"]["start_inside"]``).
    start_attempts : int
    override_penalty : float
        Subtracted from the reward of every policy step the guardian overrode for safety (a clip to
        its modelling bounds is not one): the learner then feels the shield instead of leaning on it.
    """

    h_min: float = 2.0
    v_max: float = 40.0
    traffic_accel: float = 6.0
    wreck_margin: float = 1.0
    reverse_reach: float = REVERSE_REACH
    reverse_horizon: float = 1.0
    overapprox: str = "trivial"
    use_intention: bool = True
    horizon: int = 10
    priority: tuple = (0, 1)
    resample_unsafe_start: bool = False
    start_attempts: int = 100
    override_penalty: float = 0.0

    def __post_init__(self):
        if self.overapprox not in OVERAPPROXIMATIONS:
            raise ConfigError(f"GuardianConfig.overapprox must be one of {OVERAPPROXIMATIONS}, got {self.overapprox!r}")
        if sorted(self.priority) != [0, 1]:
            raise ConfigError(f"GuardianConfig.priority must order the inputs 0 and 1, got {self.priority!r}")
        for name in ("h_min", "v_max", "traffic_accel"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"GuardianConfig.{name} must be positive, got {getattr(self, name)!r}")
        for name in ("wreck_margin", "reverse_reach", "reverse_horizon"):
            if not (getattr(self, name) >= 0 and getattr(self, name) < float("inf")):
                raise ConfigError(f"GuardianConfig.{name} must be finite and >= 0, got {getattr(self, name)!r}")
        if not self.override_penalty >= 0:
            raise ConfigError(f"GuardianConfig.override_penalty must be >= 0, got {self.override_penalty!r}")
        if self.horizon < 1 or self.start_attempts < 1:
            raise ConfigError("GuardianConfig.horizon and start_attempts must be at least 1")

    @cached_property
    def reversing(self) -> ReversingCover:
        """The cover for traffic that drives backwards (``reverse_reach``, ``reverse_horizon``)."""
        return ReversingCover(self.reverse_reach, self.traffic_accel * self.reverse_horizon)
