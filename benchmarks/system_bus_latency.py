"""Bus latency at 1 kHz between two processes on loopback: tiplog's bus (protobuf Gyro with
the sequence/type attachment) against raw Zenoh (the same number of bytes, no attachment),
both measured in the same run, one after the other, over the same kind of link.

One-way latency = receive time - send time on CLOCK_MONOTONIC (shared by every process on a
host). The publisher is a child process (`--publisher`), paced at the rate by sleeping to
absolute deadlines; the subscriber here records every arrival. Figures: median, p99 and max
latency [ms] and messages lost, per transport.

    python -m benchmarks.system_bus_latency [--seconds 10] [--rate 1000] [--json]
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from tiplog.bus import Bus, BusConfig
from tiplog.v1 import device_pb2

ROOT = Path(__file__).resolve().parents[1]
HEAD = struct.Struct("<qq")  # (seq, send_ns)


def _zenoh_config(endpoint: str, listen: bool) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints" if listen else "connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return conf


def publish(kind: str, endpoint: str, seconds: float, rate_hz: float) -> None:
    """Child: put rate_hz messages a second for `seconds` on bench/latency."""
    n = int(seconds * rate_hz)
    period_ns = int(1e9 / rate_hz)
    if kind == "tiplog":
        bus = Bus(BusConfig(mode="peer", connect=[endpoint], listen=[], prefix="lat/"))
        pub = bus.publisher("device/gyro")
        msg = device_pb2.Gyro()
        msg.rate_radps.x, msg.rate_radps.y, msg.rate_radps.z = 0.01, -0.02, 0.03

        def put(k: int) -> None:
            msg.header.seq = k
            msg.header.stamp_ns = time.monotonic_ns()
            pub.put(msg)
    else:
        session = zenoh.open(_zenoh_config(endpoint, listen=False))
        zpub = session.declare_publisher("lat/raw")
        pad = b"\0" * 40  # about a Gyro's size

        def put(k: int) -> None:
            zpub.put(HEAD.pack(k, time.monotonic_ns()) + pad)

    time.sleep(1.0)  # benchmark only: let the subscriber's declaration reach this session
    t0 = time.monotonic_ns()
    for k in range(n):
        delay = t0 + k * period_ns - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay / 1e9)
        put(k)
    time.sleep(0.5)


def measure(kind: str, seconds: float, rate_hz: float, port: int) -> dict:
    endpoint = f"tcp/127.0.0.1:{port}"
    lat_ns: list[int] = []
    seqs: list[int] = []
    lock = threading.Lock()
    if kind == "tiplog":
        bus = Bus(BusConfig(mode="peer", listen=[endpoint], connect=[], prefix="lat/"))

        def on(msg, _info) -> None:
            t = time.monotonic_ns()
            with lock:
                lat_ns.append(t - msg.header.stamp_ns)
                seqs.append(msg.header.seq)

        bus.subscribe("device/gyro", on)
        closer = bus.close
    else:
        session = zenoh.open(_zenoh_config(endpoint, listen=True))

        def on_raw(sample: zenoh.Sample) -> None:
            t = time.monotonic_ns()
            k, sent = HEAD.unpack_from(sample.payload.to_bytes())
            with lock:
                lat_ns.append(t - sent)
                seqs.append(k)

        sub = session.declare_subscriber("lat/raw", on_raw)

        def closer() -> None:
            sub.undeclare()
            session.close()

    try:
        subprocess.run(
            [sys.executable, "-m", "benchmarks.system_bus_latency", "--publisher", kind, endpoint]
            + ["--seconds", str(seconds), "--rate", str(rate_hz)],
            cwd=ROOT,
            check=True,
            timeout=seconds + 60,
        )
    finally:
        closer()
    n = int(seconds * rate_hz)
    lat_ms = np.asarray(lat_ns, np.float64) / 1e6
    if not len(lat_ms):
        raise RuntimeError(f"{kind}: no message arrived")
    return {
        "transport": kind,
        "sent": n,
        "received": len(set(seqs)),
        "lost": n - len(set(seqs)),
        "p50_ms": float(np.median(lat_ms)),
        "p99_ms": float(np.percentile(lat_ms, 99)),
        "max_ms": float(lat_ms.max()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="publishing time per transport [s]")
    ap.add_argument("--rate", type=float, default=1000.0, help="messages per second")
    ap.add_argument("--port", type=int, default=0, help="loopback port (default: a free one)")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON line at the end")
    ap.add_argument("--publisher", nargs=2, metavar=("KIND", "ENDPOINT"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.publisher:
        publish(a.publisher[0], a.publisher[1], a.seconds, a.rate)
        return 0
    import socket

    rows = []
    for kind in ("zenoh", "tiplog"):
        port = a.port
        if not port:
            with socket.socket() as s:
                s.bind(("127.0.0.1", 0))
                port = s.getsockname()[1]
        rows.append(measure(kind, a.seconds, a.rate, port))
    print(f"bus latency at {a.rate:.0f} Hz, {a.seconds:.0f} s each, publisher and subscriber in two processes")
    print(f"{'transport':10s} {'sent':>7s} {'lost':>6s} {'p50 ms':>8s} {'p99 ms':>8s} {'max ms':>8s}")
    for r in rows:
        print(
            f"{r['transport']:10s} {r['sent']:7d} {r['lost']:6d} {r['p50_ms']:8.3f} {r['p99_ms']:8.3f} {r['max_ms']:8.2f}"
        )
    if a.json:
        print(json.dumps({"rate_hz": a.rate, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
