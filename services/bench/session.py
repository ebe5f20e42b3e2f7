"""Offline session generation: robot ground truth -> sensor streams -> one MCAP file.

Topics: device/gyro, device/accel, device/tof, device/mag (one message per sample,
header.stamp_ns = host arrival, header.device_stamp_ns = device clock, header.seq per
stream), camera/info, vision/observation (measurement tier; header.stamp_ns = capture
stamp, logged when processing finishes) or camera/image (pixel tier, foxglove RawImage
rgb8, logged at capture), bench/robot (ground truth, evaluation only, at
output.robot_rate_hz). Log time = host arrival. Metadata: scenario (resolved), session
(seed, tier, protocol, error profile, rates), device (the module's hello as the recorder writes it: its
nominal rates), calibration_as_calibrated, calibration_truth (evaluation
only), trials.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from services.bench import messages
from services.bench.scenario import Scenario, scenario_dict
from services.bench.simulation import TIERS, SimulatedSession, simulate_session
from tiplog import __version__
from tiplog.mcap_io import McapWriter

log = logging.getLogger(__name__)
Progress = Callable[[str, float], None]


def generate(
    scenario: Scenario,
    out_path: str | Path,
    seed: int = 0,
    tier: str = "measurement",
    duration_s: float | None = None,
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Simulate the scenario's protocol and write the session; returns a summary
    (messages per topic, durations, timings)."""
    if tier not in TIERS:
        raise ValueError(f"tier must be one of {', '.join(TIERS)} (got {tier!r})")
    prog = progress or (lambda stage, frac: None)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    prog("robot", 0.0)
    sim = simulate_session(scenario, seed, tier, duration_s)
    gt, clock, streams, calib, truth = sim.gt, sim.clock, sim.streams, sim.calib, sim.truth
    motion_cfg = sim.motion_cfg
    frames = sim.vision
    timings.update(sim.timings)  # robot_s, models_s
    prog("encode", 0.2)

    t2 = time.perf_counter()
    batches: list[messages.Batch] = [
        messages.gyro(streams["gyro"]),
        messages.accel(streams["accel"]),
        messages.tof(streams["tof"]),
        messages.mag(streams["mag"]),
        messages.robot(gt, scenario.output.robot_rate_hz, scenario.name),
    ]
    cam = scenario.camera.model()
    first_cam_ns = 0
    if frames is not None:
        batches.append(messages.Batch("vision/observation", messages.VISION, frames.processed_ns, sim.vision_payloads))
        first_cam_ns = int(frames.capture_ns[0]) if len(frames) else 0
    else:
        batches.append(_pixel_batch(sim, prog))
        first_cam_ns = int(batches[-1].log_ns[0]) if len(batches[-1].log_ns) else 0
    timings["encode_s"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    counts: dict[str, int] = {}
    with McapWriter(out_path, chunk_size=int(scenario.output.chunk_mb * 2**20)) as w:
        w.add_metadata("scenario", {"yaml": yaml.safe_dump(scenario_dict(scenario), sort_keys=False)})
        w.add_metadata(
            "session",
            {
                "seed": str(seed),
                "tier": tier,
                "protocol": scenario.protocol,
                "scenario": scenario.name,
                "profile": scenario.profile,
                "duration_s": f"{gt.t_ns[-1] * 1e-9:.3f}",
                "robot_rate_hz": str(scenario.output.robot_rate_hz),
                "device_clock_offset_ns": str(clock.offset_ns),
                "command_camera_error_deg": json.dumps(list(motion_cfg.command_camera_error_deg)),
                "generator": f"tiplog/{__version__} services.bench.session",
            },
        )
        w.add_metadata("device", messages.device_metadata(scenario))  # as the recorder writes the hello
        w.add_metadata("calibration_as_calibrated", {"json": json.dumps(calib.to_dict())})
        w.add_metadata(
            "calibration_truth",
            {"json": json.dumps(truth.to_dict()), "evaluation_only": "true", "note": "never for estimators"},
        )
        w.add_metadata("trials", {"json": json.dumps(_jsonable(gt.trials)), "count": str(len(gt.trials))})
        w.write("camera/info", cam.to_calibration(first_cam_ns), log_time_ns=first_cam_ns)
        counts["camera/info"] = 1
        log_ns = np.concatenate([b.log_ns for b in batches])
        which = np.concatenate([np.full(len(b.log_ns), i, dtype=np.int32) for i, b in enumerate(batches)])
        index = np.concatenate([np.arange(len(b.log_ns)) for b in batches])
        order = np.argsort(log_ns, kind="stable")
        total = len(order)
        for k, j in enumerate(order.tolist()):
            b = batches[which[j]]
            i = int(index[j])
            w.write_raw(b.topic, b.type_name, b.payloads[i], int(log_ns[j]), sequence=i)
            if k % 200_000 == 0:
                prog("write", 0.4 + 0.6 * k / max(total, 1))
        for b in batches:
            counts[b.topic] = len(b.payloads)
    timings["write_s"] = time.perf_counter() - t3
    timings["total_s"] = time.perf_counter() - t0
    prog("done", 1.0)
    return {
        "path": str(out_path),
        "messages": int(sum(counts.values())),
        "counts": counts,
        "duration_s": float(gt.t_ns[-1] * 1e-9),
        "timings": timings,
        "trials": len(gt.trials),
    }


def _pixel_batch(sim: SimulatedSession, prog: Progress) -> messages.Batch:
    """camera/image: every frame of the pass rendered, stamped with its capture time."""
    frames = sim.camera_frames
    frame_id = sim.scenario.camera.model().frame_id
    payloads = []
    for k in range(len(frames.t_true_ns)):
        payloads.append(messages.raw_image(sim.render_frame(k), int(frames.capture_ns[k]), frame_id))
        if k % 50 == 0:
            prog("render", 0.2 + 0.2 * k / max(len(frames.t_true_ns), 1))
    return messages.Batch("camera/image", messages.RAW_IMAGE, frames.capture_ns, payloads)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x
