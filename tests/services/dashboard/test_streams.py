"""The streams table's rates: each over the last few seconds, so that a slow topic reads its
rate at every refresh (over one status period alone a 1 Hz topic read 0 and 2 Hz in turn), a
fast one its rate, and a topic that stopped falls to 0 within the window."""

from __future__ import annotations

from services.dashboard.streams import StreamStats


def test_rates_are_steady_for_slow_and_fast_topics_and_fall_to_zero_when_a_topic_stops():
    t = [0]
    stats = StreamStats(rate_window_s=5.0, clock=lambda: t[0])
    seq = {"bench/status": 0, "device/gyro": 0}
    seen: dict[str, list[float]] = {k: [] for k in seq}
    for ms in range(1, 30_001):  # 30 s in 1 ms steps; the status refreshes every 500 ms
        t[0] = ms * 1_000_000 + 137_000  # the 1 Hz topic's phase is off the refresh's
        if ms % 1000 == 0 and ms <= 20_000:  # 1 Hz for 20 s, then silent
            seq["bench/status"] += 1
            stats.on_sample("bench/status", seq["bench/status"], 1, t[0])
        if ms % 5 == 0:  # 200 Hz throughout
            seq["device/gyro"] += 1
            stats.on_sample("device/gyro", seq["device/gyro"], 2, t[0])
        if ms % 500 == 0:
            snap = stats.snapshot()
            for k in seq:
                seen[k].append(snap[k]["rate_hz"] if k in snap else 0.0)
    steady = slice(12, 40)  # from 6 s (a full window) to 20 s
    assert all(0.8 <= r <= 1.2 for r in seen["bench/status"][steady]), seen["bench/status"][steady]
    assert all(199.0 <= r <= 201.0 for r in seen["device/gyro"][steady]), seen["device/gyro"][steady]
    assert seen["bench/status"][-1] == 0.0  # silent for 10 s: past the window
    assert 199.0 <= seen["device/gyro"][-1] <= 201.0
    snap = stats.snapshot()
    assert snap["bench/status"]["count"] == 20 and snap["bench/status"]["dropped"] == 0
