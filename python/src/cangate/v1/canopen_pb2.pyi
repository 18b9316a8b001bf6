from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class NmtState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    NMT_STATE_UNKNOWN: _ClassVar[NmtState]
    NMT_STATE_INITIALISING: _ClassVar[NmtState]
    NMT_STATE_STOPPED: _ClassVar[NmtState]
    NMT_STATE_OPERATIONAL: _ClassVar[NmtState]
    NMT_STATE_PRE_OPERATIONAL: _ClassVar[NmtState]

class NmtCommand(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    NMT_COMMAND_UNSPECIFIED: _ClassVar[NmtCommand]
    NMT_COMMAND_START: _ClassVar[NmtCommand]
    NMT_COMMAND_STOP: _ClassVar[NmtCommand]
    NMT_COMMAND_ENTER_PRE_OPERATIONAL: _ClassVar[NmtCommand]
    NMT_COMMAND_RESET_NODE: _ClassVar[NmtCommand]
    NMT_COMMAND_RESET_COMMUNICATION: _ClassVar[NmtCommand]

class DataType(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DATA_TYPE_UNSPECIFIED: _ClassVar[DataType]
    DATA_TYPE_BOOLEAN: _ClassVar[DataType]
    DATA_TYPE_INTEGER8: _ClassVar[DataType]
    DATA_TYPE_INTEGER16: _ClassVar[DataType]
    DATA_TYPE_INTEGER32: _ClassVar[DataType]
    DATA_TYPE_UNSIGNED8: _ClassVar[DataType]
    DATA_TYPE_UNSIGNED16: _ClassVar[DataType]
    DATA_TYPE_UNSIGNED32: _ClassVar[DataType]
    DATA_TYPE_REAL32: _ClassVar[DataType]
    DATA_TYPE_VISIBLE_STRING: _ClassVar[DataType]
    DATA_TYPE_OCTET_STRING: _ClassVar[DataType]
    DATA_TYPE_UNICODE_STRING: _ClassVar[DataType]
    DATA_TYPE_DOMAIN: _ClassVar[DataType]
    DATA_TYPE_REAL64: _ClassVar[DataType]
    DATA_TYPE_INTEGER64: _ClassVar[DataType]
    DATA_TYPE_UNSIGNED64: _ClassVar[DataType]

class LifeMonitoring(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    LIFE_MONITORING_NONE: _ClassVar[LifeMonitoring]
    LIFE_MONITORING_HEARTBEAT: _ClassVar[LifeMonitoring]
    LIFE_MONITORING_NODE_GUARDING: _ClassVar[LifeMonitoring]

class ObjectAccess(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    OBJECT_ACCESS_UNSPECIFIED: _ClassVar[ObjectAccess]
    OBJECT_ACCESS_RO: _ClassVar[ObjectAccess]
    OBJECT_ACCESS_WO: _ClassVar[ObjectAccess]
    OBJECT_ACCESS_RW: _ClassVar[ObjectAccess]
    OBJECT_ACCESS_RWR: _ClassVar[ObjectAccess]
    OBJECT_ACCESS_RWW: _ClassVar[ObjectAccess]
    OBJECT_ACCESS_CONST: _ClassVar[ObjectAccess]

class PdoKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    PDO_KIND_UNSPECIFIED: _ClassVar[PdoKind]
    PDO_KIND_RPDO: _ClassVar[PdoKind]
    PDO_KIND_TPDO: _ClassVar[PdoKind]

class ProgramStep(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    PROGRAM_STEP_UNSPECIFIED: _ClassVar[ProgramStep]
    PROGRAM_STEP_READ_IDENTIFICATION_BEFORE: _ClassVar[ProgramStep]
    PROGRAM_STEP_STOP_PROGRAM: _ClassVar[ProgramStep]
    PROGRAM_STEP_CLEAR_PROGRAM: _ClassVar[ProgramStep]
    PROGRAM_STEP_DOWNLOAD_DATA: _ClassVar[ProgramStep]
    PROGRAM_STEP_WAIT_FLASH: _ClassVar[ProgramStep]
    PROGRAM_STEP_START_PROGRAM: _ClassVar[ProgramStep]
    PROGRAM_STEP_WAIT_BOOT_UP: _ClassVar[ProgramStep]
    PROGRAM_STEP_READ_IDENTIFICATION_AFTER: _ClassVar[ProgramStep]
NMT_STATE_UNKNOWN: NmtState
NMT_STATE_INITIALISING: NmtState
NMT_STATE_STOPPED: NmtState
NMT_STATE_OPERATIONAL: NmtState
NMT_STATE_PRE_OPERATIONAL: NmtState
NMT_COMMAND_UNSPECIFIED: NmtCommand
NMT_COMMAND_START: NmtCommand
NMT_COMMAND_STOP: NmtCommand
NMT_COMMAND_ENTER_PRE_OPERATIONAL: NmtCommand
NMT_COMMAND_RESET_NODE: NmtCommand
NMT_COMMAND_RESET_COMMUNICATION: NmtCommand
DATA_TYPE_UNSPECIFIED: DataType
DATA_TYPE_BOOLEAN: DataType
DATA_TYPE_INTEGER8: DataType
DATA_TYPE_INTEGER16: DataType
DATA_TYPE_INTEGER32: DataType
DATA_TYPE_UNSIGNED8: DataType
DATA_TYPE_UNSIGNED16: DataType
DATA_TYPE_UNSIGNED32: DataType
DATA_TYPE_REAL32: DataType
DATA_TYPE_VISIBLE_STRING: DataType
DATA_TYPE_OCTET_STRING: DataType
DATA_TYPE_UNICODE_STRING: DataType
DATA_TYPE_DOMAIN: DataType
DATA_TYPE_REAL64: DataType
DATA_TYPE_INTEGER64: DataType
DATA_TYPE_UNSIGNED64: DataType
LIFE_MONITORING_NONE: LifeMonitoring
LIFE_MONITORING_HEARTBEAT: LifeMonitoring
LIFE_MONITORING_NODE_GUARDING: LifeMonitoring
OBJECT_ACCESS_UNSPECIFIED: ObjectAccess
OBJECT_ACCESS_RO: ObjectAccess
OBJECT_ACCESS_WO: ObjectAccess
OBJECT_ACCESS_RW: ObjectAccess
OBJECT_ACCESS_RWR: ObjectAccess
OBJECT_ACCESS_RWW: ObjectAccess
OBJECT_ACCESS_CONST: ObjectAccess
PDO_KIND_UNSPECIFIED: PdoKind
PDO_KIND_RPDO: PdoKind
PDO_KIND_TPDO: PdoKind
PROGRAM_STEP_UNSPECIFIED: ProgramStep
PROGRAM_STEP_READ_IDENTIFICATION_BEFORE: ProgramStep
PROGRAM_STEP_STOP_PROGRAM: ProgramStep
PROGRAM_STEP_CLEAR_PROGRAM: ProgramStep
PROGRAM_STEP_DOWNLOAD_DATA: ProgramStep
PROGRAM_STEP_WAIT_FLASH: ProgramStep
PROGRAM_STEP_START_PROGRAM: ProgramStep
PROGRAM_STEP_WAIT_BOOT_UP: ProgramStep
PROGRAM_STEP_READ_IDENTIFICATION_AFTER: ProgramStep

class Value(_message.Message):
    __slots__ = ("type", "bool_value", "int_value", "uint_value", "real_value", "string_value", "bytes_value")
    TYPE_FIELD_NUMBER: _ClassVar[int]
    BOOL_VALUE_FIELD_NUMBER: _ClassVar[int]
    INT_VALUE_FIELD_NUMBER: _ClassVar[int]
    UINT_VALUE_FIELD_NUMBER: _ClassVar[int]
    REAL_VALUE_FIELD_NUMBER: _ClassVar[int]
    STRING_VALUE_FIELD_NUMBER: _ClassVar[int]
    BYTES_VALUE_FIELD_NUMBER: _ClassVar[int]
    type: DataType
    bool_value: bool
    int_value: int
    uint_value: int
    real_value: float
    string_value: str
    bytes_value: bytes
    def __init__(self, type: _Optional[_Union[DataType, str]] = ..., bool_value: _Optional[bool] = ..., int_value: _Optional[int] = ..., uint_value: _Optional[int] = ..., real_value: _Optional[float] = ..., string_value: _Optional[str] = ..., bytes_value: _Optional[bytes] = ...) -> None: ...

class Identity(_message.Message):
    __slots__ = ("vendor_id", "product_code", "revision", "serial")
    VENDOR_ID_FIELD_NUMBER: _ClassVar[int]
    PRODUCT_CODE_FIELD_NUMBER: _ClassVar[int]
    REVISION_FIELD_NUMBER: _ClassVar[int]
    SERIAL_FIELD_NUMBER: _ClassVar[int]
    vendor_id: int
    product_code: int
    revision: int
    serial: int
    def __init__(self, vendor_id: _Optional[int] = ..., product_code: _Optional[int] = ..., revision: _Optional[int] = ..., serial: _Optional[int] = ...) -> None: ...

class Emcy(_message.Message):
    __slots__ = ("node", "code", "code_name", "register", "register_bits", "manufacturer", "timestamp_ns")
    NODE_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    CODE_NAME_FIELD_NUMBER: _ClassVar[int]
    REGISTER_FIELD_NUMBER: _ClassVar[int]
    REGISTER_BITS_FIELD_NUMBER: _ClassVar[int]
    MANUFACTURER_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_NS_FIELD_NUMBER: _ClassVar[int]
    node: int
    code: int
    code_name: str
    register: int
    register_bits: _containers.RepeatedScalarFieldContainer[str]
    manufacturer: bytes
    timestamp_ns: int
    def __init__(self, node: _Optional[int] = ..., code: _Optional[int] = ..., code_name: _Optional[str] = ..., register: _Optional[int] = ..., register_bits: _Optional[_Iterable[str]] = ..., manufacturer: _Optional[bytes] = ..., timestamp_ns: _Optional[int] = ...) -> None: ...

class Node(_message.Message):
    __slots__ = ("bus", "id", "name", "state", "heartbeat_age_ms", "heartbeat_lost", "heartbeat_timeout_ms", "device_type", "device_name", "identity", "active_error", "emcy_history", "boot_ups", "configured", "monitoring", "guard_time_ms", "life_time_factor", "guarding_toggle_errors")
    BUS_FIELD_NUMBER: _ClassVar[int]
    ID_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    HEARTBEAT_AGE_MS_FIELD_NUMBER: _ClassVar[int]
    HEARTBEAT_LOST_FIELD_NUMBER: _ClassVar[int]
    HEARTBEAT_TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    DEVICE_TYPE_FIELD_NUMBER: _ClassVar[int]
    DEVICE_NAME_FIELD_NUMBER: _ClassVar[int]
    IDENTITY_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_ERROR_FIELD_NUMBER: _ClassVar[int]
    EMCY_HISTORY_FIELD_NUMBER: _ClassVar[int]
    BOOT_UPS_FIELD_NUMBER: _ClassVar[int]
    CONFIGURED_FIELD_NUMBER: _ClassVar[int]
    MONITORING_FIELD_NUMBER: _ClassVar[int]
    GUARD_TIME_MS_FIELD_NUMBER: _ClassVar[int]
    LIFE_TIME_FACTOR_FIELD_NUMBER: _ClassVar[int]
    GUARDING_TOGGLE_ERRORS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    id: int
    name: str
    state: NmtState
    heartbeat_age_ms: int
    heartbeat_lost: bool
    heartbeat_timeout_ms: int
    device_type: int
    device_name: str
    identity: Identity
    active_error: Emcy
    emcy_history: _containers.RepeatedCompositeFieldContainer[Emcy]
    boot_ups: int
    configured: bool
    monitoring: LifeMonitoring
    guard_time_ms: int
    life_time_factor: int
    guarding_toggle_errors: int
    def __init__(self, bus: _Optional[str] = ..., id: _Optional[int] = ..., name: _Optional[str] = ..., state: _Optional[_Union[NmtState, str]] = ..., heartbeat_age_ms: _Optional[int] = ..., heartbeat_lost: _Optional[bool] = ..., heartbeat_timeout_ms: _Optional[int] = ..., device_type: _Optional[int] = ..., device_name: _Optional[str] = ..., identity: _Optional[_Union[Identity, _Mapping]] = ..., active_error: _Optional[_Union[Emcy, _Mapping]] = ..., emcy_history: _Optional[_Iterable[_Union[Emcy, _Mapping]]] = ..., boot_ups: _Optional[int] = ..., configured: _Optional[bool] = ..., monitoring: _Optional[_Union[LifeMonitoring, str]] = ..., guard_time_ms: _Optional[int] = ..., life_time_factor: _Optional[int] = ..., guarding_toggle_errors: _Optional[int] = ...) -> None: ...

class ListNodesRequest(_message.Message):
    __slots__ = ("bus",)
    BUS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    def __init__(self, bus: _Optional[str] = ...) -> None: ...

class ListNodesResponse(_message.Message):
    __slots__ = ("nodes",)
    NODES_FIELD_NUMBER: _ClassVar[int]
    nodes: _containers.RepeatedCompositeFieldContainer[Node]
    def __init__(self, nodes: _Optional[_Iterable[_Union[Node, _Mapping]]] = ...) -> None: ...

class GetNodeRequest(_message.Message):
    __slots__ = ("bus", "node")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ...) -> None: ...

class SendNmtRequest(_message.Message):
    __slots__ = ("bus", "node", "command", "force")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    COMMAND_FIELD_NUMBER: _ClassVar[int]
    FORCE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    command: NmtCommand
    force: bool
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., command: _Optional[_Union[NmtCommand, str]] = ..., force: _Optional[bool] = ...) -> None: ...

class SendNmtResponse(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class SdoOptions(_message.Message):
    __slots__ = ("timeout_ms", "block")
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    BLOCK_FIELD_NUMBER: _ClassVar[int]
    timeout_ms: int
    block: bool
    def __init__(self, timeout_ms: _Optional[int] = ..., block: _Optional[bool] = ...) -> None: ...

class ReadSdoRequest(_message.Message):
    __slots__ = ("bus", "node", "index", "subindex", "type", "options", "object")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    TYPE_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    index: int
    subindex: int
    type: DataType
    options: SdoOptions
    object: str
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., index: _Optional[int] = ..., subindex: _Optional[int] = ..., type: _Optional[_Union[DataType, str]] = ..., options: _Optional[_Union[SdoOptions, _Mapping]] = ..., object: _Optional[str] = ...) -> None: ...

class ReadSdoResponse(_message.Message):
    __slots__ = ("raw", "value")
    RAW_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    raw: bytes
    value: Value
    def __init__(self, raw: _Optional[bytes] = ..., value: _Optional[_Union[Value, _Mapping]] = ...) -> None: ...

class WriteSdoRequest(_message.Message):
    __slots__ = ("bus", "node", "index", "subindex", "value", "raw", "options", "object", "force")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    RAW_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    FORCE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    index: int
    subindex: int
    value: Value
    raw: bytes
    options: SdoOptions
    object: str
    force: bool
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., index: _Optional[int] = ..., subindex: _Optional[int] = ..., value: _Optional[_Union[Value, _Mapping]] = ..., raw: _Optional[bytes] = ..., options: _Optional[_Union[SdoOptions, _Mapping]] = ..., object: _Optional[str] = ..., force: _Optional[bool] = ...) -> None: ...

class WriteSdoResponse(_message.Message):
    __slots__ = ("bytes",)
    BYTES_FIELD_NUMBER: _ClassVar[int]
    bytes: int
    def __init__(self, bytes: _Optional[int] = ...) -> None: ...

class SdoSessionRequest(_message.Message):
    __slots__ = ("id", "read", "write")
    ID_FIELD_NUMBER: _ClassVar[int]
    READ_FIELD_NUMBER: _ClassVar[int]
    WRITE_FIELD_NUMBER: _ClassVar[int]
    id: int
    read: ReadSdoRequest
    write: WriteSdoRequest
    def __init__(self, id: _Optional[int] = ..., read: _Optional[_Union[ReadSdoRequest, _Mapping]] = ..., write: _Optional[_Union[WriteSdoRequest, _Mapping]] = ...) -> None: ...

class SdoSessionAnswer(_message.Message):
    __slots__ = ("id", "read", "write", "error")
    ID_FIELD_NUMBER: _ClassVar[int]
    READ_FIELD_NUMBER: _ClassVar[int]
    WRITE_FIELD_NUMBER: _ClassVar[int]
    ERROR_FIELD_NUMBER: _ClassVar[int]
    id: int
    read: ReadSdoResponse
    write: WriteSdoResponse
    error: SdoSessionError
    def __init__(self, id: _Optional[int] = ..., read: _Optional[_Union[ReadSdoResponse, _Mapping]] = ..., write: _Optional[_Union[WriteSdoResponse, _Mapping]] = ..., error: _Optional[_Union[SdoSessionError, _Mapping]] = ...) -> None: ...

class SdoSessionError(_message.Message):
    __slots__ = ("code", "message", "reason", "metadata", "abort")
    class MetadataEntry(_message.Message):
        __slots__ = ("key", "value")
        KEY_FIELD_NUMBER: _ClassVar[int]
        VALUE_FIELD_NUMBER: _ClassVar[int]
        key: str
        value: str
        def __init__(self, key: _Optional[str] = ..., value: _Optional[str] = ...) -> None: ...
    CODE_FIELD_NUMBER: _ClassVar[int]
    MESSAGE_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    METADATA_FIELD_NUMBER: _ClassVar[int]
    ABORT_FIELD_NUMBER: _ClassVar[int]
    code: int
    message: str
    reason: str
    metadata: _containers.ScalarMap[str, str]
    abort: SdoAbortDetails
    def __init__(self, code: _Optional[int] = ..., message: _Optional[str] = ..., reason: _Optional[str] = ..., metadata: _Optional[_Mapping[str, str]] = ..., abort: _Optional[_Union[SdoAbortDetails, _Mapping]] = ...) -> None: ...

class ListObjectsRequest(_message.Message):
    __slots__ = ("bus", "node")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ...) -> None: ...

class ObjectInfo(_message.Message):
    __slots__ = ("index", "subindex", "name", "object_name", "sub_name", "object_type", "type", "type_code", "access", "pdo_mappable", "default_value", "default_text", "low_limit", "high_limit")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    OBJECT_NAME_FIELD_NUMBER: _ClassVar[int]
    SUB_NAME_FIELD_NUMBER: _ClassVar[int]
    OBJECT_TYPE_FIELD_NUMBER: _ClassVar[int]
    TYPE_FIELD_NUMBER: _ClassVar[int]
    TYPE_CODE_FIELD_NUMBER: _ClassVar[int]
    ACCESS_FIELD_NUMBER: _ClassVar[int]
    PDO_MAPPABLE_FIELD_NUMBER: _ClassVar[int]
    DEFAULT_VALUE_FIELD_NUMBER: _ClassVar[int]
    DEFAULT_TEXT_FIELD_NUMBER: _ClassVar[int]
    LOW_LIMIT_FIELD_NUMBER: _ClassVar[int]
    HIGH_LIMIT_FIELD_NUMBER: _ClassVar[int]
    index: int
    subindex: int
    name: str
    object_name: str
    sub_name: str
    object_type: str
    type: DataType
    type_code: int
    access: ObjectAccess
    pdo_mappable: bool
    default_value: Value
    default_text: str
    low_limit: Value
    high_limit: Value
    def __init__(self, index: _Optional[int] = ..., subindex: _Optional[int] = ..., name: _Optional[str] = ..., object_name: _Optional[str] = ..., sub_name: _Optional[str] = ..., object_type: _Optional[str] = ..., type: _Optional[_Union[DataType, str]] = ..., type_code: _Optional[int] = ..., access: _Optional[_Union[ObjectAccess, str]] = ..., pdo_mappable: _Optional[bool] = ..., default_value: _Optional[_Union[Value, _Mapping]] = ..., default_text: _Optional[str] = ..., low_limit: _Optional[_Union[Value, _Mapping]] = ..., high_limit: _Optional[_Union[Value, _Mapping]] = ...) -> None: ...

class ListObjectsResponse(_message.Message):
    __slots__ = ("objects",)
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[ObjectInfo]
    def __init__(self, objects: _Optional[_Iterable[_Union[ObjectInfo, _Mapping]]] = ...) -> None: ...

class ScanNetworkRequest(_message.Message):
    __slots__ = ("bus", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class ScanNetworkResponse(_message.Message):
    __slots__ = ("nodes",)
    NODES_FIELD_NUMBER: _ClassVar[int]
    nodes: _containers.RepeatedCompositeFieldContainer[Node]
    def __init__(self, nodes: _Optional[_Iterable[_Union[Node, _Mapping]]] = ...) -> None: ...

class StreamNodeEventsRequest(_message.Message):
    __slots__ = ("bus", "nodes")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODES_FIELD_NUMBER: _ClassVar[int]
    bus: str
    nodes: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, bus: _Optional[str] = ..., nodes: _Optional[_Iterable[int]] = ...) -> None: ...

class NodeEvent(_message.Message):
    __slots__ = ("bus", "node", "timestamp_ns", "boot_up", "state_changed", "heartbeat_lost", "heartbeat_recovered", "emcy", "lost", "boot_completed", "boot_failed", "guarding_toggle_error")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_NS_FIELD_NUMBER: _ClassVar[int]
    BOOT_UP_FIELD_NUMBER: _ClassVar[int]
    STATE_CHANGED_FIELD_NUMBER: _ClassVar[int]
    HEARTBEAT_LOST_FIELD_NUMBER: _ClassVar[int]
    HEARTBEAT_RECOVERED_FIELD_NUMBER: _ClassVar[int]
    EMCY_FIELD_NUMBER: _ClassVar[int]
    LOST_FIELD_NUMBER: _ClassVar[int]
    BOOT_COMPLETED_FIELD_NUMBER: _ClassVar[int]
    BOOT_FAILED_FIELD_NUMBER: _ClassVar[int]
    GUARDING_TOGGLE_ERROR_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    timestamp_ns: int
    boot_up: BootUp
    state_changed: StateChange
    heartbeat_lost: HeartbeatLost
    heartbeat_recovered: HeartbeatRecovered
    emcy: Emcy
    lost: EventsLost
    boot_completed: BootCompleted
    boot_failed: BootFailed
    guarding_toggle_error: GuardingToggleError
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., timestamp_ns: _Optional[int] = ..., boot_up: _Optional[_Union[BootUp, _Mapping]] = ..., state_changed: _Optional[_Union[StateChange, _Mapping]] = ..., heartbeat_lost: _Optional[_Union[HeartbeatLost, _Mapping]] = ..., heartbeat_recovered: _Optional[_Union[HeartbeatRecovered, _Mapping]] = ..., emcy: _Optional[_Union[Emcy, _Mapping]] = ..., lost: _Optional[_Union[EventsLost, _Mapping]] = ..., boot_completed: _Optional[_Union[BootCompleted, _Mapping]] = ..., boot_failed: _Optional[_Union[BootFailed, _Mapping]] = ..., guarding_toggle_error: _Optional[_Union[GuardingToggleError, _Mapping]] = ...) -> None: ...

