"""A python-can interface on the gateway's ``Bus.Attach``: any python-can
program (python-canopen, cantools, can.logger, ...) becomes a node on a bus
of a remote cangate gateway::

    import can
    with can.Bus(interface="cangate", channel="can0") as bus:
        bus.send(can.Message(arbitration_id=0x123, data=b"\\x01\\x02"))
        print(bus.recv(timeout=1.0))

Registered through the ``can.interface`` entry point as ``cangate``. The
server is the ``server`` argument, else ``CANGATE_SERVER``, else
``http://127.0.0.1:50051``; the token ``token``, else ``CANGATE_TOKEN``.

How it maps onto Attach (proto/cangate/v1/bus.proto):

- the bus is one Attach stream, owned by a background thread; frames are
  received with the gateway's timestamps (``Message.timestamp``: seconds
  since the UNIX epoch) and ``is_rx`` False for own frames;
- ``can_filters`` become the AttachOpen filters: the gateway applies them,
  exactly (same semantics as python-can's); setting other filters later
  re-attaches with them;
- ``receive_own_messages`` is AttachOpen.receive_own;
- CAN FD (``fd``, default: what the gateway's bus is), BRS, ESI, remote and
  extended frames, error frames with ``error_frames=True``;
- the gateway processes sent messages in order and answers each: done
  once its frame went out (AttachEvent.done), or refused (raw frame budget
  spent, bus off, malformed frame: AttachEvent.refused). ``send`` waits
  for the answer (at most its ``timeout``) and raises a refusal as
  ``can.CanOperationError`` with the gateway's reason; with
  ``confirm_send=False`` it returns once the message is queued, and a
  refusal is raised by the next ``send``;
- ``shutdown`` (the end of a ``with`` block) sends what ``send`` queued
  and waits for the gateway's answers, at most ``shutdown_timeout``
  seconds, before it closes; what was refused or not confirmed in that
  time is raised as ``can.CanOperationError`` (after the bus was closed);
- frames the gateway dropped because this program read too slowly, and
  frames dropped here when ``receive_buffer`` is full (as a socket's
  receive buffer drops them), are counted in ``frames_lost`` and logged as
  warnings: the stream is always read, so the answers to ``send`` never
  wait behind unread frames;
- the stream ending with an error (gateway shutdown, a protocol error) is
  raised by the next ``recv``/``send`` as ``can.CanOperationError`` with the
  server's message, once the frames received before it were read;
- ``send_periodic`` runs the job in the gateway (AttachCyclic): its frames
  go out at the period whatever this program does, as this bus's frames,
  in its frame budget; the task's ``stop()``, ``modify_data()`` (new data,
  the timer going on) and ``start()`` (again, after a stop) are answered
  by the gateway, and a refusal (a period below 1 ms, the job limit) is
  raised as ``can.CanOperationError``. The job ends with the task's
  ``stop()``, its ``duration``, ``shutdown``, or the stream (this program
  gone): nothing keeps sending for a dead client. A job the gateway ended
  (its frames refused: the frame budget, bus-off) is logged and
  ``task.stopped_by_gateway`` says why. With a ``modifier_callback``
  (Python code per frame) python-can's own thread sends instead.
"""

from __future__ import annotations

import collections
import itertools
import logging
import queue
import threading
from typing import Any, Optional

import can
import grpc
from can import CanProtocol
from can.broadcastmanager import (
    LimitedDurationCyclicSendTaskABC,
    ModifiableCyclicTaskABC,
    RestartableCyclicTaskABC,
)

from cangate._channel import open_channel, resolve
from cangate.errors import from_rpc_error
from cangate.v1 import bus_pb2, bus_pb2_grpc

log = logging.getLogger("can.cangate")

_MAX_ID = 0x1FFF_FFFF
_END = object()


def _filters_to_pb(filters: Optional[Any]) -> Optional[list]:
    """python-can filters as AttachOpen filters, or None when the gateway
    cannot apply them exactly (bits above the 29-bit range)."""
    out = []
    for f in filters or ():
        can_id, mask = int(f["can_id"]), int(f["can_mask"])
        if (can_id & mask) > _MAX_ID:
            return None
        fmt = bus_pb2.ID_FORMAT_ANY
        if "extended" in f:
            fmt = bus_pb2.ID_FORMAT_EXTENDED if f["extended"] else bus_pb2.ID_FORMAT_STANDARD
        out.append(bus_pb2.FrameFilter(id=can_id & mask & _MAX_ID, mask=mask & _MAX_ID, format=fmt))
    return out


