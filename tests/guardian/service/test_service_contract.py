"""The OpenAPI document describes every answer the service gives (a truthful contract).

Referees we did not write: openapi-spec-validator checks the document; openapi-core checks each response
(status listed for the operation, body valid against the schema, headers) of requests chosen to produce every
status of every operation, from the routes and from the checks and the reader before them, and the body of
each request the service accepted (the document accepts it too). The last test checks that every status the
document lists for every operation was seen: the document claims nothing the tests did not produce.
"""
import json
import re
import socket
import subprocess
import sys
import time

import jsonschema
import pytest
from openapi_core import OpenAPI
from openapi_core.testing import MockRequest, MockResponse
from openapi_spec_validator import validate as validate_spec
from service_client import Raw, call, create, secret_header, step
from websockets.sync.client import connect as ws_connect

from guardian.service import Limits, ServiceConfig, ServiceThread, openapi

ADMIN = "an-admin-token-of-some-length"
TOKEN = "the-service-token-of-some-length"
ORIGIN = "http://localhost:3000"
GOOD = step(0, [25.0, 0.0, 40.0, 20.0], [0.5, 0.0])
TEMPLATES = [(re.compile(r"^/sessions/[^/]+/step$"), "/sessions/{sid}/step"),
             (re.compile(r"^/sessions/[^/]+/lane_change$"), "/sessions/{sid}/lane_change"),
             (re.compile(r"^/sessions/[^/]+/stream$"), "/sessions/{sid}/stream"),
             (re.compile(r"^/sessions/[^/]+$"), "/sessions/{sid}")]
ANY_SID = "n0.0.zzzzzzzz.0123456789abcdef"

# scene sessions: a bicycle on a three-lane road (lanes 4 m wide, slot 0 the leftmost, centre lines y = 0, 4, 8)
BICYCLE = {"length": 5.0, "width": 2.0, "max_steering": 0.785, "max_acceleration": 6.0, "dt": 0.0667}
SCENE = {"kind": "scene", "road": {"lanes": 3, "lane_width": 4.0}, "vehicle": BICYCLE}
CARS = [{"id": "a", "x": 40.0, "y": 4.0, "speed": 20.0, "length": 5.0, "width": 2.0},   # ahead in the ego's lane
        {"id": "b", "x": -4.0, "y": 8.0, "speed": 21.0, "length": 5.0, "width": 2.0},   # beside, behind, on the right
        {"id": "c", "x": 60.0, "y": 0.0, "speed": 25.0, "length": 5.0, "width": 2.0}]   # far ahead on the left
# the overtake point mass among traffic: its library's bounds; lane_width = 2 left_lane_y lateral_scale = 3.6 m
POINT_MASS = {"model": "point_mass", "length": 5.0, "width": 2.0, "dt": 0.1, "acceleration": [-3.0, 3.0],
              "lateral_speed": [-1.8, 1.8], "lateral_scale": 2.0}
PM_SCENE = {"kind": "scene", "road": {"lanes": 3, "lane_width": 3.6}, "vehicle": POINT_MASS}


def scene_step(seq: int, ego: tuple = (0.0, 4.0, 0.0), u=(1.0, 0.0), cars=CARS, **more) -> dict:
    """Step ``seq`` of the bicycle: the ego at ``(x, y, heading)`` at 20 m/s, the cars moved on by their speeds."""
    dt = BICYCLE["dt"]
    x, y, heading = ego
    return {"seq": seq, "ego": {"x": x, "y": y, "heading": heading, "speed": 20.0},
            "cars": [{**c, "x": c["x"] + seq * dt * c["speed"]} for c in cars], "input": list(u), **more}


def pm_step(seq: int, u=(0.5, 0.0), lead="lead") -> dict:
    """Step ``seq`` of the point mass in the right lane (y = 7.2 m, y_e = 0), its lead 40 m ahead at its speed."""
    shift = 2.0 * seq
    cars = [{"id": "lead", "x": 40.0 + shift, "y": 7.2, "speed": 20.0, "length": 5.0, "width": 2.0},
            {"id": "t", "x": 30.0 + shift, "y": 3.6, "speed": 20.0, "length": 5.0, "width": 2.0}]
    return {"seq": seq, "ego": {"x": shift, "y": 7.2, "speed": 20.0}, "cars": cars, "input": list(u),
            **({"lead": lead} if lead else {})}


def template(path: str) -> str:
    path = path.split("?", 1)[0]
    for pattern, name in TEMPLATES:
        if pattern.match(path):
            return name
    return path


