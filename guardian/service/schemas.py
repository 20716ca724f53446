"""The JSON schemas of the service's answers (the records of both session kinds, the session, the listing,
health, readiness): written out, since the records are dicts, not models. ``openapi`` puts them in the document."""
from __future__ import annotations

from guardian.model.decision import LEVELS

NUMBER = {"type": "number"}
COUNT = {"type": "integer", "minimum": 0}
SLOT = {"type": "integer", "minimum": 0, "description": "A lane slot: 0 the leftmost lane."}


def _pair(description: str) -> dict:
    return {"type": "array", "prefixItems": [NUMBER, NUMBER], "minItems": 2, "maxItems": 2,
            "items": False, "description": description}


def schema_ref(name: str) -> dict:
    return {"$ref": f"#/components/schemas/{name}"}


RECORD = {
    "type": "object", "additionalProperties": False,
    "description": "What the guardian of a two-car session did at one step (guardian.decide.lead.GuardianRecord).",
    "required": ["t", "state", "proposed", "applied", "overridden", "changed", "active_set", "valid_intentions",
                 "identified", "in_invariant_set", "failsafe", "admissible", "throttle_range", "steering_range"],
    "properties": {
        "t": {"type": "integer", "minimum": 0, "description": "The step's sequence number (its seq)."},
        "state": {"type": "array", "items": NUMBER, "minItems": 4, "maxItems": 4,
                  "description": "x = (v_ex, y_e, h, v_Lx) as received."},
        "proposed": _pair("The driver's input (a_ex, v_ey)."),
        "applied": _pair("The input to apply: the driver's if admissible, else the nearest admissible one "
                         "by priority, else the fail-safe (-3, 0); always inside U_e."),
        "overridden": {"type": "boolean"},
        "changed": {"enum": ["none", "throttle", "steering", "both", "failsafe"]},
        "active_set": {"enum": ["bounded_velocity", "aggressive", "cautious"],
                       "description": "The RCIS whose supervisor is in use (C_bnd until one intention is left)."},
        "valid_intentions": {"type": "array", "items": {"enum": ["aggressive", "cautious"]}},
        "identified": {"enum": ["aggressive", "cautious", None]},
        "in_invariant_set": {"type": "boolean", "description": "x is in the active set: Theorem 4 applies."},
        "failsafe": {"type": "boolean", "description": "S(x) was empty: the fail-safe input was applied."},
        "admissible": {"type": "array", "description": "S(x) as convex polygons, vertices (a_ex, v_ey).",
                       "items": {"type": "array", "items": _pair("A vertex.")}},
        "throttle_range": {"type": "array", "items": _pair("An interval of admissible a_ex."),
                           "description": "Admissible a_ex at the proposed v_ey (one interval per polygon)."},
        "steering_range": {"type": "array", "items": _pair("An interval of admissible v_ey."),
                           "description": "Admissible v_ey at the proposed a_ex (one interval per polygon)."},
    },
}

_COVERED = {
    "ego": "The ego's transition since the last step is not the vehicle model's (the bicycle's speed and progress, "
           "or the point mass's (6.3)-(6.4) with its noise box).",
    "traffic": "Cars (by id) whose transition since the last step is outside (7.3): progress dt v, acceleration "
               "within +-guardian.traffic_accel, speed in [0, v_max].",
    "traffic_reversing_uncovered": "Cars that backed up further than the guardian's cover (reverse_reach, reverse_horizon).",
    "lead": "Point mass only: the lead's next speed is explained by no intention model (6.5)/(6.7).",
}


def _coverage_counts(keys, description: str) -> dict:
    return {"type": "object", "additionalProperties": False, "description": description,
            "required": [k for k in keys if k != "lead"],
            "properties": {k: {**COUNT, "description": _COVERED[k]} for k in keys}}


