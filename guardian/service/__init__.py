"""The guardian as an HTTP and WebSocket JSON service (``guardian serve``).

- ``sessions``: sessions, their time-to-live and the model domain (no transport);
- ``limits``: what a request may cost before it is parsed;
- ``api``: the FastAPI routes and the gate in front of them (the API is documented there);
- ``protocol``: uvicorn's h11 protocol with JSON framing errors and a request-head timeout;
- ``server``: options, binding, running (``make_server``, ``ServiceThread``).
"""
from guardian.service.api import SessionSettings, StepRequest, create_app
from guardian.service.limits import Limits
from guardian.service.server import ServiceConfig, ServiceThread, is_loopback, make_server, token_from_env
from guardian.service.sessions import ModelDomain, ServiceError, SessionStore

__all__ = ["Limits", "ModelDomain", "ServiceConfig", "ServiceError", "ServiceThread", "SessionSettings",
           "SessionStore", "StepRequest", "create_app", "is_loopback", "make_server", "token_from_env"]
