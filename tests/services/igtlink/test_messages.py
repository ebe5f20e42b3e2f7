"""OpenIGTLink bytes of one state, parsed back by pyigtl's own unpacking (no socket)."""

from __future__ import annotations

import numpy as np
import pyigtl

from services.igtlink import messages
from tiplog.geometry import rot_to_quat, so3_exp
from tiplog.v1.fusion_pb2 import FusionState


def _parse(data: bytes) -> list[pyigtl.MessageBase]:
    out, pos = [], 0
    while pos < len(data):
        head = pyigtl.MessageBase.parse_header(data[pos : pos + pyigtl.MessageBase.IGTL_HEADER_SIZE])
        pos += pyigtl.MessageBase.IGTL_HEADER_SIZE
        msg = pyigtl.MessageBase.create_message(head["message_type"])
        msg.unpack(head, data[pos : pos + head["body_size"]])
        pos += head["body_size"]
        out.append(msg)
    return out


def _state() -> FusionState:
    s = FusionState()
    s.header.stamp_ns = 1_234_567_890_123
    s.tip_m.x, s.tip_m.y, s.tip_m.z = 0.7123456789, -0.0123456789, 0.1765432198
    R = so3_exp(np.array([0.3, -2.6, 0.1]))
    s.orientation.x, s.orientation.y, s.orientation.z, s.orientation.w = rot_to_quat(R).tolist()
    s.tip_sigma_mm.x, s.tip_sigma_mm.y, s.tip_sigma_mm.z = 1.25, 0.5, 3.0
    s.vision_locked = True
    return s


def test_state_as_transforms_in_mm_with_header_v2_metadata():
    s = _state()
    rcm = np.array([0.65, 0.0, 0.3])
    msgs = _parse(b"".join(m.pack() for m in messages.state_messages(s, 1.7e9, rcm)))
    by = {m.device_name: m for m in msgs}
    assert set(by) == {"TipToReference", "ToolToReference", "TrocarToReference"}
    tool = by["ToolToReference"]
    assert tool.header_version == 2 and tool.message_type == "TRANSFORM"
    assert tool.metadata == {"TransformStatus": "OK", "StampNs": "1234567890123", "TipSigmaMm": "1.25 0.5 3",
                             "VisionLocked": "true"}  # fmt: skip
    p_mm = np.float32(np.array([s.tip_m.x, s.tip_m.y, s.tip_m.z]) * 1e3)
    np.testing.assert_array_equal(np.float32(tool.matrix[:3, 3]), p_mm)
    R = so3_exp(np.array([0.3, -2.6, 0.1]))
    np.testing.assert_allclose(tool.matrix[:3, :3], R, atol=1e-7)
    np.testing.assert_array_equal(by["TipToReference"].matrix[:3, :3], np.eye(3))
    np.testing.assert_allclose(by["TrocarToReference"].matrix[:3, 3], rcm * 1e3, atol=1e-4)
    assert abs(tool.timestamp - 1.7e9) < 1e-3


def test_not_tracking_is_invalid_identity_and_a_status_string():
    msgs = _parse(b"".join(m.pack() for m in messages.invalid_messages("no fusion state yet", 1.7e9, None)))
    transforms = [m for m in msgs if m.message_type == "TRANSFORM"]
    assert len(transforms) == 3
    assert all(m.metadata["TransformStatus"] == "INVALID" and np.array_equal(m.matrix, np.eye(4)) for m in transforms)
    (status,) = [m for m in msgs if m.message_type == "STRING"]
    assert status.device_name == "TiplogStatus" and status.string == "NOT_TRACKING: no fusion state yet"


def test_a_state_that_is_no_pose_is_never_sent_as_one():
    s = _state()
    assert messages.is_pose(s)
    bad = FusionState()
    bad.CopyFrom(s)
    bad.orientation.Clear()  # an all-zero quaternion
    assert not messages.is_pose(bad)
    bad.CopyFrom(s)
    bad.tip_m.x = float("nan")
    assert not messages.is_pose(bad)
