"""What the filter consumes, as typed values: no protobuf. `timing.measurements` builds these
from bus and recording messages; tests and the warm-up build them directly."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

KINDS = ("gyro", "accel", "tof", "vision")


class VisionObservation(NamedTuple):
    """One accepted camera frame, camera frame: the unit normals of the shaft's two tangent planes
    through the camera centre, and the unit ray to the junction (meaningful only when visible)."""

    n_left: np.ndarray  # (3,)
    n_right: np.ndarray  # (3,)
    junction_visible: bool
    ray: np.ndarray  # (3,)


class Measurement(NamedTuple):
    """One sensor sample at its measurement time t_ns (stamp minus the stream's calibrated
    latency): gyro rate (3,) [rad/s] and specific force (3,) [m/s^2] in the IMU frame, ToF range
    [m], or a `VisionObservation`."""

    kind: str  # one of KINDS
    t_ns: int
    value: np.ndarray | float | VisionObservation