class GuardingToggleError(_message.Message):
    __slots__ = ("data", "expected_toggle", "count")
    DATA_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_TOGGLE_FIELD_NUMBER: _ClassVar[int]
    COUNT_FIELD_NUMBER: _ClassVar[int]
    data: int
    expected_toggle: bool
    count: int
    def __init__(self, data: _Optional[int] = ..., expected_toggle: _Optional[bool] = ..., count: _Optional[int] = ...) -> None: ...

class BootCompleted(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class BootFailed(_message.Message):
    __slots__ = ("reason",)
    REASON_FIELD_NUMBER: _ClassVar[int]
    reason: str
    def __init__(self, reason: _Optional[str] = ...) -> None: ...

class StreamPdoRequest(_message.Message):
    __slots__ = ("bus", "nodes")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODES_FIELD_NUMBER: _ClassVar[int]
    bus: str
    nodes: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, bus: _Optional[str] = ..., nodes: _Optional[_Iterable[int]] = ...) -> None: ...

class PdoValue(_message.Message):
    __slots__ = ("index", "subindex", "name", "value")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    index: int
    subindex: int
    name: str
    value: Value
    def __init__(self, index: _Optional[int] = ..., subindex: _Optional[int] = ..., name: _Optional[str] = ..., value: _Optional[_Union[Value, _Mapping]] = ...) -> None: ...

