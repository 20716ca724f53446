"""The service's contract: the OpenAPI 3.1 document (``/openapi.json``) and its reference page (``/docs``).

Written out here rather than derived from the routes, so that it can say everything the service answers:
each operation lists every status it can give, with the body's schema and headers, including the answers
of the server's request reader (``protocol``: framing 400, 408, 413, 414, 417, 431, 501, 505, the 503 of the
connection cap) and of the checks before any route (``app.ServiceApp.check``: 400 for a repeated credential
header or an HTTP/1.1 request without Host, 401 token, 403 Host/Origin, the CORS preflight's 204, 405, 411,
415). The request bodies' schemas are pydantic's own (``model_json_schema`` of the models the routes parse
with: ``api.SessionSettings``, ``api.StepRequest`` and ``scene``'s), so the document cannot drift from what
is accepted; the vehicle is split by model into the fields each takes (``scene.MODEL_FIELDS``). The answers'
schemas are written out in ``schemas`` (the records are dicts, not models).

``tests/guardian/service/test_service_contract.py`` sends requests that produce every status listed for
every operation (and checks that no other was seen), validating each response against this document with
openapi-core, the accepted request bodies too, and the document itself with openapi-spec-validator.
``/docs`` is static HTML rendered from the document: no script, no stylesheet from elsewhere, so it works
offline.
"""
from __future__ import annotations

import html
import json
from functools import lru_cache

from guardian.service.schemas import SCHEMAS, schema_ref


_ERRORS = {
    "400": "Malformed: a framing error of the request ('invalid HTTP request: ...', then Connection: close), an "
           "HTTP/1.1 request without Host, a Host, Origin, Authorization, Session-Secret, Content-Type or "
           "Content-Length header given twice; or a body that is malformed JSON, nested deeper than 32, with a "
           "number longer than 40 characters, NaN or Infinity.",
    "401": "Missing or wrong token (only when the service has one): send Authorization: Bearer TOKEN.",
    "403": "Host is not a loopback name (loopback service), Origin is not allowed (--allow-origin), a missing "
           "or wrong Session-Secret, or a listing without the admin token.",
    "404": "An unknown session (any path this document does not list is answered 404 too).",
    "405": "A method this path does not have (listed under the path's first operation, and under OPTIONS for an "
           "OPTIONS that is not a CORS preflight); Allow lists the methods.",
    "408": "The request did not arrive whole within --read-timeout of its first byte (Connection: close).",
    "409": "Sequence conflict (a gap, an older step, or the last step with another body; expected_seq "
           "says which is next), or the session has a stream attached (streaming: true; one writer).",
    "410": "The session expired (expired: true), or the process that held it restarted (restarted: true).",
    "411": "A POST without Content-Length or chunked Transfer-Encoding.",
    "413": "The body is longer than --max-body (refused from Content-Length, on any method, or as soon as chunks "
           "exceed it; Connection: close).",
    "414": "The request target is longer than 8 KiB, or the request line than the head limit.",
    "415": "A POST whose Content-Type is not application/json (Accept-Post says which is).",
    "417": "An Expect other than 100-continue.",
    "421": "Misdirected: the session lives on another node (node: route /sessions/NODE.* to that node), or on "
           "another worker of this node and the request was pipelined behind another worker's request on the "
           "same connection (worker: send it on its own turn).",
    "422": "The body does not match the schema (the field is named), or it does and the guardian cannot "
           "guarantee it: a two-car state outside the model's domain (v_ex < 0, v_Lx outside the lead model's "
           "range); a vehicle model other than bicycle and point_mass, a field of the other model, bounds the "
           "service's sets were not computed for (point_mass: dt, acceleration, lateral_speed of its library, "
           "a library that lets the ego wait behind its lead, a straight road of >= 2 lanes whose lane_width "
           "is 2 left_lane_y lateral_scale; bicycle: max_acceleration = guardian.traffic_accel), a road that "
           "cannot be built; a step the model cannot take (a bicycle step naming a lead, a point-mass step "
           "without its lead or with ego fields it has not).",
    "426": "The stream path without a WebSocket handshake.",
    "431": "More than 100 header fields, or a request head over 16 KiB.",
    "500": "A bug: logged by the service (Connection: close).",
    "501": "A Transfer-Encoding other than chunked.",
    "503": "The connection limit (sent at connect, then closed), the session limit (retry_after_s), or "
           "/ready while warming up, restarting a worker or stopping.",
    "505": "An HTTP version other than 1.1 and 1.0.",
}
# answered by the reader and the checks before any route, whatever the operation
_ALWAYS = ["400", "401", "403", "408", "413", "414", "417", "431", "501", "503", "505"]
_RETRY_AFTER = {"Retry-After": {"schema": {"type": "string"}, "description": "Seconds."}}
_CORS = {"Access-Control-Allow-Origin": {"$ref": "#/components/headers/AllowOrigin"},
         "Vary": {"$ref": "#/components/headers/Vary"}}
