from tiplog.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class ServiceRunState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SERVICE_RUN_STATE_UNSPECIFIED: _ClassVar[ServiceRunState]
    SERVICE_RUN_STATE_WAITING: _ClassVar[ServiceRunState]
    SERVICE_RUN_STATE_RUNNING: _ClassVar[ServiceRunState]
    SERVICE_RUN_STATE_RESTARTING: _ClassVar[ServiceRunState]
    SERVICE_RUN_STATE_STOPPED: _ClassVar[ServiceRunState]
    SERVICE_RUN_STATE_FAILED: _ClassVar[ServiceRunState]
SERVICE_RUN_STATE_UNSPECIFIED: ServiceRunState
SERVICE_RUN_STATE_WAITING: ServiceRunState
SERVICE_RUN_STATE_RUNNING: ServiceRunState
SERVICE_RUN_STATE_RESTARTING: ServiceRunState
SERVICE_RUN_STATE_STOPPED: ServiceRunState
SERVICE_RUN_STATE_FAILED: ServiceRunState

class ServiceRun(_message.Message):
    __slots__ = ("service", "state", "pid", "restarts", "last_exit_code", "last_exit_stamp_ns", "restart_in_s", "uptime_s", "last_error")
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    PID_FIELD_NUMBER: _ClassVar[int]
    RESTARTS_FIELD_NUMBER: _ClassVar[int]
    LAST_EXIT_CODE_FIELD_NUMBER: _ClassVar[int]
    LAST_EXIT_STAMP_NS_FIELD_NUMBER: _ClassVar[int]
    RESTART_IN_S_FIELD_NUMBER: _ClassVar[int]
    UPTIME_S_FIELD_NUMBER: _ClassVar[int]
    LAST_ERROR_FIELD_NUMBER: _ClassVar[int]
    service: str
    state: ServiceRunState
    pid: int
    restarts: int
    last_exit_code: int
    last_exit_stamp_ns: int
    restart_in_s: float
    uptime_s: float
    last_error: str
    def __init__(self, service: _Optional[str] = ..., state: _Optional[_Union[ServiceRunState, str]] = ..., pid: _Optional[int] = ..., restarts: _Optional[int] = ..., last_exit_code: _Optional[int] = ..., last_exit_stamp_ns: _Optional[int] = ..., restart_in_s: _Optional[float] = ..., uptime_s: _Optional[float] = ..., last_error: _Optional[str] = ...) -> None: ...

class SupervisorStatus(_message.Message):
    __slots__ = ("header", "services", "router_endpoint", "event", "replayed")
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SERVICES_FIELD_NUMBER: _ClassVar[int]
    ROUTER_ENDPOINT_FIELD_NUMBER: _ClassVar[int]
    EVENT_FIELD_NUMBER: _ClassVar[int]
    REPLAYED_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    services: _containers.RepeatedCompositeFieldContainer[ServiceRun]
    router_endpoint: str
    event: str
    replayed: bool
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., services: _Optional[_Iterable[_Union[ServiceRun, _Mapping]]] = ..., router_endpoint: _Optional[str] = ..., event: _Optional[str] = ..., replayed: _Optional[bool] = ...) -> None: ...

class LoadStatus(_message.Message):
    __slots__ = ("header", "service", "target_hz", "achieved_hz", "period_s", "counts", "latency_p95_ms", "behind", "note")
    class CountsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: int
        def __init__(self, key: _Optional[str] = ..., value: _Optional[int] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    SERVICE_FIELD_NUMBER: _ClassVar[int]
    TARGET_HZ_FIELD_NUMBER: _ClassVar[int]
    ACHIEVED_HZ_FIELD_NUMBER: _ClassVar[int]
    PERIOD_S_FIELD_NUMBER: _ClassVar[int]
    COUNTS_FIELD_NUMBER: _ClassVar[int]
    LATENCY_P95_MS_FIELD_NUMBER: _ClassVar[int]
    BEHIND_FIELD_NUMBER: _ClassVar[int]
    NOTE_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    service: str
    target_hz: float
    achieved_hz: float
    period_s: float
    counts: _containers.ScalarMap[str, int]
    latency_p95_ms: float
    behind: bool
    note: str
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., service: _Optional[str] = ..., target_hz: _Optional[float] = ..., achieved_hz: _Optional[float] = ..., period_s: _Optional[float] = ..., counts: _Optional[_Mapping[str, int]] = ..., latency_p95_ms: _Optional[float] = ..., behind: _Optional[bool] = ..., note: _Optional[str] = ...) -> None: ...
