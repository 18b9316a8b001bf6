from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class CansmcPhase(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CANSMC_PHASE_UNSPECIFIED: _ClassVar[CansmcPhase]
    CANSMC_PHASE_IDLE: _ClassVar[CansmcPhase]
    CANSMC_PHASE_P0: _ClassVar[CansmcPhase]
    CANSMC_PHASE_P1: _ClassVar[CansmcPhase]
    CANSMC_PHASE_P2: _ClassVar[CansmcPhase]
    CANSMC_PHASE_FAILED: _ClassVar[CansmcPhase]

class CansmcSlaveState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    CANSMC_SLAVE_STATE_UNSPECIFIED: _ClassVar[CansmcSlaveState]
    CANSMC_SLAVE_STATE_CONNECTING: _ClassVar[CansmcSlaveState]
    CANSMC_SLAVE_STATE_CONNECTED: _ClassVar[CansmcSlaveState]
    CANSMC_SLAVE_STATE_MISSING: _ClassVar[CansmcSlaveState]
    CANSMC_SLAVE_STATE_OPERATIONAL: _ClassVar[CansmcSlaveState]
    CANSMC_SLAVE_STATE_LOST: _ClassVar[CansmcSlaveState]
CANSMC_PHASE_UNSPECIFIED: CansmcPhase
CANSMC_PHASE_IDLE: CansmcPhase
CANSMC_PHASE_P0: CansmcPhase
CANSMC_PHASE_P1: CansmcPhase
CANSMC_PHASE_P2: CansmcPhase
CANSMC_PHASE_FAILED: CansmcPhase
CANSMC_SLAVE_STATE_UNSPECIFIED: CansmcSlaveState
CANSMC_SLAVE_STATE_CONNECTING: CansmcSlaveState
CANSMC_SLAVE_STATE_CONNECTED: CansmcSlaveState
CANSMC_SLAVE_STATE_MISSING: CansmcSlaveState
CANSMC_SLAVE_STATE_OPERATIONAL: CansmcSlaveState
CANSMC_SLAVE_STATE_LOST: CansmcSlaveState

class ListMastersRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListMastersResponse(_message.Message):
    __slots__ = ("masters",)
    MASTERS_FIELD_NUMBER: _ClassVar[int]
    masters: _containers.RepeatedCompositeFieldContainer[CansmcMasterInfo]
    def __init__(self, masters: _Optional[_Iterable[_Union[CansmcMasterInfo, _Mapping]]] = ...) -> None: ...

class CansmcMasterInfo(_message.Message):
    __slots__ = ("name", "command_bus", "status_bus", "cycle_time_us", "phase", "bitrate", "slave_addresses", "axes")
    NAME_FIELD_NUMBER: _ClassVar[int]
    COMMAND_BUS_FIELD_NUMBER: _ClassVar[int]
    STATUS_BUS_FIELD_NUMBER: _ClassVar[int]
    CYCLE_TIME_US_FIELD_NUMBER: _ClassVar[int]
    PHASE_FIELD_NUMBER: _ClassVar[int]
    BITRATE_FIELD_NUMBER: _ClassVar[int]
    SLAVE_ADDRESSES_FIELD_NUMBER: _ClassVar[int]
    AXES_FIELD_NUMBER: _ClassVar[int]
    name: str
    command_bus: str
    status_bus: str
    cycle_time_us: int
    phase: CansmcPhase
    bitrate: int
    slave_addresses: _containers.RepeatedScalarFieldContainer[int]
    axes: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, name: _Optional[str] = ..., command_bus: _Optional[str] = ..., status_bus: _Optional[str] = ..., cycle_time_us: _Optional[int] = ..., phase: _Optional[_Union[CansmcPhase, str]] = ..., bitrate: _Optional[int] = ..., slave_addresses: _Optional[_Iterable[int]] = ..., axes: _Optional[_Iterable[str]] = ...) -> None: ...

class GetCansmcStatusRequest(_message.Message):
    __slots__ = ("master",)
    MASTER_FIELD_NUMBER: _ClassVar[int]
    master: str
    def __init__(self, master: _Optional[str] = ...) -> None: ...

