"""GET /api/state while many websocket clients are served: its latency (p50, p99, max) and
timeouts, the dashboard's CPU, and how many clients were still served at the end.

Processes as in `dashboard_lag`: this one holds the router, runs the websocket clients (each
reading every message) and the API poller; `python -m services.dashboard` serves; a publisher
process puts FusionState at 200 Hz.

    python -m benchmarks.dashboard_clients [--seconds 60] [--clients 50] [--poll-hz 10]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time

import httpx
import numpy as np

from benchmarks.dashboard_lag import ROOT, _client, _cpu_s, dashboard_on_bus

TARGET_P99_MS = 100.0
TIMEOUT_S = 0.5  # what the probe used: a slower answer counts as a timeout


def _poll(url: str, period_s: float, out: list[float], timeouts: list[int], stop: threading.Event) -> None:
    with httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        next_t = time.monotonic()
        while not stop.is_set():
            t = time.perf_counter()
            try:
                c.get("/api/state").raise_for_status()
                out.append((time.perf_counter() - t) * 1e3)
            except httpx.TimeoutException:
                timeouts.append(1)
            next_t += period_s
            time.sleep(max(0.0, next_t - time.monotonic()))


def run(seconds: float, clients: int, rate_hz: float, poll_hz: float) -> dict[str, float]:
    with dashboard_on_bus("cli") as (endpoint, prefix, port, dash, env):
        stop = threading.Event()
        samples: list[list[tuple[float, float]]] = [[] for _ in range(clients)]
        threads = [
            threading.Thread(target=_client, args=(f"ws://127.0.0.1:{port}/ws", samples[i], stop), daemon=True)
            for i in range(clients)
        ]
        for t in threads:
            t.start()
        lat_ms: list[float] = []
        timeouts: list[int] = []
        poller = threading.Thread(
            target=_poll, args=(f"http://127.0.0.1:{port}", 1.0 / poll_hz, lat_ms, timeouts, stop), daemon=True
        )
        cpu0, wall0 = _cpu_s(dash.pid), time.monotonic()
        publisher = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.dashboard_lag", "--publisher", endpoint, prefix]
            + ["--seconds", str(seconds + 3), "--rate", str(rate_hz)],
            cwd=ROOT,
            env=env,
        )
        time.sleep(2.0)  # benchmark only: the publisher's first states reach the clients
        poller.start()
        time.sleep(seconds)
        served = httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=10).json().get("websocket", {})
        cpu_share = (_cpu_s(dash.pid) - cpu0) / (time.monotonic() - wall0)
        stop.set()
        poller.join(5)
        for t in threads:
            t.join(5)
        publisher.wait(60)
    lat = np.array(lat_ms)
    if lat.size == 0:
        raise RuntimeError("GET /api/state never answered")
    return {
        "requests": float(lat.size + len(timeouts)),
        "timeouts": float(len(timeouts)),
        "p50_ms": float(np.percentile(lat, 50)),
        "p99_ms": float(np.percentile(lat, 99)),
        "max_ms": float(lat.max()),
        "clients_served": float(served.get("clients", -1)),
        "clients_dropped": float(served.get("dropped_slow", -1)),
        "states_per_client": float(np.mean([len(s) for s in samples])),
        "dashboard_cpu_percent": 100.0 * cpu_share,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--rate", type=float, default=200.0, help="state rate, Hz (the gyro rate)")
    ap.add_argument("--poll-hz", type=float, default=10.0, help="GET /api/state rate")
    a = ap.parse_args(argv)
    r = run(a.seconds, a.clients, a.rate, a.poll_hz)
    print(
        f"GET /api/state with {a.clients} websocket clients, {a.rate:g} Hz states, {a.seconds:g} s: "
        f"{r['requests']:.0f} requests, {r['timeouts']:.0f} over {TIMEOUT_S:g} s\n"
        f"  latency p50 {r['p50_ms']:.1f} ms, p99 {r['p99_ms']:.1f} ms (target < {TARGET_P99_MS:g} ms), "
        f"max {r['max_ms']:.1f} ms\n"
        f"  clients served at the end {r['clients_served']:.0f}, dropped {r['clients_dropped']:.0f}; "
        f"{r['states_per_client']:.0f} states per client\n"
        f"  dashboard process CPU: {r['dashboard_cpu_percent']:.0f} % of one core"
    )
    return 0 if r["p99_ms"] < TARGET_P99_MS and r["timeouts"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
