"""Bulk encoding of simulated streams into serialised protobuf messages (the hot path of
session generation: one reused message object per stream, fields set, serialised)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from services.bench.sensors.device import Stream
from services.bench.sensors.vision_model import VisionFrames
from tiplog import images
from tiplog.devproto import PROTOCOL_VERSION
from tiplog.geometry import rot_to_quat
from tiplog.v1 import device_pb2, robot_pb2, vision_pb2

RAW_IMAGE = RawImage.DESCRIPTOR.full_name
VISION = vision_pb2.VisionObservation.DESCRIPTOR.full_name


@dataclass
class Batch:
    """Serialised messages of one topic with their log times [ns]."""

    topic: str
    type_name: str
    log_ns: np.ndarray
    payloads: list[bytes]


def _vec_stream(s: Stream, cls, field: str, frame_id: str, topic: str) -> Batch:
    m = cls()
    m.header.frame_id = frame_id
    h = m.header
    v = getattr(m, field)
    out = []
    ser = m.SerializeToString
    for k, (a, d, x, y, z) in enumerate(
        zip(s.arrival_ns.tolist(), s.device_ns.tolist(), *s.values.T.tolist(), strict=True)
    ):
        h.stamp_ns = a
        h.device_stamp_ns = d
        h.seq = k
        v.x = x
        v.y = y
        v.z = z
        out.append(ser())
    return Batch(topic, cls.DESCRIPTOR.full_name, s.arrival_ns, out)


def gyro(s: Stream) -> Batch:
    return _vec_stream(s, device_pb2.Gyro, "rate_radps", "imu", "device/gyro")


def accel(s: Stream) -> Batch:
    return _vec_stream(s, device_pb2.Accel, "specific_force_mps2", "imu", "device/accel")


def mag(s: Stream) -> Batch:
    return _vec_stream(s, device_pb2.Mag, "field_ut", "imu", "device/mag")


def tof(s: Stream) -> Batch:
    m = device_pb2.Tof()
    m.header.frame_id = "tof"
    h = m.header
    out = []
    ser = m.SerializeToString
    cols = zip(
        s.arrival_ns.tolist(),
        s.device_ns.tolist(),
        s.values.tolist(),
        s.status.tolist(),
        s.extra["smoothed_mm"].tolist(),
        s.extra["smoothed_valid"].tolist(),
        strict=True,
    )
    for k, (a, d, r, st, sm, sv) in enumerate(cols):
        h.stamp_ns = a
        h.device_stamp_ns = d
        h.seq = k
        m.range_raw_mm = r
        m.status = st
        m.range_smoothed_mm = sm
        m.smoothed_valid = sv
        out.append(ser())
    return Batch("device/tof", device_pb2.Tof.DESCRIPTOR.full_name, s.arrival_ns, out)


def device_rates_hz(sc) -> dict[str, float]:
    """The rates the simulated module announces in its hello, as a real one does."""
    return {"gyro": sc.gyro.rate_hz, "accel": sc.accel.rate_hz, "tof": sc.tof.rate_hz, "mag": sc.mag.rate_hz}


def device_metadata(sc) -> dict[str, Any]:
    """The `device` metadata record the recorder writes from the module's hello, for an offline
    session: a reader learns the device's nominal rates as from a real recording."""
    return {
        "firmware": "tiplog-bench",
        "device_id": "BENCH",
        "port": "",
        "protocol_version": PROTOCOL_VERSION,
        "nominal_rates_hz": device_rates_hz(sc),
    }


def _set(v, xyz) -> None:
    v.x, v.y, v.z = xyz


def vision(f: VisionFrames) -> Batch:
    out = []
    for k in range(len(f)):
        m = vision_pb2.VisionObservation()
        m.header.stamp_ns = int(f.capture_ns[k])
        m.header.seq = k
        m.header.frame_id = "camera"
        m.accepted = bool(f.accepted[k])
        m.reject_reason = f.reject_reason[k]
        _set(m.n_left, f.n_left[k].tolist())
        _set(m.n_right, f.n_right[k].tolist())
        m.junction_u_px, m.junction_v_px = f.junction_px[k].tolist()
        m.junction_visible = bool(f.junction_visible[k])
        _set(m.junction_ray, f.junction_ray[k].tolist())
        _set(m.axis_point_m, f.axis_point_m[k].tolist())
        m.mask_iou = float(f.mask_iou[k])
        m.line_angle_deg = float(f.line_angle_deg[k])
        m.lateral_px = float(f.lateral_px[k])
        m.junction_diff_px = float(f.junction_diff_px[k])
        m.processed_stamp_ns = int(f.processed_ns[k])
        m.processing_ms = float(f.processing_ms[k])
        m.line_residual_px = float(f.line_residual_px[k])
        out.append(m.SerializeToString())
    return Batch("vision/observation", VISION, f.processed_ns, out)


def robot(gt, rate_hz: float, scenario: str) -> Batch:
    """Ground truth (evaluation only) decimated to rate_hz; stamps on the session clock."""
    t = np.asarray(gt.t_ns)
    step = max(1, int(round((1e9 / rate_hz) / max(float(np.median(np.diff(t))) if len(t) > 1 else 1e6, 1.0))))
    idx = np.arange(0, len(t), step)
    q = rot_to_quat(gt.R_base_tool[idx])
    r = np.asarray(gt.rcm_base_m, dtype=float)
    names = gt.meta.get("phase_names") or {0: "free", 1: "pre", 2: "move", 3: "post", 4: "hold"}
    names = {int(k): v for k, v in names.items()}
    u = gt.R_base_tool[idx, :, 2]
    d = gt.p_tip_base_m[idx] - r
    depth = np.einsum("ij,ij->i", d, u)
    rcm_err = np.linalg.norm(d - depth[:, None] * u, axis=1)
    m = robot_pb2.RobotState()
    m.header.frame_id = "base"
    m.scenario = scenario
    _set(m.rcm_m, r.tolist())
    out = []
    for k, i in enumerate(idx.tolist()):
        m.header.stamp_ns = int(t[i])
        m.header.seq = k
        m.q_rad[:] = gt.q_rad[i].tolist()
        m.dq_radps[:] = gt.dq_radps[i].tolist()
        _set(m.tool_pose.position_m, gt.p_tip_base_m[i].tolist())
        o = m.tool_pose.orientation
        o.x, o.y, o.z, o.w = q[k].tolist()
        _set(m.tip_m, gt.p_tip_base_m[i].tolist())
        m.depth_mm = float(depth[k] * 1e3)
        m.rcm_error_mm = float(rcm_err[k] * 1e3)
        m.trial = int(gt.trial[i])
        m.phase = names.get(int(gt.phase[i]), str(int(gt.phase[i])))
        out.append(m.SerializeToString())
    return Batch("bench/robot", robot_pb2.RobotState.DESCRIPTOR.full_name, t[idx], out)


def raw_image(img: np.ndarray, stamp_ns: int, frame_id: str) -> bytes:
    """A serialised foxglove RawImage (rgb8) of an (H, W, 3) uint8 frame."""
    return images.raw_image(img, stamp_ns, frame_id).SerializeToString()
