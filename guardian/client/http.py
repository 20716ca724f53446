"""The synchronous client: ``GuardianClient`` (one keep-alive ``http.client`` connection) and its ``Session``."""
from __future__ import annotations

import http.client
import select
import threading
import time
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING

from guardian.client.common import Answer, Attempts, ClientBase, Request, SessionBase, result
from guardian.errors import ServiceError

if TYPE_CHECKING:
    from guardian.client.stream import Stream


class GuardianClient(ClientBase):
    """A synchronous client of ``guardian serve``, on one keep-alive HTTP/1.1 connection.

    The connection is opened on first use and opened again when the server closed it (``Connection: close``,
    its idle timeout). A request whose connection fails (refused, reset, timed out, closed without an answer)
    is sent again, the same bytes, at most ``retries`` times with a short backoff: steps are idempotent (the
    service answers a repeated last step with its stored record and changes nothing). ``POST /sessions`` is
    not: once sent whole it is never sent again (``ConnectionError`` says a session may have been created).
    Answers are never retried: an error answer raises ``guardian.errors.ServiceError`` with its status and
    body (421 misdirected, 503 with ``retry_after_s`` included). Requests from several threads are
    serialized.

    Parameters
    ----------
    url : str
        The service, ``http://HOST:PORT`` (``https://`` works too).
    token : str, optional
        Sent as ``Authorization: Bearer TOKEN`` (the service's ``--token``, or its admin token).
    timeout : float
        Seconds each connect, send and read may take.
    retries : int
        How many times a request whose connection failed is sent again.
    """

    def __init__(self, url: str, token: str | None = None, timeout: float = 10.0, retries: int = 3):
        super().__init__(url, token, timeout, retries)
        cls = http.client.HTTPSConnection if self.target.scheme == "https" else http.client.HTTPConnection
        self._conn = cls(self.target.host, self.target.port, timeout=self.timeout)
        self._lock = threading.Lock()

    # ---- the connection ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Close the connection (the client opens another if it is used again)."""
        self._conn.close()

    def __enter__(self) -> "GuardianClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _stale(self, request: Request) -> bool:
        """Has the server closed the kept connection (it is readable while no answer is due), or should this
        request have a fresh one?"""
        sock = self._conn.sock
        if sock is None:
            return False
        if self.must_be_fresh(request):
            return True
        try:
            return bool(select.select([sock], [], [], 0)[0])
        except (OSError, ValueError):
            return True

    def call(self, request: Request) -> Answer:
        """Send ``request`` (again after a connection failure, as ``Attempts`` allows); its answer.

        Parameters
        ----------
        request : guardian.client.common.Request

        Returns
        -------
        Answer
            Status, headers and body, whatever the status; ``retried`` counts the attempts after the first.
        """
        attempts = Attempts(request, self.retries)
        target = self.target.prefix + request.path
        while True:
            sent = False
            try:
                with self._lock:
                    try:
                        if self._stale(request):
                            self._conn.close()
                        self._conn.request(request.method, target, body=request.body, headers=request.headers)
                        sent = True
                        response = self._conn.getresponse()
                        body = response.read()
                    except BaseException:
                        self._conn.close()  # whatever was half-done on it, the next request starts afresh
                        raise
                    finally:
                        self._last_used = time.monotonic()
                headers = {k.lower(): v for k, v in response.getheaders()}
                return Answer(response.status, headers, body, attempts.tries)
            except (OSError, http.client.HTTPException) as exc:
                time.sleep(attempts.failed(exc, sent))

    # ---- the routes ---------------------------------------------------------------------------------------
    def health(self) -> dict:
        """``GET /health``: liveness and counts.

        Returns
        -------
        dict
            ``{"status": "ok", "node", "worker", "sessions", "created", ...}``.
        """
        return result(self.call(Request("GET", "/health", None, self.headers())), 200)

    def ready(self) -> dict:
        """``GET /ready``: whether every worker is warmed up and none is stopping.

        Returns
        -------
        dict
            ``{"ready": true, "workers_ready", "workers"}``, or, while warming up or stopping (503),
            ``{"ready": false, "error": why, ...}``.
        """
        return self.ready_result(self.call(Request("GET", "/ready", None, self.headers())))

    def create_session(self, **settings) -> "Session":
        """A new two-car session (Chapter 6's overtake pair).

        Parameters
        ----------
        **settings
            ``use_intention`` (bool), ``horizon`` (int), ``priority`` (``("throttle", "steering")`` or the
            reverse); the service's defaults for those not given.

        Returns
        -------
        Session
            Bound to this client, expecting step 0.
        """
        return Session.created(self, self.call(self.create_request(settings)))

    def create_scene_session(self, road, vehicle: Mapping, guardian: Mapping | None = None) -> "Session":
        """A new scene session: the driving stack's ego among its traffic.

        Parameters
        ----------
        road : dict or guardian.model.roads.Road or guardian.model.roads.RoadMap
            ``{"lanes", "lane_width", ...}`` as ``guardian.service.scene.RoadSpec`` takes it; a ``Road`` or
            ``RoadMap`` is converted with ``guardian.model.roads.road_as_dict``.
        vehicle : dict
            The ego's model (``guardian.service.scene.VehicleSpec``): ``model`` ``"bicycle"`` with ``length``,
            ``width``, ``dt``, ``max_steering``, ``max_acceleration`` (and ``meta``), or ``"point_mass"`` with
            ``length``, ``width``, ``dt``, ``acceleration``, ``lateral_speed``, ``lateral_scale``
            (``guardian.client.bodies.vehicle_body`` makes the first from a kinematics); a model the guardian
            cannot guarantee is refused (``ServiceError`` 422, the message names why).
        guardian : dict, optional
            The guardian's options (``overapprox``, ``h_min``, ``v_max``, ...).

        Returns
        -------
        Session
            Bound to this client, expecting step 0.
        """
        return Session.created(self, self.call(self.scene_request(road, vehicle, guardian)))


