"""Offline session generation: robot ground truth -> sensor streams -> one MCAP file.

Topics: device/gyro, device/accel, device/tof, device/mag (one message per sample,
header.stamp_ns = host arrival, header.device_stamp_ns = device clock, header.seq per
stream), camera/info, vision/observation (measurement tier; header.stamp_ns = capture
stamp, logged when processing finishes) or camera/image (pixel tier, foxglove RawImage
rgb8, logged at capture), bench/robot (ground truth, evaluation only, at
output.robot_rate_hz). Log time = host arrival. Metadata: scenario (resolved), session
(seed, tier, protocol, rates), calibration_as_calibrated, calibration_truth (evaluation
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
from scipy.spatial.transform import Rotation

from services.bench import messages
from services.bench.calibration import as_calibrated, true_constants
from services.bench.scenario import Scenario, scenario_dict
from services.bench.sensors import simulate_sensors
from services.bench.vision_model import frame_times, simulate_vision
from tiplog import __version__
from tiplog.mcap_io import McapWriter

log = logging.getLogger(__name__)
TIERS = ("measurement", "pixel")
Progress = Callable[[str, float], None]


def _motion():
    from services.bench import motion  # the robot helper's module; imported late (Pinocchio)

    return motion


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
    duration = duration_s if duration_s is not None else scenario.duration_s
    ss = np.random.SeedSequence(seed)
    s_motion, s_cal, s_sens, s_vis = ss.spawn(4)
    truth = true_constants(scenario)
    calib = as_calibrated(truth, scenario, np.random.default_rng(s_cal))
    motion_cfg = _commanded_through_hand_eye(scenario, truth, calib)
    prog("robot", 0.0)
    gt = _motion().simulate(motion_cfg, scenario.protocol, int(s_motion.generate_state(1)[0]), duration)
    timings["robot_s"] = time.perf_counter() - t0
    truth.rcm_base_m = np.asarray(gt.rcm_base_m, dtype=float)
    prog("sensors", 0.2)
    t1 = time.perf_counter()
    kin, clock, streams = simulate_sensors(gt, scenario, truth, np.random.default_rng(s_sens))
    vrng = np.random.default_rng(s_vis)
    frames = simulate_vision(kin, scenario, truth, vrng) if tier == "measurement" else None
    timings["models_s"] = time.perf_counter() - t1

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
        batches.append(messages.vision(frames))
        first_cam_ns = int(frames.capture_ns[0]) if len(frames) else 0
    else:
        batches.append(_pixel_batch(kin, scenario, truth, vrng, prog))
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
                "duration_s": f"{gt.t_ns[-1] * 1e-9:.3f}",
                "robot_rate_hz": str(scenario.output.robot_rate_hz),
                "device_clock_offset_ns": str(clock.offset_ns),
                "command_camera_error_deg": json.dumps(list(motion_cfg.command_camera_error_deg)),
                "generator": f"tiplog/{__version__} services.bench.session",
            },
        )
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


def _commanded_through_hand_eye(scenario: Scenario, truth, calib):
    """The paper commanded trials along camera axes through its estimated hand-eye: unless the
    scenario sets motion.command_camera_error_deg itself, use the as-calibrated camera
    rotation (R_cmd = R_true E, E = R_true^T R_cal)."""
    mc = scenario.motion
    if any(abs(v) > 0 for v in getattr(mc, "command_camera_error_deg", (0.0, 0.0, 0.0))) or not hasattr(
        mc, "command_camera_error_deg"
    ):
        return mc
    E = truth.T_base_camera[:3, :3].T @ calib.T_base_camera[:3, :3]
    rpy = Rotation.from_matrix(E).as_euler("xyz", degrees=True)  # R = Rz Ry Rx, as rpy_to_matrix
    return mc.model_copy(update={"command_camera_error_deg": tuple(float(v) for v in rpy)})


def _pixel_batch(kin, scenario: Scenario, truth, rng: np.random.Generator, prog: Progress) -> messages.Batch:
    try:
        from services.bench import render
    except ImportError as e:
        raise RuntimeError(f"pixel tier needs services/bench/render.py ({e})") from None
    from services.bench.sensors import _interp, _interp_R, arrival

    cam = scenario.camera.model()
    params = scenario.render.model_copy(
        update={
            "shaft_radius_m": scenario.instrument.shaft_radius_m,
            "junction_from_tip_mm": max(2.0, scenario.instrument.junction_proximal_m * 1e3),
        }
    )
    t = frame_times(scenario, int(kin.t_ns[-1]), rng)
    R = _interp_R(t, kin.t_ns, kin.R_base_tool)
    p = _interp(t, kin.t_ns, kin.p_tip_base_m)
    T_cam_base = np.linalg.inv(truth.T_base_camera)
    cap = arrival(t, scenario.camera.latency_ms, scenario.camera.latency_jitter_ms, rng)
    payloads = []
    for k in range(len(t)):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[k], p[k]
        img = render.render_frame(cam, T_cam_base @ T, params, rng)
        payloads.append(messages.raw_image(img, int(cap[k]), cam.frame_id))
        if k % 50 == 0:
            prog("render", 0.2 + 0.2 * k / max(len(t), 1))
    return messages.Batch("camera/image", messages.RAW_IMAGE, cap, payloads)


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