def message_to_frame(msg: can.Message) -> bus_pb2.Frame:
    """A python-can message as a frame to send."""
    if msg.is_error_frame:
        raise ValueError("error frames cannot be sent")
    if msg.is_remote_frame:
        return bus_pb2.Frame(
            id=msg.arbitration_id,
            extended=msg.is_extended_id,
            remote=True,
            remote_dlc=msg.dlc,
        )
    return bus_pb2.Frame(
        id=msg.arbitration_id,
        extended=msg.is_extended_id,
        fd=msg.is_fd,
        brs=msg.bitrate_switch,
        esi=msg.error_state_indicator,
        data=bytes(msg.data or b""),
    )


def frame_to_message(frame: bus_pb2.Frame, channel: str) -> can.Message:
    """A streamed frame as a python-can message (timestamp in seconds since
    the UNIX epoch, from the gateway)."""
    return can.Message(
        timestamp=frame.timestamp_ns / 1e9,
        arbitration_id=frame.id,
        is_extended_id=frame.extended,
        is_remote_frame=frame.remote,
        is_error_frame=frame.error,
        is_fd=frame.fd,
        bitrate_switch=frame.brs,
        error_state_indicator=frame.esi,
        dlc=frame.remote_dlc if frame.remote else None,
        data=None if frame.remote else frame.data,
        channel=channel,
        is_rx=frame.direction != bus_pb2.DIRECTION_TX,
        check=False,
    )


