"""The recorder core without a bus: sessions, splits, events, counts, a full disk, recovery."""

from __future__ import annotations

import errno
import io
import json
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from services.recorder.config import RecorderConfig
from services.recorder.recorder import Recorder
from services.recorder.recover import recover
from tiplog.bus import SampleInfo
from tiplog.mcap_io import read_messages, read_metadata, read_summary
from tiplog.v1 import device_pb2, recorder_pb2

A = recorder_pb2.RecorderAction
S = recorder_pb2.RecorderState


def gyro(seq: int, frame_id: str = "") -> bytes:
    m = device_pb2.Gyro()
    m.header.frame_id = frame_id
    m.header.seq = seq
    m.header.stamp_ns = 5_000_000 * seq
    m.rate_radps.x = 1e-3 * seq
    return m.SerializeToString()


def info(seq: int, topic: str = "device/gyro", pid: int = 7, t: int | None = None) -> SampleInfo:
    t = 1_000_000_000 + 5_000_000 * seq if t is None else t
    return SampleInfo(topic, seq, t - 1000, t, pid, "tiplog.v1.Gyro")


def cfg(tmp_path: Path, **kw) -> RecorderConfig:
    base = dict(out_dir=str(tmp_path), autostart="never", min_free_bytes=0, fsync_period_s=0.0)
    base.update(kw)
    return RecorderConfig(**base)


def cmd(action: int, reason: str = "", session: str = "") -> recorder_pb2.RecorderCommand:
    return recorder_pb2.RecorderCommand(action=action, reason=reason, session=session)


class Statuses:
    """Collects status callbacks; waits for a state."""

    def __init__(self) -> None:
        self.items: list[recorder_pb2.RecorderStatus] = []
        self.cv = threading.Condition()

    def __call__(self, st: recorder_pb2.RecorderStatus) -> None:
        with self.cv:
            self.items.append(st)
            self.cv.notify_all()

    def wait_state(self, state: int, timeout: float = 10.0) -> recorder_pb2.RecorderStatus:
        with self.cv:
            ok = self.cv.wait_for(lambda: any(s.state == state for s in self.items), timeout)
        assert ok, f"never reached state {state}: {[s.state for s in self.items]}"
        return next(s for s in self.items if s.state == state)


def test_session_split_mark_stop_and_counts(tmp_path):
    rec = Recorder(cfg(tmp_path, calibration_file=None))
    rec.start_thread()
    try:
        r = rec.command(cmd(A.RECORDER_ACTION_START, "test", "case1"))
        assert r.ok and r.status.state == S.RECORDER_STATE_RECORDING, r.message
        for k in range(100):
            rec.on_sample(gyro(k), info(k))
        assert rec.command(cmd(A.RECORDER_ACTION_MARK, "incision")).ok
        assert rec.command(cmd(A.RECORDER_ACTION_SPLIT)).ok
        for k in range(100, 150):
            if k != 120:  # one sample lost upstream
                rec.on_sample(gyro(k), info(k))
        r = rec.command(cmd(A.RECORDER_ACTION_STOP))
        assert r.ok and r.status.state == S.RECORDER_STATE_IDLE
        assert not rec.command(cmd(A.RECORDER_ACTION_STOP)).ok
    finally:
        rec.close()
    files = sorted(tmp_path.glob("case1_*.mcap"))
    assert [f.name for f in files] == ["case1_000.mcap", "case1_001.mcap"]
    seqs = [[r.sequence for r in read_messages(f)] for f in files]
    assert seqs[0] == list(range(100)) and seqs[1] == [k for k in range(100, 150) if k != 120]
    recs = list(read_messages(files[0]))
    assert recs[3].log_time_ns == 1_015_000_000 and recs[3].publish_time_ns == 1_015_000_000 - 1000
    md0, md1 = read_metadata(files[0]), read_metadata(files[1])
    assert md0["event_0001"]["label"] == "incision"
    assert md0["session"]["session"] == "case1" and md0["session"]["start_reason"] == "test"
    assert md1["session"]["file_index"] == "1"
    final = json.loads(md1["recorder_counts"]["device/gyro"])
    assert final == {
        "received": 149,
        "written": 149,
        "dropped": 0,
        "upstream_gaps": 1,
        "time_gaps": 0,
        "time_gap_s": 0.0,
    }
    s = read_summary(files[1])
    assert s.statistics.message_count == 49 and s.chunk_indexes


