"""The guardian service under realistic load: steps/s, latency, server CPU per step, memory per session.

Run: python benchmarks/bench_service.py [--workers 1 2 4] [--clients 1 50 200 1000] [--repeat 3]
                                         [--before REV] [--json]

Trajectories are realistic: each session replays a closed loop computed beforehand with the same
guardian (a random driver's proposals, the guardian's applied inputs, the lead following one
intention's model with random disturbance, starting inside C_bnd), so the service identifies the
intention and works with C_a or C_c, as in use. The server answers exactly what the local guardian
did (the replies are checked on the last step of every session).

The server runs in its own processes (``guardian serve --workers N``); the clients are one asyncio
loop in this process sending prepared bytes (HTTP/1.1 keep-alive, one connection per session; the
stream as raw WebSocket frames), so the client costs little of the machine's two cores. Server CPU
is read from /proc for the server's processes (parent and workers) around the timed phase.

``--before REV`` also measures a revision's service (its own API: no seq, no secret) in the same run,
from a git worktree (1 worker: it had no others).

``--nginx`` runs docs/service.md's load-balancer setup on loopback (needs ``nginx`` on PATH): two nodes,
``--node a --workers 2`` and ``--node b --workers 2``, behind nginx with the documented ``map``, and
measures HTTP and the stream through it (every session's last answer checked; sessions on both nodes).
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
STEPS_PER_CLIENT = {1: 2000}  # one client: a fixed number of steps (more clients: DURATION seconds each)
TRAJECTORIES = 16


# ---- realistic trajectories -------------------------------------------------------------------------

def trajectories(library, count: int, length: int, seed: int = 0) -> list[dict]:
    """``count`` closed loops of ``length`` steps, both intentions, from states inside C_bnd."""
    from envs.overtake import DEFAULT_CONFIG, draw_disturbance, sample_initial_state
    from guardian.decide.lead import IntentionAwareGuardian

    out = []
    for k in range(count):
        intention = ("cautious", "aggressive")[k % 2]
        rng = np.random.default_rng([seed, k])
        model = library.models[intention]
        guardian = IntentionAwareGuardian(library)
        x = sample_initial_state(DEFAULT_CONFIG["initial_box"], library.region("bounded_velocity"), rng, "bench")
        steps, identified = [], 0
        for _ in range(length):
            u = rng.uniform([-3.0, -1.8], [3.0, 1.8])
            applied, record = guardian.step(x, u)
            steps.append((x.tolist(), u.tolist()))
            identified += record.identified == intention
            x = model.system.step(x, applied, draw_disturbance(library.params, "random", x, rng))
        out.append({"intention": intention, "steps": steps, "identified": identified / length})
    return out


def expected_applied(library, traj: dict, n: int) -> list:
    """The applied input of step ``n - 1`` of a trajectory (what the server must answer last)."""
    from guardian.decide.lead import IntentionAwareGuardian

    g = IntentionAwareGuardian(library)
    applied = None
    for state, u in traj["steps"][:n]:
        applied, _ = g.step(np.array(state), np.array(u))
    return applied.tolist()


# ---- the server ---------------------------------------------------------------------------------------

class ServerProcess:
    def __init__(self, workers: int, tree: Path | None = None, extra=()):
        cmd = [sys.executable, "-m", "guardian.cli", "serve", "--port", "0", "--json", "--max-sessions", "5000",
               "--session-ttl", "600", *extra]
        if tree is None:
            cmd += ["--workers", str(workers)]
        env = {**os.environ, "PYTHONPATH": str(tree or ROOT)}
        self.started = time.perf_counter()
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     cwd=str(tree or ROOT), env=env)
        lines = []
        while not lines or lines[-1] != "}":
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError("the server did not start: " + self.proc.stderr.read())
            lines.append(line.rstrip("\n"))
        self.info = json.loads("\n".join(lines))
        host, port = self.info["url"].removeprefix("http://").split(":")
        self.address = (host, int(port))
        self.workers = workers

    def pids(self) -> list[int]:
        pid = self.proc.pid
        try:
            children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        except OSError:
            children = []
        return [pid, *map(int, children)]

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

    def wait_ready(self, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                status, _ = asyncio.run(one_request(self.address, "GET", "/ready"))
                if status in (200, 404):  # 404: a revision without /ready
                    return
            except OSError:
                pass
            time.sleep(0.05)
        raise RuntimeError("the server never became ready")

    def stop(self) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


# ---- clients: prepared bytes over asyncio protocols ----------------------------------------------------

def _head(method: str, path: str, body: bytes, extra: str = "") -> bytes:
    return (f"{method} {path} HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n{extra}"
            f"Content-Length: {len(body)}\r\n\r\n").encode() + body


async def one_request(address, method: str, path: str, body: bytes = b"", extra: str = "") -> tuple[int, bytes]:
    reader, writer = await asyncio.open_connection(*address)
    try:
        writer.write(_head(method, path, body, extra))
        return await read_response(reader)
    finally:
        writer.close()


async def read_response(reader) -> tuple[int, bytes]:
    head = await reader.readuntil(b"\r\n\r\n")
    status = int(head[9:12])
    length = int(head.lower().split(b"content-length:")[1].split(b"\r\n")[0]) if b"content-length" in head.lower() else 0
    return status, await reader.readexactly(length)


def ws_frame(payload: bytes) -> bytes:
    """A masked text frame with the all-zero mask (RFC 6455 allows it; the payload needs no XOR)."""
    n = len(payload)
    if n < 126:
        header = bytes([0x81, 0x80 | n])
    elif n < 65536:
        header = bytes([0x81, 0x80 | 126]) + n.to_bytes(2, "big")
    else:
        header = bytes([0x81, 0x80 | 127]) + n.to_bytes(8, "big")
    return header + b"\0\0\0\0" + payload


class Client:
    """One session's connection in the timed phase: prepared requests, one at a time (the next when the
    last is answered), timed. Driven by ``drive`` (a bare epoll loop: ~10 us of client CPU per step)."""

    def __init__(self, sock, requests: list, stream: bool):
        self.sock, self.requests, self.stream = sock, requests, stream
        self.buf = bytearray()
        self.i = 0
        self.sent_at = 0.0
        self.last = b""
        self.errors = []
        self.keep_last = False  # time-limited runs: the last answer is whichever came last

    @property
    def answered(self) -> int:
        return self.i

    def next_answer(self) -> bool:
        """Consume one whole answer from the buffer (keeping the body of the last one); False if none yet."""
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
            if buf[at + 2:at + 7] == b"error":
                self.errors.append(bytes(buf[at:at + 80]))
        else:
            end = buf.find(b"\r\n\r\n")
            if end < 0:
                return False
            k = buf.find(b"content-length: ", 0, end)
            if k < 0:  # nginx capitalises
                k = buf.find(b"Content-Length: ", 0, end)
            total = end + 4 + int(buf[k + 16:buf.find(b"\r", k)])
            if len(buf) < total:
                return False
            if buf[9:12] != b"200":
                self.errors.append(int(buf[9:12]))
            at = end + 4
        if self.i == len(self.requests) - 1 or self.keep_last:
            self.last = bytes(buf[at:total])
        del buf[:total]
        return True


def drive(clients: list, lat: list, duration: float | None = None) -> int:
    """Run the clients on a bare epoll loop over the prepared sockets, each to its last request, or until
    ``duration`` seconds have passed (then no new request is sent, the answers in flight are awaited and
    not counted). Returns the number of answers counted (those in ``lat``)."""
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
    for c in clients:
        c.sent_at = clock()
        c.sock.sendall(c.requests[0])
    remaining = len(clients)
    while remaining:
        for fd, _ in ep.poll():
            c = by_fd[fd]
            data = c.sock.recv(65536)  # not more: a 256 KiB recv buffer costs ~11 us to allocate
            if not data:
                c.errors.append("connection lost")
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
                if c.i == len(c.requests) or not counting:
                    ep.unregister(fd)
                    remaining -= 1
                    break
                c.sent_at = now
                c.sock.sendall(c.requests[c.i])
    ep.close()
    return len(lat)


async def _open(address, traj: dict, n: int, transport: str, api: str):
    """Connect, create a session, prepare its requests (and the stream), return the client."""
    reader, writer = await asyncio.open_connection(*address)
    writer.write(_head("POST", "/sessions", b"{}"))
    status, body = await read_response(reader)
    if status != 201:
        raise RuntimeError(f"session not created: {status} {body[:200]!r}")
    created = json.loads(body)
    sid, secret = created["session"], created.get("secret")
    extra = f"Session-Secret: {secret}\r\n" if secret else ""
    bodies = []
    for k, (state, u) in enumerate(traj["steps"][:n]):
        step = {"seq": k, "state": state, "input": u} if api == "new" else {"state": state, "input": u}
        bodies.append(json.dumps(step).encode())
    if transport == "stream":
        writer.write((f"GET /sessions/{sid}/stream HTTP/1.1\r\nHost: localhost\r\nUpgrade: websocket\r\n"
                      f"Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                      f"Sec-WebSocket-Version: 13\r\n{extra}\r\n").encode())
        head = await reader.readuntil(b"\r\n\r\n")
        if head[9:12] != b"101":
            raise RuntimeError(f"stream refused: {head[:200]!r}")
        requests = [ws_frame(b) for b in bodies]
    else:
        requests = [_head("POST", f"/sessions/{sid}/step", b, extra) for b in bodies]
    sock = writer.transport.get_extra_info("socket").dup()
    writer.transport.pause_reading()
    writer.transport.abort()  # keep the socket (dup) for the bare driver
    return Client(sock, requests, transport == "stream"), sid, secret


async def _open_all(address, trajs, clients: int, n: int, transport: str, api: str) -> list:
    opened = []
    for start in range(0, clients, 100):  # connect in batches (the listen queue and our own loop)
        opened += await asyncio.gather(*(_open(address, trajs[k % len(trajs)], n, transport, api)
                                         for k in range(start, min(clients, start + 100))))
    return opened


def machine_busy_seconds() -> float:
    """CPU seconds every process of the machine has used (user + nice + system + irq + softirq + steal)."""
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    user, nice, system, idle, iowait, irq, softirq, steal = (int(v) for v in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def wait_quiet(threshold: float, max_wait: float) -> float:
    """Wait (up to ``max_wait`` s) for a second in which the machine is busier than ``threshold`` of its
    cores by less; returns the share of that last second (other users of a shared machine)."""
    deadline = time.monotonic() + max_wait
    while True:
        b0, t0 = machine_busy_seconds(), time.perf_counter()
        time.sleep(1.0)
        share = (machine_busy_seconds() - b0) / (time.perf_counter() - t0) / (os.cpu_count() or 1)
        if share < threshold or time.monotonic() > deadline:
            return share


def _run_clients(address, trajs, clients: int, n: int, transport: str, api: str, server, duration=None):
    opened = asyncio.run(_open_all(address, trajs, clients, n, transport, api))
    lat = []
    for c, _, _ in opened[:4]:
        c.keep_last = duration is not None
    cpu0, t0, own0, busy0 = server.cpu_seconds(), time.perf_counter(), time.process_time(), machine_busy_seconds()
    drive([c for c, _, _ in opened], lat, duration)
    wall = duration if duration else time.perf_counter() - t0
    answered = sum(c.answered for c, _, _ in opened)
    _run_clients.answered = answered
    cpu, own = server.cpu_seconds() - cpu0, time.process_time() - own0
    others = max(0.0, machine_busy_seconds() - busy0 - cpu - own)
    _run_clients.others_share = others / wall / (os.cpu_count() or 1)  # of the machine, during the timed phase
    errors = [e for c, _, _ in opened for e in c.errors]
    lasts = [(c.last, sid, secret, c.answered) for c, sid, secret in opened]
    for c, _, _ in opened:
        c.sock.close()
    asyncio.run(_delete_all(address, [(sid, secret) for _, sid, secret in opened]))
    return lat, errors, wall, cpu, own, lasts


async def _delete_all(address, sessions) -> None:
    for start in range(0, len(sessions), 100):
        await asyncio.gather(*(one_request(address, "DELETE", f"/sessions/{sid}", b"",
                                           f"Session-Secret: {secret}\r\n" if secret else "")
                               for sid, secret in sessions[start:start + 100]))


DURATION = 3.0       # seconds of a timed run with more than one client (no tail of clients finishing late)
RATE_BOUND = 12_000  # steps/s no configuration here reaches: requests prepared per client = rate x duration / clients


def measure(server: ServerProcess, trajs, clients: int, transport: str, api: str, library=None) -> dict:
    """One run: with one client a fixed number of steps; with more, every client steps for DURATION seconds
    (throughput = the answers within it / DURATION: no tail of clients finishing late)."""
    if clients == 1:
        n, duration = STEPS_PER_CLIENT[1], None
    else:
        n, duration = min(len(trajs[0]["steps"]), int(RATE_BOUND * DURATION / clients) + 10), DURATION
    lat, errors, wall, cpu, own, lasts = _run_clients(server.address, trajs, clients, n, transport, api, server,
                                                      duration)
    checked = mismatched = 0
    if library is not None:  # the last answer of a few sessions against the local guardian
        for k, (last, _, _, answered) in enumerate(lasts[:4]):
            if answered:
                want = expected_applied(library, trajs[k % len(trajs)], answered)
                checked += 1
                mismatched += json.loads(last)["applied"] != want
    exhausted = sum(answered == n for *_, answered in lasts) if duration else 0
    ms = np.array(lat) * 1e3
    total = _run_clients.answered
    return {"workers": server.workers, "clients": clients, "transport": transport, "steps": int(ms.size),
            "errors": len(errors), "steps_per_s": round(ms.size / wall, 1),
            "p50_ms": round(float(np.percentile(ms, 50)), 3), "p99_ms": round(float(np.percentile(ms, 99)), 3),
            "server_cpu_ms_per_step": round(cpu / total * 1e3, 4), "client_cpu_ms_per_step": round(own / total * 1e3, 4),
            "clients_that_ran_out_of_steps": exhausted,
            "checked": checked, "mismatched": mismatched, "error_sample": [str(e) for e in errors[:3]],
            "others_cpu_share": round(_run_clients.others_share, 3)}


def memory(server: ServerProcess, trajs, sessions: int = 300, steps: int = 60, api: str = "new") -> dict:
    """RSS of the server before, with ``sessions`` sessions stepped ``steps`` times, and after deleting them."""
    before = server.rss_mb()
    opened, errors = [], 0
    for start in range(0, sessions, 50):
        batch = asyncio.run(_open_all(server.address, trajs[start % len(trajs):] + trajs, min(50, sessions - start),
                                      steps, "http", api))
        drive([c for c, _, _ in batch], [])
        errors += sum(len(c.errors) for c, _, _ in batch)
        for c, _, _ in batch:
            c.sock.close()
        opened += batch
    time.sleep(0.5)
    during = server.rss_mb()

    async def delete():
        for _, sid, secret in opened:
            extra = f"Session-Secret: {secret}\r\n" if secret else ""
            await one_request(server.address, "DELETE", f"/sessions/{sid}", b"", extra)

    asyncio.run(delete())
    time.sleep(0.5)
    after = server.rss_mb()
    return {"sessions": sessions, "steps_each": steps, "rss_before_mb": round(before, 1),
            "rss_with_sessions_mb": round(during, 1), "rss_after_delete_mb": round(after, 1),
            "mb_per_session": round((during - before) / sessions, 4), "errors": errors}


def first_step(tree: Path | None, trajs, api: str) -> dict:
    """A fresh server: seconds until its address is printed, and the first step's latency."""
    server = ServerProcess(1, tree)
    try:
        started = time.perf_counter() - server.started
        lat, errors, wall, cpu, own, _ = _run_clients(server.address, trajs, 1, 1, "http", api, server)
        _run_clients.answered = 1
        return {"seconds_to_listen": round(started, 2), "first_step_ms": round(lat[0] * 1e3, 2), "errors": len(errors)}
    finally:
        server.stop()