HEADERS = {
    "AllowOrigin": {"schema": {"type": "string"},
                    "description": "The request's Origin, when it is allowed (--allow-origin)."},
    "Vary": {"schema": {"const": "Origin"}, "description": "With Access-Control-Allow-Origin."},
}


def _error(code: str, headers: dict | None = None) -> dict:
    return {"description": _ERRORS[code], "headers": {**(headers or {}), **_CORS},
            "content": {"application/json": {"schema": schema_ref("Error")}}}


def _ok(description: str, schema: dict | str) -> dict:
    return {"description": description, "headers": dict(_CORS),
            "content": {"application/json": {"schema": schema_ref(schema) if isinstance(schema, str) else schema}}}


def _responses(ok: dict, *codes: str, bug: bool = True) -> dict:
    """``ok`` and the errors: those of the checks before any route, ``codes``, and 500 when a route runs."""
    out = dict(ok)
    for code in sorted(set(_ALWAYS) | set(codes) | ({"500"} if bug else set())):
        headers = None
        if code == "405":
            headers = {"Allow": {"schema": {"type": "string"}, "description": "The methods this path allows."}}
        elif code == "401":
            headers = {"WWW-Authenticate": {"schema": {"type": "string"}}}
        elif code == "415":
            headers = {"Accept-Post": {"schema": {"type": "string"}}}
        elif code == "426":
            headers = {"Upgrade": {"schema": {"const": "websocket"}}}
        elif code == "503":
            headers = _RETRY_AFTER
        out[code] = _error(code, headers)
    return out


def _preflight(path: str) -> dict:
    """The CORS preflight of a path: answered before any route (no token needed), never a 500."""
    name = "preflight" + "".join(p.strip("{}").replace(".", "_").replace("_", " ").title().replace(" ", "")
                                 for p in path.split("/"))
    must = {"required": True}
    return {"operationId": name, "summary": "CORS preflight (a browser asks before a cross-origin request).",
            "description": "An OPTIONS with an allowed Origin and Access-Control-Request-Method is answered 204 with "
                           "the path's methods, the request headers a browser may send (authorization, "
                           "content-type, session-secret) and how long to remember them; a preflight from an "
                           "Origin not allowed gets 403, an OPTIONS that is not a preflight 405.",
            "security": [{}],
            "parameters": [{"name": "Origin", "in": "header", "required": True, "schema": {"type": "string"}},
                           {"name": "Access-Control-Request-Method", "in": "header", "required": True,
                            "schema": {"type": "string"}}],
            "responses": _responses({"204": {"description": "The preflight's answer.", "headers": {
                "Access-Control-Allow-Origin": {**HEADERS["AllowOrigin"], **must},
                "Vary": {**HEADERS["Vary"], **must},
                "Access-Control-Allow-Methods": {"schema": {"type": "string"}, **must,
                                                 "description": "The path's methods (not HEAD), comma-separated."},
                "Access-Control-Allow-Headers": {"schema": {"type": "string"}, **must,
                                                 "description": "authorization, content-type, session-secret"},
                "Access-Control-Max-Age": {"schema": {"type": "string"}, **must,
                                           "description": "Seconds a browser may keep this answer (600)."}}}},
                "405", bug=False)}


SID = {"name": "sid", "in": "path", "required": True, "schema": {"type": "string"},
       "description": "The session id returned by POST /sessions."}
