from tiplog.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class TofStatus(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TOF_STATUS_UNSPECIFIED: _ClassVar[TofStatus]
    TOF_STATUS_VALID: _ClassVar[TofStatus]
    TOF_STATUS_SIGMA_FAIL: _ClassVar[TofStatus]
    TOF_STATUS_SIGNAL_FAIL: _ClassVar[TofStatus]
    TOF_STATUS_OUT_OF_RANGE: _ClassVar[TofStatus]
    TOF_STATUS_PHASE_FAIL: _ClassVar[TofStatus]
    TOF_STATUS_HARDWARE_FAIL: _ClassVar[TofStatus]

class DeviceState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DEVICE_STATE_UNSPECIFIED: _ClassVar[DeviceState]
    DEVICE_STATE_DISCONNECTED: _ClassVar[DeviceState]
    DEVICE_STATE_CONNECTING: _ClassVar[DeviceState]
    DEVICE_STATE_STREAMING: _ClassVar[DeviceState]
    DEVICE_STATE_STALLED: _ClassVar[DeviceState]
TOF_STATUS_UNSPECIFIED: TofStatus
TOF_STATUS_VALID: TofStatus
TOF_STATUS_SIGMA_FAIL: TofStatus
TOF_STATUS_SIGNAL_FAIL: TofStatus
TOF_STATUS_OUT_OF_RANGE: TofStatus
TOF_STATUS_PHASE_FAIL: TofStatus
TOF_STATUS_HARDWARE_FAIL: TofStatus
DEVICE_STATE_UNSPECIFIED: DeviceState
DEVICE_STATE_DISCONNECTED: DeviceState
DEVICE_STATE_CONNECTING: DeviceState
DEVICE_STATE_STREAMING: DeviceState
DEVICE_STATE_STALLED: DeviceState

class Gyro(_message.Message):
    __slots__ = ("header", "rate_radps")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    RATE_RADPS_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    rate_radps: _common_pb2.Vector3
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., rate_radps: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ...) -> None: ...

class Accel(_message.Message):
    __slots__ = ("header", "specific_force_mps2")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SPECIFIC_FORCE_MPS2_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    specific_force_mps2: _common_pb2.Vector3
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., specific_force_mps2: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ...) -> None: ...

class Tof(_message.Message):
    __slots__ = ("header", "range_raw_mm", "status", "range_smoothed_mm", "smoothed_valid")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    RANGE_RAW_MM_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    RANGE_SMOOTHED_MM_FIELD_NUMBER: _ClassVar[int]
    SMOOTHED_VALID_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    range_raw_mm: float
    status: TofStatus
    range_smoothed_mm: float
    smoothed_valid: bool
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., range_raw_mm: _Optional[float] = ..., status: _Optional[_Union[TofStatus, str]] = ..., range_smoothed_mm: _Optional[float] = ..., smoothed_valid: _Optional[bool] = ...) -> None: ...

class Mag(_message.Message):
    __slots__ = ("header", "field_ut")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    FIELD_UT_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    field_ut: _common_pb2.Vector3
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., field_ut: _Optional[_Union[_common_pb2.Vector3, _Mapping]] = ...) -> None: ...

class DeviceStatus(_message.Message):
    __slots__ = ("header", "state", "port", "firmware", "protocol_version", "device_id", "nominal_rates_hz", "measured_rates_hz", "faults", "frames_ok", "last_frame_stamp_ns", "message")
    class NominalRatesHzEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    class MeasuredRatesHzEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: float
        def __init__(self, key: _Optional[str] = ..., value: _Optional[float] = ...) -> None: ...
    class FaultsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    PORT_FIELD_NUMBER: _ClassVar[int]
    FIRMWARE_FIELD_NUMBER: _ClassVar[int]
    PROTOCOL_VERSION_FIELD_NUMBER: _ClassVar[int]
    DEVICE_ID_FIELD_NUMBER: _ClassVar[int]
    NOMINAL_RATES_HZ_FIELD_NUMBER: _ClassVar[int]
    MEASURED_RATES_HZ_FIELD_NUMBER: _ClassVar[int]
    FAULTS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_OK_FIELD_NUMBER: _ClassVar[int]
    LAST_FRAME_STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    state: DeviceState
    port: str
    firmware: str
    protocol_version: int
    device_id: str
    nominal_rates_hz: _containers.ScalarMap[str, float]
    measured_rates_hz: _containers.ScalarMap[str, float]
    faults: _containers.ScalarMap[str, int]
    frames_ok: int
    last_frame_stamp_ns: int
    message: str
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., state: _Optional[_Union[DeviceState, str]] = ..., port: _Optional[str] = ..., firmware: _Optional[str] = ..., protocol_version: _Optional[int] = ..., device_id: _Optional[str] = ..., nominal_rates_hz: _Optional[_Mapping[str, float]] = ..., measured_rates_hz: _Optional[_Mapping[str, float]] = ..., faults: _Optional[_Mapping[str, int]] = ..., frames_ok: _Optional[int] = ..., last_frame_stamp_ns: _Optional[int] = ..., message: _Optional[str] = ...) -> None: ...