NGINX_CONF = """
worker_processes 1;
pid {tmp}/nginx.pid;
error_log {tmp}/error.log warn;
events {{ worker_connections 4096; }}
http {{
    access_log off;
    keepalive_requests 100000;  # nginx closes a client's keep-alive connection after 1,000 requests by default
    client_body_temp_path {tmp}/body; proxy_temp_path {tmp}/proxy;
    fastcgi_temp_path {tmp}/fcgi; uwsgi_temp_path {tmp}/uwsgi; scgi_temp_path {tmp}/scgi;
    map $uri $guardian_node {{
        ~^/sessions/(?<node>[a-z0-9-]+)\\.   $node;
        default                              any;
    }}
    map $http_upgrade $connection_upgrade {{ default upgrade; "" ""; }}
    upstream guardian_a   {{ server {a}; keepalive 64; }}
    upstream guardian_b   {{ server {b}; keepalive 64; }}
    upstream guardian_any {{ server {a}; server {b}; keepalive 64; }}
    server {{
        listen 127.0.0.1:{port};
        location / {{
            proxy_pass http://guardian_$guardian_node;
            proxy_http_version 1.1;
            proxy_set_header Host localhost;
            proxy_set_header Upgrade $http_upgrade;
            proxy_set_header Connection $connection_upgrade;
            proxy_read_timeout 120s;
        }}
    }}
}}
"""


