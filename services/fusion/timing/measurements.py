"""The one adapter from bus and recording messages (protobuf, by topic) to the filter's
`Measurement`s: the device's samples timed by its own clock (`device_clock.py`), each stream's
calibrated latency taken off, the sensors not in use, invalid ToF ranges and frames the vision
service did not accept left out (and counted)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from services.fusion.eskf.measurement import Measurement, VisionObservation
from services.fusion.eskf.params import Params
from services.fusion.timing.device_clock import DeviceClock
from tiplog.calibration import Calibration

TOF_VALID = 1


def _v3(v: Any) -> np.ndarray:
    """A message's vector (3,); ValueError when any component is not finite (a corrupt message)."""
    x, y, z = float(v.x), float(v.y), float(v.z)
    if not math.isfinite(x + y + z):
        raise ValueError("non-finite value")
    return np.array((x, y, z))


class MessageAdapter:
    """Messages -> measurements for one calibration, parameter set and sensor subset. What it
    leaves out on purpose is counted in `dropped` ("tof:invalid", "vision:not_accepted")."""

    def __init__(self, calibration: Calibration, params: Params, sensors: frozenset[str], dropped: dict[str, int]):
        self.sensors = sensors
        self.params = params
        self.lat = {k: calibration.latency_ns(k) for k in ("gyro", "accel", "tof", "camera")}
        self.dropped = dropped
        self.clocks = {k: DeviceClock() for k in ("gyro", "accel", "tof")}

    def _t(self, stream: str, header: Any) -> int:
        """The sample's time on the host clock, its stream's latency taken off."""
        return self.clocks[stream].host_ns(int(header.stamp_ns), int(header.device_stamp_ns)) - self.lat[stream]

    def measurement(self, topic: str, msg: Any) -> Measurement | None:
        """The message's measurement, or None for a topic or sample the filter does not use;
        AttributeError, TypeError or ValueError for a corrupt message."""
        if topic == "device/gyro":
            w = _v3(msg.rate_radps)
            return Measurement("gyro", self._t("gyro", msg.header), w)
        if topic == "device/accel":
            if "imu" not in self.sensors:
                return None
            f = _v3(msg.specific_force_mps2)
            return Measurement("accel", self._t("accel", msg.header), f)
        if topic == "device/tof":
            if "tof" not in self.sensors:
                return None
            rng = float(msg.range_raw_mm)
            if msg.status != TOF_VALID or not (self.params.tof_min_mm <= rng <= self.params.tof_max_mm):
                self.dropped["tof:invalid"] = self.dropped.get("tof:invalid", 0) + 1
                return None
            return Measurement("tof", self._t("tof", msg.header), rng * 1e-3)
        if topic == "vision/observation":
            if "vision" not in self.sensors:
                return None
            if not msg.accepted:
                self.dropped["vision:not_accepted"] = self.dropped.get("vision:not_accepted", 0) + 1
                return None
            obs = VisionObservation(
                _v3(msg.n_left), _v3(msg.n_right), bool(msg.junction_visible), _v3(msg.junction_ray)
            )
            return Measurement("vision", msg.header.stamp_ns - self.lat["camera"], obs)
        return None