SECRET = [{"sessionSecret": []}, {"sessionSecret": [], "bearer": []}]
SECRET_OR_ADMIN = [*SECRET, {"bearer": []}]
OPEN = [{}, {"bearer": []}]
STREAM = (
    "Handshake refusals are HTTP answers: 400 a repeated credential header, 401 token, 403 Host/Origin/secret, "
    "409 the session already has a stream. An unknown, expired, restarted or misrouted session is accepted, told "
    "{\"error\", \"status\"} and closed with 4000 + status (4404, 4410, 4421). Each message is a step body of the "
    "session's kind (StepRequest or SceneStep), each reply its record (Record or SceneRecord) or {\"error\", "
    "\"status\", ...} with the status HTTP would give, in message order. A browser's WebSocket cannot send "
    "headers: a handshake from an allowed Origin without Session-Secret (and, when the service has a token, "
    "without Authorization) is accepted, and its first message must be the credentials {\"secret\": SECRET, "
    "\"token\": TOKEN} (token only when the service has one); it is answered {\"authenticated\": true, "
    "\"session\": ID}, or told {\"error\", \"status\"} and closed with 4403 (no or wrong secret), 4401 (missing "
    "or wrong token) or 4409 (another stream attached meanwhile); no credentials within --stream-idle-timeout: "
    "closed 4408. A message over --max-body gets {\"status\": 413} and the stream stays open; one over 16 x "
    "--max-body closes it with 1009. No message for --stream-idle-timeout: closed 4408. A deleted session "
    "closes its stream with 4404, a stopping service with 1012.")


def _strip_titles(schema, names: bool = False):
    """pydantic's schemas without the ``title`` it derives from each field's name (noise in a reference);
    ``names``: ``schema`` maps field names to schemas (a field called title stays)."""
    if isinstance(schema, dict):
        return {k: _strip_titles(v, k == "properties" and not names) for k, v in schema.items()
                if names or k != "title"}
    if isinstance(schema, list):
        return [_strip_titles(v) for v in schema]
    return schema


def _not_null(schema: dict) -> dict:
    """An optional field's schema without its ``null`` alternative and its default (for a model that needs it)."""
    out = {k: v for k, v in schema.items() if k not in ("anyOf", "default")}
    if "anyOf" in schema:
        alternatives = [a for a in schema["anyOf"] if a != {"type": "null"}]
        out = {**alternatives[0], **out} if len(alternatives) == 1 else {"anyOf": alternatives, **out}
    return out


def _vehicles(spec: dict) -> dict:
    """``VehicleSpec`` as one schema per supervised model, each with the fields it takes (``MODEL_FIELDS`` required,
    ``MODEL_OPTIONS`` optional): a field of another model, or another model, is refused."""
    from guardian.service.scene import MODEL_FIELDS, MODEL_OPTIONS

    props = spec["properties"]
    default = props["model"].get("default")
    per_model = {f for fields in (*MODEL_FIELDS.values(), *MODEL_OPTIONS.values()) for f in fields}
    common = [f for f in props if f != "model" and f not in per_model]
    variants = []
    for model, fields in MODEL_FIELDS.items():
        model_schema = {"const": model, **({"default": model} if model == default else {})}
        variants.append({
            "type": "object", "additionalProperties": False, "title": model,
            "required": [*([] if model == default else ["model"]), *(f for f in common if f in spec["required"]),
                         *fields],
            "properties": {"model": model_schema, **{f: props[f] for f in common},
                           **{f: _not_null(props[f]) for f in (*fields, *MODEL_OPTIONS[model])}}})
    return {"description": spec["description"], "oneOf": variants}


def _request_schemas() -> dict:
    """The request bodies' schemas, pydantic's, with the models they nest (as components)."""
    from pydantic.json_schema import models_json_schema

    from guardian.service.api import SessionSettings, StepRequest
    from guardian.service.scene import LaneChangeQuery, SceneSettings, SceneStep

    models = (SessionSettings, StepRequest, SceneSettings, SceneStep, LaneChangeQuery)
    _, top = models_json_schema([(m, "validation") for m in models], ref_template="#/components/schemas/{model}")
    defs = _strip_titles(top["$defs"])
    defs["VehicleSpec"] = _vehicles(defs["VehicleSpec"])
    return defs