class Contract:
    """Validates each answer (and each accepted request) against the document; records which (path, method,
    status) were seen."""

    def __init__(self):
        self.doc = openapi.document()
        self.api = OpenAPI.from_dict(json.loads(json.dumps(self.doc)))
        self.seen = set()

    def operation(self, method: str, path: str) -> tuple[str, str]:
        """The (template, operation) an answer is judged by: a method the path does not have (405), or HEAD, by
        the path's GET or else its first operation."""
        tpl = template(path)
        assert tpl in self.doc["paths"], f"{method} {path}: a path the document lacks"
        ops = [m for m in self.doc["paths"][tpl] if m != "parameters"]
        op = method.lower() if method.lower() in ops else ("get" if "get" in ops else ops[0])
        return tpl, op

    def check(self, method: str, path: str, answer) -> tuple:
        assert answer is not None, f"{method} {path}: no answer"
        status, headers, body = answer
        tpl, op = self.operation(method, path)
        responses = self.doc["paths"][tpl][op]["responses"]
        assert str(status) in responses, f"{method} {path} answered {status} ({body}), not in {sorted(responses)}"
        self.seen.add((tpl, op, status))
        if method == "HEAD" or status == 101:
            return answer
        raw_body = body if isinstance(body, bytes) else (b"" if body is None else json.dumps(body).encode())
        ctype = headers.get("content-type", "")
        self.api.validate_response(
            MockRequest("http://localhost", op, path.split("?", 1)[0]),
            MockResponse(raw_body, status, headers=headers, content_type=ctype.split(";")[0]))
        return answer

    def send(self, address, method: str, path: str, body=None, headers: dict | None = None) -> tuple:
        """One request through ``call``; its answer checked, and, when the service accepted it (2xx), the request
        too: the document must accept what the service does."""
        answer = self.check(method, path, call(address, method, path, body, headers))
        if 200 <= answer[0] < 300 and method != "HEAD":
            self.accepts(method, path, body, headers)
        return answer

    def accepts(self, method: str, path: str, body=None, headers: dict | None = None) -> None:
        data = None if body is None else (body if isinstance(body, bytes) else json.dumps(body).encode())
        given = {k.lower(): v for k, v in (headers or {}).items()}
        self.api.validate_request(MockRequest("http://localhost", method, path, headers=given, data=data,
                                              content_type=given.get("content-type", "application/json")))

    def schema_rejects(self, method: str, path: str, body: dict) -> str:
        """The document's request-body schema refuses ``body`` (as the service does, with 422): the reason."""
        _, op = self.operation(method, path)
        schema = self.doc["paths"][template(path)][op]["requestBody"]["content"]["application/json"]["schema"]
        errors = list(self.validator(schema).iter_errors(body))
        assert errors, f"the document accepts {body}"
        return "; ".join(e.message for e in errors)

    def validator(self, schema: dict):
        return jsonschema.Draft202012Validator({**schema, "components": self.doc["components"]})

    def valid(self, name: str, instance) -> None:
        """``instance`` is valid against the document's schema ``name`` (for WebSocket replies)."""
        self.validator({"$ref": f"#/components/schemas/{name}"}).validate(instance)

    def documented(self) -> set:
        return {(path, method, int(code)) for path, item in self.doc["paths"].items()
                for method, op in item.items() if method != "parameters" for code in op["responses"]}


@pytest.fixture(scope="module")
def contract():
    return Contract()


@pytest.fixture(scope="module")
def service(library):
    limits = Limits(read_timeout=0.5, keepalive_timeout=2.0)
    with ServiceThread(library, ServiceConfig(port=0, limits=limits, admin_token=ADMIN, max_sessions=60,
                                              session_ttl=3.0, allow_origins=(ORIGIN,))) as svc:
        yield svc


def _raw(svc, data: bytes, half_close: bool = False):
    raw = Raw(svc.address).send(data)
    if half_close:
        raw.half_close()
    try:
        return raw.response()
    finally:
        raw.close()


def _head(method: str, target: str, *lines: str, version: str = "HTTP/1.1", end: bool = True) -> bytes:
    return (f"{method} {target} {version}\r\n" + "".join(f"{line}\r\n" for line in lines)
            + ("\r\n" if end else "")).encode("latin-1")


def _operations(doc: dict, sid: str = ANY_SID):
    """(method, concrete path) of every operation of the document."""
    for path, item in doc["paths"].items():
        for method in item:
            if method != "parameters":
                yield method.upper(), path.replace("{sid}", sid)


def _handshake(sid: str, secret: str | None, extra: bytes = b"") -> bytes:
    return (f"GET /sessions/{sid}/stream HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
            + (f"Session-Secret: {secret}\r\n" if secret is not None else "")).encode() + extra + b"\r\n"


