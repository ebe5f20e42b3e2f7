"""Display lag through the dashboard: from a state sample's stamp to the websocket message that
carries it leaving the dashboard (its `sent_ns`), p50/p95/p99, and to its arrival at a client.

Three processes on one host clock (CLOCK_MONOTONIC): this one holds the router and reads the
websocket; `python -m services.dashboard` serves; a publisher process puts FusionState at
200 Hz with header.stamp_ns = now_ns() just before each put, i.e. the gyro sample's arrival
stamp at the gateway with no filter work in between. Fusion's deliberate hold (30 ms in the
paper, `lag_ms` in each state) comes on top of these figures and is reported by fusion.

    python -m benchmarks.dashboard_lag [--seconds 20] [--clients 1]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from tiplog.bus import Bus, BusConfig
from tiplog.clock import now_ns

ROOT = Path(__file__).resolve().parents[1]
PAPER_MS = 33.0
TARGET_P95_MS = 15.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _state(k: int, stamp_ns: int, rate_hz: float):
    """A state on a slow figure of eight, 20 mm across, with depth and tilt moving."""
    from tiplog.v1 import fusion_pb2

    t = k / rate_hz
    st = fusion_pb2.FusionState(depth_mm=140.0 + 5.0 * np.sin(0.3 * t), tilt_deg=6.0 + 4.0 * np.sin(0.2 * t))
    st.tip_m.x, st.tip_m.y, st.tip_m.z = 0.6 + 0.01 * np.sin(0.5 * t), 0.01 * np.sin(1.0 * t), 0.2 + 0.002 * np.cos(t)
    st.shaft_direction.z = -1.0
    st.header.seq = k
    st.header.stamp_ns = stamp_ns
    return st


def publisher(endpoint: str, prefix: str, seconds: float, rate_hz: float, prefill: int = 0) -> int:
    """Child process: `prefill` states at once (stamped as if 1/rate_hz apart in the past),
    then FusionState at `rate_hz`, stamped now_ns() just before each put."""
    with Bus(BusConfig(connect=[endpoint], prefix=prefix), service="fusion") as bus:
        pub = bus.publisher("fusion/state")
        time.sleep(1.0)  # benchmark only: let the dashboard's subscription propagate
        period = 1.0 / rate_hz
        start_ns = now_ns()
        for k in range(prefill):
            pub.put(_state(k, start_ns - int((prefill - k) * period * 1e9), rate_hz))
        t_next = time.monotonic()
        end = t_next + seconds
        k = prefill
        while time.monotonic() < end:
            pub.put(_state(k, now_ns(), rate_hz))
            k += 1
            t_next += period
            time.sleep(max(0.0, t_next - time.monotonic()))
    return 0


def _client(url: str, out: list[tuple[float, float]], stop: threading.Event) -> None:
    from websockets.sync.client import connect

    with connect(url) as ws:
        hello = json.loads(ws.recv(timeout=30))
        t0 = hello["t0_ns"]
        while not stop.is_set():
            try:
                raw = ws.recv(timeout=0.5)
            except TimeoutError:
                continue
            recv_ns = now_ns()
            msg = json.loads(raw)
            if msg.get("type") != "batch":
                continue
            for row in msg["state"]:
                stamp = t0 + row[0] * 1e6
                out.append(((msg["sent_ns"] - stamp) / 1e6, (recv_ns - stamp) / 1e6))


@contextmanager
def dashboard_on_bus(tag: str) -> Iterator[tuple[str, str, int, subprocess.Popen, dict[str, str]]]:
    """A router bus in this process on a free port and the dashboard service connected to it,
    answering HTTP: (endpoint, prefix, port, dashboard process, env for further processes).
    The dashboard is stopped on exit, whatever happened."""
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    prefix = f"{tag}{_free_port()}/"
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    with Bus(BusConfig(mode="router", listen=[endpoint], connect=[], prefix=prefix)):
        dash = subprocess.Popen(
            [sys.executable, "-m", "services.dashboard", "--connect", endpoint, "--prefix", prefix]
            + ["--set", f"port={port}", "--log-level", "WARNING"],
            cwd=ROOT,
            env=env,
        )
        try:
            _wait_http(port, dash)
            yield endpoint, prefix, port, dash, env
        finally:
            dash.terminate()
            dash.wait(10)


def run(seconds: float, clients: int, rate_hz: float) -> dict[str, float]:
    with dashboard_on_bus("lag") as (endpoint, prefix, port, dash, env):
        samples: list[list[tuple[float, float]]] = [[] for _ in range(clients)]
        stop = threading.Event()
        threads = [
            threading.Thread(target=_client, args=(f"ws://127.0.0.1:{port}/ws", samples[i], stop), daemon=True)
            for i in range(clients)
        ]
        for t in threads:
            t.start()
        cpu0, wall0 = _cpu_s(dash.pid), time.monotonic()
        pub = subprocess.run(
            [sys.executable, "-m", "benchmarks.dashboard_lag", "--publisher", endpoint, prefix]
            + ["--seconds", str(seconds), "--rate", str(rate_hz)],
            cwd=ROOT,
            env=env,
            timeout=seconds + 60,
        )
        cpu_share = (_cpu_s(dash.pid) - cpu0) / (time.monotonic() - wall0)
        time.sleep(0.5)  # benchmark only: the last batch
        stop.set()
        for t in threads:
            t.join(5)
        if pub.returncode:
            raise RuntimeError(f"publisher exited with {pub.returncode}")
    rows = np.array([s for per in samples for s in per])
    if rows.size == 0:
        raise RuntimeError("no state reached the websocket client")
    leave, arrive = rows[:, 0], rows[:, 1]
    return {
        "samples": float(len(rows)),
        "per_client": float(len(rows) / clients),
        "expected_per_client": seconds * rate_hz,
        "leave_p50_ms": float(np.percentile(leave, 50)),
        "leave_p95_ms": float(np.percentile(leave, 95)),
        "leave_p99_ms": float(np.percentile(leave, 99)),
        "leave_max_ms": float(leave.max()),
        "arrive_p50_ms": float(np.percentile(arrive, 50)),
        "arrive_p95_ms": float(np.percentile(arrive, 95)),
        "dashboard_cpu_percent": 100.0 * cpu_share,
    }


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of process `pid` (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _wait_http(port: int, proc: subprocess.Popen, timeout_s: float = 180.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"dashboard exited with {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.1)
    raise TimeoutError("dashboard did not listen")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--clients", type=int, default=1)
    ap.add_argument("--rate", type=float, default=200.0, help="state rate, Hz (the gyro rate)")
    ap.add_argument("--publisher", nargs=2, metavar=("ENDPOINT", "PREFIX"), help=argparse.SUPPRESS)
    ap.add_argument("--prefill", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.publisher:
        return publisher(a.publisher[0], a.publisher[1], a.seconds, a.rate, a.prefill)
    r = run(a.seconds, a.clients, a.rate)
    print(
        f"dashboard display lag, {a.clients} client(s), {a.rate:g} Hz, {a.seconds:g} s: "
        f"{r['per_client']:.0f} of {r['expected_per_client']:.0f} states per client\n"
        f"  stamp -> websocket message leaves: p50 {r['leave_p50_ms']:.2f} ms, p95 {r['leave_p95_ms']:.2f} ms, "
        f"p99 {r['leave_p99_ms']:.2f} ms, max {r['leave_max_ms']:.2f} ms "
        f"(target p95 < {TARGET_P95_MS:g} ms; paper {PAPER_MS:g} ms end to end incl. its 30 ms hold)\n"
        f"  stamp -> client has it:           p50 {r['arrive_p50_ms']:.2f} ms, p95 {r['arrive_p95_ms']:.2f} ms\n"
        f"  dashboard process CPU: {r['dashboard_cpu_percent']:.0f} % of one core"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
