"""The guardian as an HTTP and WebSocket JSON service (``guardian serve``; docs/service.md).

- ``sessions``: sessions (sequence numbers, secrets, one writer), their time-to-live, ids that say
  where a session lives, the model domain (no transport);
- ``limits``: what a request may cost before it is parsed;
- ``http``: the strict HTTP/1.1 request reader and the response writer (no I/O);
- ``api``: who may ask what, and the routes;
- ``protocol``: one connection (requests, timeouts, the hand-over to another worker);
- ``stream``: the WebSocket step stream;
- ``openapi``: the contract (``/openapi.json``, ``/docs``);
- ``server``: options, binding, one worker's loop, warm-up (``ServiceThread`` for tests);
- ``workers``: ``--workers N`` processes and the routing of connections between them.
"""
from guardian.service.api import App, SessionSettings, StepRequest
from guardian.service.limits import Limits
from guardian.service.server import (ServiceConfig, ServiceThread, Server, bind, is_loopback, make_server,
                                     token_from_env, warm_up)
from guardian.service.sessions import ModelDomain, ServiceError, SessionIds, SessionStore

__all__ = ["App", "Limits", "ModelDomain", "ServiceConfig", "ServiceError", "ServiceThread", "Server",
           "SessionIds", "SessionSettings", "SessionStore", "StepRequest", "bind", "is_loopback", "make_server",
           "token_from_env", "warm_up"]
