from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class LssMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    LSS_MODE_WAITING: _ClassVar[LssMode]
    LSS_MODE_CONFIGURATION: _ClassVar[LssMode]
LSS_MODE_WAITING: LssMode
LSS_MODE_CONFIGURATION: LssMode

class LssIdentity(_message.Message):
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

class LssAck(_message.Message):
    __slots__ = ("confirmed",)
    CONFIRMED_FIELD_NUMBER: _ClassVar[int]
    confirmed: bool
    def __init__(self, confirmed: _Optional[bool] = ...) -> None: ...

class FastscanRequest(_message.Message):
    __slots__ = ("bus", "step_time_ms", "max_devices")
    BUS_FIELD_NUMBER: _ClassVar[int]
    STEP_TIME_MS_FIELD_NUMBER: _ClassVar[int]
    MAX_DEVICES_FIELD_NUMBER: _ClassVar[int]
    bus: str
    step_time_ms: int
    max_devices: int
    def __init__(self, bus: _Optional[str] = ..., step_time_ms: _Optional[int] = ..., max_devices: _Optional[int] = ...) -> None: ...

class FastscanResponse(_message.Message):
    __slots__ = ("devices", "elapsed_ms")
    DEVICES_FIELD_NUMBER: _ClassVar[int]
    ELAPSED_MS_FIELD_NUMBER: _ClassVar[int]
    devices: _containers.RepeatedCompositeFieldContainer[LssIdentity]
    elapsed_ms: int
    def __init__(self, devices: _Optional[_Iterable[_Union[LssIdentity, _Mapping]]] = ..., elapsed_ms: _Optional[int] = ...) -> None: ...

class SwitchGlobalRequest(_message.Message):
    __slots__ = ("bus", "mode")
    BUS_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    mode: LssMode
    def __init__(self, bus: _Optional[str] = ..., mode: _Optional[_Union[LssMode, str]] = ...) -> None: ...

class SwitchSelectiveRequest(_message.Message):
    __slots__ = ("bus", "identity", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    IDENTITY_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    identity: LssIdentity
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., identity: _Optional[_Union[LssIdentity, _Mapping]] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class ConfigureNodeIdRequest(_message.Message):
    __slots__ = ("bus", "node_id", "timeout_ms", "force")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_ID_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    FORCE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node_id: int
    timeout_ms: int
    force: bool
    def __init__(self, bus: _Optional[str] = ..., node_id: _Optional[int] = ..., timeout_ms: _Optional[int] = ..., force: _Optional[bool] = ...) -> None: ...

class ConfigureBitTimingRequest(_message.Message):
    __slots__ = ("bus", "table", "index", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    TABLE_FIELD_NUMBER: _ClassVar[int]
    INDEX_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    table: int
    index: int
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., table: _Optional[int] = ..., index: _Optional[int] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class ActivateBitTimingRequest(_message.Message):
    __slots__ = ("bus", "switch_delay_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    SWITCH_DELAY_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    switch_delay_ms: int
    def __init__(self, bus: _Optional[str] = ..., switch_delay_ms: _Optional[int] = ...) -> None: ...

class StoreConfigurationRequest(_message.Message):
    __slots__ = ("bus", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class InquireRequest(_message.Message):
    __slots__ = ("bus", "identity", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    IDENTITY_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    identity: LssIdentity
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., identity: _Optional[_Union[LssIdentity, _Mapping]] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class InquireResponse(_message.Message):
    __slots__ = ("identity", "node_id")
    IDENTITY_FIELD_NUMBER: _ClassVar[int]
    NODE_ID_FIELD_NUMBER: _ClassVar[int]
    identity: LssIdentity
    node_id: int
    def __init__(self, identity: _Optional[_Union[LssIdentity, _Mapping]] = ..., node_id: _Optional[int] = ...) -> None: ...

class IdentifyRemoteRequest(_message.Message):
    __slots__ = ("bus", "vendor_id", "product_code", "revision_low", "revision_high", "serial_low", "serial_high", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    VENDOR_ID_FIELD_NUMBER: _ClassVar[int]
    PRODUCT_CODE_FIELD_NUMBER: _ClassVar[int]
    REVISION_LOW_FIELD_NUMBER: _ClassVar[int]
    REVISION_HIGH_FIELD_NUMBER: _ClassVar[int]
    SERIAL_LOW_FIELD_NUMBER: _ClassVar[int]
    SERIAL_HIGH_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    vendor_id: int
    product_code: int
    revision_low: int
    revision_high: int
    serial_low: int
    serial_high: int
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., vendor_id: _Optional[int] = ..., product_code: _Optional[int] = ..., revision_low: _Optional[int] = ..., revision_high: _Optional[int] = ..., serial_low: _Optional[int] = ..., serial_high: _Optional[int] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class IdentifyNonConfiguredRequest(_message.Message):
    __slots__ = ("bus", "timeout_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    timeout_ms: int
    def __init__(self, bus: _Optional[str] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class IdentifyResponse(_message.Message):
    __slots__ = ("present",)
    PRESENT_FIELD_NUMBER: _ClassVar[int]
    present: bool
    def __init__(self, present: _Optional[bool] = ...) -> None: ...

class AssignNodeIdRequest(_message.Message):
    __slots__ = ("bus", "identity", "serial", "node_id", "store", "timeout_ms", "force")
    BUS_FIELD_NUMBER: _ClassVar[int]
    IDENTITY_FIELD_NUMBER: _ClassVar[int]
    SERIAL_FIELD_NUMBER: _ClassVar[int]
    NODE_ID_FIELD_NUMBER: _ClassVar[int]
    STORE_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    FORCE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    identity: LssIdentity
    serial: int
    node_id: int
    store: bool
    timeout_ms: int
    force: bool
    def __init__(self, bus: _Optional[str] = ..., identity: _Optional[_Union[LssIdentity, _Mapping]] = ..., serial: _Optional[int] = ..., node_id: _Optional[int] = ..., store: _Optional[bool] = ..., timeout_ms: _Optional[int] = ..., force: _Optional[bool] = ...) -> None: ...

class AssignNodeIdResponse(_message.Message):
    __slots__ = ("identity", "previous_node_id", "node_id", "stored")
    IDENTITY_FIELD_NUMBER: _ClassVar[int]
    PREVIOUS_NODE_ID_FIELD_NUMBER: _ClassVar[int]
    NODE_ID_FIELD_NUMBER: _ClassVar[int]
    STORED_FIELD_NUMBER: _ClassVar[int]
    identity: LssIdentity
    previous_node_id: int
    node_id: int
    stored: bool
    def __init__(self, identity: _Optional[_Union[LssIdentity, _Mapping]] = ..., previous_node_id: _Optional[int] = ..., node_id: _Optional[int] = ..., stored: _Optional[bool] = ...) -> None: ...