class PdoMessage(_message.Message):
    __slots__ = ("bus", "node", "pdo", "cob_id", "timestamp_ns", "values", "lost_before")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    PDO_FIELD_NUMBER: _ClassVar[int]
    COB_ID_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_NS_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    LOST_BEFORE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    pdo: int
    cob_id: int
    timestamp_ns: int
    values: _containers.RepeatedCompositeFieldContainer[PdoValue]
    lost_before: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., pdo: _Optional[int] = ..., cob_id: _Optional[int] = ..., timestamp_ns: _Optional[int] = ..., values: _Optional[_Iterable[_Union[PdoValue, _Mapping]]] = ..., lost_before: _Optional[int] = ...) -> None: ...

class WritePdoRequest(_message.Message):
    __slots__ = ("bus", "node", "pdo", "values")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    PDO_FIELD_NUMBER: _ClassVar[int]
    VALUES_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    pdo: int
    values: _containers.RepeatedCompositeFieldContainer[PdoValue]
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., pdo: _Optional[int] = ..., values: _Optional[_Iterable[_Union[PdoValue, _Mapping]]] = ...) -> None: ...

class WritePdoResponse(_message.Message):
    __slots__ = ("data",)
    DATA_FIELD_NUMBER: _ClassVar[int]
    data: bytes
    def __init__(self, data: _Optional[bytes] = ...) -> None: ...

