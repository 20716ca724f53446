"""What every decision object answers: the one interface the simulator adapters and the service ask."""
from __future__ import annotations

from typing import Protocol, runtime_checkable

from guardian.model.decision import Decision
from guardian.model.scene import Scene


@runtime_checkable
class DecisionObject(Protocol):
    """A guardian for one ego, without a simulator.

    ``state`` is the ego's state in the decision object's own model (the overtake state ``[v_ex, y_e, h,
    v_Lx]`` for ``PointMassGuardian``, an ``EgoState`` for ``BicycleGuardian``); ``scene`` the other cars as
    ITHA agents; ``proposed`` the driver's input.
    """

    def reset(self) -> None:
        """Forget the episode (the intention estimate, the lanes held)."""

    def inside(self, state, scene: Scene) -> bool:
        """Does ``state`` lie in the invariant sets, so that the promise holds from it?"""

    def step(self, state, scene: Scene, proposed) -> tuple:
        """``(applied, decision)``: the input to apply, always within the input bounds, and a ``Decision``
        saying what was changed and why."""


__all__ = ["Decision", "DecisionObject"]
