from tiplog.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class RobotState(_message.Message):
    __slots__ = ("header", "q_rad", "dq_radps", "tool_pose", "tip_m", "rcm_m", "depth_mm", "rcm_error_mm", "scenario", "trial", "phase")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    Q_RAD_FIELD_NUMBER: _ClassVar[int]
    DQ_RADPS_FIELD_NUMBER: _ClassVar[int]
    TOOL_POSE_FIELD_NUMBER: _ClassVar[int]
    TIP_M_FIELD_NUMBER: _ClassVar[int]
    RCM_M_FIELD_NUMBER: _ClassVar[int]
    DEPTH_MM_FIELD_NUMBER: _ClassVar[int]
    RCM_ERROR_MM_FIELD_NUMBER: _ClassVar[int]
    SCENARIO_FIELD_NUMBER: _ClassVar[int]
    TRIAL_FIELD_NUMBER: _ClassVar[int]
    PHASE_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    q_rad: _containers.RepeatedScalarFieldContainer[float]
    dq_radps: _containers.RepeatedScalarFieldContainer[float]
    tool_pose: _common_pb2.Pose
    tip_m: _common_pb2.Vector3
    rcm_m: _common_pb2.Vector3
    depth_mm: float
    rcm_error_mm: float
    scenario: str
    trial: int
    phase: str
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., q_rad: _Optional[_Iterable[float]] = ..., dq_radps: _Optional[_Iterable[float]] = ..., tool_pose: _Optional[_Union[_common_pb2.Pose, _Mapping]] = ..., tip_m: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., rcm_m: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., depth_mm: _Optional[float] = ..., rcm_error_mm: _Optional[float] = ..., scenario: _Optional[str] = ..., trial: _Optional[int] = ..., phase: _Optional[str] = ...) -> None: ...