def test_queue_overflow_is_counted_as_dropped(tmp_path):
    rec = Recorder(cfg(tmp_path, max_queue_messages=100))
    # Writer thread not started yet: START is queued behind nothing, so run it by hand.
    rec._start("test", "q")
    for k in range(150):
        rec.on_sample(gyro(k), info(k))
    c = rec.counts()["device/gyro"]
    assert c["received"] == 150 and c["dropped"] == 50
    rec.start_thread()
    assert rec.command(cmd(A.RECORDER_ACTION_STOP)).ok
    rec.close()
    assert rec.counts()["device/gyro"]["written"] == 100


class FullDisk(io.RawIOBase):
    """A file on a disk with `capacity` bytes: writes past it fail with ENOSPC."""

    def __init__(self, path: Path, capacity: int):
        self.f = open(path, "wb", buffering=0)  # noqa: SIM115
        self.capacity = capacity

    def writable(self) -> bool:
        return True

    def write(self, b) -> int:  # type: ignore[override]
        room = self.capacity - self.f.tell()
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self.f.write(bytes(b)[:room])

    def seek(self, pos: int, whence: int = 0) -> int:
        return self.f.seek(pos, whence)

    def tell(self) -> int:
        return self.f.tell()

    def truncate(self, size: int | None = None) -> int:
        return self.f.truncate(size)

    def flush(self) -> None:
        pass

    def fileno(self) -> int:
        return self.f.fileno()

    def close(self) -> None:
        self.f.close()
        super().close()


def test_disk_full_keeps_file_valid_and_raises_alarm(tmp_path):
    statuses = Statuses()
    rec = Recorder(
        cfg(tmp_path, chunk_size_bytes=64 * 1024, flush_period_s=0.05),
        opener=lambda p: FullDisk(p, 200_000),
        on_status=statuses,
    )
    rec.start_thread()
    try:
        assert rec.command(cmd(A.RECORDER_ACTION_START, session="full")).ok
        big = "\x01" * 3000  # a 3000-byte frame name: messages of 3 kB
        k = 0
        while rec.state == S.RECORDER_STATE_RECORDING and k < 10_000:
            rec.on_sample(gyro(k, big), info(k))
            k += 1
            if k % 20 == 0:
                rec.command(cmd(A.RECORDER_ACTION_STATUS))  # let the writer catch up now and then
        err = statuses.wait_state(S.RECORDER_STATE_ERROR)
        assert "No space left" in err.alarm or "ENOSPC" in err.alarm or "disk full" in err.alarm
        assert rec.command(cmd(A.RECORDER_ACTION_STATUS)).status.state == S.RECORDER_STATE_ERROR
    finally:
        rec.close()
    path = tmp_path / "full_000.mcap"
    assert path.stat().st_size <= 200_000
    got = list(read_messages(path))  # valid without recovery
    c = rec.counts()["device/gyro"]
    assert 0 < len(got) <= c["written"] and c["dropped"] >= 1
    assert [r.sequence for r in got] == list(range(len(got)))


