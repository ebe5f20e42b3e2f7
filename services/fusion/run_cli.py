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
import hashlib
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

from services.fusion.messages import to_fusion_state
from services.fusion.params import Params, ParamsError, mode_name, parse_sensors
from services.fusion.runner import FusionRunner
from tiplog import topics
from tiplog.calibration import Calibration, CalibrationError
from tiplog.mcap_io import McapWriter, raw_messages, read_metadata, read_summary, topic_spans
from tiplog.userio import UserError, atomic_output, input_file, input_mcap, output_file

log = logging.getLogger("tiplog.fusion")
INPUT_TOPICS = ("device/gyro", "device/accel", "device/tof", "device/status", "vision/observation", "camera/info")
# The paper's module (BNO085, VL53L0X) and camera; a device's own hello (the recording's `device`
# metadata) overrides the device streams', so a module with other rates is checked against it.
NOMINAL_HZ = {"device/gyro": 200.0, "device/accel": 240.0, "device/tof": 100.0, "vision/observation": 15.0}
RATE_TOLERANCE = 0.5  # a stream below half or above twice its nominal rate is refused
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
        params = Params.load_yaml(input_file(args.params, "parameter file")) if args.params else Params()
    except ParamsError as e:
        raise UserError(str(e)) from None
    meta = _metadata(src)
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


def _metadata(src: Path) -> dict[str, dict[str, str]]:
    try:
        return read_metadata(src)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001 - any reader failure is a bad file for the user
        raise UserError(f"{src}: cannot read the MCAP metadata ({type(e).__name__})") from None


def check_streams(src: Path, sensors: frozenset[str], announced: dict[str, float]) -> None:
    """IMU topics present, each used stream near its nominal rate (its count in the file's
    summary over its own first-to-last span): the rate the device announced where `announced`
    names it, else the paper's module's."""
    try:
        summary = read_summary(src)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001
        raise UserError(f"{src}: cannot read the MCAP summary ({type(e).__name__})") from None
    if summary is None or summary.statistics is None:
        raise UserError(f"{src}: no summary (an unfinished recording? recover it with `tiplog record --recover`)")
    counts: dict[str, int] = {}
    for cid, ch in summary.channels.items():
        counts[ch.topic] = counts.get(ch.topic, 0) + summary.statistics.channel_message_counts.get(cid, 0)
    need = ["device/gyro"] + (["device/accel"] if "imu" in sensors else [])
    missing = [t for t in need if counts.get(t, 0) == 0]
    if missing:
        raise UserError(f"{src}: no IMU data (topic {', '.join(missing)} missing)")
    span_s = (summary.statistics.message_end_time - summary.statistics.message_start_time) * 1e-9
    if span_s < 1.0:
        raise UserError(f"{src}: recording too short ({span_s:.2f} s)")
    use = {"device/gyro", "device/accel"} | ({"device/tof"} if "tof" in sensors else set())
    use |= {"vision/observation"} if "vision" in sensors else set()
    # each stream's rate over its own span: a recording started before the device (a recorder
    # that waits for the bench, a module plugged in later) holds other topics before it
    spans = topic_spans(src, sorted(t for t in use if counts.get(t, 0)))
    for t in sorted(use):
        if counts.get(t, 0) == 0:
            if t != "device/gyro":
                log.warning("%s: no %s messages; running without them", src, t)
            continue
        first, last = spans.get(t, (0, 0))
        rate = (counts[t] - 1) / ((last - first) * 1e-9) if last > first else 0.0
        nominal = announced.get(t, NOMINAL_HZ[t])
        high = float("inf") if t == "vision/observation" else nominal / RATE_TOLERANCE  # a faster camera is fine
        if not (nominal * RATE_TOLERANCE <= rate <= high):
            whose = "announced by the device" if t in announced else "default; the recording names no device rates"
            raise UserError(f"{src}: {t} at {rate:.1f} Hz, far off its nominal {nominal:.0f} Hz ({whose})")


def announced_rates(meta: dict[str, dict[str, str]]) -> dict[str, float]:
    """Device stream rates by topic from the recording's `device` metadata: the module's hello,
    as the recorder (and the bench) writes it; empty when the recording has none."""
    raw = meta.get("device", {}).get("nominal_rates_hz")
    if raw is None:
        return {}
    try:
        rates = {f"device/{k}": float(v) for k, v in json.loads(raw).items() if k in ("gyro", "accel", "tof")}
    except (ValueError, TypeError, AttributeError):
        log.warning("device metadata: nominal_rates_hz unreadable (%.40r); checking rates against the defaults", raw)
        return {}
    return {t: v for t, v in rates.items() if v > 0}


def source_fingerprint(path: Path) -> str:
    """A short digest of a recording's message statistics (counts per topic, first and last log
    time): what `tiplog metrics` compares to tell an estimate of this recording from one of
    another."""
    s = read_summary(path)
    if s is None or s.statistics is None:
        return ""
    topic_of = {cid: c.topic for cid, c in s.channels.items()}
    counts = sorted((topic_of.get(cid, str(cid)), n) for cid, n in s.statistics.channel_message_counts.items())
    key = json.dumps([s.statistics.message_start_time, s.statistics.message_end_time, counts])
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def iter_inputs(src: Path, stats: dict[str, int]):
    """(topic, message, log_time_ns) of the filter's input topics in log-time order; a message
    that does not decode is counted in stats['corrupt'] and skipped (a damaged chunk, which
    fails its CRC, is a UserError: nothing of it is fed to the filter)."""
    for _schema, channel, message in raw_messages(src, INPUT_TOPICS):
        try:
            cls = topics.message_type(channel.topic)
            msg = cls.FromString(message.data)
        except Exception:  # noqa: BLE001 - protobuf raises DecodeError and others
            stats["corrupt"] = stats.get("corrupt", 0) + 1
            continue
        yield channel.topic, msg, message.log_time


def run_filter(src: Path, runner: FusionRunner, progress: bool = False) -> tuple[list, dict[str, int]]:
    """Feed the recording in arrival order and collect every published state (offline)."""
    stats: dict[str, int] = {}
    s = read_summary(src)
    t0, t1 = s.statistics.message_start_time, s.statistics.message_end_time
    out = []
    next_report = 0.1
    wall = time.monotonic()
    for topic, msg, log_ns in iter_inputs(src, stats):
        runner.feed(topic, msg, log_ns)
        if topic == "device/gyro":
            out.extend(runner.advance(log_ns))
        frac = (log_ns - t0) / max(t1 - t0, 1)
        if progress and frac >= next_report:
            print(f"\rfusion {frac * 100:5.1f} %  {time.monotonic() - wall:6.1f} s", end="", file=sys.stderr)
            next_report += 0.1
    out.extend(runner.finish())
    if progress:
        print(f"\rfusion 100.0 %  {time.monotonic() - wall:6.1f} s", file=sys.stderr)
    return out, stats


def write_output(tmp: Path, samples: list, runner: FusionRunner, meta: dict[str, Any], smoothed=None) -> None:
    from services.fusion.publish import to_diagnostics, to_frame_transforms
    from services.fusion.scene import SCENE_PERIOD_NS, SceneTrail

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
        from services.fusion.smoother import smooth

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
