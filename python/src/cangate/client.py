"""A thin typed client of the cangate gateway: buses, CANopen (SDO, NMT,
node events), axes with a control lease, handwheel feed. Every call is
bounded by the client's timeout; every error is a
:class:`~cangate.errors.CangateError` (an SDO abort a
:class:`~cangate.errors.SdoAbortError`). Descriptions of buses, nodes and
axes are the generated messages (typed by their ``.pyi`` stubs); the
generated stubs themselves are at hand for anything not wrapped here
(``client.bus_stub``, ``client.canopen_stub``, ...)."""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass
from typing import Any, Generic, Iterable, Iterator, Optional, Sequence, TypeVar, Union

import grpc

from cangate._channel import open_channel, resolve
from cangate.errors import CangateError, from_rpc_error, from_session_error
from cangate.v1 import (
    axes_pb2,
    axes_pb2_grpc,
    bus_pb2,
    bus_pb2_grpc,
    canopen_pb2,
    canopen_pb2_grpc,
    cansmc_pb2_grpc,
    handwheel_pb2,
    handwheel_pb2_grpc,
)

T = TypeVar("T")


class DataType(enum.IntEnum):
    """CiA 301 basic data types (the object dictionary codes)."""

    BOOLEAN = canopen_pb2.DATA_TYPE_BOOLEAN
    INTEGER8 = canopen_pb2.DATA_TYPE_INTEGER8
    INTEGER16 = canopen_pb2.DATA_TYPE_INTEGER16
    INTEGER32 = canopen_pb2.DATA_TYPE_INTEGER32
    INTEGER64 = canopen_pb2.DATA_TYPE_INTEGER64
    UNSIGNED8 = canopen_pb2.DATA_TYPE_UNSIGNED8
    UNSIGNED16 = canopen_pb2.DATA_TYPE_UNSIGNED16
    UNSIGNED32 = canopen_pb2.DATA_TYPE_UNSIGNED32
    UNSIGNED64 = canopen_pb2.DATA_TYPE_UNSIGNED64
    REAL32 = canopen_pb2.DATA_TYPE_REAL32
    REAL64 = canopen_pb2.DATA_TYPE_REAL64
    VISIBLE_STRING = canopen_pb2.DATA_TYPE_VISIBLE_STRING
    OCTET_STRING = canopen_pb2.DATA_TYPE_OCTET_STRING
    UNICODE_STRING = canopen_pb2.DATA_TYPE_UNICODE_STRING
    DOMAIN = canopen_pb2.DATA_TYPE_DOMAIN


_INTS = {DataType.INTEGER8, DataType.INTEGER16, DataType.INTEGER32, DataType.INTEGER64}
_UINTS = {DataType.UNSIGNED8, DataType.UNSIGNED16, DataType.UNSIGNED32, DataType.UNSIGNED64}
_REALS = {DataType.REAL32, DataType.REAL64}
_STRINGS = {DataType.VISIBLE_STRING, DataType.UNICODE_STRING}

Scalar = Union[bool, int, float, str, bytes]


@dataclass(frozen=True)
class SdoValue:
    """What an SDO read returned: the bytes, and the value decoded by
    `type` (the request's, else the node's EDS; None when neither knew)."""

    raw: bytes
    type: Optional[DataType]
    value: Optional[Scalar]


@dataclass(frozen=True)
class Frame:
    """A CAN frame as a frame stream delivers it (`timestamp_ns`,
    `direction`, `origin` and `sender_id` are the gateway's; ignored when
    sending)."""

    id: int
    data: bytes = b""
    extended: bool = False
    remote: bool = False
    remote_dlc: int = 0
    fd: bool = False
    brs: bool = False
    esi: bool = False
    error: bool = False
    timestamp_ns: int = 0
    direction: int = bus_pb2.DIRECTION_UNSPECIFIED
    origin: int = bus_pb2.FRAME_ORIGIN_UNSPECIFIED
    sender_id: int = 0

    def to_pb(self) -> bus_pb2.Frame:
        """The frame as a protobuf message."""
        return bus_pb2.Frame(
            id=self.id,
            data=self.data,
            extended=self.extended,
            remote=self.remote,
            remote_dlc=self.remote_dlc,
            fd=self.fd,
            brs=self.brs,
            esi=self.esi,
        )

    @classmethod
    def from_pb(cls, f: bus_pb2.Frame) -> "Frame":
        """A protobuf frame."""
        return cls(
            id=f.id,
            data=bytes(f.data),
            extended=f.extended,
            remote=f.remote,
            remote_dlc=f.remote_dlc,
            fd=f.fd,
            brs=f.brs,
            esi=f.esi,
            error=f.error,
            timestamp_ns=f.timestamp_ns,
            direction=f.direction,
            origin=f.origin,
            sender_id=f.sender.id if f.HasField("sender") else 0,
        )


