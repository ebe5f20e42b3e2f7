"""The dashboard's side of the bus: every fusion state into a ring (none dropped), the robot
reference and vision observations into their own rings, the newest of everything else.

Callbacks run on Zenoh's threads: each converts one message into a row (microseconds) and
appends it, then calls the listeners (the web server's wake-up, which only schedules work on
its event loop). Nothing here waits on a client.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from services.dashboard.ring import Ring
from services.dashboard.streams import Envelope, Health, StreamStats
from tiplog.bus import Bus, SampleInfo, decode_attachment
from tiplog.calibration import Calibration
from tiplog.clock import now_ns
from tiplog.v1 import fusion_pb2, robot_pb2, vision_pb2

log = logging.getLogger("tiplog.dashboard")

# Columns of the rows the page receives (units in the names; positions in the base frame).
STATE_COLUMNS = (
    "x_mm",
    "y_mm",
    "z_mm",
    "depth_mm",
    "tilt_deg",
    "roll_deg",
    "tof_offset_mm",
    "vision_locked",
    "lag_ms",  # fusion's hold: publish time minus state time
    "arrival_lag_ms",  # state time to its arrival at the dashboard
    "err_mm",  # |estimate - reference| at the state's time (NaN without a reference)
    "err_radial_mm",  # along the reference shaft (signed)
    "err_tangential_mm",  # perpendicular to it
)
REF_COLUMNS = ("x_mm", "y_mm", "z_mm", "depth_mm")
VISION_COLUMNS = ("x_mm", "y_mm", "z_mm", "accepted", "latency_ms")

Listener = Callable[[], None]


def _v3(v: Any) -> np.ndarray:
    return np.array([v.x, v.y, v.z], dtype=float)


class BusFeed:
    """Subscribes on `bus` and keeps what the page shows. Close before the bus."""

    def __init__(
        self,
        bus: Bus,
        *,
        trail_samples: int = 24_000,
        reference_samples: int = 24_000,
        vision_samples: int = 2_000,
        stale_after_s: float = 2.0,
        calibration: Calibration | None = None,
    ):
        self.bus = bus
        self.t0_ns = now_ns()  # origin of the times the page receives
        self.calibration = calibration
        self.state = Ring(trail_samples, len(STATE_COLUMNS))
        self.reference = Ring(reference_samples, len(REF_COLUMNS))
        self.vision = Ring(vision_samples, len(VISION_COLUMNS))
        self.streams = StreamStats()
        self.health = Health(self.streams, stale_after_s)
        self.envelope = Envelope()
        self._listeners: list[Listener] = []
        self._lock = threading.Lock()
        self._robot_recent: deque[tuple[int, np.ndarray]] = deque(maxlen=400)  # (stamp, [tip, u])
        self.latest: dict[str, Any] = {}  # topic -> newest message
        self.latest_receive_ns: dict[str, int] = {}
        self.preview: tuple[int, str, bytes] | None = None  # (seq, format, data)
        self._preview_seq = 0
        self._preview_cv = threading.Condition()
        self._latest_cv = threading.Condition()
        self._subs: list[Any] = []
        # (state total, newest state as sent to pages), shared by the websocket senders.
        self.current_cache: tuple[int, dict[str, Any]] | None = None
        # JSON text shared by the websocket senders (services.dashboard.websocket.BatchCache).
        self.batch_cache: Any = None
        self.ws_clients = 0  # websocket clients being served (on the event loop's thread)
        self.ws_dropped = 0  # websocket clients dropped for not taking messages in time
        self._closed = False
        sub = bus.subscribe
        self._subs += [
            sub("fusion/state", self._on_state),
            sub("fusion/diagnostics", self._keep),
            sub("bench/robot", self._on_robot),
            sub("vision/observation", self._on_vision),
            sub("vision/preview", self._on_preview),
            sub("recorder/status", self._keep),
            sub("device/status", self._keep),
            sub("vision/status", self._keep),  # frames vision dropped as stale, its rate and latency
            sub("bench/status", self._keep),  # the pixel tier's rendering: whether it keeps 15 fps
            sub("device/tof", self._keep),  # the device's own smoothed range, shown as it is
            sub("system/supervisor", self._on_supervisor),  # `tiplog up`: run state and restarts
            sub("fusion/predicted", self._keep),  # the newest state carried to the present
        ]
        # Counting every topic needs only the attachment: no payload copy (camera frames).
        self._count_sub = bus.session.declare_subscriber(bus.key("**"), self._count)
        bus.watch_alive(self.health.on_token)

    # listeners ------------------------------------------------------------
    def add_listener(self, fn: Listener) -> None:
        """`fn()` is called on the bus thread after each new state or reference row."""
        with self._lock:
            self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        with self._lock:
            if fn in self._listeners:
                self._listeners.remove(fn)

    def _notify(self) -> None:
        with self._lock:
            listeners = list(self._listeners)
        for fn in listeners:
            fn()

    # callbacks (Zenoh threads) -----------------------------------------------
    def _count(self, sample: zenoh.Sample) -> None:
        att = sample.attachment
        seq, _pub_ns, pid, _name = decode_attachment(att.to_bytes() if att is not None else None)
        self.streams.on_sample(self.bus.topic_of(str(sample.key_expr)), seq, pid, now_ns())

    def _on_supervisor(self, msg: Any, info: SampleInfo) -> None:
        if not msg.replayed:  # a past status handed to a recorder again: not news
            self._keep(msg, info)

    def _keep(self, msg: Any, info: SampleInfo) -> None:
        with self._latest_cv:
            self.latest[info.topic] = msg
            self.latest_receive_ns[info.topic] = info.receive_ns
            self._latest_cv.notify_all()

    def wait_latest(self, topic: str, timeout_s: float) -> bool:
        """Block until a message of `topic` has been kept (for tests and tools)."""
        with self._latest_cv:
            return self._latest_cv.wait_for(lambda: topic in self.latest, timeout_s)

    def _on_state(self, msg: fusion_pb2.FusionState, info: SampleInfo) -> None:
        self._keep(msg, info)
        stamp = msg.header.stamp_ns
        tip_mm = _v3(msg.tip_m) * 1e3
        err = self._error_mm(stamp, tip_mm)
        row = [
            *tip_mm,
            msg.depth_mm,
            msg.tilt_deg,
            msg.roll_deg,
            msg.tof_offset_mm,
            1.0 if msg.vision_locked else 0.0,
            msg.lag_ms,
            (info.receive_ns - stamp) / 1e6,
            *err,
        ]
        self.state.append(stamp, row)
        self.envelope.add(msg.depth_mm, msg.tilt_deg)
        self._notify()

    def _on_robot(self, msg: robot_pb2.RobotState, info: SampleInfo) -> None:
        self._keep(msg, info)
        tip_mm = _v3(msg.tip_m) * 1e3
        axis = tip_mm - _v3(msg.rcm_m) * 1e3
        n = np.linalg.norm(axis)
        u = axis / n if n > 0 else np.full(3, np.nan)
        with self._lock:
            self._robot_recent.append((msg.header.stamp_ns, np.concatenate([tip_mm, u])))
        self.reference.append(msg.header.stamp_ns, [*tip_mm, msg.depth_mm])
        self._notify()

    def _on_vision(self, msg: vision_pb2.VisionObservation, info: SampleInfo) -> None:
        self._keep(msg, info)
        if msg.accepted:
            self.latest["vision/accepted"] = msg
            self.latest_receive_ns["vision/accepted"] = info.receive_ns
        p = self._vision_tip_base_mm(msg) if msg.accepted else None
        if p is None:
            p = np.full(3, np.nan)
        self.vision.append(
            msg.header.stamp_ns, [*p, 1.0 if msg.accepted else 0.0, (info.receive_ns - msg.header.stamp_ns) / 1e6]
        )

    def _on_preview(self, msg: Any, info: SampleInfo) -> None:
        fmt = msg.format.lower()
        if fmt in ("jpeg", "jpg", "png", "webp"):
            self._preview_seq += 1
            with self._preview_cv:
                self.preview = (self._preview_seq, "jpeg" if fmt == "jpg" else fmt, bytes(msg.data))
                self._preview_cv.notify_all()
        self.latest_receive_ns[info.topic] = info.receive_ns

    def wait_preview(self, timeout_s: float) -> bool:
        """Block until a preview image has been kept."""
        with self._preview_cv:
            return self._preview_cv.wait_for(lambda: self.preview is not None, timeout_s)

    # derived quantities ----------------------------------------------------
    def _error_mm(self, stamp_ns: int, tip_mm: np.ndarray) -> list[float]:
        """[|e|, radial, tangential] of the estimate against the reference interpolated at
        `stamp_ns` (radial: along the reference shaft direction); NaN without a bracket."""
        with self._lock:
            recent = list(self._robot_recent)[-64:]
        for k in range(len(recent) - 1, 0, -1):
            (t1, r1), (t0, r0) = recent[k], recent[k - 1]
            if t0 <= stamp_ns <= t1:
                w = (stamp_ns - t0) / (t1 - t0) if t1 > t0 else 0.0
                ref = r0 + w * (r1 - r0)
                break
        else:
            return [np.nan, np.nan, np.nan]
        e = tip_mm - ref[:3]
        u = ref[3:] / np.linalg.norm(ref[3:])
        radial = float(e @ u)
        tangential = float(np.linalg.norm(e - radial * u))
        return [float(np.linalg.norm(e)), radial, tangential]

    def error_rms_mm(self, window_s: float = 30.0) -> dict[str, float | int | None]:
        """RMS of the error against the reference (3-D, radial, tangential) over the states of
        the last `window_s` seconds that had a reference: a filter's start-up transient leaves
        the figure once it is older than the window."""
        newest = self.state.last()
        if newest is None:
            return {
                "samples": 0,
                "window_s": window_s,
                "rms_mm": None,
                "radial_rms_mm": None,
                "tangential_rms_mm": None,
            }
        n_rows = min(len(self.state), int(window_s * 1000) + 1)  # at most 1 kHz of states
        s = self.state.read(self.state.total - n_rows, n_rows)
        keep = s.stamps_ns >= newest[0] - int(window_s * 1e9)
        cols = [STATE_COLUMNS.index(c) for c in ("err_mm", "err_radial_mm", "err_tangential_mm")]
        err = s.rows[keep][:, cols]
        err = err[np.isfinite(err).all(axis=1)]
        rms = np.sqrt(np.mean(np.square(err), axis=0)) if len(err) else [None] * 3
        keys = ("rms_mm", "radial_rms_mm", "tangential_rms_mm")
        out: dict[str, float | int | None] = {"samples": len(err), "window_s": window_s}
        out.update({k: (round(float(v), 3) if v is not None else None) for k, v in zip(keys, rms, strict=True)})
        return out

    def _vision_tip_base_mm(self, msg: vision_pb2.VisionObservation) -> np.ndarray | None:
        """Tip from an accepted observation (junction on the axis + the junction-to-tip length),
        in the base frame through the calibration's hand-eye; None without a calibration."""
        cal = self.calibration
        if cal is None or not msg.junction_visible:
            return None
        from tiplog.geometry.vision import axis_direction_from_normals, ray_axis_intersection

        u_cam = axis_direction_from_normals(_v3(msg.n_left), _v3(msg.n_right))
        _s, junction_cam, cond = ray_axis_intersection(_v3(msg.junction_ray), _v3(msg.axis_point_m), u_cam)
        if not np.isfinite(junction_cam).all() or cond < 1e-6:
            return None
        tip_cam = junction_cam + cal.junction_proximal_m * u_cam
        return (cal.R_base_camera @ tip_cam + cal.p_base_camera_m) * 1e3

    # lifetime --------------------------------------------------------------
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._count_sub.undeclare()
        except Exception as e:  # the session may already be closing
            log.debug("undeclare failed: %s", e)
