"""The asyncio client: ``AsyncGuardianClient`` and its ``AsyncSession``, the synchronous client's methods as
coroutines, on asyncio streams and the minimal HTTP/1.1 of ``guardian.client.wire``."""
from __future__ import annotations

import asyncio
import ssl
import time
from collections.abc import Iterable, Mapping

from guardian.client.common import Answer, Attempts, ClientBase, Request, SessionBase, result
from guardian.client.wire import head, read_answer
from guardian.errors import ServiceError


class AsyncGuardianClient(ClientBase):
    """An asyncio client of ``guardian serve``, on one keep-alive HTTP/1.1 connection; coroutines used together
    take turns on it. Its connection, retry and error rules are ``guardian.client.GuardianClient``'s.

    Parameters
    ----------
    url : str
        The service, ``http://HOST:PORT`` (``https://`` works too).
    token : str, optional
        Sent as ``Authorization: Bearer TOKEN``.
    timeout : float
        Seconds a request (connect, send, answer) may take.
    retries : int
        How many times a request whose connection failed is sent again.
    """

    def __init__(self, url: str, token: str | None = None, timeout: float = 10.0, retries: int = 3):
        super().__init__(url, token, timeout, retries)
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lock: asyncio.Lock | None = None

    # ---- the connection -----------------------------------------------------------------------------------
    def _drop(self) -> None:
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None

    async def close(self) -> None:
        """Close the connection (the client opens another if it is used again)."""
        writer = self._writer
        self._drop()
        if writer is not None:
            try:
                await writer.wait_closed()
            except OSError:
                pass

    async def __aenter__(self) -> "AsyncGuardianClient":
        return self

    async def __aexit__(self, *exc) -> None:
        await self.close()

    async def _connection(self, request: Request) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        if self._writer is not None and (self._reader.at_eof() or self._writer.is_closing()
                                         or self.must_be_fresh(request)):
            self._drop()  # closed by the server while idle
        if self._writer is None:
            context = ssl.create_default_context() if self.target.scheme == "https" else None
            self._reader, self._writer = await asyncio.open_connection(self.target.host, self.target.port,
                                                                       ssl=context)
        return self._reader, self._writer

    async def _attempt(self, request: Request, state: dict) -> Answer:
        reader, writer = await self._connection(request)
        writer.write(head(request, self.target) + (request.body or b""))
        await writer.drain()
        state["sent"] = True
        answer, close = await read_answer(reader, request.method)
        if close:
            self._drop()
        return answer

    async def call(self, request: Request) -> Answer:
        """Send ``request`` (again after a connection failure, as ``common.Attempts`` allows); its answer.

        Parameters
        ----------
        request : guardian.client.common.Request

        Returns
        -------
        Answer
            Status, headers and body, whatever the status; ``retried`` counts the attempts after the first.
        """
        if self._lock is None:
            self._lock = asyncio.Lock()
        attempts = Attempts(request, self.retries)
        while True:
            state = {"sent": False}
            try:
                async with self._lock:
                    try:
                        answer = await asyncio.wait_for(self._attempt(request, state), self.timeout)
                    except BaseException:
                        self._drop()  # cancelled or failed half-way: the next request starts afresh
                        raise
                    finally:
                        self._last_used = time.monotonic()
                answer.retried = attempts.tries
                return answer
            except (OSError, EOFError, ValueError, asyncio.TimeoutError) as exc:  # EOFError: IncompleteReadError
                await asyncio.sleep(attempts.failed(exc, state["sent"]))

    # ---- the routes ---------------------------------------------------------------------------------------
    async def health(self) -> dict:
        """``GET /health`` (see ``GuardianClient.health``).

        Returns
        -------
        dict
            Liveness and counts.
        """
        return result(await self.call(Request("GET", "/health", None, self.headers())), 200)

    async def ready(self) -> dict:
        """``GET /ready`` (see ``GuardianClient.ready``).

        Returns
        -------
        dict
            ``"ready"`` true or false, and why.
        """
        return self.ready_result(await self.call(Request("GET", "/ready", None, self.headers())))

    async def create_session(self, **settings) -> "AsyncSession":
        """A new two-car session (see ``GuardianClient.create_session``).

        Parameters
        ----------
        **settings
            ``use_intention``, ``horizon``, ``priority``.

        Returns
        -------
        AsyncSession
        """
        return AsyncSession.created(self, await self.call(self.create_request(settings)))

    async def create_scene_session(self, road, vehicle: Mapping, guardian: Mapping | None = None) -> "AsyncSession":
        """A new scene session (see ``GuardianClient.create_scene_session``).

        Parameters
        ----------
        road : dict or guardian.model.roads.Road or guardian.model.roads.RoadMap
        vehicle : dict
        guardian : dict, optional

        Returns
        -------
        AsyncSession
        """
        return AsyncSession.created(self, await self.call(self.scene_request(road, vehicle, guardian)))


class AsyncSession(SessionBase):
    """One session of an ``AsyncGuardianClient``: ``guardian.client.Session``'s attributes, its methods as
    coroutines; ``async with`` closes it.

    Parameters
    ----------
    client : AsyncGuardianClient
    id, secret : str
    kind : str
    next_seq : int
    info : dict, optional
    """

    async def step(self, **body) -> dict:
        """``POST /sessions/ID/step`` with the next sequence number (see ``Session.step``).

        Parameters
        ----------
        **body
            ``state``/``input`` (two-car) or ``ego``/``cars``/``input`` (scene).

        Returns
        -------
        dict
            The step's record.
        """
        seq, request = self.step_request(body)
        return self.step_result(seq, await self.client.call(request))

    async def lane_change(self, ego: Mapping, cars: Iterable[Mapping], to: int) -> dict:
        """May a scene session's ego begin a lane change to ``to`` now (see ``Session.lane_change``)?

        Parameters
        ----------
        ego : dict
        cars : iterable of dict
        to : int

        Returns
        -------
        dict
            ``{"allowed", "reason"}``.
        """
        return result(await self.client.call(self.lane_change_request(ego, cars, to)), 200)

    async def summary(self) -> dict:
        """``GET /sessions/ID``.

        Returns
        -------
        dict
            ``{"session", "kind", "steps", "next_seq", "last", ...}``.
        """
        return result(await self.client.call(self.summary_request()), 200)

    async def close(self) -> dict:
        """``DELETE /sessions/ID``.

        Returns
        -------
        dict
            ``{"closed": ID}``.
        """
        return self.close_result(await self.client.call(self.close_request()))

    def stream(self):
        """The session's WebSocket step stream: ``async with session.stream() as s`` or ``await session.stream()``.

        Returns
        -------
        guardian.client.stream.AsyncStream
        """
        from guardian.client.stream import AsyncStream

        return AsyncStream(self)

    async def __aenter__(self) -> "AsyncSession":
        return self

    async def __aexit__(self, exc_type, *rest) -> None:
        if self.closed:
            return
        try:
            await self.close()
        except (ServiceError, ConnectionError):
            if exc_type is None:
                raise