@dataclass(frozen=True)
class FramesLost:
    """The gateway dropped `count` frames for this stream here (it was read
    too slowly)."""

    count: int


def _value_to_pb(value: Scalar, type: DataType) -> canopen_pb2.Value:
    t = DataType(type)
    if t == DataType.BOOLEAN:
        return canopen_pb2.Value(type=t, bool_value=bool(value))
    if t in _INTS:
        return canopen_pb2.Value(type=t, int_value=int(value))
    if t in _UINTS:
        return canopen_pb2.Value(type=t, uint_value=int(value))
    if t in _REALS:
        return canopen_pb2.Value(type=t, real_value=float(value))
    if t in _STRINGS:
        return canopen_pb2.Value(type=t, string_value=str(value))
    return canopen_pb2.Value(type=t, bytes_value=bytes(value))  # type: ignore[arg-type]


def _value_from_pb(v: canopen_pb2.Value) -> tuple[Optional[DataType], Optional[Scalar]]:
    kind = v.WhichOneof("value")
    if kind is None:
        return None, None
    t = DataType(v.type) if v.type in DataType._value2member_map_ else None
    return t, getattr(v, kind)


class Stream(Generic[T]):
    """A server stream as an iterator. Errors are raised as
    :class:`CangateError`; :meth:`cancel` (or leaving a ``with`` block)
    ends it, after which iteration stops quietly."""

    def __init__(self, call: Any, convert: Any) -> None:
        self._call = call
        self._convert = convert
        self._cancelled = False

    def __iter__(self) -> Iterator[T]:
        try:
            for message in self._call:
                yield from self._convert(message)
        except grpc.RpcError as err:
            if self._cancelled and err.code() == grpc.StatusCode.CANCELLED:
                return
            raise from_rpc_error(err) from None

    def cancel(self) -> None:
        """Ends the stream."""
        self._cancelled = True
        self._call.cancel()

    def __enter__(self) -> "Stream[T]":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.cancel()


def _one(message: Any) -> Iterator[Any]:
    yield message


def _batch_events(batch: Any) -> Iterator[Any]:
    yield from batch.events


def _frame_events(response: Any) -> Iterator[Union[Frame, FramesLost, bus_pb2.BusStatus]]:
    for ev in response.events:
        kind = ev.WhichOneof("event")
        if kind == "frame":
            yield Frame.from_pb(ev.frame)
        elif kind == "lost":
            yield FramesLost(ev.lost.count)
        elif kind == "state":
            yield ev.state


_NMT = {
    "start": canopen_pb2.NMT_COMMAND_START,
    "stop": canopen_pb2.NMT_COMMAND_STOP,
    "preop": canopen_pb2.NMT_COMMAND_ENTER_PRE_OPERATIONAL,
    "reset": canopen_pb2.NMT_COMMAND_RESET_NODE,
    "reset-comm": canopen_pb2.NMT_COMMAND_RESET_COMMUNICATION,
}


