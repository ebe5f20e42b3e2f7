"""`FusionRunner`: the tracking filter fed message by message, live or offline, with the same
result either way.

Times: every stream is shifted by its calibrated latency (t = header stamp - latency); vision
stamps are capture stamps. Messages are fed in arrival order. The state at gyro time t_k is
published with exactly the information that had arrived by its publication time
c_k = max(t_k + output_delay, arrival of gyro k): the runner incorporates, in time order, every
message that arrived by c_k and is not later than t_k, rewinding its history (snapshots after
every gyro sample) when one is older than what it already processed (late vision). So the
output depends only on the inputs, never on how `advance` calls interleave with `feed`:
offline (`feed` everything, then `finish`) equals live. A measurement that arrives more than
`max_age_ms` after its time, or older than the kept history, is counted and dropped.

Two outputs. The display stream (`output="display"`, the live `fusion/state`) is the one above,
`output_delay_ms` behind. The settled stream holds the state at t_k once every measurement that
can still be applied at its time has arrived, `max_age_ms` after it: the causal filter with
every late frame applied at its time, which the display stream converges to. `output="settled"`
publishes only that (offline: no frame is ever late, so nothing is rewound); `output="both"`
(the live service) returns the display stream from `advance` and the settled one from
`take_settled`. The settled states of "both" equal those of "settled" (bit for bit in the tests;
a rewound map could leave a difference in the last bits).
"""

from __future__ import annotations

import bisect
import heapq
import math
from collections import Counter, deque
from typing import Any

import numpy as np

from services.fusion.eskf.filter import ADAPTIVE, State, TrackingFilter
from services.fusion.eskf.init import initial_rotation, shaft_from_tilt
from services.fusion.eskf.measurement import Measurement
from services.fusion.eskf.params import SENSORS, Params, mode_name
from services.fusion.eskf.sample import StateSample, finite_sample
from services.fusion.timing.measurements import MessageAdapter
from tiplog.calibration import Calibration

ALL = SENSORS
KIND_ORDER = {"gyro": 0, "accel": 1, "tof": 2, "vision": 3}
# An event's key is one int, (t << T_SHIFT) + (kind order << K_SHIFT) + seq: time order, then
# kind, then arrival (seq < 2^K_SHIFT, years of messages). One int compares in one step where a
# (t, kind, seq) tuple took several, and the queue of pending events compares keys at every
# message.
T_SHIFT, K_SHIFT = 40, 36
KEY_BEFORE_ALL = -(1 << 110)  # below every key (the empty start's snapshot)
OUTPUTS = ("display", "settled", "both")
__all__ = ["ALL", "FusionRunner", "StateSample"]


class _Track:
    """What a rewind restores: the filter state (None before initialisation) and the latest
    accelerometer sample (for initialising roll)."""

    __slots__ = (
        "state",
        "f_last",
        "resets",
        "reset_reasons",
        "reset_ns",
        "neutral_u",
        "carried",
        "carried_nis",
        "map_mark",
        "noise",
        "tof_last",
        "start_refused",
    )

    def __init__(self) -> None:
        self.state: State | None = None
        self.f_last: np.ndarray | None = None
        self.resets = 0
        self.reset_reasons: dict[str, int] = {}
        self.reset_ns: int | None = None  # when the last reset dropped the state, until a restart
        self.neutral_u: np.ndarray | None = None
        # update counts and NIS sums of the states a reset discarded: diagnostics cover the run
        self.carried: Counter[str] = Counter()
        self.carried_nis: Counter[str] = Counter()
        self.map_mark: tuple[int, ...] = ()  # the filter's maps' mark() when this was taken
        # the streams' noise factors of the state a reset discarded (`State.noise`): what a
        # stream's innovations taught is kept for the next state; None before any reset
        self.noise: np.ndarray | None = None
        self.tof_last: tuple[int, float] | None = None  # (t_ns, range_m) of the latest range while there is no state
        self.start_refused = 0  # vision starts the ToF refused in a row (`TrackingFilter.start_from_vision`)

    def copy(self) -> _Track:
        t = _Track.__new__(_Track)
        t.state = None if self.state is None else self.state.copy()
        t.f_last = self.f_last
        t.resets = self.resets
        # shared, not copied: a reset replaces these (never mutates them), and a snapshot is
        # taken at every gyro sample
        t.reset_reasons = self.reset_reasons
        t.reset_ns = self.reset_ns
        t.neutral_u = self.neutral_u
        t.carried = self.carried
        t.carried_nis = self.carried_nis
        t.map_mark = self.map_mark
        t.noise = self.noise  # replaced at a reset, never changed in place
        t.tof_last = self.tof_last
        t.start_refused = self.start_refused
        return t