def test_the_document_is_valid_openapi_with_the_bearer_scheme():
    doc = openapi.document()
    validate_spec(doc)
    schemes = doc["components"]["securitySchemes"]
    assert schemes["bearer"] == {**schemes["bearer"], "type": "http", "scheme": "bearer"}
    assert schemes["sessionSecret"]["in"] == "header" and schemes["sessionSecret"]["name"] == "Session-Secret"
    assert doc["components"]["schemas"]["Error"]["required"] == ["error"]
    assert "detail" not in json.dumps(doc)  # FastAPI's {"detail": ...} is not what the service sends
    assert '"$defs"' not in json.dumps(doc)  # pydantic's nested models are components, reachable by $ref
    stream = doc["paths"]["/sessions/{sid}/stream"]["get"]["description"]
    assert '{"secret": SECRET, "token": TOKEN}' in stream and "first message" in stream


def test_the_request_schemas_are_the_models_the_routes_parse_with():
    """Each pydantic model's fields and bounds are in the document (derived, so they cannot drift); the vehicle
    is one schema per supervised model, with the fields each takes."""
    from guardian.service.api import SessionSettings, StepRequest
    from guardian.service.scene import MODEL_FIELDS, CarSpec, EgoSpec, LaneChangeQuery, SceneStep

    schemas = openapi.document()["components"]["schemas"]
    for model in (SessionSettings, StepRequest, SceneStep, LaneChangeQuery, EgoSpec, CarSpec):
        assert set(schemas[model.__name__]["properties"]) == set(model.model_fields), model.__name__
    assert schemas["RoadSpec"]["properties"]["lanes"] == {"type": "integer", "minimum": 1, "maximum": 64}
    assert schemas["CarSpec"]["properties"]["length"] == {"type": "number", "exclusiveMinimum": 0, "maximum": 30}
    vehicles = {v["properties"]["model"]["const"]: v for v in schemas["VehicleSpec"]["oneOf"]}
    assert set(vehicles) == set(MODEL_FIELDS)
    for model, fields in MODEL_FIELDS.items():
        assert set(fields) <= set(vehicles[model]["required"])
        others = {f for m, fs in MODEL_FIELDS.items() if m != model for f in fs}
        assert not others & set(vehicles[model]["properties"])


def test_docs_work_offline(service):
    status, headers, page = call(service.address, "GET", "/docs")
    assert status == 200 and headers["content-type"].startswith("text/html")
    page = page.decode()
    assert "<script" not in page.lower() and not re.search(r"""(src|href)=["']?(https?:)?//""", page)
    for path, item in openapi.document()["paths"].items():
        for method, op in item.items():
            if method != "parameters":
                assert op["operationId"] in page and f"{method.upper()} {path}" in page
    assert "Access-Control-Allow-Methods (always)" in page and "SceneRecord" in page


