from tiplog.v1 import common_pb2 as _common_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class RecorderState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    RECORDER_STATE_UNSPECIFIED: _ClassVar[RecorderState]
    RECORDER_STATE_IDLE: _ClassVar[RecorderState]
    RECORDER_STATE_RECORDING: _ClassVar[RecorderState]
    RECORDER_STATE_ERROR: _ClassVar[RecorderState]

class RecorderAction(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    RECORDER_ACTION_UNSPECIFIED: _ClassVar[RecorderAction]
    RECORDER_ACTION_START: _ClassVar[RecorderAction]
    RECORDER_ACTION_STOP: _ClassVar[RecorderAction]
    RECORDER_ACTION_SPLIT: _ClassVar[RecorderAction]
    RECORDER_ACTION_MARK: _ClassVar[RecorderAction]
    RECORDER_ACTION_STATUS: _ClassVar[RecorderAction]
RECORDER_STATE_UNSPECIFIED: RecorderState
RECORDER_STATE_IDLE: RecorderState
RECORDER_STATE_RECORDING: RecorderState
RECORDER_STATE_ERROR: RecorderState
RECORDER_ACTION_UNSPECIFIED: RecorderAction
RECORDER_ACTION_START: RecorderAction
RECORDER_ACTION_STOP: RecorderAction
RECORDER_ACTION_SPLIT: RecorderAction
RECORDER_ACTION_MARK: RecorderAction
RECORDER_ACTION_STATUS: RecorderAction

class TopicCounts(_message.Message):
    __slots__ = ("received", "written", "dropped", "upstream_gaps", "time_gaps", "time_gap_s")
    RECEIVED_FIELD_NUMBER: _ClassVar[int]
    WRITTEN_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    UPSTREAM_GAPS_FIELD_NUMBER: _ClassVar[int]
    TIME_GAPS_FIELD_NUMBER: _ClassVar[int]
    TIME_GAP_S_FIELD_NUMBER: _ClassVar[int]
    received: int
    written: int
    dropped: int
    upstream_gaps: int
    time_gaps: int
    time_gap_s: float
    def __init__(self, received: _Optional[int] = ..., written: _Optional[int] = ..., dropped: _Optional[int] = ..., upstream_gaps: _Optional[int] = ..., time_gaps: _Optional[int] = ..., time_gap_s: _Optional[float] = ...) -> None: ...

class RecorderStatus(_message.Message):
    __slots__ = ("header", "state", "path", "bytes_written", "free_bytes", "duration_s", "alarm", "topics", "file_index", "session")
    class TopicsEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: TopicCounts
        def __init__(self, key: _Optional[str] = ..., value: _Optional[_Union[TopicCounts, _Mapping]] = ...) -> None: ...
    HEADER_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    PATH_FIELD_NUMBER: _ClassVar[int]
    BYTES_WRITTEN_FIELD_NUMBER: _ClassVar[int]
    FREE_BYTES_FIELD_NUMBER: _ClassVar[int]
    DURATION_S_FIELD_NUMBER: _ClassVar[int]
    ALARM_FIELD_NUMBER: _ClassVar[int]
    TOPICS_FIELD_NUMBER: _ClassVar[int]
    FILE_INDEX_FIELD_NUMBER: _ClassVar[int]
    SESSION_FIELD_NUMBER: _ClassVar[int]
    header: _common_pb2.Header
    state: RecorderState
    path: str
    bytes_written: int
    free_bytes: int
    duration_s: float
    alarm: str
    topics: _containers.MessageMap[str, TopicCounts]
    file_index: int
    session: str
    def __init__(self, header: _Optional[_Union[_common_pb2.Header, _Mapping]] = ..., state: _Optional[_Union[RecorderState, str]] = ..., path: _Optional[str] = ..., bytes_written: _Optional[int] = ..., free_bytes: _Optional[int] = ..., duration_s: _Optional[float] = ..., alarm: _Optional[str] = ..., topics: _Optional[_Mapping[str, TopicCounts]] = ..., file_index: _Optional[int] = ..., session: _Optional[str] = ...) -> None: ...

class RecorderCommand(_message.Message):
    __slots__ = ("action", "reason", "session")
    ACTION_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    SESSION_FIELD_NUMBER: _ClassVar[int]
    action: RecorderAction
    reason: str
    session: str
    def __init__(self, action: _Optional[_Union[RecorderAction, str]] = ..., reason: _Optional[str] = ..., session: _Optional[str] = ...) -> None: ...

class RecorderReply(_message.Message):
    __slots__ = ("ok", "message", "status")
    OK_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    ok: bool
    message: str
    status: RecorderStatus
    def __init__(self, ok: _Optional[bool] = ..., message: _Optional[str] = ..., status: _Optional[_Union[RecorderStatus, _Mapping]] = ...) -> None: ...
