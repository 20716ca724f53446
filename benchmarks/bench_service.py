"""Step latency of ``guardian serve`` for 1, 50 and 200 concurrent clients, over HTTP and the stream.

Run: python benchmarks/bench_service.py [--json] [--no-before]

The server runs in its own process (as in use); the clients are asyncio connections in this one.
"before" is the landed ``http.server`` service (commit a821829, read from git), measured in the
same run; it has no stream. Targets (issue 15): a single client's step under 1 ms median over
loopback, 0 connection errors at 200 clients.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BEFORE_COMMIT = "a821829"
PLAN = [(1, 2000, None), (50, 60, None), (200, 20, None), (50, 40, 10.0), (200, 30, 10.0)]
# (clients, steps each, control rate in Hz per client; None = flat out, each step sent as the last is answered)


def step_body(i: int) -> bytes:
    rng = np.random.default_rng(i)
    return json.dumps({"state": [float(rng.uniform(20, 30)), 0.0, float(rng.uniform(20, 60)), 20.0],
                       "input": [float(rng.uniform(-3, 3)), 0.0]}).encode()


def start_after() -> tuple[subprocess.Popen, tuple]:
    proc = subprocess.Popen([sys.executable, "-m", "guardian.cli", "serve", "--port", "0", "--json",
                             "--max-sessions", "5000"], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    while not lines or lines[-1] != "}":
        lines.append(proc.stdout.readline().rstrip("\n"))
    host, port = json.loads("\n".join(lines))["url"].removeprefix("http://").split(":")
    return proc, (host, int(port))


def start_before(tmp: Path) -> tuple[subprocess.Popen, tuple] | None:
    try:
        source = subprocess.run(["git", "show", f"{BEFORE_COMMIT}:guardian/service.py"], cwd=ROOT, check=True,
                                capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    (tmp / "old_service.py").write_text(source)
    runner = ("import sys; sys.path.insert(0, %r)\nfrom old_service import make_server\n"
              "from intention.library import build_library\n"
              "srv = make_server(build_library(quiet=True), '127.0.0.1', 0)\n"
              "print(srv.server_address[1], flush=True)\nsrv.serve_forever()\n") % str(tmp)
    proc = subprocess.Popen([sys.executable, "-c", runner], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    return proc, ("127.0.0.1", int(proc.stdout.readline()))


async def _http(reader, writer, method: str, path: str, body: bytes = b"") -> tuple[int, bytes]:
    writer.write(f"{method} {path} HTTP/1.1\r\nHost: x\r\nContent-Length: {len(body)}\r\n\r\n".encode() + body)
    head = await reader.readuntil(b"\r\n\r\n")
    status = int(head.split(b" ", 2)[1])
    length = next(int(line.split(b":")[1]) for line in head.split(b"\r\n") if line.lower().startswith(b"content-length"))
    return status, await reader.readexactly(length)


async def _pace(rate, t_next: float) -> float:
    if rate is None:
        return t_next
    await asyncio.sleep(max(0.0, t_next - time.perf_counter()))
    return t_next + 1.0 / rate


async def http_client(address, steps: int, seed: int, lat: list, errors: list, rate=None) -> None:
    try:
        reader, writer = await asyncio.open_connection(*address)
        _, body = await _http(reader, writer, "POST", "/sessions", b"{}")
        sid = json.loads(body)["session"]
        t_next = time.perf_counter() + (seed % 10) / (10 * rate) if rate else 0.0
        for i in range(steps):
            b = step_body(seed * 10_000 + i)
            t_next = await _pace(rate, t_next)
            t = time.perf_counter()
            status, _ = await _http(reader, writer, "POST", f"/sessions/{sid}/step", b)
            lat.append(time.perf_counter() - t)
            if status != 200:
                errors.append(f"status {status}")
        await _http(reader, writer, "DELETE", f"/sessions/{sid}")
        writer.close()
    except (OSError, asyncio.IncompleteReadError) as exc:
        errors.append(type(exc).__name__)


async def stream_client(address, steps: int, seed: int, lat: list, errors: list, rate=None) -> None:
    from websockets.asyncio.client import connect

    try:
        reader, writer = await asyncio.open_connection(*address)
        _, body = await _http(reader, writer, "POST", "/sessions", b"{}")
        sid = json.loads(body)["session"]
        async with connect(f"ws://{address[0]}:{address[1]}/sessions/{sid}/stream", max_size=2 ** 20) as ws:
            t_next = time.perf_counter() + (seed % 10) / (10 * rate) if rate else 0.0
            for i in range(steps):
                b = step_body(seed * 10_000 + i).decode()
                t_next = await _pace(rate, t_next)
                t = time.perf_counter()
                await ws.send(b)
                reply = await ws.recv()
                lat.append(time.perf_counter() - t)
                if '"error"' in reply:
                    errors.append("error reply")
        await _http(reader, writer, "DELETE", f"/sessions/{sid}")
        writer.close()
    except (OSError, asyncio.IncompleteReadError, Exception) as exc:  # noqa: BLE001 - counted
        errors.append(type(exc).__name__)


def run(address, clients: int, steps: int, kind: str, rate=None) -> dict:
    lat, errors = [], []
    client = http_client if kind == "http" else stream_client

    async def main():
        await asyncio.gather(*(client(address, steps, k, lat, errors, rate) for k in range(clients)))

    t0 = time.perf_counter()
    asyncio.run(main())
    wall = time.perf_counter() - t0
    ms = np.array(lat) * 1e3
    return {"clients": clients, "transport": kind, "rate_hz": rate, "steps": int(ms.size), "errors": len(errors),
            "median_ms": round(float(np.median(ms)), 3) if ms.size else None,
            "p99_ms": round(float(np.percentile(ms, 99)), 3) if ms.size else None,
            "steps_per_s": round(ms.size / wall, 1)}


def measure(label: str, started, kinds) -> list:
    if started is None:
        return []
    proc, address = started
    out = []
    try:
        for clients, steps, rate in PLAN:
            for kind in kinds:
                r = {"server": label, **run(address, clients, steps, kind, rate)}
                pace = f"{rate:g} Hz" if rate else "flat out"
                print(f"{label:7s} {kind:6s} {clients:4d} clients {pace:8s}: median {r['median_ms']} ms, p99 {r['p99_ms']} ms, "
                      f"{r['steps_per_s']} steps/s, connection errors {r['errors']}", file=sys.stderr)
                out.append(r)
    finally:
        proc.terminate()
        proc.wait(30)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-before", action="store_true", help="skip the http.server service of commit a821829")
    args = ap.parse_args()
    os.environ.setdefault("PYTHONPATH", str(ROOT))
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        if not args.no_before:
            results += measure("before", start_before(Path(tmp)), ["http"])
        results += measure("after", start_after(), ["http", "stream"])
    if args.json:
        print(json.dumps({"runs": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
