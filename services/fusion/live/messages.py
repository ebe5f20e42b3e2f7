"""StateSample -> tiplog.v1.FusionState (the `fusion/state` message)."""

from __future__ import annotations

from services.fusion.eskf.sample import StateSample
from tiplog.v1.fusion_pb2 import FusionState


def _set3(v, xyz) -> None:
    v.x, v.y, v.z = float(xyz[0]), float(xyz[1]), float(xyz[2])


def to_fusion_state(s: StateSample, lag_ms: float = 0.0, seq: int = 0) -> FusionState:
    """One published state; header.stamp_ns is the time the state describes, frame_id "base"."""
    m = FusionState()
    m.header.stamp_ns = int(s.stamp_ns)
    m.header.seq = int(seq)
    m.header.frame_id = "base"
    _set3(m.tip_m, s.p_tip_base_m)
    _set3(m.tip_velocity_mps, s.v_tip_base_mps)
    w, x, y, z = (float(c) for c in s.q_base_tool)
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = x, y, z, w
    _set3(m.shaft_direction, s.u_base)
    m.depth_mm = s.depth_m * 1e3
    m.tilt_deg = s.tilt_deg
    m.roll_deg = s.roll_deg
    _set3(m.gyro_bias_radps, s.gyro_bias_radps)
    _set3(m.accel_bias_mps2, s.accel_bias_mps2)
    m.tof_offset_mm = s.tof_offset_m * 1e3
    _set3(m.tip_sigma_mm, s.tip_sigma_m * 1e3)
    m.attitude_sigma_deg = s.attitude_sigma_deg
    m.vision_locked = bool(s.vision_locked)
    m.last_vision_stamp_ns = int(s.last_vision_stamp_ns)
    m.lag_ms = float(lag_ms)
    return m
