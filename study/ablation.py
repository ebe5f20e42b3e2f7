"""Ablations on one recording, as the paper ran them: the tracking filter re-run with sensor
subsets and with degraded vision, every variant scored against the bench's ground truth.

`imu_tof_start` is IMU+ToF from a known start: vision only for the first second (`vision_start`).
Degradations change only the vision observations the filter is fed (the truth is never fed):
`third` keeps one accepted frame in three, `noise5` adds white tangent-plane noise so that
the per-frame axis noise is five times the recording's (seeded; the paper "multiplied the vision
axis noise fivefold", the junction is left as recorded), `blackout1/3/10`
blanks vision for 1, 3 or 10 s at sixteen points of the session shared over its blocks (or at
`blackouts` points: the paper's sixteen were spread over one recording of all seven blocks, so
`shared_blackouts` shares them over the sessions that hold those blocks), and
`junction_hidden` clears `junction_visible` on every observation after the first second of
accepted frames that show it (no independent tip from vision, so the ToF offset stays held; the
tracking filter starts only from a frame with a visible junction once an accelerometer sample has
come, so the first second is kept). Scoring uses `study.evaluation` (first 20 %
of each block excluded).

`run_ablations` runs the variants in a process pool; each worker reads the MCAP itself, so
nothing large is pickled between processes.
"""

from __future__ import annotations

import copy
import logging
import os
import time
from collections.abc import Callable, Iterable
from concurrent.futures import as_completed
from pathlib import Path
from typing import Any

import numpy as np

from services.fusion.eskf.params import Params, parse_sensors
from services.fusion.eskf.sample import StateSample
from services.fusion.offline.inputs import iter_inputs
from services.fusion.timing.runner import FusionRunner
from study.evaluation import (
    Estimate,
    block_errors_mm,
    block_windows,
    load_truth,
    read_trials,
    score_continuous,
)
from tiplog.calibration import Calibration
from tiplog.geometry import vision as vg
from tiplog.mcap_io import read_metadata
from tiplog.procpool import process_pool

log = logging.getLogger("tiplog.evaluate")

# variant name -> the filter's sensors (the RCM is always used, as in the paper)
SUBSETS = {
    "full": "imu,tof,vision",
    "vision_only": "vision",
    "imu_tof": "imu,tof",
    "imu_tof_start": "imu,tof,vision",  # vision only for the first second: see `vision_start`
    "imu_vision": "imu,vision",
}
DEGRADED = ("third", "noise5", "blackout1", "blackout3", "blackout10", "junction_hidden")
BLACKOUT_COUNT = 16
PER_SESSION = "_per_session"  # a report's name for blackouts sixteen per session, not shared over sessions
JUNCTION_INIT_NS = 1_000_000_000  # junction_hidden keeps the junction this long, to start from
# the recording's per-frame (white) tangent-plane noise, from the bench's defaults; five times
# in total needs sqrt(25 - 1) times that added
PLANE_WHITE_DEG = 0.06


