"""Per-frame time of the vision pipeline (labeler, network, total, preview) and the sustained
frames per second of `tiplog vision run` on a pixel-tier recording.

    python -m benchmarks.vision_frame --frames 60 --device cpu --threads 1
    python -m benchmarks.vision_frame --recording teleop.mcap   # an existing pixel-tier file

Without --recording a short teleoperated pixel-tier session is generated first (seed 4).

Per frame: the frames of that recording one after another on the chosen device (after a few
warm-up frames), p50/p95 of the wall time of each stage and of the CPU time of the thread
that ran it. On a shared host the wall time grows with the host's load while the CPU time
barely does: both are printed, with the load average.

Sustained: `tiplog vision run` as a user runs it (its own process: reading, decompressing,
processing and writing every frame), once per `--workers` value, frames/s from its own
summary line; the load average before and after each run is printed beside it. Note that a
Linux host with autogroup scheduling shares the CPU between sessions, not threads: when other
sessions keep the cores busy, a second worker gains little.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("labeler", "network", "total")


def _percentiles(xs: list[float]) -> dict[str, float]:
    a = np.asarray(xs)
    return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)), "mean": float(a.mean())}


def _load() -> float:
    return os.getloadavg()[0]


def per_frame(rec: Path, weights: Path, device: str, frames: int) -> tuple[dict, int, str]:
    """({stage_ms | stage_cpu_ms | preview_ms: percentiles}, frames timed, device)."""
    from services.vision.frames import decode_frame, recording_frames
    from services.vision.network import load_checkpoint
    from services.vision.pipeline import Pipeline
    from services.vision.preview import preview_message
    from tiplog.calibration import Calibration
    from tiplog.mcap_io import read_metadata

    seg, _ = load_checkpoint(weights, device)
    calib = Calibration.from_mcap_metadata(read_metadata(rec))
    pipe = Pipeline(seg, calib.shaft_radius_m)
    keys = [f"{s}_ms" for s in STAGES] + [f"{s}_cpu_ms" for s in STAGES]
    rows: dict[str, list[float]] = {k: [] for k in [*keys, "preview_ms"]}
    n = 0
    for k, _, msg, cam in recording_frames(rec):
        frame = decode_frame(msg, cam)
        res = pipe.process(frame, cam, msg.timestamp.ToNanoseconds(), k)
        t0 = time.perf_counter()
        preview_message(frame, res, cam)
        prev_ms = (time.perf_counter() - t0) * 1e3
        if k < 3:  # warm-up (allocator, caches, CUDA kernels)
            continue
        for key in keys:
            rows[key].append(res.timings_ms[key])
        rows["preview_ms"].append(prev_ms)
        n += 1
        if n >= frames:
            break
    if n == 0:
        raise SystemExit(f"{rec}: no camera frames after the warm-up (is it a pixel-tier recording?)")
    return {k: _percentiles(v) for k, v in rows.items()}, n, str(seg.device)


def sustained(rec: Path, weights: Path, device: str, threads: int, workers: int, timeout_s: float) -> dict:
    """`tiplog vision run` in its own process; frames/s from its summary line."""
    with tempfile.TemporaryDirectory() as d:
        cmd = [sys.executable, "-m", "tiplog.cli", "vision", "run", str(rec), "--out", str(Path(d) / "obs.mcap")]
        cmd += ["--weights", str(weights), "--device", device, "--threads", str(threads), "--workers", str(workers)]
        load_before = _load()
        t0 = time.perf_counter()
        p = subprocess.run(
            [*cmd, "--quiet"], cwd=ROOT, capture_output=True, text=True, timeout=timeout_s,
            env={**os.environ, "PYTHONPATH": str(ROOT)},
        )  # fmt: skip
        wall = time.perf_counter() - t0
    m = re.search(r"(\d+) frames, .* in ([\d.]+) s \(([\d.]+) frames/s\)", p.stderr)
    if p.returncode != 0 or not m:
        tail = (p.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"tiplog vision run --workers {workers} failed (exit {p.returncode}): {tail}")
    return {
        "workers": workers,
        "frames": int(m.group(1)),
        "seconds": float(m.group(2)),
        "fps": float(m.group(3)),
        "process_wall_s": wall,
        "load_before": load_before,
        "load_after": _load(),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.vision_frame", description=__doc__.split("\n")[0])
    ap.add_argument("--recording", help="pixel-tier MCAP (default: generate a teleop session)")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds of the generated session")
    ap.add_argument("--frames", type=int, default=60, help="frames timed one by one")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (per worker for the sustained run)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="sustained runs with these worker counts")
    ap.add_argument("--weights", default=None)
    ap.add_argument("--skip-run", action="store_true", help="per-frame figures only")
    ap.add_argument("--run-timeout", type=float, default=900.0, help="seconds each `tiplog vision run` may take")
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args(argv)

    import torch

    from services.vision import DEFAULT_WEIGHTS

    if a.threads > 0:
        torch.set_num_threads(a.threads)
    weights = Path(a.weights or DEFAULT_WEIGHTS)
    tmp = tempfile.TemporaryDirectory()
    rec = Path(a.recording) if a.recording else Path(tmp.name) / "teleop.mcap"
    if not a.recording:
        from services.bench.scenario import load_scenario
        from services.bench.session import generate

        print(f"generating {a.duration:g} s of pixel-tier teleop ...", file=sys.stderr)
        generate(load_scenario("teleop"), rec, seed=4, tier="pixel", duration_s=a.duration)
    load_before = _load()
    stats, n, device = per_frame(rec, weights, a.device, a.frames)
    report: dict = {
        "cpu_count": os.cpu_count(),
        "device": device,
        "torch_threads": torch.get_num_threads(),
        "frames_timed": n,
        "per_frame": stats,
        "per_frame_load": [load_before, _load()],  # the figures mean little on a busy host: say how busy
        "load_average_1min": _load(),
    }
    print(f"per frame: device {device}, torch threads {report['torch_threads']}, {n} frames; "
          f"host load {load_before:.1f} -> {_load():.1f} on {report['cpu_count']} CPUs")  # fmt: skip
    print(f"  {'ms':14s} {'wall p50':>9s} {'p95':>7s} {'CPU p50':>9s} {'p95':>7s}")
    for s in STAGES:
        w, c = stats[f"{s}_ms"], stats[f"{s}_cpu_ms"]
        print(f"  {s:14s} {w['p50']:9.1f} {w['p95']:7.1f} {c['p50']:9.1f} {c['p95']:7.1f}")
    print(f"  {'preview':14s} {stats['preview_ms']['p50']:9.1f} {stats['preview_ms']['p95']:7.1f}")
    if not a.skip_run:
        report["vision_run"] = []
        for w in a.workers:
            r = sustained(rec, weights, a.device, a.threads, w, a.run_timeout)
            report["vision_run"].append(r)
            print(f"  tiplog vision run --workers {w}: {r['frames']} frames in {r['seconds']:.1f} s = "
                  f"{r['fps']:.1f} frames/s (target >= 15); host load {r['load_before']:.1f} -> "
                  f"{r['load_after']:.1f}", flush=True)  # fmt: skip
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
