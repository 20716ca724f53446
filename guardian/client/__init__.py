"""Clients of the guardian service (``guardian serve``), for a driving stack that runs the guardian out of
process: create a session, step it (over HTTP or its WebSocket stream), read and close it.

- ``http``: ``GuardianClient`` and ``Session``, synchronous, on one keep-alive ``http.client`` connection;
- ``aio``: ``AsyncGuardianClient`` and ``AsyncSession``, the same methods as coroutines, on asyncio streams;
- ``wire``: the asyncio client's minimal HTTP/1.1 (``Content-Length`` bodies, ``Connection: close`` honoured);
- ``stream``: ``Stream`` and ``AsyncStream``, a session's WebSocket step stream (``websockets``);
- ``common``: what both share (no I/O): the requests, the retry rule, answers to results and errors;
- ``bodies``: a scene session's bodies from the guardian's model objects (``EgoState``, ``Scene``, a kinematics);
- ``shadow``: ``Shadow``, an in-process decision object that asks a session every question too and keeps every
  disagreement (a deployment checked against the library it came from).

A session keeps its sequence numbers: ``step(**body)`` sends the next one, and a step whose connection
failed is sent again with the same number and body, which the service applies once (it answers a repeated
last step with its stored record). ``POST /sessions`` is never sent twice. An error answer raises
``guardian.errors.ServiceError`` (``status``, ``message``, the body's other fields in ``extra``); a request
that got no answer raises ``ConnectionError``.

::

    from guardian.client import GuardianClient

    with GuardianClient("http://127.0.0.1:8765") as client, client.create_session() as session:
        record = session.step(state=[25.0, 0.0, 40.0, 20.0], input=[0.5, 0.0])
        record["applied"]                      # the input the vehicle may apply

What it may import: the standard library, ``websockets`` (a dependency of the project; imported when a
stream opens), ``guardian.errors`` and ``guardian.model`` (roads and model objects, only when converting them).
Never ``guardian.service``: the client knows the service by its wire contract only (the house's import rules
keep the two rooms apart), so it runs wherever the service does not, without uvicorn or pydantic.
"""
from guardian.client.aio import AsyncGuardianClient, AsyncSession
from guardian.client.http import GuardianClient, Session
from guardian.client.stream import AsyncStream, Stream
from guardian.errors import ServiceError

__all__ = ["AsyncGuardianClient", "AsyncSession", "AsyncStream", "GuardianClient", "ServiceError", "Session",
           "Stream"]