class CansmcStatus(_message.Message):
    __slots__ = ("master", "phase", "cycle", "cycle_time_us", "bitrate", "start_error", "starts", "counters", "slaves", "jitter", "timestamp_us")
    MASTER_FIELD_NUMBER: _ClassVar[int]
    PHASE_FIELD_NUMBER: _ClassVar[int]
    CYCLE_FIELD_NUMBER: _ClassVar[int]
    CYCLE_TIME_US_FIELD_NUMBER: _ClassVar[int]
    BITRATE_FIELD_NUMBER: _ClassVar[int]
    START_ERROR_FIELD_NUMBER: _ClassVar[int]
    STARTS_FIELD_NUMBER: _ClassVar[int]
    COUNTERS_FIELD_NUMBER: _ClassVar[int]
    SLAVES_FIELD_NUMBER: _ClassVar[int]
    JITTER_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_US_FIELD_NUMBER: _ClassVar[int]
    master: str
    phase: CansmcPhase
    cycle: int
    cycle_time_us: int
    bitrate: int
    start_error: str
    starts: int
    counters: CansmcMasterCounters
    slaves: _containers.RepeatedCompositeFieldContainer[CansmcSlave]
    jitter: CycleJitter
    timestamp_us: int
    def __init__(self, master: _Optional[str] = ..., phase: _Optional[_Union[CansmcPhase, str]] = ..., cycle: _Optional[int] = ..., cycle_time_us: _Optional[int] = ..., bitrate: _Optional[int] = ..., start_error: _Optional[str] = ..., starts: _Optional[int] = ..., counters: _Optional[_Union[CansmcMasterCounters, _Mapping]] = ..., slaves: _Optional[_Iterable[_Union[CansmcSlave, _Mapping]]] = ..., jitter: _Optional[_Union[CycleJitter, _Mapping]] = ..., timestamp_us: _Optional[int] = ...) -> None: ...

class CansmcMasterCounters(_message.Message):
    __slots__ = ("cycles", "overruns", "mdt_slots_missed", "foreign_frames", "stray_parameter_answers")
    CYCLES_FIELD_NUMBER: _ClassVar[int]
    OVERRUNS_FIELD_NUMBER: _ClassVar[int]
    MDT_SLOTS_MISSED_FIELD_NUMBER: _ClassVar[int]
    FOREIGN_FRAMES_FIELD_NUMBER: _ClassVar[int]
    STRAY_PARAMETER_ANSWERS_FIELD_NUMBER: _ClassVar[int]
    cycles: int
    overruns: int
    mdt_slots_missed: int
    foreign_frames: int
    stray_parameter_answers: int
    def __init__(self, cycles: _Optional[int] = ..., overruns: _Optional[int] = ..., mdt_slots_missed: _Optional[int] = ..., foreign_frames: _Optional[int] = ..., stray_parameter_answers: _Optional[int] = ...) -> None: ...

class CansmcSlave(_message.Message):
    __slots__ = ("address", "name", "required", "state", "device_type", "firmware_version", "status_word", "counters", "consecutive_misses", "axis")
    ADDRESS_FIELD_NUMBER: _ClassVar[int]
    NAME_FIELD_NUMBER: _ClassVar[int]
    REQUIRED_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    DEVICE_TYPE_FIELD_NUMBER: _ClassVar[int]
    FIRMWARE_VERSION_FIELD_NUMBER: _ClassVar[int]
    STATUS_WORD_FIELD_NUMBER: _ClassVar[int]
    COUNTERS_FIELD_NUMBER: _ClassVar[int]
    CONSECUTIVE_MISSES_FIELD_NUMBER: _ClassVar[int]
    AXIS_FIELD_NUMBER: _ClassVar[int]
    address: int
    name: str
    required: bool
    state: CansmcSlaveState
    device_type: int
    firmware_version: int
    status_word: CansmcStatusWord
    counters: CansmcSlaveCounters
    consecutive_misses: int
    axis: str
    def __init__(self, address: _Optional[int] = ..., name: _Optional[str] = ..., required: _Optional[bool] = ..., state: _Optional[_Union[CansmcSlaveState, str]] = ..., device_type: _Optional[int] = ..., firmware_version: _Optional[int] = ..., status_word: _Optional[_Union[CansmcStatusWord, _Mapping]] = ..., counters: _Optional[_Union[CansmcSlaveCounters, _Mapping]] = ..., consecutive_misses: _Optional[int] = ..., axis: _Optional[str] = ...) -> None: ...

