from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class HandwheelMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    HANDWHEEL_MODE_UNSPECIFIED: _ClassVar[HandwheelMode]
    HANDWHEEL_MODE_AUTOMATIC: _ClassVar[HandwheelMode]
    HANDWHEEL_MODE_MANUAL: _ClassVar[HandwheelMode]

class WheelAxis(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    WHEEL_AXIS_UNSPECIFIED: _ClassVar[WheelAxis]
    WHEEL_AXIS_X: _ClassVar[WheelAxis]
    WHEEL_AXIS_Y: _ClassVar[WheelAxis]
    WHEEL_AXIS_Z: _ClassVar[WheelAxis]
    WHEEL_AXIS_W: _ClassVar[WheelAxis]
    WHEEL_AXIS_V: _ClassVar[WheelAxis]

class CounterLayout(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    COUNTER_LAYOUT_UNSPECIFIED: _ClassVar[CounterLayout]
    COUNTER_LAYOUT_NIBBLE: _ClassVar[CounterLayout]
    COUNTER_LAYOUT_BITS6_7: _ClassVar[CounterLayout]

class SimulatedDeviceKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SIMULATED_DEVICE_KIND_UNSPECIFIED: _ClassVar[SimulatedDeviceKind]
    SIMULATED_DEVICE_KIND_NODE: _ClassVar[SimulatedDeviceKind]
    SIMULATED_DEVICE_KIND_DRIVE: _ClassVar[SimulatedDeviceKind]
    SIMULATED_DEVICE_KIND_HANDWHEEL: _ClassVar[SimulatedDeviceKind]
HANDWHEEL_MODE_UNSPECIFIED: HandwheelMode
HANDWHEEL_MODE_AUTOMATIC: HandwheelMode
HANDWHEEL_MODE_MANUAL: HandwheelMode
WHEEL_AXIS_UNSPECIFIED: WheelAxis
WHEEL_AXIS_X: WheelAxis
WHEEL_AXIS_Y: WheelAxis
WHEEL_AXIS_Z: WheelAxis
WHEEL_AXIS_W: WheelAxis
WHEEL_AXIS_V: WheelAxis
COUNTER_LAYOUT_UNSPECIFIED: CounterLayout
COUNTER_LAYOUT_NIBBLE: CounterLayout
COUNTER_LAYOUT_BITS6_7: CounterLayout
SIMULATED_DEVICE_KIND_UNSPECIFIED: SimulatedDeviceKind
SIMULATED_DEVICE_KIND_NODE: SimulatedDeviceKind
SIMULATED_DEVICE_KIND_DRIVE: SimulatedDeviceKind
SIMULATED_DEVICE_KIND_HANDWHEEL: SimulatedDeviceKind

class FeedStats(_message.Message):
    __slots__ = ("frames", "positive_units", "negative_units", "gaps", "compensated_units", "duplicates", "bad_frames", "baselines", "baseline_resets")
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    POSITIVE_UNITS_FIELD_NUMBER: _ClassVar[int]
    NEGATIVE_UNITS_FIELD_NUMBER: _ClassVar[int]
    GAPS_FIELD_NUMBER: _ClassVar[int]
    COMPENSATED_UNITS_FIELD_NUMBER: _ClassVar[int]
    DUPLICATES_FIELD_NUMBER: _ClassVar[int]
    BAD_FRAMES_FIELD_NUMBER: _ClassVar[int]
    BASELINES_FIELD_NUMBER: _ClassVar[int]
    BASELINE_RESETS_FIELD_NUMBER: _ClassVar[int]
    frames: int
    positive_units: _containers.RepeatedScalarFieldContainer[int]
    negative_units: _containers.RepeatedScalarFieldContainer[int]
    gaps: int
    compensated_units: int
    duplicates: int
    bad_frames: int
    baselines: int
    baseline_resets: int
    def __init__(self, frames: _Optional[int] = ..., positive_units: _Optional[_Iterable[int]] = ..., negative_units: _Optional[_Iterable[int]] = ..., gaps: _Optional[int] = ..., compensated_units: _Optional[int] = ..., duplicates: _Optional[int] = ..., bad_frames: _Optional[int] = ..., baselines: _Optional[int] = ..., baseline_resets: _Optional[int] = ...) -> None: ...

class BindingStats(_message.Message):
    __slots__ = ("executed_units", "dropped_backlog", "dropped_not_enabled", "dropped_not_controlled", "dropped_unbound", "blocked", "units", "dropped_not_manual", "pending_units")
    EXECUTED_UNITS_FIELD_NUMBER: _ClassVar[int]
    DROPPED_BACKLOG_FIELD_NUMBER: _ClassVar[int]
    DROPPED_NOT_ENABLED_FIELD_NUMBER: _ClassVar[int]
    DROPPED_NOT_CONTROLLED_FIELD_NUMBER: _ClassVar[int]
    DROPPED_UNBOUND_FIELD_NUMBER: _ClassVar[int]
    BLOCKED_FIELD_NUMBER: _ClassVar[int]
    UNITS_FIELD_NUMBER: _ClassVar[int]
    DROPPED_NOT_MANUAL_FIELD_NUMBER: _ClassVar[int]
    PENDING_UNITS_FIELD_NUMBER: _ClassVar[int]
    executed_units: int
    dropped_backlog: int
    dropped_not_enabled: int
    dropped_not_controlled: int
    dropped_unbound: int
    blocked: str
    units: int
    dropped_not_manual: int
    pending_units: int
    def __init__(self, executed_units: _Optional[int] = ..., dropped_backlog: _Optional[int] = ..., dropped_not_enabled: _Optional[int] = ..., dropped_not_controlled: _Optional[int] = ..., dropped_unbound: _Optional[int] = ..., blocked: _Optional[str] = ..., units: _Optional[int] = ..., dropped_not_manual: _Optional[int] = ..., pending_units: _Optional[int] = ...) -> None: ...

class AxisBinding(_message.Message):
    __slots__ = ("wheel_axis", "axis", "distance_per_unit")
    WHEEL_AXIS_FIELD_NUMBER: _ClassVar[int]
    AXIS_FIELD_NUMBER: _ClassVar[int]
    DISTANCE_PER_UNIT_FIELD_NUMBER: _ClassVar[int]
    wheel_axis: WheelAxis
    axis: str
    distance_per_unit: float
    def __init__(self, wheel_axis: _Optional[_Union[WheelAxis, str]] = ..., axis: _Optional[str] = ..., distance_per_unit: _Optional[float] = ...) -> None: ...

class Handwheel(_message.Message):
    __slots__ = ("name", "bus", "node", "counter_layout", "mode", "node_lost", "simulated", "stats", "bindings", "max_units_per_s", "stop_within_ms", "binding")
    NAME_FIELD_NUMBER: _ClassVar[int]
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    COUNTER_LAYOUT_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    NODE_LOST_FIELD_NUMBER: _ClassVar[int]
    SIMULATED_FIELD_NUMBER: _ClassVar[int]
    STATS_FIELD_NUMBER: _ClassVar[int]
    BINDINGS_FIELD_NUMBER: _ClassVar[int]
    MAX_UNITS_PER_S_FIELD_NUMBER: _ClassVar[int]
    STOP_WITHIN_MS_FIELD_NUMBER: _ClassVar[int]
    BINDING_FIELD_NUMBER: _ClassVar[int]
    name: str
    bus: str
    node: int
    counter_layout: CounterLayout
    mode: HandwheelMode
    node_lost: bool
    simulated: bool
    stats: FeedStats
    bindings: _containers.RepeatedCompositeFieldContainer[AxisBinding]
    max_units_per_s: float
    stop_within_ms: int
    binding: BindingStats
    def __init__(self, name: _Optional[str] = ..., bus: _Optional[str] = ..., node: _Optional[int] = ..., counter_layout: _Optional[_Union[CounterLayout, str]] = ..., mode: _Optional[_Union[HandwheelMode, str]] = ..., node_lost: _Optional[bool] = ..., simulated: _Optional[bool] = ..., stats: _Optional[_Union[FeedStats, _Mapping]] = ..., bindings: _Optional[_Iterable[_Union[AxisBinding, _Mapping]]] = ..., max_units_per_s: _Optional[float] = ..., stop_within_ms: _Optional[int] = ..., binding: _Optional[_Union[BindingStats, _Mapping]] = ...) -> None: ...

class ListHandwheelsRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListHandwheelsResponse(_message.Message):
    __slots__ = ("handwheels",)
    HANDWHEELS_FIELD_NUMBER: _ClassVar[int]
    handwheels: _containers.RepeatedCompositeFieldContainer[Handwheel]
    def __init__(self, handwheels: _Optional[_Iterable[_Union[Handwheel, _Mapping]]] = ...) -> None: ...

class GetHandwheelRequest(_message.Message):
    __slots__ = ("handwheel",)
    HANDWHEEL_FIELD_NUMBER: _ClassVar[int]
    handwheel: str
    def __init__(self, handwheel: _Optional[str] = ...) -> None: ...

class SetModeRequest(_message.Message):
    __slots__ = ("handwheel", "mode")
    HANDWHEEL_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    handwheel: str
    mode: HandwheelMode
    def __init__(self, handwheel: _Optional[str] = ..., mode: _Optional[_Union[HandwheelMode, str]] = ...) -> None: ...

class StreamFeedRequest(_message.Message):
    __slots__ = ("handwheels", "coalesce_ms")
    HANDWHEELS_FIELD_NUMBER: _ClassVar[int]
    COALESCE_MS_FIELD_NUMBER: _ClassVar[int]
    handwheels: _containers.RepeatedScalarFieldContainer[str]
    coalesce_ms: int
    def __init__(self, handwheels: _Optional[_Iterable[str]] = ..., coalesce_ms: _Optional[int] = ...) -> None: ...

class FeedEventBatch(_message.Message):
    __slots__ = ("events",)
    EVENTS_FIELD_NUMBER: _ClassVar[int]
    events: _containers.RepeatedCompositeFieldContainer[FeedEvent]
    def __init__(self, events: _Optional[_Iterable[_Union[FeedEvent, _Mapping]]] = ...) -> None: ...

class FeedEvent(_message.Message):
    __slots__ = ("handwheel", "timestamp_us", "axis", "direction", "units", "compensated", "sequence", "gap", "duplicate", "compensated_flag", "baseline", "bad", "note", "raw", "frames", "lost_before")
    HANDWHEEL_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_US_FIELD_NUMBER: _ClassVar[int]
    AXIS_FIELD_NUMBER: _ClassVar[int]
    DIRECTION_FIELD_NUMBER: _ClassVar[int]
    UNITS_FIELD_NUMBER: _ClassVar[int]
    COMPENSATED_FIELD_NUMBER: _ClassVar[int]
    SEQUENCE_FIELD_NUMBER: _ClassVar[int]
    GAP_FIELD_NUMBER: _ClassVar[int]
    DUPLICATE_FIELD_NUMBER: _ClassVar[int]
    COMPENSATED_FLAG_FIELD_NUMBER: _ClassVar[int]
    BASELINE_FIELD_NUMBER: _ClassVar[int]
    BAD_FIELD_NUMBER: _ClassVar[int]
    NOTE_FIELD_NUMBER: _ClassVar[int]
    RAW_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    LOST_BEFORE_FIELD_NUMBER: _ClassVar[int]
    handwheel: str
    timestamp_us: int
    axis: WheelAxis
    direction: int
    units: int
    compensated: int
    sequence: int
    gap: int
    duplicate: bool
    compensated_flag: bool
    baseline: bool
    bad: bool
    note: str
    raw: int
    frames: int
    lost_before: int
    def __init__(self, handwheel: _Optional[str] = ..., timestamp_us: _Optional[int] = ..., axis: _Optional[_Union[WheelAxis, str]] = ..., direction: _Optional[int] = ..., units: _Optional[int] = ..., compensated: _Optional[int] = ..., sequence: _Optional[int] = ..., gap: _Optional[int] = ..., duplicate: _Optional[bool] = ..., compensated_flag: _Optional[bool] = ..., baseline: _Optional[bool] = ..., bad: _Optional[bool] = ..., note: _Optional[str] = ..., raw: _Optional[int] = ..., frames: _Optional[int] = ..., lost_before: _Optional[int] = ...) -> None: ...

class TurnHandwheelRequest(_message.Message):
    __slots__ = ("handwheel", "detents", "axis", "multiplier", "loss", "max_consecutive_loss")
    HANDWHEEL_FIELD_NUMBER: _ClassVar[int]
    DETENTS_FIELD_NUMBER: _ClassVar[int]
    AXIS_FIELD_NUMBER: _ClassVar[int]
    MULTIPLIER_FIELD_NUMBER: _ClassVar[int]
    LOSS_FIELD_NUMBER: _ClassVar[int]
    MAX_CONSECUTIVE_LOSS_FIELD_NUMBER: _ClassVar[int]
    handwheel: str
    detents: int
    axis: WheelAxis
    multiplier: int
    loss: float
    max_consecutive_loss: int
    def __init__(self, handwheel: _Optional[str] = ..., detents: _Optional[int] = ..., axis: _Optional[_Union[WheelAxis, str]] = ..., multiplier: _Optional[int] = ..., loss: _Optional[float] = ..., max_consecutive_loss: _Optional[int] = ...) -> None: ...

class TurnHandwheelResponse(_message.Message):
    __slots__ = ("pending_units", "discarded_units")
    PENDING_UNITS_FIELD_NUMBER: _ClassVar[int]
    DISCARDED_UNITS_FIELD_NUMBER: _ClassVar[int]
    pending_units: int
    discarded_units: int
    def __init__(self, pending_units: _Optional[int] = ..., discarded_units: _Optional[int] = ...) -> None: ...

class ListSimulatedDevicesRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListSimulatedDevicesResponse(_message.Message):
    __slots__ = ("devices",)
    DEVICES_FIELD_NUMBER: _ClassVar[int]
    devices: _containers.RepeatedCompositeFieldContainer[SimulatedDevice]
    def __init__(self, devices: _Optional[_Iterable[_Union[SimulatedDevice, _Mapping]]] = ...) -> None: ...

class SimulatedDevice(_message.Message):
    __slots__ = ("bus", "node", "kind", "powered", "nmt_state")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    KIND_FIELD_NUMBER: _ClassVar[int]
    POWERED_FIELD_NUMBER: _ClassVar[int]
    NMT_STATE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    kind: SimulatedDeviceKind
    powered: bool
    nmt_state: str
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., kind: _Optional[_Union[SimulatedDeviceKind, str]] = ..., powered: _Optional[bool] = ..., nmt_state: _Optional[str] = ...) -> None: ...

class BusFaults(_message.Message):
    __slots__ = ("bus", "drop_probability", "drop_ids", "delay_us", "bus_off", "dropped_by_fault")
    BUS_FIELD_NUMBER: _ClassVar[int]
    DROP_PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    DROP_IDS_FIELD_NUMBER: _ClassVar[int]
    DELAY_US_FIELD_NUMBER: _ClassVar[int]
    BUS_OFF_FIELD_NUMBER: _ClassVar[int]
    DROPPED_BY_FAULT_FIELD_NUMBER: _ClassVar[int]
    bus: str
    drop_probability: float
    drop_ids: _containers.RepeatedScalarFieldContainer[int]
    delay_us: int
    bus_off: bool
    dropped_by_fault: int
    def __init__(self, bus: _Optional[str] = ..., drop_probability: _Optional[float] = ..., drop_ids: _Optional[_Iterable[int]] = ..., delay_us: _Optional[int] = ..., bus_off: _Optional[bool] = ..., dropped_by_fault: _Optional[int] = ...) -> None: ...

class SetBusFaultsRequest(_message.Message):
    __slots__ = ("bus", "drop_probability", "drop_ids", "delay_us")
    BUS_FIELD_NUMBER: _ClassVar[int]
    DROP_PROBABILITY_FIELD_NUMBER: _ClassVar[int]
    DROP_IDS_FIELD_NUMBER: _ClassVar[int]
    DELAY_US_FIELD_NUMBER: _ClassVar[int]
    bus: str
    drop_probability: float
    drop_ids: _containers.RepeatedScalarFieldContainer[int]
    delay_us: int
    def __init__(self, bus: _Optional[str] = ..., drop_probability: _Optional[float] = ..., drop_ids: _Optional[_Iterable[int]] = ..., delay_us: _Optional[int] = ...) -> None: ...

class GetBusFaultsRequest(_message.Message):
    __slots__ = ("bus",)
    BUS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    def __init__(self, bus: _Optional[str] = ...) -> None: ...

class SetBusOffRequest(_message.Message):
    __slots__ = ("bus", "bus_off")
    BUS_FIELD_NUMBER: _ClassVar[int]
    BUS_OFF_FIELD_NUMBER: _ClassVar[int]
    bus: str
    bus_off: bool
    def __init__(self, bus: _Optional[str] = ..., bus_off: _Optional[bool] = ...) -> None: ...

class PowerCycleDeviceRequest(_message.Message):
    __slots__ = ("bus", "node", "off_ms")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    OFF_MS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    off_ms: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., off_ms: _Optional[int] = ...) -> None: ...