class _Attachment:
    """One Attach stream: requests go through a bounded queue that gRPC's
    sending thread drains; a reader thread puts received messages into a
    bounded queue (when it is full, frames are dropped and counted) and
    records the gateway's answers to the messages sent."""

    def __init__(
        self,
        stub: bus_pb2_grpc.BusStub,
        open_msg: bus_pb2.AttachOpen,
        *,
        receive_buffer: int,
        send_buffer: int,
        timeout: float,
    ) -> None:
        self.bus = open_msg.bus
        self.requests: queue.Queue = queue.Queue(maxsize=send_buffer)
        self.received: queue.Queue = queue.Queue(maxsize=receive_buffer)
        self.refusals: collections.deque = collections.deque(maxlen=100)
        # The gateway answers messages in the order sent: every sequence
        # number up to `answered` is done or refused.
        self.answered = 0
        self.last_sent = 0
        # Sequence numbers whose send() waits for the answer: their
        # refusals are theirs to raise, not the next send's.
        self.waiting: set = set()
        self.answers = threading.Condition()
        self.ended = False
        self.lost = 0
        self.state: Optional[bus_pb2.BusStatus] = None
        self.opened: Optional[bus_pb2.AttachOpened] = None
        self.error: Optional[can.CanOperationError] = None
        self._status: Optional[Exception] = None
        # Called with each CyclicStopped (a job the gateway ended).
        self.on_cyclic_stopped = None
        self._closing = threading.Event()
        self._open_done = threading.Event()
        self.requests.put(bus_pb2.AttachRequest(open=open_msg))
        self._call = stub.Attach(self._outgoing())
        self._reader = threading.Thread(
            target=self._read, name=f"cangate-attach-{self.bus}", daemon=True
        )
        self._reader.start()
        if not self._open_done.wait(timeout):
            self.close()
            raise can.CanInitializationError(
                f"cangate: no answer to attaching to {self.bus!r} within {timeout} s"
            )
        if self.opened is None:
            self.close()
            raise can.CanInitializationError(
                f"cangate: attaching to {self.bus!r} failed: {self._status}"
            )

    def _outgoing(self):
        # Runs in gRPC's sending thread; wakes up regularly so that it ends
        # with the attachment.
        while not self._closing.is_set():
            try:
                item = self.requests.get(timeout=0.1)
            except queue.Empty:
                continue
            if item is None:
                return
            yield item

    def _read(self) -> None:
        try:
            for response in self._call:
                for ev in response.events:
                    self._on_event(ev)
            self._status = "the gateway ended the stream"
        except grpc.RpcError as err:
            self._status = from_rpc_error(err)
        except Exception as err:  # noqa: BLE001 - reported, not lost
            self._status = err
        finally:
            self._open_done.set()
            if not self._closing.is_set():
                self.error = can.CanOperationError(
                    f"cangate: the attachment to {self.bus!r} ended: {self._status}"
                )
                if self.opened is not None:  # else the constructor raises it
                    log.error("%s", self.error)
                try:
                    self.received.put_nowait(_END)
                except queue.Full:
                    pass  # the reader of the full queue finds the error after it
            with self.answers:
                self.ended = True
                self.answers.notify_all()

    def _on_event(self, ev: bus_pb2.AttachEvent) -> None:
        kind = ev.WhichOneof("event")
        if kind == "frame":
            msg = frame_to_message(ev.frame, self.bus)
            try:
                self.received.put_nowait(msg)
            except queue.Full:
                # Not read in time: dropped here, like the gateway does for
                # a slow stream, so that the answers behind it still come.
                self.lost += 1
                if self.lost & (self.lost - 1) == 0:  # 1, 2, 4, 8, ...
                    log.warning(
                        "cangate %s: receive buffer full, frames dropped (read too slowly); "
                        "%d in all",
                        self.bus,
                        self.lost,
                    )
        elif kind == "done":
            with self.answers:
                self.answered = max(self.answered, ev.done.sequence)
                self.answers.notify_all()
        elif kind == "lost":
            self.lost += ev.lost.count
            log.warning(
                "cangate %s: the gateway dropped %d frames for this client (read too slowly); "
                "%d in all",
                self.bus,
                ev.lost.count,
                self.lost,
            )
        elif kind == "state":
            self.state = ev.state
            log.info("cangate %s: bus state %s", self.bus, bus_pb2.BusState.Name(ev.state.state))
        elif kind == "refused":
            with self.answers:
                self.refusals.append(ev.refused)
                self.answered = max(self.answered, ev.refused.sequence)
                self.answers.notify_all()
            r = ev.refused
            log.warning(
                "cangate %s: message %d refused (%d of %d frames sent): %s %s",
                self.bus,
                r.sequence,
                r.sent,
                r.total,
                r.reason,
                r.message,
            )
        elif kind == "opened":
            self.opened = ev.opened
            self._open_done.set()
        elif kind == "cyclic_stopped":
            callback = self.on_cyclic_stopped
            if callback is not None:
                callback(ev.cyclic_stopped)

    def wait_answered(self, sequence: int, timeout: Optional[float]) -> bool:
        """Waits until the gateway answered every message up to `sequence`
        (None: as long as the stream lasts); False when it did not in time
        or the stream ended first."""
        with self.answers:
            return self.answers.wait_for(
                lambda: self.answered >= sequence or self.ended,
                timeout,
            ) and self.answered >= sequence

    def take_refusal(self, sequence: Optional[int] = None) -> Optional[list]:
        """The refusals not raised yet (only that of `sequence` when given),
        removed; None when there is none."""
        with self.answers:
            if sequence is None:
                refused = [r for r in self.refusals if r.sequence not in self.waiting]
                for r in refused:
                    self.refusals.remove(r)
            else:
                refused = [r for r in self.refusals if r.sequence == sequence]
                for r in refused:
                    self.refusals.remove(r)
        return refused or None

    def close(self, flush_timeout: float = 0.0) -> Optional[str]:
        """Ends the stream: no more messages; waits up to `flush_timeout`
        seconds for the gateway's answers to the messages queued, then
        cancels the call. Returns what was not sent, for people, or None."""
        unsent = None
        if not self.ended and flush_timeout > 0:
            try:
                # The end of the messages, after those queued (half-close).
                self.requests.put(None, timeout=flush_timeout)
            except queue.Full:
                pass
        if not self.wait_answered(self.last_sent, flush_timeout):
            with self.answers:
                missing = self.last_sent - self.answered
            unsent = f"{missing} of the messages sent were not confirmed by the gateway"
            unsent += f": {self.error}" if self.error else f" within {flush_timeout} s"
        self._closing.set()
        self._call.cancel()
        self._reader.join(timeout=2.0)
        refused = self.take_refusal()
        if refused:
            r = refused[-1]
            text = (
                f"{len(refused)} messages refused by the gateway, the last ({r.sequence}): "
                f"{r.reason}: {r.message}"
            )
            unsent = f"{text}; {unsent}" if unsent else text
        return unsent


