"""The guardian service's HTTP API: the requests it takes and the routes (no I/O; ``app`` serves them).

    GET    /health                -> 200 liveness and counts
    GET    /ready                 -> 200 when every worker is warmed up and none is stopping, else 503
    GET    /sessions              -> 200 every live session (admin token only)
    POST   /sessions              a two-car session: {"use_intention": true, "horizon": 10,
                                  "priority": ["throttle", "steering"]}, or a scene session: {"kind": "scene",
                                  "road": ..., "vehicle": ..., "guardian": ...} (guardian.service.scene)
                                  -> 201 {"session": ID, "secret": SECRET, "next_seq": 0, ...}
    POST   /sessions/ID/step      two-car: {"seq": N, "state": [v_ex, y_e, h, v_Lx], "input": [a_ex, v_ey]};
                                  scene: {"seq": N, "ego": ..., "cars": [...], "input": [a, steering]}
                                  -> 200 the step record ("t" is N)
    POST   /sessions/ID/lane_change  scene sessions: {"ego", "cars", "to": LANE} -> 200 {"allowed", "reason"}
    GET    /sessions/ID           -> 200 {"session", "kind", "steps", "next_seq", ...}
    DELETE /sessions/ID           -> 200 {"closed": ID}
    GET    /sessions/ID/stream    WebSocket: each text message a step body, each reply its record, in order
    GET    /openapi.json, /docs   the contract (OpenAPI 3.1) and its reference page, served from the package

A session's requests carry its secret (``Session-Secret``). Every answer is JSON; every error is
``{"error": message, ...}`` with the status the OpenAPI document lists for it (``openapi.py``).
"""
from __future__ import annotations

import ipaddress
import json
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictInt, ValidationError, field_validator

from guardian.service.limits import Limits, json_cost_error
from guardian.service.sessions import ServiceError

Finite = Annotated[float, Field(strict=True, allow_inf_nan=False)]


class SessionSettings(BaseModel):
    """Body of ``POST /sessions`` for a two-car session; every field optional."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["two_car"] = "two_car"
    use_intention: StrictBool = True
    horizon: StrictInt = Field(10, ge=1, le=1000)
    priority: tuple[Literal["throttle", "steering"], Literal["throttle", "steering"]] = ("throttle", "steering")

    @field_validator("priority")
    @classmethod
    def _both_inputs(cls, v):
        if v[0] == v[1]:
            raise ValueError("priority must order 'throttle' and 'steering', each once")
        return v


class StepRequest(BaseModel):
    """Body of one step: its sequence number, the state ``x = (v_ex, y_e, h, v_Lx)`` and the driver's
    input ``(a_ex, v_ey)``."""

    model_config = ConfigDict(extra="forbid")
    seq: StrictInt = Field(ge=0, le=2 ** 62)
    state: tuple[Finite, Finite, Finite, Finite]
    input: tuple[Finite, Finite]


@dataclass
class Response:
    status: int
    body: bytes
    headers: tuple = ()
    close: bool = False
    content_type: bytes = b"application/json"


def json_response(status: int, body: dict, headers=(), close: bool = False) -> Response:
    return Response(status, json.dumps(body).encode(), tuple(headers), close)


def error(status: int, message: str, headers=(), close: bool = False, **extra) -> Response:
    return json_response(status, {"error": message, **extra}, headers, close)


def service_error(exc: ServiceError) -> Response:
    headers = (("retry-after", str(int(exc.extra["retry_after_s"]))),) if "retry_after_s" in exc.extra else ()
    return json_response(exc.status, exc.body(), headers)


def _validation_message(errors) -> str:
    parts = []
    for e in errors:
        loc = [str(p) for p in e.get("loc", ())]
        parts.append((f"field {'.'.join(loc)!r}: " if loc else "") + e.get("msg", "invalid"))
    return "; ".join(parts)


def is_scene(raw: bytes, limits: Limits) -> bool:
    """Does a ``POST /sessions`` body ask for a scene session (``"kind": "scene"``)? Bodies that are not a JSON
    object are left to the two-car parser, which says what is wrong."""
    if json_cost_error(raw, limits):
        return False
    try:
        body = json.loads(raw)
    except ValueError:
        return False
    return isinstance(body, dict) and body.get("kind") == "scene"


def parse_body(model, raw: bytes, limits: Limits):
    """``raw`` checked for cost, then validated as ``model`` by pydantic's own JSON parser.

    Errors: 400 (too deep, a number too long, not JSON) or 422 (not the schema).
    """
    problem = json_cost_error(raw, limits)
    if problem:
        raise ServiceError(400, problem)
    try:
        return model.model_validate_json(raw)
    except ValidationError as exc:
        errors = exc.errors()
        if any(e.get("type") == "json_invalid" for e in errors):
            raise ServiceError(400, "malformed JSON body: " + _validation_message(errors)) from None
        raise ServiceError(422, _validation_message(errors)) from None


# ---- routes ----------------------------------------------------------------------------------------

ALLOWED = {"health": ("GET", "HEAD"), "ready": ("GET", "HEAD"), "sessions": ("GET", "HEAD", "POST"),
           "session": ("GET", "HEAD", "DELETE"), "step": ("POST",), "lane_change": ("POST",), "stream": ("GET",),
           "openapi": ("GET", "HEAD"), "docs": ("GET", "HEAD")}
_FIXED = {"/health": "health", "/ready": "ready", "/sessions": "sessions", "/openapi.json": "openapi",
          "/docs": "docs"}


def route(path: str) -> tuple[str, str | None] | None:
    """``(route name, session id)`` of a path, or None."""
    name = _FIXED.get(path)
    if name is not None:
        return name, None
    parts = path.split("/")
    if len(parts) >= 3 and parts[0] == "" and parts[1] == "sessions" and parts[2]:
        if len(parts) == 3:
            return "session", parts[2]
        if len(parts) == 4 and parts[3] in ("step", "lane_change", "stream"):
            return parts[3], parts[2]
    return None


def session_of(target: str) -> str | None:
    """The session id a request target names, if any (for routing a connection to its worker)."""
    if not target.startswith("/sessions/"):
        return None
    sid = target[10:].split("/", 1)[0].split("?", 1)[0]
    return sid or None


def is_loopback_host(value: str) -> bool:
    """Is a ``Host`` header's host a loopback name (``localhost``, 127.0.0.0/8, ``[::1]``)?"""
    host = value.strip().lower()
    if host.startswith("["):
        host = host[1:host.find("]")] if "]" in host else host
    elif host.count(":") == 1:
        host = host.split(":", 1)[0]
    if host in ("localhost", "localhost.") or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
