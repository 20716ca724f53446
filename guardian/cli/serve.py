"""``guardian serve``: the HTTP and WebSocket service (docs/service.md)."""
from __future__ import annotations

import argparse
import asyncio
import sys

from guardian.cli.common import add_library_options, count, emit, load_library, positive_number


def cmd_serve(args) -> int:
    from guardian.service import Limits, ServiceConfig, bind, token_from_env
    from guardian.service.server import make_server
    from guardian.service.server import ADMIN_TOKEN_ENV

    limits = Limits(max_body=args.max_body, read_timeout=args.read_timeout, keepalive_timeout=args.keepalive_timeout,
                    max_connections=args.max_connections, stream_idle_timeout=args.stream_idle_timeout)
    config = ServiceConfig(host=args.host, port=args.port, token=token_from_env(args.token),
                           admin_token=token_from_env(args.admin_token, ADMIN_TOKEN_ENV),
                           allow_origins=tuple(args.allow_origin), session_ttl=args.session_ttl,
                           max_sessions=args.max_sessions, workers=args.workers, node=args.node, limits=limits)
    try:
        config.check()
    except ValueError as exc:
        print(f"guardian serve: {exc}", file=sys.stderr)
        return 2
    try:  # bound first: a busy port is refused at once, not after the sets have loaded
        sock = bind(config.host, config.port, config.backlog)
    except OSError as exc:
        print(f"guardian serve: cannot listen on {config.host}:{config.port}: {exc}", file=sys.stderr)
        return 2
    # the library is built with at least 2 processes when the cache is cold, whatever --workers says
    lib = load_library(argparse.Namespace(**{**vars(args), "workers": max(2, args.workers)}))
    if config.workers == 1:
        server, sock = make_server(lib, config, sock=sock)  # warmed up before the first connection is accepted
    host, port = sock.getsockname()[:2]
    url = f"http://[{host}]:{port}" if ":" in host else f"http://{host}:{port}"
    info = {"url": url, "workers": config.workers, "node": config.node, "token_required": config.token is not None,
            "admin_token": config.admin_token is not None, "allow_origins": list(config.allow_origins),
            "session_ttl_s": config.session_ttl, "max_sessions_per_worker": config.max_sessions,
            "max_connections_per_worker": limits.connection_cap()}
    if config.workers == 1:
        _announce(info, args, config)
        asyncio.run(server.serve(sock))  # SIGTERM and SIGINT stop it gracefully
        sock.close()
        return 0
    from guardian.service.workers import serve_workers

    supervisor = serve_workers(lib, config, sock)
    _announce(info, args, config)
    return supervisor.run()


def _announce(info: dict, args, config) -> None:
    emit(info, args.json, f"guardian service on {info['url']} with {config.workers} worker(s) (SIGINT or SIGTERM "
                          f"stops it; sessions idle {config.session_ttl:g} s expire; token "
                          f"{'required' if config.token else 'off'}; /ready says when it takes traffic)")
    sys.stdout.flush()


def port_number(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"--port must be a TCP port, 0..65535, got {text!r}")
    return value


def add_commands(sub) -> None:
    p = sub.add_parser("serve", help="the guardian as an HTTP and WebSocket JSON service (one guardian per session)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to bind (default loopback; any other address needs a token)")
    p.add_argument("--port", type=port_number, default=8765, help="a TCP port, 0..65535; 0 picks a free one (printed)")
    p.add_argument("--token", default=None,
                   help="bearer token checked on every request and stream (default: $GUARDIAN_TOKEN)")
    p.add_argument("--admin-token", default=None,
                   help="bearer token that lists every session and may read or delete any "
                        "(default: $GUARDIAN_ADMIN_TOKEN; without one, GET /sessions answers 403)")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="a browser origin allowed to call (repeatable; default none: requests with an Origin "
                        "header get 403)")
    p.add_argument("--node", default="n0",
                   help="this host's name in session ids, for several hosts behind a load balancer (default n0)")
    p.add_argument("--session-ttl", type=positive_number, default=300.0, help="seconds an idle session lives (300)")
    p.add_argument("--max-sessions", type=count(1), default=1000, help="live sessions per worker at most (1000)")
    p.add_argument("--max-connections", type=count(1), default=None,
                   help="open connections per worker at most (default: the file-descriptor limit less 64, "
                        "at most 10000); beyond it a connection gets 503 and is closed")
    p.add_argument("--max-body", type=count(1), default=64 * 1024, help="bytes of a body or stream message (65536)")
    p.add_argument("--read-timeout", type=positive_number, default=10.0,
                   help="seconds to receive a whole request once it began (10)")
    p.add_argument("--keepalive-timeout", type=positive_number, default=5.0, help="seconds an idle connection stays open (5)")
    p.add_argument("--stream-idle-timeout", type=positive_number, default=60.0,
                   help="seconds a stream may go without a message before it is closed (60)")
    add_library_options(p)
    for action in p._actions:  # serve's --workers: the processes that serve sessions
        if "--workers" in action.option_strings:
            action.help = ("worker processes serving sessions, each on its own core (default 1); a cold "
                           "library build uses max(2, N) processes")
            action.default = 1
    p.set_defaults(func=cmd_serve, workers=1)
