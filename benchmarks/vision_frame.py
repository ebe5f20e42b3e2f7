"""Per-frame time of the vision pipeline (labeler, network, total, preview) and the sustained
frames per second of `tiplog vision run` on a pixel-tier recording.

    python -m benchmarks.vision_frame --frames 60 --device cpu --threads 1
    python -m benchmarks.vision_frame --recording teleop.mcap   # an existing pixel-tier file

Without --recording a short teleoperated pixel-tier session is generated first (seed 4). The
per-frame figures (wall time per stage, and the pipeline's CPU time, which a busy shared host
inflates less) come from the frames of that recording, processed one after another on the
chosen device after a few warm-up frames; `tiplog vision run` is timed end to end (reading,
decompressing, processing and writing every frame), as a user would run it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _percentiles(xs: list[float]) -> dict[str, float]:
    a = np.asarray(xs)
    return {"p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)), "mean": float(a.mean())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.vision_frame", description=__doc__.split("\n")[0])
    ap.add_argument("--recording", help="pixel-tier MCAP (default: generate a teleop session)")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds of the generated session")
    ap.add_argument("--frames", type=int, default=60, help="frames timed one by one")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--weights", default=None)
    ap.add_argument("--skip-run", action="store_true", help="per-frame figures only")
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args(argv)

    import torch

    from services.vision import DEFAULT_WEIGHTS
    from services.vision.frames import decode_frame, recording_frames
    from services.vision.network import load_checkpoint
    from services.vision.offline import run_file
    from services.vision.pipeline import Pipeline
    from services.vision.preview import preview_message
    from tiplog.calibration import Calibration
    from tiplog.mcap_io import read_metadata

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
    seg, _ = load_checkpoint(weights, a.device)
    calib = Calibration.from_mcap_metadata(read_metadata(rec))
    pipe = Pipeline(seg, calib.shaft_radius_m)
    rows: dict[str, list[float]] = {"labeler_ms": [], "network_ms": [], "total_ms": [], "preview_ms": [], "cpu_ms": []}
    n = 0
    for k, _, msg, cam in recording_frames(rec):
        frame = decode_frame(msg, cam)
        c0 = time.thread_time()  # CPU time of this thread: what a frame costs on a core of its own
        res = pipe.process(frame, cam, msg.timestamp.ToNanoseconds(), k)
        cpu_ms = (time.thread_time() - c0) * 1e3
        t0 = time.perf_counter()
        preview_message(frame, res, cam)
        prev_ms = (time.perf_counter() - t0) * 1e3
        if k < 3:  # warm-up (allocator, caches, CUDA kernels)
            continue
        for key in ("labeler_ms", "network_ms", "total_ms"):
            rows[key].append(res.timings_ms[key])
        rows["preview_ms"].append(prev_ms)
        rows["cpu_ms"].append(cpu_ms)
        n += 1
        if n >= a.frames:
            break
    report = {
        "load_average_1min": os.getloadavg()[0],  # the figures mean little on a busy host: say how busy
        "cpu_count": os.cpu_count(),
        "device": str(seg.device),
        "torch_threads": torch.get_num_threads(),
        "frames_timed": n,
        "per_frame": {k: _percentiles(v) for k, v in rows.items()},
    }
    if not a.skip_run:
        out = Path(tmp.name) / "obs.mcap"
        s = run_file(rec, out, weights, None, a.device, a.threads, quiet=True)
        report["vision_run"] = {"frames": s["frames"], "seconds": s["seconds"], "fps": s["fps"]}
    print(f"device {report['device']}, torch threads {report['torch_threads']}, {n} frames; "
          f"host load {report['load_average_1min']:.1f} on {report['cpu_count']} CPUs")  # fmt: skip
    for k, v in report["per_frame"].items():
        print(f"  {k:12s} p50 {v['p50']:7.1f}  p95 {v['p95']:7.1f}  mean {v['mean']:7.1f}")
    if "vision_run" in report:
        r = report["vision_run"]
        print(f"  tiplog vision run: {r['frames']} frames in {r['seconds']:.1f} s = {r['fps']:.1f} frames/s")
    if a.json:
        Path(a.json).write_text(json.dumps(report, indent=1))
    tmp.cleanup()
    return 0


if __name__ == "__main__":
    sys.exit(main())
