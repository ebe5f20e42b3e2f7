"""FusionState -> OpenIGTLink messages (pyigtl), pure: no socket, no bus.

Three TRANSFORM messages per state, in millimetres, in the reference (robot base) frame:
- `TipToReference`: the tip position, identity rotation (a point, for a fiducial or a needle tip);
- `ToolToReference`: the shaft frame at the tip (origin at the tip, z distal along the shaft,
  the estimate's R_base_tool);
- `TrocarToReference`: the registered remote centre of motion, identity rotation.

Header version 2 metadata carries what Slicer's node does not keep: `TransformStatus` (`OK` or
`INVALID`, PLUS's convention), the state's own host-clock stamp `StampNs` (int64 ns, exact; the
header's timestamp is a float of seconds), the tip's 1-sigma `TipSigmaMm` ("x y z", base axes)
and `VisionLocked` ("true"/"false"). When fusion is not tracking the transforms go out with
`TransformStatus: INVALID` and an identity matrix (never the last pose), beside a STRING message
`TiplogStatus` that says why.
"""

from __future__ import annotations

import numpy as np
import pyigtl

from tiplog.geometry import quat_to_rot
from tiplog.v1.fusion_pb2 import FusionState

TIP = "TipToReference"
TOOL = "ToolToReference"
TROCAR = "TrocarToReference"
STATUS = "TiplogStatus"
TRANSFORM_NAMES = (TIP, TOOL, TROCAR)
HEADER_VERSION = 2


def is_pose(state: FusionState) -> bool:
    """A finite tip and a unit quaternion (within 1e-3): a pose that may be sent as OK."""
    q = state.orientation
    v = np.array([state.tip_m.x, state.tip_m.y, state.tip_m.z, q.x, q.y, q.z, q.w])
    return bool(np.all(np.isfinite(v)) and abs(np.linalg.norm(v[3:]) - 1.0) < 1e-3)


def tool_matrices_mm(state: FusionState) -> dict[str, np.ndarray]:
    """4x4 T_reference_tip and T_reference_tool [mm] from one state (base frame = reference)."""
    p_mm = np.array([state.tip_m.x, state.tip_m.y, state.tip_m.z]) * 1e3
    q = state.orientation
    tip = np.eye(4)
    tip[:3, 3] = p_mm
    tool = np.eye(4)
    tool[:3, :3] = quat_to_rot(np.array([q.x, q.y, q.z, q.w]))
    tool[:3, 3] = p_mm
    return {TIP: tip, TOOL: tool}


def trocar_matrix_mm(rcm_base_m: np.ndarray) -> np.ndarray:
    """4x4 T_reference_trocar [mm]: the RCM, identity rotation."""
    m = np.eye(4)
    m[:3, 3] = np.asarray(rcm_base_m, float) * 1e3
    return m


def _transform(name: str, matrix: np.ndarray, timestamp_s: float, metadata: dict[str, str]) -> pyigtl.TransformMessage:
    msg = pyigtl.TransformMessage(matrix, timestamp=timestamp_s, device_name=name)
    msg.header_version = HEADER_VERSION
    msg.metadata = dict(metadata)
    return msg


def state_messages(
    state: FusionState, timestamp_s: float, rcm_base_m: np.ndarray | None
) -> list[pyigtl.TransformMessage]:
    """The valid TRANSFORMs for `state`; `timestamp_s` is the state's time on the wall clock
    (OpenIGTLink's header time), the exact host stamp travels as `StampNs`."""
    s = state.tip_sigma_mm
    meta = {
        "TransformStatus": "OK",
        "StampNs": str(int(state.header.stamp_ns)),
        "TipSigmaMm": f"{s.x:.6g} {s.y:.6g} {s.z:.6g}",
        "VisionLocked": "true" if state.vision_locked else "false",
    }
    out = [_transform(name, m, timestamp_s, meta) for name, m in tool_matrices_mm(state).items()]
    if rcm_base_m is not None:
        out.append(_transform(TROCAR, trocar_matrix_mm(rcm_base_m), timestamp_s, meta))
    return out


def invalid_messages(reason: str, timestamp_s: float, last_stamp_ns: int | None) -> list[pyigtl.MessageBase]:
    """Not tracking: every TRANSFORM as INVALID with an identity matrix, and the STRING status."""
    meta = {"TransformStatus": "INVALID", "StampNs": str(int(last_stamp_ns or 0)), "Reason": reason}
    out: list[pyigtl.MessageBase] = [_transform(n, np.eye(4), timestamp_s, meta) for n in TRANSFORM_NAMES]
    status = pyigtl.StringMessage(f"NOT_TRACKING: {reason}", timestamp=timestamp_s, device_name=STATUS)
    status.header_version = HEADER_VERSION
    status.metadata = {"TransformStatus": "INVALID"}
    out.append(status)
    return out


def tracking_message(timestamp_s: float) -> pyigtl.StringMessage:
    """The STRING status once fusion tracks (again)."""
    msg = pyigtl.StringMessage("TRACKING", timestamp=timestamp_s, device_name=STATUS)
    msg.header_version = HEADER_VERSION
    msg.metadata = {"TransformStatus": "OK"}
    return msg