def blackout_spans(
    blocks: list[tuple[str, int, int]], length_ns: int, count: int = BLACKOUT_COUNT
) -> list[tuple[int, int]]:
    """`count` blackouts of `length_ns` over the session's blocks [(name, start_ns, end_ns)],
    shared out in proportion to each block's length and centred in equal slices of it, never
    overlapping (the paper blanks vision at sixteen points of its recording; placed per block
    they would overlap into one block-long blackout)."""
    total = sum(b - a for _, a, b in blocks)
    spans = []
    for _, a, b in blocks:
        n = min(int(round(count * (b - a) / total)), (b - a) // max(length_ns, 1)) if total > 0 else 0
        for j in range(int(n)):
            mid = a + (j + 0.5) * (b - a) / n
            spans.append((int(mid - length_ns / 2), int(mid + length_ns / 2)))
    return spans


def shared_blackouts(lengths_ns: list[int], count: int = BLACKOUT_COUNT) -> list[int]:
    """`count` blackouts shared over sessions whose blocks last `lengths_ns` in all, in
    proportion to those lengths (largest remainder: they add up to `count`). The paper blanked
    vision at sixteen points of one recording holding both kinds of block; here each kind is
    its own session, and sixteen in each would be twice as dense."""
    total = sum(lengths_ns)
    if total <= 0:
        return [0] * len(lengths_ns)
    quota = [count * n / total for n in lengths_ns]
    out = [int(q) for q in quota]
    for i in sorted(range(len(quota)), key=lambda i: out[i] - quota[i])[: count - sum(out)]:
        out[i] += 1
    return out


def session_blocks(session: str | Path) -> list[tuple[str, int, int]]:
    """A bench session's scored blocks (`block_windows`), from its `trials` metadata alone."""
    return block_windows(read_trials(session))


def sessions_blackouts(sessions: list[str | Path], count: int = BLACKOUT_COUNT) -> list[int]:
    """`shared_blackouts` over bench sessions, by the length of their scored blocks."""
    return shared_blackouts([sum(b - a for _, a, b in session_blocks(p)) for p in sessions], count)


def _add_noise(msg: Any, rng: np.random.Generator) -> Any:
    """The tangent planes' white noise made five times the recording's (the paper "multiplied
    the vision axis noise fivefold"); the junction ray is left as recorded."""
    msg = copy.deepcopy(msg)
    k = np.sqrt(24.0)
    for f in ("n_left", "n_right"):
        v = getattr(msg, f)
        n = np.array([v.x, v.y, v.z])
        u = np.cross(n, rng.normal(size=3))
        a, b = rng.normal(size=2) * np.radians(PLANE_WHITE_DEG) * k
        n2 = vg.tilt_normal(n, a, b, u / np.linalg.norm(u))
        v.x, v.y, v.z = (float(c) for c in n2)
    return msg


def start_window(msgs: Iterable[tuple]) -> tuple[int, int] | None:
    """[t0, t0 + 1 s) from the first accepted vision frame with a visible junction (the frame
    the tracking filter starts from), or None. `junction_hidden` keeps the junction and
    `imu_tof_start` keeps vision in this window, so that the filter can start."""
    for topic, msg, _ in msgs:
        if topic == "vision/observation" and msg.accepted and msg.junction_visible:
            return msg.header.stamp_ns, msg.header.stamp_ns + JUNCTION_INIT_NS
    return None


def vision_start(msgs: Iterable[tuple]) -> list[tuple]:
    """The filter's inputs with vision only in the `start_window`: IMU+ToF from a known start.
    `imu_tof` has no heading at all (it starts from the ToF plane's azimuth); the paper's
    IMU+ToF "drifted in heading", so it had one to drift from."""
    msgs = list(msgs)
    t0, t1 = start_window(msgs) or (0, 0)
    return [e for e in msgs if e[0] != "vision/observation" or t0 <= e[1].header.stamp_ns < t1]


def degrade(
    name: str,
    msgs: Iterable[tuple],
    blocks: list[tuple[str, int, int]],
    seed: int = 0,
    blackouts: int = BLACKOUT_COUNT,
) -> list[tuple]:
    """The filter's inputs [(topic, message, arrival_ns)] with vision degraded as `name` (one of
    DEGRADED; `blackouts`: how many for blackout1/3/10); other topics pass unchanged.
    ValueError for an unknown name."""
    if name not in DEGRADED:
        raise ValueError(f"degradation: unknown name {name!r}; choose from {', '.join(DEGRADED)}")
    rng = np.random.default_rng(seed)
    length_ns = int(float(name[len("blackout") :]) * 1e9) if name.startswith("blackout") else 0
    spans = blackout_spans(blocks, length_ns, blackouts) if length_ns else []
    msgs = list(msgs)
    t0, t1 = start_window(msgs) or (0, 0)
    out = []
    accepted = 0
    for topic, msg, arr in msgs:
        if topic == "vision/observation":
            if name == "junction_hidden":
                if not (msg.accepted and t0 <= msg.header.stamp_ns < t1):
                    msg = copy.deepcopy(msg)
                    msg.junction_visible = False
            elif msg.accepted:
                t = msg.header.stamp_ns
                if name == "third":
                    accepted += 1
                    if accepted % 3:
                        continue
                elif name == "noise5":
                    msg = _add_noise(msg, rng)
                elif spans and any(s <= t < e for s, e in spans):
                    continue
        out.append((topic, msg, arr))
    return out


def variant_inputs(
    variant: str, msgs: list[tuple], blocks: list[tuple[str, int, int]], seed: int = 0, blackouts: int = BLACKOUT_COUNT
) -> tuple[list[tuple], str]:
    """(the filter's inputs, its sensors) for one variant (a SUBSETS or DEGRADED name)."""
    if variant == "imu_tof_start":
        return vision_start(msgs), SUBSETS[variant]
    if variant in SUBSETS:
        return msgs, SUBSETS[variant]
    return degrade(variant, msgs, blocks, seed, blackouts), SUBSETS["full"]


def run_variant(
    msgs: Iterable[tuple], calib: Calibration, params: Params, sensors: str, output: str = "settled"
) -> tuple[Estimate, dict, float]:
    """The tracking filter over `msgs` in arrival order: (estimate, diagnostics, CPU seconds);
    `output` as `FusionRunner`'s."""
    t0 = time.process_time()
    states, runner = run_states(msgs, calib, params, sensors, output=output)
    cpu = time.process_time() - t0
    tip = np.array([s.p_tip_base_m for s in states], float).reshape(-1, 3)
    est = Estimate(np.array([s.stamp_ns for s in states], np.int64), tip)
    return est, runner.diagnostics(), cpu


def run_states(
    msgs: Iterable[tuple],
    calib: Calibration,
    params: Params,
    sensors: str,
    probe: Callable[[FusionRunner], None] | None = None,
    output: str = "settled",
) -> tuple[list[StateSample], FusionRunner]:
    """The tracking filter over `msgs` in arrival order, advanced at every gyro arrival: every
    published state (settled, as `tiplog fusion run` writes them, or output="display" for what
    the live service published), and the runner (for its diagnostics). `probe`, if given, sees
    the runner after every advance (a benchmark reading the filter's covariance at its head)."""
    runner = FusionRunner(calib, params, parse_sensors(sensors), output)
    states: list[StateSample] = []
    for topic, msg, arr in msgs:
        runner.feed(topic, msg, arr)
        if topic == "device/gyro":
            states += runner.advance(arr)
            if probe is not None:
                probe(runner)
    states += runner.finish()
    return states, runner


def variants() -> list[str]:
    """Every ablation variant: the sensor subsets, then the degradations."""
    return [*SUBSETS, *DEGRADED]


def evaluate_variant(
    session: str | Path,
    variant: str,
    calibration: Path | None = None,
    seed: int = 0,
    series: bool = False,
    blackouts: int = BLACKOUT_COUNT,
    block_errors: bool = False,
) -> dict[str, Any]:
    """One variant on one session (reads the MCAP itself; safe to run in a worker process).
    `calibration`: a calibration YAML, else the session's `calibration_as_calibrated`;
    `series`: keep the scored time series (private `_series`, for plots); `blackouts`: how
    many for blackout1/3/10 (reported as `blackouts`); `block_errors`: keep each block's
    scored stamps and tip error norms in mm (private `_block_errors`, {block: (t_ns, err_mm)},
    for comparing variants block by block with `evaluation.paired_rmse_difference`)."""
    session = Path(session)
    truth = load_truth(session)
    calib = (
        Calibration.load_yaml(calibration)
        if calibration
        else Calibration.from_mcap_metadata(read_metadata(session), where=str(session))
    )
    msgs = list(iter_inputs(session, {}))
    use, sensors = variant_inputs(variant, msgs, block_windows(truth.trials), seed, blackouts)
    est, diag, cpu = run_variant(use, calib, Params(), sensors)
    r = score_continuous(truth, est)
    out = {
        "session": session.name,
        "variant": variant,
        "kind": "subset" if variant in SUBSETS else "degraded",
        "tip_rmse_mm": r["pooled"]["tip_rmse_mm"],
        "tip_p95_mm": r["pooled"]["tip_p95_mm"],
        "coverage": r["pooled"]["coverage"],
        "pooled": r["pooled"],
        "blocks": r["blocks"],
        "block_mean_mm": float(np.mean([b["tip_rmse_mm"] for b in r["blocks"]])),
        "states": int(len(est.t_ns)),
        "cpu_s": round(cpu, 2),
        "resets": int(diag.get("resets", 0)),
        "reacquired": int(diag.get("updates", {}).get("reacquire", 0)),
    }
    if variant.startswith("blackout"):
        out["blackouts"] = int(blackouts)
    if series:
        out["_series"] = r["_series"]
    if block_errors:
        out["_block_errors"] = block_errors_mm(r["_series"])
    return out


def _worker(job: tuple[str, str, str | None]) -> dict[str, Any]:
    session, variant, cal = job
    return evaluate_variant(session, variant, Path(cal) if cal else None)


def run_jobs(
    jobs: list[tuple[str, str, str | None]], workers: int | None = None, progress: Callable[[str], None] | None = None
) -> list[dict[str, Any]]:
    """(session, variant, calibration or None) jobs in a process pool of `workers` (default
    os.cpu_count()); results in the order of `jobs`. `progress` gets one line per finished job."""
    workers = max(1, min(workers or os.cpu_count() or 1, len(jobs)))
    out: list[dict[str, Any] | None] = [None] * len(jobs)
    with process_pool(workers) as pool:
        futures = {pool.submit(_worker, j): i for i, j in enumerate(jobs)}
        for done, f in enumerate(as_completed(futures), 1):
            r = f.result()
            out[futures[f]] = r
            if progress:
                progress(f"[{done}/{len(jobs)}] {r['session']} {r['variant']}: tip RMSE {r['tip_rmse_mm']:.2f} mm")
    return [r for r in out if r is not None]


def ablation_table(results: list[dict[str, Any]]) -> dict[str, Any]:
    """JSON shape `subsets.<name>.tip_rmse_mm`, `degraded.<name>.tip_rmse_mm` of one session's
    variant results."""
    out: dict[str, Any] = {"subsets": {}, "degraded": {}}
    for r in results:
        key = "subsets" if r["kind"] == "subset" else "degraded"
        out[key][r["variant"]] = {
            k: r[k] for k in ("tip_rmse_mm", "tip_p95_mm", "block_mean_mm", "coverage", "resets", "blocks")
        }
    return out


def run_ablations(
    session: str | Path, calibration: Path | None = None, workers: int | None = None, progress=None
) -> dict[str, Any]:
    """Every subset and degradation on one continuous session (see `ablation_table`)."""
    cal = str(calibration) if calibration else None
    return ablation_table(run_jobs([(str(session), v, cal) for v in variants()], workers, progress))
