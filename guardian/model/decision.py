"""What the guardian decided in one simulation step, and the order in which it gives up guarantees.

Every decision object (``guardian.decide.overtake.PointMassGuardian``, ``guardian.decide.bicycle.BicycleGuardian``)
answers ``step(...) -> (applied, Decision)``. The admissible set is built from parts; when they do
not intersect, parts are dropped in a fixed order (``LEVELS``), and the level reached is recorded:

0. ``composed``: every part holds (the lead's set, self-safety (7.4) against every car ahead in
   every lane the body may occupy, every lane entry ρ̂-responsible (7.5), the followers of lanes
   being entered kept in their sets).
1. ``follower_dropped``: the followers of lanes being entered are no longer kept in their sets (the
   entry was responsible when it began; from then on ITHA makes them answer for themselves).
2. ``conflict``: the lead's set yields; the lead is kept as an ordinary car with its physical
   bounds (self-safety when it is ahead, responsibility when the ego enters its lane).
3. ``failsafe``: no input keeps self-safety: the hardest braking the model allows, down to
   standstill and never reversing, and the lateral input back towards the ego's own lane.

Lateral inputs never enter a lane without a responsible entry, at any level: a lane the applied input
may enter is always one whose entry was checked (``entries``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

LEVELS = ("composed", "follower_dropped", "conflict", "failsafe")


@dataclass
class Entry:
    """A lane the body may begin to overlap this step under some admissible input, and the verdict."""

    lane: int                # ITHA lane (1 = rightmost)
    responsible: bool        # (7.5) holds for the applied input's next speed
    reason: str = ""

    def as_dict(self) -> dict:
        return {"lane": self.lane, "responsible": self.responsible, "reason": self.reason}


@dataclass
class Decision:
    """One simulation step of a decision object.

    ``proposed``/``applied`` are the ego's inputs (``[a_ex, v_ey]`` for the point mass,
    ``[acceleration, steering]`` for the bicycle); ``entered`` are the lanes the applied input may make
    the body overlap for the first time (each checked, responsible); ``refused`` are lanes the proposed
    input would have entered but the guardian kept the body out of.
    """

    proposed: list
    applied: list
    changed: str                      # "none" | "throttle" | "steering" | "both" | "conflict" | "failsafe"
    level: str = "composed"           # one of LEVELS
    reasons: list = field(default_factory=list)
    entered: list = field(default_factory=list)    # [lane, ...]
    lanes: list = field(default_factory=list)      # every lane the body may overlap during the step: the
                                                   # lanes it held and those entered responsibly
    touched: list = field(default_factory=list)    # lanes the body overlaps without holding them (the road
                                                   # brought them; their entry refused): not to be entered
    refused: list = field(default_factory=list)    # [lane, ...]
    entries: list = field(default_factory=list)    # [Entry, ...] every entry checked this step
    active_set: str = "itha"
    lead_target: str = ""             # "C" (the active set) | "follow" (F_R: behind the lead, own lane) | ""
    in_invariant_set: bool = True     # the state lies in the composed invariant set
    admissible_acceleration: list = field(default_factory=list)   # at the applied lateral input
    admissible_lateral: list = field(default_factory=list)        # at the applied acceleration
    clipped_to_model: bool = False    # the only change is a clip to the guardian's modelling bounds

    @property
    def overridden(self) -> bool:
        return self.changed != "none"

    def note(self, reason: str) -> None:
        if reason and reason not in self.reasons:
            self.reasons.append(reason)