def test_reserve_refuses_start_and_stops_recording(tmp_path):
    free = [10 * 2**30]
    statuses = Statuses()

    class Usage:
        def __init__(self, free: int) -> None:
            self.free = free

    rec = Recorder(
        cfg(tmp_path, min_free_bytes=2**30, disk_check_period_s=0.05),
        disk_usage=lambda _p: Usage(free[0]),
        on_status=statuses,
    )
    rec.start_thread()
    try:
        assert rec.command(cmd(A.RECORDER_ACTION_START, session="r")).ok
        for k in range(10):
            rec.on_sample(gyro(k), info(k))
        free[0] = 2**29
        err = statuses.wait_state(S.RECORDER_STATE_ERROR)
        assert "reserve" in err.alarm
        r = rec.command(cmd(A.RECORDER_ACTION_START, session="r2"))
        assert not r.ok and "reserve" in r.message
    finally:
        rec.close()
    assert [r.sequence for r in read_messages(tmp_path / "r_000.mcap")] == list(range(10))
    assert read_summary(tmp_path / "r_000.mcap").statistics.message_count == 10
    assert not (tmp_path / "r2_000.mcap").exists()


def test_recover_truncated_file(tmp_path):
    rec = Recorder(cfg(tmp_path, chunk_size_bytes=64 * 1024))
    rec.start_thread()
    assert rec.command(cmd(A.RECORDER_ACTION_START, session="t")).ok
    for k in range(3000):
        rec.on_sample(gyro(k), info(k))
    rec.command(cmd(A.RECORDER_ACTION_STOP))
    rec.close()
    src = tmp_path / "t_000.mcap"
    data = src.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(Exception):  # noqa: B017  (the truncated file has no footer)
        list(make_reader(open(cut, "rb")).iter_messages())
    rep = recover(cut, tmp_path / "fixed.mcap")
    assert not rep.complete and rep.lost_bytes > 0 and rep.error
    got = [r.sequence for r in read_messages(tmp_path / "fixed.mcap")]
    assert got == list(range(len(got))) and 0 < len(got) < 3000
    assert rep.messages_by_topic["device/gyro"] == len(got)
    assert rep.last_good_log_ns == 1_000_000_000 + 5_000_000 * (len(got) - 1)
    assert "session" in read_metadata(tmp_path / "fixed.mcap")
    full = recover(src, tmp_path / "copy.mcap")
    assert full.complete and full.messages == 3000 and full.lost_bytes == 0


def test_unwritable_directory_raises_alarm_and_stays_up(tmp_path):
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("a file where the recordings folder should be")
    statuses = Statuses()
    rec = Recorder(cfg(tmp_path, out_dir=str(blocker / "rec")), on_status=statuses)
    rec.start_thread()
    try:
        r = rec.command(cmd(A.RECORDER_ACTION_START, session="u"))
        assert not r.ok and r.status.state == S.RECORDER_STATE_ERROR and "cannot open" in r.status.alarm
        rec.on_sample(gyro(0), info(0))  # ignored, not raised
        blocker.unlink()  # the operator fixes the mount: the next start works
        r = rec.command(cmd(A.RECORDER_ACTION_START, session="u"))
        assert r.ok and r.status.state == S.RECORDER_STATE_RECORDING and not r.status.alarm
        assert rec.command(cmd(A.RECORDER_ACTION_STOP)).ok
    finally:
        rec.close()
    assert read_summary(blocker / "rec" / "u_000.mcap").statistics.message_count == 0


@pytest.mark.parametrize("limit", [{"max_file_bytes": 40_000}, {"max_file_duration_s": 0.005}])
def test_automatic_split_by_size_and_duration_loses_nothing(tmp_path, limit):
    rec = Recorder(cfg(tmp_path, chunk_size_bytes=64 * 1024, **limit))
    rec.start_thread()
    try:
        assert rec.command(cmd(A.RECORDER_ACTION_START, session="s")).ok
        for k in range(3000):
            rec.on_sample(gyro(k), info(k))
            if k % 500 == 0:
                rec.command(cmd(A.RECORDER_ACTION_STATUS))
        assert rec.command(cmd(A.RECORDER_ACTION_MARK, "sync")).ok  # the writer has drained
        assert rec.command(cmd(A.RECORDER_ACTION_STOP)).ok
    finally:
        rec.close()
    files = sorted(tmp_path.glob("s_*.mcap"), key=lambda f: int(f.stem.split("_")[1]))
    assert len(files) > 1
    seqs = [r.sequence for f in files for r in read_messages(f)]
    assert seqs == list(range(3000))
    if "max_file_bytes" in limit:  # a file ends at the first flush past the limit
        assert all(f.stat().st_size < 40_000 + 64 * 1024 + 20_000 for f in files)


