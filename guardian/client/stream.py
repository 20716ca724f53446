"""A session's WebSocket step stream (``GET /sessions/ID/stream``), synchronous (``Stream``) and asyncio
(``AsyncStream``), on the ``websockets`` package.

Each ``step(**body)`` sends the body with the session's next sequence number and returns its record; the
session's ``next_seq`` moves on with it, so HTTP steps may follow once the stream is closed. A reply
``{"error", "status", ...}`` raises ``ServiceError`` with that status; a stream the service closed with
``4000 + status`` (4404 deleted or unknown, 4410 expired, 4408 idle, 4421 misdirected) raises
``ServiceError(status)``, one closed otherwise ``ConnectionError``. A refused handshake (401 token, 403
secret, 409 a stream is already attached) raises ``ServiceError`` with the HTTP status. A stream is not
reopened by itself: a step without a reply within the client's timeout closes it (``ConnectionError``);
the same body sent again on a new stream (or over HTTP) is applied once.
"""
from __future__ import annotations

import asyncio
import inspect
import json

from guardian.client.common import SECRET_HEADER, Answer, error_of
from guardian.errors import ServiceError


def _options(session, connect) -> dict:
    """``connect``'s keyword arguments: the session's headers, the client's timeout, no proxy, no compression
    (the service offers none)."""
    client = session.client
    headers = {SECRET_HEADER: session.secret}
    if client.token is not None:
        headers["Authorization"] = f"Bearer {client.token}"
    options = {"additional_headers": headers, "open_timeout": client.timeout, "compression": None}
    if "proxy" in inspect.signature(connect).parameters:
        options["proxy"] = None  # straight to the service, as the HTTP requests go
    return options


def _url(session) -> str:
    return session.client.target.ws_url(session._path + "/stream")


def _refused(exc) -> Exception:
    """The error of a failed handshake: ``ServiceError`` with the HTTP status of a refusal, else
    ``ConnectionError``."""
    from websockets.exceptions import InvalidStatus

    if isinstance(exc, InvalidStatus):
        response = exc.response
        headers = {k.lower(): v for k, v in response.headers.raw_items()}
        return error_of(Answer(response.status_code, headers, response.body or b""))
    return ConnectionError(f"the step stream could not be opened: {type(exc).__name__}: {exc}")


def _closed(exc, session) -> Exception:
    """The error of a stream the service closed (``websockets.exceptions.ConnectionClosed``)."""
    code = exc.rcvd.code if exc.rcvd is not None else None
    reason = exc.rcvd.reason if exc.rcvd is not None else ""
    if code is not None and 4000 <= code < 5000:
        return ServiceError(code - 4000, reason or f"the stream of session {session.id} was closed ({code})")
    if code == 1009:
        return ServiceError(413, f"the stream of session {session.id} was closed: message too big")
    return ConnectionError(f"the stream of session {session.id} was closed ({code}: {reason or 'no reason'})")


def _record(session, seq: int, raw) -> dict:
    """The record of step ``seq`` from its reply (the session then expects ``seq + 1``), or the reply's error
    raised."""
    try:
        reply = json.loads(raw)
    except ValueError:
        raise ConnectionError(f"the stream of session {session.id} replied with non-JSON: {raw[:200]!r}") from None
    if not isinstance(reply, dict):
        raise ConnectionError(f"the stream of session {session.id} replied with {type(reply).__name__}")
    if "error" in reply:
        extra = {k: v for k, v in reply.items() if k not in ("error", "status", "message")}
        raise ServiceError(int(reply.get("status", 500)), str(reply["error"]), **extra)
    session.next_seq = seq + 1
    return reply


class Stream:
    """The synchronous step stream of a ``Session`` (``Session.stream()`` opens it; see the module docstring).

    Parameters
    ----------
    session : guardian.client.http.Session
    ws : websockets.sync.client.ClientConnection
        The open WebSocket.
    """

    def __init__(self, session, ws):
        self.session, self.ws = session, ws

    @classmethod
    def open(cls, session) -> "Stream":
        from websockets.exceptions import InvalidHandshake
        from websockets.sync.client import connect

        try:  # entered as a context manager: what websockets asks of connect() now and in its next versions
            ws = connect(_url(session), **_options(session, connect)).__enter__()
        except InvalidHandshake as exc:
            raise _refused(exc) from None
        return cls(session, ws)

    def step(self, **body) -> dict:
        """One step over the stream, with the session's next sequence number.

        Parameters
        ----------
        **body
            As ``Session.step`` takes it (``state``/``input``, or ``ego``/``cars``/``input``).

        Returns
        -------
        dict
            The step's record.
        """
        from websockets.exceptions import ConnectionClosed

        seq, raw = self.session.step_body(body)
        try:
            self.ws.send(raw.decode())
        except ConnectionClosed:
            pass  # the reply saying why may be waiting: read it
        try:
            reply = self.ws.recv(timeout=self.session.client.timeout)
        except ConnectionClosed as exc:
            raise _closed(exc, self.session) from None
        except TimeoutError:
            self.close()
            raise ConnectionError(f"step {seq} of session {self.session.id}: no reply on the stream within "
                                  f"{self.session.client.timeout:g} s; the stream is closed") from None
        return _record(self.session, seq, reply)

    def close(self) -> None:
        """Close the stream (HTTP steps are taken again)."""
        self.ws.close()

    def __enter__(self) -> "Stream":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class AsyncStream:
    """The asyncio step stream of an ``AsyncSession``: ``async with session.stream() as s`` or
    ``s = await session.stream()`` (see the module docstring).

    Parameters
    ----------
    session : guardian.client.aio.AsyncSession
    """

    def __init__(self, session):
        self.session, self.ws = session, None

    async def open(self) -> "AsyncStream":
        """Open the WebSocket (once).

        Returns
        -------
        AsyncStream
            This stream.
        """
        if self.ws is None:
            from websockets.asyncio.client import connect
            from websockets.exceptions import InvalidHandshake

            try:
                self.ws = await connect(_url(self.session), **_options(self.session, connect))
            except InvalidHandshake as exc:
                raise _refused(exc) from None
        return self

    def __await__(self):
        return self.open().__await__()

    async def step(self, **body) -> dict:
        """One step over the stream, with the session's next sequence number.

        Parameters
        ----------
        **body
            As ``AsyncSession.step`` takes it.

        Returns
        -------
        dict
            The step's record.
        """
        from websockets.exceptions import ConnectionClosed

        await self.open()
        seq, raw = self.session.step_body(body)
        try:
            await self.ws.send(raw.decode())
        except ConnectionClosed:
            pass  # the reply saying why may be waiting: read it
        try:
            reply = await asyncio.wait_for(self.ws.recv(), self.session.client.timeout)
        except ConnectionClosed as exc:
            raise _closed(exc, self.session) from None
        except (asyncio.TimeoutError, TimeoutError):
            await self.close()
            raise ConnectionError(f"step {seq} of session {self.session.id}: no reply on the stream within "
                                  f"{self.session.client.timeout:g} s; the stream is closed") from None
        return _record(self.session, seq, reply)

    async def close(self) -> None:
        """Close the stream (HTTP steps are taken again)."""
        if self.ws is not None:
            await self.ws.close()

    async def __aenter__(self) -> "AsyncStream":
        return await self.open()

    async def __aexit__(self, *exc) -> None:
        await self.close()