class Client:
    """A connection to a cangate gateway.

    :param server: "host:port", "http://host:port" or "https://host:port";
        default ``CANGATE_SERVER``, else ``http://127.0.0.1:50051``.
    :param token: bearer token; default ``CANGATE_TOKEN``.
    :param ca: PEM file of the CA to trust (enables TLS).
    :param cert: PEM client certificate for mTLS, with `key`.
    :param key: PEM private key of `cert`.
    :param timeout: seconds each unary call may take (streams: unbounded).
    """

    def __init__(
        self,
        server: Optional[str] = None,
        token: Optional[str] = None,
        *,
        ca: Optional[str] = None,
        cert: Optional[str] = None,
        key: Optional[str] = None,
        timeout: float = 10.0,
    ) -> None:
        self.server, token = resolve(server, token)
        self.timeout = timeout
        self.channel = open_channel(self.server, token, ca=ca, cert=cert, key=key)
        self.bus_stub = bus_pb2_grpc.BusStub(self.channel)
        self.canopen_stub = canopen_pb2_grpc.CanopenStub(self.channel)
        self.axes_stub = axes_pb2_grpc.AxesStub(self.channel)
        self.handwheels_stub = handwheel_pb2_grpc.HandwheelsStub(self.channel)
        self.simulator_stub = handwheel_pb2_grpc.SimulatorStub(self.channel)
        self.cansmc_stub = cansmc_pb2_grpc.CansmcStub(self.channel)

    def close(self) -> None:
        """Closes the connection (open streams end)."""
        self.channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _call(self, method: Any, request: Any, timeout: Optional[float] = None) -> Any:
        try:
            return method(request, timeout=timeout or self.timeout)
        except grpc.RpcError as err:
            raise from_rpc_error(err) from None

    # ------------------------------------------------------------ buses

    def list_buses(self) -> list[bus_pb2.BusInfo]:
        """Every bus with its configuration, state and counters."""
        return list(self._call(self.bus_stub.ListBuses, bus_pb2.ListBusesRequest()).buses)

    def get_bus(self, bus: str) -> bus_pb2.BusInfo:
        """One bus by name."""
        return self._call(self.bus_stub.GetBus, bus_pb2.GetBusRequest(bus=bus))

    def send_frames(self, bus: str, frames: Iterable[Frame]) -> int:
        """Sends frames in order (all or none are accepted); the count."""
        request = bus_pb2.SendFramesRequest(bus=bus, frames=[f.to_pb() for f in frames])
        return self._call(self.bus_stub.SendFrames, request).sent

    def stream_frames(
        self,
        bus: str,
        filters: Sequence[tuple[int, int]] = (),
        *,
        include_transmitted: bool = False,
        error_frames: bool = False,
        queue_length: int = 0,
    ) -> Stream[Union[Frame, FramesLost, bus_pb2.BusStatus]]:
        """Frames of `bus` passing any of `filters` ((id, mask) pairs; none:
        all), lost-frame notices, and the bus state (first, then changes)."""
        request = bus_pb2.StreamFramesRequest(
            bus=bus,
            filters=[bus_pb2.FrameFilter(id=i, mask=m) for i, m in filters],
            include_transmitted=include_transmitted,
            include_error_frames=error_frames,
            queue_length=queue_length,
            # Each frame at once: grpcio has no limit on small messages
            # (see StreamFramesRequest.low_latency).
            low_latency=True,
        )
        return Stream(self.bus_stub.StreamFrames(request), _frame_events)

    # ------------------------------------------------------------ CANopen

    def list_nodes(self, bus: str = "") -> list[canopen_pb2.Node]:
        """The CANopen nodes known on `bus` (every CANopen bus when empty)."""
        return list(self._call(self.canopen_stub.ListNodes, canopen_pb2.ListNodesRequest(bus=bus)).nodes)

    def get_node(self, bus: str, node: int) -> canopen_pb2.Node:
        """One node as the master knows it."""
        return self._call(self.canopen_stub.GetNode, canopen_pb2.GetNodeRequest(bus=bus, node=node))

    def send_nmt(self, bus: str, node: int, command: Union[str, int]) -> None:
        """Sends an NMT command ("start", "stop", "preop", "reset",
        "reset-comm" or an NmtCommand value) to a node, or all with 0."""
        cmd = _NMT[command] if isinstance(command, str) else command
        self._call(
            self.canopen_stub.SendNmt, canopen_pb2.SendNmtRequest(bus=bus, node=node, command=cmd)
        )

    def read_sdo(
        self,
        bus: str,
        node: int,
        index: int,
        subindex: int = 0,
        type: Optional[DataType] = None,
        *,
        block: bool = False,
        timeout_ms: int = 0,
    ) -> SdoValue:
        """Reads an object over SDO, decoded as `type` (else by the node's
        EDS when the gateway has it). Raises :class:`SdoAbortError`."""
        request = canopen_pb2.ReadSdoRequest(
            bus=bus,
            node=node,
            index=index,
            subindex=subindex,
            type=int(type) if type is not None else 0,
            options=canopen_pb2.SdoOptions(timeout_ms=timeout_ms, block=block),
        )
        r = self._call(self.canopen_stub.ReadSdo, request, self._sdo_timeout(timeout_ms))
        t, v = _value_from_pb(r.value) if r.HasField("value") else (None, None)
        return SdoValue(raw=bytes(r.raw), type=t, value=v)

    def write_sdo(
        self,
        bus: str,
        node: int,
        index: int,
        subindex: int,
        value: Scalar,
        type: Optional[DataType] = None,
        *,
        block: bool = False,
        timeout_ms: int = 0,
    ) -> int:
        """Writes an object over SDO: `value` encoded as `type`, or raw
        bytes when no type is given. Returns the bytes written."""
        options = canopen_pb2.SdoOptions(timeout_ms=timeout_ms, block=block)
        common = dict(bus=bus, node=node, index=index, subindex=subindex, options=options)
        if type is None:
            if not isinstance(value, (bytes, bytearray)):
                raise TypeError("a value without a type must be bytes")
            request = canopen_pb2.WriteSdoRequest(raw=bytes(value), **common)
        else:
            request = canopen_pb2.WriteSdoRequest(value=_value_to_pb(value, type), **common)
        return self._call(self.canopen_stub.WriteSdo, request, self._sdo_timeout(timeout_ms)).bytes

    def sdo_session(self, bus: str) -> "SdoSession":
        """An SDO session on `bus` (Canopen.SdoSession): pipelined reads and
        writes on one stream, answered as futures (see :class:`SdoSession`);
        a context manager that closes it."""
        return SdoSession(self, bus)

    def _sdo_timeout(self, timeout_ms: int) -> float:
        # A large transfer takes many answers of the node: the client's
        # timeout per call, and at least 10 answer timeouts.
        return max(self.timeout, 10 * timeout_ms / 1000.0)

    def node_events(self, bus: str = "", nodes: Sequence[int] = ()) -> Stream[canopen_pb2.NodeEvent]:
        """Boot-ups, state changes, heartbeat loss/recovery and EMCYs."""
        request = canopen_pb2.StreamNodeEventsRequest(bus=bus, nodes=list(nodes))
        return Stream(self.canopen_stub.StreamNodeEvents(request), _one)

    def pdos(self, bus: str = "", nodes: Sequence[int] = ()) -> Stream[canopen_pb2.PdoMessage]:
        """Decoded TPDOs as they arrive."""
        request = canopen_pb2.StreamPdoRequest(bus=bus, nodes=list(nodes))
        return Stream(self.canopen_stub.StreamPdo(request), _one)

    # ------------------------------------------------------------ axes

    def list_axes(self) -> list[axes_pb2.Axis]:
        """Every axis with its live state."""
        return list(self._call(self.axes_stub.ListAxes, axes_pb2.ListAxesRequest()).axes)

    def get_axis(self, axis: str) -> axes_pb2.Axis:
        """One axis."""
        return self._call(self.axes_stub.GetAxis, axes_pb2.GetAxisRequest(axis=axis))

    def axis(self, name: str) -> "AxisHandle":
        """A handle on one axis (state, stops, :meth:`AxisHandle.control`)."""
        return AxisHandle(self, name)

    def control(self, *axes: str, ttl_ms: int = 2000, name: str = "") -> "Lease":
        """A control lease over `axes`, as a context manager (see
        :class:`Lease`)."""
        return Lease(self, list(axes), ttl_ms=ttl_ms, name=name)

    def stop_axes(
        self, axes: Sequence[str], *, quick: bool = False, wait: bool = False
    ) -> list[axes_pb2.AxisCommandResponse]:
        """Stops several axes at once (no lease needed)."""
        request = axes_pb2.StopAxesRequest(axes=list(axes), quick=quick, wait=wait)
        timeout = max(self.timeout, 60.0) if wait else None
        return list(self._call(self.axes_stub.StopAxes, request, timeout).results)

    def axis_states(self, axes: Sequence[str] = (), *, changes_only: bool = False) -> Stream[axes_pb2.AxisUpdate]:
        """Live statuses and events of axes (all when empty)."""
        request = axes_pb2.StreamAxisStateRequest(axes=list(axes), changes_only=changes_only)
        return Stream(self.axes_stub.StreamAxisState(request), _one)

    # ------------------------------------------------------------ handwheels

    def list_handwheels(self) -> list[handwheel_pb2.Handwheel]:
        """Every configured handwheel."""
        r = self._call(self.handwheels_stub.ListHandwheels, handwheel_pb2.ListHandwheelsRequest())
        return list(r.handwheels)

    def set_handwheel_mode(self, handwheel: str, manual: bool) -> handwheel_pb2.Handwheel:
        """Manual (the wheel sends feed) or automatic mode."""
        mode = handwheel_pb2.HANDWHEEL_MODE_MANUAL if manual else handwheel_pb2.HANDWHEEL_MODE_AUTOMATIC
        request = handwheel_pb2.SetModeRequest(handwheel=handwheel, mode=mode)
        return self._call(self.handwheels_stub.SetMode, request)

    def feed(self, handwheels: Sequence[str] = (), *, coalesce_ms: int = 0) -> Stream[handwheel_pb2.FeedEvent]:
        """Feed events of handwheels (all when empty), one per frame or per
        `coalesce_ms` window."""
        request = handwheel_pb2.StreamFeedRequest(handwheels=list(handwheels), coalesce_ms=coalesce_ms)
        # Batches: fewer messages when the gateway falls behind; the events
        # come out one by one all the same.
        return Stream(self.handwheels_stub.StreamFeedBatches(request), _batch_events)


