"""The service's contract: the OpenAPI 3.1 document (``/openapi.json``) and its reference page (``/docs``).

Written out here rather than derived from the routes, so that it can say everything the service
answers: each operation lists every status it can give, with the body's schema, including the
answers of the request reader and of the checks before any route (framing 400/414/431, 408, 401
token, 403 Host/Origin, 413, 415, 503 connection limit, ...). ``tests/guardian/service/test_service_contract.py``
sends requests that produce each answer and validates every response against this document with
openapi-core, and the document itself with openapi-spec-validator. ``/docs`` is static HTML rendered
from the document: no script, no stylesheet from elsewhere, so it works offline.
"""
from __future__ import annotations

import html
import json
from functools import lru_cache

NUMBER = {"type": "number"}


def _pair(description: str) -> dict:
    return {"type": "array", "prefixItems": [NUMBER, NUMBER], "minItems": 2, "maxItems": 2,
            "items": False, "description": description}


RECORD = {
    "type": "object", "additionalProperties": False,
    "description": "What the guardian did at one step (guardian.decide.lead.GuardianRecord).",
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

_SUMMARY_PROPS = {
    "session": {"type": "string", "pattern": r"^[a-z0-9][a-z0-9-]*\.[0-9]+\.[0-9a-z]+\.[0-9a-f]{16}$",
                "description": "NODE.WORKER.BOOT.RANDOM: where the session lives."},
    "steps": {"type": "integer", "minimum": 0},
    "next_seq": {"type": "integer", "minimum": 0, "description": "The seq the next step must carry."},
    "active_set": RECORD["properties"]["active_set"],
    "valid_intentions": RECORD["properties"]["valid_intentions"],
    "use_intention": {"type": "boolean"},
    "horizon": {"type": "integer", "minimum": 1},
    "priority": {"type": "array", "items": {"enum": ["throttle", "steering"]}, "minItems": 2, "maxItems": 2},
    "idle_s": NUMBER,
    "streaming": {"type": "boolean", "description": "A stream is attached (HTTP steps get 409)."},
    "last": {"oneOf": [{"$ref": "#/components/schemas/Record"}, {"type": "null"}]},
}

SCHEMAS = {
    "Record": RECORD,
    "Session": {"type": "object", "additionalProperties": False, "required": list(_SUMMARY_PROPS),
                "properties": _SUMMARY_PROPS},
    "CreatedSession": {"type": "object", "additionalProperties": False, "required": [*_SUMMARY_PROPS, "secret"],
                       "properties": {**_SUMMARY_PROPS, "secret": {
                           "type": "string", "description": "Send it as Session-Secret; shown this once."}}},
    "SessionList": {"type": "object", "additionalProperties": False, "required": ["sessions"], "properties": {
        "sessions": {"type": "array", "items": {
            "type": "object", "additionalProperties": False,
            "required": ["session", "steps", "idle_s", "active_set", "streaming"],
            "properties": {k: _SUMMARY_PROPS[k] for k in ("session", "steps", "idle_s", "active_set", "streaming")}}},
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
        "expired": {"const": True, "description": "410: the session expired (idle longer than the TTL)."},
        "restarted": {"const": True, "description": "410: the process that held the session restarted."},
        "node": {"type": "string", "description": "421: the node the session lives on."},
        "retry_after_s": {"type": "number", "description": "503 session limit: when idle sessions expire."},
        "ready": {"const": False}, "workers_ready": {"type": "integer"}, "workers": {"type": "integer"}}},
}

_ERRORS = {
    "400": "Malformed: a framing error of the request (then Connection: close), malformed JSON, JSON nested "
           "deeper than 32 or a number longer than 40 characters, NaN or Infinity.",
    "401": "Missing or wrong token (only when the service has one): send Authorization: Bearer TOKEN.",
    "403": "Host is not a loopback name (loopback service), Origin is not allowed (--allow-origin), a missing "
           "or wrong Session-Secret, or a listing without the admin token.",
    "404": "No such path, or an unknown session.",
    "405": "Method not allowed on this path; Allow lists the methods.",
    "408": "The request did not arrive whole within --read-timeout of its first byte (Connection: close).",
    "409": "Sequence conflict (a gap, an older step, or the last step with another body; expected_seq "
           "says which is next), or the session has a stream attached (one writer).",
    "410": "The session expired (expired: true), or the process that held it restarted (restarted: true).",
    "411": "A POST without Content-Length or chunked Transfer-Encoding.",
    "413": "The body is longer than --max-body (refused from Content-Length, or as soon as chunks exceed it).",
    "414": "The request target is longer than 8 KiB, or the request line than the head limit.",
    "415": "A POST whose Content-Type is not application/json (Accept-Post says which is).",
    "417": "An Expect other than 100-continue.",
    "421": "The session lives on another node: route /sessions/NODE.* to that node.",
    "422": "The body does not match the schema (the field is named), or the state is outside the model's "
           "domain (v_ex < 0, or v_Lx outside the lead model's range).",
    "426": "The stream path without a WebSocket handshake.",
    "431": "More than 100 header fields, or a request head over 16 KiB.",
    "500": "A bug: logged by the service (Connection: close).",
    "501": "A Transfer-Encoding other than chunked.",
    "503": "The connection limit (sent at connect, then closed), the session limit (retry_after_s), or "
           "/ready while warming up, restarting a worker or stopping.",
    "505": "An HTTP version other than 1.1 and 1.0.",
}
_ALWAYS = ["400", "401", "403", "408", "414", "417", "431", "500", "501", "503", "505"]
_RETRY_AFTER = {"Retry-After": {"schema": {"type": "string"}, "description": "Seconds."}}


def _error(code: str, headers: dict | None = None) -> dict:
    out = {"description": _ERRORS[code], "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}}}
    if headers:
        out["headers"] = headers
    return out


def _ok(description: str, schema: str) -> dict:
    return {"description": description, "content": {"application/json": {"schema": {"$ref": f"#/components/schemas/{schema}"}}}}


def _responses(ok: dict, *codes: str) -> dict:
    out = dict(ok)
    for code in sorted(set(_ALWAYS) | set(codes)):
        headers = None
        if code == "405":
            headers = {"Allow": {"schema": {"type": "string"}, "description": "The methods this path allows."}}
        elif code == "401":
            headers = {"WWW-Authenticate": {"schema": {"type": "string"}}}
        elif code == "415":
            headers = {"Accept-Post": {"schema": {"type": "string"}}}
        elif code == "503":
            headers = _RETRY_AFTER
        out[code] = _error(code, headers)
    return out


SID = {"name": "sid", "in": "path", "required": True, "schema": {"type": "string"},
       "description": "The session id returned by POST /sessions."}
SECRET = [{"sessionSecret": []}, {"sessionSecret": [], "bearer": []}]
SECRET_OR_ADMIN = [*SECRET, {"bearer": []}]
OPEN = [{}, {"bearer": []}]


def _body(schema: dict, required: bool) -> dict:
    return {"required": required, "content": {"application/json": {"schema": schema}}}


@lru_cache(maxsize=1)
def document() -> dict:
    """The OpenAPI 3.1 document of the service."""
    from guardian.service.api import SessionSettings, StepRequest

    settings_schema = SessionSettings.model_json_schema()
    step_schema = StepRequest.model_json_schema()
    return {
        "openapi": "3.1.0",
        "info": {"title": "guardian", "version": "3",
                 "description": "The intention-aware safety supervisor of Chapter 6 as a service: one guardian "
                                "per session. Steps carry sequence numbers (a retry is answered from the stored "
                                "answer, a gap gets 409); a session's secret is required to step, read or delete "
                                "it. See docs/service.md."},
        "components": {
            "schemas": SCHEMAS,
            "securitySchemes": {
                "bearer": {"type": "http", "scheme": "bearer",
                           "description": "The service token (guardian serve --token), required on every request "
                                          "when set; or the admin token (--admin-token), which also lists every "
                                          "session and may read or delete any."},
                "sessionSecret": {"type": "apiKey", "in": "header", "name": "Session-Secret",
                                  "description": "The secret POST /sessions returned for this session."}},
        },
        "security": OPEN,
        "paths": {
            "/health": {"get": {"operationId": "health", "summary": "Liveness and counts (all workers).",
                                "responses": _responses({"200": _ok("Alive.", "Health")}, "405")}},
            "/ready": {"get": {"operationId": "ready",
                               "summary": "200 when every worker is warmed up and none is stopping, else 503.",
                               "responses": _responses({"200": _ok("Ready for traffic.", "Ready")}, "405")}},
            "/sessions": {
                "get": {"operationId": "listSessions", "summary": "Every live session (admin token only).",
                        "security": [{"bearer": []}],
                        "responses": _responses({"200": _ok("The sessions of every worker.", "SessionList")}, "405")},
                "post": {"operationId": "createSession", "summary": "A new session (its guardian and secret).",
                         "requestBody": _body(settings_schema, False),
                         "responses": _responses({"201": _ok("Created; the secret is shown this once.",
                                                             "CreatedSession")},
                                                 "405", "411", "413", "415", "422")}},
            "/sessions/{sid}": {
                "parameters": [SID],
                "get": {"operationId": "getSession", "summary": "The session's state and last record.",
                        "security": SECRET_OR_ADMIN,
                        "responses": _responses({"200": _ok("The session.", "Session")},
                                                "404", "405", "410", "421")},
                "delete": {"operationId": "deleteSession", "summary": "End the session (its stream closes, 4404).",
                           "security": SECRET_OR_ADMIN,
                           "responses": _responses({"200": _ok("Closed.", "Closed")}, "404", "405", "410", "421")}},
            "/sessions/{sid}/step": {
                "parameters": [SID],
                "post": {"operationId": "step", "summary": "Supervise one step (seq = the session's next_seq).",
                         "security": SECRET, "requestBody": _body(step_schema, True),
                         "responses": _responses({"200": _ok("The record (also for a retry of the last step).",
                                                             "Record")},
                                                 "404", "405", "409", "410", "411", "413", "415", "421", "422")}},
            "/sessions/{sid}/stream": {
                "parameters": [SID],
                "get": {"operationId": "stream",
                        "summary": "WebSocket: each message a step body, each reply its record or "
                                   "{\"error\", \"status\"}.",
                        "description": "Handshake refusals are HTTP answers: 401 token, 403 Host/Origin/secret, "
                                       "409 the session already has a stream. An unknown, expired, restarted or "
                                       "misrouted session is accepted, told {\"error\", \"status\"} and closed with "
                                       "4000 + status. A message over --max-body gets {\"status\": 413} and the "
                                       "stream stays open; one over 16 x --max-body closes it with 1009. No message "
                                       "for --stream-idle-timeout: closed 4408.",
                        "security": SECRET,
                        "responses": {"101": {"description": "Switching Protocols: the stream is open."},
                                      **{k: v for k, v in _responses({}, "405", "409", "426").items()}}}},
            "/openapi.json": {"get": {"operationId": "openapi", "summary": "This document.",
                                      "responses": _responses({"200": {"description": "OpenAPI 3.1.", "content": {
                                          "application/json": {"schema": {"type": "object"}}}}}, "405")}},
            "/docs": {"get": {"operationId": "docs", "summary": "This document as a page (no scripts, offline).",
                              "responses": _responses({"200": {"description": "HTML.", "content": {
                                  "text/html": {"schema": {"type": "string"}}}}}, "405")}},
        },
    }


def _schema_html(schema) -> str:
    return f"<pre>{html.escape(json.dumps(schema, indent=2))}</pre>"


@lru_cache(maxsize=1)
def docs_html() -> str:
    """The reference page: every operation, its parameters, body and answers, from ``document()``."""
    doc = document()
    out = ["<!doctype html><html lang=en><head><meta charset=utf-8><title>guardian service API</title>",
           "<style>body{font:15px/1.45 system-ui,sans-serif;max-width:60em;margin:2em auto;padding:0 1em}"
           "code,pre{background:#f4f4f4}pre{padding:.5em;overflow:auto;font-size:12px}"
           "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:.2em .5em;vertical-align:top}"
           "h2{border-top:2px solid #333;padding-top:.5em}details{margin:.3em 0}</style></head><body>",
           f"<h1>{html.escape(doc['info']['title'])} API (version {html.escape(doc['info']['version'])})</h1>",
           f"<p>{html.escape(doc['info']['description'])}</p>",
           "<p>The machine-readable contract: <a href=\"openapi.json\">openapi.json</a> (OpenAPI 3.1).</p>",
           "<h2>Credentials</h2><ul>"]
    for name, scheme in doc["components"]["securitySchemes"].items():
        out.append(f"<li><b>{html.escape(name)}</b>: {html.escape(scheme['description'])}</li>")
    out.append("</ul>")
    for path, item in doc["paths"].items():
        for method, op in item.items():
            if method == "parameters":
                continue
            out.append(f"<h2 id=\"{html.escape(op['operationId'])}\"><code>{method.upper()} {html.escape(path)}</code></h2>")
            out.append(f"<p>{html.escape(op['summary'])}</p>")
            if "description" in op:
                out.append(f"<p>{html.escape(op['description'])}</p>")
            security = op.get("security", doc["security"])
            alternatives = [" + ".join(s) or "none" for s in security]
            out.append(f"<p>Credentials: {html.escape(' | '.join(alternatives))}</p>")
            if "requestBody" in op:
                schema = op["requestBody"]["content"]["application/json"]["schema"]
                req = "required" if op["requestBody"]["required"] else "optional"
                out.append(f"<details open><summary>Request body ({req}, application/json)</summary>"
                           f"{_schema_html(schema)}</details>")
            out.append("<table><tr><th>Status</th><th>Meaning</th><th>Body</th></tr>")
            for code, resp in op["responses"].items():
                content = resp.get("content", {})
                body = ", ".join(f"{t}: {c['schema'].get('$ref', '').rsplit('/', 1)[-1] or c['schema'].get('type', '')}"
                                 for t, c in content.items())
                out.append(f"<tr><td>{code}</td><td>{html.escape(resp['description'])}</td>"
                           f"<td>{html.escape(body)}</td></tr>")
            out.append("</table>")
    out.append("<h2>Schemas</h2>")
    for name, schema in doc["components"]["schemas"].items():
        out.append(f"<details><summary>{html.escape(name)}</summary>{_schema_html(schema)}</details>")
    out.append("</body></html>")
    return "".join(out)
