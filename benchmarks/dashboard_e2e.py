"""End-to-end display lag on the whole simulated system: from the time a fusion state describes
(the gyro sample's arrival stamp at the gateway) to the websocket message carrying it leaving
the dashboard, beside fusion's deliberate hold (`lag_ms`) and the dashboard's own share.

Processes: a router held here, `services.bench` (demo scenario, measurement tier, device
bytes through a pseudo-terminal), `services.sensor_gateway`, `services.fusion` (with the
session's as-calibrated constants) and `services.dashboard`; a websocket client here.

    python -m benchmarks.dashboard_e2e [--seconds 20] [--seed 1]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import yaml

from benchmarks.dashboard_lag import ROOT, _free_port, _wait_http
from tiplog.bus import Bus, BusConfig

PAPER_MS = 33.0


def _calibration(tmp: Path, seed: int) -> Path:
    """The session's "as calibrated" constants (what an estimator may use) as a file."""
    from tiplog.calibration import Calibration
    from tiplog.mcap_io import read_metadata

    session = tmp / "calibration-session.mcap"
    subprocess.run(
        [sys.executable, "-m", "tiplog.cli", "sim", "generate", "--scenario", "demo", "--duration", "1"]
        + ["--seed", str(seed), "--out", str(session), "--force"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    out = tmp / "calibration.yaml"
    Calibration.from_mcap_metadata(read_metadata(session)).save_yaml(out)
    return out


def _collect(url: str, rows: list[tuple[float, float]], stop: threading.Event) -> None:
    from websockets.sync.client import connect

    with connect(url) as ws:
        hello = json.loads(ws.recv(timeout=60))
        t0, lag_col = hello["t0_ns"], hello["columns"]["state"].index("lag_ms")
        history = True  # the first batch holds states from before we connected
        while not stop.is_set():
            try:
                msg = json.loads(ws.recv(timeout=0.5))
            except TimeoutError:
                continue
            if msg.get("type") != "batch":
                continue
            if history:
                history = False
                continue
            for r in msg["state"]:
                rows.append(((msg["sent_ns"] - (t0 + r[0] * 1e6)) / 1e6, r[lag_col]))


def run(seconds: float, seed: int) -> dict[str, float]:
    tmp = Path(tempfile.mkdtemp(prefix="tiplog-e2e-"))
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    prefix = f"e2e{_free_port()}/"
    port = _free_port()
    cal = str(_calibration(tmp, seed))
    device = str(tmp / "device")
    config = {
        "bench": {"scenario": "demo", "camera_tier": "measurement", "device_link": device, "seed": seed},
        "sensor_gateway": {"port": device},
        "fusion": {"calibration_file": cal},
        "dashboard": {"port": port},
    }
    (tmp / "system.yaml").write_text(yaml.safe_dump(config))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    procs: list[subprocess.Popen] = []
    rows: list[tuple[float, float]] = []
    with Bus(BusConfig(mode="router", listen=[endpoint], connect=[], prefix=prefix)):
        try:
            for name in ("bench", "sensor_gateway", "fusion", "dashboard"):
                procs.append(
                    subprocess.Popen(
                        [sys.executable, "-m", f"services.{name}", "-c", str(tmp / "system.yaml")]
                        + ["--connect", endpoint, "--prefix", prefix, "--log-level", "WARNING"],
                        cwd=ROOT,
                        env=env,
                    )
                )
            _wait_http(port, procs[-1])
            time.sleep(10.0)  # benchmark only: the bench simulates its pass, fusion initialises
            stop = threading.Event()
            t = threading.Thread(target=_collect, args=(f"ws://127.0.0.1:{port}/ws", rows, stop), daemon=True)
            t.start()
            time.sleep(seconds)
            stop.set()
            t.join(5)
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait(10)
    if not rows:
        raise RuntimeError("no fusion state reached the websocket client")
    a = np.array(rows)
    total, hold = a[:, 0], a[:, 1]
    own = total - hold  # from fusion's publish to the websocket message leaving
    pct = {
        f"{name}_{q}_ms": float(np.percentile(v, q))
        for name, v in (("total", total), ("hold", hold), ("after_fusion", own))
        for q in (50, 95)
    }
    return {"states": float(len(a)), "rate_hz": len(a) / seconds, **pct}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    r = run(a.seconds, a.seed)
    print(
        f"end-to-end display lag, whole simulated system, {a.seconds:g} s, {r['states']:.0f} states "
        f"({r['rate_hz']:.0f} Hz):\n"
        f"  state time (gyro arrival) -> websocket message leaves: p50 {r['total_50_ms']:.1f} ms, "
        f"p95 {r['total_95_ms']:.1f} ms (paper: {PAPER_MS:g} ms)\n"
        f"  of which fusion's hold (lag_ms):                      p50 {r['hold_50_ms']:.1f} ms, p95 {r['hold_95_ms']:.1f} ms\n"
        f"  fusion's publish -> websocket message leaves:         p50 {r['after_fusion_50_ms']:.2f} ms, "
        f"p95 {r['after_fusion_95_ms']:.2f} ms"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