class CansmcStatusWord(_message.Message):
    __slots__ = ("raw", "ready", "enabled", "fault", "target_reached", "homed", "following_error", "parameter_error", "counter_echo")
    RAW_FIELD_NUMBER: _ClassVar[int]
    READY_FIELD_NUMBER: _ClassVar[int]
    ENABLED_FIELD_NUMBER: _ClassVar[int]
    FAULT_FIELD_NUMBER: _ClassVar[int]
    TARGET_REACHED_FIELD_NUMBER: _ClassVar[int]
    HOMED_FIELD_NUMBER: _ClassVar[int]
    FOLLOWING_ERROR_FIELD_NUMBER: _ClassVar[int]
    PARAMETER_ERROR_FIELD_NUMBER: _ClassVar[int]
    COUNTER_ECHO_FIELD_NUMBER: _ClassVar[int]
    raw: int
    ready: bool
    enabled: bool
    fault: bool
    target_reached: bool
    homed: bool
    following_error: bool
    parameter_error: bool
    counter_echo: int
    def __init__(self, raw: _Optional[int] = ..., ready: _Optional[bool] = ..., enabled: _Optional[bool] = ..., fault: _Optional[bool] = ..., target_reached: _Optional[bool] = ..., homed: _Optional[bool] = ..., following_error: _Optional[bool] = ..., parameter_error: _Optional[bool] = ..., counter_echo: _Optional[int] = ...) -> None: ...

class CansmcSlaveCounters(_message.Message):
    __slots__ = ("dts", "missed", "late", "counter_mismatch", "rejects", "malformed", "losses", "mdts")
    DTS_FIELD_NUMBER: _ClassVar[int]
    MISSED_FIELD_NUMBER: _ClassVar[int]
    LATE_FIELD_NUMBER: _ClassVar[int]
    COUNTER_MISMATCH_FIELD_NUMBER: _ClassVar[int]
    REJECTS_FIELD_NUMBER: _ClassVar[int]
    MALFORMED_FIELD_NUMBER: _ClassVar[int]
    LOSSES_FIELD_NUMBER: _ClassVar[int]
    MDTS_FIELD_NUMBER: _ClassVar[int]
    dts: int
    missed: int
    late: int
    counter_mismatch: int
    rejects: int
    malformed: int
    losses: int
    mdts: int
    def __init__(self, dts: _Optional[int] = ..., missed: _Optional[int] = ..., late: _Optional[int] = ..., counter_mismatch: _Optional[int] = ..., rejects: _Optional[int] = ..., malformed: _Optional[int] = ..., losses: _Optional[int] = ..., mdts: _Optional[int] = ...) -> None: ...

class CycleJitter(_message.Message):
    __slots__ = ("samples", "p50_us", "p99_us", "p999_us", "max_us", "mean_us", "histogram", "histogram_bucket_us")
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    P50_US_FIELD_NUMBER: _ClassVar[int]
    P99_US_FIELD_NUMBER: _ClassVar[int]
    P999_US_FIELD_NUMBER: _ClassVar[int]
    MAX_US_FIELD_NUMBER: _ClassVar[int]
    MEAN_US_FIELD_NUMBER: _ClassVar[int]
    HISTOGRAM_FIELD_NUMBER: _ClassVar[int]
    HISTOGRAM_BUCKET_US_FIELD_NUMBER: _ClassVar[int]
    samples: int
    p50_us: float
    p99_us: float
    p999_us: float
    max_us: float
    mean_us: float
    histogram: _containers.RepeatedScalarFieldContainer[int]
    histogram_bucket_us: int
    def __init__(self, samples: _Optional[int] = ..., p50_us: _Optional[float] = ..., p99_us: _Optional[float] = ..., p999_us: _Optional[float] = ..., max_us: _Optional[float] = ..., mean_us: _Optional[float] = ..., histogram: _Optional[_Iterable[int]] = ..., histogram_bucket_us: _Optional[int] = ...) -> None: ...