def test_every_answer_of_the_routes_matches_the_document(service, contract):
    a = service.address
    c, s = contract.check, contract.send
    admin = {"authorization": f"Bearer {ADMIN}"}
    s(a, "GET", "/health")
    s(a, "HEAD", "/health")
    s(a, "GET", "/ready")
    s(a, "GET", "/openapi.json")
    s(a, "GET", "/docs")
    for path in ("/health", "/ready", "/sessions", "/openapi.json", "/docs"):
        s(a, "PUT", path, b"{}")
    sid, secret = create(a)
    auth = secret_header(secret)
    s(a, "POST", "/sessions", {"horizon": 4})
    s(a, "POST", "/sessions", None, {"content-length": "0", "content-type": "application/json"})  # all defaults
    s(a, "POST", "/sessions", {"horizon": 0})                                                      # 422
    contract.schema_rejects("POST", "/sessions", {"horizon": 0})
    s(a, "POST", "/sessions", b"{nope")                                                            # 400
    s(a, "POST", "/sessions", b"[" * 40 + b"]" * 40)                                               # 400 depth
    s(a, "POST", "/sessions", {}, {"content-type": "text/plain"})                                  # 415
    s(a, "POST", "/sessions", b"x" * 70_000)                                                       # 413
    c("POST", "/sessions", _raw(service, b"POST /sessions HTTP/1.1\r\nHost: localhost\r\n"
                                         b"Content-Type: application/json\r\n\r\n"))          # 411
    s(a, "GET", "/sessions")                                                                       # 403
    s(a, "GET", "/sessions", None, admin)                                                          # 200
    for body, headers in [(GOOD, auth), (step(5, [25, 0, 40, 20], [0, 0]), auth),             # 200, 409
                          (GOOD, auth),                                                        # 200 (a retry)
                          (step(1, [25, 0, 40, 99], [0, 0]), auth),                            # 422 domain
                          (b'{"seq": 1}', auth), (b"nope", auth),                              # 422, 400
                          (GOOD, {}), (GOOD, secret_header("wrong")),                          # 403, 403
                          (GOOD, {**auth, "content-type": "text/plain"})]:                     # 415
        s(a, "POST", f"/sessions/{sid}/step", body, headers)
    s(a, "POST", f"/sessions/{sid}/step", b"x" * 70_000, auth)                                     # 413
    c("POST", f"/sessions/{sid}/step", _raw(service, _head("POST", f"/sessions/{sid}/step", "Host: localhost",
                                                           f"Session-Secret: {secret}",
                                                           "Content-Type: application/json")))  # 411
    for unknown in ("nope", ANY_SID, "far.0.1.0123456789abcdef", "n0.0.1.0123456789abcdef"):  # 404 404 421 410
        s(a, "POST", f"/sessions/{unknown}/step", GOOD, auth)
        s(a, "GET", f"/sessions/{unknown}", None, auth)
        s(a, "DELETE", f"/sessions/{unknown}", None, auth)
    status, _, body = s(a, "GET", "/sessions/far.0.1.0123456789abcdef", None, auth)
    assert status == 421 and body["node"] == "far"
    status, _, summary = s(a, "GET", f"/sessions/{sid}", None, auth)
    assert status == 200 and summary["kind"] == "two_car" and summary["last"]["t"] == 0
    s(a, "GET", f"/sessions/{sid}", None, admin)
    s(a, "GET", f"/sessions/{sid}", None)                                                          # 403
    s(a, "HEAD", f"/sessions/{sid}", None, auth)
    s(a, "PATCH", f"/sessions/{sid}", b"{}", auth)                                                 # 405
    s(a, "GET", f"/sessions/{sid}/step", None, auth)                                               # 405
    s(a, "GET", f"/sessions/{sid}/stream", None, auth)                                             # 426
    s(a, "POST", f"/sessions/{sid}/stream", {}, auth)                                              # 405
    url = f"ws://{a[0]}:{a[1]}/sessions/{sid}/stream"
    with ws_connect(url, additional_headers=auth):
        c("GET", f"/sessions/{sid}/stream", (101, {}, None))
        c("GET", f"/sessions/{sid}/stream", _raw(service, _handshake(sid, secret)))           # 409 second stream
        status, _, body = s(a, "POST", f"/sessions/{sid}/step", step(1, [25, 0, 40, 20], [0, 0]), auth)
        assert status == 409 and body["streaming"] is True and body["expected_seq"] == 1  # one writer
    c("GET", f"/sessions/{sid}/stream", _raw(service, _handshake(sid, "wrong")))              # 403
    s(a, "DELETE", f"/sessions/{sid}", None, secret_header("wrong"))                               # 403
    s(a, "DELETE", f"/sessions/{sid}", None, auth)                                                 # 200
    old, old_secret = create(a)
    time.sleep(3.5)
    s(a, "GET", f"/sessions/{old}", None, secret_header(old_secret))                               # 410 expired
    s(a, "POST", f"/sessions/{old}/lane_change", {"ego": {"x": 0, "y": 4, "speed": 20}, "to": 0},
      secret_header(old_secret))                                                                   # 410 expired
    full = [create(a) for _ in range(60 - len(service.store.live))]
    status, headers, _ = s(a, "POST", "/sessions", {})                                             # 503 session limit
    assert status == 503 and int(headers["retry-after"]) >= 1
    for sess, sec in full:
        call(a, "DELETE", f"/sessions/{sess}", None, secret_header(sec))


