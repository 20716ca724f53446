"""docs/service.md's Python snippets run as written against a service (only its address, and the session the
WebSocket snippet says comes from ``POST /sessions``, put in)."""
import json
import re
import urllib.request

import pytest
from project import ROOT

from guardian.service import ServiceConfig, ServiceThread


def _snippets() -> list[str]:
    text = (ROOT / "docs" / "service.md").read_text()
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


@pytest.fixture(scope="module")
def service(library):
    with ServiceThread(library, ServiceConfig(port=0)) as svc:
        yield svc


def _post(url: str, body: dict, headers=None) -> dict:
    request = urllib.request.Request(url, data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json", **(headers or {})})
    with urllib.request.urlopen(request, timeout=30) as reply:
        return json.loads(reply.read())


def test_the_client_snippet_runs_as_written_and_answers_what_it_says(service):
    (client_snippet,) = [s for s in _snippets() if "GuardianClient" in s]
    code = client_snippet.replace("http://127.0.0.1:8765", service.url)
    scope: dict = {}
    exec(compile(code, "docs/service.md", "exec"), scope)
    record = scope["record"]
    assert record["applied"] == [1.523809519237762, 0.0] and record["safety_override"]
    assert record["reasons"] == ["acceleration limited by self-safety towards truck ahead in lane 1: next speed at "
                                 "most 25.10 m/s"]


def test_the_websocket_snippet_runs_as_written_after_the_curl_step(service):
    (ws_snippet,) = [s for s in _snippets() if "websockets" in s]
    created = _post(service.url + "/sessions", {})
    sid, secret = created["session"], created["secret"]
    _post(f"{service.url}/sessions/{sid}/step", {"seq": 0, "state": [25, 0, 40, 20], "input": [0.5, 0]},
          {"Session-Secret": secret})
    host = service.url.split("://", 1)[1]
    code = re.sub(r'sid, secret = "[^"]*", "[^"]*"', f'sid, secret = "{sid}", "{secret}"', ws_snippet)
    code = code.replace("localhost:8765", host)
    assert code != ws_snippet
    scope: dict = {}
    exec(compile(code, "docs/service.md", "exec"), scope)
    assert scope["record"]["t"] == 1 and len(scope["record"]["applied"]) == 2
