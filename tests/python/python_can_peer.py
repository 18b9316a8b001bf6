#!/usr/bin/env python3
"""python-can through the cangate interface, against a gateway.

Run by tests/tests/python_package.rs, which started the gateway (a virtual
FD bus can0, bearer tokens on) and watches can0 with its own Rust client. The
gateway is CANGATE_SERVER, the token CANGATE_TOKEN; the script uses nothing
but python-can's public API (``can.Bus(interface="cangate", ...)``).

Protocol with the test, one line each:

stdout
  ``READY``                 buses open (errors already checked)
  ``SENT``                  the frames of step 1 were sent by bus B
  ``RECEIVED``              the frames of step 2 were received and checked
  ``LOST <received> <lost>``  the flood of step 3, read slowly
  ``WAITING``               blocked in recv until the gateway goes away
  ``END <message>``         recv raised CanOperationError with this message
stdin
  ``GO <n>``                step 2: the test sent its frames
  ``FLOOD <n>``             step 3: the test sent n frames of id 0x3FF
  end of input              stop

Any failed check raises (non-zero exit with a traceback).
"""

import logging
import os
import sys
import time

import can

logging.basicConfig(level=logging.WARNING, stream=sys.stderr)

#: No wait of this script is longer.
WAIT = 10.0


def say(line):
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def expect(cond, what):
    if not cond:
        raise AssertionError(what)


def recv_all(bus, n, what):
    """n messages, each within WAIT."""
    got = []
    while len(got) < n:
        m = bus.recv(WAIT)
        expect(m is not None, f"{what}: only {len(got)} of {n} messages: {got}")
        got.append(m)
    return got


def quiet(bus, what, seconds=0.3):
    m = bus.recv(seconds)
    expect(m is None, f"{what}: unexpected {m}")


def check_errors():
    """An unknown bus and a bad token fail when the bus is made."""
    try:
        can.Bus(interface="cangate", channel="nope")
        raise AssertionError("an unknown bus opened")
    except can.CanInitializationError as e:
        expect("NOT_FOUND" in str(e) and "nope" in str(e), f"unknown bus: {e}")
        print(f"ok unknown bus: {e}", file=sys.stderr)
    try:
        can.Bus(interface="cangate", channel="can0", token="wrong")
        raise AssertionError("a wrong token was accepted")
    except can.CanInitializationError as e:
        expect("UNAUTHENTICATED" in str(e), f"bad token: {e}")
        print(f"ok bad token: {e}", file=sys.stderr)
    # FD on a bus configured classic is refused by the gateway (fd given,
    # so the interface does not ask the bus first).
    try:
        can.Bus(interface="cangate", channel="classic", fd=True)
        raise AssertionError("fd on a classic bus opened")
    except can.CanInitializationError as e:
        expect("INVALID_ARGUMENT" in str(e), f"fd on classic: {e}")
        print(f"ok fd on classic: {e}", file=sys.stderr)
    configs = can.detect_available_configs(interfaces=["cangate"])
    names = sorted(c["channel"] for c in configs)
    expect(names == ["can0", "classic"], f"detected configs {configs}")