class PdoMappedObject(_message.Message):
    __slots__ = ("index", "subindex", "bits", "name", "object")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    BITS_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    index: int
    subindex: int
    bits: int
    name: str
    object: str
    def __init__(self, index: _Optional[int] = ..., subindex: _Optional[int] = ..., bits: _Optional[int] = ..., name: _Optional[str] = ..., object: _Optional[str] = ...) -> None: ...

class PdoConfiguration(_message.Message):
    __slots__ = ("kind", "pdo", "cob_id", "enabled", "transmission_type", "inhibit_time_100us", "event_timer_ms", "mapping")
    KIND_FIELD_NUMBER: _ClassVar[int]
    PDO_FIELD_NUMBER: _ClassVar[int]
    COB_ID_FIELD_NUMBER: _ClassVar[int]
    ENABLED_FIELD_NUMBER: _ClassVar[int]
    TRANSMISSION_TYPE_FIELD_NUMBER: _ClassVar[int]
    INHIBIT_TIME_100US_FIELD_NUMBER: _ClassVar[int]
    EVENT_TIMER_MS_FIELD_NUMBER: _ClassVar[int]
    MAPPING_FIELD_NUMBER: _ClassVar[int]
    kind: PdoKind
    pdo: int
    cob_id: int
    enabled: bool
    transmission_type: int
    inhibit_time_100us: int
    event_timer_ms: int
    mapping: _containers.RepeatedCompositeFieldContainer[PdoMappedObject]
    def __init__(self, kind: _Optional[_Union[PdoKind, str]] = ..., pdo: _Optional[int] = ..., cob_id: _Optional[int] = ..., enabled: _Optional[bool] = ..., transmission_type: _Optional[int] = ..., inhibit_time_100us: _Optional[int] = ..., event_timer_ms: _Optional[int] = ..., mapping: _Optional[_Iterable[_Union[PdoMappedObject, _Mapping]]] = ...) -> None: ...