SCENE_RECORD = {
    "type": "object", "additionalProperties": False,
    "description": "What the guardian of a scene session did at one step (guardian.service.scene.SceneGuardian.step; "
                   "lanes are slots, 0 the leftmost). Point-mass sessions add the overtake state and the lead's "
                   "coverage; the texts in reasons and entries[].reason are the decision object's own.",
    "required": ["t", "applied", "proposed", "overridden", "safety_override", "changed", "level", "failsafe", "reasons",
                 "lanes", "entered", "refused", "touched", "entries", "in_invariant_set", "clipped_to_model",
                 "admissible_acceleration", "coverage", "model"],
    "properties": {
        "t": {"type": "integer", "minimum": 0, "description": "The step's sequence number (its seq)."},
        "applied": _pair("The input to apply (bicycle [acceleration m/s^2, steering rad], point mass [a_ex, v_ey])."),
        "proposed": _pair("The input the step proposed."),
        "overridden": {"type": "boolean", "description": "applied differs from proposed (changed is not none)."},
        "safety_override": {"type": "boolean",
                            "description": "Overridden for safety, not only clipped to the model's bounds."},
        "changed": {"enum": ["none", "throttle", "steering", "both", "lane_change", "conflict", "failsafe"]},
        "level": {"enum": list(LEVELS), "description": "The guarantees kept (guardian.model.decision.LEVELS): "
                                                      "composed, then giving up parts in this order."},
        "failsafe": {"type": "boolean", "description": "No input keeps self-safety: the hardest braking the model "
                                                        "allows, steering back towards the ego's lane."},
        "reasons": {"type": "array", "items": {"type": "string"}, "description": "Why the input was changed."},
        "lanes": {"type": "array", "items": SLOT,
                  "description": "Every lane the body may overlap during the step (held or entered responsibly)."},
        "entered": {"type": "array", "items": SLOT, "description": "Lanes the applied input may enter (checked)."},
        "refused": {"type": "array", "items": SLOT,
                    "description": "Lanes the proposed input would have entered; the guardian kept the body out."},
        "touched": {"type": "array", "items": SLOT,
                    "description": "Lanes the body overlaps without holding them (their entry refused)."},
        "entries": {"type": "array", "description": "Every lane entry judged this step ((7.5) responsibility).",
                    "items": {"type": "object", "additionalProperties": False,
                              "required": ["lane", "responsible", "reason"],
                              "properties": {"lane": SLOT, "responsible": {"type": "boolean"},
                                             "reason": {"type": "string"}}}},
        "in_invariant_set": {"type": "boolean", "description": "Some input keeps every part of the admissible set."},
        "clipped_to_model": {"type": "boolean", "description": "The only change is a clip to the model's bounds."},
        "admissible_acceleration": {"type": "array", "items": _pair("An interval of admissible acceleration."),
                                    "description": "Admissible accelerations at the applied lateral input."},
        "coverage": {**_coverage_counts(("ego", "traffic", "traffic_reversing_uncovered", "lead"),
                                        "Transitions since the last step the model does not cover "
                                        "(guardian.decide.coverage); totals: since the session began."),
                     "required": ["ego", "traffic", "traffic_reversing_uncovered", "totals"]},
        "model": schema_ref("SceneModel"),
        "state": {"type": "array", "items": NUMBER, "minItems": 4, "maxItems": 4,
                  "description": "Point mass only: the overtake state x = (v_ex, y_e, h, v_Lx) the step decided on."},
    },
}
SCENE_RECORD["properties"]["coverage"]["properties"]["totals"] = _coverage_counts(
    ("ego", "traffic", "traffic_reversing_uncovered", "lead"), "The counts summed over the session's steps.")

_COMMON_SUMMARY = {
    "session": {"type": "string", "pattern": r"^[a-z0-9][a-z0-9-]*\.[0-9]+\.[0-9a-z]+\.[0-9a-f]{16}$",
                "description": "NODE.WORKER.BOOT.RANDOM: where the session lives."},
    "steps": {"type": "integer", "minimum": 0},
    "next_seq": {"type": "integer", "minimum": 0, "description": "The seq the next step must carry."},
    "idle_s": NUMBER,
    "streaming": {"type": "boolean", "description": "A stream is attached (HTTP steps get 409)."},
}
_TWO_CAR_SUMMARY = {
    **_COMMON_SUMMARY,
    "kind": {"const": "two_car"},
    "active_set": RECORD["properties"]["active_set"],
    "valid_intentions": RECORD["properties"]["valid_intentions"],
    "use_intention": {"type": "boolean"},
    "horizon": {"type": "integer", "minimum": 1},
    "priority": {"type": "array", "items": {"enum": ["throttle", "steering"]}, "minItems": 2, "maxItems": 2},
    "last": {"oneOf": [schema_ref("Record"), {"type": "null"}]},
}
_SCENE_SUMMARY = {
    **_COMMON_SUMMARY,
    "kind": {"const": "scene"},
    "model": schema_ref("SceneModel"),
    "last": {"oneOf": [schema_ref("SceneRecord"), {"type": "null"}]},
}
_SECRET = {"type": "string", "description": "Send it as Session-Secret; shown this once."}


