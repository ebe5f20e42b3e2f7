"""The recorder's core: a bounded queue filled on Zenoh's threads, one writer thread that owns
every file operation, sessions split by size and duration, per-topic counts, disk alarms.

Times: `log_time` is the receive time on this host's clock (`tiplog.clock.now_ns`,
CLOCK_MONOTONIC), `publish_time` the publisher's stamp at put, `sequence` the publisher's bus
sequence number (low 32 bits). Receive time rather than the header stamp because every
message has one (foreign and header-less types too), it never runs backwards within a file,
so chunks stay in time order, and it is the moment the data existed on this host, which is
what a replay reproduces; the sample's own capture stamp stays inside the payload. The wall
clock at the session start is in the `session` metadata to place the file in calendar time.

Commands (start/stop/split/mark/status) run on the writer thread too, so a file is never
touched from two threads; the caller waits for the reply.
"""

from __future__ import annotations

import logging
import queue
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from services.recorder.admission import QUARANTINE_TYPE, Admission, quarantine_record, quarantine_topic
from services.recorder.camera_archive import CameraArchive
from services.recorder.config import RecorderConfig
from services.recorder.counting import Counting
from services.recorder.mcap_file import Opener, RecordingFile, open_file
from services.recorder.session_files import SessionFiles
from tiplog.bus import SampleInfo
from tiplog.clock import NS_PER_S, now_ns, wall_ns
from tiplog.v1 import device_pb2, recorder_pb2

log = logging.getLogger(__name__)

S = recorder_pb2.RecorderState
A = recorder_pb2.RecorderAction
STATUS_TOPIC = "recorder/status"
DiskUsage = Callable[[str], Any]  # shutil.disk_usage's signature: .free in bytes


@dataclass
class _Command:
    cmd: recorder_pb2.RecorderCommand
    done: threading.Event = field(default_factory=threading.Event)
    reply: recorder_pb2.RecorderReply | None = None


_STOP = object()


LOW_DISK = "low disk: "  # the alarm while recording goes on, before the reserve stops it


@dataclass
class WriteRate:
    """The recorder's write rate (bytes per second, a running mean over disk checks) and the
    minutes of case the free space above the reserve holds at that rate."""

    alpha: float = 0.2
    rate_bps: float = 0.0
    _t: float | None = None
    _bytes: int = 0

    def update(self, t_s: float, total_bytes: int) -> None:
        if self._t is not None and t_s > self._t and total_bytes >= self._bytes:
            inst = (total_bytes - self._bytes) / (t_s - self._t)
            self.rate_bps = inst if self.rate_bps == 0.0 else self.rate_bps + self.alpha * (inst - self.rate_bps)
        self._t, self._bytes = t_s, total_bytes

    def minutes_left(self, free_bytes: int, reserve_bytes: int) -> float | None:
        if self.rate_bps <= 0 or free_bytes < 0:
            return None
        return max(0.0, free_bytes - reserve_bytes) / self.rate_bps / 60.0


