"""What the wrapper reports for one policy step: ``info["guardian"]``, as typed records.

``CarRecord`` is one guarded car's policy step, made from the decisions of its simulation steps
(``CarRecord.of``); ``FleetRecord`` holds every car's record and their sum when several cars are guarded.
``as_dict`` gives the dictionary ``info["guardian"]`` holds (its keys are listed in
``guardian.wrappers.guardian``'s docstring and in docs/guardian.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from guardian.adapters.highway_env.monitor import COUNTS as MONITOR_COUNTS
from guardian.model.decision import LEVELS

META = "DiscreteMetaAction"
SUMMED = ("clipped_steps", "model_clip_steps", "follower_dropped_steps", "conflict_steps", "failsafe_steps",
          "unsupervised_steps")


def allowed_lanes(decisions) -> list:
    """The lanes a car's body was allowed to overlap over one policy step: those its first decision held
    (where the body was, and entries judged before) and every lane entered responsibly during the step.

    Not the lanes of every decision: a later decision starts where the body is, so a lane the body reached
    in between without an entry would look held (``unchecked_entries`` counts exactly those)."""
    if not decisions:
        return []
    return sorted(set(decisions[0].lanes) | {lane for d in decisions for lane in d.entered})


@dataclass
class CarRecord:
    """One guarded car over one policy step (the fields of ``info["guardian"]``)."""

    proposed: object
    applied: object
    applied_action: object
    applied_mean: list
    applied_range: list
    overridden: bool
    safety_override: bool
    changed: str
    level: str
    reasons: list
    refused_lane_change: bool
    entered: list
    lanes: list
    active_set: str
    valid_intentions: list
    identified: str | None
    in_invariant_set: bool
    admissible_acceleration: list
    admissible_lateral: list
    sim_steps: int
    clipped_steps: int
    model_clip_steps: int
    follower_dropped_steps: int
    conflict_steps: int
    failsafe_steps: int
    unsupervised_steps: int
    reattached: bool
    model_violations: dict
    proposed_input: list | None = None   # the input of the last simulation step (shown for meta agents)
    applied_input: list | None = None

    @classmethod
    def of(cls, car, kind: str, proposed, notes: list, reattached: bool, unsupervised: int) -> "CarRecord":
        """The record of ``car``'s policy step from its decisions (``car.decisions``); ``notes`` are the
        wrapper's own reasons (a re-attachment)."""
        ds = car.decisions
        last = ds[-1] if ds else None
        meta = kind == META
        reasons = list(notes)
        if car.refused_meta:
            reasons.append(car.refused_meta)
        for d in ds:
            for r in d.reasons:
                if r not in reasons:
                    reasons.append(r)
        if unsupervised:
            reasons.append(f"{unsupervised} simulation steps ran without the guardian")
        changed = "none"
        for d in ds:
            if d.changed != "none":
                changed = d.changed
        refused = bool(car.refused_meta) or any(d.refused for d in ds)
        if refused and changed in ("none", "steering"):
            changed = "lane_change" if meta else changed
        inputs = np.array([d.applied for d in ds], dtype=float).reshape(-1, 2)
        action = applied_action(car, kind, proposed, ds, inputs)
        applied = proposed
        if meta:  # the meta action executed over the whole policy step
            applied = car.action_type.actions[action]
        elif last is not None:
            applied, proposed = last.applied, last.proposed
        clipped = sum(d.changed != "none" for d in ds)
        model_clips = sum(d.changed != "none" and d.clipped_to_model for d in ds)
        lead = getattr(car.guard, "lead", None)
        return cls(
            proposed=proposed, applied=applied, applied_action=action,
            applied_mean=inputs.mean(axis=0).tolist() if len(ds) else [],
            applied_range=[[float(inputs[:, k].min()), float(inputs[:, k].max())] for k in range(2)] if len(ds) else [],
            overridden=bool(clipped or refused), safety_override=bool(clipped - model_clips or refused),
            changed=changed, level=LEVELS[max((LEVELS.index(d.level) for d in ds), default=0)],
            reasons=reasons, refused_lane_change=refused,
            entered=sorted({lane for d in ds for lane in d.entered}), lanes=allowed_lanes(ds),
            active_set=last.active_set if last else "itha",
            valid_intentions=list(lead.estimator.valid) if lead else [],
            identified=lead.identified if lead else None,
            in_invariant_set=bool(ds[0].in_invariant_set) if ds else True,
            admissible_acceleration=last.admissible_acceleration if last else [],
            admissible_lateral=last.admissible_lateral if last else [],
            sim_steps=len(ds), clipped_steps=clipped, model_clip_steps=model_clips,
            follower_dropped_steps=sum(d.level == "follower_dropped" for d in ds),
            conflict_steps=sum(d.level == "conflict" for d in ds),
            failsafe_steps=sum(d.level == "failsafe" for d in ds),
            unsupervised_steps=unsupervised, reattached=reattached, model_violations=dict(car.monitor_counts),
            proposed_input=last.proposed if last else None, applied_input=last.applied if last else None)

    def as_dict(self, inputs: bool) -> dict:
        """``info["guardian"]``; ``inputs``: with ``proposed_input`` and ``applied_input`` (meta agents)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        if not inputs:
            del out["proposed_input"], out["applied_input"]
        return out


@dataclass
class FleetRecord:
    """Several guarded cars over one policy step: each car's record and their sum."""

    agents: list                    # CarRecord per car, in highway-env's controlled order
    overapprox: str
    order: list                     # the announcing order of the last simulation step (car numbers)
    applied_action: tuple
    meta: bool = field(default=False)

    def as_dict(self) -> dict:
        records = [r.as_dict(self.meta) for r in self.agents]
        out = {"agents": records, "controlled": len(records), "overapprox": self.overapprox,
               "order": list(self.order), "applied_action": tuple(r["applied_action"] for r in records),
               "overridden": any(r["overridden"] for r in records),
               "safety_override": any(r["safety_override"] for r in records),
               "refused_lane_change": any(r["refused_lane_change"] for r in records),
               "reattached": any(r["reattached"] for r in records),
               "level": LEVELS[max(LEVELS.index(r["level"]) for r in records)],
               "reasons": [f"car {i}: {reason}" for i, r in enumerate(records) for reason in r["reasons"]],
               "sim_steps": max(r["sim_steps"] for r in records),
               "model_violations": {k: sum(r["model_violations"][k] for r in records) for k in MONITOR_COUNTS}}
        out.update({k: sum(r[k] for r in records) for k in SUMMED})
        return out


