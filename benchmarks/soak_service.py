"""Soak: ``guardian serve`` under 200 connections for minutes; errors, and the server's fds and memory before and after.

Run: python benchmarks/soak_service.py [--minutes 5] [--clients 200] [--abort-share 0.05] [--stream-share 0.1]
                                       [--json]
Smoke: python benchmarks/soak_service.py --minutes 0.2 --clients 20

Starts ``python -m guardian.cli serve --port 0 --json`` (one worker, its defaults but ``--max-sessions``), waits
for ``/ready``, reads the server's open file descriptors (``/proc/PID/fd``) and resident memory (``VmRSS`` in
``/proc/PID/status``), then runs ``--clients`` threads at once, each on its own keep-alive connection, until
the time is up. Each round of a client is one of:

- a session's life over HTTP: ``POST /sessions``, 5 to 20 steps (random states inside the model's domain and
  random inputs), ``GET`` its summary, ``DELETE`` it (then, one time in ten, a new connection);
- the same with the steps over the session's WebSocket stream (``--stream-share`` of the rounds);
- an abort (``--abort-share``): a step whose body is cut short on a second connection, which is then reset
  (``SO_LINGER`` 0): the request never runs, and its connection must not be kept.

An error is any exception or any answer other than the one expected (201, 200, the step records). At the end the
clients close their connections, the server gets 2 s to see them go, and its fds and memory are read again, with
``/health`` (every session deleted: 0 live). The server is then stopped with SIGTERM (exit code reported).
Printed: requests, steps and rounds, throughput, latency p50/p99, errors (and the first few), fds and RSS at the
start, their peaks during the run (sampled every 5 s) and at the end. ``--json``: the same as JSON.
"""
from __future__ import annotations

import argparse
import http.client
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
    return float("nan")


def stderr_tail(proc) -> str:
    proc.stderr_file.seek(0)
    return proc.stderr_file.read()[-2000:]


def start_server(max_sessions: int) -> tuple[subprocess.Popen, tuple[str, int]]:
    cmd = [sys.executable, "-m", "guardian.cli", "serve", "--port", "0", "--json", "--max-sessions", str(max_sessions)]
    err = tempfile.TemporaryFile("w+")  # a file, not a pipe: a server logging much never blocks on it
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err, text=True, cwd=str(ROOT),
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    proc.stderr_file = err
    lines = []
    while not lines or lines[-1] != "}":
        line = proc.stdout.readline()
        if not line:
            raise RuntimeError(f"guardian serve did not start: {stderr_tail(proc)}")
        lines.append(line.rstrip("\n"))
    threading.Thread(target=proc.stdout.read, daemon=True).start()  # drained from now on
    url = json.loads("\n".join(lines))["url"]
    host, port = url.removeprefix("http://").rsplit(":", 1)
    address = (host, int(port))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            conn = http.client.HTTPConnection(*address, timeout=5)
            conn.request("GET", "/ready", headers={"Host": "localhost"})
            if conn.getresponse().status == 200:
                conn.close()
                return proc, address
            conn.close()
        except OSError:
            pass
        time.sleep(0.1)
    raise RuntimeError("guardian serve never became ready")


def step_body(rng: random.Random, seq: int) -> bytes:
    state = [rng.uniform(18, 32), rng.uniform(-0.8, 2.6), rng.uniform(-60, 80), rng.uniform(10, 33)]
    return json.dumps({"seq": seq, "state": state, "input": [rng.uniform(-3, 3), rng.uniform(-1.8, 1.8)]}).encode()


