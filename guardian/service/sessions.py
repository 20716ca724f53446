"""Sessions of the guardian service, independent of any transport.

One :class:`~guardian.decide.lead.IntentionAwareGuardian` (hence one intention estimator) per
session. What keeps a session's estimate intact:

- **Sequence numbers.** Step ``seq`` must be the session's next step (its record's ``t``). The same
  step sent again (a retry: the same ``seq`` and the same state and input as the last step) gets
  the stored answer and changes nothing; any other ``seq`` gets 409 with ``expected_seq``.
- **A secret per session**, returned once at creation and required (header ``Session-Secret``) to
  step, read or delete it. Only its SHA-256 is kept; it is compared in constant time.
- **One writer.** While a stream is attached to a session, HTTP steps on it get 409.

Ids say where a session lives: ``NODE.WORKER.BOOT.RANDOM`` (e.g. ``n0.1.m3x9q2a8.5f0c...``): the
node (a host behind a load balancer), the worker process on it, the worker's start time (ms since
the epoch, base 36) and 64 random bits. An id of an earlier boot is answered 410 "server restarted"
(its session died with the process); an id of another node 421 (misrouted).
"""
from __future__ import annotations

import hashlib
import hmac
import json
import re
import secrets
import time
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from guardian.errors import ServiceError
from guardian.decide.lead import IntentionAwareGuardian

PRIORITY_NAMES = {"throttle": 0, "steering": 1}
INPUT_NAMES = {i: n for n, i in PRIORITY_NAMES.items()}
EXPIRED_MEMORY = 100_000  # expired ids remembered (older ones become "unknown")
NODE_NAME = re.compile(r"^[a-z0-9][a-z0-9-]{0,31}$")
SESSION_ID = re.compile(r"^([a-z0-9][a-z0-9-]{0,31})\.([0-9]{1,3})\.([0-9a-z]{1,13})\.([0-9a-f]{16})$")
SECRET_HEADER = "session-secret"


def base36(n: int) -> str:
    digits = "0123456789abcdefghijklmnopqrstuvwxyz"
    out = ""
    while True:
        n, r = divmod(n, 36)
        out = digits[r] + out
        if n == 0:
            return out


@dataclass(frozen=True)
class SessionIds:
    """Where this store's sessions live: ``node``, ``worker`` and the worker's ``boot`` (ms).

    ``service_boot`` is when the service (all its workers) started: an id older than it belongs to a
    previous run of the service; an id of this worker older than ``boot`` to a previous run of the worker.
    """

    node: str = "n0"
    worker: int = 0
    boot: int = 0
    service_boot: int = 0
    workers: int = 1      # the workers of this node (an id naming another index is unknown here)

    def __post_init__(self):
        if not NODE_NAME.match(self.node):
            raise ValueError(f"node name {self.node!r} must be 1-32 of a-z, 0-9 and '-', starting with a letter or digit")
        if not 0 <= self.worker < self.workers <= 1000:
            raise ValueError(f"worker index {self.worker} must be in 0..{self.workers - 1} (of at most 1000)")

    @classmethod
    def starting_now(cls, node: str = "n0", worker: int = 0, service_boot: int | None = None,
                     workers: int = 1) -> "SessionIds":
        now = time.time_ns() // 1_000_000
        return cls(node, worker, now, now if service_boot is None else service_boot, workers)

    def new(self) -> str:
        return f"{self.node}.{self.worker}.{base36(self.boot)}.{secrets.token_hex(8)}"

    @staticmethod
    def parse(sid: str) -> tuple[str, int, int] | None:
        """``(node, worker, boot)`` of a well-formed id, else None."""
        m = SESSION_ID.match(sid)
        if m is None:
            return None
        return m.group(1), int(m.group(2)), int(m.group(3), 36)

    def unknown(self, sid: str) -> ServiceError:
        """Why ``sid`` (not live, not remembered as expired) is not here: 404, 410 or 421."""
        parsed = self.parse(sid)
        if parsed is None:
            return ServiceError(404, f"unknown session {sid!r}")
        node, worker, boot = parsed
        if node != self.node:
            return ServiceError(421, f"session {sid!r} lives on node {node!r}, this is node {self.node!r}: "
                                     f"route /sessions/{node}.* to that node", node=node)
        if boot < self.service_boot or (worker == self.worker and boot < self.boot):
            return ServiceError(410, f"server restarted: session {sid!r} was lost with the process that held it",
                                restarted=True)
        if worker >= self.workers:
            return ServiceError(404, f"unknown session {sid!r}")
        if worker != self.worker:  # only a request pipelined behind another on its connection lands here
            return ServiceError(421, f"session {sid!r} lives on worker {worker}: send its requests on their own "
                                     "turn (a request pipelined behind another worker's is not moved there)",
                                node=node, worker=worker)
        return ServiceError(404, f"unknown session {sid!r}")


