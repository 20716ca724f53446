"""The intention-aware guardian of the overtake scenario (Definition 15, Theorem 4).

At each step the guardian (1) feeds the last transition to the intention
estimator, (2) picks the supervisor of the valid intentions — ``S_{I_i}`` once
intention i is the only valid one, the intention-agnostic ``S_I`` (from
``C_bnd``) otherwise —, (3) computes ``S(x)`` and (4) keeps the driver's input
if admissible, else applies the nearest admissible input by priority.

Fail-safe (the state is outside the active invariant set, so Theorem 4 no
longer applies — e.g. the episode started outside ``C_bnd`` or the lead fits no
model): the record says ``in_invariant_set=False`` and the guardian applies

* the nearest input of ``S(x)`` if it is non-empty (every successor is then
  back inside the active set, for every disturbance), else
* ``FAILSAFE_INPUT``: full braking with no lateral motion (the record says ``failsafe=True``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from intention.estimator import IntentionEstimator
from intention.models import unclip_standstill
from rcis.validate import finite_vector

FAILSAFE_INPUT = (-3.0, 0.0)  # (a_ex, v_ey): brake fully, hold the lateral position
AGNOSTIC = "bounded_velocity"


@dataclass
class GuardianRecord:
    t: int
    state: list
    proposed: list
    applied: list
    overridden: bool
    changed: str                 # "none" | "throttle" | "steering" | "both" | "failsafe"
    active_set: str              # the RCIS whose supervisor is in use
    valid_intentions: list
    identified: str | None
    in_invariant_set: bool       # x in the active set: Theorem 4's guarantee holds
    failsafe: bool               # S(x) was empty: FAILSAFE_INPUT was applied
    admissible: list = field(default_factory=list)      # S(x) as polygons [[a, v_ey], ...]
    throttle_range: list = field(default_factory=list)  # admissible a_ex at the proposed v_ey
    steering_range: list = field(default_factory=list)  # admissible v_ey at the proposed a_ex

    def as_dict(self, polygons: bool = True) -> dict:
        d = dict(self.__dict__)
        if not polygons:
            d.pop("admissible")
        return d


@runtime_checkable
class Supervisor(Protocol):
    """A supervisor: ``step(x, u)`` returns the input to apply (inside the input bounds) and its record."""

    def reset(self) -> None: ...

    def step(self, x, u_driver) -> tuple[np.ndarray, "GuardianRecord"]: ...


class IntentionAwareGuardian:
    """Supervises one ego vehicle; ``step(x, u)`` returns the input to apply and a record.

    Parameters
    ----------
    library : intention.library.OvertakeLibrary
        The sets ``C_bnd``, ``C_a``, ``C_c`` and their models.
    use_intention : bool
        Switch to the identified intention's set; False pins the guardian to ``C_bnd``.
    horizon : int
        The estimator's horizon N.
    priority : tuple of int
        Which input the override changes first (0: acceleration, 1: lateral velocity).
    """

    def __init__(self, library, use_intention: bool = True, horizon: int = 10, priority=(0, 1),
                 ego_stops_at_zero: bool = False):
        self.library = library
        self.use_intention = use_intention
        self.ego_stops_at_zero = ego_stops_at_zero  # the simulator clips v_ex at 0 (intention.models.unclip_standstill)
        self.priority = tuple(priority)
        candidates = {n: library.models[n] for n in ("aggressive", "cautious")}
        self.estimator = IntentionEstimator(candidates, horizon=horizon)
        self.reset()

    def reset(self) -> None:
        self.estimator.reset()
        self.t = 0
        self._last = None  # (x, applied input) of the previous step

    @property
    def active_set(self) -> str:
        if self.use_intention and len(self.estimator.valid) == 1:
            return self.estimator.valid[0]
        return AGNOSTIC

    def observe(self, x) -> "LeadView":
        """Feed the last transition to the estimator and return the active set's ``S(x)`` (Theorem 4).

        Call ``commit(x, applied)`` once the input to apply is known (``step`` does both).
        """
        x = finite_vector(x, 4, "state")
        self.library.models[AGNOSTIC].system.piece_index(x)  # raises before any state changes
        if self._last is not None:
            x_seen = unclip_standstill(self.library.params, *self._last, x) if self.ego_stops_at_zero else x
            self.estimator.update(self._last[0], self._last[1], x_seen)
        name = self.active_set
        adm = self.library.admissible(name)
        return LeadView(x, name, adm, adm.at(x), bool(self.library.region(name).contains(x)))

    def commit(self, x, applied) -> None:
        self._last = (np.asarray(x, dtype=float), np.asarray(applied, dtype=float))
        self.t += 1

    def step(self, x, u_driver) -> tuple[np.ndarray, GuardianRecord]:
        """Supervise one step (Theorem 4).

        Parameters
        ----------
        x : array of 4 floats
            The state ``(v_ex, y_e, h, v_Lx)``.
        u_driver : array of 2 floats
            The driver's input ``(a_ex, v_ey)``.

        Returns
        -------
        applied : ndarray
            The driver's input if admissible, else the nearest admissible one by priority, else
            ``FAILSAFE_INPUT``; always inside ``U_e``.
        record : GuardianRecord
            What happened and why.

        Raises
        ------
        ValueError
            For a wrong shape, a non-finite entry, or a state in no piece of the model.
        """
        u = finite_vector(u_driver, 2, "driver input")
        view = self.observe(x)
        x = view.x
        query = view.query
        result = view.admissible.override(x, u, self.priority, query=query)
        if result.feasible:
            applied, changed, overridden = result.applied, result.changed, result.overridden
        else:
            applied, changed = np.array(FAILSAFE_INPUT), "failsafe"
            overridden = not np.array_equal(applied, u)
        record = GuardianRecord(
            t=self.t, state=x.tolist(), proposed=u.tolist(), applied=applied.tolist(),
            overridden=bool(overridden), changed=changed, active_set=view.name,
            valid_intentions=list(self.estimator.valid),
            identified=self.identified,
            in_invariant_set=view.inside, failsafe=changed == "failsafe",
            admissible=[P.tolist() for P in query.polygons],
            throttle_range=query.ranges(0, u[1]),
            steering_range=query.ranges(1, u[0]))
        self.commit(x, applied)
        return applied, record

    @property
    def identified(self) -> str | None:
        return self.estimator.valid[0] if len(self.estimator.valid) == 1 else None


@dataclass(frozen=True)
class LeadView:
    """What the lead part knows at one state: the active set and its ``S(x)``."""

    x: np.ndarray
    name: str
    admissible: object      # rcis.admissible.AdmissibleInputs of the active set
    query: object           # rcis.admissible.AdmissibleQuery: S(x)
    inside: bool            # x in the active set (Theorem 4 applies)