def _body(schema: dict, required: bool) -> dict:
    return {"required": required, "content": {"application/json": {"schema": schema}}}


def _with_preflights(paths: dict) -> dict:
    for path, item in paths.items():
        item["options"] = _preflight(path)
    return paths


@lru_cache(maxsize=1)
def document() -> dict:
    """The OpenAPI 3.1 document of the service."""
    requests = _request_schemas()
    session_ops = ("404", "405", "410", "421")
    body_errors = ("404", "405", "409", "410", "411", "415", "421", "422")
    paths = {
        "/health": {"get": {"operationId": "health", "summary": "Liveness and counts (all workers).",
                            "responses": _responses({"200": _ok("Alive.", "Health")}, "405")}},
        "/ready": {"get": {"operationId": "ready",
                           "summary": "200 when every worker is warmed up and none is stopping, else 503.",
                           "responses": _responses({"200": _ok("Ready for traffic.", "Ready")}, "405")}},
        "/sessions": {
            "get": {"operationId": "listSessions", "summary": "Every live session (admin token only).",
                    "security": [{"bearer": []}],
                    "responses": _responses({"200": _ok("The sessions of every worker.", "SessionList")}, "405")},
            "post": {"operationId": "createSession",
                     "summary": "A new session (its guardian and secret): two-car (the default), or a scene "
                                "(\"kind\": \"scene\").",
                     "description": "A two-car session supervises Chapter 6's overtake pair from the state "
                                    "(v_ex, y_e, h, v_Lx); a scene session an ego among traffic on a road, for the "
                                    "vehicle model its driving stack declares (bicycle or point_mass). A vehicle "
                                    "the guardian cannot guarantee is refused with 422 saying why.",
                     "requestBody": _body({"oneOf": [schema_ref("SessionSettings"), schema_ref("SceneSettings")]}, False),
                     "responses": _responses({"201": _ok("Created; the secret is shown this once.",
                                                         "CreatedSession")},
                                             "411", "415", "422")}},
        "/sessions/{sid}": {
            "parameters": [SID],
            "get": {"operationId": "getSession", "summary": "The session's state and last record.",
                    "security": SECRET_OR_ADMIN,
                    "responses": _responses({"200": _ok("The session (two-car or scene).", "Session")}, *session_ops)},
            "delete": {"operationId": "deleteSession", "summary": "End the session (its stream closes, 4404).",
                       "security": SECRET_OR_ADMIN,
                       "responses": _responses({"200": _ok("Closed.", "Closed")}, "404", "410", "421")}},
        "/sessions/{sid}/step": {
            "parameters": [SID],
            "post": {"operationId": "step", "summary": "Supervise one step (seq = the session's next_seq).",
                     "description": "The body is the session's kind's: StepRequest (two-car) or SceneStep (scene); "
                                    "the answer its record.",
                     "security": SECRET,
                     "requestBody": _body({"oneOf": [schema_ref("StepRequest"), schema_ref("SceneStep")]}, True),
                     "responses": _responses({"200": _ok("The record (also for a retry of the last step).",
                                                         {"oneOf": [schema_ref("Record"), schema_ref("SceneRecord")]})},
                                             *body_errors)}},
        "/sessions/{sid}/lane_change": {
            "parameters": [SID],
            "post": {"operationId": "laneChange",
                     "summary": "May the ego of a scene session begin a lane change to lane `to` now?",
                     "description": "For a driving stack whose own controller steers lane changes (a bicycle with "
                                    "meta): judged once, before the change starts; nothing of the session changes. "
                                    "409 for a two-car or a point-mass session (their lane changes are judged in "
                                    "their steps). A lane the road does not have is answered allowed: false.",
                     "security": SECRET, "requestBody": _body(schema_ref("LaneChangeQuery"), True),
                     "responses": _responses({"200": _ok("The verdict.", "LaneChange")}, *body_errors)}},
        "/sessions/{sid}/stream": {
            "parameters": [SID],
            "get": {"operationId": "stream",
                    "summary": "WebSocket: each message a step body, each reply its record or "
                               "{\"error\", \"status\"}.",
                    "description": STREAM, "security": SECRET,
                    "responses": {"101": {"description": "Switching Protocols: the stream is open."},
                                  **_responses({}, "405", "409", "426")}}},
        "/openapi.json": {"get": {"operationId": "openapi", "summary": "This document.",
                                  "responses": _responses({"200": _ok("OpenAPI 3.1.", {"type": "object"})}, "405")}},
        "/docs": {"get": {"operationId": "docs", "summary": "This document as a page (no scripts, offline).",
                          "responses": _responses({"200": {"description": "HTML.", "headers": dict(_CORS), "content": {
                              "text/html": {"schema": {"type": "string"}}}}}, "405")}},
    }
    return {
        "openapi": "3.1.0",
        "info": {"title": "guardian", "version": "4",
                 "description": "The guardian as a service: one guardian per session, either Chapter 6's "
                                "intention-aware supervisor of an overtake pair (two-car sessions) or an ego among "
                                "traffic on a road (scene sessions: a bicycle or the overtake point mass). Steps "
                                "carry sequence numbers (a retry is answered from the stored answer, a gap gets "
                                "409); a session's secret is required to step, read or delete it. Browsers: an "
                                "allowed Origin (--allow-origin) gets Access-Control-Allow-Origin on every answer "
                                "and its preflights are answered (OPTIONS). See docs/service.md."},
        "components": {
            "schemas": {**SCHEMAS, **requests},
            "headers": HEADERS,
            "securitySchemes": {
                "bearer": {"type": "http", "scheme": "bearer",
                           "description": "The service token (guardian serve --token), required on every request "
                                          "but a CORS preflight when set (a browser's stream may send it in its "
                                          "first message); or the admin token (--admin-token), which also lists "
                                          "every session and may read or delete any."},
                "sessionSecret": {"type": "apiKey", "in": "header", "name": "Session-Secret",
                                  "description": "The secret POST /sessions returned for this session (a browser's "
                                                 "stream sends it in its first message instead)."}},
        },
        "security": OPEN,
        "paths": _with_preflights(paths),
    }