class SendEmcyRequest(_message.Message):
    __slots__ = ("bus", "node", "code", "error_register", "manufacturer")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    ERROR_REGISTER_FIELD_NUMBER: _ClassVar[int]
    MANUFACTURER_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    code: int
    error_register: int
    manufacturer: bytes
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., code: _Optional[int] = ..., error_register: _Optional[int] = ..., manufacturer: _Optional[bytes] = ...) -> None: ...

class RaiseDriveFaultRequest(_message.Message):
    __slots__ = ("bus", "node", "code")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    CODE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    code: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., code: _Optional[int] = ...) -> None: ...

class SetIoInputsRequest(_message.Message):
    __slots__ = ("bus", "node", "digital", "analogue")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    DIGITAL_FIELD_NUMBER: _ClassVar[int]
    ANALOGUE_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    digital: bytes
    analogue: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., digital: _Optional[bytes] = ..., analogue: _Optional[_Iterable[int]] = ...) -> None: ...

class SetIoInputsResponse(_message.Message):
    __slots__ = ("device", "digital", "analogue")
    DEVICE_FIELD_NUMBER: _ClassVar[int]
    DIGITAL_FIELD_NUMBER: _ClassVar[int]
    ANALOGUE_FIELD_NUMBER: _ClassVar[int]
    device: SimulatedDevice
    digital: bytes
    analogue: _containers.RepeatedScalarFieldContainer[int]
    def __init__(self, device: _Optional[_Union[SimulatedDevice, _Mapping]] = ..., digital: _Optional[bytes] = ..., analogue: _Optional[_Iterable[int]] = ...) -> None: ...

