"""The live fusion loop: bus callbacks only stamp and enqueue; one worker thread feeds the
`FusionRunner`, advances it to the present and publishes what it returns: fusion/state
(`output_delay_ms` behind, for display) and fusion/state_settled (`max_age_ms` behind, every late
frame applied at its time: what `tiplog fusion run` writes, for archives). Before it subscribes
it warms the compiled kernels (`services.fusion.live.warmup`), so the first samples do not queue
behind their loading.

Clocks. Every input's header stamp is on the gateway's host clock; the runner wants arrival
times on that same clock. Live on one host the two agree; a replayed recording carries its
own clock. The loop therefore maps its own arrival stamps onto the stamps' clock with
`offset = min over device samples of (arrival - header stamp)` (the smallest transport delay
seen: about zero live, the replay's start for a replay) and hands the runner
`arrival - offset`. The runner's output depends only on those inputs, so writing them to
`input_log_file` lets `tiplog fusion run` (or a test) reproduce the live trajectory bit for
bit.
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from services.fusion.eskf.params import Params
from services.fusion.live.messages import to_fusion_state
from services.fusion.live.publish import to_diagnostics, to_frame_transforms
from services.fusion.live.scene import SCENE_PERIOD_NS, SceneTrail
from services.fusion.live.warmup import cold_start_line, warm_up
from services.fusion.timing.runner import FusionRunner
from tiplog.bus import Bus, SampleInfo
from tiplog.calibration import Calibration
from tiplog.clock import now_ns
from tiplog.mcap_io import McapWriter

log = logging.getLogger("tiplog.fusion")

INPUTS = ("device/gyro", "device/accel", "device/tof", "vision/observation", "camera/info")
_CLOCK_TOPICS = ("device/gyro", "device/accel", "device/tof")


class LiveFusion:
    """One runner on the bus. `start(stop)` runs the worker until `stop` is set."""

    def __init__(
        self,
        bus: Bus,
        calibration: Calibration,
        params: Params,
        sensors: frozenset[str],
        *,
        diagnostics_hz: float = 2.0,
        prediction_hz: float = 30.0,
        tf_every: int = 1,
        queue_size: int = 100_000,
        input_log_file: str | None = None,
        poll_s: float = 0.005,
        clock: Callable[[], int] = now_ns,
        warm: bool = True,
    ):
        if warm:
            warm_kernels(calibration, params, sensors)
        self.runner = FusionRunner(calibration, params, sensors, output="both")
        self._clock = clock
        self._poll_s = poll_s
        self._queue: deque[tuple[str, Any, int]] = deque()
        self._queue_size = queue_size
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self.queue_drops = 0
        self.inputs = 0
        self.feed_errors = 0
        self.published = 0
        self.settled = 0
        self._offset: int | None = None
        self._held: list[tuple[str, Any, int]] = []  # inputs before the first device sample
        self._vision_latency_ms = 0.0
        self._state_lag_ms = params.output_delay_ms
        self._prediction_lag_ms = 0.0
        self._diag_period_ns = int(1e9 / diagnostics_hz)
        self._pred_period_ns = int(1e9 / prediction_hz) if prediction_hz > 0 else 0
        self._tf_every = max(int(tf_every), 1)
        self._state_pub = bus.publisher("fusion/state")
        self._settled_pub = bus.publisher("fusion/state_settled")
        self._pred_pub = bus.publisher("fusion/predicted", reliable=False)
        self._tf_pub = bus.publisher("fusion/tf")
        self._diag_pub = bus.publisher("fusion/diagnostics")
        self._scene_pub = bus.publisher("fusion/scene", reliable=False)
        self._trail = SceneTrail(calibration.rcm_base_m)
        self._log: McapWriter | None = None
        if input_log_file:
            self._log = McapWriter(input_log_file)
            self._log.add_metadata("calibration", {"json": _json(calibration.to_dict())})
            self._log.add_metadata("fusion_params", {"json": _json(params.to_dict())})
        self._subs = {t: bus.subscribe(t, self._enqueue_for(t)) for t in INPUTS}

    # ------------------------------------------------------------------ bus threads
    def _enqueue_for(self, topic: str) -> Callable[[Any, SampleInfo], None]:
        def enqueue(msg: Any, _info: SampleInfo) -> None:
            # Stamped under the lock the worker reads the clock under: everything stamped
            # before the worker's `now` is in the queue when it drains it.
            with self._lock:
                if len(self._queue) >= self._queue_size:
                    self.queue_drops += 1
                    return
                self._queue.append((topic, msg, self._clock()))
            self._wake.set()

        return enqueue

    # ------------------------------------------------------------------ worker
    def start(self, stop: threading.Event) -> None:
        """Run the worker on this thread until `stop` is set; then close the input log."""
        next_diag = self._clock()
        next_pred = next_diag
        next_scene = next_diag
        try:
            while not stop.is_set():
                self._wake.wait(self._poll_s)
                self._wake.clear()
                now = self.step()
                if self._pred_period_ns and now >= next_pred:
                    next_pred = now + self._pred_period_ns
                    self._publish_prediction(now)
                if now >= next_scene and len(self._trail):
                    next_scene = now + SCENE_PERIOD_NS
                    self._scene_pub.put(self._trail.message(now - (self._offset or 0)))
                if now >= next_diag:
                    next_diag = now + self._diag_period_ns
                    self._diag_pub.put(self.diagnostics_message(now))
            self.flush()
        finally:
            if self._log is not None:
                self._log.close()

    def flush(self) -> None:
        """At stop: whatever is queued fed, then every state not yet published, as `tiplog
        fusion run` ends its file. No input comes after the stop, so the display stream's last
        `output_delay_ms` and the settled stream's last `max_age_ms` are final now; without
        this a recording's settled stream would end a second before its inputs."""
        now = self.step()
        if self._offset is None:
            return
        self._publish_due(self.runner.finish, now - self._offset)
        self._diag_pub.put(self.diagnostics_message(now))

    def step(self) -> int:
        """Feed everything queued, publish every state due; returns the host time used."""
        with self._lock:
            now = self._clock()
            items = list(self._queue)
            self._queue.clear()
        for topic, msg, arrival in items:
            self._feed(topic, msg, arrival)
        if self._offset is not None:
            t_now = now - self._offset
            self._publish_due(lambda: self.runner.advance(t_now), t_now)
        return now

    def _publish_due(self, run: Callable[[], list], t_now: int) -> None:
        """Both streams' states that `run` (the runner's advance or finish) makes due."""
        try:
            samples = run()
        except Exception:  # the filter's bug must not stop the service; it is logged
            self.feed_errors += 1
            log.exception("the fusion runner failed")
            samples = []
        for s in samples:
            self._publish_state(s, t_now)
        for s in self.runner.take_settled():
            self._publish_settled(s, t_now)

    def _feed(self, topic: str, msg: Any, arrival: int) -> None:
        if topic in _CLOCK_TOPICS:
            d = arrival - int(msg.header.stamp_ns)
            if self._offset is None or d < self._offset:
                self._offset = d
        if self._offset is None:
            self._held.append((topic, msg, arrival))
            return
        if self._held:
            held, self._held = self._held, []
            for h in held:
                self._feed_now(*h)
        self._feed_now(topic, msg, arrival)

    def _feed_now(self, topic: str, msg: Any, arrival: int) -> None:
        a = arrival - self._offset
        if topic == "vision/observation":
            lat = (a - int(msg.header.stamp_ns)) * 1e-6
            self._vision_latency_ms = (
                lat if self._vision_latency_ms == 0.0 else 0.9 * self._vision_latency_ms + 0.1 * lat
            )
        try:
            self.runner.feed(topic, msg, a)
        except Exception:
            self.feed_errors += 1
            if self.feed_errors <= 10:
                log.exception("runner.feed failed on %s", topic)
            return
        self.inputs += 1
        if self._log is not None:
            self._log.write(topic, msg, a)

    def _publish_state(self, s: Any, t_now: int) -> None:
        if not _finite(s):
            return  # never publish NaN (the runner should not return one)
        lag_ms = (t_now - s.stamp_ns) * 1e-6
        self._state_lag_ms = lag_ms
        self._state_pub.put(to_fusion_state(s, lag_ms=lag_ms, seq=self.published))
        if self.published % self._tf_every == 0:
            self._tf_pub.put(to_frame_transforms(s))
        self._trail.add(s.stamp_ns, s.p_tip_base_m)
        self.published += 1

    def _publish_settled(self, s: Any, t_now: int) -> None:
        if not _finite(s):
            return
        self._settled_pub.put(to_fusion_state(s, lag_ms=(t_now - s.stamp_ns) * 1e-6, seq=self.settled))
        self.settled += 1

    def _publish_prediction(self, now: int) -> None:
        if self._offset is None:
            return
        try:
            s = self.runner.predict(now - self._offset)
        except Exception:
            log.exception("runner.predict failed")
            return
        if s is None or not np.all(np.isfinite(s.p_tip_base_m)):
            return
        self._prediction_lag_ms = (self._clock() - now) * 1e-6
        self._pred_pub.put(to_fusion_state(s, lag_ms=self._prediction_lag_ms))

    def diagnostics_message(self, now: int):
        """FusionDiagnostics now: the runner's counts plus what the service saw before it."""
        extra = {f"{t}:undecodable": sub.decode_errors for t, sub in self._subs.items()}
        extra["input:feed_error"] = self.feed_errors
        t = now - self._offset if self._offset is not None else now
        return to_diagnostics(
            self.runner.diagnostics(),
            t,
            extra_rejected=extra,
            vision_latency_ms=self._vision_latency_ms,
            lag_ms=self._state_lag_ms,
            prediction_lag_ms=self._prediction_lag_ms,
            inputs=self.inputs,
            queue_drops=self.queue_drops,
        )


def warm_kernels(calibration: Calibration, params: Params, sensors: frozenset[str]) -> None:
    """The compiled kernels loaded before the first subscription (`services.fusion.live.warmup`);
    a calibration it cannot build a session from costs only the first samples' delay. With no
    compiled cache (a fresh install) that takes a minute: one warning line says so first."""
    cold = cold_start_line()
    if cold:
        log.warning("%s", cold)
    try:
        diag = warm_up(calibration, params, sensors)
    except Exception as e:  # never a reason not to start
        log.warning("filter warm-up skipped (%s): the first samples will wait for the compiled kernels", e)
        return
    log.info("filter kernels %s in %.1f s", "compiled" if cold else "ready", diag["warm_up_s"])


def _finite(s: Any) -> bool:
    return bool(np.all(np.isfinite(s.p_tip_base_m)) and np.all(np.isfinite(s.q_base_tool)))


def _json(d: dict) -> str:
    import json

    return json.dumps(d, default=lambda v: None if isinstance(v, float) and not math.isfinite(v) else str(v))
