"""The topics of the system and the message type each one carries.

Keys on the bus are `<prefix><topic>`, prefix `tiplog/` by default. A topic not listed here
may still travel: every payload carries its full message name in the attachment (see
`tiplog.bus`), so the recorder can archive topics it has never heard of.
"""

from __future__ import annotations

from foxglove_schemas_protobuf import (
    CameraCalibration_pb2,
    CompressedImage_pb2,
    FrameTransforms_pb2,
    RawImage_pb2,
    SceneUpdate_pb2,
)
from google.protobuf import descriptor_pool, message_factory
from google.protobuf.message import Message

from tiplog.v1 import device_pb2, fusion_pb2, recorder_pb2, robot_pb2, system_pb2, vision_pb2

TOPICS: dict[str, type[Message]] = {
    "device/gyro": device_pb2.Gyro,
    "device/accel": device_pb2.Accel,
    "device/tof": device_pb2.Tof,
    "device/mag": device_pb2.Mag,
    "device/status": device_pb2.DeviceStatus,
    "camera/image": RawImage_pb2.RawImage,
    "camera/image/compressed": CompressedImage_pb2.CompressedImage,  # the recorder's archive (JPEG)
    "camera/info": CameraCalibration_pb2.CameraCalibration,
    "vision/observation": vision_pb2.VisionObservation,
    "vision/preview": CompressedImage_pb2.CompressedImage,
    # Frames the vision service processed, dropped as stale, and its latency (every status period).
    "vision/status": system_pb2.LoadStatus,
    "fusion/state": fusion_pb2.FusionState,
    "fusion/diagnostics": fusion_pb2.FusionDiagnostics,
    # The state once every late measurement has been applied at its time (max_age_ms behind):
    # what `tiplog fusion run` writes as fusion/state, for archives.
    "fusion/state_settled": fusion_pb2.FusionState,
    # Forward prediction of the newest state to the present, for display (not for archives).
    "fusion/predicted": fusion_pb2.FusionState,
    # The estimated tool pose (base -> tool_estimate) for Foxglove's 3D panel beside bench/tf.
    "fusion/tf": FrameTransforms_pb2.FrameTransforms,
    # The trocar and the tip's recent trail for Foxglove's 3D panel (base frame, 5 Hz).
    "fusion/scene": SceneUpdate_pb2.SceneUpdate,
    "bench/robot": robot_pb2.RobotState,
    "bench/tf": FrameTransforms_pb2.FrameTransforms,
    # The pixel tier's rendering: frames published and skipped late, and whether it keeps 15 fps.
    "bench/status": system_pb2.LoadStatus,
    "recorder/status": recorder_pb2.RecorderStatus,
    "system/supervisor": system_pb2.SupervisorStatus,
}

# Request/reply keys (queryables), not streams.
RECORDER_COMMAND = "recorder/command"
# Liveliness tokens: `<prefix>alive/<service>`.
ALIVE = "alive"


def message_type(topic: str) -> type[Message]:
    """Message class registered for `topic` (without prefix); KeyError names the topic."""
    try:
        return TOPICS[topic]
    except KeyError:
        raise KeyError(f"unknown topic {topic!r}; known: {', '.join(sorted(TOPICS))}") from None


def message_class_by_name(full_name: str) -> type[Message]:
    """Message class for a full protobuf name such as 'tiplog.v1.Gyro' (any imported schema)."""
    try:
        desc = descriptor_pool.Default().FindMessageTypeByName(full_name)
    except KeyError:
        raise KeyError(f"no protobuf schema named {full_name!r} is loaded") from None
    return message_factory.GetMessageClass(desc)
