"""The recorder's sessions on its writer thread: the commands (start, stop, split, mark), and
each file's life from opening (header metadata) to its end (counts, summary). A part of
`Recorder` (services.recorder.recorder), which holds the state these methods use; only the
writer thread calls them, so a file is never touched from two threads."""

from __future__ import annotations

import logging
import time

from services.recorder.file_metadata import write_header_metadata
from services.recorder.mcap_file import RecordingFile
from tiplog.clock import now_ns, wall_ns
from tiplog.v1 import recorder_pb2

log = logging.getLogger("services.recorder.recorder")

S = recorder_pb2.RecorderState
A = recorder_pb2.RecorderAction


class SessionFiles:
    """Commands and file life of `Recorder` (mixed in; see there for the state)."""

    def _execute(self, cmd: recorder_pb2.RecorderCommand) -> recorder_pb2.RecorderReply:
        a = cmd.action
        if a == A.RECORDER_ACTION_START:
            ok, msg = self._start(cmd.reason or "command", cmd.session)
        elif a == A.RECORDER_ACTION_STOP:
            self._auto_armed = False  # the operator stopped: no restart until the device reconnects
            self._faulted = False
            if self._file is None:
                ok, msg = False, "not recording"
            else:
                path = self._end_file(cmd.reason or "stop command")
                self._set_idle()
                ok, msg = True, f"stopped; {path}"
        elif a == A.RECORDER_ACTION_SPLIT:
            ok, msg = (False, "not recording") if self._file is None else self._split(cmd.reason or "split command")
        elif a == A.RECORDER_ACTION_MARK:
            ok, msg = self._mark(cmd.reason)
        elif a == A.RECORDER_ACTION_STATUS:
            ok, msg = True, "status"
        else:
            ok, msg = False, f"unknown action {a}"
        return recorder_pb2.RecorderReply(ok=ok, message=msg, status=self.status())

    def _start(self, reason: str, name: str) -> tuple[bool, str]:
        try:
            return self._start_session(reason, name)
        finally:
            self._pending_start = False

    def _start_session(self, reason: str, name: str) -> tuple[bool, str]:
        if self._file is not None:
            return False, f"already recording to {self._file.path}"
        self._free_bytes = free = self._free()
        if 0 <= free < self.config.min_free_bytes:
            self._alarm_error(f"not started: free space {free / 2**20:.0f} MiB below the reserve")
            return False, self.alarm
        safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name)
        self.session = safe or self.config.session_prefix + time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
        self._faulted = False
        if not self._pending_start:  # the autostart's early samples are already counted
            self._counting.reset()
        self.file_index = 0
        self._bytes_before = 0
        self._events = 0
        self._session_start_ns = now_ns()
        self._start_reason = reason
        if not self._open_file():
            return False, self.alarm
        self.alarm = ""
        log.info("recording session %s (%s) to %s", self.session, reason, self._file.path if self._file else "?")
        return True, f"recording to {self._file.path if self._file else '?'}"

    def _open_file(self) -> bool:
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            path = self.out_dir / f"{self.session}_{self.file_index:03d}.mcap"
            while path.exists():  # a session name used before: never overwrite a recording
                self.file_index += 1
                path = self.out_dir / f"{self.session}_{self.file_index:03d}.mcap"
            f = RecordingFile(
                path, compression=self.config.compression, chunk_size=self.config.chunk_size_bytes, opener=self._opener
            )
        except OSError as e:
            self._alarm_error(f"cannot open a file in {self.out_dir}: {e}")
            return False
        self._file = f
        self._file_start_ns = now_ns()
        self._device_written = False
        try:
            self._write_header_metadata(f)
            f.flush()
        except OSError as e:
            self._fault(f"write failed: {e}")
            return False
        self._recording = True
        self.state = S.RECORDER_STATE_RECORDING
        self._notify()
        return True

    def _write_header_metadata(self, f: RecordingFile) -> None:
        session = {"session": self.session, "file_index": self.file_index, "start_reason": self._start_reason}
        write_header_metadata(f, self.config, session, self._extra_metadata, self._extra_attachments)
        self._write_device(f)

    def _write_device(self, f: RecordingFile) -> None:
        d = self._device
        if d is None or self._device_written:
            return
        f.add_metadata(
            "device",
            {
                "firmware": d.firmware,
                "device_id": d.device_id,
                "port": d.port,
                "protocol_version": d.protocol_version,
                "nominal_rates_hz": dict(d.nominal_rates_hz),
            },
        )
        self._device_written = True

    def _end_file(self, reason: str) -> str:
        """Write the closing metadata and finish the file; salvage it when that fails."""
        f = self._file
        self._file = None
        if f is None:
            return ""
        self._last_path = str(f.path)
        self._bytes_before += f.bytes_written
        try:
            self._write_device(f)
            f.add_metadata("recorder_counts", self.counts())
            f.add_metadata(
                "recorder_end",
                {
                    "reason": reason,
                    "wall_end_ns": wall_ns(),
                    "file_written": f.written_by_topic,
                    "events": self._events,
                },
            )
            f.close()
        except OSError as e:
            log.error("finishing %s failed: %s", f.path, e)
            f.salvage()
        log.info("closed %s (%s)", f.path, reason)
        return str(f.path)

    def _split(self, reason: str) -> tuple[bool, str]:
        old = self._end_file(reason)
        self.file_index += 1
        if not self._open_file():
            return False, self.alarm
        return True, f"split: {old} -> {self._file.path if self._file else '?'}"

    def _mark(self, label: str) -> tuple[bool, str]:
        f = self._file
        if f is None:
            return False, "not recording"
        self._events += 1
        t = now_ns()
        try:
            f.add_metadata(f"event_{self._events:04d}", {"label": label, "log_time_ns": t, "wall_ns": wall_ns()})
        except OSError as e:
            self._fault(f"write failed: {e}")
            return False, self.alarm
        return True, f"event {self._events} marked at {t} ns"