def test_scene_sessions_answer_as_documented(service, contract):
    """A bicycle on a three-lane road among three cars: its records, retries, conflicts, summary, stream and
    lane-change verdicts, and the refusals of what the guardian cannot guarantee."""
    a = service.address
    c, s = contract.check, contract.send
    status, _, created = s(a, "POST", "/sessions", SCENE)
    assert status == 201 and created["kind"] == "scene" and created["model"]["vehicle"]["model"] == "bicycle"
    assert created["model"]["guardian"]["traffic_accel"] == 6.0 and created["last"] is None
    sid, auth = created["session"], secret_header(created["secret"])
    steps = [scene_step(0), scene_step(1, (1.33, 4.0, 0.0), (10.0, 0.0)),          # clipped to the model's bound
             scene_step(2, (2.7, 4.5, 0.05), (0.0, 0.5)),                            # steering into b's lane: refused
             scene_step(3, (4.0, 4.5, 0.05), (0.0, 0.785))]
    records = []
    for body in steps:
        status, _, record = s(a, "POST", f"/sessions/{sid}/step", body, auth)
        assert status == 200 and record["t"] == body["seq"] and record["proposed"] == body["input"]
        records.append(record)
    assert "state" not in records[0] and "lead" not in records[0]["coverage"]
    assert records[1]["clipped_to_model"] and records[1]["applied"][0] == 6.0 and not records[1]["safety_override"]
    refused = [e for r in records for e in r["entries"] if not e["responsible"]]
    assert refused and refused[0]["lane"] == 2 and refused[0]["reason"] and records[2]["refused"] == [2]
    assert records[2]["safety_override"] and records[2]["changed"] == "steering"
    assert s(a, "POST", f"/sessions/{sid}/step", steps[-1], auth)[2] == records[-1]                # a retry
    status, _, body = s(a, "POST", f"/sessions/{sid}/step", scene_step(9), auth)                   # 409 gap
    assert status == 409 and body["expected_seq"] == 4
    status, _, body = s(a, "POST", f"/sessions/{sid}/step", scene_step(3, (9.9, 4.0, 0.0)), auth)  # 409 changed
    assert status == 409 and "different scene" in body["error"]
    status, _, body = s(a, "POST", f"/sessions/{sid}/step", scene_step(4, lead="a"), auth)         # 422: no lead
    assert status == 422 and "lead" in body["error"]
    s(a, "POST", f"/sessions/{sid}/step", {**scene_step(4), "ego": {"x": 0, "y": 4}}, auth)        # 422 schema
    s(a, "POST", f"/sessions/{sid}/step", GOOD, auth)                                              # 422: two-car body
    status, _, summary = s(a, "GET", f"/sessions/{sid}", None, auth)
    assert status == 200 and summary["kind"] == "scene" and summary["steps"] == 4 and summary["last"] == records[-1]
    assert summary["model"] == created["model"] and "active_set" not in summary

    # lane changes: may the ego (lane 1, the middle) begin one now?
    lc = f"/sessions/{sid}/lane_change"
    ego = {"x": 0.0, "y": 4.0, "speed": 20.0}
    verdicts = {to: s(a, "POST", lc, {"ego": ego, "cars": CARS, "to": to}, auth)[2] for to in (0, 1, 2, 7)}
    assert verdicts[0] == {"allowed": True, "reason": ""}          # the left lane is free near the ego
    assert not verdicts[2]["allowed"] and verdicts[2]["reason"]    # b is beside, behind, on the right
    assert not verdicts[1]["allowed"] and not verdicts[7]["allowed"]
    assert s(a, "GET", f"/sessions/{sid}", None, auth)[2]["steps"] == 4  # a query changes nothing
    for body, headers in [({"ego": ego, "to": 0}, {}), ({"ego": ego, "to": 0}, secret_header("wrong")),  # 403 403
                          ({"ego": ego}, auth), (b"{nope", auth),                                        # 422 400
                          ({"ego": ego, "to": 0}, {**auth, "content-type": "text/plain"}),               # 415
                          (b"x" * 70_000, auth)]:                                                        # 413
        s(a, "POST", lc, body, headers)
    c("POST", lc, _raw(service, _head("POST", lc, "Host: localhost", f"Session-Secret: {created['secret']}",
                                      "Content-Type: application/json")))                   # 411
    s(a, "GET", lc, None, auth)                                                                    # 405
    for unknown in ("nope", "far.0.1.0123456789abcdef"):                                            # 404, 421
        s(a, "POST", f"/sessions/{unknown}/lane_change", {"ego": ego, "to": 0}, auth)
    two_car, two_secret = create(a)
    status, _, body = s(a, "POST", f"/sessions/{two_car}/lane_change", {"ego": ego, "to": 0},
                        secret_header(two_secret))                                                 # 409 two-car
    assert status == 409 and "two-car" in body["error"]

    # the stream of a scene session: its replies are scene records
    url = f"ws://{a[0]}:{a[1]}/sessions/{sid}/stream"
    with ws_connect(url, additional_headers=auth) as ws:
        c("GET", f"/sessions/{sid}/stream", (101, {}, None))
        ws.send(json.dumps(scene_step(4, (5.3, 4.0, 0.0))))
        record = json.loads(ws.recv(5))
        contract.valid("SceneRecord", record)
        assert record["t"] == 4
        ws.send(json.dumps(scene_step(5, (6.6, 4.0, 0.0), lead="a")))
        reply = json.loads(ws.recv(5))
        assert reply["status"] == 422 and set(reply) == {"error", "status"}
    status, _, listing = s(a, "GET", "/sessions", None, {"authorization": f"Bearer {ADMIN}"})
    assert {"session": sid, "kind": "scene"}.items() <= next(x for x in listing["sessions"] if x["session"] == sid).items()

    # what the guardian cannot guarantee is refused by name (422); the document refuses what is not its schema
    refusals = [({**SCENE, "vehicle": {**BICYCLE, "model": "unicycle"}}, "unicycle", True),
                ({**SCENE, "vehicle": {**BICYCLE, "lateral_scale": 2.0}}, "lateral_scale", True),
                ({**SCENE, "vehicle": {k: v for k, v in BICYCLE.items() if k != "max_steering"}}, "max_steering",
                 True),
                ({**SCENE, "vehicle": {**BICYCLE, "max_acceleration": 5.0}}, "traffic_accel", False),
                ({**SCENE, "road": {"lanes": 3, "lane_width": 4.0, "ends": [[5, 100.0]]}}, "lane 5", False),
                # the default library takes v_ex >= 16 m/s: a point mass could not wait behind its lead
                ({**PM_SCENE, "road": {"lanes": 3, "lane_width": 3.6}}, "wait behind its lead", False)]
    for body, named, by_schema in refusals:
        status, _, answer = s(a, "POST", "/sessions", body)
        assert status == 422 and named in answer["error"], answer
        if by_schema:
            contract.schema_rejects("POST", "/sessions", body)
        else:
            contract.accepts("POST", "/sessions", body)  # a valid body the guardian cannot guarantee
    for sess, sec in ((sid, created["secret"]), (two_car, two_secret)):
        s(a, "DELETE", f"/sessions/{sess}", None, secret_header(sec))


