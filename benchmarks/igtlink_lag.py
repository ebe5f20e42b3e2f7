"""OpenIGTLink to 3D Slicer: the rate a client gets TRANSFORMs at and their lag, from a state's
stamp to the moment pyigtl's client (another process) has parsed it, p50/p95/p99.

Four processes on one host clock (CLOCK_MONOTONIC): this one holds the router; a publisher puts
FusionState at 200 Hz (a tip moving on a slow circle, a fixed shaft) stamped now_ns() just
before each put;
`python -m services.igtlink` serves at `--rate`; the pyigtl client writes what it receives.
Fusion's deliberate hold (30 ms, `lag_ms` in each state) comes on top of these figures.

    python -m benchmarks.igtlink_lag [--seconds 20] [--rate 50] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.dashboard_lag import _free_port
from tiplog.bus import Bus, BusConfig
from tiplog.clock import now_ns

ROOT = Path(__file__).resolve().parents[1]


def _rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.endswith("}")]


def publisher(endpoint: str, prefix: str, seconds: float) -> int:
    """Child process: FusionState at 200 Hz, each stamped now_ns() just before its put."""
    from tiplog.v1.fusion_pb2 import FusionState

    with Bus(BusConfig(connect=[endpoint], prefix=prefix), service="fusion") as bus:
        pub = bus.publisher("fusion/state")
        time.sleep(1.0)  # benchmark only: let the service's subscription propagate
        t_next = time.monotonic()
        end = t_next + seconds
        k = 0
        while time.monotonic() < end:
            st = FusionState(depth_mm=140.0)
            st.tip_m.x, st.tip_m.y, st.tip_m.z = 0.7 + 0.01 * np.cos(k / 200), 0.01 * np.sin(k / 200), 0.18
            st.orientation.y, st.orientation.w = 0.96, 0.28  # about 148 deg about y: the shaft points down
            st.header.seq, st.header.stamp_ns = k, now_ns()
            pub.put(st)
            k += 1
            t_next += 1 / 200
            time.sleep(max(0.0, t_next - time.monotonic()))
    print(json.dumps({"published": k}))
    return 0


def run(seconds: float, rate_hz: float) -> dict[str, float]:
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    prefix = f"igtl{_free_port()}/"
    port = _free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = Path(tempfile.mkdtemp(prefix="igtlink-lag-")) / "client.jsonl"
    with Bus(BusConfig(mode="router", listen=[endpoint], connect=[], prefix=prefix)):
        svc = subprocess.Popen(
            [sys.executable, "-m", "services.igtlink", "--connect", endpoint, "--prefix", prefix]
            + ["--set", f"port={port}", "--set", f"rate_hz={rate_hz}", "--log-level", "WARNING"],
            cwd=ROOT,
            env=env,
        )
        client = subprocess.Popen(
            [sys.executable, "-m", "tests.helpers.igtl_client", "127.0.0.1", str(port), str(out)], cwd=ROOT, env=env
        )
        try:
            deadline = time.monotonic() + 60
            while not any(r["type"] == "STRING" for r in _rows(out)):  # connected: the status came
                if time.monotonic() > deadline or svc.poll() is not None:
                    raise RuntimeError("the client never connected to the igtlink service")
                time.sleep(0.1)
            pub = subprocess.run(
                [sys.executable, "-m", "benchmarks.igtlink_lag", "--publisher", endpoint, prefix]
                + ["--seconds", str(seconds)],
                cwd=ROOT,
                env=env,
                timeout=seconds + 60,
                capture_output=True,
                text=True,
            )
            time.sleep(0.5)  # benchmark only: the last messages
            if pub.returncode:
                raise RuntimeError(f"publisher exited with {pub.returncode}: {pub.stderr[-500:]}")
            published = json.loads(pub.stdout.strip().splitlines()[-1])["published"]
        finally:
            for p in (client, svc):
                p.terminate()
                p.wait(10)
    tips = [r for r in _rows(out) if r["device"] == "TipToReference" and r["metadata"].get("TransformStatus") == "OK"]
    if len(tips) < 2:
        raise RuntimeError("no valid transform reached the client")
    stamps = np.array([int(r["metadata"]["StampNs"]) for r in tips])
    lag_ms = (np.array([r["received_ns"] for r in tips]) - stamps) / 1e6
    span_s = (stamps[-1] - stamps[0]) / 1e9
    return {
        "states_published": float(published),
        "states_hz": float(published / seconds),
        "transforms": float(len(tips)),
        "rate_hz": float((len(tips) - 1) / span_s),
        "configured_hz": rate_hz,
        "lag_p50_ms": float(np.percentile(lag_ms, 50)),
        "lag_p95_ms": float(np.percentile(lag_ms, 95)),
        "lag_p99_ms": float(np.percentile(lag_ms, 99)),
        "lag_max_ms": float(lag_ms.max()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--rate", type=float, default=50.0, help="igtlink rate_hz")
    ap.add_argument("--json", action="store_true", help="also print the figures as one JSON line")
    ap.add_argument("--publisher", nargs=2, metavar=("ENDPOINT", "PREFIX"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.publisher:
        return publisher(a.publisher[0], a.publisher[1], a.seconds)
    r = run(a.seconds, a.rate)
    print(
        f"OpenIGTLink, {a.seconds:g} s: {r['states_published']:.0f} states published ({r['states_hz']:.1f} Hz of 200), "
        f"service at {a.rate:g} Hz: {r['transforms']:.0f} tip transforms, {r['rate_hz']:.2f} Hz\n"
        f"  state stamp -> client has it: p50 {r['lag_p50_ms']:.2f} ms, p95 {r['lag_p95_ms']:.2f} ms, "
        f"p99 {r['lag_p99_ms']:.2f} ms, max {r['lag_max_ms']:.2f} ms"
    )
    if a.json:
        print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