def applied_action(car, kind: str, proposed, ds, inputs):
    """What the vehicle did over the policy step, as an action of the env's own space (so a learner can
    relabel what it proposed): the meta action executed (a refused lane change is ``IDLE``, an acceleration
    held below the proposal ``SLOWER``), or the mean applied input in the action's normalised coordinates
    (a ``DiscreteAction``: the nearest of its grid)."""
    at = car.action_type
    if kind == META:
        name = "IDLE" if car.refused_meta or any(d.refused for d in ds) else proposed
        if any(d.applied[0] < d.proposed[0] - 1e-9 and not d.clipped_to_model for d in ds):
            name = "SLOWER"
        return int(at.actions_indexes[name])
    if not len(ds):
        return None
    mean = inputs.mean(axis=0)
    axes = [(0, at.acceleration_range)] * at.longitudinal + [(1, at.steering_range)] * at.lateral
    unit = np.array([np.clip(2 * (mean[k] - lo) / (hi - lo) - 1, -1.0, 1.0) for k, (lo, hi) in axes])
    if type(at).__name__ == "DiscreteAction":
        grid = np.linspace(-1.0, 1.0, at.actions_per_axis)
        index = 0
        for value in unit:  # itertools.product's order: the first axis varies slowest
            index = index * at.actions_per_axis + int(np.argmin(np.abs(grid - value)))
        return index
    return unit.astype(np.float32).tolist()


def penalised(reward: float, info: dict, records: list, per_override: float) -> float:
    """``GuardianConfig.override_penalty``: the reward less ``per_override`` for every car overridden for
    safety in the step (a clip to the modelling bounds is not one), noted as ``info["penalty"]``."""
    overridden = sum(r.safety_override for r in records)
    if not (per_override and overridden):
        return reward
    info["penalty"] = per_override * overridden
    return reward - info["penalty"]