@dataclass(frozen=True)
class ModelDomain:
    """The states the service accepts: where the overtake model describes the two cars.

    The lead's PWA pieces cover ``v_Lx`` in ``[v_L_min, v_L_max]``; neither car reverses, so
    ``v_ex >= 0``. Every ``y_e`` and ``h`` is in the domain. A state in the domain but outside the
    active set is answered with the fail-safe and ``"failsafe": true``; a state outside the domain
    is refused (422) and never reaches the session.
    """

    v_L_min: float
    v_L_max: float

    @classmethod
    def of(cls, library) -> "ModelDomain":
        lo, hi = library.params.v_Lx_bounds
        return cls(float(lo), float(hi))

    def violations(self, state) -> list[str]:
        v_ex, _, _, v_L = state
        out = []
        if v_ex < 0:
            out.append(f"v_ex = {v_ex!r} is negative (the model has no reverse)")
        if not self.v_L_min <= v_L <= self.v_L_max:
            out.append(f"v_Lx = {v_L!r} is outside the lead model's [{self.v_L_min}, {self.v_L_max}] m/s")
        return out


def _digest(secret: str) -> bytes:
    return hashlib.sha256(secret.encode("utf-8", "surrogateescape")).digest()


class Session:
    """One guardian, its secret's digest, its last answer (for retries) and its stream, if any.

    ``kind`` is ``two_car`` (Chapter 6's overtake pair: ``IntentionAwareGuardian``) or ``scene`` (an ego among
    traffic: ``guardian.service.scene.SceneGuardian``)."""

    __slots__ = ("id", "kind", "guardian", "t", "secret_digest", "created", "last_used", "last_request", "last_reply",
                 "stream")

    def __init__(self, sid: str, guardian, kind: str, now: float):
        self.id = sid
        self.kind = kind
        self.guardian = guardian
        self.t = 0               # the next step's number
        self.secret_digest = b""
        self.created = now
        self.last_used = now
        self.last_request = None     # the last step's request (parsed), for retries
        self.last_reply = b""    # its JSON answer, sent again to a retry
        self.stream = None       # the attached stream, if any (one writer)

    @property
    def next_seq(self) -> int:
        return self.t

    def idle(self, now: float) -> float:
        return now - self.last_used

    def step(self, seq: int, request) -> bytes:
        """The JSON record of step ``seq`` (a retry of the last step gets the stored one)."""
        expected = self.t
        if seq != expected:
            if seq == expected - 1 and self._same_as_last(request):
                return self.last_reply
            if seq == expected - 1:
                why = (f"step {seq} was already applied with a different "
                       + ("scene or input" if self.kind == "scene" else "state or input"))
            elif seq < expected:
                why = f"step {seq} was already applied"
            else:
                why = f"step {seq} would skip step {expected}"
            raise ServiceError(409, f"{why}; session {self.id!r} expects step {expected} next", expected_seq=expected)
        if self.kind == "scene":
            record = {"t": seq, **self.guardian.step(request)}
        else:
            _, rec = self.guardian.step(np.array(request.state, dtype=float), np.array(request.input, dtype=float))
            record = rec.as_dict()
        reply = json.dumps(record).encode()
        self.t += 1
        self.last_request, self.last_reply = request, reply
        return reply

    def _same_as_last(self, request) -> bool:
        """Is ``request`` the last step again (its state and input; the dump is made only for a retry)?"""
        last = self.last_request
        return (last is not None and type(last) is type(request)
                and last.model_dump_json(exclude={"seq"}) == request.model_dump_json(exclude={"seq"}))

    def summary(self, now: float) -> dict:
        last = json.loads(self.last_reply) if self.last_reply else None
        common = {"session": self.id, "kind": self.kind, "steps": self.t, "next_seq": self.t,
                  "idle_s": round(self.idle(now), 3), "streaming": self.stream is not None, "last": last}
        if self.kind == "scene":
            return {**common, "model": self.guardian.model}
        g = self.guardian
        return {**common, "active_set": g.active_set, "valid_intentions": list(g.estimator.valid),
                "use_intention": g.use_intention, "horizon": g.estimator.horizon,
                "priority": [INPUT_NAMES[i] for i in g.priority]}