def test_a_point_mass_scene_session_answers_as_documented(traffic_library, contract):
    """The overtake point mass among traffic, on a library whose ego may wait behind its lead: records with the
    overtake state and the lead's coverage; its lane changes are judged in its steps (409 to a query)."""
    with ServiceThread(traffic_library, ServiceConfig(port=0)) as svc:
        a, s = svc.address, contract.send
        status, _, created = s(a, "POST", "/sessions", PM_SCENE)
        assert status == 201 and created["model"]["vehicle"] == POINT_MASS
        sid, auth = created["session"], secret_header(created["secret"])
        for seq, u in enumerate([(0.5, 0.0), (3.0, 1.8), (0.0, 1.8)]):
            status, _, record = s(a, "POST", f"/sessions/{sid}/step", pm_step(seq, u), auth)
            assert status == 200 and record["t"] == seq and record["state"][1:] == [0.0, 40.0, 20.0]
            assert "lead" in record["coverage"] and "lead" in record["coverage"]["totals"]
        status, _, body = s(a, "POST", f"/sessions/{sid}/step", pm_step(3, lead=None), auth)       # 422: no lead
        assert status == 422 and "lead" in body["error"]
        bad = pm_step(3)
        bad["ego"]["heading"] = 0.1
        status, _, body = s(a, "POST", f"/sessions/{sid}/step", bad, auth)                         # 422: heading
        assert status == 422 and "heading" in body["error"]
        status, _, body = s(a, "POST", f"/sessions/{sid}/lane_change",
                            {"ego": pm_step(3)["ego"], "to": 1}, auth)                             # 409 point mass
        assert status == 409 and "point-mass" in body["error"]
        status, _, summary = s(a, "GET", f"/sessions/{sid}", None, auth)
        assert summary["kind"] == "scene" and summary["steps"] == 3 and len(summary["last"]["state"]) == 4
        status, _, body = s(a, "POST", "/sessions", {**PM_SCENE, "road": {"lanes": 3, "lane_width": 4.0}})
        assert status == 422 and "lane_width" in body["error"]
        contract.accepts("POST", "/sessions", {**PM_SCENE, "road": {"lanes": 3, "lane_width": 4.0}})
        status, _, body = s(a, "POST", "/sessions", {**PM_SCENE, "vehicle": {**POINT_MASS, "dt": 0.2}})
        assert status == 422 and "dt" in body["error"]
        status, _, body = s(a, "POST", "/sessions", {**PM_SCENE, "vehicle": {**POINT_MASS, "meta": True}})
        assert status == 422 and "meta" in body["error"]
        contract.schema_rejects("POST", "/sessions", {**PM_SCENE, "vehicle": {**POINT_MASS, "meta": True}})