def behind_nginx(trajs, library, clients=(1, 50, 200), repeat: int = 1, transports=("http", "stream")) -> list:
    """Two nodes of 2 workers behind nginx (docs/service.md), measured through it."""
    import shutil
    import socket
    import tempfile

    if shutil.which("nginx") is None:
        raise SystemExit("--nginx needs nginx on PATH (apt-get install nginx-light)")
    nodes = {name: ServerProcess(2, extra=("--node", name)) for name in ("a", "b")}
    for node in nodes.values():
        node.workers = 4  # both nodes' CPU is read below
        node.wait_ready()
    probe = socket.socket()
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        conf = Path(tmp) / "nginx.conf"
        conf.write_text(NGINX_CONF.format(tmp=tmp, port=port, a="%s:%d" % nodes["a"].address,
                                          b="%s:%d" % nodes["b"].address))
        nginx = subprocess.Popen(["nginx", "-p", tmp, "-c", str(conf), "-g", "daemon off;"],
                                 stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 10
            while True:
                try:
                    socket.create_connection(("127.0.0.1", port), timeout=1).close()
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        raise RuntimeError("nginx did not start: " + nginx.stderr.read())
                    time.sleep(0.05)

            class Both:
                address, workers = ("127.0.0.1", port), 4

                def cpu_seconds(self):
                    return sum(n.cpu_seconds() for n in nodes.values())

            for transport in transports:
                for n in clients:
                    reps = [measure(Both(), trajs, n, transport, "new", library) for _ in range(repeat)]
                    for r in reps:
                        r["server"] = "2 nodes x 2 workers behind nginx"
                        rows.append(r)
                        print(f"nginx  {transport:6s} {n:5d} clients: {r['steps_per_s']:8.0f} steps/s, p50 "
                              f"{r['p50_ms']} ms, p99 {r['p99_ms']} ms, errors {r['errors']}, replies checked "
                              f"{r['checked']} mismatched {r['mismatched']} {r['error_sample']}", file=sys.stderr, flush=True)
            health = [asyncio.run(one_request(n.address, "GET", "/health"))[1] for n in nodes.values()]
            created = [json.loads(h)["created"] for h in health]
            print(f"nginx  sessions created per node: {dict(zip(nodes, created))}", file=sys.stderr, flush=True)
            rows.append({"server": "nginx", "sessions_created_per_node": dict(zip(nodes, created))})
        finally:
            nginx.terminate()
            nginx.wait(10)
            for node in nodes.values():
                node.stop()
    return rows


WRK_SCRIPT = """
local counter = 0
function setup(thread)
  thread:set("id", counter)
  counter = counter + 1
end
function init(args)
  local f = io.open(args[1] .. "/" .. id .. ".req", "rb")
  local data = f:read("*a")
  f:close()
  reqs = {}
  for r in string.gmatch(data, "(.-)%z") do reqs[#reqs + 1] = r end
  -- wrk calls request() of the first thread once before the run (script_verify_request): give it a copy
  if id == 0 then table.insert(reqs, 1, reqs[1]) end
  i = 0
end
function request()
  i = i + 1
  if i > #reqs then i = #reqs end  -- past the prepared steps: the last again (a retry: its stored answer)
  return reqs[i]
end
"""


def _wrk_value(text: str, pattern: str) -> str | None:
    import re

    m = re.search(pattern, text)
    return m.group(1) if m else None


def _ms(value: str | None) -> float | None:
    if value is None:
        return None
    for unit, scale in (("us", 1e-3), ("ms", 1.0), ("s", 1e3)):
        if value.endswith(unit):
            return round(float(value[:-len(unit)]) * scale, 3)
    return None


def with_wrk(server: ServerProcess, trajs, clients: int, duration: float = DURATION) -> dict:
    """HTTP steps driven by wrk (C, one thread per connection, each thread its own session's prepared
    requests from a file): throughput and latency from a load generator this project did not write."""
    import shutil
    import tempfile

    if shutil.which("wrk") is None:
        raise SystemExit("--wrk needs wrk on PATH (apt-get install wrk)")
    n = min(len(trajs[0]["steps"]), int(RATE_BOUND * duration / clients) + 10)
    opened = asyncio.run(_open_all(server.address, trajs, clients, n, "http", "new"))
    with tempfile.TemporaryDirectory() as tmp:
        for k, (c, _, _) in enumerate(opened):
            Path(tmp, f"{k}.req").write_bytes(b"".join(r + b"\0" for r in c.requests))
            c.sock.close()
        script = Path(tmp, "steps.lua")
        script.write_text(WRK_SCRIPT)
        url = "http://%s:%d/" % server.address
        cpu0 = server.cpu_seconds()
        out = subprocess.run(["wrk", "-t", str(clients), "-c", str(clients), "-d", f"{duration:g}s", "--latency",
                              "-s", str(script), url, "--", tmp], capture_output=True, text=True, timeout=120).stdout
        cpu = server.cpu_seconds() - cpu0
    asyncio.run(_delete_all(server.address, [(sid, secret) for _, sid, secret in opened]))
    total = int(_wrk_value(out, r"(\d+) requests in") or 0)
    return {"workers": server.workers, "clients": clients, "client": "wrk", "steps": total,
            "steps_per_s": float(_wrk_value(out, r"Requests/sec:\s+([\d.]+)") or 0),
            "p50_ms": _ms(_wrk_value(out, r"50%\s+([\d.]+\w+)")), "p99_ms": _ms(_wrk_value(out, r"99%\s+([\d.]+\w+)")),
            "non_2xx": int(_wrk_value(out, r"Non-2xx or 3xx responses: (\d+)") or 0),
            "socket_errors": _wrk_value(out, r"Socket errors: (.*)"),
            "server_cpu_ms_per_step": round(cpu / total * 1e3, 4) if total else None,
            "ran_out_of_steps": total > n * clients}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--clients", type=int, nargs="+", default=[1, 50, 200, 1000])
    ap.add_argument("--transports", nargs="+", default=["http", "stream"], choices=["http", "stream"])
    ap.add_argument("--repeat", type=int, default=3, help="runs of each configuration (median and range reported)")
    ap.add_argument("--before", default=None, metavar="REV", help="also measure this revision's service")
    ap.add_argument("--no-memory", action="store_true")
    ap.add_argument("--nginx", action="store_true", help="only the two-node setup behind nginx (docs/service.md)")
    ap.add_argument("--quiet", type=float, default=1.0, metavar="SHARE",
                    help="--scaling: before each measurement wait for a second with the machine busy less than "
                         "SHARE (e.g. 0.1: other users take under 10 %% of the cores)")
    ap.add_argument("--quiet-wait", type=float, default=300.0, help="seconds to wait for such a second at most")
    ap.add_argument("--wrk", action="store_true",
                    help="only HTTP steps driven by wrk (one thread per session), servers in alternation")
    ap.add_argument("--scaling", action="store_true",
                    help="only throughput by workers, the servers measured in alternation (round r: every "
                         "worker count once), so that load from other processes falls on all of them alike")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    from intention.library import build_library

    library = build_library(quiet=True)
    t = time.perf_counter()
    trajs = trajectories(library, TRAJECTORIES, STEPS_PER_CLIENT[1])
    print(f"{len(trajs)} trajectories in {time.perf_counter() - t:.1f} s; intention identified on "
          f"{100 * np.mean([tr['identified'] for tr in trajs]):.0f} % of steps", file=sys.stderr)
    load = os.getloadavg()
    result = {"load_before": load, "cpus": os.cpu_count(), "runs": [], "memory": {}, "first_step": {}}

    if args.nginx:
        result["nginx"] = behind_nginx(trajs, library, tuple(args.clients), args.repeat, tuple(args.transports))
        if args.json:
            print(json.dumps(result, indent=2))
        return 0

    if args.wrk:
        servers = {w: ServerProcess(w) for w in args.workers}
        try:
            for server in servers.values():
                server.wait_ready()
            rows = []
            for clients in args.clients:
                for rnd in range(args.repeat):
                    got = {}
                    for w, server in servers.items():
                        before = wait_quiet(args.quiet, args.quiet_wait) if args.quiet < 1 else None
                        got[w] = {**with_wrk(server, trajs, clients), "machine_busy_before": before}
                    base = got[min(got)]["steps_per_s"]
                    print(f"wrk     http   {clients:5d} clients round {rnd}: " + ", ".join(
                        f"{w} w: {r['steps_per_s']:.0f} ({r['steps_per_s'] / base:.2f}x, p50 {r['p50_ms']} ms, "
                        f"p99 {r['p99_ms']} ms, non-2xx {r['non_2xx']}, server CPU {r['server_cpu_ms_per_step']} "
                        f"ms/step)" for w, r in got.items()), file=sys.stderr, flush=True)
                    rows.append({"clients": clients, "round": rnd, **{f"workers_{w}": r for w, r in got.items()}})
            result["wrk"] = rows
        finally:
            for server in servers.values():
                server.stop()
        if args.json:
            print(json.dumps(result, indent=2))
        return 0

    if args.scaling:
        servers = {w: ServerProcess(w) for w in args.workers}
        try:
            for server in servers.values():
                server.wait_ready()
            rows = []
            for transport in args.transports:
                for clients in args.clients:
                    for rnd in range(args.repeat):
                        got = {}
                        for w, server in servers.items():
                            before = wait_quiet(args.quiet, args.quiet_wait) if args.quiet < 1 else None
                            got[w] = measure(server, trajs, clients, transport, "new", library)
                            got[w]["machine_busy_before"] = before
                        base = got[min(got)]["steps_per_s"]
                        line = ", ".join(f"{w} w: {r['steps_per_s']:.0f} ({r['steps_per_s'] / base:.2f}x, others "
                                         f"{100 * r['others_cpu_share']:.0f} %)" for w, r in got.items())
                        print(f"scaling {transport:6s} {clients:5d} clients round {rnd}: {line}", file=sys.stderr,
                              flush=True)
                        rows.append({"transport": transport, "clients": clients, "round": rnd,
                                     **{f"workers_{w}": r for w, r in got.items()}})
            result["scaling"] = rows
        finally:
            for server in servers.values():
                server.stop()
        if args.json:
            print(json.dumps(result, indent=2))
        return 0

    def run_server(label, workers, tree, api):
        server = ServerProcess(workers, tree)
        try:
            server.wait_ready()
            for transport in args.transports:
                for clients in args.clients:
                    reps = [measure(server, trajs, clients, transport, api, library) for _ in range(args.repeat)]
                    rates = [r["steps_per_s"] for r in reps]
                    best = sorted(reps, key=lambda r: r["steps_per_s"])[len(reps) // 2]
                    row = {"server": label, **best, "steps_per_s_runs": rates,
                           "server_cpu_ms_runs": [r["server_cpu_ms_per_step"] for r in reps],
                           "others_cpu_share_runs": [r["others_cpu_share"] for r in reps],
                           "errors": sum(r["errors"] for r in reps), "mismatched": sum(r["mismatched"] for r in reps)}
                    result["runs"].append(row)
                    print(f"{label:6s} w={workers} {transport:6s} {clients:5d} clients: {statistics.median(rates):8.0f} "
                          f"steps/s [{min(rates):.0f}-{max(rates):.0f}], p50 {row['p50_ms']} ms, p99 {row['p99_ms']} ms, "
                          f"server CPU {row['server_cpu_ms_per_step']} ms/step, client CPU "
                          f"{row['client_cpu_ms_per_step']} ms/step, errors {row['errors']}, replies checked "
                          f"{4 * len(reps)} mismatched {row['mismatched']}, other processes "
                          f"{100 * max(r['others_cpu_share'] for r in reps):.0f} % of the machine at most",
                          file=sys.stderr, flush=True)
        finally:
            server.stop()

    def run_memory(label, tree, api):
        server = ServerProcess(1, tree)  # a fresh one: memory freed by earlier runs would hide the growth
        try:
            server.wait_ready()
            result["memory"][label] = memory(server, trajs, api=api)
            print(f"{label:6s} memory: {result['memory'][label]}", file=sys.stderr, flush=True)
        finally:
            server.stop()

    if args.before:
        from benchmarks.worktree import checkout

        with checkout(args.before) as tree:
            result["first_step"]["before"] = first_step(tree, trajs, "old")
            print(f"before first step: {result['first_step']['before']}", file=sys.stderr, flush=True)
            if not args.no_memory:
                run_memory("before", tree, "old")
            run_server("before", 1, tree, "old")
    result["first_step"]["after"] = first_step(None, trajs, "new")
    print(f"after  first step: {result['first_step']['after']}", file=sys.stderr, flush=True)
    if not args.no_memory:
        run_memory("after", None, "new")
    for workers in args.workers:
        run_server("after", workers, None, "new")
    result["load_after"] = os.getloadavg()
    if args.json:
        print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