class ReadPdoConfigRequest(_message.Message):
    __slots__ = ("bus", "node", "kind", "pdo", "options")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    PDO_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    kind: PdoKind
    pdo: int
    options: SdoOptions
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., kind: _Optional[_Union[PdoKind, str]] = ..., pdo: _Optional[int] = ..., options: _Optional[_Union[SdoOptions, _Mapping]] = ...) -> None: ...

class ReadPdoConfigResponse(_message.Message):
    __slots__ = ("pdos",)
    PDOS_FIELD_NUMBER: _ClassVar[int]
    pdos: _containers.RepeatedCompositeFieldContainer[PdoConfiguration]
    def __init__(self, pdos: _Optional[_Iterable[_Union[PdoConfiguration, _Mapping]]] = ...) -> None: ...

class ConfigurePdoRequest(_message.Message):
    __slots__ = ("bus", "node", "pdo", "options")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    PDO_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    pdo: PdoConfiguration
    options: SdoOptions
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., pdo: _Optional[_Union[PdoConfiguration, _Mapping]] = ..., options: _Optional[_Union[SdoOptions, _Mapping]] = ...) -> None: ...

class ConfigurePdoResponse(_message.Message):
    __slots__ = ("pdo", "writes")
    PDO_FIELD_NUMBER: _ClassVar[int]
    WRITES_FIELD_NUMBER: _ClassVar[int]
    pdo: PdoConfiguration
    writes: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, pdo: _Optional[_Union[PdoConfiguration, _Mapping]] = ..., writes: _Optional[_Iterable[str]] = ...) -> None: ...

