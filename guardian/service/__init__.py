"""The guardian as an HTTP and WebSocket JSON service (``guardian serve``; docs/service.md).

- ``sessions``: sessions (sequence numbers, secrets, one writer), their time-to-live, ids that say
  where a session lives, the two-car model's domain (no transport);
- ``scene``: scene sessions: a driving stack's ego among its traffic (road, vehicle model, steps);
- ``limits``: what a request may cost before it is parsed;
- ``api``: the requests (pydantic models) and the routes (no I/O);
- ``app``: the ASGI application: the checks before the routes, the routes, CORS;
- ``stream``: the WebSocket step stream;
- ``protocol``: one connection on uvicorn's httptools protocol (limits, timeouts, the hand-over to another
  worker);
- ``openapi``: the contract (``/openapi.json``, ``/docs``);
- ``server``: options, binding, one worker served by uvicorn, warm-up (``ServiceThread`` for tests);
- ``workers``: ``--workers N`` processes and the routing of connections between them.

Clients: ``guardian.client``.
"""
from guardian.service.api import SessionSettings, StepRequest
from guardian.service.app import ServiceApp
from guardian.service.limits import Limits
from guardian.service.server import (ServiceConfig, ServiceThread, Server, bind, is_loopback, make_server,
                                     token_from_env, warm_up)
from guardian.service.sessions import ModelDomain, ServiceError, SessionIds, SessionStore

__all__ = ["Limits", "ModelDomain", "ServiceApp", "ServiceConfig", "ServiceError", "ServiceThread", "Server",
           "SessionIds", "SessionSettings", "SessionStore", "StepRequest", "bind", "is_loopback", "make_server",
           "token_from_env", "warm_up"]