class SetProgramFaultsRequest(_message.Message):
    __slots__ = ("bus", "node", "flash_error", "abort_at_byte", "abort_code", "no_boot")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    FLASH_ERROR_FIELD_NUMBER: _ClassVar[int]
    ABORT_AT_BYTE_FIELD_NUMBER: _ClassVar[int]
    ABORT_CODE_FIELD_NUMBER: _ClassVar[int]
    NO_BOOT_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    flash_error: int
    abort_at_byte: int
    abort_code: int
    no_boot: bool
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., flash_error: _Optional[int] = ..., abort_at_byte: _Optional[int] = ..., abort_code: _Optional[int] = ..., no_boot: _Optional[bool] = ...) -> None: ...

class ProgramFaults(_message.Message):
    __slots__ = ("bus", "node", "flash_error", "abort_at_byte", "abort_code", "no_boot", "identification", "running", "downloads")
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    FLASH_ERROR_FIELD_NUMBER: _ClassVar[int]
    ABORT_AT_BYTE_FIELD_NUMBER: _ClassVar[int]
    ABORT_CODE_FIELD_NUMBER: _ClassVar[int]
    NO_BOOT_FIELD_NUMBER: _ClassVar[int]
    IDENTIFICATION_FIELD_NUMBER: _ClassVar[int]
    RUNNING_FIELD_NUMBER: _ClassVar[int]
    DOWNLOADS_FIELD_NUMBER: _ClassVar[int]
    bus: str
    node: int
    flash_error: int
    abort_at_byte: int
    abort_code: int
    no_boot: bool
    identification: int
    running: bool
    downloads: int
    def __init__(self, bus: _Optional[str] = ..., node: _Optional[int] = ..., flash_error: _Optional[int] = ..., abort_at_byte: _Optional[int] = ..., abort_code: _Optional[int] = ..., no_boot: _Optional[bool] = ..., identification: _Optional[int] = ..., running: _Optional[bool] = ..., downloads: _Optional[int] = ...) -> None: ...
