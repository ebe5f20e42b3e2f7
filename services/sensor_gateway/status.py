"""The gateway's device status: state, hello contents, measured rates and fault counters,
published on device/status at a fixed period and at once on every state change.

Thread-safe: the serial reader and the camera runner update it, the service's main loop
publishes the periodic message. Camera counters share the faults map under a `camera_`
prefix and the camera's measured rate appears as `measured_rates_hz["camera"]`.
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable, Mapping

from tiplog.clock import NS_PER_S, now_ns
from tiplog.devproto.packets import FLAG_IMU_OK, FLAG_TOF_OK, HelloPacket
from tiplog.v1 import device_pb2

State = int  # a device_pb2.DeviceState value


class GatewayStatus:
    """Accumulates what device/status reports; `publish` is called with each message."""

    def __init__(self, port: str, publish: Callable[[device_pb2.DeviceStatus], None]) -> None:
        self._publish = publish
        self._lock = threading.Lock()
        self.port = port
        self.state: State = device_pb2.DEVICE_STATE_DISCONNECTED
        self.firmware = ""
        self.device_id = ""
        self.protocol_version = 0
        self.nominal_rates_hz: dict[str, float] = {}
        self.faults: Counter[str] = Counter()
        self.frames_ok = 0
        self.last_frame_stamp_ns = 0
        self.message = "starting"
        self._counts: Counter[str] = Counter()  # samples per stream since the last period
        self._period_start_ns = now_ns()
        self._measured: dict[str, float] = {}
        self.state_changes: list[tuple[int, State]] = []  # (stamp_ns, state), for tests/logs

    # updates from the reader / camera threads ---------------------------------
    def set_state(self, state: State, message: str = "", stamp_ns: int | None = None) -> None:
        """Change state; publishes at once (stamped with the transition time) if it changed."""
        stamp = stamp_ns or now_ns()
        with self._lock:
            if state == self.state and message == self.message:
                return
            changed = state != self.state
            self.state, self.message = state, message
            if changed:
                self.state_changes.append((stamp, state))
            msg = self._snapshot(stamp)
        self._publish(msg)

    def on_samples(self, stream_counts: Mapping[str, int], stamp_ns: int) -> None:
        """Valid device frames that arrived at `stamp_ns`, by stream."""
        with self._lock:
            for k, n in stream_counts.items():
                self._counts[k] += n
                self.frames_ok += n
            self.last_frame_stamp_ns = stamp_ns

    def on_camera_frame(self) -> None:
        """One camera frame published (counts toward measured_rates_hz["camera"] only)."""
        with self._lock:
            self._counts["camera"] += 1

    def on_hello(self, hello: HelloPacket, protocol_version: int) -> None:
        with self._lock:
            self.firmware = hello.firmware
            self.device_id = hello.device_id
            self.protocol_version = protocol_version
            self.nominal_rates_hz = {k: v for k, v in hello.rates_hz.items() if v > 0}
            self.faults["device_tx_dropped"] = hello.tx_dropped
            self.faults["device_imu_not_ok"] += 0 if hello.flags & FLAG_IMU_OK else 1
            self.faults["device_tof_not_ok"] += 0 if hello.flags & FLAG_TOF_OK else 1

    def set_faults(self, faults: Mapping[str, int], prefix: str = "") -> None:
        """Replace the counters under `prefix` with cumulative values from their owner."""
        with self._lock:
            for k, v in faults.items():
                self.faults[prefix + k] = v

    def add_fault(self, kind: str, n: int = 1) -> None:
        with self._lock:
            self.faults[kind] += n

    # periodic ------------------------------------------------------------------
    def publish_periodic(self) -> device_pb2.DeviceStatus:
        """Close the rate window, publish and return the status message."""
        now = now_ns()
        with self._lock:
            dt_s = max(now - self._period_start_ns, 1) / NS_PER_S
            self._measured = {k: n / dt_s for k, n in self._counts.items()}
            self._counts.clear()
            self._period_start_ns = now
            msg = self._snapshot(now)
        self._publish(msg)
        return msg

    def _snapshot(self, stamp_ns: int) -> device_pb2.DeviceStatus:
        m = device_pb2.DeviceStatus(
            state=self.state,
            port=self.port,
            firmware=self.firmware,
            protocol_version=self.protocol_version,
            device_id=self.device_id,
            frames_ok=self.frames_ok,
            last_frame_stamp_ns=self.last_frame_stamp_ns,
            message=self.message,
        )
        m.header.stamp_ns = stamp_ns
        m.header.frame_id = "device"
        m.nominal_rates_hz.update(self.nominal_rates_hz)
        m.measured_rates_hz.update(self._measured)
        m.faults.update({k: int(v) for k, v in self.faults.items()})
        return m
