"""The guardian service under load: steps/s, p50/p99 latency and server CPU per step.

Run: python benchmarks/bench_service.py [--servers uvicorn granian] [--workers 1 2] [--clients 1 50 200 1000]
                                         [--kinds two_car scene10 scene30] [--transport http stream]
                                         [--duration 3] [--repeat 1] [--before REV|PATH] [--json]
Smoke: python benchmarks/bench_service.py --clients 1 50 --duration 1 --workers 1 2
Today's figures (the baseline's hand-written HTTP stack, two-car sessions): add --before /work/baseline
(a checkout) or --before a62cb0f (a revision: a temporary git worktree).

By server, workers, workload, transport and connections, every configuration is one timed run of
``--duration`` seconds: ``clients`` connections, one session each, each sending its next step as soon as the
last one is answered (no pipelining), over HTTP/1.1 keep-alive (``POST /sessions/ID/step``) or the session's
WebSocket stream (``/sessions/ID/stream``, one text message per step), after ``--lead-in`` untimed steps of
every session (20: sessions in their steady state, the two-car guardian past identifying the lead's
intention, even when 1,000 sessions take only a few steps each in the timed run). Reported: the steps
answered within the duration per second, their latencies' p50 and p99 (send to whole answer), the server's
CPU seconds per step (user + system of every process of the server's tree, from /proc, over the timed phase
and the answers in flight at its end), the errors (non-200 answers, stream error replies, lost
connections), and how many sessions' last answers were checked against the local guardian (every session
without an error) and differed. A server that stops during a run is reported, started again and the run
made again (once).

Workloads (each session replays a closed loop computed here beforehand with the same guardian, and the
server must answer exactly what the local guardian did):

- ``two_car``: ``POST /sessions {}`` and steps ``{"seq", "state", "input"}``: a random driver's proposals, the
  ``IntentionAwareGuardian``'s applied inputs, the lead following one intention's model with random disturbance,
  starting inside C_bnd (HighwayOvertake's initial box), so the service identifies the intention and works
  with C_a or C_c, as in use;
- ``scene10`` / ``scene30``: scene sessions (``{"kind": "scene", ...}``, the bicycle) on a 3-lane road with 10
  cars / a 4-lane road with 30 cars around the ego (from 150 m behind to 260 m ahead; cars leaving that window
  are replaced by new ones, with new ids, at its other end). Traffic follows its leader in its lane (IDM, the
  ego counting as a leader where its body is) and advances by ``dt * speed`` each step, its speed changing
  within +-6 m/s^2, as the guardian's traffic model has it; the ego is the kinematic bicycle driven by the
  applied inputs; the proposals come from a driver that changes lanes and target speeds at random intervals,
  oblivious to traffic, so the guardian limits the acceleration and refuses lane changes often (the share of
  overridden steps is printed).

Servers: ``uvicorn``: ``guardian serve --workers N`` (uvicorn + httptools with the service's own protocol
class, ``guardian.service.protocol``, and with N > 1 the router that hands connections to the worker owning
the session); ``granian``: the same ASGI app (``benchmarks/granian_app.py``, built as ``guardian serve`` builds a
worker) on granian's own HTTP and WebSocket stack (``--workers N``: no router; each session stays on the
worker of its connection). ``--before REV`` (a git revision, checked out in a temporary worktree, or the path
of a checkout, e.g. /work/baseline) also runs that revision's ``guardian serve`` (two-car sessions only).

The client is this process: sessions are opened with asyncio, then every connection is driven by a bare
epoll loop sending prepared bytes (~10 us of client CPU per step; the stream as masked WebSocket frames with
the all-zero mask), so it takes little of the machine. The CPU other processes use during each timed run is
reported (``others %``): on a shared machine the figures are only comparable when it is low (``--quiet``
waits for a quiet second before each run).

Progress goes to stderr, the table to stdout (``--json``: the whole result as JSON instead).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

KINDS = ("two_car", "scene10", "scene30")
SERVERS = ("uvicorn", "granian")
TRANSPORTS = ("http", "stream")
TRAJECTORIES = {"two_car": 16, "scene10": 8, "scene30": 8}
# steps/s no configuration reaches, for one connection and for all together: each client gets
# min(one, all / clients) x duration steps prepared (a client that runs out stops early: reported)
RATE_CAPS = {"two_car": (5000, 15000), "scene10": (2000, 5000), "scene30": (1500, 3500)}
LANE_WIDTH = 4.0
VEHICLE = {"length": 5, "width": 2, "max_steering": 0.785, "max_acceleration": 6, "dt": 0.0667}
SCENES = {"scene10": (3, 10), "scene30": (4, 30)}  # lanes, cars
LEAD_IN = 20  # untimed steps of every session first: the two-car guardian identifies the intention in ~10
STALL = 60.0  # seconds without any answer after which the clients waiting give up (a stuck server)


def log(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def steps_needed(kind: str, clients: int, duration: float, lead_in: int = LEAD_IN) -> int:
    """The steps prepared for each of ``clients`` sessions: the lead-in and more than the timed run takes."""
    one, total = RATE_CAPS[kind]
    return lead_in + int(min(one, total / clients) * duration) + 10


# ---- workloads: closed loops computed with the local guardian ------------------------------------------------

class Workload:
    """A kind of session: its creation body and trajectories (prepared step bodies, the applied inputs the
    local guardian gave, step by step)."""

    def __init__(self, kind: str, create: bytes, trajs: list, summary: str):
        self.kind, self.create, self.trajs, self.summary = kind, create, trajs, summary


def _lengths(kind: str, clients: list, duration: float, lead_in: int) -> tuple[int, int]:
    """(length of trajectory 0, of the others): 0 also serves a single connection."""
    longest = max(steps_needed(kind, c, duration, lead_in) for c in clients)
    many = [c for c in clients if c > 1]
    return longest, (steps_needed(kind, min(many), duration, lead_in) if many else 0)


def two_car_workload(library, clients: list, duration: float, lead_in: int, seed: int = 0) -> Workload:
    """Closed loops of both intentions from states inside C_bnd (a random driver, the lead one intention's
    model with random disturbance)."""
    from envs.highway_overtake import HighwayOvertakeEnv
    from envs.overtake import draw_disturbance, sample_initial_state
    from guardian.decide.lead import IntentionAwareGuardian

    box = HighwayOvertakeEnv.default_config()["initial_box"]
    first, rest = _lengths("two_car", clients, duration, lead_in)
    count = min(TRAJECTORIES["two_car"], max(clients)) if rest else 1
    trajs, identified, overridden, total = [], 0, 0, 0
    for k in range(count):
        intention = ("cautious", "aggressive")[k % 2]
        rng = np.random.default_rng([seed, k])
        model = library.models[intention]
        guardian = IntentionAwareGuardian(library)
        x = sample_initial_state(box, library.region("bounded_velocity"), rng, "bench")
        bodies, applied_all = [], []
        for t in range(first if k == 0 else rest):
            u = rng.uniform([-3.0, -1.8], [3.0, 1.8])
            applied, record = guardian.step(x, u)
            bodies.append(json.dumps({"seq": t, "state": x.tolist(), "input": u.tolist()}).encode())
            applied_all.append(applied.tolist())
            identified += record.identified == intention
            overridden += bool(np.any(applied != u))
            total += 1
            x = model.system.step(x, applied, draw_disturbance(library.params, "random", x, rng))
        trajs.append({"bodies": bodies, "applied": applied_all})
    return Workload("two_car", b"{}", trajs, f"intention identified on {100 * identified / total:.0f} % of steps, "
                                              f"input changed on {100 * overridden / total:.0f} %")


def scene_settings(lanes: int) -> dict:
    return {"kind": "scene", "road": {"lanes": lanes, "lane_width": LANE_WIDTH}, "vehicle": VEHICLE}


def scene_trajectory(library, lanes: int, n_cars: int, length: int, rng) -> dict:
    """One closed loop of a scene session (see the module docstring)."""
    from guardian.service.scene import SceneGuardian, SceneSettings, SceneStep

    guardian = SceneGuardian(SceneSettings.model_validate(scene_settings(lanes)), library)
    dt, L, W, max_steer = VEHICLE["dt"], VEHICLE["length"], VEHICLE["width"], VEHICLE["max_steering"]
    ego = {"x": 0.0, "y": LANE_WIDTH * (lanes // 2), "heading": 0.0, "speed": float(rng.uniform(22, 28))}
    cars, made = [], 0

    def ego_lanes() -> set:
        return {math.floor((ego["y"] + dy) / LANE_WIDTH + 0.5) for dy in (-W / 2, W / 2)}

    def free(lane: int, x: float, gap: float = 25.0) -> bool:
        if lane in ego_lanes() and abs(ego["x"] - x) < gap:
            return False
        return all(abs(c["x"] - x) >= gap for c in cars if c["lane"] == lane)

    def spawn(lo: float, hi: float, v_lo: float, v_hi: float) -> bool:
        nonlocal made
        for _ in range(50):
            lane, x = int(rng.integers(lanes)), ego["x"] + float(rng.uniform(lo, hi))
            if free(lane, x):
                v = float(rng.uniform(v_lo, v_hi))
                cars.append({"id": f"c{made}", "x": x, "lane": lane, "speed": v, "v0": v + float(rng.uniform(-1, 3))})
                made += 1
                return True
        return False

    while len(cars) < n_cars:
        spawn(-120.0, 220.0, 20.0, 30.0)
    target_lane, target_speed, change_at = lanes // 2, float(rng.uniform(24, 34)), float(rng.uniform(2, 6))
    bodies, applied_all, overridden, collisions = [], [], 0, 0
    for k in range(length):
        if k * dt >= change_at:  # the driver picks another lane and speed now and then
            target_lane = int(np.clip(target_lane + rng.choice([-1, 1]), 0, lanes - 1))
            target_speed, change_at = float(rng.uniform(22, 34)), k * dt + float(rng.uniform(3, 8))
        v = ego["speed"]
        accel = float(np.clip(0.6 * (target_speed - v) + rng.normal(0, 0.8), -5, 4))
        v_lat = float(np.clip(0.6 * (target_lane * LANE_WIDTH - ego["y"]), -2.5, 2.5))
        heading_ref = math.asin(float(np.clip(v_lat / max(v, 1.0), -0.25, 0.25)))
        sin_beta = float(np.clip(3.0 * (heading_ref - ego["heading"]) * (L / 2) / max(v, 1.0), -0.35, 0.35))
        steering = float(np.clip(math.atan(2 * math.tan(math.asin(sin_beta))) + rng.normal(0, 0.003),
                                 -max_steer, max_steer))
        body = {"seq": k, "ego": dict(ego),
                "cars": [{"id": c["id"], "x": c["x"], "y": c["lane"] * LANE_WIDTH, "speed": c["speed"], "length": L,
                          "width": W} for c in cars],
                "input": [accel, steering]}
        raw = json.dumps(body).encode()
        record = guardian.step(SceneStep.model_validate_json(raw))
        bodies.append(raw)
        applied_all.append(record["applied"])
        overridden += bool(record["overridden"])
        collisions += any(abs(c["x"] - ego["x"]) < L and abs(c["lane"] * LANE_WIDTH - ego["y"]) < W for c in cars)
        a_applied, steer_applied = record["applied"]
        # traffic: IDM behind its leader in its lane (the ego leads in the lanes its body is in)
        here = ego_lanes()
        accels = []
        for c in cars:
            gap, dv = math.inf, 0.0
            for o in cars:
                if o is not c and o["lane"] == c["lane"] and o["x"] > c["x"] and o["x"] - c["x"] - L < gap:
                    gap, dv = o["x"] - c["x"] - L, c["speed"] - o["speed"]
            if c["lane"] in here and ego["x"] > c["x"] and ego["x"] - c["x"] - L < gap:
                gap, dv = ego["x"] - c["x"] - L, c["speed"] - ego["speed"]
            vc = c["speed"]
            wanted = max(0.0, 10.0 + 1.5 * vc + vc * dv / (2 * math.sqrt(3.0 * 5.0)))
            a = 3.0 * (1 - (vc / c["v0"]) ** 4 - ((wanted / gap) ** 2 if gap > 0.1 else 1e9))
            accels.append(float(np.clip(a, -6.0, 6.0)))
        for c, a in zip(cars, accels):  # highway-env's order: move at the old speed, then change it
            c["x"] += c["speed"] * dt
            c["speed"] = float(np.clip(c["speed"] + a * dt, 0.0, 40.0))
        beta = math.atan(0.5 * math.tan(steer_applied))  # highway-env's kinematic bicycle (Vehicle.step)
        ego["x"] += v * math.cos(ego["heading"] + beta) * dt
        ego["y"] += v * math.sin(ego["heading"] + beta) * dt
        ego["heading"] += v * math.sin(beta) / (L / 2) * dt
        ego["speed"] = v + a_applied * dt
        for c in list(cars):
            ahead = c["x"] - ego["x"]
            if ahead < -150.0 or ahead > 260.0:
                cars.remove(c)
                if not (spawn(180.0, 250.0, 18.0, 26.0) if ahead < 0 else spawn(-150.0, -110.0, 27.0, 33.0)):
                    cars.append(c)  # no room at the other end: it stays
    return {"bodies": bodies, "applied": applied_all, "overridden": overridden, "collisions": collisions,
            "coverage": record["coverage"]["totals"]}


def scene_workload(library, kind: str, clients: list, duration: float, lead_in: int, seed: int = 0) -> Workload:
    lanes, n_cars = SCENES[kind]
    first, rest = _lengths(kind, clients, duration, lead_in)
    count = min(TRAJECTORIES[kind], max(clients)) if rest else 1
    trajs = [scene_trajectory(library, lanes, n_cars, first if k == 0 else rest, np.random.default_rng([seed, 7, k]))
             for k in range(count)]
    total = sum(len(t["bodies"]) for t in trajs)
    uncovered = {key: sum(t["coverage"][key] for t in trajs) for key in trajs[0]["coverage"]}
    return Workload(kind, json.dumps(scene_settings(lanes)).encode(), trajs,
                    f"{lanes} lanes, {n_cars} cars, input changed on "
                    f"{100 * sum(t['overridden'] for t in trajs) / total:.0f} % of steps, steps with a body "
                    f"overlap {sum(t['collisions'] for t in trajs)}, transitions outside the model {uncovered}, "
                    f"step bodies ~{len(trajs[0]['bodies'][-1])} bytes")


def workloads(library, kinds: list, clients: list, duration: float, lead_in: int) -> dict:
    out = {}
    for kind in kinds:
        t = time.perf_counter()
        if kind == "two_car":
            out[kind] = two_car_workload(library, clients, duration, lead_in)
        else:
            out[kind] = scene_workload(library, kind, clients, duration, lead_in)
        steps = sum(len(tr["bodies"]) for tr in out[kind].trajs)
        log(f"{kind}: {len(out[kind].trajs)} closed loops, {steps} steps in {time.perf_counter() - t:.1f} s; "
            f"{out[kind].summary}")
    return out


# ---- the servers -------------------------------------------------------------------------------------------

def process_tree(root: int) -> list[int]:
    """``root`` and every process below it (granian's workers are started by a thread of its main process)."""
    children: dict = {}
    for entry in os.scandir("/proc"):
        if entry.name.isdigit():
            try:
                ppid = int(Path(f"/proc/{entry.name}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo += children.get(pid, [])
    return out


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """A server in its own processes: started, read from /proc, stopped."""

    label = "?"
    routes_sessions = True   # a request for a session reaches its worker on any connection
    ids_name_worker = True   # session ids name the worker that holds the session
    kinds = KINDS

    def __init__(self, cmd: list, workers: int, cwd: Path, env: dict, stdout=subprocess.DEVNULL):
        self.workers = workers
        self.started = time.perf_counter()
        self.stderr_path = Path(os.environ.get("TMPDIR", "/tmp")) / f"bench_service_{os.getpid()}_{id(self)}.err"
        self.stderr = open(self.stderr_path, "w+")  # noqa: SIM115 -- the server's stderr while it runs
        self.proc = subprocess.Popen(cmd, stdout=stdout, stderr=self.stderr, text=True, cwd=str(cwd),
                                     env=env, start_new_session=True)
        self.address = None

    def stderr_tail(self, lines: int = 20) -> str:
        self.stderr.flush()
        return "\n".join(self.stderr_path.read_text().splitlines()[-lines:])

    def pids(self) -> list[int]:
        return process_tree(self.proc.pid)  # again each time: a worker may have been started again

    def cpu_seconds(self) -> float:
        total = 0.0
        for pid in self.pids():
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        return total

    def rss_mb(self) -> float:
        total = 0
        for pid in self.pids():
            try:
                for line in Path(f"/proc/{pid}/status").read_text().splitlines():
                    if line.startswith("VmRSS"):
                        total += int(line.split()[1])
            except OSError:
                continue
        return total / 1024

    def wait_ready(self, timeout: float = 180.0) -> float:
        """Seconds from the start until GET /ready answers 200."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"{self.label} exited with {self.proc.returncode} before it was ready")
            if self.address is not None:
                try:
                    status, _ = asyncio.run(one_request(self.address, "GET", "/ready", timeout=2.0))
                    if status == 200:
                        return time.perf_counter() - self.started
                except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError):
                    pass
            time.sleep(0.1)
        raise RuntimeError(f"{self.label} never became ready in {timeout:g} s")

    def serving(self) -> bool:
        """Running and accepting connections (a server stopping gracefully has closed its socket)."""
        if self.proc.poll() is not None:
            return False
        try:
            socket.create_connection(self.address, timeout=5).close()
            return True
        except OSError:
            return False

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                for pid in reversed(process_tree(self.proc.pid)):
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except OSError:
                        pass
                self.proc.wait()
        self.stderr.close()
        self.stderr_path.unlink(missing_ok=True)


class GuardianServe(ServerProcess):
    """``guardian serve`` (uvicorn, or a revision's own server when ``tree`` is given)."""

    def __init__(self, workers: int, tree: Path | None = None, label: str = "uvicorn"):
        self.label = label
        if tree is not None:
            self.kinds = ("two_car",)  # the baseline had no scene sessions
        cmd = [sys.executable, "-m", "guardian.cli", "serve", "--port", "0", "--json", "--max-sessions", "5000",
               "--session-ttl", "600", "--workers", str(workers)]
        super().__init__(cmd, workers, tree or ROOT, {**os.environ, "PYTHONPATH": str(tree or ROOT)},
                         stdout=subprocess.PIPE)  # its address, then nothing
        lines = []
        while not lines or lines[-1] != "}":
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"{label} did not start (no address printed)")
            lines.append(line.rstrip("\n"))
        self.info = json.loads("\n".join(lines))
        host, port = self.info["url"].removeprefix("http://").rsplit(":", 1)
        self.address = (host, int(port))


class GranianServe(ServerProcess):
    """The same app on granian's ASGI interface (``benchmarks/granian_app.py``)."""

    label = "granian"
    ids_name_worker = False

    def __init__(self, workers: int, extra: list = ()):
        self.routes_sessions = workers == 1
        port = free_port()
        exe = shutil.which("granian")
        cmd = ([exe] if exe else [sys.executable, "-m", "granian"]) + [
            "--interface", "asgi", "--factory", "benchmarks.granian_app:app", "--host", "127.0.0.1", "--port",
            str(port), "--workers", str(workers), "--http", "1", "--loop", "asyncio", "--backlog", "2048",
            "--no-access-log", "--log-level", "warning", *extra]
        super().__init__(cmd, workers, ROOT, {**os.environ, "PYTHONPATH": str(ROOT),
                                              "GUARDIAN_BENCH_MAX_SESSIONS": "5000",
                                              "GUARDIAN_BENCH_SESSION_TTL": "600"})
        self.address = ("127.0.0.1", port)


# ---- the client: sessions opened with asyncio, then prepared bytes on a bare epoll loop --------------------

def _head(method: str, path: str, body: bytes, extra: str = "") -> bytes:
    return (f"{method} {path} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n{extra}"
            f"Content-Length: {len(body)}\r\n\r\n").encode() + body


async def read_response(reader) -> tuple[int, bytes]:
    head = await reader.readuntil(b"\r\n\r\n")
    status = int(head[9:12])
    low = head.lower()
    length = int(low.split(b"content-length:")[1].split(b"\r\n")[0]) if b"content-length:" in low else 0
    return status, await reader.readexactly(length)


async def one_request(address, method: str, path: str, body: bytes = b"", extra: str = "",
                      timeout: float = 30.0) -> tuple[int, bytes]:
    async def go():
        reader, writer = await asyncio.open_connection(*address)
        try:
            writer.write(_head(method, path, body, extra))
            return await read_response(reader)
        finally:
            writer.close()
    return await asyncio.wait_for(go(), timeout)


def ws_frame(payload: bytes, opcode: int = 0x1) -> bytes:
    """A masked frame with the all-zero mask (RFC 6455 allows it; the payload needs no XOR)."""
    n = len(payload)
    if n < 126:
        header = bytes([0x80 | opcode, 0x80 | n])
    elif n < 65536:
        header = bytes([0x80 | opcode, 0x80 | 126]) + n.to_bytes(2, "big")
    else:
        header = bytes([0x80 | opcode, 0x80 | 127]) + n.to_bytes(8, "big")
    return header + b"\0\0\0\0" + payload


WS_CLOSE = ws_frame((1000).to_bytes(2, "big"), opcode=0x8)


class Client:
    """One session's connection in the timed phase: prepared requests, one at a time (the next when the
    last is answered), timed. Driven by ``drive``."""

    def __init__(self, sock, requests: list, stream: bool, sid: str, secret: str, traj: dict):
        self.sock, self.requests, self.stream = sock, requests, stream
        self.sid, self.secret, self.traj = sid, secret, traj
        self.buf = bytearray()
        self.i = 0               # the next request's index
        self.start = 0           # the first request of the timed run (after the lead-in)
        self.stop = len(requests)  # drive sends requests up to this index
        self.sent_at = 0.0
        self.last = b""
        self.errors = []
        self.lost = False

    def next_answer(self) -> bool:
        """Consume one whole answer from the buffer (keeping its body); False if none is whole yet."""
        buf = self.buf
        if self.stream:
            if len(buf) < 2:
                return False
            n, at = buf[1] & 0x7F, 2
            if n >= 126:
                at = 4 if n == 126 else 10
                if len(buf) < at:
                    return False
                n = int.from_bytes(buf[2:at], "big")
            total = at + n
            if len(buf) < total:
                return False
            if buf[0] & 0x0F in (0x9, 0xA):  # a ping or a pong: not an answer
                del buf[:total]
                return self.next_answer()
            if buf[0] & 0x0F == 0x8:
                self.errors.append(f"stream closed {int.from_bytes(buf[at:at + 2], 'big') if n >= 2 else ''} "
                                   f"{bytes(buf[at + 2:total])!r}")
            elif buf[at + 2:at + 7] == b"error":
                self.errors.append(bytes(buf[at:at + 120]))
        else:
            end = buf.find(b"\r\n\r\n")
            if end < 0:
                return False
            k = buf.find(b"content-length: ", 0, end)
            if k < 0:
                k = buf.find(b"Content-Length: ", 0, end)
            total = end + 4 + int(buf[k + 16:buf.find(b"\r", k)])
            if len(buf) < total:
                return False
            at = end + 4
            if buf[9:12] != b"200":
                self.errors.append(f"HTTP {bytes(buf[9:12]).decode()} {bytes(buf[at:min(total, at + 120)])!r}")
        self.last = bytes(buf[at:total])
        del buf[:total]
        return True


def drive(clients: list, lat: list, duration: float | None = None) -> None:
    """Run the clients on a bare epoll loop, each from request ``i`` to request ``stop``, or until ``duration``
    seconds have passed (then no new request is sent; the answers in flight are awaited and not timed)."""
    import select

    ep = select.epoll()
    by_fd = {}
    for c in clients:
        c.sock.setblocking(True)
        by_fd[c.sock.fileno()] = c
        ep.register(c.sock.fileno(), select.EPOLLIN)
    clock = time.perf_counter
    deadline = clock() + duration if duration else float("inf")
    counting = True
    remaining = len(clients)
    for c in clients:
        c.sent_at = clock()
        c.sock.sendall(c.requests[c.i])
    while remaining:
        events = ep.poll(STALL)
        if not events:  # a server that stopped answering: the clients still waiting give up
            for fd, c in by_fd.items():
                if c.i < c.stop and not c.lost:
                    c.errors.append(f"no answer within {STALL:g} s")
                    c.lost = True
            break
        for fd, _ in events:
            c = by_fd[fd]
            try:
                data = c.sock.recv(65536)  # not more: a 256 KiB recv buffer costs ~11 us to allocate
            except OSError as exc:
                data, c.errors = b"", c.errors + [f"recv: {exc}"]
            if not data:
                c.errors.append("connection lost")
                c.lost = True
                ep.unregister(fd)
                remaining -= 1
                continue
            c.buf += data
            while c.next_answer():
                now = clock()
                if counting and now > deadline:
                    counting = False
                if counting:
                    lat.append(now - c.sent_at)
                c.i += 1
                if c.i == c.stop or not counting:
                    ep.unregister(fd)
                    remaining -= 1
                    break
                c.sent_at = now
                c.sock.sendall(c.requests[c.i])
    ep.close()


async def _open(address, workload: Workload, traj: dict, n: int, transport: str) -> Client:
    """Connect, create a session, prepare its requests (and open its stream), return its client."""
    reader, writer = await asyncio.open_connection(*address)
    writer.write(_head("POST", "/sessions", workload.create))
    status, body = await read_response(reader)
    if status != 201:
        raise RuntimeError(f"session not created: {status} {body[:300]!r}")
    created = json.loads(body)
    sid, secret = created["session"], created["secret"]
    extra = f"Session-Secret: {secret}\r\n"
    bodies = traj["bodies"][:n]
    if transport == "stream":
        writer.write((f"GET /sessions/{sid}/stream HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\n"
                      f"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                      f"Sec-WebSocket-Version: 13\r\n{extra}\r\n").encode())
        head = await reader.readuntil(b"\r\n\r\n")
        if head[9:12] != b"101":
            raise RuntimeError(f"stream refused: {head[:300]!r}")
        requests = [ws_frame(b) for b in bodies]
    else:
        path = f"/sessions/{sid}/step"
        requests = [_head("POST", path, b, extra) for b in bodies]
    sock = writer.transport.get_extra_info("socket").dup()
    writer.transport.pause_reading()
    writer.transport.abort()  # keep the socket (dup) for the bare driver
    return Client(sock, requests, transport == "stream", sid, secret, traj)


async def _open_all(address, workload: Workload, clients: int, n: int, transport: str) -> list:
    opened = []
    trajs = workload.trajs
    for start in range(0, clients, 100):  # connect in batches (the listen queue and our own loop)
        opened += await asyncio.gather(*(_open(address, workload, trajs[k % len(trajs)], n, transport)
                                         for k in range(start, min(clients, start + 100))))
    return opened


async def _delete_all(server: ServerProcess, clients: list) -> int:
    """DELETE each session on a new connection; granian with several workers has no router: a request that
    reached another worker than its session's (404, 410) is sent again on another connection. Returns the
    sessions not deleted."""
    async def one(c):
        for _ in range(1 if server.routes_sessions else 12):
            try:
                status, _ = await one_request(server.address, "DELETE", f"/sessions/{c.sid}", b"",
                                              f"Session-Secret: {c.secret}\r\n", timeout=10)
            except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError):
                continue
            if status == 200:
                return 0
            if status not in (404, 410, 421):
                return 1
        return 1

    failed = 0
    for start in range(0, len(clients), 100):
        failed += sum(await asyncio.gather(*(one(c) for c in clients[start:start + 100])))
    return failed


def close_sessions(server: ServerProcess, clients: list, transport: str) -> int:
    """End every session of a run (so that the next runs find an empty store); returns those left behind."""
    if transport == "http":
        alive = [c for c in clients if not c.lost]
        for c in alive:
            c.requests, c.i, c.stop, c.errors = [_head("DELETE", f"/sessions/{c.sid}", b"",
                                                       f"Session-Secret: {c.secret}\r\n")], 0, 1, []
        drive(alive, [])
        left = [c for c in clients if c.lost or c.errors]
    else:
        for c in clients:
            if not c.lost:
                try:
                    c.sock.sendall(WS_CLOSE)
                except OSError:
                    pass
        left = clients
    for c in clients:
        c.sock.close()
    return asyncio.run(_delete_all(server, left)) if left else 0


# ---- one measurement -------------------------------------------------------------------------------------

def machine_busy_seconds() -> float:
    """CPU seconds every process of the machine has used (user + nice + system + irq + softirq + steal)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(v) for v in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def wait_quiet(threshold: float, max_wait: float) -> float:
    """Wait (up to ``max_wait`` s) for a second in which the machine is busier than ``threshold`` of its
    cores by less; returns the share of that last second."""
    deadline = time.monotonic() + max_wait
    while True:
        b0, t0 = machine_busy_seconds(), time.perf_counter()
        time.sleep(1.0)
        share = (machine_busy_seconds() - b0) / (time.perf_counter() - t0) / (os.cpu_count() or 1)
        if share < threshold or time.monotonic() > deadline:
            return share


def measure(server: ServerProcess, workload: Workload, clients: int, transport: str, duration: float,
            lead_in: int = LEAD_IN) -> dict:
    """One timed run (see the module docstring), after ``lead_in`` untimed steps of every session."""
    n = steps_needed(workload.kind, clients, duration, lead_in)
    t_open = time.perf_counter()
    opened = asyncio.run(_open_all(server.address, workload, clients, n, transport))
    if lead_in:
        for c in opened:
            c.stop = min(lead_in, len(c.requests))
        drive(opened, [])
    for c in opened:
        c.start, c.stop = c.i, len(c.requests)
    lead_errors = sum(len(c.errors) for c in opened)
    open_s = time.perf_counter() - t_open
    lat = []
    cpu0, own0, busy0 = server.cpu_seconds(), time.process_time(), machine_busy_seconds()
    t0 = time.perf_counter()
    drive([c for c in opened if not c.lost and c.i < c.stop], lat, duration)
    wall = time.perf_counter() - t0
    cpu, own = server.cpu_seconds() - cpu0, time.process_time() - own0
    others = max(0.0, machine_busy_seconds() - busy0 - cpu - own) / wall / (os.cpu_count() or 1)
    answered = sum(c.i - c.start for c in opened)
    errors = [e for c in opened for e in c.errors]
    checked = mismatched = 0
    mismatch_sample = []
    for c in opened:  # every session's last answer against the local guardian's
        if c.i and not c.errors:
            checked += 1
            try:
                got = json.loads(c.last)["applied"]
            except (ValueError, KeyError):
                got = None
            want = c.traj["applied"][c.i - 1]
            if got != want:
                mismatched += 1
                mismatch_sample.append(f"{c.sid} step {c.i - 1}: {got} != {want}")
    ran_out = sum(c.i == len(c.requests) for c in opened)
    per_worker: dict = {}  # sessions, and steps answered, by the worker in their id (NODE.WORKER.BOOT.RANDOM)
    for c in opened:
        w = per_worker.setdefault(c.sid.split(".")[1], [0, 0])
        w[0] += 1
        w[1] += c.i - c.start
    left = close_sessions(server, opened, transport)
    ms = np.array(lat) * 1e3
    return {"server": server.label, "workers": server.workers, "kind": workload.kind, "transport": transport,
            "clients": clients, "duration_s": duration, "steps": int(ms.size), "steps_answered": answered,
            "steps_per_s": round(ms.size / duration, 1),
            "p50_ms": round(float(np.percentile(ms, 50)), 3) if ms.size else None,
            "p99_ms": round(float(np.percentile(ms, 99)), 3) if ms.size else None,
            "server_cpu_ms_per_step": round(cpu / answered * 1e3, 4) if answered else None,
            "server_cpu_share": round(cpu / wall, 3),
            "client_cpu_ms_per_step": round(own / answered * 1e3, 4) if answered else None,
            "errors": len(errors), "error_sample": [str(e)[:200] for e in errors[:3]],
            "checked": checked, "mismatched": mismatched, "mismatch_sample": mismatch_sample[:3],
            "clients_that_ran_out_of_steps": ran_out, "sessions_left_behind": left,
            "sessions_and_steps_by_worker": per_worker,
            "lead_in_steps": lead_in, "lead_in_errors": lead_errors, "open_and_lead_in_s": round(open_s, 2),
            "others_cpu_share": round(others, 3)}


def warm(server: ServerProcess, loads: dict, seconds: float, lead_in: int) -> None:
    """A short run of every workload, not recorded (the first sessions of each kind, the sockets' paths)."""
    for kind, workload in loads.items():
        if kind in server.kinds and seconds > 0:
            r = measure(server, workload, 8, "http", seconds, lead_in)
            if r["errors"] or r["mismatched"]:
                log(f"  warm-up of {kind} on {server.label}: errors {r['error_sample']} mismatched "
                    f"{r['mismatch_sample']}")


# ---- the table -------------------------------------------------------------------------------------------

COLUMNS = (("server", "server", "{}"), ("w", "workers", "{}"), ("kind", "kind", "{}"), ("transport", "transport", "{}"),
           ("conns", "clients", "{}"), ("steps/s", "steps_per_s", "{:.0f}"), ("p50 ms", "p50_ms", "{:.3f}"),
           ("p99 ms", "p99_ms", "{:.3f}"), ("cpu ms/step", "server_cpu_ms_per_step", "{:.3f}"),
           ("errors", "errors", "{}"), ("checked", "checked", "{}"), ("mismatch", "mismatched", "{}"),
           ("ran out", "clients_that_ran_out_of_steps", "{}"), ("others %", "others_cpu_share", "{:.0%}"))


def table(rows: list) -> str:
    cells = [[h for h, _, _ in COLUMNS]]
    for r in rows:
        cells.append(["-" if r.get(k) is None else f.format(r[k]) for _, k, f in COLUMNS])
    widths = [max(len(row[i]) for row in cells) for i in range(len(COLUMNS))]
    lines = ["  ".join(c.rjust(w) if i > 3 else c.ljust(w) for i, (c, w) in enumerate(zip(row, widths)))
             for row in cells]
    return "\n".join([lines[0], "-" * len(lines[0]), *lines[1:]])


def summarize(reps: list) -> dict:
    """The run of median throughput, with every run's throughput and CPU per step."""
    best = sorted(reps, key=lambda r: r["steps_per_s"])[len(reps) // 2]
    if len(reps) == 1:
        return best
    return {**best, "steps_per_s_runs": [r["steps_per_s"] for r in reps],
            "server_cpu_ms_runs": [r["server_cpu_ms_per_step"] for r in reps],
            "others_cpu_share_runs": [r["others_cpu_share"] for r in reps],
            "errors": sum(r["errors"] for r in reps), "mismatched": sum(r["mismatched"] for r in reps),
            "checked": sum(r["checked"] for r in reps)}


def main() -> int:
    paragraphs = __doc__.split("\n\n")
    ap = argparse.ArgumentParser(description=" ".join(paragraphs[0].split()),
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=paragraphs[1])
    ap.add_argument("--servers", nargs="*", default=list(SERVERS), choices=SERVERS,
                    help="servers of this tree to measure (none: only --before)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 50, 200, 1000],
                    help="connections (one session each) of each run")
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--transport", "--transports", dest="transports", nargs="+", default=list(TRANSPORTS),
                    choices=TRANSPORTS)
    ap.add_argument("--duration", type=float, default=3.0, help="seconds of each timed run (3)")
    ap.add_argument("--lead-in", type=int, default=LEAD_IN,
                    help=f"untimed steps of every session before the timed run ({LEAD_IN}: past the two-car "
                         "guardian's identification of the lead's intention, as in a session's steady state)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each configuration (the median is reported)")
    ap.add_argument("--warm", type=float, default=0.5,
                    help="seconds of an unrecorded run of each workload on each server first (0: none)")
    ap.add_argument("--before", default=None, metavar="REV",
                    help="also measure this git revision's (or this checkout's) guardian serve: two-car sessions")
    ap.add_argument("--granian-option", action="append", default=[], metavar="ARG",
                    help="an extra granian argument (repeatable), e.g. --granian-option=--runtime-threads=2")
    ap.add_argument("--quiet", type=float, default=1.0, metavar="SHARE",
                    help="before each run wait for a second with the machine busy less than SHARE of its cores "
                         "(e.g. 0.1; default 1: no wait)")
    ap.add_argument("--quiet-wait", type=float, default=120.0, help="seconds to wait for such a second at most")
    ap.add_argument("--json", action="store_true", help="print the result as JSON instead of the table")
    args = ap.parse_args()

    import resource

    from intention.library import build_library

    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)  # 1,000 connections here, and in the servers
    if soft != resource.RLIM_INFINITY and (hard == resource.RLIM_INFINITY or soft < hard):
        resource.setrlimit(resource.RLIMIT_NOFILE, (hard, hard))
    library = build_library(quiet=True)
    loads = workloads(library, args.kinds, args.clients, args.duration, args.lead_in)
    result = {"load_before": os.getloadavg(), "cpus": os.cpu_count(), "duration_s": args.duration,
              "workloads": {k: w.summary for k, w in loads.items()}, "servers": [], "runs": []}

    def start(make, label):
        """A server, ready and warmed up (None if it did not start: reported)."""
        server = None
        try:
            server = make()
            ready = server.wait_ready()
            rss = server.rss_mb()
            log(f"{label}: ready after {ready:.1f} s, {len(server.pids())} processes, {rss:.0f} MB")
            warm(server, loads, args.warm, args.lead_in)
            c0, t0 = server.cpu_seconds(), time.perf_counter()
            time.sleep(1.0)
            idle = (server.cpu_seconds() - c0) / (time.perf_counter() - t0)
            log(f"{label}: idle, it uses {100 * idle:.1f} % of a core")
            result["servers"].append({"server": label, "workers": server.workers, "ready_s": round(ready, 2),
                                      "rss_mb_at_start": round(rss, 1), "processes": len(server.pids()),
                                      "idle_cpu_share": round(idle, 4)})
            return server
        except Exception as exc:  # noqa: BLE001 -- reported, and the other servers still run
            failed(label, server, exc)
            if server is not None:
                server.stop()
            return None

    def failed(label, server, exc) -> None:
        exited = server.proc.poll() if server is not None else None
        tail = server.stderr_tail() if server is not None else ""
        log(f"{label}: FAILED: {exc!r}; server {'exited with ' + str(exited) if exited is not None else 'alive'}"
            f"{'; its stderr ends:' + chr(10) + tail if tail else '; nothing on its stderr'}")
        result.setdefault("failures", []).append({"server": label, "error": repr(exc), "exit": exited, "stderr": tail})

    def run_server(make, label):
        """Every workload, transport and connection count on one server. A server that exits during a run is
        reported and started again, and the run made again (once)."""
        server = start(make, label)
        try:
            for kind, workload in loads.items():
                for transport in args.transports:
                    for clients in args.clients:
                        if server is None:
                            return
                        if kind not in server.kinds:
                            continue
                        reps = []
                        for _ in range(args.repeat):
                            if args.quiet < 1:
                                wait_quiet(args.quiet, args.quiet_wait)
                            for attempt in (0, 1):
                                try:
                                    rep = measure(server, workload, clients, transport, args.duration,
                                                  args.lead_in)
                                    if rep["errors"] and not server.serving():
                                        raise RuntimeError(f"the server stopped during the run: {rep['errors']} "
                                                           f"errors, e.g. {rep['error_sample']}")
                                    reps.append(rep)
                                    if attempt:
                                        result["failures"][-1]["recovered"] = "started again, the run made again"
                                    break
                                except Exception as exc:
                                    failed(f"{label} {kind} {transport} {clients} conns", server, exc)
                                    if attempt or server.serving():
                                        raise
                                    server.stop()
                                    log(f"{label}: starting it again")
                                    server = start(make, label)
                                    if server is None:
                                        return
                        row = summarize(reps)
                        result["runs"].append(row)
                        log(f"{server.label:8s} w={server.workers} {kind:8s} {transport:6s} {clients:5d} conns: "
                            f"{row['steps_per_s']:8.0f} steps/s, p50 {row['p50_ms']} ms, p99 {row['p99_ms']} ms, "
                            f"server CPU {row['server_cpu_ms_per_step']} ms/step, errors {row['errors']}"
                            f"{' ' + str(row['error_sample']) if row['errors'] else ''}, checked {row['checked']} "
                            f"mismatched {row['mismatched']}"
                            f"{' ' + str(row['mismatch_sample']) if row['mismatched'] else ''}"
                            f", ran out {row['clients_that_ran_out_of_steps']}, left behind "
                            f"{row['sessions_left_behind']}, others {100 * row['others_cpu_share']:.0f} %"
                            + (f", sessions/steps by worker {row['sessions_and_steps_by_worker']}"
                               if server.workers > 1 and server.ids_name_worker else ""))
            result["servers"][-1]["rss_mb_at_end"] = round(server.rss_mb(), 1)
        except Exception as exc:  # noqa: BLE001 -- reported; the other servers still run
            failed(label, server, exc)
        finally:
            if server is not None:
                server.stop()

    if args.before:
        if "two_car" not in loads:
            log("--before measures two-car sessions only: add two_car to --kinds")
        else:
            from contextlib import nullcontext

            from benchmarks.worktree import checkout

            given = Path(args.before)
            with (nullcontext(given.resolve()) if given.is_dir() else checkout(args.before)) as tree:
                label = f"before:{Path(args.before).name if given.is_dir() else args.before}"[:16]
                for workers in args.workers:
                    run_server(lambda w=workers: GuardianServe(w, tree, label), f"{label} w={workers}")
    for name in args.servers:
        for workers in args.workers:
            make = ((lambda w=workers: GuardianServe(w)) if name == "uvicorn" else
                    (lambda w=workers: GranianServe(w, args.granian_option)))
            run_server(make, f"{name} w={workers}")
    result["load_after"] = os.getloadavg()
    for failure in result.get("failures", []):
        log(f"FAILED{' (recovered: ' + failure['recovered'] + ')' if 'recovered' in failure else ''}: "
            f"{failure['server']}: {failure['error']}")
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(table(result["runs"]))
    return 1 if any("recovered" not in f for f in result.get("failures", [])) else 0


if __name__ == "__main__":
    sys.exit(main())