class SessionStore:
    """Live sessions with an idle time-to-live and a cap; ``clock`` is injectable for tests."""

    def __init__(self, library, ttl: float = 300.0, max_sessions: int = 1000, clock=time.monotonic,
                 ids: SessionIds | None = None):
        if ttl <= 0 or max_sessions < 1:
            raise ValueError(f"session ttl must be > 0 and max_sessions >= 1, got {ttl}, {max_sessions}")
        self.library = library
        self.domain = ModelDomain.of(library)
        self.ttl = float(ttl)
        self.max_sessions = int(max_sessions)
        self.clock = clock
        self.ids = ids or SessionIds.starting_now()
        self.live: dict[str, Session] = {}
        self.expired: OrderedDict[str, float] = OrderedDict()  # id -> when it expired
        self.expired_total = 0
        self.closed_total = 0
        self.created_total = 0
        self.on_change = None  # called with the store after sessions come or go (worker statistics)

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change(self)

    def sweep(self) -> int:
        """Expire every session idle longer than the ttl (a streaming one is in use); returns how many."""
        now = self.clock()
        stale = [sid for sid, s in self.live.items() if s.idle(now) > self.ttl and s.stream is None]
        for sid in stale:
            del self.live[sid]
            self.expired[sid] = now
            self.expired_total += 1
        while len(self.expired) > EXPIRED_MEMORY:
            self.expired.popitem(last=False)
        if stale:
            self._changed()
        return len(stale)

    def create(self, use_intention: bool, horizon: int, priority: tuple[str, str]) -> dict:
        """A new two-car session; the answer holds its ``secret``, shown this once."""
        guardian = IntentionAwareGuardian(self.library, use_intention=use_intention, horizon=horizon,
                                          priority=tuple(PRIORITY_NAMES[p] for p in priority))
        return self._add(guardian, "two_car")

    def create_scene(self, settings) -> dict:
        """A new scene session (``guardian.service.scene.SceneSettings``); 422 for a model it cannot guarantee."""
        from guardian.service.scene import SceneGuardian

        return self._add(SceneGuardian(settings, self.library), "scene")

    def _room(self) -> None:
        if len(self.live) >= self.max_sessions:
            self.sweep()
        if len(self.live) >= self.max_sessions:
            raise ServiceError(503, f"session limit {self.max_sessions} reached; idle sessions expire "
                                    f"after {self.ttl:g} s", retry_after_s=self.ttl)

    def _add(self, guardian, kind: str) -> dict:
        self._room()
        now = self.clock()
        session = Session(self.ids.new(), guardian, kind, now)
        secret = secrets.token_urlsafe(24)
        session.secret_digest = _digest(secret)
        self.live[session.id] = session
        self.created_total += 1
        self._changed()
        return {**session.summary(now), "secret": secret}

    def get(self, sid: str) -> Session:
        """The live session ``sid``, or the ServiceError saying why not (404, 410, 421)."""
        session = self.live.get(sid)
        if session is not None and session.stream is None and session.idle(self.clock()) > self.ttl:
            self.sweep()
            session = None
        if session is None:
            if sid in self.expired:
                raise ServiceError(410, f"session {sid!r} expired after {self.ttl:g} s idle", expired=True)
            raise self.ids.unknown(sid)
        return session

    def authorized(self, sid: str, secret: str | None, admin: bool = False) -> Session:
        """The session, if ``secret`` is its secret (or the caller holds the admin token), else 403."""
        session = self.get(sid)
        if admin:
            return session
        if secret is None:
            raise ServiceError(403, f"session {sid!r} needs its secret: send the 'Session-Secret' header "
                                    "with the secret returned when it was created")
        if not hmac.compare_digest(_digest(secret), session.secret_digest):
            raise ServiceError(403, f"wrong secret for session {sid!r}")
        return session

    def check_state(self, state) -> None:
        bad = self.domain.violations(state)
        if bad:
            raise ServiceError(422, "state outside the model domain: " + "; ".join(bad))

    def step_model(self, sid: str):
        """The request body a step of session ``sid`` takes (404/410/421 for a session that is not here)."""
        from guardian.service.api import StepRequest
        from guardian.service.scene import SceneStep

        return SceneStep if self.get(sid).kind == "scene" else StepRequest

    def step(self, sid: str, secret: str | None, request, stream=None) -> bytes:
        """Validate, then step the session's guardian with ``request`` (its ``step_model``); returns the record
        as JSON bytes.

        ``stream`` is the caller's stream, if the step came on one: a session with a stream attached
        takes steps from that stream only.
        """
        session = self.authorized(sid, secret)
        if session.stream is not stream:
            raise ServiceError(409, f"session {sid!r} is attached to a stream: steps go there (one writer per "
                                    "session)", expected_seq=session.next_seq, streaming=True)
        if session.kind == "two_car":
            self.check_state(request.state)
        session.last_used = self.clock()
        return session.step(request.seq, request)

    def lane_change(self, sid: str, secret: str | None, query) -> dict:
        """May a scene session's ego begin a lane change now (``guardian.service.scene.LaneChangeQuery``)?"""
        session = self.authorized(sid, secret)
        if session.kind != "scene":
            raise ServiceError(409, f"session {sid!r} is a two-car session: lane changes are judged in its steps")
        session.last_used = self.clock()
        return session.guardian.lane_change(query)

    def summary(self, sid: str, secret: str | None, admin: bool = False) -> dict:
        session = self.authorized(sid, secret, admin)
        return session.summary(self.clock())

    def close(self, sid: str, secret: str | None, admin: bool = False) -> dict:
        session = self.authorized(sid, secret, admin)
        del self.live[sid]
        self.closed_total += 1
        if session.stream is not None:
            session.stream.session_closed()
        self._changed()
        return {"closed": sid}

    def listing(self) -> list[dict]:
        self.sweep()
        now = self.clock()
        return [{"session": s.id, "kind": s.kind, "steps": s.t, "idle_s": round(s.idle(now), 3),
                 "streaming": s.stream is not None} for s in self.live.values()]

    def counts(self) -> dict:
        self.sweep()
        return {"sessions": len(self.live), "expired": self.expired_total, "closed": self.closed_total,
                "created": self.created_total}
