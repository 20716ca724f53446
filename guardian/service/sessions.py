"""Sessions of the guardian service, independent of any transport.

One :class:`~guardian.supervisor.IntentionAwareGuardian` (hence one intention estimator) per
session. Sessions idle longer than ``ttl`` seconds expire; the store remembers the most recent
expired ids so that a client asking for one hears "expired", not "unknown".
"""
from __future__ import annotations

import time
import uuid
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from guardian.errors import ServiceError
from guardian.supervisor import IntentionAwareGuardian

PRIORITY_NAMES = {"throttle": 0, "steering": 1}
EXPIRED_MEMORY = 100_000  # expired ids remembered (older ones become "unknown")


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


class Session:
    def __init__(self, library, use_intention: bool, horizon: int, priority: tuple, now: float):
        self.id = uuid.uuid4().hex[:16]
        self.guardian = IntentionAwareGuardian(library, use_intention=use_intention, horizon=horizon,
                                               priority=priority)
        self.created = now
        self.last_used = now
        self.steps = 0
        self.last = None

    def idle(self, now: float) -> float:
        return now - self.last_used

    def step(self, state, u) -> dict:
        _, record = self.guardian.step(np.asarray(state, dtype=float), np.asarray(u, dtype=float))
        out = record.as_dict()
        self.steps += 1
        self.last = out
        return out

    def summary(self, now: float) -> dict:
        g = self.guardian
        return {"session": self.id, "steps": self.steps, "active_set": g.active_set,
                "valid_intentions": list(g.estimator.valid), "use_intention": g.use_intention,
                "horizon": g.estimator.horizon, "idle_s": round(self.idle(now), 3), "last": self.last}


class SessionStore:
    """Live sessions with an idle time-to-live and a cap; ``clock`` is injectable for tests."""

    def __init__(self, library, ttl: float = 300.0, max_sessions: int = 1000, clock=time.monotonic):
        if ttl <= 0 or max_sessions < 1:
            raise ValueError(f"session ttl must be > 0 and max_sessions >= 1, got {ttl}, {max_sessions}")
        self.library = library
        self.domain = ModelDomain.of(library)
        self.ttl = float(ttl)
        self.max_sessions = int(max_sessions)
        self.clock = clock
        self.live: dict[str, Session] = {}
        self.expired: OrderedDict[str, float] = OrderedDict()  # id -> when it expired
        self.expired_total = 0
        self.closed_total = 0

    def sweep(self) -> int:
        """Expire every session idle longer than the ttl; returns how many expired."""
        now = self.clock()
        stale = [sid for sid, s in self.live.items() if s.idle(now) > self.ttl]
        for sid in stale:
            del self.live[sid]
            self.expired[sid] = now
            self.expired_total += 1
        while len(self.expired) > EXPIRED_MEMORY:
            self.expired.popitem(last=False)
        return len(stale)

    def create(self, use_intention: bool, horizon: int, priority: tuple[str, str]) -> dict:
        if len(self.live) >= self.max_sessions:
            self.sweep()
        if len(self.live) >= self.max_sessions:
            raise ServiceError(503, f"session limit {self.max_sessions} reached; idle sessions expire "
                                    f"after {self.ttl:g} s", retry_after_s=self.ttl)
        now = self.clock()
        session = Session(self.library, use_intention, horizon,
                          tuple(PRIORITY_NAMES[p] for p in priority), now)
        self.live[session.id] = session
        return session.summary(now)

    def get(self, sid: str) -> Session:
        session = self.live.get(sid)
        now = self.clock()
        if session is not None and session.idle(now) > self.ttl:
            self.sweep()
            session = None
        if session is None:
            if sid in self.expired:
                raise ServiceError(410, f"session {sid!r} expired after {self.ttl:g} s idle", expired=True)
            raise ServiceError(404, f"unknown session {sid!r}")
        return session

    def step(self, sid: str, state, u) -> dict:
        """Validate the state against the model domain, then step the session's guardian."""
        session = self.get(sid)
        bad = self.domain.violations(state)
        if bad:
            raise ServiceError(422, "state outside the model domain: " + "; ".join(bad))
        session.last_used = self.clock()
        return session.step(state, u)

    def summary(self, sid: str) -> dict:
        session = self.get(sid)
        return session.summary(self.clock())

    def close(self, sid: str) -> dict:
        self.get(sid)
        del self.live[sid]
        self.closed_total += 1
        return {"closed": sid}

    def listing(self) -> list[dict]:
        self.sweep()
        now = self.clock()
        return [{"session": s.id, "steps": s.steps, "idle_s": round(s.idle(now), 3),
                 "active_set": s.guardian.active_set} for s in self.live.values()]

    def health(self) -> dict:
        self.sweep()
        return {"status": "ok", "sessions": len(self.live), "expired": self.expired_total,
                "closed": self.closed_total, "max_sessions": self.max_sessions, "session_ttl_s": self.ttl}
