"""Time gaps on a topic: an outage shows as an interval between arrivals far longer than the
topic's own rate, whatever the sequence numbers say (a restarted publisher starts again at 0,
so its outage leaves no sequence gap).

The expected interval is learnt from the stream itself (a running mean of the intervals that
are not gaps), so no table of rates is needed and a topic at 1 Hz and one at 240 Hz are
judged alike. An interval counts as a gap once `min_intervals` have been seen and it exceeds
both `factor` times the expected interval and `floor_s`. The recorder (live, on arrival) and
`tiplog info` (on the file's log times) use the same rule.

The rate reported beside the gaps (`expected_hz` in `as_dict`) is the topic's rate while it
flowed: every interval that was not a gap, over their total time. The running mean forgets
(a publisher that flushes what it held at its stop, as fusion's settled stream ends with a
second of states at once, leaves it at thousands of hertz), so it is not the figure to show.
"""

from __future__ import annotations

from dataclasses import dataclass

NS_PER_S = 1_000_000_000


@dataclass
class TimeGaps:
    """Gaps in one topic's arrival times (int64 ns, non-decreasing)."""

    factor: float = 10.0
    floor_s: float = 0.1
    min_intervals: int = 20
    alpha: float = 0.02  # weight of a new interval in the running mean
    count: int = 0  # gaps
    missing_s: float = 0.0  # time in gaps beyond the expected interval
    longest_s: float = 0.0
    _last_ns: int | None = None
    _intervals: int = 0
    _mean_ns: float = 0.0
    _flowing_ns: int = 0  # the total time of the intervals that were not gaps

    @property
    def expected_hz(self) -> float:
        """The rate the next interval is judged against (the running mean's)."""
        return NS_PER_S / self._mean_ns if self._mean_ns > 0 else 0.0

    @property
    def flowing_hz(self) -> float:
        """The topic's rate while it flowed: the intervals that were not gaps, over their time."""
        return self._intervals * NS_PER_S / self._flowing_ns if self._flowing_ns > 0 else 0.0

    def add(self, t_ns: int) -> bool:
        """One arrival at `t_ns`; True when the interval before it was a gap."""
        last, self._last_ns = self._last_ns, t_ns if self._last_ns is None else max(self._last_ns, t_ns)
        if last is None or t_ns <= last:
            return False
        dt = t_ns - last
        if self._intervals >= self.min_intervals and dt > max(self.factor * self._mean_ns, self.floor_s * NS_PER_S):
            self.count += 1
            gap_s = (dt - self._mean_ns) / NS_PER_S
            self.missing_s += gap_s
            self.longest_s = max(self.longest_s, dt / NS_PER_S)
            return True
        self._intervals += 1
        self._flowing_ns += dt
        a = max(self.alpha, 1.0 / self._intervals)  # a plain mean until there are enough
        self._mean_ns += a * (dt - self._mean_ns)
        return False

    def as_dict(self) -> dict[str, float | int]:
        return {
            "time_gaps": self.count,
            "time_gap_s": round(self.missing_s, 3),
            "longest_gap_s": round(self.longest_s, 3),
            "expected_hz": round(self.flowing_hz, 3),
        }
