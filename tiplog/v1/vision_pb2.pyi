from tiplog.v1 import common_pb2 as _common_pb2
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class VisionObservation(_message.Message):
    __slots__ = ("header", "accepted", "reject_reason", "n_left", "n_right", "junction_u_px", "junction_v_px", "junction_visible", "junction_ray", "axis_point_m", "mask_iou", "line_angle_deg", "lateral_px", "junction_diff_px", "processed_stamp_ns", "processing_ms", "line_residual_px")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    ACCEPTED_FIELD_NUMBER: _ClassVar[int]
    REJECT_REASON_FIELD_NUMBER: _ClassVar[int]
    N_LEFT_FIELD_NUMBER: _ClassVar[int]
    N_RIGHT_FIELD_NUMBER: _ClassVar[int]
    JUNCTION_U_PX_FIELD_NUMBER: _ClassVar[int]
    JUNCTION_V_PX_FIELD_NUMBER: _ClassVar[int]
    JUNCTION_VISIBLE_FIELD_NUMBER: _ClassVar[int]
    JUNCTION_RAY_FIELD_NUMBER: _ClassVar[int]
    AXIS_POINT_M_FIELD_NUMBER: _ClassVar[int]
    MASK_IOU_FIELD_NUMBER: _ClassVar[int]
    LINE_ANGLE_DEG_FIELD_NUMBER: _ClassVar[int]
    LATERAL_PX_FIELD_NUMBER: _ClassVar[int]
    JUNCTION_DIFF_PX_FIELD_NUMBER: _ClassVar[int]
    PROCESSED_STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    PROCESSING_MS_FIELD_NUMBER: _ClassVar[int]
    LINE_RESIDUAL_PX_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    accepted: bool
    reject_reason: str
    n_left: _common_pb2.Vector3
    n_right: _common_pb2.Vector3
    junction_u_px: float
    junction_v_px: float
    junction_visible: bool
    junction_ray: _common_pb2.Vector3
    axis_point_m: _common_pb2.Vector3
    mask_iou: float
    line_angle_deg: float
    lateral_px: float
    junction_diff_px: float
    processed_stamp_ns: int
    processing_ms: float
    line_residual_px: float
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., accepted: _Optional[bool] = ..., reject_reason: _Optional[str] = ..., n_left: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., n_right: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., junction_u_px: _Optional[float] = ..., junction_v_px: _Optional[float] = ..., junction_visible: _Optional[bool] = ..., junction_ray: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., axis_point_m: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., mask_iou: _Optional[float] = ..., line_angle_deg: _Optional[float] = ..., lateral_px: _Optional[float] = ..., junction_diff_px: _Optional[float] = ..., processed_stamp_ns: _Optional[int] = ..., processing_ms: _Optional[float] = ..., line_residual_px: _Optional[float] = ...) -> None: ...