def test_browsers_get_cors_answers_and_preflights_as_documented(service, contract):
    """An allowed Origin gets Access-Control-Allow-Origin and Vary on its answers; a preflight of every path is
    answered 204 with that path's methods (those the document lists); other origins get 403; a browser's stream
    sends its secret in its first message."""
    a, doc = service.address, contract.doc
    c, s = contract.check, contract.send
    origin = {"origin": ORIGIN}
    for method, path, body in [("GET", "/health", None), ("POST", "/sessions", {}), ("GET", "/nowhere/x", None)]:
        if path == "/nowhere/x":
            status, headers, _ = call(a, method, path, body, origin)
            assert status == 404  # not a path of the document: not checked against it
        else:
            status, headers, _ = s(a, method, path, body, origin)
        assert headers["access-control-allow-origin"] == ORIGIN and headers["vary"] == "Origin"
    assert "access-control-allow-origin" not in call(a, "GET", "/health")[1]
    sid, secret = create(a)
    for path, item in doc["paths"].items():
        concrete = path.replace("{sid}", sid)
        methods = [m.upper() for m in item if m not in ("parameters", "options")]
        status, headers, _ = s(a, "OPTIONS", concrete, None, {**origin, "access-control-request-method": methods[0],
                                                              "access-control-request-headers": "session-secret"})
        assert status == 204 and headers["access-control-allow-methods"].split(", ") == methods
        assert set(headers["access-control-allow-headers"].split(", ")) >= {"authorization", "content-type",
                                                                            "session-secret"}
        s(a, "OPTIONS", concrete, None, {"origin": "http://attacker.example",
                                         "access-control-request-method": methods[0]})               # 403
        s(a, "OPTIONS", concrete, None, origin)                                                        # 405
        s(a, "OPTIONS", concrete)                                                                      # 405
    # a browser's stream: no header can carry the secret, the first message does
    url = f"ws://{a[0]}:{a[1]}/sessions/{sid}/stream"
    with ws_connect(url, origin=ORIGIN) as ws:
        c("GET", f"/sessions/{sid}/stream", (101, {}, None))
        ws.send(json.dumps({"secret": secret}))
        assert json.loads(ws.recv(5)) == {"authenticated": True, "session": sid}
        ws.send(json.dumps(GOOD))
        contract.valid("Record", json.loads(ws.recv(5)))
    with ws_connect(url, origin=ORIGIN) as ws:
        ws.send(json.dumps({"secret": "wrong"}))
        assert json.loads(ws.recv(5))["status"] == 403
    call(a, "DELETE", f"/sessions/{sid}", None, secret_header(secret))


def test_every_answer_of_the_reader_and_the_checks_matches_the_document(service, contract):
    """Answers given before any route runs, for every operation of the document: framing (400, 414, 417, 431,
    501, 505), 413 from Content-Length on any method, 408, 400 for a repeated credential header or HTTP/1.1
    without Host, 403 Host/Origin, 405."""
    c = contract.check
    a = service.address
    c("GET", "/health", _raw(service, b"GET /health HTTP/1.1\r\n\r\n"))                               # 400 no Host
    status, _, body = c("GET", "/health", _raw(service, b"GET /health HTTP/1.0\r\n\r\n"))             # 1.0: no need
    assert status == 200
    status, _, body = c("GET", "/health", _raw(service, b"GET /health HTTP/1.1\r\nHost: localhost\r\n"
                                                        b"Content-Length: 1x\r\n\r\n"))              # 400 framing
    assert status == 400 and body["error"].startswith("invalid HTTP request: ")
    c("POST", "/sessions", call(a, "POST", "/sessions", {}, {"origin": "http://attacker.example"}))    # 403 Origin
    slow = []
    for method, path in _operations(contract.doc):
        # 405 is listed under the path's first operation and under OPTIONS (an OPTIONS that is no preflight)
        wrong = "OPTIONS" if method == "OPTIONS" else "PUT"
        if contract.operation(wrong, path)[1] == method.lower():
            c(wrong, path, _raw(service, _head(wrong, path, "Host: localhost", "Content-Length: 0")))
        for lines, version, expect in [
                (["Host: localhost", "Host: localhost"], "HTTP/1.1", 400),
                (["Host: localhost", "Session-Secret: a", "Session-Secret: b"], "HTTP/1.1", 400),
                (["Host: attacker.example"], "HTTP/1.1", 403),
                (["Host: localhost", "Content-Length: 100000"], "HTTP/1.1", 413),
                (["Host: localhost", "Expect: x"], "HTTP/1.1", 417),
                (["Host: localhost", "Transfer-Encoding: gzip"], "HTTP/1.1", 501),
                (["Host: localhost"], "HTTP/2.0", 505),
                (["Host: x", *(f"X-{i}: y" for i in range(200))], "HTTP/1.1", 431)]:
            answer = c(method, path, _raw(service, _head(method, path, *lines, version=version)))
            assert answer[0] == expect, (method, path, lines, answer)
        answer = c(method, path + "?" + "a" * 9000, _raw(service, _head(method, path + "?" + "a" * 9000)))
        assert answer[0] == 414
        slow.append((method, path, Raw(a).send(_head(method, path, "Host: localhost", end=False))))
    for method, path, raw in slow:  # heads never finished: 408 after the read timeout (0.5 s), all at once
        try:
            assert c(method, path, raw.response())[0] == 408
        finally:
            raw.close()


