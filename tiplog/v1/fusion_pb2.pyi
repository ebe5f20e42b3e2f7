from tiplog.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class FusionState(_message.Message):
    __slots__ = ("header", "tip_m", "tip_velocity_mps", "orientation", "shaft_direction", "depth_mm", "tilt_deg", "roll_deg", "gyro_bias_radps", "accel_bias_mps2", "tof_offset_mm", "tip_sigma_mm", "attitude_sigma_deg", "vision_locked", "last_vision_stamp_ns", "lag_ms", "depth_smoothed_mm")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    TIP_M_FIELD_NUMBER: _ClassVar[int]
    TIP_VELOCITY_MPS_FIELD_NUMBER: _ClassVar[int]
    ORIENTATION_FIELD_NUMBER: _ClassVar[int]
    SHAFT_DIRECTION_FIELD_NUMBER: _ClassVar[int]
    DEPTH_MM_FIELD_NUMBER: _ClassVar[int]
    TILT_DEG_FIELD_NUMBER: _ClassVar[int]
    ROLL_DEG_FIELD_NUMBER: _ClassVar[int]
    GYRO_BIAS_RADPS_FIELD_NUMBER: _ClassVar[int]
    ACCEL_BIAS_MPS2_FIELD_NUMBER: _ClassVar[int]
    TOF_OFFSET_MM_FIELD_NUMBER: _ClassVar[int]
    TIP_SIGMA_MM_FIELD_NUMBER: _ClassVar[int]
    ATTITUDE_SIGMA_DEG_FIELD_NUMBER: _ClassVar[int]
    VISION_LOCKED_FIELD_NUMBER: _ClassVar[int]
    LAST_VISION_STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    LAG_MS_FIELD_NUMBER: _ClassVar[int]
    DEPTH_SMOOTHED_MM_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    tip_m: _common_pb2.Vector3
    tip_velocity_mps: _common_pb2.Vector3
    orientation: _common_pb2.Quaternion
    shaft_direction: _common_pb2.Vector3
    depth_mm: float
    tilt_deg: float
    roll_deg: float
    gyro_bias_radps: _common_pb2.Vector3
    accel_bias_mps2: _common_pb2.Vector3
    tof_offset_mm: float
    tip_sigma_mm: _common_pb2.Vector3
    attitude_sigma_deg: float
    vision_locked: bool
    last_vision_stamp_ns: int
    lag_ms: float
    depth_smoothed_mm: float
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., tip_m: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., tip_velocity_mps: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., orientation: _Optional[_Union[_common_pb2.Quaternion, _Mapping]] = ..., shaft_direction: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., depth_mm: _Optional[float] = ..., tilt_deg: _Optional[float] = ..., roll_deg: _Optional[float] = ..., gyro_bias_radps: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., accel_bias_mps2: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., tof_offset_mm: _Optional[float] = ..., tip_sigma_mm: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ..., attitude_sigma_deg: _Optional[float] = ..., vision_locked: _Optional[bool] = ..., last_vision_stamp_ns: _Optional[int] = ..., lag_ms: _Optional[float] = ..., depth_smoothed_mm: _Optional[float] = ...) -> None: ...

class FusionDiagnostics(_message.Message):
    __slots__ = ("header", "updates", "rejected", "innovation_nis", "rewinds", "max_rewind_ms", "vision_latency_ms", "lag_ms", "mode", "vision_locked", "initialised", "resets", "reset_reasons", "inputs", "prediction_lag_ms", "queue_drops", "deferred", "noise_scale", "set_aside", "aside", "held_up", "clock_restarts")
    class UpdatesEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class RejectedEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class InnovationNisEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    class ResetReasonsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class DeferredEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class NoiseScaleEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    class SetAsideEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class HeldUpEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    class ClockRestartsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    UPDATES_FIELD_NUMBER: _ClassVar[int]
    REJECTED_FIELD_NUMBER: _ClassVar[int]
    INNOVATION_NIS_FIELD_NUMBER: _ClassVar[int]
    REWINDS_FIELD_NUMBER: _ClassVar[int]
    MAX_REWIND_MS_FIELD_NUMBER: _ClassVar[int]
    VISION_LATENCY_MS_FIELD_NUMBER: _ClassVar[int]
    LAG_MS_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    VISION_LOCKED_FIELD_NUMBER: _ClassVar[int]
    INITIALISED_FIELD_NUMBER: _ClassVar[int]
    RESETS_FIELD_NUMBER: _ClassVar[int]
    RESET_REASONS_FIELD_NUMBER: _ClassVar[int]
    INPUTS_FIELD_NUMBER: _ClassVar[int]
    PREDICTION_LAG_MS_FIELD_NUMBER: _ClassVar[int]
    QUEUE_DROPS_FIELD_NUMBER: _ClassVar[int]
    DEFERRED_FIELD_NUMBER: _ClassVar[int]
    NOISE_SCALE_FIELD_NUMBER: _ClassVar[int]
    SET_ASIDE_FIELD_NUMBER: _ClassVar[int]
    ASIDE_FIELD_NUMBER: _ClassVar[int]
    HELD_UP_FIELD_NUMBER: _ClassVar[int]
    CLOCK_RESTARTS_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    updates: _containers.ScalarMap[str, int]
    rejected: _containers.ScalarMap[str, int]
    innovation_nis: _containers.ScalarMap[str, float]
    rewinds: int
    max_rewind_ms: float
    vision_latency_ms: float
    lag_ms: float
    mode: str
    vision_locked: bool
    initialised: bool
    resets: int
    reset_reasons: _containers.ScalarMap[str, int]
    inputs: int
    prediction_lag_ms: float
    queue_drops: int
    deferred: _containers.ScalarMap[str, int]
    noise_scale: _containers.ScalarMap[str, float]
    set_aside: _containers.ScalarMap[str, int]
    aside: _containers.RepeatedScalarFieldContainer[str]
    held_up: _containers.ScalarMap[str, int]
    clock_restarts: _containers.ScalarMap[str, int]
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., updates: _Optional[_Mapping[str, int]] = ..., rejected: _Optional[_Mapping[str, int]] = ..., innovation_nis: _Optional[_Mapping[str, float]] = ..., rewinds: _Optional[int] = ..., max_rewind_ms: _Optional[float] = ..., vision_latency_ms: _Optional[float] = ..., lag_ms: _Optional[float] = ..., mode: _Optional[str] = ..., vision_locked: _Optional[bool] = ..., initialised: _Optional[bool] = ..., resets: _Optional[int] = ..., reset_reasons: _Optional[_Mapping[str, int]] = ..., inputs: _Optional[int] = ..., prediction_lag_ms: _Optional[float] = ..., queue_drops: _Optional[int] = ..., deferred: _Optional[_Mapping[str, int]] = ..., noise_scale: _Optional[_Mapping[str, float]] = ..., set_aside: _Optional[_Mapping[str, int]] = ..., aside: _Optional[_Iterable[str]] = ..., held_up: _Optional[_Mapping[str, int]] = ..., clock_restarts: _Optional[_Mapping[str, int]] = ...) -> None: ...