def test_a_session_name_used_twice_never_overwrites(tmp_path):
    rec = Recorder(cfg(tmp_path))
    rec.start_thread()
    try:
        for k in range(2):
            assert rec.command(cmd(A.RECORDER_ACTION_START, session="same")).ok
            rec.on_sample(gyro(k), info(k))
            assert rec.command(cmd(A.RECORDER_ACTION_STOP)).ok
    finally:
        rec.close()
    files = sorted(tmp_path.glob("same_*.mcap"))
    assert [f.name for f in files] == ["same_000.mcap", "same_001.mcap"]
    assert [[r.sequence for r in read_messages(f)] for f in files] == [[0], [1]]


def test_salvage_cuts_back_further_when_the_end_of_file_does_not_fit(tmp_path):
    """The disk fills a few bytes after a record boundary: no room for DataEnd + Footer there,
    so the file must end at the boundary before it, still valid without recovery."""
    from services.recorder.mcap_file import RecordingFile

    def write_all(f: RecordingFile, n: int) -> list[int]:
        offsets = []
        for k in range(n):
            f.write("device/gyro", "tiplog.v1.Gyro", gyro(k), 1000 * k, 1000 * k, k)
            f.flush()
            offsets.append(f.good_offset)
        return offsets

    probe = RecordingFile(tmp_path / "probe.mcap", compression="none", chunk_size=1 << 20)
    offsets = write_all(probe, 6)
    probe.close()
    capacity = offsets[3] + 10  # room for the 4th record's end, not for the 5th nor the footer
    f = RecordingFile(
        tmp_path / "full.mcap", compression="none", chunk_size=1 << 20, opener=lambda p: FullDisk(p, capacity)
    )
    with pytest.raises(OSError):
        write_all(f, 6)
    assert f.salvage()
    got = list(read_messages(tmp_path / "full.mcap"))
    assert [r.sequence for r in got] == [0, 1, 2]
    assert (tmp_path / "full.mcap").stat().st_size <= capacity


def test_write_rate_gives_the_minutes_of_case_left():
    from services.recorder.recorder import WriteRate

    w = WriteRate()
    assert w.minutes_left(10**9, 0) is None  # no rate yet
    for k in range(10):
        w.update(float(k), k * 2_000_000)  # 2 MB/s
    assert abs(w.rate_bps - 2e6) < 1 and abs(w.minutes_left(2_000_000 * 60 * 7 + 5, 5) - 7.0) < 1e-6
    w.update(10.0, 0)  # a new session: its bytes start again, the rate stays
    assert abs(w.rate_bps - 2e6) < 1


def test_the_low_disk_alarm_says_minutes_of_case_left_and_recording_goes_on(tmp_path):
    class Usage:
        free = 3 * 2**30

    rec = Recorder(
        cfg(tmp_path, min_free_bytes=2**30, disk_check_period_s=0.05, warn_minutes_left=1e9),
        disk_usage=lambda _p: Usage(),
    )
    rec.start_thread()
    try:
        assert rec.command(cmd(A.RECORDER_ACTION_START, session="low")).ok
        deadline, k = time.monotonic() + 20, 0
        while "min of case left" not in rec.status().alarm:
            assert time.monotonic() < deadline, rec.status().alarm
            rec.on_sample(gyro(k, "x" * 2000), info(k))
            k += 1
            time.sleep(0.001)
        st = rec.status()
        assert st.state == S.RECORDER_STATE_RECORDING and st.alarm.startswith("low disk: 3.0 GiB free: about ")
        assert " MB/s" in st.alarm
    finally:
        rec.close()