def test_the_token_and_the_connection_limit_and_a_bug_answer_as_documented(library, contract, monkeypatch):
    c = contract.check
    config = ServiceConfig(port=0, token=TOKEN, limits=Limits(max_connections=3, keepalive_timeout=5.0),
                           allow_origins=(ORIGIN,))
    token = {"authorization": f"Bearer {TOKEN}"}
    with ServiceThread(library, config) as svc:
        a = svc.address
        operations = list(_operations(contract.doc))
        for method, path in operations:                                                            # 401
            status, headers, _ = c(method, path, call(a, method, path, {} if method == "POST" else None))
            assert status == 401 and headers["www-authenticate"].startswith("Bearer")
        c("POST", "/sessions", call(a, "POST", "/sessions", {}, {"authorization": "Bearer nope"}))  # 401
        status, _, _ = contract.send(a, "OPTIONS", "/sessions", None, {"origin": ORIGIN,           # no token needed
                                                                       "access-control-request-method": "POST"})
        assert status == 204
        held = [socket.create_connection(a) for _ in range(3)]
        time.sleep(0.2)
        for method, path in operations:                                                            # 503 at connect
            status, headers, _ = c(method, path, call(a, method, path, {} if method == "POST" else None, token))
            assert status == 503 and headers["retry-after"] == "1"
        for sock in held:
            sock.close()
        time.sleep(0.2)
        svc.server.app.stopping = True
        c("GET", "/ready", call(a, "GET", "/ready", None, token))                                  # 503 stopping
        svc.server.app.stopping = False
        for route in ("_health", "_ready", "_sessions", "_session", "_step", "_lane_change", "_stream", "_openapi",
                      "_docs"):
            monkeypatch.setattr(svc.server.app, route, lambda *a: 1 / 0)
        for method, path in operations:                                                            # 500: a bug
            if method != "OPTIONS":  # answered by the checks, before any route: no route's bug reaches it
                status, headers, _ = c(method, path, call(a, method, path, {} if method == "POST" else None, token))
                assert status == 500 and headers["connection"] == "close"


def _serve_two_workers(cache_dir) -> tuple:
    """``guardian serve --workers 2`` on a free port (the library from the session's cache): (process, address)."""
    proc = subprocess.Popen([sys.executable, "-m", "guardian.cli", "serve", "--cache-dir", str(cache_dir), "--json",
                             "--port", "0", "--workers", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    lines = []
    while not lines or lines[-1] != "}":
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(proc.stderr.read())
        lines.append(line.rstrip("\n"))
    host, port = json.loads("\n".join(lines))["url"].removeprefix("http://").split(":")
    address = (host, int(port))
    deadline = time.monotonic() + 60
    while call(address, "GET", "/ready")[0] != 200:
        assert time.monotonic() < deadline, "never ready"
        time.sleep(0.05)
    return proc, address


LANE_CHANGE = b'{"ego": {"x": 0, "y": 0, "speed": 1}, "to": 0}'


def test_a_request_pipelined_behind_another_workers_is_misdirected_as_documented(library, cache_dir, contract):
    """With two workers, a connection is handed to a session's worker between requests only: a request pipelined
    behind one for another worker's session reaches the wrong worker and is answered 421 with the right one."""
    proc, address = _serve_two_workers(cache_dir)
    try:
        sessions = {}
        while len(sessions) < 2:  # new sessions go to the worker with the fewest: one on each
            sid, secret = create(address)
            sessions.setdefault(int(sid.split(".")[1]), (sid, secret))
        raw = Raw(address)
        try:
            raw.send(b"".join(_head(method, f"/sessions/{sid}{tail}", "Host: localhost", f"Session-Secret: {secret}",
                                    *(["Content-Type: application/json", f"Content-Length: {len(body)}"]
                                      if body else []), end=True) + body
                              for sid, secret in (sessions[0], sessions[1], sessions[0])
                              for method, tail, body in [("GET", "", b""), ("POST", "/lane_change", LANE_CHANGE)]))
            answers = [raw.response() for _ in range(6)]
        finally:
            raw.close()
        for (sid, _), (method, path), answer in zip([sessions[0]] * 2 + [sessions[1]] * 2 + [sessions[0]] * 2,
                                                    [("GET", "/sessions/{}"), ("POST", "/sessions/{}/lane_change")] * 3,
                                                    answers):
            contract.check(method, path.format(sid), answer)
            # answered by the session's worker (409: lane changes of a two-car session), or misdirected
            assert answer[0] in (200, 409) or (answer[0] == 421 and answer[2]["worker"] == int(sid.split(".")[1]))
        assert [status for status, _, _ in answers].count(421) >= 2, answers
    finally:
        proc.terminate()
        proc.communicate(timeout=30)


def test_the_answers_seen_cover_the_document(contract):
    """Run last in this module: every status the document lists for every operation was produced above (the
    document claims nothing the tests did not see), as every answer seen was listed (``Contract.check``)."""
    missing = contract.documented() - contract.seen
    assert not missing, sorted(missing)
    assert contract.seen <= contract.documented()
