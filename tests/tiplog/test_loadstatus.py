"""LoadMeter: per-period rate and latency beside running counts, and when a service is behind."""

from __future__ import annotations

from tiplog.loadstatus import LoadMeter


def test_each_period_gives_its_own_rate_latency_and_the_running_counts():
    m = LoadMeter("bench", 15.0)
    first = m.status(1_000_000_000)
    assert first.period_s == 0 and first.achieved_hz == 0 and not first.behind  # no period yet
    for k in range(15):
        m.done(float(k))
    m.count("frames_skipped_late", 2)
    a = m.status(2_000_000_000)
    assert (a.service, a.period_s, a.achieved_hz, a.target_hz) == ("bench", 1.0, 15.0, 15.0)
    assert not a.behind and a.counts["frames_skipped_late"] == 2
    assert 13.0 < a.latency_p95_ms <= 14.0
    for _ in range(6):
        m.done()
    m.count("frames_skipped_late", 9)
    b = m.status(3_000_000_000)
    assert b.achieved_hz == 6.0 and b.behind and m.behind
    assert b.counts["frames_skipped_late"] == 11 and b.latency_p95_ms == 0.0  # none given this period


def test_no_target_is_never_behind():
    m = LoadMeter("vision", 0.0)
    m.status(0)
    assert not m.status(1_000_000_000).behind