class Recorder(SessionFiles):
    """Records whatever `on_sample` is given while a session runs.

    `opener` and `disk_usage` are seams for tests (a full disk, a shrinking free space);
    `on_status` is called with a RecorderStatus on every state change."""

    def __init__(
        self,
        config: RecorderConfig,
        *,
        opener: Opener = open_file,
        disk_usage: DiskUsage = shutil.disk_usage,
        on_status: Callable[[recorder_pb2.RecorderStatus], None] | None = None,
        extra_metadata: dict[str, dict[str, Any]] | None = None,
        extra_attachments: dict[str, tuple[bytes, str]] | None = None,
    ):
        self.config = config
        self.out_dir = Path(config.out_dir)
        self._opener = opener
        self._disk_usage = disk_usage
        self._on_status = on_status
        self._extra_metadata = extra_metadata or {}
        self._extra_attachments = extra_attachments or {}  # name -> (data, media type)
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._counting = Counting(config.max_queue_bytes, config.max_queue_messages)
        self._admission = Admission()  # used on the writer thread only
        self.camera_kept_raw = 0  # camera frames that could not be compressed, written as they came
        self._camera = (
            CameraArchive(config.camera_topics, config.camera_jpeg_quality) if config.camera_archive == "jpeg" else None
        )
        # autostart=always: the start command is queued first, and every sample from now on
        # (the subscription may already be declared) queues behind it and lands in the first
        # file: a publisher that sees the subscription may start at once (`tiplog replay` does).
        self._pending_start = config.autostart == "always"
        if self._pending_start:
            self._q.put(_Command(recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_START, reason="autostart")))
        self._recording = False  # read on Zenoh's threads without the lock (a bool is atomic)
        self._faulted = False  # a session ended on a fault: keep counting drops until stop/start
        self.state = S.RECORDER_STATE_IDLE
        self.alarm = ""
        self.disk = WriteRate()
        self.session = ""
        self.file_index = 0
        self._file: RecordingFile | None = None
        self._session_start_ns = 0
        self._file_start_ns = 0
        self._bytes_before = 0  # bytes of the session's earlier files
        self._free_bytes = 0
        self._events = 0
        self._start_reason = ""
        self._last_path = ""
        self._device: device_pb2.DeviceStatus | None = None
        self._device_written = False
        self._auto_armed = True
        self._thread = threading.Thread(target=self._run, name="recorder-writer", daemon=True)

    # ---------------------------------------------------------------- Zenoh's threads
    def on_sample(self, payload: bytes, info: SampleInfo) -> None:
        """Bus callback: count, check sequence, enqueue. No disk work here."""
        if info.topic == "device/status":
            self._on_device_status(payload)
        if not self._recording and not self._pending_start:
            if self._faulted:  # the session was cut short: count what it is missing
                self._counting.missed(info.topic)
            return
        if not self._counting.admit(info, len(payload)):
            return
        self._q.put((payload, info))

    def _on_device_status(self, payload: bytes) -> None:
        try:
            st = device_pb2.DeviceStatus.FromString(payload)
        except Exception:  # counted by the writer as any other message; nothing to act on
            return
        self._device = st
        streaming = st.state == device_pb2.DEVICE_STATE_STREAMING
        if not streaming:
            self._auto_armed = True
        elif self.config.autostart == "device" and self._auto_armed and not self._recording:
            self._auto_armed = False
            cmd = recorder_pb2.RecorderCommand(action=A.RECORDER_ACTION_START, reason="device streaming")
            self._q.put(_Command(cmd))  # no wait: this is Zenoh's thread

    # ---------------------------------------------------------------- public API
    def start_thread(self) -> None:
        self._free_bytes = self._free()
        self._thread.start()

    def command(self, cmd: recorder_pb2.RecorderCommand, timeout_s: float = 10.0) -> recorder_pb2.RecorderReply:
        """Run a command on the writer thread and return its reply."""
        if cmd.action == A.RECORDER_ACTION_STATUS:
            return recorder_pb2.RecorderReply(ok=True, message="status", status=self.status())
        c = _Command(cmd)
        self._q.put(c)
        if not c.done.wait(timeout_s) or c.reply is None:
            return recorder_pb2.RecorderReply(ok=False, message="recorder busy: no reply in time", status=self.status())
        return c.reply

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop the session (file finished) and the writer thread."""
        if self._thread.is_alive():
            self._q.put(_STOP)
            self._thread.join(timeout_s)

    def counts(self) -> dict[str, dict[str, int]]:
        return self._counting.snapshot()

    def status(self) -> recorder_pb2.RecorderStatus:
        st = recorder_pb2.RecorderStatus(
            state=self.state, alarm=self.alarm, session=self.session, file_index=self.file_index
        )
        st.header.stamp_ns = now_ns()
        f = self._file
        if f is not None:
            st.path = str(f.path)
            st.bytes_written = self._bytes_before + f.bytes_written
        else:
            st.path = self._last_path  # the file just finished, until the next one opens
            st.bytes_written = self._bytes_before
        st.free_bytes = max(0, self._free_bytes)
        if self._session_start_ns and self._recording:
            st.duration_s = (now_ns() - self._session_start_ns) / NS_PER_S
        for topic, c in self.counts().items():
            st.topics[topic].CopyFrom(recorder_pb2.TopicCounts(**c))
        return st

    # ---------------------------------------------------------------- writer thread
    def _run(self) -> None:
        cfg = self.config
        next_flush = next_fsync = next_disk = time.monotonic()
        while True:
            now = time.monotonic()
            if self._file is not None:
                if now >= next_flush:
                    self._guard(self._file.flush)
                    next_flush = now + cfg.flush_period_s
                if self._file is not None and cfg.fsync_period_s and now >= next_fsync:
                    self._guard(self._file.fsync)
                    next_fsync = now + cfg.fsync_period_s
                if self._file is not None and now >= next_disk:
                    self._check_disk()
                    next_disk = now + cfg.disk_check_period_s
                if self._file is not None:
                    self._check_split()
            elif now >= next_disk:
                self._free_bytes = self._free()
                next_disk = now + cfg.disk_check_period_s
            timeout = max(0.0, min(next_flush, next_disk) - time.monotonic()) if self._file else cfg.disk_check_period_s
            try:
                item = self._q.get(timeout=min(timeout, 0.25))
            except queue.Empty:
                continue
            if item is _STOP:
                if self._file is not None:
                    self._end_file("recorder shut down")
                self._set_idle()
                return
            if isinstance(item, _Command):
                try:
                    item.reply = self._execute(item.cmd)
                except Exception as e:  # a bug must not leave the caller waiting
                    log.exception("command %s failed", item.cmd.action)
                    item.reply = recorder_pb2.RecorderReply(ok=False, message=f"internal error: {e}")
                item.done.set()
                continue
            try:
                self._write(*item)
            except Exception:  # a bug on one message must not stop the recording
                log.exception("writing a message of %s failed", item[1].topic)

    def _write(self, payload: bytes, info: SampleInfo) -> None:
        self._counting.dequeued(len(payload))
        f = self._file
        if f is None:  # arrived while a stop or a fault was on its way
            self._counting.unrecorded(info.topic, dropped=self.state == S.RECORDER_STATE_ERROR)
            return
        reason = self._admission.check(info.topic, info.type_name, payload)
        if reason is not None:
            self._reject(f, payload, info, reason)
            return
        topic, type_name = info.topic, info.type_name
        if self._camera is not None and self._camera.wants(topic, type_name):
            try:
                topic, type_name, payload = self._camera.encode(topic, payload)
            except ValueError as e:  # kept as it came rather than lost
                self.camera_kept_raw += 1
                if self.camera_kept_raw == 1:
                    log.warning("a camera frame on %s is kept raw: %s", topic, e)
        try:
            f.write(topic, type_name, payload, info.receive_ns, info.publish_ns, info.seq)
        except OSError as e:
            self._counting.drop(info.topic)
            self._fault(f"write failed: {e}")
            return
        except (KeyError, ValueError) as e:  # unknown schema or a type change on a topic
            if self._counting.drop(info.topic) == 1:  # once per topic and session: the counts carry the rest
                log.warning("cannot record %s: %s", info.topic, e)
            return
        self._counting.written(info.topic)

    def _reject(self, f: RecordingFile, payload: bytes, info: SampleInfo, reason: str) -> None:
        """Keep a payload that failed the admission check off its topic's channel: counted under
        `_rejected/<topic>:<reason>` and, within the configured sizes, kept there."""
        qtopic = quarantine_topic(info.topic, reason)
        cfg = self.config
        keep = (
            cfg.quarantine
            and len(payload) <= cfg.quarantine_max_payload_bytes
            and f.quarantined_bytes + len(payload) <= cfg.quarantine_max_bytes_per_file
        )
        if keep:
            record = quarantine_record(info.type_name, payload)
            try:
                f.write(qtopic, QUARANTINE_TYPE, record, info.receive_ns, info.publish_ns, info.seq)
            except OSError as e:
                self._counting.rejected(qtopic, kept=False)
                self._fault(f"write failed: {e}")
                return
            f.quarantined_bytes += len(payload)
        if self._counting.rejected(qtopic, kept=keep) == 1:  # once per topic, reason and session
            log.warning(
                "rejected a payload on %s (%s; claimed type %.80r, %d bytes): %s",
                info.topic,
                reason,
                info.type_name,
                len(payload),
                f"kept on {qtopic}" if keep else "not kept",
            )

    def _guard(self, fn: Callable[[], None]) -> None:
        try:
            fn()
        except OSError as e:
            self._fault(f"write failed: {e}")

    def _free(self) -> int:
        try:
            target = self.out_dir if self.out_dir.exists() else self.out_dir.parent
            return int(self._disk_usage(str(target)).free)
        except OSError as e:
            log.warning("free space of %s unknown: %s", self.out_dir, e)
            return -1

    def _check_disk(self) -> None:
        self._free_bytes = free = self._free()
        self.disk.update(time.monotonic(), self._bytes_before + (self._file.bytes_written if self._file else 0))
        left = self.disk.minutes_left(free, self.config.min_free_bytes)
        at = f"{self.disk.rate_bps / 1e6:.1f} MB/s" if self.disk.rate_bps else "an unknown rate"
        if 0 <= free < self.config.min_free_bytes:
            self._fault(
                f"free space {free / 2**20:.0f} MiB below the reserve of {self.config.min_free_bytes / 2**20:.0f} MiB "
                f"(writing {at})"
            )
        elif left is not None and left < self.config.warn_minutes_left:
            alarm = f"{LOW_DISK}{free / 2**30:.1f} GiB free: about {left:.0f} min of case left at {at}"
            if not self.alarm.startswith(LOW_DISK):
                log.warning("recorder alarm: %s", alarm)
            self.alarm = alarm
        elif self.alarm.startswith(LOW_DISK):
            self.alarm = ""

    def _check_split(self) -> None:
        f, cfg = self._file, self.config
        if f is None:
            return
        too_big = cfg.max_file_bytes and f.bytes_written >= cfg.max_file_bytes
        too_long = cfg.max_file_duration_s and now_ns() - self._file_start_ns >= cfg.max_file_duration_s * NS_PER_S
        if too_big or too_long:
            self._split("size limit" if too_big else "duration limit")

    # ---------------------------------------------------------------- state
    def _fault(self, alarm: str) -> None:
        """Stop writing, keep the file valid, raise the alarm; the process stays up."""
        f = self._file
        self._recording = False
        self._file = None
        if f is not None:
            self._faulted = True
            self._last_path = str(f.path)
            self._bytes_before += f.bytes_written
            if alarm.startswith("write failed"):
                f.salvage()
            else:  # the reserve tripped: the disk still takes the summary
                try:
                    f.add_metadata("recorder_counts", self.counts())
                    f.add_metadata("recorder_end", {"reason": alarm, "wall_end_ns": wall_ns()})
                    f.close()
                except OSError:
                    f.salvage()
        self._alarm_error(alarm)

    def _alarm_error(self, alarm: str) -> None:
        self.alarm = alarm
        self.state = S.RECORDER_STATE_ERROR
        log.error("recorder alarm: %s", alarm)
        self._notify()

    def _set_idle(self) -> None:
        self._recording = False
        if self.state != S.RECORDER_STATE_ERROR:
            self.state = S.RECORDER_STATE_IDLE
        self._notify()

    def _notify(self) -> None:
        if self._on_status is not None:
            try:
                self._on_status(self.status())
            except Exception:
                log.exception("status callback raised")