class Session(SessionBase):
    """One session of a ``GuardianClient``: ``id``, ``secret``, ``kind`` (``"two_car"`` or ``"scene"``),
    ``next_seq`` (the step the service expects next, kept by the session) and ``info`` (the creation answer,
    without the secret). A context manager: leaving it closes the session.

    A step that raised ``ConnectionError`` may or may not have been applied: calling ``step`` again with the same
    body sends the same sequence number, which the service applies once. One thread steps a session at a time
    (the service takes one writer per session).

    Parameters
    ----------
    client : GuardianClient
    id, secret : str
        As the service returned them when it created the session.
    kind : str
        ``"two_car"`` or ``"scene"``.
    next_seq : int
        The step the service expects next.
    info : dict, optional
        What the service said of the session.
    """

    def step(self, **body) -> dict:
        """``POST /sessions/ID/step`` with the next sequence number.

        Parameters
        ----------
        **body
            Two-car: ``state`` ``[v_ex, y_e, h, v_Lx]`` and ``input`` ``[a_ex, v_ey]``; scene: ``ego``, ``cars``
            and ``input`` ``[acceleration, steering]`` (a point mass: ``[a_ex, v_ey]`` and ``lead``, the id of
            its lead among ``cars``); ``guardian.client.bodies.step_body`` makes one from model objects. Lists,
            tuples or numpy arrays.

        Returns
        -------
        dict
            The step's record (``"t"`` is its sequence number).
        """
        seq, request = self.step_request(body)
        return self.step_result(seq, self.client.call(request))

    def lane_change(self, ego: Mapping, cars: Iterable[Mapping], to: int) -> dict:
        """May a scene session's ego begin a lane change to lane ``to`` now?

        Parameters
        ----------
        ego : dict
            The ego now (``guardian.service.scene.EgoSpec``).
        cars : iterable of dict
            The other cars (``CarSpec``).
        to : int
            The target lane (0 the leftmost).

        Returns
        -------
        dict
            ``{"allowed": bool, "reason": str}``.
        """
        return result(self.client.call(self.lane_change_request(ego, cars, to)), 200)

    def summary(self) -> dict:
        """``GET /sessions/ID``.

        Returns
        -------
        dict
            ``{"session", "kind", "steps", "next_seq", "last", ...}``.
        """
        return result(self.client.call(self.summary_request()), 200)

    def close(self) -> dict:
        """``DELETE /sessions/ID``.

        Returns
        -------
        dict
            ``{"closed": ID}``.
        """
        return self.close_result(self.client.call(self.close_request()))

    def stream(self) -> "Stream":
        """Open the session's WebSocket step stream (while it is open, HTTP steps get 409).

        Returns
        -------
        guardian.client.stream.Stream
            ``step(**body)`` and ``close()``; a context manager. It shares this session's ``next_seq``.
        """
        from guardian.client.stream import Stream

        return Stream.open(self)

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, exc_type, *rest) -> None:
        if self.closed:
            return
        try:
            self.close()
        except (ServiceError, ConnectionError):
            if exc_type is None:
                raise  # else the error that left the block is the one to see