class GetSyncRequest(_message.Message):
    __slots__ = ("bus",)
    BUS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    def __init__(self, bus: _Optional[str] = ...) -> None: ...

class SetSyncRequest(_message.Message):
    __slots__ = ("bus", "running", "period_us", "counter_overflow")
    BUS_FIELD_NUMBER: _ClassVar[int]
    RUNNING_FIELD_NUMBER: _ClassVar[int]
    PERIOD_US_FIELD_NUMBER: _ClassVar[int]
    COUNTER_OVERFLOW_FIELD_NUMBER: _ClassVar[int]
    bus: str
    running: bool
    period_us: int
    counter_overflow: int
    def __init__(self, bus: _Optional[str] = ..., running: _Optional[bool] = ..., period_us: _Optional[int] = ..., counter_overflow: _Optional[int] = ...) -> None: ...

class SyncStatus(_message.Message):
    __slots__ = ("bus", "running", "period_us", "counter_overflow", "sent", "skipped", "time_period_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    RUNNING_FIELD_NUMBER: _ClassVar[int]
    PERIOD_US_FIELD_NUMBER: _ClassVar[int]
    COUNTER_OVERFLOW_FIELD_NUMBER: _ClassVar[int]
    SENT_FIELD_NUMBER: _ClassVar[int]
    SKIPPED_FIELD_NUMBER: _ClassVar[int]
    TIME_PERIOD_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    running: bool
    period_us: int
    counter_overflow: int
    sent: int
    skipped: int
    time_period_ms: int
    def __init__(self, bus: _Optional[str] = ..., running: _Optional[bool] = ..., period_us: _Optional[int] = ..., counter_overflow: _Optional[int] = ..., sent: _Optional[int] = ..., skipped: _Optional[int] = ..., time_period_ms: _Optional[int] = ...) -> None: ...

class SetTimeRequest(_message.Message):
    __slots__ = ("bus", "send_now", "period_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    SEND_NOW_FIELD_NUMBER: _ClassVar[int]
    PERIOD_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    send_now: bool
    period_ms: int
    def __init__(self, bus: _Optional[str] = ..., send_now: _Optional[bool] = ..., period_ms: _Optional[int] = ...) -> None: ...

class TimeOfDay(_message.Message):
    __slots__ = ("ms_after_midnight", "days_since_1984", "unix_ms")
    MS_AFTER_MIDNIGHT_FIELD_NUMBER: _ClassVar[int]
    DAYS_SINCE_1984_FIELD_NUMBER: _ClassVar[int]
    UNIX_MS_FIELD_NUMBER: _ClassVar[int]
    ms_after_midnight: int
    days_since_1984: int
    unix_ms: int
    def __init__(self, ms_after_midnight: _Optional[int] = ..., days_since_1984: _Optional[int] = ..., unix_ms: _Optional[int] = ...) -> None: ...

class SetTimeResponse(_message.Message):
    __slots__ = ("sent", "time_period_ms")
    SENT_FIELD_NUMBER: _ClassVar[int]
    TIME_PERIOD_MS_FIELD_NUMBER: _ClassVar[int]
    sent: TimeOfDay
    time_period_ms: int
    def __init__(self, sent: _Optional[_Union[TimeOfDay, _Mapping]] = ..., time_period_ms: _Optional[int] = ...) -> None: ...

class ExportDcfRequest(_message.Message):
    __slots__ = ("bus", "node", "options")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    options: SdoOptions
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., options: _Optional[_Union[SdoOptions, _Mapping]] = ...) -> None: ...

class SkippedObject(_message.Message):
    __slots__ = ("index", "subindex", "reason")
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    index: int
    subindex: int
    reason: str
    def __init__(self, index: _Optional[int] = ..., subindex: _Optional[int] = ..., reason: _Optional[str] = ...) -> None: ...

class ExportDcfResponse(_message.Message):
    __slots__ = ("dcf", "objects_read", "skipped")
    DCF_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_READ_FIELD_NUMBER: _ClassVar[int]
    SKIPPED_FIELD_NUMBER: _ClassVar[int]
    dcf: str
    objects_read: int
    skipped: _containers.RepeatedCompositeFieldContainer[SkippedObject]
    def __init__(self, dcf: _Optional[str] = ..., objects_read: _Optional[int] = ..., skipped: _Optional[_Iterable[_Union[SkippedObject, _Mapping]]] = ...) -> None: ...

class BootUp(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class StateChange(_message.Message):
    __slots__ = ("to",)
    FROM_FIELD_NUMBER: _ClassVar[int]
    TO_FIELD_NUMBER: _ClassVar[int]
    to: NmtState
    def __init__(self, to: _Optional[_Union[NmtState, str]] = ..., **kwargs) -> None: ...

class HeartbeatLost(_message.Message):
    __slots__ = ("timeout_ms", "monitoring")
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    MONITORING_FIELD_NUMBER: _ClassVar[int]
    timeout_ms: int
    monitoring: LifeMonitoring
    def __init__(self, timeout_ms: _Optional[int] = ..., monitoring: _Optional[_Union[LifeMonitoring, str]] = ...) -> None: ...

class HeartbeatRecovered(_message.Message):
    __slots__ = ("state", "silent_ms", "monitoring")
    STATE_FIELD_NUMBER: _ClassVar[int]
    SILENT_MS_FIELD_NUMBER: _ClassVar[int]
    MONITORING_FIELD_NUMBER: _ClassVar[int]
    state: NmtState
    silent_ms: int
    monitoring: LifeMonitoring
    def __init__(self, state: _Optional[_Union[NmtState, str]] = ..., silent_ms: _Optional[int] = ..., monitoring: _Optional[_Union[LifeMonitoring, str]] = ...) -> None: ...

class EventsLost(_message.Message):
    __slots__ = ("count",)
    COUNT_FIELD_NUMBER: _ClassVar[int]
    count: int
    def __init__(self, count: _Optional[int] = ...) -> None: ...

class SdoAbortDetails(_message.Message):
    __slots__ = ("code", "name", "index", "subindex", "from_node")
    CODE_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    FROM_NODE_FIELD_NUMBER: _ClassVar[int]
    code: int
    name: str
    index: int
    subindex: int
    from_node: bool
    def __init__(self, code: _Optional[int] = ..., name: _Optional[str] = ..., index: _Optional[int] = ..., subindex: _Optional[int] = ..., from_node: _Optional[bool] = ...) -> None: ...

class ListSdoTransfersRequest(_message.Message):
    __slots__ = ("bus",)
    BUS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    def __init__(self, bus: _Optional[str] = ...) -> None: ...

class SdoTransfer(_message.Message):
    __slots__ = ("node", "index", "subindex", "upload", "protocol", "transferred", "total")
    NODE_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    SUBINDEX_FIELD_NUMBER: _ClassVar[int]
    UPLOAD_FIELD_NUMBER: _ClassVar[int]
    PROTOCOL_FIELD_NUMBER: _ClassVar[int]
    TRANSFERRED_FIELD_NUMBER: _ClassVar[int]
    TOTAL_FIELD_NUMBER: _ClassVar[int]
    node: int
    index: int
    subindex: int
    upload: bool
    protocol: str
    transferred: int
    total: int
    def __init__(self, node: _Optional[int] = ..., index: _Optional[int] = ..., subindex: _Optional[int] = ..., upload: _Optional[bool] = ..., protocol: _Optional[str] = ..., transferred: _Optional[int] = ..., total: _Optional[int] = ...) -> None: ...

class ListSdoTransfersResponse(_message.Message):
    __slots__ = ("transfers",)
    TRANSFERS_FIELD_NUMBER: _ClassVar[int]
    transfers: _containers.RepeatedCompositeFieldContainer[SdoTransfer]
    def __init__(self, transfers: _Optional[_Iterable[_Union[SdoTransfer, _Mapping]]] = ...) -> None: ...

class DownloadProgramRequest(_message.Message):
    __slots__ = ("bus", "node", "image", "program", "expected_identification", "clear", "flash_timeout_ms", "boot_timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    IMAGE_FIELD_NUMBER: _ClassVar[int]
    PROGRAM_FIELD_NUMBER: _ClassVar[int]
    EXPECTED_IDENTIFICATION_FIELD_NUMBER: _ClassVar[int]
    CLEAR_FIELD_NUMBER: _ClassVar[int]
    FLASH_TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    BOOT_TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    image: bytes
    program: int
    expected_identification: int
    clear: bool
    flash_timeout_ms: int
    boot_timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., image: _Optional[bytes] = ..., program: _Optional[int] = ..., expected_identification: _Optional[int] = ..., clear: _Optional[bool] = ..., flash_timeout_ms: _Optional[int] = ..., boot_timeout_ms: _Optional[int] = ...) -> None: ...

class DownloadProgramProgress(_message.Message):
    __slots__ = ("step", "bytes_done", "bytes_total", "outcome")
    STEP_FIELD_NUMBER: _ClassVar[int]
    BYTES_DONE_FIELD_NUMBER: _ClassVar[int]
    BYTES_TOTAL_FIELD_NUMBER: _ClassVar[int]
    OUTCOME_FIELD_NUMBER: _ClassVar[int]
    step: ProgramStep
    bytes_done: int
    bytes_total: int
    outcome: DownloadProgramOutcome
    def __init__(self, step: _Optional[_Union[ProgramStep, str]] = ..., bytes_done: _Optional[int] = ..., bytes_total: _Optional[int] = ..., outcome: _Optional[_Union[DownloadProgramOutcome, _Mapping]] = ...) -> None: ...

class DownloadProgramOutcome(_message.Message):
    __slots__ = ("old_identification", "new_identification", "bytes", "duration_ms", "data_duration_ms", "data_bytes_per_second")
    OLD_IDENTIFICATION_FIELD_NUMBER: _ClassVar[int]
    NEW_IDENTIFICATION_FIELD_NUMBER: _ClassVar[int]
    BYTES_FIELD_NUMBER: _ClassVar[int]
    DURATION_MS_FIELD_NUMBER: _ClassVar[int]
    DATA_DURATION_MS_FIELD_NUMBER: _ClassVar[int]
    DATA_BYTES_PER_SECOND_FIELD_NUMBER: _ClassVar[int]
    old_identification: int
    new_identification: int
    bytes: int
    duration_ms: int
    data_duration_ms: int
    data_bytes_per_second: float
    def __init__(self, old_identification: _Optional[int] = ..., new_identification: _Optional[int] = ..., bytes: _Optional[int] = ..., duration_ms: _Optional[int] = ..., data_duration_ms: _Optional[int] = ..., data_bytes_per_second: _Optional[float] = ...) -> None: ...