class SdoSession:
    """Reads and writes over SDO on one stream (Canopen.SdoSession).

    :meth:`read` and :meth:`write` send their request at once and return a
    :class:`concurrent.futures.Future` of the answer, so many can be
    outstanding: the gateway answers those of one node in the order they
    were sent, different nodes concurrently (at most 64 outstanding; more
    wait in the transport). A failed request's future raises what
    :meth:`Client.read_sdo` / :meth:`Client.write_sdo` would
    (:class:`SdoAbortError`, :class:`CangateError`); the session goes on.
    :meth:`close` waits for every answer; :meth:`cancel` drops what is
    outstanding (the gateway aborts those transfers)."""

    _END = object()

    def __init__(self, client: Client, bus: str) -> None:
        import concurrent.futures
        import queue

        self._futures_mod = concurrent.futures
        self.bus = bus
        self._requests: "queue.Queue[Any]" = queue.Queue()
        self._pending: dict[int, Any] = {}
        self._lock = threading.Lock()
        self._next_id = 1
        self._closed = False
        self._call = client.canopen_stub.SdoSession(iter(self._requests.get, self._END))
        self._reader = threading.Thread(target=self._read_answers, daemon=True)
        self._reader.start()

    def _read_answers(self) -> None:
        error: Optional[CangateError] = None
        try:
            for answer in self._call:
                with self._lock:
                    future = self._pending.pop(answer.id, None)
                if future is None:
                    continue
                kind = answer.WhichOneof("result")
                if kind == "error":
                    future.set_exception(from_session_error(answer.error))
                elif kind == "read":
                    r = answer.read
                    t, v = _value_from_pb(r.value) if r.HasField("value") else (None, None)
                    future.set_result(SdoValue(raw=bytes(r.raw), type=t, value=v))
                else:
                    future.set_result(answer.write.bytes)
        except grpc.RpcError as err:
            error = from_rpc_error(err)
        with self._lock:
            self._closed = True
            left, self._pending = self._pending, {}
        for future in left.values():
            future.set_exception(
                error or CangateError(grpc.StatusCode.CANCELLED, "the SDO session ended", "CANCELLED", {})
            )

    def _send(self, build: Any) -> Any:
        future = self._futures_mod.Future()
        with self._lock:
            if self._closed:
                raise CangateError(grpc.StatusCode.CANCELLED, "the SDO session is closed", "CANCELLED", {})
            request_id = self._next_id
            self._next_id += 1
            self._pending[request_id] = future
            self._requests.put(build(request_id))
        return future

    def read(
        self,
        node: int,
        index: int,
        subindex: int = 0,
        type: Optional[DataType] = None,
        *,
        block: bool = False,
        timeout_ms: int = 0,
    ) -> "Any":
        """Sends a read (as :meth:`Client.read_sdo`); a future of its
        :class:`SdoValue`."""
        read = canopen_pb2.ReadSdoRequest(
            bus=self.bus,
            node=node,
            index=index,
            subindex=subindex,
            type=int(type) if type is not None else 0,
            options=canopen_pb2.SdoOptions(timeout_ms=timeout_ms, block=block),
        )
        return self._send(lambda i: canopen_pb2.SdoSessionRequest(id=i, read=read))

    def write(
        self,
        node: int,
        index: int,
        subindex: int,
        value: Scalar,
        type: Optional[DataType] = None,
        *,
        block: bool = False,
        timeout_ms: int = 0,
    ) -> "Any":
        """Sends a write (as :meth:`Client.write_sdo`); a future of the
        bytes written."""
        options = canopen_pb2.SdoOptions(timeout_ms=timeout_ms, block=block)
        common = dict(bus=self.bus, node=node, index=index, subindex=subindex, options=options)
        if type is None:
            if not isinstance(value, (bytes, bytearray)):
                raise TypeError("a value without a type must be bytes")
            write = canopen_pb2.WriteSdoRequest(raw=bytes(value), **common)
        else:
            write = canopen_pb2.WriteSdoRequest(value=_value_to_pb(value, type), **common)
        return self._send(lambda i: canopen_pb2.SdoSessionRequest(id=i, write=write))

    def close(self) -> None:
        """Ends the session after every outstanding request is answered."""
        with self._lock:
            if self._closed:
                return
            self._requests.put(self._END)
        self._reader.join()

    def cancel(self) -> None:
        """Ends the session now: outstanding transfers are aborted, their
        futures fail."""
        self._call.cancel()
        self._reader.join()

    def __enter__(self) -> "SdoSession":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class AxisHandle:
    """One axis by name: its state, stops (no lease needed) and
    :meth:`control`."""

    def __init__(self, client: Client, name: str) -> None:
        self.client = client
        self.name = name

    def get(self) -> axes_pb2.Axis:
        """The axis with its live state."""
        return self.client.get_axis(self.name)

    def stop(self, *, quick: bool = False, wait: bool = False) -> axes_pb2.AxisCommandResponse:
        """Stops the axis (profile deceleration, or quick stop)."""
        return self.client.stop_axes([self.name], quick=quick, wait=wait)[0]

    def control(self, *, ttl_ms: int = 2000, name: str = "") -> "Lease":
        """A control lease over this axis (``with axis.control() as ax:
        ax.move(10.0)``)."""
        return Lease(self.client, [self.name], ttl_ms=ttl_ms, name=name)

    def states(self, *, changes_only: bool = False) -> Stream[axes_pb2.AxisUpdate]:
        """Live statuses and events of this axis."""
        return self.client.axis_states([self.name], changes_only=changes_only)