class Client(threading.Thread):
    def __init__(self, k: int, address, deadline: float, start: threading.Barrier, args):
        super().__init__(daemon=True)
        self.k, self.address, self.deadline, self.start_barrier, self.args = k, address, deadline, start, args
        self.rng = random.Random(k)
        self.requests = self.steps = self.rounds = self.aborts = self.streams = self.idle_reconnects = 0
        self.last_used = time.monotonic()
        self.latencies: list[float] = []
        self.errors: list[str] = []
        self.conn = None

    def call(self, method: str, path: str, body: bytes | None = None, headers: dict | None = None, expect: int = 200):
        if self.conn is not None and time.monotonic() - self.last_used > self.args.idle_reconnect:
            # the server closes a connection idle for its keep-alive timeout (5 s by default); a request sent on
            # it as it closes is lost (http.client does not retry): open a new one first, as clients do
            self.conn.close()
            self.conn = None
            self.idle_reconnects += 1
        if self.conn is None:
            self.conn = http.client.HTTPConnection(*self.address, timeout=30)
        h = {"Host": "localhost", **({"Content-Type": "application/json"} if body is not None else {}), **(headers or {})}
        t0 = time.perf_counter()
        try:
            self.conn.request(method, path, body=body, headers=h)
            resp = self.conn.getresponse()
            data = resp.read()
        except OSError as exc:
            raise OSError(f"{method} {path} on a connection idle {time.monotonic() - self.last_used:.2f} s: "
                          f"{exc!r}") from exc
        finally:
            self.last_used = time.monotonic()
        self.latencies.append(time.perf_counter() - t0)
        self.requests += 1
        if resp.status != expect:
            raise AssertionError(f"{method} {path}: {resp.status} {data[:200]!r}")
        if resp.getheader("connection", "").lower() == "close":
            self.conn.close()
            self.conn = None
        return json.loads(data)

    def session_round(self, stream: bool) -> None:
        created = self.call("POST", "/sessions", b"{}", expect=201)
        sid, auth = created["session"], {"Session-Secret": created["secret"]}
        n = self.rng.randint(5, 20)
        if stream:
            from websockets.sync.client import connect

            url = f"ws://{self.address[0]}:{self.address[1]}/sessions/{sid}/stream"
            with connect(url, additional_headers=auth, open_timeout=30) as ws:
                for seq in range(n):
                    t0 = time.perf_counter()
                    ws.send(step_body(self.rng, seq).decode())
                    reply = json.loads(ws.recv(timeout=30))
                    self.latencies.append(time.perf_counter() - t0)
                    if reply.get("t") != seq:
                        raise AssertionError(f"stream step {seq}: {reply!r:.200}")
            self.streams += 1
        else:
            for seq in range(n):
                record = self.call("POST", f"/sessions/{sid}/step", step_body(self.rng, seq), auth)
                if record.get("t") != seq:
                    raise AssertionError(f"step {seq}: {record!r:.200}")
        self.steps += n
        summary = self.call("GET", f"/sessions/{sid}", None, auth)
        if summary["steps"] != n:
            raise AssertionError(f"summary says {summary['steps']} steps, {n} sent")
        self.call("DELETE", f"/sessions/{sid}", None, auth)
        if self.rng.random() < 0.1 and self.conn is not None:
            self.conn.close()
            self.conn = None

    def abort_round(self) -> None:
        sock = socket.create_connection(self.address, timeout=30)
        sock.sendall(b"POST /sessions/n0.0.x.0123456789abcdef/step HTTP/1.1\r\nHost: localhost\r\n"
                     b"Content-Type: application/json\r\nContent-Length: 90\r\n\r\n{\"seq\": 0, \"state\": [25")
        time.sleep(self.rng.uniform(0, 0.05))
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
        sock.close()  # a reset
        self.aborts += 1

    def run(self) -> None:
        try:
            self.start_barrier.wait(60)
        except threading.BrokenBarrierError:
            self.errors.append("start barrier broken")
            return
        while time.monotonic() < self.deadline:
            r = self.rng.random()
            try:
                if r < self.args.abort_share:
                    self.abort_round()
                else:
                    self.session_round(stream=r < self.args.abort_share + self.args.stream_share)
                self.rounds += 1
            except Exception as exc:  # noqa: BLE001 - every failure is counted
                self.errors.append(repr(exc)[:300])
                if self.conn is not None:
                    self.conn.close()
                    self.conn = None
        if self.conn is not None:
            self.conn.close()


def percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def soak(args) -> dict:
    proc, address = start_server(max_sessions=max(1000, 2 * args.clients))
    pid = proc.pid
    try:
        time.sleep(1.0)
        start = {"fds": fds(pid), "rss_mb": rss_mb(pid)}
        deadline = time.monotonic() + args.minutes * 60
        barrier = threading.Barrier(args.clients)
        clients = [Client(k, address, deadline, barrier, args) for k in range(args.clients)]
        t0 = time.monotonic()
        for c in clients:
            c.start()
        peak_fds, peak_rss, samples = start["fds"], start["rss_mb"], []
        while any(c.is_alive() for c in clients):
            time.sleep(5.0 if time.monotonic() < deadline else 0.2)
            if proc.poll() is not None:
                raise RuntimeError(f"the server exited with {proc.returncode}: {stderr_tail(proc)}")
            f, r = fds(pid), rss_mb(pid)
            peak_fds, peak_rss = max(peak_fds, f), max(peak_rss, r)
            samples.append({"t_s": round(time.monotonic() - t0, 1), "fds": f, "rss_mb": round(r, 1)})
            if time.monotonic() > deadline + 120:
                break
        elapsed = time.monotonic() - t0
        stuck = sum(c.is_alive() for c in clients)
        time.sleep(2.0)
        end = {"fds": fds(pid), "rss_mb": rss_mb(pid)}
        conn = http.client.HTTPConnection(*address, timeout=10)
        conn.request("GET", "/health", headers={"Host": "localhost"})
        health = json.loads(conn.getresponse().read())
        conn.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            code = proc.wait()
        log = stderr_tail(proc)
    latencies = [x for c in clients for x in c.latencies]
    errors = [e for c in clients for e in c.errors]
    total = lambda name: sum(getattr(c, name) for c in clients)  # noqa: E731
    return {
        "minutes": args.minutes, "clients": args.clients, "seconds": round(elapsed, 1),
        "requests": total("requests"), "steps": total("steps"), "rounds": total("rounds"),
        "stream_rounds": total("streams"), "aborts": total("aborts"), "idle_reconnects": total("idle_reconnects"),
        "requests_per_s": round(total("requests") / elapsed, 1), "steps_per_s": round(total("steps") / elapsed, 1),
        "latency_ms_p50": round(1000 * percentile(latencies, 0.5), 2),
        "latency_ms_p99": round(1000 * percentile(latencies, 0.99), 2),
        "errors": len(errors), "first_errors": errors[:10], "clients_still_running": stuck,
        "server": {"pid": pid, "start": start, "peak": {"fds": peak_fds, "rss_mb": round(peak_rss, 1)}, "end": end,
                   "live_sessions_at_end": health.get("sessions"), "created": health.get("created"),
                   "closed": health.get("closed"), "exit_code_on_sigterm": code,
                   "stderr_tail": log[-600:]},
        "samples": samples,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=5.0, help="how long the clients run (default 5)")
    ap.add_argument("--clients", type=int, default=200, help="connections at once, one thread each (default 200)")
    ap.add_argument("--abort-share", type=float, default=0.05, help="rounds that are a request cut short and reset")
    ap.add_argument("--stream-share", type=float, default=0.1, help="rounds that step over the WebSocket stream")
    ap.add_argument("--idle-reconnect", type=float, default=4.0,
                    help="seconds idle after which a client opens a new connection rather than reuse its own "
                         "(below the server's keep-alive timeout, 5 s; a huge value shows the race at that timeout)")
    ap.add_argument("--json", action="store_true", help="print the result as JSON")
    args = ap.parse_args(argv)
    result = soak(args)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        s = result["server"]
        print(f"soak: {result['clients']} clients for {result['seconds']} s: {result['requests']} requests "
              f"({result['requests_per_s']}/s), {result['steps']} steps ({result['steps_per_s']}/s), "
              f"{result['rounds']} rounds ({result['stream_rounds']} over the stream, {result['aborts']} aborts); "
              f"{result['idle_reconnects']} new connections for ones idle over {args.idle_reconnect:g} s")
        print(f"latency p50 {result['latency_ms_p50']} ms, p99 {result['latency_ms_p99']} ms")
        print(f"errors: {result['errors']}" + (f" (clients still running: {result['clients_still_running']})"
                                                if result["clients_still_running"] else ""))
        for e in result["first_errors"]:
            print(f"  {e}")
        print(f"server pid {s['pid']}: fds {s['start']['fds']} at start, {s['peak']['fds']} at peak, "
              f"{s['end']['fds']} at end; RSS {s['start']['rss_mb']:.1f} MB at start, {s['peak']['rss_mb']:.1f} MB "
              f"at peak, {s['end']['rss_mb']:.1f} MB at end")
        print(f"sessions: {s['created']} created, {s['closed']} closed, {s['live_sessions_at_end']} live at the end; "
              f"exit code on SIGTERM: {s['exit_code_on_sigterm']}")
    return 0 if result["errors"] == 0 and result["clients_still_running"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