class CangateCyclicTask(
    LimitedDurationCyclicSendTaskABC, ModifiableCyclicTaskABC, RestartableCyclicTaskABC
):
    """A cyclic transmission job run by the gateway (``send_periodic``):
    ``stop()``, ``start()`` again, ``modify_data()`` with new data for the
    same identifier and number of messages, the timer going on."""

    def __init__(
        self,
        bus: "CangateBus",
        job: int,
        messages: Any,
        period: float,
        duration: Optional[float],
    ) -> None:
        super().__init__(messages, period, duration)
        self._bus = bus
        self.job = job
        self.running = False
        #: Why the gateway ended the job (its frames refused), if it did.
        self.stopped_by_gateway: Optional[str] = None

    def start(self) -> None:
        """Starts the job (again, after a stop), its timer from now."""
        self._bus._cyclic_start(self)

    def stop(self) -> None:
        """Stops the job: once this returns, none of its frames is sent."""
        self._bus._cyclic_stop(self)

    def modify_data(self, messages: Any) -> None:
        """New data for the job's messages (the same identifier, as many
        messages), sent from the next period on."""
        messages = self._check_and_convert_messages(messages)
        self._check_modified_messages(messages)
        self._bus._cyclic_modify(self, messages)
        self.messages = messages


class CangateBus(can.BusABC):
    """A python-can bus on a cangate gateway's bus, through ``Bus.Attach``.

    :param channel: the gateway's bus name ("can0").
    :param can_filters: python-can filters, applied by the gateway.
    :param server: the gateway ("host:port", "http://…", "https://…");
        default ``CANGATE_SERVER``, else ``http://127.0.0.1:50051``.
    :param token: bearer token; default ``CANGATE_TOKEN``.
    :param receive_own_messages: also receive the frames this bus sent (as
        ``is_rx=False``, once they went out).
    :param fd: handle CAN FD frames; None (default): when the gateway's bus
        is configured for CAN FD.
    :param error_frames: also receive SocketCAN error frames.
    :param queue_length: events the gateway buffers for this client (0: its
        default, 8192).
    :param receive_buffer: received frames held here before the reader
        waits (and the gateway starts dropping, counted in ``frames_lost``).
    :param send_buffer: messages waiting to be sent before ``send`` blocks.
    :param confirm_send: ``send`` returns once the gateway confirmed the
        frame went out, and raises its refusal (default); False: once the
        message is queued, a refusal raised by the next ``send``.
    :param shutdown_timeout: seconds ``shutdown`` waits for the messages
        sent to go out before it closes (and raises for those that did
        not).
    :param connect_timeout: seconds to wait for the gateway when opening.
    :param ca: PEM file of the CA to trust (enables TLS).
    :param cert: PEM client certificate (mTLS), with ``key``.
    :param key: PEM private key of ``cert``.
    """

    def __init__(
        self,
        channel: Any = "can0",
        can_filters: Optional[Any] = None,
        *,
        server: Optional[str] = None,
        token: Optional[str] = None,
        receive_own_messages: bool = False,
        fd: Optional[bool] = None,
        error_frames: bool = False,
        queue_length: int = 0,
        receive_buffer: int = 10_000,
        send_buffer: int = 1_000,
        confirm_send: bool = True,
        shutdown_timeout: float = 5.0,
        connect_timeout: float = 5.0,
        ca: Optional[str] = None,
        cert: Optional[str] = None,
        key: Optional[str] = None,
        **kwargs: Any,
    ) -> None:
        self._server, token = resolve(server, token)
        self.channel = str(channel or "can0")
        self.channel_info = f"cangate {self.channel} on {self._server}"
        self._receive_own = bool(receive_own_messages)
        self._error_frames = bool(error_frames)
        self._queue_length = int(queue_length)
        self._buffers = (int(receive_buffer), int(send_buffer))
        self._timeout = float(connect_timeout)
        self._confirm = bool(confirm_send)
        self._shutdown_timeout = float(shutdown_timeout)
        self._sequence = itertools.count(1)
        # Sequence numbers are taken and queued together: the gateway
        # answers in the order of the messages.
        self._send_lock = threading.Lock()
        self._lost_before = 0
        self._jobs = itertools.count(1)
        # The cyclic tasks running in the gateway, by job number.
        self._cyclic: dict = {}
        self._attachment: Optional[_Attachment] = None
        self._grpc = open_channel(self._server, token, ca=ca, cert=cert, key=key)
        self._stub = bus_pb2_grpc.BusStub(self._grpc)
        try:
            if fd is None:
                try:
                    info = self._stub.GetBus(
                        bus_pb2.GetBusRequest(bus=self.channel), timeout=self._timeout
                    )
                except grpc.RpcError as err:
                    raise can.CanInitializationError(
                        f"cangate: bus {self.channel!r} on {self._server}: {from_rpc_error(err)}"
                    ) from err
                fd = info.fd
            self._fd = bool(fd)
            self._can_protocol = CanProtocol.CAN_FD if self._fd else CanProtocol.CAN_20
            self._server_filters = _filters_to_pb(can_filters)
            self._attachment = self._attach(self._server_filters or [])
        except BaseException:
            self._grpc.close()
            raise
        super().__init__(channel=self.channel, can_filters=can_filters, **kwargs)

    def _attach(self, filters: list) -> _Attachment:
        open_msg = bus_pb2.AttachOpen(
            bus=self.channel,
            filters=filters,
            receive_own=self._receive_own,
            fd=self._fd,
            include_error_frames=self._error_frames,
            queue_length=self._queue_length,
            # Every frame at once: a python-can program waits for answers
            # (an SDO response) one by one, and grpcio tolerates the small
            # messages this makes (see AttachOpen.low_latency).
            low_latency=True,
        )
        attachment = _Attachment(
            self._stub,
            open_msg,
            receive_buffer=self._buffers[0],
            send_buffer=self._buffers[1],
            timeout=self._timeout,
        )
        attachment.on_cyclic_stopped = self._on_cyclic_stopped
        return attachment

    # ------------------------------------------------------------ state

    @property
    def frames_lost(self) -> int:
        """Frames the gateway dropped for this bus because it read too
        slowly (FramesLost notices), since it was opened."""
        a = self._attachment
        return self._lost_before + (a.lost if a else 0)

    @property
    def sender_id(self) -> int:
        """This attachment's sender number (FrameSender.id of its frames as
        the gateway's other clients see them)."""
        return self._attachment.opened.sender_id if self._attachment else 0

    @property
    def bus_info(self) -> bus_pb2.BusInfo:
        """The gateway's description of the bus when it was attached."""
        return self._attachment.opened.bus

    @property
    def state(self) -> can.BusState:
        """The bus state as the gateway last reported it."""
        s = self._attachment.state if self._attachment else None
        if s is None:
            return can.BusState.ACTIVE
        if s.state == bus_pb2.BUS_STATE_ERROR_PASSIVE:
            return can.BusState.PASSIVE
        if s.state in (bus_pb2.BUS_STATE_BUS_OFF, bus_pb2.BUS_STATE_DOWN):
            return can.BusState.ERROR
        return can.BusState.ACTIVE

    # ------------------------------------------------------------ filters

    def _apply_filters(self, filters: Optional[Any]) -> None:
        pb = _filters_to_pb(filters)
        if self._attachment is None or pb == self._server_filters:
            return
        # The gateway takes filters when attaching only: attach again with
        # the new ones (frames in between are not received).
        log.info("cangate %s: new filters, attaching again", self.channel)
        old = self._attachment
        unsent = old.close(self._shutdown_timeout)
        self._lost_before += old.lost
        if unsent:
            log.error("cangate %s: attaching again: %s", self.channel, unsent)
        self._server_filters = pb
        self._attachment = self._attach(pb or [])
        # The cyclic jobs ended with the old stream: start them again.
        for task in list(self._cyclic.values()):
            self._cyclic_start(task)

    # ------------------------------------------------------------ receive

    def _recv_internal(self, timeout: Optional[float]) -> tuple[Optional[can.Message], bool]:
        a = self._attachment
        if a is None:
            raise can.CanOperationError("cangate: the bus is shut down")
        filtered = self._server_filters is not None
        if a.error is not None and a.received.empty():
            raise a.error
        try:
            item = a.received.get(timeout=timeout) if timeout != 0 else a.received.get_nowait()
        except queue.Empty:
            return None, filtered
        if item is _END:
            raise a.error
        return item, filtered

    # ------------------------------------------------------------ send

    def send(self, msg: can.Message, timeout: Optional[float] = None) -> None:
        """Sends `msg` and waits (at most `timeout` seconds; None: as long
        as the stream lasts) until the gateway confirmed it went out.
        Raises ``can.CanOperationError`` when the gateway refused it (its
        reason in the message, the ``SendRefused`` in ``refusals``), when
        the stream has ended, when the send buffer stays full or no answer
        comes within `timeout`, or for an earlier message the gateway
        refused after its ``send`` returned. With ``confirm_send=False`` it
        returns once the message is queued."""
        a = self._attachment
        if a is None:
            raise can.CanOperationError("cangate: the bus is shut down")
        if a.error is not None:
            raise a.error
        self._raise_refusal(a.take_refusal())
        if msg.is_fd and not self._fd:
            raise can.CanOperationError("cangate: CAN FD frame on a bus opened without fd")
        frame = message_to_frame(msg)
        self._request(
            lambda sequence: bus_pb2.AttachRequest(
                send=bus_pb2.AttachSend(frames=[frame], sequence=sequence)
            ),
            timeout,
            self._confirm,
        )

    def _request(self, build: Any, timeout: Optional[float], confirm: bool) -> None:
        """Queues the request `build(sequence)` makes and, with `confirm`,
        waits for the gateway's answer (raising its refusal)."""
        a = self._attachment
        if a is None:
            raise can.CanOperationError("cangate: the bus is shut down")
        with self._send_lock:
            sequence = next(self._sequence)
            request = build(sequence)
            if confirm:
                with a.answers:
                    a.waiting.add(sequence)
            try:
                a.requests.put(request, timeout=timeout)
            except queue.Full:
                with a.answers:
                    a.waiting.discard(sequence)
                raise can.CanOperationError(
                    f"cangate: send buffer full for {timeout} s (the bus is slower than the sender)"
                ) from None
            a.last_sent = sequence
        if not confirm:
            return
        try:
            answered = a.wait_answered(sequence, timeout)
        finally:
            with a.answers:
                a.waiting.discard(sequence)
        self._raise_refusal(a.take_refusal(sequence))
        if not answered:
            if a.error is not None:
                raise a.error
            raise can.CanOperationError(
                f"cangate: message {sequence} not confirmed by the gateway within {timeout} s"
            )

    # ------------------------------------------------------------ cyclic

    def _send_periodic_internal(
        self,
        msgs: Any,
        period: float,
        duration: Optional[float] = None,
        autostart: bool = True,
        modifier_callback: Optional[Any] = None,
    ) -> can.broadcastmanager.CyclicSendTaskABC:
        """``send_periodic``: a job in the gateway (see the module
        documentation); with a ``modifier_callback``, python-can's thread."""
        if modifier_callback is not None:
            return super()._send_periodic_internal(
                msgs, period, duration, autostart, modifier_callback
            )
        task = CangateCyclicTask(self, next(self._jobs), msgs, period, duration)
        for m in task.messages:
            if m.is_fd and not self._fd:
                raise can.CanOperationError("cangate: CAN FD frame on a bus opened without fd")
        if autostart:
            task.start()
        return task

    def _cyclic_start(self, task: CangateCyclicTask) -> None:
        frames = [message_to_frame(m) for m in task.messages]
        interval = max(1, round(task.period * 1e9))
        duration = round(task.duration * 1e9) if task.duration else 0
        self._request(
            lambda sequence: bus_pb2.AttachRequest(
                cyclic=bus_pb2.AttachCyclic(
                    job=task.job,
                    frames=frames,
                    interval_ns=interval,
                    duration_ns=max(duration, 0),
                    sequence=sequence,
                )
            ),
            self._timeout,
            True,
        )
        task.running = True
        task.stopped_by_gateway = None
        self._cyclic[task.job] = task

    def _cyclic_modify(self, task: CangateCyclicTask, messages: tuple) -> None:
        frames = [message_to_frame(m) for m in messages]
        if not task.running:
            return
        self._request(
            lambda sequence: bus_pb2.AttachRequest(
                cyclic=bus_pb2.AttachCyclic(job=task.job, frames=frames, sequence=sequence)
            ),
            self._timeout,
            True,
        )

    def _cyclic_stop(self, task: CangateCyclicTask) -> None:
        # A stop always stops: when the stream is gone, so is the job.
        self._cyclic.pop(task.job, None)
        was_running, task.running = task.running, False
        a = self._attachment
        if not was_running or a is None or a.error is not None:
            return
        try:
            self._request(
                lambda sequence: bus_pb2.AttachRequest(
                    cyclic_stop=bus_pb2.AttachCyclicStop(job=task.job, sequence=sequence)
                ),
                self._timeout,
                True,
            )
        except can.CanOperationError as err:
            log.warning("cangate %s: stopping cyclic job %d: %s", self.channel, task.job, err)

    def _on_cyclic_stopped(self, stopped: Any) -> None:
        # Called by the attachment's reader thread.
        task = self._cyclic.pop(stopped.job, None)
        if task is None:
            return
        task.running = False
        if stopped.code != 0:
            task.stopped_by_gateway = f"{stopped.reason}: {stopped.message}"
            log.warning(
                "cangate %s: the gateway stopped cyclic job %d (id 0x%X): %s",
                self.channel,
                stopped.job,
                task.arbitration_id,
                task.stopped_by_gateway,
            )

    @staticmethod
    def _raise_refusal(refused: Optional[list]) -> None:
        if not refused:
            return
        r = refused[-1]
        more = f" ({len(refused)} messages refused)" if len(refused) > 1 else ""
        err = can.CanOperationError(
            f"cangate: message {r.sequence} was refused by the gateway{more}: "
            f"{r.reason}: {r.message}"
        )
        err.refusals = refused  # type: ignore[attr-defined]
        raise err

    def flush_tx_buffer(self) -> None:
        """Drops the messages not yet handed to gRPC."""
        a = self._attachment
        while a is not None:
            try:
                a.requests.get_nowait()
            except queue.Empty:
                return

    # ------------------------------------------------------------ lifecycle

    def shutdown(self) -> None:
        """Sends what ``send`` queued and waits for the gateway's answers
        (at most ``shutdown_timeout`` seconds), ends the Attach stream and
        closes the connection. Then raises ``can.CanOperationError`` when a
        message was refused or not confirmed in that time (it may not have
        reached the bus)."""
        if self._is_shutdown:
            return
        super().shutdown()
        a, self._attachment = self._attachment, None
        unsent = None
        if a is not None:
            unsent = a.close(self._shutdown_timeout)
            self._lost_before += a.lost
        self._grpc.close()
        if unsent:
            log.error("cangate %s: at shutdown: %s", self.channel, unsent)
            raise can.CanOperationError(f"cangate {self.channel}: at shutdown: {unsent}")

    @staticmethod
    def _detect_available_configs() -> list:
        """The buses of the gateway at ``CANGATE_SERVER`` (a ListBuses call
        bounded by 1 s; nothing when it does not answer)."""
        server, token = resolve(None, None)
        try:
            channel = open_channel(server, token)
        except Exception:  # noqa: BLE001 - detection never fails
            return []
        try:
            buses = bus_pb2_grpc.BusStub(channel).ListBuses(bus_pb2.ListBusesRequest(), timeout=1.0)
        except grpc.RpcError:
            return []
        finally:
            channel.close()
        return [
            {"interface": "cangate", "channel": b.name, "server": server, "fd": b.fd}
            for b in buses.buses
        ]


__all__ = ["CangateBus", "CangateCyclicTask", "frame_to_message", "message_to_frame"]
