"""Speed of one guardian step and of the HTTP service over loopback.

Run: python benchmarks/bench_guardian.py [--json]
Targets (issue 3): one guardian step (estimator update, admissible set, override)
median < 1 ms, 99th percentile < 5 ms.
"""
from __future__ import annotations

import argparse
import http.client
import json
import threading
import time

import numpy as np

from envs.drivers import make_driver
from envs.overtake import OvertakeEnv
from guardian.service import make_server
from guardian.supervisor import IntentionAwareGuardian
from rcis.library import build_library


def guardian_step_times(lib, use_intention: bool, episodes: int = 20) -> np.ndarray:
    env = OvertakeEnv({"intention": "cautious", "initial_region": lib.region("bounded_velocity")})
    guard = IntentionAwareGuardian(lib, use_intention=use_intention)
    times = []
    for ep in range(episodes):
        driver = make_driver("bad" if ep % 2 else "random")
        driver.reset(np.random.default_rng(ep))
        obs, _ = env.reset(seed=ep)
        guard.reset()
        done = False
        while not done:
            u = driver.act(obs)
            t = time.perf_counter()
            applied, _ = guard.step(obs, u)
            times.append(time.perf_counter() - t)
            obs, _, term, trunc, _ = env.step(applied)
            done = term or trunc
    return np.array(times)


def service_figures(lib, requests: int = 2000, clients: int = 2) -> dict:
    srv = make_server(lib, "127.0.0.1", 0)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    addr = srv.server_address

    def client(n, out):
        conn = http.client.HTTPConnection(*addr)
        conn.request("POST", "/sessions", body=b"{}")
        sid = json.loads(conn.getresponse().read())["session"]
        x = np.array([25.0, 0.0, 40.0, 20.0])
        model = lib.models["cautious"]
        for i in range(n):
            body = json.dumps({"state": x.tolist(), "input": [1.0, 0.0]}).encode()
            t = time.perf_counter()
            conn.request("POST", f"/sessions/{sid}/step", body=body)
            rec = json.loads(conn.getresponse().read())
            out.append(time.perf_counter() - t)
            x = model.system.step(x, rec["applied"], np.zeros(4))
            if x[2] < -50:  # passed the lead: start over
                x = np.array([25.0, 0.0, 40.0, 20.0])
        conn.close()

    single: list = []
    client(requests, single)
    lat = np.array(single)
    outs = [[] for _ in range(clients)]
    t = time.perf_counter()
    threads = [threading.Thread(target=client, args=(requests // clients, outs[i])) for i in range(clients)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    wall = time.perf_counter() - t
    srv.shutdown()
    srv.server_close()
    return {"latency_ms_median": float(np.median(lat) * 1e3), "latency_ms_p99": float(np.percentile(lat, 99) * 1e3),
            "throughput_steps_per_s_1_client": float(len(lat) / lat.sum()),
            f"throughput_steps_per_s_{clients}_clients": float(sum(map(len, outs)) / wall)}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    lib = build_library(quiet=True)
    out = {}
    for use in (True, False):
        t = guardian_step_times(lib, use)
        out["guardian_step_ms" + ("" if use else "_no_intention")] = {
            "median": float(np.median(t) * 1e3), "p99": float(np.percentile(t, 99) * 1e3), "steps": int(t.size)}
    out["service"] = service_figures(lib)
    if args.json:
        print(json.dumps(out, indent=2))
        return
    for k in ("guardian_step_ms", "guardian_step_ms_no_intention"):
        print(f"{k:32s} median {out[k]['median']:.3f} ms, p99 {out[k]['p99']:.3f} ms over {out[k]['steps']} steps "
              f"(target median < 1 ms, p99 < 5 ms)")
    s = out["service"]
    print(f"service step latency            median {s['latency_ms_median']:.3f} ms, p99 {s['latency_ms_p99']:.3f} ms")
    for k, v in s.items():
        if k.startswith("throughput"):
            print(f"service {k:24s} {v:.0f}")


if __name__ == "__main__":
    main()
