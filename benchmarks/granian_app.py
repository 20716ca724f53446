"""The guardian service's ASGI application for granian (``benchmarks/bench_service.py --servers granian``).

Built as ``guardian serve`` builds one worker (``guardian.service.server.Server``): the library as the CLI
loads it by default, warmed up (``warm_up``) before the app is returned, one ``SessionStore`` and one
``ServiceApp`` with the default ``ServiceConfig`` (loopback, no token, the default ``Limits``). What uvicorn's
side adds and granian does not run: our HTTP protocol (``guardian.service.protocol``: its limits, timeouts and
the hand-off of connections between workers) and the sweeper (expired sessions are still swept when a store
fills up or a session is looked up). With ``--workers N`` every granian worker builds its own app; a session
lives in the worker whose connection created it (no router), so use one connection per session.

Run: granian --interface asgi --factory benchmarks.granian_app:app  (from the repository's root)

Environment: GUARDIAN_BENCH_MAX_SESSIONS (5000), GUARDIAN_BENCH_SESSION_TTL (600 s).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def app():
    """The ASGI application of one worker (a granian factory: ``--factory benchmarks.granian_app:app``)."""
    from guardian.service.app import ServiceApp
    from guardian.service.server import ServiceConfig, is_loopback, warm_up
    from guardian.service.sessions import SessionIds, SessionStore
    from intention.library import LibrarySettings, build_library
    from intention.params import OvertakeParams

    config = ServiceConfig(port=0, session_ttl=float(os.environ.get("GUARDIAN_BENCH_SESSION_TTL", "600")),
                           max_sessions=int(os.environ.get("GUARDIAN_BENCH_MAX_SESSIONS", "5000")))
    config.check()
    # guardian serve's defaults (guardian.cli.common.load_library without options)
    library = build_library(params=OvertakeParams(), settings=LibrarySettings(), quiet=True)
    warm_up(library)
    # as Server builds one worker's store; with several granian workers every one calls itself worker 0 (a
    # request reaching another worker than its session's is told 404 or 410)
    store = SessionStore(library, ttl=config.session_ttl, max_sessions=config.max_sessions,
                         ids=SessionIds.starting_now(config.node))
    service = ServiceApp(store, config.limits, config.token, config.admin_token, config.allow_origins,
                         loopback=is_loopback(config.host))
    service.ready = True
    return service
