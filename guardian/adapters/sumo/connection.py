"""How the guardian reaches SUMO: libsumo in this process, or TraCI over TCP.

Three connections, each a module with TraCI's API (``vehicle``, ``simulation``, ...):

* ``"libsumo"``: SUMO as a library in this process (the fastest);
* ``"traci"``: the ``sumo`` binary of the ``eclipse-sumo`` package in a process of its own, driven over TraCI's TCP
  socket by the ``traci`` client: the path a SUMO on another machine takes;
* ``"HOST:PORT"``: a SUMO server already running there (``sumo -c guardian.sumocfg --remote-port PORT``, on the
  files ``guardian sumo --write-scenario DIR`` wrote). It is connected to once; each episode reloads it
  (``traci.load``) with the episode's seed and the scenario's files, which must lie at the same paths on the
  server (the same machine, or a shared folder). SUMO ends when its client closes: ``close_servers`` at the end.
"""
from __future__ import annotations

import contextlib
import io
import sys

from guardian.errors import ConfigError

LOCAL = ("libsumo", "traci")
_servers: dict = {}   # "HOST:PORT" -> the traci label of the open connection


def parse_connection(text: str) -> str:
    """``text`` if it is ``libsumo``, ``traci`` or ``HOST:PORT`` (a port 1..65535); else ``ConfigError``."""
    if text in LOCAL:
        return text
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConfigError(f"a SUMO connection is libsumo, traci or HOST:PORT with a port 1..65535, got {text!r}")
    return text


def open_sumo(connection: str, args: list):
    """SUMO started (or reloaded) with the command-line ``args`` (without the binary), as a TraCI-like module."""
    if connection == "libsumo":
        try:
            with contextlib.redirect_stdout(sys.stderr):  # libsumo prints its warnings (pyarrow's version) on stdout
                import libsumo as traci
        except ImportError:
            raise ConfigError("libsumo is not installed: pip install 'guardian[sumo]'") from None
        traci.start(["sumo", *args])
        return traci
    traci = _traci()
    if connection == "traci":
        from guardian.adapters.sumo.network import sumo_home

        import subprocess

        with contextlib.redirect_stdout(sys.stderr):  # the client prints its connection retries on stdout
            traci.start([str(sumo_home() / "bin" / "sumo"), *args], label="guardian-local", stdout=subprocess.DEVNULL)
        return traci
    return _server(traci, connection, args)


def close_sumo(connection: str, traci) -> None:
    """End the episode's SUMO (a server stays connected for the next episode: ``close_servers``)."""
    if connection in LOCAL:
        traci.close()


def close_servers() -> None:
    """Close every connection to a SUMO server (each server then ends)."""
    if not _servers:
        return
    traci = _traci()
    for label in list(_servers.values()):
        traci.switch(label)
        traci.close()
    _servers.clear()


def _traci():
    try:
        import traci
    except ImportError:
        raise ConfigError("the traci client is not installed: pip install 'guardian[sumo]'") from None
    return traci


def _server(traci, address: str, args: list):
    host, _, port = address.rpartition(":")
    label = _servers.get(address)
    if label is None:
        label = f"guardian-{address}"
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # its retries: the failure is said below, in one line
                traci.init(int(port), host=host, label=label, numRetries=2)
        except traci.exceptions.FatalTraCIError as exc:
            raise ConfigError(f"no SUMO server answers at {address}: {exc}") from None
        except OSError as exc:
            raise ConfigError(f"no SUMO server answers at {address}: {exc.strerror or exc}") from None
        _servers[address] = label
    traci.switch(label)
    traci.load(args)
    return traci
