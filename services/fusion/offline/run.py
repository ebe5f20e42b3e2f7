"""`tiplog fusion run IN.mcap --out OUT.mcap`: the tracking filter over a recording, offline and
deterministic. OUT holds fusion/state (gyro rate), fusion/tf (the estimated tool pose for
Foxglove, 20 Hz), fusion/diagnostics, and as metadata the calibration, parameters, sensors and
output used. Only device/*, vision/observation and camera/info are read: never the bench's
truth.

fusion/state is the settled causal filter (every measurement applied at its time: what the live
service publishes on fusion/state_settled); `--as-live` writes instead what the live service
published on fusion/state, `output_delay_ms` behind, late frames only from their arrival on."""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

from services.fusion.eskf.params import Params, ParamsError, mode_name, parse_sensors
from services.fusion.live.messages import to_fusion_state
from services.fusion.offline.inputs import (
    announced_rates,
    check_streams,
    iter_inputs,
    recording_metadata,
    source_fingerprint,
)
from services.fusion.params_file import load_params
from services.fusion.timing.runner import FusionRunner
from tiplog.calibration import Calibration, CalibrationError
from tiplog.mcap_io import McapWriter, read_summary
from tiplog.progress import Progress
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file

log = logging.getLogger("tiplog.fusion")
TF_PERIOD_NS = 50_000_000


def register(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", help="MCAP file with device and vision topics")
    p.add_argument("--out", required=True, help="MCAP file for the estimated trajectory")
    p.add_argument("--sensors", default="imu,tof,vision", help="comma list of imu, tof, vision (ablation)")
    p.add_argument("--params", help="YAML file of filter parameters (default: the built-in set)")
    p.add_argument("--calibration", help="calibration YAML (default: the recording's own calibration metadata)")
    p.add_argument("--smooth", action="store_true", help="also write fusion/state_smoothed (RTS smoother)")
    p.add_argument(
        "--as-live",
        action="store_true",
        help="fusion/state as the live service published it (output_delay_ms behind) instead of settled",
    )
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=run)


def load_inputs(args: argparse.Namespace) -> tuple[Path, Calibration, Params, frozenset[str]]:
    """Check everything the user gave before any work; UserError names what is wrong."""
    src = input_mcap(args.recording)
    try:
        sensors = parse_sensors(args.sensors)
        params = load_params(input_file(args.params, "parameter file")) if args.params else Params()
    except ParamsError as e:
        raise UserError(str(e)) from None
    meta = recording_metadata(src)
    try:
        if args.calibration:
            calib = Calibration.load_yaml(input_file(args.calibration, "calibration file"))
        else:
            calib = Calibration.from_mcap_metadata(meta, where=str(src))
    except CalibrationError as e:
        raise UserError(str(e)) from None
    output_file(args.out, args.force)  # after the inputs: it must not be one of them
    check_streams(src, sensors, announced_rates(meta))
    return src, calib, params, sensors


def run_filter(src: Path, runner: FusionRunner, progress: bool = False) -> tuple[list, dict[str, int]]:
    """Feed the recording in arrival order and collect every published state (offline)."""
    stats: dict[str, int] = {}
    s = read_summary(src)
    t0, t1 = s.statistics.message_start_time, s.statistics.message_end_time
    out = []
    next_report = 0.1
    wall = time.monotonic()
    with Progress(sys.stderr, enabled=progress) as bar:
        for topic, msg, log_ns in iter_inputs(src, stats):
            runner.feed(topic, msg, log_ns)
            if topic == "device/gyro":
                out.extend(runner.advance(log_ns))
            frac = (log_ns - t0) / max(t1 - t0, 1)
            if frac >= next_report:  # every tenth of the recording: no string work per message
                bar.update(f"fusion {frac * 100:5.1f} %  {time.monotonic() - wall:6.1f} s")
                next_report += 0.1
        out.extend(runner.finish())
        bar.update(f"fusion 100.0 %  {time.monotonic() - wall:6.1f} s", force=True)
    return out, stats


def write_output(tmp: Path, samples: list, runner: FusionRunner, meta: dict[str, Any], smoothed=None) -> None:
    from services.fusion.live.publish import to_diagnostics, to_frame_transforms
    from services.fusion.live.scene import SCENE_PERIOD_NS, SceneTrail

    delay = runner.delay_ns
    lag = delay * 1e-6
    with McapWriter(tmp) as w:
        for k, v in meta.items():
            w.add_metadata(k, v)
        last_tf = last_scene = -(1 << 62)
        trail = SceneTrail(runner.calib.rcm_base_m)
        for i, s in enumerate(samples):
            log_ns = s.stamp_ns + delay
            w.write("fusion/state", to_fusion_state(s, lag, i), log_ns)
            if s.stamp_ns - last_tf >= TF_PERIOD_NS:
                w.write("fusion/tf", to_frame_transforms(s), log_ns)
                last_tf = s.stamp_ns
            trail.add(s.stamp_ns, s.p_tip_base_m)
            if s.stamp_ns - last_scene >= SCENE_PERIOD_NS:
                w.write("fusion/scene", trail.message(s.stamp_ns), log_ns)
                last_scene = s.stamp_ns
        if samples:
            w.write("fusion/diagnostics", to_diagnostics(runner.diagnostics(), samples[-1].stamp_ns + delay), log_ns)
        for i, s in enumerate(smoothed or []):
            w.write("fusion/state_smoothed", to_fusion_state(s, 0.0, i), s.stamp_ns + delay)


def run(args: argparse.Namespace) -> int:
    src, calib, params, sensors = load_inputs(args)
    runner = FusionRunner(calib, params, sensors, "display" if args.as_live else "settled")
    samples, stats = run_filter(src, runner, progress=not args.quiet)
    if not samples:
        raise UserError(f"{src}: the filter never initialised (no usable vision frame or IMU data)")
    smoothed = None
    if args.smooth:
        from services.fusion.offline.smoother import smooth

        smoothed = smooth(calib, params, iter_inputs(src, {}), sensors)
    diag = runner.diagnostics()
    diag["corrupt"] = diag.get("corrupt", 0) + stats.get("corrupt", 0)
    meta = {
        "fusion": {
            "source": src.name,
            "source_fingerprint": source_fingerprint(src),
            "sensors": ",".join(sorted(sensors)),
            "mode": mode_name(sensors),
            "output": runner.output,
            "states": str(len(samples)),
        },
        "fusion_params": {"json": json.dumps(params.to_dict())},
        "fusion_calibration": {"json": json.dumps(calib.to_dict())},
        "fusion_diagnostics": {"json": json.dumps(diag)},
    }
    with atomic_output(args.out, args.force) as tmp:
        write_output(tmp, samples, runner, meta, smoothed)
    log.info("%s: %d states, %d rewinds, %d resets", args.out, len(samples), diag["rewinds"], diag["resets"])
    return 0