def main():
    commands = iter(sys.stdin)
    check_errors()

    started = time.time()
    # A: filtered by the gateway, standard ids 0x100..0x10F only, no own frames.
    a = can.Bus(
        interface="cangate",
        channel="can0",
        can_filters=[{"can_id": 0x100, "can_mask": 0x7F0, "extended": False}],
    )
    # B: everything, and its own frames back.
    b = can.Bus(interface="cangate", channel="can0", receive_own_messages=True)
    expect(a.protocol == can.CanProtocol.CAN_FD, f"A protocol {a.protocol}")
    expect(a.sender_id != b.sender_id, "one sender per bus")
    say("READY")

    # 1. B sends: classic, extended, remote, FD with BRS; its own come back.
    sent = [
        can.Message(arbitration_id=0x123, is_extended_id=False, data=bytes.fromhex("DEADBEEF")),
        can.Message(arbitration_id=0x1F334455, is_extended_id=True, data=b"\x11"),
        can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=4),
        can.Message(
            arbitration_id=0x7AB,
            is_extended_id=False,
            is_fd=True,
            bitrate_switch=True,
            data=bytes(range(64)),
        ),
    ]
    for m in sent:
        b.send(m, timeout=WAIT)
    own = recv_all(b, len(sent), "own frames of B")
    for m, o in zip(sent, own):
        expect(not o.is_rx, f"own frame marked rx: {o}")
        expect(
            (o.arbitration_id, o.is_extended_id, o.is_remote_frame, o.is_fd, o.bitrate_switch)
            == (m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_fd, m.bitrate_switch),
            f"own frame {o} != sent {m}",
        )
        expect(o.dlc == m.dlc and bytes(o.data) == bytes(m.data), f"own frame {o} != sent {m}")
        expect(o.channel == "can0", f"channel {o.channel}")
    quiet(a, "A (filtered) got one of B's frames")
    say("SENT")

    # 2. The test sent frames; A gets the ones its filter passes, B all.
    cmd = next(commands).split()
    expect(cmd[0] == "GO", f"expected GO, got {cmd}")
    n = int(cmd[1])
    on_b = recv_all(b, n, "B")
    for m in on_b:
        expect(m.is_rx, f"a frame of the test marked own: {m}")
    ids = [(m.arbitration_id, m.is_extended_id, m.is_fd) for m in on_b]
    print(f"B received {[hex(i) for i, _, _ in ids]}", file=sys.stderr)
    on_a = recv_all(a, 2, "A")
    expect(
        [(m.arbitration_id, m.is_extended_id, m.is_fd) for m in on_a]
        == [(0x105, False, False), (0x10A, False, True)],
        f"A's filter passed {on_a}",
    )
    expect(bytes(on_a[1].data) == bytes(range(48)) and not on_a[1].bitrate_switch, f"FD {on_a[1]}")
    quiet(a, "A after the filtered frames")
    # Timestamps: the gateway's, non-decreasing, within this run's wall time.
    now = time.time()
    stamps = [m.timestamp for m in own + on_b]
    expect(stamps == sorted(stamps), f"timestamps go back: {stamps}")
    expect(
        all(started - 1.0 <= t <= now + 1.0 for t in stamps),
        f"timestamps {stamps} outside [{started}, {now}]",
    )

    # Own frames only when asked: A sends one that passes its own filter.
    a.send(can.Message(arbitration_id=0x101, is_extended_id=False, data=b"\xaa"))
    m = b.recv(WAIT)
    expect(m is not None and m.arbitration_id == 0x101 and m.is_rx, f"B got {m}")
    quiet(a, "A got its own frame without receive_own_messages")

    # A refused message is raised by its send, with the gateway's reason;
    # the next one goes out.
    try:
        b.send(can.Message(arbitration_id=0x800, is_extended_id=False, data=b"\x01"))
        raise AssertionError("an 11-bit id 0x800 was accepted")
    except can.CanOperationError as e:
        expect("INVALID_FRAME" in str(e), f"refusal: {e}")
        print(f"ok refused: {e}", file=sys.stderr)
    b.send(can.Message(arbitration_id=0x124, is_extended_id=False, data=b"\x02"))
    # New filters: the interface attaches again with them.
    a.set_filters([{"can_id": 0x124, "can_mask": 0x7FF, "extended": False}])
    b.send(can.Message(arbitration_id=0x124, is_extended_id=False, data=b"\x03"))
    m = a.recv(WAIT)
    expect(m is not None and m.arbitration_id == 0x124 and bytes(m.data) == b"\x03", f"A got {m}")
    quiet(a, "A after its new filter")
    a.shutdown()
    # Drain what B got meanwhile (its own 0x124 frames).
    while b.recv(0.2) is not None:
        pass
    say("RECEIVED")

    # 3. Read slowly: the gateway drops frames for us and says how many.
    slow = can.Bus(
        interface="cangate",
        channel="can0",
        can_filters=[{"can_id": 0x3FF, "can_mask": 0x7FF}],
        queue_length=16,
        receive_buffer=1,
    )
    say("SLOW")
    cmd = next(commands).split()
    expect(cmd[0] == "FLOOD", f"expected FLOOD, got {cmd}")
    n = int(cmd[1])
    time.sleep(1.0)
    received = 0
    while slow.recv(0.5) is not None:
        received += 1
    lost = slow.frames_lost
    say(f"LOST {received} {lost}")
    expect(lost > 0, f"nothing lost with a 16-event queue: received {received}")
    expect(received + lost == n, f"received {received} + lost {lost} != {n}")
    slow.shutdown()

    # 4. The gateway goes away: recv raises with its message.
    say("WAITING")
    try:
        while True:
            b.recv(WAIT * 3)
    except can.CanOperationError as e:
        say(f"END {e}")
    b.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