class FusionRunner:
    def __init__(
        self,
        calibration: Calibration,
        params: Params | None = None,
        sensors: frozenset[str] = ALL,
        output: str = "display",
    ):
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {', '.join(OUTPUTS)} (got {output!r})")
        self.calib = calibration
        self.params = params or Params()
        self.sensors = frozenset(sensors)
        self.output = output
        self.filt = TrackingFilter(calibration, self.params, self.sensors)
        p = self.params
        self.history_ns = int(p.history_ms * 1e6)
        self.max_age_ns = int(p.max_age_ms * 1e6)
        # what advance() returns, this far behind: settled, nothing arrives late, so no history
        # is kept for rewinds
        self.delay_ns = self.max_age_ns if output == "settled" else p.output_delay_ns
        self._keep_history = output != "settled"
        self.lock_ns = int(p.vision_lock_ms * 1e6)
        self.restart_ns = int(p.restart_without_vision_ms * 1e6) if p.restart_without_vision_ms > 0 else None
        self._pending: deque[tuple[int, tuple]] = deque()  # (arrival, event) in feed order
        self._gyro_due: deque[tuple[int, int, int]] = deque()  # (cutoff, t, key) to publish
        self._settle_due: deque[tuple[int, int, int]] = deque()  # the same, settled ("both")
        self._settled: list[StateSample] = []
        self._last_settled_t = -(1 << 62)
        self._ready: list[tuple] = []  # heap of arrived events not yet processed (ahead of head)
        self._done_keys: list[int] = []  # processed events in key order
        self._done: list[tuple] = []
        self._last_done: int | None = None  # the key of the newest event processed
        self._last_gyro: int | None = None  # ... and gyro event
        self._track = _Track()
        self._track.map_mark = (0,) * len(self.filt.maps)
        self._marks = tuple(m.mark for m in self.filt.maps)
        # snapshots after every gyro event, and one of the empty start (a frame captured before
        # the first gyro sample can still be applied at its time)
        self._snap_keys: list[int] = [KEY_BEFORE_ALL]
        self._snaps: list[_Track] = [self._track.copy()]
        self._seq = 0
        self._last_pub_t = -(1 << 62)
        self._last_arrival = -(1 << 62)
        self.stats: dict[str, float] = {"rewinds": 0, "max_rewind_ms": 0.0, "corrupt": 0, "late_gyro": 0}
        self.dropped: dict[str, int] = {}
        self.adapter = MessageAdapter(calibration, self.params, self.sensors, self.dropped)

    # ------------------------------------------------------------------ input
    def feed(self, topic: str, msg: Any, arrival_ns: int) -> None:
        """One bus or recording message as it arrived (arrival order); topics and samples the
        filter does not use are ignored, a corrupt message is counted."""
        try:
            m = self.adapter.measurement(topic, msg)
        except (AttributeError, TypeError, ValueError):
            self.stats["corrupt"] += 1
            return
        if m is not None:
            self.feed_measurement(m, arrival_ns)

    def feed_measurement(self, m: Measurement, arrival_ns: int) -> None:
        """One measurement as it arrived (arrival order)."""
        ev = self.event(m)
        arrival_ns = max(int(arrival_ns), self._last_arrival)
        self._last_arrival = arrival_ns
        key = ev[0]
        t = key >> T_SHIFT
        if arrival_ns - t > self.max_age_ns:
            self._drop(ev[1], "too_old")
            return
        self._pending.append((arrival_ns, ev))
        if ev[1] == "gyro":
            self._gyro_due.append((max(t + self.delay_ns, arrival_ns), t, key))
            if self.output == "both":
                self._settle_due.append((max(t + self.max_age_ns, arrival_ns), t, key))

    def _drop(self, kind: str, reason: str) -> None:
        name = f"{kind}:{reason}"
        self.dropped[name] = self.dropped.get(name, 0) + 1

    def event(self, m: Measurement) -> tuple:
        """(key, kind, value) with key = (t << T_SHIFT) + (kind order << K_SHIFT) + seq: the
        measurement's place in the filter's time order (arrival order breaks ties)."""
        self._seq += 1
        return ((int(m.t_ns) << T_SHIFT) + (KIND_ORDER[m.kind] << K_SHIFT) + self._seq, m.kind, m.value)

    # ------------------------------------------------------------------ output
    def advance(self, now_ns: int) -> list[StateSample]:
        """States at gyro times up to now_ns - output_delay, each exactly once (assumes every
        message that arrived by now_ns has been fed)."""
        out: list[StateSample] = []
        self._run_due(now_ns, out)
        return out

    def finish(self) -> list[StateSample]:
        """Offline: every state not yet published, once all inputs have arrived."""
        out: list[StateSample] = []
        self._run_due(None, out)
        return out

    def take_settled(self) -> list[StateSample]:
        """With output="both": the settled states that came due in `advance` or `finish` since
        the last call, in time order."""
        out, self._settled = self._settled, []
        return out

    @property
    def head(self) -> State | None:
        """The filter's state after the newest event processed: its covariance too, which the
        published samples summarise (None before the filter starts and while it restarts)."""
        return self._track.state

    def history(self) -> list[StateSample]:
        """The kept history (the last history_ms) as the filter now has it, every late
        measurement applied at its time: what the published states converge to once all
        inputs have arrived (none with output="settled", which needs no history)."""
        out: list[StateSample] = []
        for tr in self._snaps:
            self._append_sample(out, tr.state)
        return out

    def predict(self, now_ns: int) -> StateSample | None:
        """The newest state carried forward to now_ns at constant velocity and angular rate."""
        s = self._track.state
        if s is None:
            return None
        s = s.copy()
        self.filt.propagate(s, int(now_ns))
        return self._sample(s)

    def diagnostics(self) -> dict:
        tr = self._track
        s = tr.state
        counts, nis_sum = tr.carried.copy(), tr.carried_nis.copy()
        if s is not None:
            counts.update(s.counts)  # Counter.update adds
            nis_sum.update(s.nis)

        def kind(prefix: str) -> dict[str, int]:  # "updates:vision_tip" -> {"vision_tip": n}
            return {k.split(":", 1)[1]: int(v) for k, v in counts.items() if k.startswith(prefix + ":")}

        updates, rejected, deferred = kind("updates"), kind("rejected"), kind("deferred")
        rejected.update(self.dropped)
        nis = {k: v / max(updates.get(k, 0), 1) for k, v in nis_sum.items()}
        noise = s.noise if s is not None else tr.noise
        return {
            "updates": updates,
            "rejected": rejected,
            "deferred": deferred,
            "nis": nis,
            # each ADAPTIVE stream's variance factor now, the times it was set aside, those set aside now
            "noise_scale": {} if noise is None else {k: float(noise[i, 0]) for k, i in ADAPTIVE.items()},
            "set_aside": kind("set_aside"),
            "aside": [] if noise is None else [k for k, i in ADAPTIVE.items() if noise[i, 2] != 0.0],
            "rewinds": int(self.stats["rewinds"]),
            "max_rewind_ms": float(self.stats["max_rewind_ms"]),
            "lag_ms": self.delay_ns * 1e-6,
            "mode": mode_name(self.sensors),
            "resets": self._track.resets,
            "reset_reasons": dict(self._track.reset_reasons),
            "corrupt": int(self.stats["corrupt"]),
            "initialised": s is not None,
            "vision_locked": bool(s is not None and (s.t_ns - s.last_vision_ns) <= self.lock_ns),
            "held_up": {k: c.held for k, c in self.adapter.clocks.items() if c.held},
            "clock_restarts": {k: c.restarts for k, c in self.adapter.clocks.items() if c.restarts},
        }

    # ------------------------------------------------------------------ machinery
    def _neutral(self, tr: _Track | None = None) -> np.ndarray:
        n = (tr or self._track).neutral_u
        return n if n is not None else np.array([0.0, 0.0, -1.0])

    def _sample(self, state: State, tr: _Track | None = None) -> StateSample | None:
        """The published sample of `state` (neutral shaft of `tr`, default the live track), or
        None if any of it is not finite."""
        return finite_sample(state, self.calib.rcm_base_m, self._neutral(tr), self.lock_ns)

    def _append_sample(self, out: list[StateSample], state: State | None, tr: _Track | None = None) -> None:
        if state is not None and (sample := self._sample(state, tr)) is not None:
            out.append(sample)

    def _run_due(self, now_ns: int | None, out: list[StateSample]) -> None:
        """Both streams' states due by now_ns (None: all), in cutoff order (the display's first
        on a tie): each stream then sees exactly the inputs that had arrived by its cutoff."""
        gyro, settle = self._gyro_due, self._settle_due
        end = math.inf if now_ns is None else now_ns
        while gyro or settle:
            d = gyro[0][0] if gyro else math.inf
            e = settle[0][0] if settle else math.inf
            if min(d, e) > end:
                return
            if d <= e:
                self._publish_next(out)
            else:
                self._settle_next()

    def _take_arrived(self, cutoff: int) -> None:
        """Every input that arrived by `cutoff` into the filter's queue (a late one at its time)."""
        while self._pending and self._pending[0][0] <= cutoff:
            _, ev = self._pending.popleft()
            if self._last_done is not None and ev[0] < self._last_done:
                self._rewind_insert(ev)
            else:
                heapq.heappush(self._ready, ev)

    def _settle_next(self) -> None:
        # Gyro k was processed by the display stream (its cutoff is not later); late inputs
        # that arrived since are applied at their times before its snapshot is read.
        cutoff, t_k, key_k = self._settle_due.popleft()
        self._take_arrived(cutoff)
        if t_k <= self._last_settled_t:
            return
        i = bisect.bisect_left(self._snap_keys, key_k)
        if i == len(self._snap_keys) or self._snap_keys[i] != key_k:
            return  # gyro dropped (too old)
        self._last_settled_t = t_k
        tr = self._snaps[i]
        self._append_sample(self._settled, tr.state, tr)

    def _publish_next(self, out: list[StateSample]) -> None:
        cutoff, t_k, key_k = self._gyro_due.popleft()
        self._take_arrived(cutoff)
        while self._ready and self._ready[0][0] <= key_k:
            self._process(heapq.heappop(self._ready))
        if t_k <= self._last_pub_t:
            self.stats["late_gyro"] += 1
            return
        if self._last_gyro != key_k:
            return  # gyro dropped (too old)
        self._last_pub_t = t_k
        # the filter stands at gyro k (its snapshot, if kept, is a copy)
        self._append_sample(out, self._track.state)
        if self._keep_history:
            self._prune(t_k - self.history_ns)

    def _prune(self, t_min: int) -> None:
        if self._snap_keys[0] >> T_SHIFT >= t_min - self.history_ns // 4:
            return  # prune in batches: deleting from the list head is O(n)
        k = bisect.bisect_left(self._snap_keys, t_min << T_SHIFT)
        if k > 1:
            k -= 1  # keep one snapshot at or before t_min
            del self._snap_keys[:k]
            del self._snaps[:k]
            j = bisect.bisect_right(self._done_keys, self._snap_keys[0])
            del self._done_keys[:j]
            del self._done[:j]

    def _rewind_insert(self, ev: tuple) -> None:
        key = ev[0]
        i = bisect.bisect_right(self._snap_keys, key) - 1
        if i < 0 or not self._keep_history:  # settled: an input this late is too old (not reached)
            self._drop(ev[1], "older_than_history")
            return
        self.stats["rewinds"] += 1
        self.stats["max_rewind_ms"] = max(
            self.stats["max_rewind_ms"], ((self._last_done >> T_SHIFT) - (key >> T_SHIFT)) * 1e-6
        )
        snap_key = self._snap_keys[i]
        self._track = self._snaps[i].copy()
        for m, mark in zip(self.filt.maps, self._track.map_mark, strict=True):
            m.rewind(mark)
        del self._snap_keys[i + 1 :]
        del self._snaps[i + 1 :]
        j = bisect.bisect_right(self._done_keys, snap_key)
        replay = self._done[j:]
        del self._done_keys[j:]
        del self._done[j:]
        k = bisect.bisect_left([e[0] for e in replay], key)
        replay.insert(k, ev)
        for e in replay:
            self._process(e)

    def _process(self, ev: tuple) -> None:
        key, kind, payload = ev
        t = key >> T_SHIFT
        tr = self._track
        s = tr.state
        f = self.filt
        if kind == "gyro":
            if s is not None:
                why = f.on_gyro(s, t, payload)
                if why is not None:
                    for m in f.maps:  # what they learnt since the last vision tip came from a state going wrong
                        m.forget_after(s.last_tip_ns)
                    tr.carried, tr.carried_nis = Counter(tr.carried), Counter(tr.carried_nis)
                    tr.carried.update(s.counts)
                    tr.carried_nis.update(s.nis)
                    tr.noise = s.noise.copy()
                    tr.state = None
                    tr.reset_ns = t
                    tr.resets += 1
                    tr.reset_reasons = {**tr.reset_reasons, why: tr.reset_reasons.get(why, 0) + 1}
            elif tr.f_last is not None and self._start_without_vision(t):
                self._init_without_vision(t)
        elif kind == "accel":
            tr.f_last = payload
            if s is not None:
                f.on_accel(s, t, payload)
        elif kind == "tof":
            if s is not None:  # at the state's time: at most one gyro period earlier
                f.update_tof(s, payload)
            else:  # what a start from vision is checked against
                tr.tof_last = (t, payload)
        elif kind == "vision":
            if s is not None:
                f.propagate(s, t)
                f.update_vision(s, payload)
            elif not f.imu or tr.f_last is not None:
                # Not before the first accelerometer sample: without it the roll is unknown and
                # gravity would be removed along the wrong axis (live, vision can come first).
                f_imu = tr.f_last if f.imu else None
                refused = tr.start_refused
                tr.state, tr.start_refused = f.start_from_vision(t, payload, f_imu, tr.tof_last, refused)
                if tr.start_refused > refused:  # counted in the diagnostics (a new Counter: snapshots share it)
                    tr.carried = tr.carried + Counter({"rejected:start:tof_disagrees": 1})
                if tr.state is not None:
                    self._carry_noise(tr.state)
                    tr.reset_ns = None
                    if tr.neutral_u is None:
                        tr.neutral_u = tr.state.R[:, 2].copy()
        self._last_done = key
        if kind == "gyro":
            self._last_gyro = key
        if not self._keep_history:
            return
        self._done_keys.append(key)
        self._done.append(ev)
        if kind == "gyro":
            if self._marks:
                tr.map_mark = tuple([mark() for mark in self._marks])
            self._snap_keys.append(key)
            self._snaps.append(tr.copy())

    def _carry_noise(self, s: State) -> None:
        """A new state after a reset takes the discarded one's noise factors (not the time of
        each stream's last innovation: the first after the restart only restarts the clock)."""
        if self._track.noise is not None:
            s.noise = self._track.noise.copy()
            s.noise[:, 1] = np.nan

    def _start_without_vision(self, t: int) -> bool:
        """Whether a filter with no state starts from the IMU and ToF: always without vision;
        with vision, only after a reset that no vision frame could restart from for
        `restart_without_vision_ms`, so that depth and inclination are still published through a
        long loss of view (a returning frame that disagrees is re-acquired, or resets it onto
        vision)."""
        if not self.filt.vision:
            return True
        tr = self._track
        return self.restart_ns is not None and tr.reset_ns is not None and t - tr.reset_ns >= self.restart_ns

    def _init_without_vision(self, t: int) -> None:
        """Without vision nothing observes heading: start from the accelerometer's inclination
        with the azimuth of the ToF target plane's normal, at the working depth `start_depth_mm`."""
        tr = self._track
        c = self.calib
        u = shaft_from_tilt(tr.f_last, c.R_tool_imu, c.tof_plane_normal_base)
        R = initial_rotation(u, tr.f_last, c.R_tool_imu)
        s = self.filt.new_state(t, R, self.params.start_depth_mm * 1e-3, tr.f_last)
        s.P[0:3, 0:3] *= 100.0
        s.P[6:9, 6:9] *= 25.0
        if self.filt.vision:  # a restart after a reset while the view was lost: the diagnostics say so
            s.counts["updates:restart_without_vision"] = 1
        self._carry_noise(s)
        tr.state = s
        tr.reset_ns = None
        if tr.neutral_u is None:
            tr.neutral_u = u
