"""The fusion service's outputs besides `fusion/state`: the runner's diagnostics as
`tiplog.v1.FusionDiagnostics`, and the estimated tool pose as Foxglove `FrameTransforms`
(parent "base", child "tool_estimate"), so a recording shows the estimate beside the bench's
truth (bench/tf: base -> tool) in Foxglove's 3D panel. `tiplog fusion run --out` may use both.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms

from services.fusion.eskf.sample import StateSample
from tiplog.v1.fusion_pb2 import FusionDiagnostics

PARENT_FRAME = "base"
CHILD_FRAME = "tool_estimate"


def _u64(v: Any) -> int:
    return max(int(v), 0)


def to_diagnostics(
    diag: Mapping[str, Any],
    stamp_ns: int,
    *,
    seq: int = 0,
    extra_rejected: Mapping[str, int] | None = None,
    vision_latency_ms: float = 0.0,
    lag_ms: float | None = None,
    prediction_lag_ms: float = 0.0,
    inputs: int = 0,
    queue_drops: int = 0,
) -> FusionDiagnostics:
    """FusionRunner.diagnostics() (updates, rejected, deferred, nis, rewinds, max_rewind_ms, lag_ms,
    mode, resets, reset_reasons, vision_locked, initialised) -> FusionDiagnostics.
    `extra_rejected` adds counts the service sees before the runner (undecodable payloads)."""
    m = FusionDiagnostics()
    m.header.stamp_ns = int(stamp_ns)
    m.header.seq = int(seq)
    m.header.frame_id = "base"
    for k, v in (diag.get("updates") or {}).items():
        m.updates[str(k)] = _u64(v)
    rejected = dict(diag.get("rejected") or {})
    if diag.get("corrupt"):
        rejected["input:corrupt"] = rejected.get("input:corrupt", 0) + int(diag["corrupt"])
    for k, v in (extra_rejected or {}).items():
        if v:
            rejected[k] = rejected.get(k, 0) + int(v)
    for k, v in rejected.items():
        m.rejected[str(k)] = _u64(v)
    for k, v in (diag.get("deferred") or {}).items():
        m.deferred[str(k)] = _u64(v)
    for k, v in (diag.get("nis") or {}).items():
        m.innovation_nis[str(k)] = float(v)
    m.rewinds = _u64(diag.get("rewinds", 0))
    m.max_rewind_ms = float(diag.get("max_rewind_ms", 0.0))
    m.vision_latency_ms = float(vision_latency_ms)
    m.lag_ms = float(diag.get("lag_ms", 0.0) if lag_ms is None else lag_ms)
    m.mode = str(diag.get("mode", ""))
    m.vision_locked = bool(diag.get("vision_locked", False))
    m.initialised = bool(diag.get("initialised", False))
    m.resets = _u64(diag.get("resets", 0))
    for k, v in (diag.get("reset_reasons") or {}).items():
        m.reset_reasons[str(k)] = _u64(v)
    m.inputs = _u64(inputs)
    m.prediction_lag_ms = float(prediction_lag_ms)
    m.queue_drops = _u64(queue_drops)
    for k, v in (diag.get("noise_scale") or {}).items():
        m.noise_scale[str(k)] = float(v)
    for k, v in (diag.get("set_aside") or {}).items():
        m.set_aside[str(k)] = _u64(v)
    m.aside.extend(str(k) for k in diag.get("aside") or ())
    for k, v in (diag.get("held_up") or {}).items():
        m.held_up[str(k)] = _u64(v)
    for k, v in (diag.get("clock_restarts") or {}).items():
        m.clock_restarts[str(k)] = _u64(v)
    return m


def to_frame_transforms(s: StateSample, child_frame: str = CHILD_FRAME) -> FrameTransforms:
    """The estimated tool pose at s.stamp_ns: translation = tip [m], rotation = R_base_tool."""
    msg = FrameTransforms()
    tf = msg.transforms.add()
    tf.timestamp.FromNanoseconds(int(s.stamp_ns))
    tf.parent_frame_id, tf.child_frame_id = PARENT_FRAME, child_frame
    tf.translation.x, tf.translation.y, tf.translation.z = (float(c) for c in s.p_tip_base_m)
    w, x, y, z = (float(c) for c in s.q_base_tool)
    tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = x, y, z, w
    return msg