class Lease:
    """Control of axes for the duration of a ``with`` block.

    Entering acquires the lease (all axes or none) and starts a thread that
    renews it every third of its TTL. Leaving releases it; leaving with an
    exception first stops the axes (as the gateway would when the lease
    lapsed, but at once). A renewal that fails (the lease lapsed: the
    gateway already stopped the axes) is raised by the next command.

    The commands take the axis name, which may be left out when the lease
    covers one axis. ``wait=True`` returns when the command completed (the
    gateway's `wait`); otherwise when the drive accepted it.
    """

    def __init__(self, client: Client, axes: list[str], *, ttl_ms: int = 2000, name: str = "") -> None:
        if not axes:
            raise ValueError("a lease needs at least one axis")
        self.client = client
        self.axes = axes
        self.ttl_ms = ttl_ms
        self.name = name
        self.token: Optional[str] = None
        self.holder = ""
        self._stop = threading.Event()
        self._renewer: Optional[threading.Thread] = None
        self._renew_error: Optional[CangateError] = None

    def __enter__(self) -> "Lease":
        request = axes_pb2.AcquireControlRequest(axes=self.axes, ttl_ms=self.ttl_ms, client_name=self.name)
        lease = self.client._call(self.client.axes_stub.AcquireControl, request)
        self.token, self.holder, self.ttl_ms = lease.lease, lease.holder, lease.ttl_ms
        self._renewer = threading.Thread(target=self._renew, name="cangate-lease", daemon=True)
        self._renewer.start()
        return self

    def _renew(self) -> None:
        period = max(self.ttl_ms / 3000.0, 0.03)
        while not self._stop.wait(period):
            try:
                self.client._call(
                    self.client.axes_stub.RenewControl,
                    axes_pb2.RenewControlRequest(lease=self.token),
                    timeout=period,
                )
            except CangateError as err:
                if err.reason == "LEASE_UNKNOWN":
                    self._renew_error = err
                    return
                # A renewal that timed out: the next one may make it.

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        self._stop.set()
        if self._renewer is not None:
            self._renewer.join(timeout=5.0)
        try:
            if exc_type is not None:
                self.client.stop_axes(self.axes)
        finally:
            try:
                self.client._call(
                    self.client.axes_stub.ReleaseControl, axes_pb2.ReleaseControlRequest(lease=self.token)
                )
            except CangateError as err:
                if exc_type is None and err.reason != "LEASE_UNKNOWN":
                    raise

    def _axis(self, axis: Optional[str]) -> str:
        if axis is not None:
            return axis
        if len(self.axes) != 1:
            raise ValueError(f"name the axis: the lease covers {self.axes}")
        return self.axes[0]

    def _options(self, wait: bool, wait_timeout_ms: int) -> axes_pb2.CommandOptions:
        if self._renew_error is not None:
            raise self._renew_error
        return axes_pb2.CommandOptions(lease=self.token, wait=wait, wait_timeout_ms=wait_timeout_ms)

    def _timeout(self, wait: bool, wait_timeout_ms: int) -> Optional[float]:
        if not wait:
            return None
        return (wait_timeout_ms or 60_000) / 1000.0 + self.client.timeout

    def _simple(self, method: Any, axis: Optional[str], wait: bool, wait_timeout_ms: int) -> axes_pb2.AxisCommandResponse:
        request = axes_pb2.AxisCommandRequest(axis=self._axis(axis), options=self._options(wait, wait_timeout_ms))
        return self.client._call(method, request, self._timeout(wait, wait_timeout_ms))

    def enable(self, axis: Optional[str] = None, *, wait: bool = False, wait_timeout_ms: int = 0) -> axes_pb2.AxisCommandResponse:
        """Switches the drive on (to operation enabled)."""
        return self._simple(self.client.axes_stub.Enable, axis, wait, wait_timeout_ms)

    def disable(self, axis: Optional[str] = None, *, wait: bool = False, wait_timeout_ms: int = 0) -> axes_pb2.AxisCommandResponse:
        """Switches the power stage off."""
        return self._simple(self.client.axes_stub.Disable, axis, wait, wait_timeout_ms)

    def home(self, axis: Optional[str] = None, *, wait: bool = False, wait_timeout_ms: int = 0) -> axes_pb2.AxisCommandResponse:
        """Runs the configured homing method."""
        return self._simple(self.client.axes_stub.Home, axis, wait, wait_timeout_ms)

    def reset_fault(self, axis: Optional[str] = None, *, wait: bool = False, wait_timeout_ms: int = 0) -> axes_pb2.AxisCommandResponse:
        """Resets a drive fault (then enable again)."""
        return self._simple(self.client.axes_stub.ResetFault, axis, wait, wait_timeout_ms)

    def arm_touch_probe(
        self, edge: str = "rising", axis: Optional[str] = None, *, continuous: bool = False
    ) -> axes_pb2.AxisCommandResponse:
        """Arms touch probe 1 of a CiA 402 axis on its "rising", "falling" or
        "both" edges (the first event only, or every one with
        ``continuous=True``); "off" switches it off. Returns once the drive
        confirmed it; each latch comes as a ``touch_probe`` event in
        ``states()``, with the position in user units."""
        edges = {
            "off": axes_pb2.TOUCH_PROBE_EDGE_UNSPECIFIED,
            "rising": axes_pb2.TOUCH_PROBE_EDGE_RISING,
            "falling": axes_pb2.TOUCH_PROBE_EDGE_FALLING,
            "both": axes_pb2.TOUCH_PROBE_EDGE_BOTH,
        }
        if edge not in edges:
            raise ValueError(f"edge must be one of {sorted(edges)}, not {edge!r}")
        request = axes_pb2.ArmTouchProbeRequest(
            axis=self._axis(axis), edge=edges[edge], continuous=continuous, options=self._options(False, 0)
        )
        return self.client._call(self.client.axes_stub.ArmTouchProbe, request)

    def stop(self, axis: Optional[str] = None, *, quick: bool = False, wait: bool = False) -> axes_pb2.AxisCommandResponse:
        """Stops the axis (the lease is not needed for this)."""
        method = self.client.axes_stub.QuickStop if quick else self.client.axes_stub.Stop
        return self._simple(method, axis, wait, 0)

    def move(
        self,
        target: float,
        axis: Optional[str] = None,
        *,
        relative: bool = False,
        velocity: float = 0.0,
        acceleration: float = 0.0,
        wait: bool = False,
        wait_timeout_ms: int = 0,
    ) -> axes_pb2.AxisCommandResponse:
        """Moves to `target` (or by it, `relative`) in the axis's unit;
        velocity and acceleration 0 are the axis's defaults."""
        request = axes_pb2.MoveRequest(
            axis=self._axis(axis),
            target=target,
            relative=relative,
            velocity=velocity,
            acceleration=acceleration,
            options=self._options(wait, wait_timeout_ms),
        )
        return self.client._call(self.client.axes_stub.Move, request, self._timeout(wait, wait_timeout_ms))

    def jog(self, velocity: float, axis: Optional[str] = None, *, acceleration: float = 0.0) -> axes_pb2.AxisCommandResponse:
        """Moves at a signed velocity; a dead-man: repeat it within the
        axis's ``jog_deadman_ms`` or the axis stops."""
        request = axes_pb2.JogRequest(
            axis=self._axis(axis),
            velocity=velocity,
            acceleration=acceleration,
            options=self._options(False, 0),
        )
        return self.client._call(self.client.axes_stub.Jog, request)

    def stream_setpoints(
        self,
        batches: Iterable[Sequence[tuple[int, Sequence[float]]]],
        axes: Optional[Sequence[str]] = None,
        *,
        depth_ms: int = 20,
        extrapolate_ms: int = 0,
        point_period_us: int = 0,
        status_period_ms: int = 0,
        velocities: bool = False,
        torques: bool = False,
    ) -> Stream[axes_pb2.SetpointStreamStatus]:
        """Streams time-stamped set-points into the gateway's jitter buffer
        (``Axes.StreamSetpoints``), played on the SYNC grid of cyclic axes.

        `batches` yields lists of points ``(t_us, positions)``: the client's
        clock in µs (any origin, increasing) and one position per axis of
        `axes` (default: the lease's axes), in user units. With
        ``velocities=True`` (axes in csv) the points are ``(t_us,
        velocities)``: one velocity per axis in user units/s, starting from
        rest; the gateway sends each SYNC's velocity in 0x60FF. With
        ``torques=True`` (axes in cst) the points are ``(t_us, torques)``:
        one torque per axis in per mille of the rated torque, starting from
        0; the gateway sends each SYNC's torque in 0x6071 and, whenever the
        stream ends, ramps the torques to 0 and halts the drives. gRPC iterates it
        in its own thread, so a generator may pace itself (sleep until its
        points are due). When it ends, the gateway plays the buffered points,
        ramps the axes to rest and ends the returned stream of
        ``SetpointStreamStatus`` (buffer level, counters, clock offset,
        positions, events: UNDERRUN, refused points with their reason). A
        stop of one of the axes, a lost lease or a drive leaving operation
        enabled ends it with :class:`CangateError` (ABORTED).
        """
        names = list(axes) if axes is not None else list(self.axes)
        opening = axes_pb2.SetpointStreamOpen(
            axes=names,
            lease=self._options(False, 0).lease,
            depth_ms=depth_ms,
            extrapolate_ms=extrapolate_ms,
            point_period_us=point_period_us,
            status_period_ms=status_period_ms,
        )

        def requests() -> Iterator[axes_pb2.SetpointStreamRequest]:
            yield axes_pb2.SetpointStreamRequest(open=opening)
            for batch in batches:
                if torques:
                    points = [axes_pb2.Setpoint(t_us=t, torques=list(v)) for t, v in batch]
                elif velocities:
                    points = [axes_pb2.Setpoint(t_us=t, velocities=list(v)) for t, v in batch]
                else:
                    points = [axes_pb2.Setpoint(t_us=t, positions=list(p)) for t, p in batch]
                yield axes_pb2.SetpointStreamRequest(batch=axes_pb2.SetpointBatch(points=points))

        return Stream(self.client.axes_stub.StreamSetpoints(requests()), _one)

    def move_axes(self, targets: dict, *, wait: bool = False) -> list[axes_pb2.AxisCommandResponse]:
        """A coordinated move of cyclic axes: {axis: target}."""
        request = axes_pb2.MoveAxesRequest(
            targets=[axes_pb2.AxisTarget(axis=a, target=t) for a, t in targets.items()],
            lease=self._options(wait, 0).lease,
            wait=wait,
        )
        timeout = 120.0 + self.client.timeout if wait else None
        return list(self.client._call(self.client.axes_stub.MoveAxes, request, timeout).results)