def _schema_name(schema: dict) -> str:
    if "$ref" in schema:
        return schema["$ref"].rsplit("/", 1)[-1]
    if "oneOf" in schema:
        return " | ".join(_schema_name(s) for s in schema["oneOf"])
    return schema.get("type", "")


def _schema_html(schema) -> str:
    return f"<pre>{html.escape(json.dumps(schema, indent=2))}</pre>"


@lru_cache(maxsize=1)
def docs_html() -> str:
    """The reference page: every operation, its parameters, body and answers, from ``document()``."""
    doc = document()
    out = ["<!doctype html><html lang=en><head><meta charset=utf-8><title>guardian service API</title>",
           ("<style>body{font:15px/1.45 system-ui,sans-serif;max-width:60em;margin:2em auto;padding:0 1em}"
            "code,pre{background:#f4f4f4}pre{padding:.5em;overflow:auto;font-size:12px}"
            "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:.2em .5em;vertical-align:top}"
            "h2{border-top:2px solid #333;padding-top:.5em}details{margin:.3em 0}</style></head><body>"),
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
            for p in [*item.get("parameters", []), *op.get("parameters", [])]:
                out.append(f"<p>Parameter <code>{html.escape(p['name'])}</code> ({html.escape(p['in'])}"
                           f"{', required' if p.get('required') else ''}): {html.escape(p.get('description', ''))}</p>")
            out.append("<table><tr><th>Status</th><th>Meaning</th><th>Body</th><th>Headers</th></tr>")
            for code, resp in op["responses"].items():
                content = resp.get("content", {})
                body = ", ".join(f"{t}: {_schema_name(c['schema'])}" for t, c in content.items())
                headers = ", ".join(name + (" (always)" if h.get("required") else "")
                                    for name, h in resp.get("headers", {}).items())
                out.append(f"<tr><td>{code}</td><td>{html.escape(resp['description'])}</td>"
                           f"<td>{html.escape(body)}</td><td>{html.escape(headers)}</td></tr>")
            out.append("</table>")
    out.append("<h2>Schemas</h2>")
    for name, schema in doc["components"]["schemas"].items():
        out.append(f"<details id=\"schema-{html.escape(name)}\"><summary>{html.escape(name)}</summary>"
                   f"{_schema_html(schema)}</details>")
    out.append("</body></html>")
    return "".join(out)