def _object(props: dict, description: str = "") -> dict:
    out = {"type": "object", "additionalProperties": False, "required": list(props), "properties": props}
    return {**out, "description": description} if description else out


SCHEMAS = {
    "Record": RECORD,
    "SceneRecord": SCENE_RECORD,
    "SceneModel": {"type": "object", "additionalProperties": False, "required": ["vehicle", "guardian"],
                   "description": "The model and parameters that decide (the session's vehicle and guardian "
                                  "options, defaults filled in).",
                   "properties": {"vehicle": schema_ref("VehicleSpec"), "guardian": schema_ref("GuardianSpec")}},
    "TwoCarSession": _object(_TWO_CAR_SUMMARY, "A two-car session (Chapter 6's overtake pair)."),
    "SceneSession": _object(_SCENE_SUMMARY, "A scene session (an ego among traffic)."),
    "Session": {"oneOf": [schema_ref("TwoCarSession"), schema_ref("SceneSession")]},
    "CreatedSession": {"oneOf": [_object({**_TWO_CAR_SUMMARY, "secret": _SECRET}, "A new two-car session."),
                                 _object({**_SCENE_SUMMARY, "secret": _SECRET}, "A new scene session.")]},
    "LaneChange": _object({"allowed": {"type": "boolean"},
                           "reason": {"type": "string", "description": "Why not (empty when allowed)."}},
                          "May the ego begin this lane change now ((7.5) responsibility of the entry)?"),
    "SessionList": {"type": "object", "additionalProperties": False, "required": ["sessions"], "properties": {
        "sessions": {"type": "array", "items": _object(
            {"session": _COMMON_SUMMARY["session"], "kind": {"enum": ["two_car", "scene"]},
             "steps": _COMMON_SUMMARY["steps"], "idle_s": NUMBER, "streaming": _COMMON_SUMMARY["streaming"]})},
        "workers_missing": {"type": "array", "items": {"type": "integer"},
                            "description": "Workers that did not answer within 2 s."}}},
    "Closed": {"type": "object", "additionalProperties": False, "required": ["closed"],
               "properties": {"closed": {"type": "string"}}},
    "Health": {"type": "object", "additionalProperties": False,
               "required": ["status", "node", "worker", "workers", "sessions", "expired", "closed", "created",
                            "max_sessions", "session_ttl_s"],
               "properties": {"status": {"const": "ok"}, "node": {"type": "string"}, "worker": {"type": "integer"},
                              "workers": {"type": "integer"}, "workers_alive": {"type": "integer"},
                              "sessions": {"type": "integer"}, "expired": {"type": "integer"},
                              "closed": {"type": "integer"}, "created": {"type": "integer"},
                              "max_sessions": {"type": "integer", "description": "Per worker."},
                              "session_ttl_s": NUMBER}},
    "Ready": {"type": "object", "additionalProperties": False, "required": ["ready", "workers_ready", "workers"],
              "properties": {"ready": {"const": True}, "workers_ready": {"type": "integer"},
                             "workers": {"type": "integer"}}},
    "Error": {"type": "object", "additionalProperties": False, "required": ["error"], "properties": {
        "error": {"type": "string", "description": "What was wrong, naming the field, value or limit."},
        "expected_seq": {"type": "integer", "description": "409: the seq the session expects next."},
        "streaming": {"const": True, "description": "409: a stream is attached to the session (one writer)."},
        "expired": {"const": True, "description": "410: the session expired (idle longer than the TTL)."},
        "restarted": {"const": True, "description": "410: the process that held the session restarted."},
        "node": {"type": "string", "description": "421: the node the session lives on."},
        "worker": {"type": "integer", "description": "421: the worker the session lives on (a request pipelined "
                                                    "behind another worker's on one connection)."},
        "retry_after_s": {"type": "number", "description": "503 session limit: when idle sessions expire."},
        "ready": {"const": False}, "workers_ready": {"type": "integer"}, "workers": {"type": "integer"}}},
}
