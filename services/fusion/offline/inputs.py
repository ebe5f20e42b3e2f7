"""A recorded session as the filter's input, as a library: the topics the filter reads, in
log-time order (`iter_inputs`), and the checks `tiplog fusion run` makes before any work
(streams present, each near its nominal rate). The study and the benchmarks read sessions
through here too."""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

from tiplog import topics
from tiplog.mcap_io import raw_messages, read_metadata, read_summary, topic_spans
from tiplog.userio import UserError

log = logging.getLogger("tiplog.fusion")
INPUT_TOPICS = ("device/gyro", "device/accel", "device/tof", "device/status", "vision/observation", "camera/info")
# The paper's module (BNO085, VL53L0X) and camera; a device's own hello (the recording's `device`
# metadata) overrides the device streams', so a module with other rates is checked against it.
NOMINAL_HZ = {"device/gyro": 200.0, "device/accel": 240.0, "device/tof": 100.0, "vision/observation": 15.0}
RATE_TOLERANCE = 0.5  # an IMU or ToF stream below half or above twice its nominal rate is refused


def recording_metadata(src: Path) -> dict[str, dict[str, str]]:
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
        whose = "announced by the device" if t in announced else "default; the recording names no device rates"
        if t == "vision/observation":
            # vision sheds stale frames on a loaded host by design, and a faster camera is fine:
            # a slow vision stream is a recording to process, with a word about it
            if rate < nominal * RATE_TOLERANCE:
                log.warning("%s: %s at %.1f Hz, below its nominal %.0f Hz (%s)", src, t, rate, nominal, whose)
            continue
        if not (nominal * RATE_TOLERANCE <= rate <= nominal / RATE_TOLERANCE):
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
