from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class DriveState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DRIVE_STATE_UNSPECIFIED: _ClassVar[DriveState]
    DRIVE_STATE_NOT_READY_TO_SWITCH_ON: _ClassVar[DriveState]
    DRIVE_STATE_SWITCH_ON_DISABLED: _ClassVar[DriveState]
    DRIVE_STATE_READY_TO_SWITCH_ON: _ClassVar[DriveState]
    DRIVE_STATE_SWITCHED_ON: _ClassVar[DriveState]
    DRIVE_STATE_OPERATION_ENABLED: _ClassVar[DriveState]
    DRIVE_STATE_QUICK_STOP_ACTIVE: _ClassVar[DriveState]
    DRIVE_STATE_FAULT_REACTION_ACTIVE: _ClassVar[DriveState]
    DRIVE_STATE_FAULT: _ClassVar[DriveState]

class AxisActivity(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    AXIS_ACTIVITY_UNSPECIFIED: _ClassVar[AxisActivity]
    AXIS_ACTIVITY_IDLE: _ClassVar[AxisActivity]
    AXIS_ACTIVITY_SWITCHING: _ClassVar[AxisActivity]
    AXIS_ACTIVITY_HOMING: _ClassVar[AxisActivity]
    AXIS_ACTIVITY_MOVING: _ClassVar[AxisActivity]
    AXIS_ACTIVITY_JOGGING: _ClassVar[AxisActivity]
    AXIS_ACTIVITY_STOPPING: _ClassVar[AxisActivity]

class AxisBackend(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    AXIS_BACKEND_UNSPECIFIED: _ClassVar[AxisBackend]
    AXIS_BACKEND_CIA402: _ClassVar[AxisBackend]
    AXIS_BACKEND_CANSMC: _ClassVar[AxisBackend]

class PositionMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    POSITION_MODE_UNSPECIFIED: _ClassVar[PositionMode]
    POSITION_MODE_PROFILE: _ClassVar[PositionMode]
    POSITION_MODE_CYCLIC: _ClassVar[PositionMode]

class DriveMode(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    DRIVE_MODE_UNSPECIFIED: _ClassVar[DriveMode]
    DRIVE_MODE_PROFILE_POSITION: _ClassVar[DriveMode]
    DRIVE_MODE_CSP: _ClassVar[DriveMode]
    DRIVE_MODE_IP: _ClassVar[DriveMode]
    DRIVE_MODE_CSV: _ClassVar[DriveMode]
    DRIVE_MODE_CST: _ClassVar[DriveMode]
    DRIVE_MODE_PROFILE_TORQUE: _ClassVar[DriveMode]

class ProcessDataPath(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    PROCESS_DATA_PATH_UNSPECIFIED: _ClassVar[ProcessDataPath]
    PROCESS_DATA_PATH_PDO: _ClassVar[ProcessDataPath]
    PROCESS_DATA_PATH_SDO: _ClassVar[ProcessDataPath]

class StopKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    STOP_KIND_UNSPECIFIED: _ClassVar[StopKind]
    STOP_KIND_HALT: _ClassVar[StopKind]
    STOP_KIND_QUICK_STOP: _ClassVar[StopKind]

class Outcome(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    OUTCOME_UNSPECIFIED: _ClassVar[Outcome]
    OUTCOME_ACCEPTED: _ClassVar[Outcome]
    OUTCOME_COMPLETED: _ClassVar[Outcome]
    OUTCOME_SUPERSEDED: _ClassVar[Outcome]
    OUTCOME_FAULT: _ClassVar[Outcome]
    OUTCOME_TIMEOUT: _ClassVar[Outcome]
    OUTCOME_STOPPED: _ClassVar[Outcome]

class TouchProbeEdge(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    TOUCH_PROBE_EDGE_UNSPECIFIED: _ClassVar[TouchProbeEdge]
    TOUCH_PROBE_EDGE_RISING: _ClassVar[TouchProbeEdge]
    TOUCH_PROBE_EDGE_FALLING: _ClassVar[TouchProbeEdge]
    TOUCH_PROBE_EDGE_BOTH: _ClassVar[TouchProbeEdge]

class SetpointStreamState(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SETPOINT_STREAM_STATE_UNSPECIFIED: _ClassVar[SetpointStreamState]
    SETPOINT_STREAM_WAITING: _ClassVar[SetpointStreamState]
    SETPOINT_STREAM_FILLING: _ClassVar[SetpointStreamState]
    SETPOINT_STREAM_PLAYING: _ClassVar[SetpointStreamState]
    SETPOINT_STREAM_EXTRAPOLATING: _ClassVar[SetpointStreamState]
    SETPOINT_STREAM_STOPPING: _ClassVar[SetpointStreamState]
    SETPOINT_STREAM_ENDED: _ClassVar[SetpointStreamState]

class SetpointEventKind(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SETPOINT_EVENT_KIND_UNSPECIFIED: _ClassVar[SetpointEventKind]
    SETPOINT_EVENT_UNDERRUN: _ClassVar[SetpointEventKind]
    SETPOINT_EVENT_POINT_REFUSED: _ClassVar[SetpointEventKind]
    SETPOINT_EVENT_AT_REST: _ClassVar[SetpointEventKind]
    SETPOINT_EVENT_ENDED: _ClassVar[SetpointEventKind]
DRIVE_STATE_UNSPECIFIED: DriveState
DRIVE_STATE_NOT_READY_TO_SWITCH_ON: DriveState
DRIVE_STATE_SWITCH_ON_DISABLED: DriveState
DRIVE_STATE_READY_TO_SWITCH_ON: DriveState
DRIVE_STATE_SWITCHED_ON: DriveState
DRIVE_STATE_OPERATION_ENABLED: DriveState
DRIVE_STATE_QUICK_STOP_ACTIVE: DriveState
DRIVE_STATE_FAULT_REACTION_ACTIVE: DriveState
DRIVE_STATE_FAULT: DriveState
AXIS_ACTIVITY_UNSPECIFIED: AxisActivity
AXIS_ACTIVITY_IDLE: AxisActivity
AXIS_ACTIVITY_SWITCHING: AxisActivity
AXIS_ACTIVITY_HOMING: AxisActivity
AXIS_ACTIVITY_MOVING: AxisActivity
AXIS_ACTIVITY_JOGGING: AxisActivity
AXIS_ACTIVITY_STOPPING: AxisActivity
AXIS_BACKEND_UNSPECIFIED: AxisBackend
AXIS_BACKEND_CIA402: AxisBackend
AXIS_BACKEND_CANSMC: AxisBackend
POSITION_MODE_UNSPECIFIED: PositionMode
POSITION_MODE_PROFILE: PositionMode
POSITION_MODE_CYCLIC: PositionMode
DRIVE_MODE_UNSPECIFIED: DriveMode
DRIVE_MODE_PROFILE_POSITION: DriveMode
DRIVE_MODE_CSP: DriveMode
DRIVE_MODE_IP: DriveMode
DRIVE_MODE_CSV: DriveMode
DRIVE_MODE_CST: DriveMode
DRIVE_MODE_PROFILE_TORQUE: DriveMode
PROCESS_DATA_PATH_UNSPECIFIED: ProcessDataPath
PROCESS_DATA_PATH_PDO: ProcessDataPath
PROCESS_DATA_PATH_SDO: ProcessDataPath
STOP_KIND_UNSPECIFIED: StopKind
STOP_KIND_HALT: StopKind
STOP_KIND_QUICK_STOP: StopKind
OUTCOME_UNSPECIFIED: Outcome
OUTCOME_ACCEPTED: Outcome
OUTCOME_COMPLETED: Outcome
OUTCOME_SUPERSEDED: Outcome
OUTCOME_FAULT: Outcome
OUTCOME_TIMEOUT: Outcome
OUTCOME_STOPPED: Outcome
TOUCH_PROBE_EDGE_UNSPECIFIED: TouchProbeEdge
TOUCH_PROBE_EDGE_RISING: TouchProbeEdge
TOUCH_PROBE_EDGE_FALLING: TouchProbeEdge
TOUCH_PROBE_EDGE_BOTH: TouchProbeEdge
SETPOINT_STREAM_STATE_UNSPECIFIED: SetpointStreamState
SETPOINT_STREAM_WAITING: SetpointStreamState
SETPOINT_STREAM_FILLING: SetpointStreamState
SETPOINT_STREAM_PLAYING: SetpointStreamState
SETPOINT_STREAM_EXTRAPOLATING: SetpointStreamState
SETPOINT_STREAM_STOPPING: SetpointStreamState
SETPOINT_STREAM_ENDED: SetpointStreamState
SETPOINT_EVENT_KIND_UNSPECIFIED: SetpointEventKind
SETPOINT_EVENT_UNDERRUN: SetpointEventKind
SETPOINT_EVENT_POINT_REFUSED: SetpointEventKind
SETPOINT_EVENT_AT_REST: SetpointEventKind
SETPOINT_EVENT_ENDED: SetpointEventKind

class Axis(_message.Message):
    __slots__ = ("name", "backend", "bus", "node", "unit", "counts_per_unit", "min_position", "max_position", "max_velocity", "max_acceleration", "position_mode", "stop_on_loss", "jog_deadman_ms", "status", "process_data", "sdo_poll_ms", "display_decimals", "mode", "max_torque")
    NAME_FIELD_NUMBER: _ClassVar[int]
    BACKEND_FIELD_NUMBER: _ClassVar[int]
    BUS_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    UNIT_FIELD_NUMBER: _ClassVar[int]
    COUNTS_PER_UNIT_FIELD_NUMBER: _ClassVar[int]
    MIN_POSITION_FIELD_NUMBER: _ClassVar[int]
    MAX_POSITION_FIELD_NUMBER: _ClassVar[int]
    MAX_VELOCITY_FIELD_NUMBER: _ClassVar[int]
    MAX_ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    POSITION_MODE_FIELD_NUMBER: _ClassVar[int]
    STOP_ON_LOSS_FIELD_NUMBER: _ClassVar[int]
    JOG_DEADMAN_MS_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    PROCESS_DATA_FIELD_NUMBER: _ClassVar[int]
    SDO_POLL_MS_FIELD_NUMBER: _ClassVar[int]
    DISPLAY_DECIMALS_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    MAX_TORQUE_FIELD_NUMBER: _ClassVar[int]
    name: str
    backend: AxisBackend
    bus: str
    node: int
    unit: str
    counts_per_unit: float
    min_position: float
    max_position: float
    max_velocity: float
    max_acceleration: float
    position_mode: PositionMode
    stop_on_loss: StopKind
    jog_deadman_ms: int
    status: AxisStatus
    process_data: ProcessDataPath
    sdo_poll_ms: int
    display_decimals: int
    mode: DriveMode
    max_torque: float
    def __init__(self, name: _Optional[str] = ..., backend: _Optional[_Union[AxisBackend, str]] = ..., bus: _Optional[str] = ..., node: _Optional[int] = ..., unit: _Optional[str] = ..., counts_per_unit: _Optional[float] = ..., min_position: _Optional[float] = ..., max_position: _Optional[float] = ..., max_velocity: _Optional[float] = ..., max_acceleration: _Optional[float] = ..., position_mode: _Optional[_Union[PositionMode, str]] = ..., stop_on_loss: _Optional[_Union[StopKind, str]] = ..., jog_deadman_ms: _Optional[int] = ..., status: _Optional[_Union[AxisStatus, _Mapping]] = ..., process_data: _Optional[_Union[ProcessDataPath, str]] = ..., sdo_poll_ms: _Optional[int] = ..., display_decimals: _Optional[int] = ..., mode: _Optional[_Union[DriveMode, str]] = ..., max_torque: _Optional[float] = ...) -> None: ...

class AxisStatus(_message.Message):
    __slots__ = ("axis", "state", "statusword", "mode", "activity", "position", "velocity", "demand_position", "following_error", "homed", "node_lost", "fault_code", "fault_text", "controlled_by", "lease_remaining_ms", "timestamp_us", "torque_actual", "following_error_actual", "digital_inputs", "touch_probe_status")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    STATE_FIELD_NUMBER: _ClassVar[int]
    STATUSWORD_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    ACTIVITY_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    DEMAND_POSITION_FIELD_NUMBER: _ClassVar[int]
    FOLLOWING_ERROR_FIELD_NUMBER: _ClassVar[int]
    HOMED_FIELD_NUMBER: _ClassVar[int]
    NODE_LOST_FIELD_NUMBER: _ClassVar[int]
    FAULT_CODE_FIELD_NUMBER: _ClassVar[int]
    FAULT_TEXT_FIELD_NUMBER: _ClassVar[int]
    CONTROLLED_BY_FIELD_NUMBER: _ClassVar[int]
    LEASE_REMAINING_MS_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_US_FIELD_NUMBER: _ClassVar[int]
    TORQUE_ACTUAL_FIELD_NUMBER: _ClassVar[int]
    FOLLOWING_ERROR_ACTUAL_FIELD_NUMBER: _ClassVar[int]
    DIGITAL_INPUTS_FIELD_NUMBER: _ClassVar[int]
    TOUCH_PROBE_STATUS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    state: DriveState
    statusword: int
    mode: int
    activity: AxisActivity
    position: float
    velocity: float
    demand_position: float
    following_error: float
    homed: bool
    node_lost: bool
    fault_code: int
    fault_text: str
    controlled_by: str
    lease_remaining_ms: int
    timestamp_us: int
    torque_actual: int
    following_error_actual: float
    digital_inputs: DigitalInputs
    touch_probe_status: int
    def __init__(self, axis: _Optional[str] = ..., state: _Optional[_Union[DriveState, str]] = ..., statusword: _Optional[int] = ..., mode: _Optional[int] = ..., activity: _Optional[_Union[AxisActivity, str]] = ..., position: _Optional[float] = ..., velocity: _Optional[float] = ..., demand_position: _Optional[float] = ..., following_error: _Optional[float] = ..., homed: _Optional[bool] = ..., node_lost: _Optional[bool] = ..., fault_code: _Optional[int] = ..., fault_text: _Optional[str] = ..., controlled_by: _Optional[str] = ..., lease_remaining_ms: _Optional[int] = ..., timestamp_us: _Optional[int] = ..., torque_actual: _Optional[int] = ..., following_error_actual: _Optional[float] = ..., digital_inputs: _Optional[_Union[DigitalInputs, _Mapping]] = ..., touch_probe_status: _Optional[int] = ...) -> None: ...

class DigitalInputs(_message.Message):
    __slots__ = ("negative_limit_switch", "positive_limit_switch", "home_switch", "raw")
    NEGATIVE_LIMIT_SWITCH_FIELD_NUMBER: _ClassVar[int]
    POSITIVE_LIMIT_SWITCH_FIELD_NUMBER: _ClassVar[int]
    HOME_SWITCH_FIELD_NUMBER: _ClassVar[int]
    RAW_FIELD_NUMBER: _ClassVar[int]
    negative_limit_switch: bool
    positive_limit_switch: bool
    home_switch: bool
    raw: int
    def __init__(self, negative_limit_switch: _Optional[bool] = ..., positive_limit_switch: _Optional[bool] = ..., home_switch: _Optional[bool] = ..., raw: _Optional[int] = ...) -> None: ...

class ListAxesRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ListAxesResponse(_message.Message):
    __slots__ = ("axes",)
    AXES_FIELD_NUMBER: _ClassVar[int]
    axes: _containers.RepeatedCompositeFieldContainer[Axis]
    def __init__(self, axes: _Optional[_Iterable[_Union[Axis, _Mapping]]] = ...) -> None: ...

class GetAxisRequest(_message.Message):
    __slots__ = ("axis",)
    AXIS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    def __init__(self, axis: _Optional[str] = ...) -> None: ...

class AcquireControlRequest(_message.Message):
    __slots__ = ("axes", "ttl_ms", "client_name")
    AXES_FIELD_NUMBER: _ClassVar[int]
    TTL_MS_FIELD_NUMBER: _ClassVar[int]
    CLIENT_NAME_FIELD_NUMBER: _ClassVar[int]
    axes: _containers.RepeatedScalarFieldContainer[str]
    ttl_ms: int
    client_name: str
    def __init__(self, axes: _Optional[_Iterable[str]] = ..., ttl_ms: _Optional[int] = ..., client_name: _Optional[str] = ...) -> None: ...

class ControlLease(_message.Message):
    __slots__ = ("lease", "axes", "holder", "ttl_ms")
    LEASE_FIELD_NUMBER: _ClassVar[int]
    AXES_FIELD_NUMBER: _ClassVar[int]
    HOLDER_FIELD_NUMBER: _ClassVar[int]
    TTL_MS_FIELD_NUMBER: _ClassVar[int]
    lease: str
    axes: _containers.RepeatedScalarFieldContainer[str]
    holder: str
    ttl_ms: int
    def __init__(self, lease: _Optional[str] = ..., axes: _Optional[_Iterable[str]] = ..., holder: _Optional[str] = ..., ttl_ms: _Optional[int] = ...) -> None: ...

class RenewControlRequest(_message.Message):
    __slots__ = ("lease",)
    LEASE_FIELD_NUMBER: _ClassVar[int]
    lease: str
    def __init__(self, lease: _Optional[str] = ...) -> None: ...

class ReleaseControlRequest(_message.Message):
    __slots__ = ("lease",)
    LEASE_FIELD_NUMBER: _ClassVar[int]
    lease: str
    def __init__(self, lease: _Optional[str] = ...) -> None: ...

class ReleaseControlResponse(_message.Message):
    __slots__ = ("axes",)
    AXES_FIELD_NUMBER: _ClassVar[int]
    axes: _containers.RepeatedScalarFieldContainer[str]
    def __init__(self, axes: _Optional[_Iterable[str]] = ...) -> None: ...

class CommandOptions(_message.Message):
    __slots__ = ("lease", "wait", "wait_timeout_ms")
    LEASE_FIELD_NUMBER: _ClassVar[int]
    WAIT_FIELD_NUMBER: _ClassVar[int]
    WAIT_TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    lease: str
    wait: bool
    wait_timeout_ms: int
    def __init__(self, lease: _Optional[str] = ..., wait: _Optional[bool] = ..., wait_timeout_ms: _Optional[int] = ...) -> None: ...

class AxisCommandRequest(_message.Message):
    __slots__ = ("axis", "options")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    options: CommandOptions
    def __init__(self, axis: _Optional[str] = ..., options: _Optional[_Union[CommandOptions, _Mapping]] = ...) -> None: ...

class AxisCommandResponse(_message.Message):
    __slots__ = ("outcome", "detail", "status")
    OUTCOME_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    STATUS_FIELD_NUMBER: _ClassVar[int]
    outcome: Outcome
    detail: str
    status: AxisStatus
    def __init__(self, outcome: _Optional[_Union[Outcome, str]] = ..., detail: _Optional[str] = ..., status: _Optional[_Union[AxisStatus, _Mapping]] = ...) -> None: ...

class MoveRequest(_message.Message):
    __slots__ = ("axis", "target", "relative", "velocity", "acceleration", "options")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    TARGET_FIELD_NUMBER: _ClassVar[int]
    RELATIVE_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    target: float
    relative: bool
    velocity: float
    acceleration: float
    options: CommandOptions
    def __init__(self, axis: _Optional[str] = ..., target: _Optional[float] = ..., relative: _Optional[bool] = ..., velocity: _Optional[float] = ..., acceleration: _Optional[float] = ..., options: _Optional[_Union[CommandOptions, _Mapping]] = ...) -> None: ...

class JogRequest(_message.Message):
    __slots__ = ("axis", "velocity", "acceleration", "options")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    velocity: float
    acceleration: float
    options: CommandOptions
    def __init__(self, axis: _Optional[str] = ..., velocity: _Optional[float] = ..., acceleration: _Optional[float] = ..., options: _Optional[_Union[CommandOptions, _Mapping]] = ...) -> None: ...

class SetTorqueRequest(_message.Message):
    __slots__ = ("axis", "torque_per_mille", "options")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    TORQUE_PER_MILLE_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    torque_per_mille: float
    options: CommandOptions
    def __init__(self, axis: _Optional[str] = ..., torque_per_mille: _Optional[float] = ..., options: _Optional[_Union[CommandOptions, _Mapping]] = ...) -> None: ...

class SetAxisModeRequest(_message.Message):
    __slots__ = ("axis", "mode", "options")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    MODE_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    mode: DriveMode
    options: CommandOptions
    def __init__(self, axis: _Optional[str] = ..., mode: _Optional[_Union[DriveMode, str]] = ..., options: _Optional[_Union[CommandOptions, _Mapping]] = ...) -> None: ...

class StopAxesRequest(_message.Message):
    __slots__ = ("axes", "quick", "wait")
    AXES_FIELD_NUMBER: _ClassVar[int]
    QUICK_FIELD_NUMBER: _ClassVar[int]
    WAIT_FIELD_NUMBER: _ClassVar[int]
    axes: _containers.RepeatedScalarFieldContainer[str]
    quick: bool
    wait: bool
    def __init__(self, axes: _Optional[_Iterable[str]] = ..., quick: _Optional[bool] = ..., wait: _Optional[bool] = ...) -> None: ...

class MultiAxisResponse(_message.Message):
    __slots__ = ("results",)
    RESULTS_FIELD_NUMBER: _ClassVar[int]
    results: _containers.RepeatedCompositeFieldContainer[AxisCommandResponse]
    def __init__(self, results: _Optional[_Iterable[_Union[AxisCommandResponse, _Mapping]]] = ...) -> None: ...

class MoveAxesRequest(_message.Message):
    __slots__ = ("targets", "lease", "wait")
    TARGETS_FIELD_NUMBER: _ClassVar[int]
    LEASE_FIELD_NUMBER: _ClassVar[int]
    WAIT_FIELD_NUMBER: _ClassVar[int]
    targets: _containers.RepeatedCompositeFieldContainer[AxisTarget]
    lease: str
    wait: bool
    def __init__(self, targets: _Optional[_Iterable[_Union[AxisTarget, _Mapping]]] = ..., lease: _Optional[str] = ..., wait: _Optional[bool] = ...) -> None: ...

class AxisTarget(_message.Message):
    __slots__ = ("axis", "target", "velocity", "acceleration")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    TARGET_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    ACCELERATION_FIELD_NUMBER: _ClassVar[int]
    axis: str
    target: float
    velocity: float
    acceleration: float
    def __init__(self, axis: _Optional[str] = ..., target: _Optional[float] = ..., velocity: _Optional[float] = ..., acceleration: _Optional[float] = ...) -> None: ...

class StreamAxisStateRequest(_message.Message):
    __slots__ = ("axes", "changes_only")
    AXES_FIELD_NUMBER: _ClassVar[int]
    CHANGES_ONLY_FIELD_NUMBER: _ClassVar[int]
    axes: _containers.RepeatedScalarFieldContainer[str]
    changes_only: bool
    def __init__(self, axes: _Optional[_Iterable[str]] = ..., changes_only: _Optional[bool] = ...) -> None: ...

class AxisUpdate(_message.Message):
    __slots__ = ("status", "event")
    STATUS_FIELD_NUMBER: _ClassVar[int]
    EVENT_FIELD_NUMBER: _ClassVar[int]
    status: AxisStatus
    event: AxisEvent
    def __init__(self, status: _Optional[_Union[AxisStatus, _Mapping]] = ..., event: _Optional[_Union[AxisEvent, _Mapping]] = ...) -> None: ...

class AxisEvent(_message.Message):
    __slots__ = ("axis", "timestamp_us", "motion_done", "fault", "control", "node", "lost", "touch_probe")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_US_FIELD_NUMBER: _ClassVar[int]
    MOTION_DONE_FIELD_NUMBER: _ClassVar[int]
    FAULT_FIELD_NUMBER: _ClassVar[int]
    CONTROL_FIELD_NUMBER: _ClassVar[int]
    NODE_FIELD_NUMBER: _ClassVar[int]
    LOST_FIELD_NUMBER: _ClassVar[int]
    TOUCH_PROBE_FIELD_NUMBER: _ClassVar[int]
    axis: str
    timestamp_us: int
    motion_done: MotionDone
    fault: Fault
    control: ControlChange
    node: NodeLink
    lost: int
    touch_probe: TouchProbeLatch
    def __init__(self, axis: _Optional[str] = ..., timestamp_us: _Optional[int] = ..., motion_done: _Optional[_Union[MotionDone, _Mapping]] = ..., fault: _Optional[_Union[Fault, _Mapping]] = ..., control: _Optional[_Union[ControlChange, _Mapping]] = ..., node: _Optional[_Union[NodeLink, _Mapping]] = ..., lost: _Optional[int] = ..., touch_probe: _Optional[_Union[TouchProbeLatch, _Mapping]] = ...) -> None: ...

class ArmTouchProbeRequest(_message.Message):
    __slots__ = ("axis", "edge", "continuous", "options")
    AXIS_FIELD_NUMBER: _ClassVar[int]
    EDGE_FIELD_NUMBER: _ClassVar[int]
    CONTINUOUS_FIELD_NUMBER: _ClassVar[int]
    OPTIONS_FIELD_NUMBER: _ClassVar[int]
    axis: str
    edge: TouchProbeEdge
    continuous: bool
    options: CommandOptions
    def __init__(self, axis: _Optional[str] = ..., edge: _Optional[_Union[TouchProbeEdge, str]] = ..., continuous: _Optional[bool] = ..., options: _Optional[_Union[CommandOptions, _Mapping]] = ...) -> None: ...

class TouchProbeLatch(_message.Message):
    __slots__ = ("probe", "edge", "position")
    PROBE_FIELD_NUMBER: _ClassVar[int]
    EDGE_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    probe: int
    edge: TouchProbeEdge
    position: float
    def __init__(self, probe: _Optional[int] = ..., edge: _Optional[_Union[TouchProbeEdge, str]] = ..., position: _Optional[float] = ...) -> None: ...

class MotionDone(_message.Message):
    __slots__ = ("command", "outcome", "detail")
    COMMAND_FIELD_NUMBER: _ClassVar[int]
    OUTCOME_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    command: str
    outcome: Outcome
    detail: str
    def __init__(self, command: _Optional[str] = ..., outcome: _Optional[_Union[Outcome, str]] = ..., detail: _Optional[str] = ...) -> None: ...

class Fault(_message.Message):
    __slots__ = ("code", "text", "active")
    CODE_FIELD_NUMBER: _ClassVar[int]
    TEXT_FIELD_NUMBER: _ClassVar[int]
    ACTIVE_FIELD_NUMBER: _ClassVar[int]
    code: int
    text: str
    active: bool
    def __init__(self, code: _Optional[int] = ..., text: _Optional[str] = ..., active: _Optional[bool] = ...) -> None: ...

class ControlChange(_message.Message):
    __slots__ = ("holder", "previous", "reason")
    HOLDER_FIELD_NUMBER: _ClassVar[int]
    PREVIOUS_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    holder: str
    previous: str
    reason: str
    def __init__(self, holder: _Optional[str] = ..., previous: _Optional[str] = ..., reason: _Optional[str] = ...) -> None: ...

class NodeLink(_message.Message):
    __slots__ = ("lost", "reason")
    LOST_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    lost: bool
    reason: str
    def __init__(self, lost: _Optional[bool] = ..., reason: _Optional[str] = ...) -> None: ...

class SetpointStreamRequest(_message.Message):
    __slots__ = ("open", "batch")
    OPEN_FIELD_NUMBER: _ClassVar[int]
    BATCH_FIELD_NUMBER: _ClassVar[int]
    open: SetpointStreamOpen
    batch: SetpointBatch
    def __init__(self, open: _Optional[_Union[SetpointStreamOpen, _Mapping]] = ..., batch: _Optional[_Union[SetpointBatch, _Mapping]] = ...) -> None: ...

class SetpointStreamOpen(_message.Message):
    __slots__ = ("axes", "lease", "depth_ms", "extrapolate_ms", "point_period_us", "status_period_ms")
    AXES_FIELD_NUMBER: _ClassVar[int]
    LEASE_FIELD_NUMBER: _ClassVar[int]
    DEPTH_MS_FIELD_NUMBER: _ClassVar[int]
    EXTRAPOLATE_MS_FIELD_NUMBER: _ClassVar[int]
    POINT_PERIOD_US_FIELD_NUMBER: _ClassVar[int]
    STATUS_PERIOD_MS_FIELD_NUMBER: _ClassVar[int]
    axes: _containers.RepeatedScalarFieldContainer[str]
    lease: str
    depth_ms: int
    extrapolate_ms: int
    point_period_us: int
    status_period_ms: int
    def __init__(self, axes: _Optional[_Iterable[str]] = ..., lease: _Optional[str] = ..., depth_ms: _Optional[int] = ..., extrapolate_ms: _Optional[int] = ..., point_period_us: _Optional[int] = ..., status_period_ms: _Optional[int] = ...) -> None: ...

class SetpointBatch(_message.Message):
    __slots__ = ("points",)
    POINTS_FIELD_NUMBER: _ClassVar[int]
    points: _containers.RepeatedCompositeFieldContainer[Setpoint]
    def __init__(self, points: _Optional[_Iterable[_Union[Setpoint, _Mapping]]] = ...) -> None: ...

class Setpoint(_message.Message):
    __slots__ = ("t_us", "positions", "velocities", "torques")
    T_US_FIELD_NUMBER: _ClassVar[int]
    POSITIONS_FIELD_NUMBER: _ClassVar[int]
    VELOCITIES_FIELD_NUMBER: _ClassVar[int]
    TORQUES_FIELD_NUMBER: _ClassVar[int]
    t_us: int
    positions: _containers.RepeatedScalarFieldContainer[float]
    velocities: _containers.RepeatedScalarFieldContainer[float]
    torques: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, t_us: _Optional[int] = ..., positions: _Optional[_Iterable[float]] = ..., velocities: _Optional[_Iterable[float]] = ..., torques: _Optional[_Iterable[float]] = ...) -> None: ...

class SetpointCounters(_message.Message):
    __slots__ = ("received", "accepted", "refused", "played", "late", "dropped", "underruns", "limited")
    RECEIVED_FIELD_NUMBER: _ClassVar[int]
    ACCEPTED_FIELD_NUMBER: _ClassVar[int]
    REFUSED_FIELD_NUMBER: _ClassVar[int]
    PLAYED_FIELD_NUMBER: _ClassVar[int]
    LATE_FIELD_NUMBER: _ClassVar[int]
    DROPPED_FIELD_NUMBER: _ClassVar[int]
    UNDERRUNS_FIELD_NUMBER: _ClassVar[int]
    LIMITED_FIELD_NUMBER: _ClassVar[int]
    received: int
    accepted: int
    refused: int
    played: int
    late: int
    dropped: int
    underruns: int
    limited: int
    def __init__(self, received: _Optional[int] = ..., accepted: _Optional[int] = ..., refused: _Optional[int] = ..., played: _Optional[int] = ..., late: _Optional[int] = ..., dropped: _Optional[int] = ..., underruns: _Optional[int] = ..., limited: _Optional[int] = ...) -> None: ...

class SetpointStreamStatus(_message.Message):
    __slots__ = ("state", "buffer_level_us", "counters", "clock_offset_us", "commanded_positions", "actual_positions", "events", "timestamp_us", "ended", "signals", "commanded_torques", "velocity_feed_forward_sent", "torque_feed_forward_sent")
    STATE_FIELD_NUMBER: _ClassVar[int]
    BUFFER_LEVEL_US_FIELD_NUMBER: _ClassVar[int]
    COUNTERS_FIELD_NUMBER: _ClassVar[int]
    CLOCK_OFFSET_US_FIELD_NUMBER: _ClassVar[int]
    COMMANDED_POSITIONS_FIELD_NUMBER: _ClassVar[int]
    ACTUAL_POSITIONS_FIELD_NUMBER: _ClassVar[int]
    EVENTS_FIELD_NUMBER: _ClassVar[int]
    TIMESTAMP_US_FIELD_NUMBER: _ClassVar[int]
    ENDED_FIELD_NUMBER: _ClassVar[int]
    SIGNALS_FIELD_NUMBER: _ClassVar[int]
    COMMANDED_TORQUES_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FEED_FORWARD_SENT_FIELD_NUMBER: _ClassVar[int]
    TORQUE_FEED_FORWARD_SENT_FIELD_NUMBER: _ClassVar[int]
    state: SetpointStreamState
    buffer_level_us: int
    counters: SetpointCounters
    clock_offset_us: int
    commanded_positions: _containers.RepeatedScalarFieldContainer[float]
    actual_positions: _containers.RepeatedScalarFieldContainer[float]
    events: _containers.RepeatedCompositeFieldContainer[SetpointStreamEvent]
    timestamp_us: int
    ended: str
    signals: _containers.RepeatedCompositeFieldContainer[StreamAxisSignals]
    commanded_torques: _containers.RepeatedScalarFieldContainer[float]
    velocity_feed_forward_sent: _containers.RepeatedScalarFieldContainer[bool]
    torque_feed_forward_sent: _containers.RepeatedScalarFieldContainer[bool]
    def __init__(self, state: _Optional[_Union[SetpointStreamState, str]] = ..., buffer_level_us: _Optional[int] = ..., counters: _Optional[_Union[SetpointCounters, _Mapping]] = ..., clock_offset_us: _Optional[int] = ..., commanded_positions: _Optional[_Iterable[float]] = ..., actual_positions: _Optional[_Iterable[float]] = ..., events: _Optional[_Iterable[_Union[SetpointStreamEvent, _Mapping]]] = ..., timestamp_us: _Optional[int] = ..., ended: _Optional[str] = ..., signals: _Optional[_Iterable[_Union[StreamAxisSignals, _Mapping]]] = ..., commanded_torques: _Optional[_Iterable[float]] = ..., velocity_feed_forward_sent: _Optional[_Iterable[bool]] = ..., torque_feed_forward_sent: _Optional[_Iterable[bool]] = ...) -> None: ...

class StreamAxisSignals(_message.Message):
    __slots__ = ("torque_actual", "velocity_actual", "following_error_actual", "digital_inputs")
    TORQUE_ACTUAL_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_ACTUAL_FIELD_NUMBER: _ClassVar[int]
    FOLLOWING_ERROR_ACTUAL_FIELD_NUMBER: _ClassVar[int]
    DIGITAL_INPUTS_FIELD_NUMBER: _ClassVar[int]
    torque_actual: int
    velocity_actual: float
    following_error_actual: float
    digital_inputs: DigitalInputs
    def __init__(self, torque_actual: _Optional[int] = ..., velocity_actual: _Optional[float] = ..., following_error_actual: _Optional[float] = ..., digital_inputs: _Optional[_Union[DigitalInputs, _Mapping]] = ...) -> None: ...

class SetpointStreamEvent(_message.Message):
    __slots__ = ("kind", "reason", "axis", "t_us", "detail")
    KIND_FIELD_NUMBER: _ClassVar[int]
    REASON_FIELD_NUMBER: _ClassVar[int]
    AXIS_FIELD_NUMBER: _ClassVar[int]
    T_US_FIELD_NUMBER: _ClassVar[int]
    DETAIL_FIELD_NUMBER: _ClassVar[int]
    kind: SetpointEventKind
    reason: str
    axis: str
    t_us: int
    detail: str
    def __init__(self, kind: _Optional[_Union[SetpointEventKind, str]] = ..., reason: _Optional[str] = ..., axis: _Optional[str] = ..., t_us: _Optional[int] = ..., detail: _Optional[str] = ...) -> None: ...
