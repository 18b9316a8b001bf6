from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class BackendKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    BACKEND_KIND_UNSPECIFIED: _ClassVar[BackendKind]
    BACKEND_KIND_SOCKETCAN: _ClassVar[BackendKind]
    BACKEND_KIND_VIRTUAL: _ClassVar[BackendKind]

class BusState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    BUS_STATE_UNSPECIFIED: _ClassVar[BusState]
    BUS_STATE_UP: _ClassVar[BusState]
    BUS_STATE_ERROR_WARNING: _ClassVar[BusState]
    BUS_STATE_ERROR_PASSIVE: _ClassVar[BusState]
    BUS_STATE_BUS_OFF: _ClassVar[BusState]
    BUS_STATE_DOWN: _ClassVar[BusState]

class Direction(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DIRECTION_UNSPECIFIED: _ClassVar[Direction]
    DIRECTION_RX: _ClassVar[Direction]
    DIRECTION_TX: _ClassVar[Direction]

class FrameOrigin(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    FRAME_ORIGIN_UNSPECIFIED: _ClassVar[FrameOrigin]
    FRAME_ORIGIN_BUS: _ClassVar[FrameOrigin]
    FRAME_ORIGIN_GATEWAY: _ClassVar[FrameOrigin]
    FRAME_ORIGIN_CLIENT: _ClassVar[FrameOrigin]

class IdFormat(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    ID_FORMAT_ANY: _ClassVar[IdFormat]
    ID_FORMAT_STANDARD: _ClassVar[IdFormat]
    ID_FORMAT_EXTENDED: _ClassVar[IdFormat]
BACKEND_KIND_UNSPECIFIED: BackendKind
BACKEND_KIND_SOCKETCAN: BackendKind
BACKEND_KIND_VIRTUAL: BackendKind
BUS_STATE_UNSPECIFIED: BusState
BUS_STATE_UP: BusState
BUS_STATE_ERROR_WARNING: BusState
BUS_STATE_ERROR_PASSIVE: BusState
BUS_STATE_BUS_OFF: BusState
BUS_STATE_DOWN: BusState
DIRECTION_UNSPECIFIED: Direction
DIRECTION_RX: Direction
DIRECTION_TX: Direction
FRAME_ORIGIN_UNSPECIFIED: FrameOrigin
FRAME_ORIGIN_BUS: FrameOrigin
FRAME_ORIGIN_GATEWAY: FrameOrigin
FRAME_ORIGIN_CLIENT: FrameOrigin
ID_FORMAT_ANY: IdFormat
ID_FORMAT_STANDARD: IdFormat
ID_FORMAT_EXTENDED: IdFormat

class FrameSender(_message.Message):
    __slots__ = ("id", "client")
    ID_FIELD_NUMBER: _ClassVar[int]
    CLIENT_FIELD_NUMBER: _ClassVar[int]
    id: int
    client: str
    def __init__(self, id: _Optional[int] = ..., client: _Optional[str] = ...) -> None: ...

class Frame(_message.Message):
    __slots__ = ("id", "extended", "remote", "fd", "brs", "esi", "data", "remote_dlc", "error", "timestamp_ns", "direction", "origin", "sender")
    ID_FIELD_NUMBER: _ClassVar[int]
    EXTENDED_FIELD_NUMBER: _ClassVar[int]
    REMOTE_FIELD_NUMBER: _ClassVar[int]
    FD_FIELD_NUMBER: _ClassVar[int]
    BRS_FIELD_NUMBER: _ClassVar[int]
    ESI_FIELD_NUMBER: _ClassVar[int]
    DATA_FIELD_NUMBER: _ClassVar[int]
    REMOTE_DLC_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_NS_FIELD_NUMBER: _ClassVar[int]
    DIRECTION_FIELD_NUMBER: _ClassVar[int]
    ORIGIN_FIELD_NUMBER: _ClassVar[int]
    SENDER_FIELD_NUMBER: _ClassVar[int]
    id: int
    extended: bool
    remote: bool
    fd: bool
    brs: bool
    esi: bool
    data: bytes
    remote_dlc: int
    error: bool
    timestamp_ns: int
    direction: Direction
    origin: FrameOrigin
    sender: FrameSender
    def __init__(self, id: _Optional[int] = ..., extended: _Optional[bool] = ..., remote: _Optional[bool] = ..., fd: _Optional[bool] = ..., brs: _Optional[bool] = ..., esi: _Optional[bool] = ..., data: _Optional[bytes] = ..., remote_dlc: _Optional[int] = ..., error: _Optional[bool] = ..., timestamp_ns: _Optional[int] = ..., direction: _Optional[_Union[Direction, str]] = ..., origin: _Optional[_Union[FrameOrigin, str]] = ..., sender: _Optional[_Union[FrameSender, _Mapping]] = ...) -> None: ...

class FrameFilter(_message.Message):
    __slots__ = ("id", "mask", "format", "invert")
    ID_FIELD_NUMBER: _ClassVar[int]
    MASK_FIELD_NUMBER: _ClassVar[int]
    FORMAT_FIELD_NUMBER: _ClassVar[int]
    INVERT_FIELD_NUMBER: _ClassVar[int]
    id: int
    mask: int
    format: IdFormat
    invert: bool
    def __init__(self, id: _Optional[int] = ..., mask: _Optional[int] = ..., format: _Optional[_Union[IdFormat, str]] = ..., invert: _Optional[bool] = ...) -> None: ...

class BusStatus(_message.Message):
    __slots__ = ("state", "tx_errors", "rx_errors", "since_ns")
    STATE_FIELD_NUMBER: _ClassVar[int]
    TX_ERRORS_FIELD_NUMBER: _ClassVar[int]
    RX_ERRORS_FIELD_NUMBER: _ClassVar[int]
    SINCE_NS_FIELD_NUMBER: _ClassVar[int]
    state: BusState
    tx_errors: int
    rx_errors: int
    since_ns: int
    def __init__(self, state: _Optional[_Union[BusState, str]] = ..., tx_errors: _Optional[int] = ..., rx_errors: _Optional[int] = ..., since_ns: _Optional[int] = ...) -> None: ...

class BusStatistics(_message.Message):
    __slots__ = ("rx_frames", "tx_frames", "rx_bytes", "tx_bytes", "error_frames", "tx_failed", "rx_overflows", "subscriber_drops", "load_percent", "subscribers", "tx_retries", "tx_queued")
    RX_FRAMES_FIELD_NUMBER: _ClassVar[int]
    TX_FRAMES_FIELD_NUMBER: _ClassVar[int]
    RX_BYTES_FIELD_NUMBER: _ClassVar[int]
    TX_BYTES_FIELD_NUMBER: _ClassVar[int]
    ERROR_FRAMES_FIELD_NUMBER: _ClassVar[int]
    TX_FAILED_FIELD_NUMBER: _ClassVar[int]
    RX_OVERFLOWS_FIELD_NUMBER: _ClassVar[int]
    SUBSCRIBER_DROPS_FIELD_NUMBER: _ClassVar[int]
    LOAD_PERCENT_FIELD_NUMBER: _ClassVar[int]
    SUBSCRIBERS_FIELD_NUMBER: _ClassVar[int]
    TX_RETRIES_FIELD_NUMBER: _ClassVar[int]
    TX_QUEUED_FIELD_NUMBER: _ClassVar[int]
    rx_frames: int
    tx_frames: int
    rx_bytes: int
    tx_bytes: int
    error_frames: int
    tx_failed: int
    rx_overflows: int
    subscriber_drops: int
    load_percent: float
    subscribers: int
    tx_retries: int
    tx_queued: int
    def __init__(self, rx_frames: _Optional[int] = ..., tx_frames: _Optional[int] = ..., rx_bytes: _Optional[int] = ..., tx_bytes: _Optional[int] = ..., error_frames: _Optional[int] = ..., tx_failed: _Optional[int] = ..., rx_overflows: _Optional[int] = ..., subscriber_drops: _Optional[int] = ..., load_percent: _Optional[float] = ..., subscribers: _Optional[int] = ..., tx_retries: _Optional[int] = ..., tx_queued: _Optional[int] = ...) -> None: ...

class BusInfo(_message.Message):
    __slots__ = ("name", "backend", "interface", "fd", "bitrate", "data_bitrate", "bit_timed", "status", "statistics")
    NAME_FIELD_NUMBER: _ClassVar[int]
    BACKEND_FIELD_NUMBER: _ClassVar[int]
    INTERFACE_FIELD_NUMBER: _ClassVar[int]
    FD_FIELD_NUMBER: _ClassVar[int]
    BITRATE_FIELD_NUMBER: _ClassVar[int]
    DATA_BITRATE_FIELD_NUMBER: _ClassVar[int]
    BIT_TIMED_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    STATISTICS_FIELD_NUMBER: _ClassVar[int]
    name: str
    backend: BackendKind
    interface: str
    fd: bool
    bitrate: int
    data_bitrate: int
    bit_timed: bool
    status: BusStatus
    statistics: BusStatistics
    def __init__(self, name: _Optional[str] = ..., backend: _Optional[_Union[BackendKind, str]] = ..., interface: _Optional[str] = ..., fd: _Optional[bool] = ..., bitrate: _Optional[int] = ..., data_bitrate: _Optional[int] = ..., bit_timed: _Optional[bool] = ..., status: _Optional[_Union[BusStatus, _Mapping]] = ..., statistics: _Optional[_Union[BusStatistics, _Mapping]] = ...) -> None: ...

class ListBusesRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListBusesResponse(_message.Message):
    __slots__ = ("buses",)
    BUSES_FIELD_NUMBER: _ClassVar[int]
    buses: _containers.RepeatedCompositeFieldContainer[BusInfo]
    def __init__(self, buses: _Optional[_Iterable[_Union[BusInfo, _Mapping]]] = ...) -> None: ...

class GetBusRequest(_message.Message):
    __slots__ = ("bus",)
    BUS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    def __init__(self, bus: _Optional[str] = ...) -> None: ...

class SendFramesRequest(_message.Message):
    __slots__ = ("bus", "frames")
    BUS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    bus: str
    frames: _containers.RepeatedCompositeFieldContainer[Frame]
    def __init__(self, bus: _Optional[str] = ..., frames: _Optional[_Iterable[_Union[Frame, _Mapping]]] = ...) -> None: ...

class SendFramesResponse(_message.Message):
    __slots__ = ("sent",)
    SENT_FIELD_NUMBER: _ClassVar[int]
    sent: int
    def __init__(self, sent: _Optional[int] = ...) -> None: ...

class StreamFramesRequest(_message.Message):
    __slots__ = ("bus", "filters", "include_transmitted", "include_error_frames", "max_batch", "queue_length", "low_latency")
    BUS_FIELD_NUMBER: _ClassVar[int]
    FILTERS_FIELD_NUMBER: _ClassVar[int]
    INCLUDE_TRANSMITTED_FIELD_NUMBER: _ClassVar[int]
    INCLUDE_ERROR_FRAMES_FIELD_NUMBER: _ClassVar[int]
    MAX_BATCH_FIELD_NUMBER: _ClassVar[int]
    QUEUE_LENGTH_FIELD_NUMBER: _ClassVar[int]
    LOW_LATENCY_FIELD_NUMBER: _ClassVar[int]
    bus: str
    filters: _containers.RepeatedCompositeFieldContainer[FrameFilter]
    include_transmitted: bool
    include_error_frames: bool
    max_batch: int
    queue_length: int
    low_latency: bool
    def __init__(self, bus: _Optional[str] = ..., filters: _Optional[_Iterable[_Union[FrameFilter, _Mapping]]] = ..., include_transmitted: _Optional[bool] = ..., include_error_frames: _Optional[bool] = ..., max_batch: _Optional[int] = ..., queue_length: _Optional[int] = ..., low_latency: _Optional[bool] = ...) -> None: ...

class FramesLost(_message.Message):
    __slots__ = ("count",)
    COUNT_FIELD_NUMBER: _ClassVar[int]
    count: int
    def __init__(self, count: _Optional[int] = ...) -> None: ...

class StreamEvent(_message.Message):
    __slots__ = ("frame", "lost", "state")
    FRAME_FIELD_NUMBER: _ClassVar[int]
    LOST_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    frame: Frame
    lost: FramesLost
    state: BusStatus
    def __init__(self, frame: _Optional[_Union[Frame, _Mapping]] = ..., lost: _Optional[_Union[FramesLost, _Mapping]] = ..., state: _Optional[_Union[BusStatus, _Mapping]] = ...) -> None: ...

class StreamFramesResponse(_message.Message):
    __slots__ = ("events",)
    EVENTS_FIELD_NUMBER: _ClassVar[int]
    events: _containers.RepeatedCompositeFieldContainer[StreamEvent]
    def __init__(self, events: _Optional[_Iterable[_Union[StreamEvent, _Mapping]]] = ...) -> None: ...

class AttachRequest(_message.Message):
    __slots__ = ("open", "send", "cyclic", "cyclic_stop")
    OPEN_FIELD_NUMBER: _ClassVar[int]
    SEND_FIELD_NUMBER: _ClassVar[int]
    CYCLIC_FIELD_NUMBER: _ClassVar[int]
    CYCLIC_STOP_FIELD_NUMBER: _ClassVar[int]
    open: AttachOpen
    send: AttachSend
    cyclic: AttachCyclic
    cyclic_stop: AttachCyclicStop
    def __init__(self, open: _Optional[_Union[AttachOpen, _Mapping]] = ..., send: _Optional[_Union[AttachSend, _Mapping]] = ..., cyclic: _Optional[_Union[AttachCyclic, _Mapping]] = ..., cyclic_stop: _Optional[_Union[AttachCyclicStop, _Mapping]] = ...) -> None: ...

class AttachOpen(_message.Message):
    __slots__ = ("bus", "filters", "receive_own", "fd", "include_error_frames", "max_batch", "queue_length", "low_latency")
    BUS_FIELD_NUMBER: _ClassVar[int]
    FILTERS_FIELD_NUMBER: _ClassVar[int]
    RECEIVE_OWN_FIELD_NUMBER: _ClassVar[int]
    FD_FIELD_NUMBER: _ClassVar[int]
    INCLUDE_ERROR_FRAMES_FIELD_NUMBER: _ClassVar[int]
    MAX_BATCH_FIELD_NUMBER: _ClassVar[int]
    QUEUE_LENGTH_FIELD_NUMBER: _ClassVar[int]
    LOW_LATENCY_FIELD_NUMBER: _ClassVar[int]
    bus: str
    filters: _containers.RepeatedCompositeFieldContainer[FrameFilter]
    receive_own: bool
    fd: bool
    include_error_frames: bool
    max_batch: int
    queue_length: int
    low_latency: bool
    def __init__(self, bus: _Optional[str] = ..., filters: _Optional[_Iterable[_Union[FrameFilter, _Mapping]]] = ..., receive_own: _Optional[bool] = ..., fd: _Optional[bool] = ..., include_error_frames: _Optional[bool] = ..., max_batch: _Optional[int] = ..., queue_length: _Optional[int] = ..., low_latency: _Optional[bool] = ...) -> None: ...

class AttachSend(_message.Message):
    __slots__ = ("frames", "sequence")
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    frames: _containers.RepeatedCompositeFieldContainer[Frame]
    sequence: int
    def __init__(self, frames: _Optional[_Iterable[_Union[Frame, _Mapping]]] = ..., sequence: _Optional[int] = ...) -> None: ...

class AttachCyclic(_message.Message):
    __slots__ = ("job", "frames", "interval_ns", "duration_ns", "sequence")
    JOB_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    INTERVAL_NS_FIELD_NUMBER: _ClassVar[int]
    DURATION_NS_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    job: int
    frames: _containers.RepeatedCompositeFieldContainer[Frame]
    interval_ns: int
    duration_ns: int
    sequence: int
    def __init__(self, job: _Optional[int] = ..., frames: _Optional[_Iterable[_Union[Frame, _Mapping]]] = ..., interval_ns: _Optional[int] = ..., duration_ns: _Optional[int] = ..., sequence: _Optional[int] = ...) -> None: ...

class AttachCyclicStop(_message.Message):
    __slots__ = ("job", "sequence")
    JOB_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    job: int
    sequence: int
    def __init__(self, job: _Optional[int] = ..., sequence: _Optional[int] = ...) -> None: ...

class CyclicStopped(_message.Message):
    __slots__ = ("job", "code", "message", "reason")
    JOB_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    job: int
    code: int
    message: str
    reason: str
    def __init__(self, job: _Optional[int] = ..., code: _Optional[int] = ..., message: _Optional[str] = ..., reason: _Optional[str] = ...) -> None: ...

class AttachResponse(_message.Message):
    __slots__ = ("events",)
    EVENTS_FIELD_NUMBER: _ClassVar[int]
    events: _containers.RepeatedCompositeFieldContainer[AttachEvent]
    def __init__(self, events: _Optional[_Iterable[_Union[AttachEvent, _Mapping]]] = ...) -> None: ...

class AttachEvent(_message.Message):
    __slots__ = ("opened", "frame", "lost", "state", "refused", "done", "cyclic_stopped")
    OPENED_FIELD_NUMBER: _ClassVar[int]
    FRAME_FIELD_NUMBER: _ClassVar[int]
    LOST_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    REFUSED_FIELD_NUMBER: _ClassVar[int]
    DONE_FIELD_NUMBER: _ClassVar[int]
    CYCLIC_STOPPED_FIELD_NUMBER: _ClassVar[int]
    opened: AttachOpened
    frame: Frame
    lost: FramesLost
    state: BusStatus
    refused: SendRefused
    done: SendDone
    cyclic_stopped: CyclicStopped
    def __init__(self, opened: _Optional[_Union[AttachOpened, _Mapping]] = ..., frame: _Optional[_Union[Frame, _Mapping]] = ..., lost: _Optional[_Union[FramesLost, _Mapping]] = ..., state: _Optional[_Union[BusStatus, _Mapping]] = ..., refused: _Optional[_Union[SendRefused, _Mapping]] = ..., done: _Optional[_Union[SendDone, _Mapping]] = ..., cyclic_stopped: _Optional[_Union[CyclicStopped, _Mapping]] = ...) -> None: ...

class AttachOpened(_message.Message):
    __slots__ = ("bus", "sender_id", "client", "queue_length")
    BUS_FIELD_NUMBER: _ClassVar[int]
    SENDER_ID_FIELD_NUMBER: _ClassVar[int]
    CLIENT_FIELD_NUMBER: _ClassVar[int]
    QUEUE_LENGTH_FIELD_NUMBER: _ClassVar[int]
    bus: BusInfo
    sender_id: int
    client: str
    queue_length: int
    def __init__(self, bus: _Optional[_Union[BusInfo, _Mapping]] = ..., sender_id: _Optional[int] = ..., client: _Optional[str] = ..., queue_length: _Optional[int] = ...) -> None: ...

class SendRefused(_message.Message):
    __slots__ = ("sequence", "sent", "total", "code", "message", "reason", "metadata")
    class MetadataEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    SENT_FIELD_NUMBER: _ClassVar[int]
    TOTAL_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    METADATA_FIELD_NUMBER: _ClassVar[int]
    sequence: int
    sent: int
    total: int
    code: int
    message: str
    reason: str
    metadata: _containers.ScalarMap[str, str]
    def __init__(self, sequence: _Optional[int] = ..., sent: _Optional[int] = ..., total: _Optional[int] = ..., code: _Optional[int] = ..., message: _Optional[str] = ..., reason: _Optional[str] = ..., metadata: _Optional[_Mapping[str, str]] = ...) -> None: ...

class SendDone(_message.Message):
    __slots__ = ("sequence", "sent")
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    SENT_FIELD_NUMBER: _ClassVar[int]
    sequence: int
    sent: int
    def __init__(self, sequence: _Optional[int] = ..., sent: _Optional[int] = ...) -> None: ...
