"""`tiplog info`'s gaps: sequence gaps per publisher when two share a topic, time gaps against
the topic's own rate when an outage leaves no sequence gap (a restarted publisher), and a
table whose columns never run together."""

from __future__ import annotations

from services.recorder.info import SequenceGaps, format_info, inspect
from services.recorder.timegaps import TimeGaps
from tiplog.mcap_io import McapWriter
from tiplog.v1 import device_pb2

MS = 1_000_000


def _write(path, samples) -> None:
    """samples: (topic, log_ns, seq)"""
    with McapWriter(path) as w:
        for topic, t, seq in samples:
            m = device_pb2.Gyro()
            m.header.stamp_ns = t
            w.write(topic, m, t, sequence=seq)


def test_two_publishers_interleaved_count_only_their_own_gaps(tmp_path):
    # Two gateways on device/gyro (one far into its sequence), 200 Hz each; the second misses 7.
    a = [("device/gyro", 1_000 * MS + k * 5 * MS, 900_000 + k) for k in range(2_000)]
    b = [("device/gyro", 1_001 * MS + k * 5 * MS, k) for k in range(2_000) if not 500 <= k < 507]
    _write(tmp_path / "two.mcap", sorted(a + b, key=lambda s: s[1]))
    info = inspect(tmp_path / "two.mcap")
    gyro = info["topics"]["device/gyro"]
    assert gyro["count"] == 3_993 and gyro["gaps"] == 7 and gyro["gap_events"] == 1, gyro
    assert gyro["sequences"] == 2 and info["gaps"] == 7


def test_a_restart_outage_is_a_time_gap_not_a_sequence_gap(tmp_path):
    before = [("device/accel", k * 4 * MS, k) for k in range(1_000)]  # 250 Hz for 4 s
    t_back = before[-1][1] + 3_000 * MS  # 3 s without data, then a new publisher from 0
    after = [("device/accel", t_back + k * 4 * MS, k) for k in range(1_000)]
    _write(tmp_path / "restart.mcap", before + after)
    info = inspect(tmp_path / "restart.mcap")
    acc = info["topics"]["device/accel"]
    assert acc["gaps"] == 0 and acc["time_gaps"] == 1 and info["time_gaps"] == 1
    assert 2.9 < acc["time_gap_s"] < 3.01 and abs(acc["longest_gap_s"] - 3.0) < 1e-6
    assert abs(acc["expected_hz"] - 250.0) < 0.5


def test_the_table_keeps_large_counts_apart(tmp_path):
    a = [("device/accel", k * MS, 10_000_000 * (k % 2) + k // 2) for k in range(3_000)]
    _write(tmp_path / "big.mcap", a)
    text = format_info(inspect(tmp_path / "big.mcap"))
    head, row = (ln for ln in text.splitlines() if ln.startswith(("topic ", "device/accel")))
    cells = row.split()
    assert cells[0] == "device/accel" and cells[2] == "3000", row
    assert len(cells) == len(
        head.replace("rate Hz", "rate")
        .replace(" gaps", "_gaps")
        .replace("gap s", "gap_s")
        .replace("longest s", "longest")
        .split()
    )
    assert "sequence gaps: 0" in text, text  # two interleaved sequences, each without a gap


def test_sequence_and_time_gap_rules_alone():
    g = SequenceGaps()
    for k, s in enumerate([0, 1, 2, 5, 100, 6, 101, 7, 0, 1]):  # two publishers, then a third from 0
        g.add(s, k * 10 * MS, 100.0)
    assert (g.gaps, g.events, g.sequences) == (2, 1, 3)
    t = TimeGaps()
    assert not any(t.add(k * 10 * MS) for k in range(50))
    assert t.add(49 * 10 * MS + 50 * MS) is False  # 5x the interval: not a gap
    assert t.add(49 * 10 * MS + 50 * MS + 200 * MS) is True and t.count == 1


def test_a_burst_at_the_end_does_not_become_the_expected_rate(tmp_path):
    # fusion/state_settled: 200 Hz for a minute, then at its stop the last second's states at
    # once (10 us apart): the rate shown is the minute's, not the flush's
    steady = [("fusion/state_settled", k * 5 * MS, k) for k in range(12_000)]
    t_stop = steady[-1][1] + 5 * MS
    flush = [("fusion/state_settled", t_stop + k * 10_000, 12_000 + k) for k in range(200)]
    _write(tmp_path / "flush.mcap", steady + flush)
    info = inspect(tmp_path / "flush.mcap")
    settled = info["topics"]["fusion/state_settled"]
    assert 200.0 <= settled["expected_hz"] < 204.0 and settled["time_gaps"] == 0, settled
    row = next(ln for ln in format_info(info).splitlines() if ln.startswith("fusion/state_settled"))
    assert 200.0 <= float(row.split()[4]) < 204.0, row


def test_the_recorders_counts_have_per_publisher_sequence_gaps_and_time_gaps():
    from services.recorder.counting import Counting
    from tiplog.bus import SampleInfo

    c = Counting(max_queue_bytes=10**9, max_queue_messages=10**9)
    t = 0
    for k in range(400):  # two publishers, 200 Hz each, interleaved; the second misses 3
        t += 2_500_000
        c.admit(SampleInfo("device/gyro", 900_000 + k, t, t, 1, "tiplog.v1.Gyro"), 10)
        if not 100 <= k < 103:
            c.admit(SampleInfo("device/gyro", k, t + 1, t + 1, 2, "tiplog.v1.Gyro"), 10)
    t += 3_000 * MS  # an outage of 3 s; the first publisher comes back from 0 (restarted)
    for k in range(10):
        t += 5 * MS
        c.admit(SampleInfo("device/gyro", k, t, t, 3, "tiplog.v1.Gyro"), 10)
    gyro = c.snapshot()["device/gyro"]
    assert gyro["upstream_gaps"] == 3 and gyro["time_gaps"] == 1 and 2.9 < gyro["time_gap_s"] < 3.01, gyro


def test_the_recorder_s_own_count_is_said_beside_the_sequence_gaps_when_they_differ(tmp_path):
    import json

    samples = [("device/gyro", k * 5 * MS, k) for k in range(100) if k != 50]  # one sample missing
    for name, upstream in (("same", 1), ("other", 4)):
        with McapWriter(tmp_path / f"{name}.mcap") as w:
            for topic, t, seq in samples:
                m = device_pb2.Gyro()
                m.header.stamp_ns = t
                w.write(topic, m, t, sequence=seq)
            w.add_metadata("recorder_counts", {"device/gyro": json.dumps({"written": 99, "upstream_gaps": upstream})})
    same = inspect(tmp_path / "same.mcap")
    assert same["gaps"] == 1 and same["recorder_gaps"] == 1
    assert "sequence gaps: 1   time gaps" in format_info(same)
    other = inspect(tmp_path / "other.mcap")
    assert other["gaps"] == 1 and other["recorder_gaps"] == 4
    assert "sequence gaps: 1 (the recorder counted 4 for its session, per publisher)" in format_info(other)
