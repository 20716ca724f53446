"""``guardian serve``: the HTTP and WebSocket service."""
from __future__ import annotations

import signal
import sys

from guardian.cli.common import emit, load_library, add_library_options


def cmd_serve(args) -> int:
    from guardian.service import Limits, ServiceConfig, make_server, token_from_env

    limits = Limits(max_body=args.max_body, read_timeout=args.read_timeout, keepalive_timeout=args.keepalive_timeout)
    config = ServiceConfig(host=args.host, port=args.port, token=token_from_env(args.token),
                           session_ttl=args.session_ttl, max_sessions=args.max_sessions, limits=limits)
    try:
        config.check()
    except ValueError as exc:
        print(f"guardian serve: {exc}", file=sys.stderr)
        return 2
    lib = load_library(args)
    server, sock = make_server(lib, config)
    host, port = sock.getsockname()[:2]
    url = f"http://{host}:{port}"
    info = {"url": url, "token_required": config.token is not None, "session_ttl_s": config.session_ttl,
            "max_sessions": config.max_sessions}
    emit(info, args.json, f"guardian service on {url} (SIGINT or SIGTERM stops it; sessions idle "
                           f"{config.session_ttl:g} s expire; token {'required' if config.token else 'off'})")
    sys.stdout.flush()
    # uvicorn answers the requests in flight, restores these handlers and re-raises the signal
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("serve", help="the guardian as an HTTP JSON service (one estimator per session)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default loopback; any other address needs a token)")
    p.add_argument("--port", type=int, default=8765, help="0 picks a free port (printed)")
    p.add_argument("--token", default=None,
                   help="bearer token checked on every request and stream (default: $GUARDIAN_TOKEN)")
    p.add_argument("--session-ttl", type=float, default=300.0, help="seconds an idle session lives (300)")
    p.add_argument("--max-sessions", type=int, default=1000, help="live sessions at most (1000)")
    p.add_argument("--max-body", type=int, default=64 * 1024, help="bytes of a body or stream message (65536)")
    p.add_argument("--read-timeout", type=float, default=10.0,
                   help="seconds to receive a whole request once it began (10)")
    p.add_argument("--keepalive-timeout", type=float, default=5.0, help="seconds an idle connection stays open (5)")
    add_library_options(p)
    p.set_defaults(func=cmd_serve)
