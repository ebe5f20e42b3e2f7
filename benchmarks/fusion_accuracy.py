"""Tip accuracy of the tracking filter on bench sessions (continuous blocks), with the built-in
parameters: full fusion, sensor subsets, degraded vision, as the paper's tables.

Degradations are applied to the same recordings, as the paper did: `third` keeps one accepted
frame in three, `noise5` adds white tangent-plane and junction noise so that the per-frame
vision noise is five times the recording's (seeded), `blackout1/3/10` blanks vision for
1, 3 or 10 s at sixteen points of each session, shared over its blocks (the paper's sixteen
were over one recording holding both the sweeps and the teleoperated blocks, so this is the
harsher reading). The filter never sees the truth;
scoring uses `services.fusion.evaluation` (first 20 % of each block excluded).

    python -m benchmarks.fusion_accuracy SESSION.mcap [...] [--variants full,imu_tof,...] [--json OUT]
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

from services.fusion.evaluation import Estimate, block_windows, load_truth, score_continuous
from services.fusion.params import Params, parse_sensors
from services.fusion.run_cli import iter_inputs
from services.fusion.runner import FusionRunner
from services.fusion.smoother import smooth
from tiplog import vision_geometry as vg
from tiplog.calibration import Calibration
from tiplog.mcap_io import read_metadata

SMOOTH = "smoothed"  # full fusion through the RTS smoother
SUBSETS = {"full": "imu,tof,vision", "vision_only": "vision", "imu_tof": "imu,tof", "imu_vision": "imu,vision"}
DEGRADED = ("third", "noise5", "blackout1", "blackout3", "blackout10")
# the recording's per-frame (white) vision noise, from the bench's defaults: plane 0.06 deg,
# junction depth 0.30 mm; five times in total needs sqrt(25 - 1) times that added
PLANE_WHITE_DEG = 0.06
JUNCTION_WHITE_M = 0.30e-3


def _blackout_spans(blocks: list[tuple[str, int, int]], length_ns: int, count: int = 16) -> list[tuple[int, int]]:
    """`count` blackouts of `length_ns` over the session's blocks, shared out in proportion to
    each block's length and centred in equal slices of it, never overlapping (the paper blanks
    vision at sixteen points of its recording; placed per block they would overlap into one
    block-long blackout)."""
    total = sum(b - a for _, a, b in blocks)
    spans = []
    for _, a, b in blocks:
        n = min(int(round(count * (b - a) / total)), (b - a) // max(length_ns, 1)) if total > 0 else 0
        for j in range(int(n)):
            mid = a + (j + 0.5) * (b - a) / n
            spans.append((int(mid - length_ns / 2), int(mid + length_ns / 2)))
    return spans


def _degrade(name: str, msgs: list, blocks: list[tuple[str, int, int]], seed: int) -> list:
    rng = np.random.default_rng(seed)
    out = []
    if name.startswith("blackout"):
        length = int(float(name[len("blackout") :]) * 1e9)
        spans = _blackout_spans(blocks, length)
    accepted = 0
    for topic, msg, arr in msgs:
        if topic == "vision/observation" and msg.accepted:
            t = msg.header.stamp_ns
            if name == "third":
                accepted += 1
                if accepted % 3:
                    continue
            elif name == "noise5":
                msg = copy.deepcopy(msg)
                k = np.sqrt(24.0)
                for f in ("n_left", "n_right"):
                    v = getattr(msg, f)
                    n = np.array([v.x, v.y, v.z])
                    u = np.cross(n, rng.normal(size=3))
                    a, b = rng.normal(size=2) * np.radians(PLANE_WHITE_DEG) * k
                    n2 = vg.tilt_normal(n, a, b, u / np.linalg.norm(u))
                    v.x, v.y, v.z = (float(c) for c in n2)
                r = msg.junction_ray
                d = np.array([r.x, r.y, r.z]) + rng.normal(size=3) * JUNCTION_WHITE_M * k / 0.09  # ~90 mm range
                d /= np.linalg.norm(d)
                r.x, r.y, r.z = (float(c) for c in d)
            elif name.startswith("blackout") and any(s <= t < e for s, e in spans):
                continue
        out.append((topic, msg, arr))
    return out


def run_variant(msgs: list, calib: Calibration, params: Params, sensors: str) -> tuple[Estimate, dict, float]:
    runner = FusionRunner(calib, params, parse_sensors(sensors))
    t0 = time.process_time()
    states = []
    for topic, msg, arr in msgs:
        runner.feed(topic, msg, arr)
        if topic == "device/gyro":
            states += runner.advance(arr)
    states += runner.finish()
    cpu = time.process_time() - t0
    est = Estimate(np.array([s.stamp_ns for s in states], np.int64), np.array([s.p_tip_base_m for s in states]))
    return est, runner.diagnostics(), cpu


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sessions", nargs="+", help="bench sessions (sweeps, teleop, demo)")
    ap.add_argument("--variants", default="full", help=f"comma list of {', '.join([*SUBSETS, *DEGRADED, SMOOTH])}")
    ap.add_argument("--params", help="parameter YAML (default: built-in)")
    ap.add_argument("--json", help="write all results here")
    args = ap.parse_args(argv)
    params = Params.load_yaml(args.params) if args.params else Params()
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    results = []
    for path in args.sessions:
        truth = load_truth(path)
        calib = Calibration.from_mcap_metadata(read_metadata(path), where=path)
        msgs = list(iter_inputs(Path(path), {}))
        blocks = block_windows(truth.trials)
        for v in variants:
            sensors = SUBSETS.get(v, SUBSETS["full"])
            use = msgs if v in SUBSETS or v == SMOOTH else _degrade(v, msgs, blocks, seed=0)
            if v == SMOOTH:
                t0 = time.process_time()
                sm = smooth(calib, params, use)
                cpu = time.process_time() - t0
                est = Estimate(np.array([s.stamp_ns for s in sm], np.int64), np.array([s.p_tip_base_m for s in sm]))
                diag = {"resets": 0}
            else:
                est, diag, cpu = run_variant(use, calib, params, sensors)
            r = score_continuous(truth, est)
            row = {
                "session": Path(path).name,
                "variant": v,
                "pooled": r["pooled"],
                "blocks": r["blocks"],
                "block_mean_mm": float(np.mean([b["tip_rmse_mm"] for b in r["blocks"]])),
                "cpu_s": round(cpu, 2),
                "resets": diag["resets"],
                "reset_reasons": diag.get("reset_reasons", {}),
                "reacquired": int(diag.get("updates", {}).get("reacquire", 0)),
            }
            results.append(row)
            blk = " ".join(f"{b['name']}={b['tip_rmse_mm']:.2f}" for b in r["blocks"])
            print(
                f"{row['session']:<22} {v:<11} pooled {r['pooled']['tip_rmse_mm']:6.2f} mm "
                f"(median {r['pooled']['tip_median_mm']:.2f}, p95 {r['pooled']['tip_p95_mm']:.2f}, "
                f"radial {r['pooled']['radial_rmse_mm']:.2f}, tangential {r['pooled']['tangential_rmse_mm']:.2f}) "
                f"[{blk}] cpu {cpu:.1f} s resets {diag['resets']} reacquired {row['reacquired']}",
                flush=True,
            )
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
