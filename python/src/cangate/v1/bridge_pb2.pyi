from cangate.v1 import axes_pb2 as _axes_pb2
from cangate.v1 import bus_pb2 as _bus_pb2
from cangate.v1 import canopen_pb2 as _canopen_pb2
from cangate.v1 import cansmc_pb2 as _cansmc_pb2
from cangate.v1 import handwheel_pb2 as _handwheel_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class GapReason(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    GAP_REASON_UNSPECIFIED: _ClassVar[GapReason]
    GAP_REASON_QUEUE_FULL: _ClassVar[GapReason]
    GAP_REASON_SOURCE_LAGGED: _ClassVar[GapReason]
GAP_REASON_UNSPECIFIED: GapReason
GAP_REASON_QUEUE_FULL: GapReason
GAP_REASON_SOURCE_LAGGED: GapReason

class BridgeEnvelope(_message.Message):
    __slots__ = ("gateway", "epoch", "stream", "seq", "timestamp_ns", "status", "node_event", "frames", "bus", "gap", "axis_status", "axis_event", "feed", "cansmc_status")
    GATEWAY_FIELD_NUMBER: _ClassVar[int]
    EPOCH_FIELD_NUMBER: _ClassVar[int]
    STREAM_FIELD_NUMBER: _ClassVar[int]
    SEQ_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_NS_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    NODE_EVENT_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    BUS_FIELD_NUMBER: _ClassVar[int]
    GAP_FIELD_NUMBER: _ClassVar[int]
    AXIS_STATUS_FIELD_NUMBER: _ClassVar[int]
    AXIS_EVENT_FIELD_NUMBER: _ClassVar[int]
    FEED_FIELD_NUMBER: _ClassVar[int]
    CANSMC_STATUS_FIELD_NUMBER: _ClassVar[int]
    gateway: str
    epoch: int
    stream: str
    seq: int
    timestamp_ns: int
    status: GatewayStatus
    node_event: _canopen_pb2.NodeEvent
    frames: _bus_pb2.StreamFramesResponse
    bus: _bus_pb2.BusInfo
    gap: BridgeGap
    axis_status: _axes_pb2.AxisStatus
    axis_event: _axes_pb2.AxisEvent
    feed: _handwheel_pb2.FeedEvent
    cansmc_status: _cansmc_pb2.CansmcStatus
    def __init__(self, gateway: _Optional[str] = ..., epoch: _Optional[int] = ..., stream: _Optional[str] = ..., seq: _Optional[int] = ..., timestamp_ns: _Optional[int] = ..., status: _Optional[_Union[GatewayStatus, _Mapping]] = ..., node_event: _Optional[_Union[_canopen_pb2.NodeEvent, _Mapping]] = ..., frames: _Optional[_Union[_bus_pb2.StreamFramesResponse, _Mapping]] = ..., bus: _Optional[_Union[_bus_pb2.BusInfo, _Mapping]] = ..., gap: _Optional[_Union[BridgeGap, _Mapping]] = ..., axis_status: _Optional[_Union[_axes_pb2.AxisStatus, _Mapping]] = ..., axis_event: _Optional[_Union[_axes_pb2.AxisEvent, _Mapping]] = ..., feed: _Optional[_Union[_handwheel_pb2.FeedEvent, _Mapping]] = ..., cansmc_status: _Optional[_Union[_cansmc_pb2.CansmcStatus, _Mapping]] = ...) -> None: ...

class GatewayStatus(_message.Message):
    __slots__ = ("online", "gateway", "version", "buses", "axes", "started_ns")
    ONLINE_FIELD_NUMBER: _ClassVar[int]
    GATEWAY_FIELD_NUMBER: _ClassVar[int]
    VERSION_FIELD_NUMBER: _ClassVar[int]
    BUSES_FIELD_NUMBER: _ClassVar[int]
    AXES_FIELD_NUMBER: _ClassVar[int]
    STARTED_NS_FIELD_NUMBER: _ClassVar[int]
    online: bool
    gateway: str
    version: str
    buses: _containers.RepeatedScalarFieldContainer[str]
    axes: _containers.RepeatedScalarFieldContainer[str]
    started_ns: int
    def __init__(self, online: _Optional[bool] = ..., gateway: _Optional[str] = ..., version: _Optional[str] = ..., buses: _Optional[_Iterable[str]] = ..., axes: _Optional[_Iterable[str]] = ..., started_ns: _Optional[int] = ...) -> None: ...

class BridgeGap(_message.Message):
    __slots__ = ("stream", "first_seq", "last_seq", "count", "reason")
    STREAM_FIELD_NUMBER: _ClassVar[int]
    FIRST_SEQ_FIELD_NUMBER: _ClassVar[int]
    LAST_SEQ_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    stream: str
    first_seq: int
    last_seq: int
    count: int
    reason: GapReason
    def __init__(self, stream: _Optional[str] = ..., first_seq: _Optional[int] = ..., last_seq: _Optional[int] = ..., count: _Optional[int] = ..., reason: _Optional[_Union[GapReason, str]] = ...) -> None: ...