class ReadParameterRequest(_message.Message):
    __slots__ = ("master", "address", "number")
    MASTER_FIELD_NUMBER: _ClassVar[int]
    ADDRESS_FIELD_NUMBER: _ClassVar[int]
    NUMBER_FIELD_NUMBER: _ClassVar[int]
    master: str
    address: int
    number: int
    def __init__(self, master: _Optional[str] = ..., address: _Optional[int] = ..., number: _Optional[int] = ...) -> None: ...

class WriteParameterRequest(_message.Message):
    __slots__ = ("master", "address", "number", "value")
    MASTER_FIELD_NUMBER: _ClassVar[int]
    ADDRESS_FIELD_NUMBER: _ClassVar[int]
    NUMBER_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    master: str
    address: int
    number: int
    value: int
    def __init__(self, master: _Optional[str] = ..., address: _Optional[int] = ..., number: _Optional[int] = ..., value: _Optional[int] = ...) -> None: ...

class ParameterValue(_message.Message):
    __slots__ = ("master", "address", "number", "value")
    MASTER_FIELD_NUMBER: _ClassVar[int]
    ADDRESS_FIELD_NUMBER: _ClassVar[int]
    NUMBER_FIELD_NUMBER: _ClassVar[int]
    VALUE_FIELD_NUMBER: _ClassVar[int]
    master: str
    address: int
    number: int
    value: int
    def __init__(self, master: _Optional[str] = ..., address: _Optional[int] = ..., number: _Optional[int] = ..., value: _Optional[int] = ...) -> None: ...

class StreamCycleStatsRequest(_message.Message):
    __slots__ = ("master", "interval_ms")
    MASTER_FIELD_NUMBER: _ClassVar[int]
    INTERVAL_MS_FIELD_NUMBER: _ClassVar[int]
    master: str
    interval_ms: int
    def __init__(self, master: _Optional[str] = ..., interval_ms: _Optional[int] = ...) -> None: ...

class CansmcEvent(_message.Message):
    __slots__ = ("timestamp_us", "phase", "slave")
    TIMESTAMP_US_FIELD_NUMBER: _ClassVar[int]
    PHASE_FIELD_NUMBER: _ClassVar[int]
    SLAVE_FIELD_NUMBER: _ClassVar[int]
    timestamp_us: int
    phase: CansmcPhase
    slave: CansmcSlaveEvent
    def __init__(self, timestamp_us: _Optional[int] = ..., phase: _Optional[_Union[CansmcPhase, str]] = ..., slave: _Optional[_Union[CansmcSlaveEvent, _Mapping]] = ...) -> None: ...

class CansmcSlaveEvent(_message.Message):
    __slots__ = ("address", "what")
    ADDRESS_FIELD_NUMBER: _ClassVar[int]
    WHAT_FIELD_NUMBER: _ClassVar[int]
    address: int
    what: str
    def __init__(self, address: _Optional[int] = ..., what: _Optional[str] = ...) -> None: ...

class CycleStatsUpdate(_message.Message):
    __slots__ = ("status", "events", "events_lost")
    STATUS_FIELD_NUMBER: _ClassVar[int]
    EVENTS_FIELD_NUMBER: _ClassVar[int]
    EVENTS_LOST_FIELD_NUMBER: _ClassVar[int]
    status: CansmcStatus
    events: _containers.RepeatedCompositeFieldContainer[CansmcEvent]
    events_lost: int
    def __init__(self, status: _Optional[_Union[CansmcStatus, _Mapping]] = ..., events: _Optional[_Iterable[_Union[CansmcEvent, _Mapping]]] = ..., events_lost: _Optional[int] = ...) -> None: ...

class RestartRequest(_message.Message):
    __slots__ = ("master",)
    MASTER_FIELD_NUMBER: _ClassVar[int]
    master: str
    def __init__(self, master: _Optional[str] = ...) -> None: ...

class RestartResponse(_message.Message):
    __slots__ = ("master",)
    MASTER_FIELD_NUMBER: _ClassVar[int]
    master: str
    def __init__(self, master: _Optional[str] = ...) -> None: ...
