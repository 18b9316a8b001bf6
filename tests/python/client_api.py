#!/usr/bin/env python3
"""The cangate package's typed client against a gateway on the demo
configuration (can0: simulated drives X/Y/Z, I/O node 3, handwheel hw1).

Run by tests/tests/python_package.rs: ``python client_api.py`` with
CANGATE_SERVER set. Prints ``ok ...`` per check and ``client api: all
checks passed`` at the end; any failed check raises (non-zero exit).
"""

import signal
import sys
import threading
import time

import grpc

import cangate
from cangate import CangateError, DataType, SdoAbortError
from cangate.v1 import axes_pb2, handwheel_pb2


def expect(cond, what):
    if not cond:
        raise AssertionError(what)


def wait_until(stream, pred, what, poke=None, limit=10.0):
    """The first item of `stream` that `pred` accepts, while `poke` runs in
    a thread every 0.2 s (so the subscription is certainly in place)."""
    stop = threading.Event()

    def poker():
        while not stop.wait(0.2):
            poke()

    t = threading.Thread(target=poker, daemon=True) if poke else None
    timer = threading.Timer(limit, stream.cancel)
    timer.start()
    if t:
        t.start()
    try:
        for item in stream:
            if pred(item):
                return item
        raise AssertionError(f"no {what} within {limit} s")
    finally:
        stop.set()
        timer.cancel()
        stream.cancel()
        if t:
            t.join()


def main():
    # Never outlive the test that started us.
    signal.alarm(120)
    with cangate.Client(timeout=10.0) as c:
        # Buses.
        buses = c.list_buses()
        expect([b.name for b in buses] == ["can0"], buses)
        expect(c.get_bus("can0").fd, "can0 is FD")
        try:
            c.get_bus("nope")
            raise AssertionError("an unknown bus was found")
        except CangateError as e:
            expect(e.code == grpc.StatusCode.NOT_FOUND and e.reason == "BUS_NOT_FOUND", e)
            expect(e.metadata == {"kind": "bus", "name": "nope"}, e.metadata)
        print("ok buses")

        # SDO: typed by the node's EDS, by the request, errors with the abort.
        r = c.read_sdo("can0", 1, 0x1008)
        expect(r.type == DataType.VISIBLE_STRING and r.value == "cangate sim drive", r)
        hb = c.read_sdo("can0", 1, 0x1017, 0, DataType.UNSIGNED16)
        expect(r.raw and isinstance(hb.value, int), hb)
        expect(c.write_sdo("can0", 1, 0x1017, 0, hb.value, DataType.UNSIGNED16) == 2, "wrote 2")
        expect(c.read_sdo("can0", 1, 0x1017, 0, DataType.UNSIGNED16).value == hb.value, "read back")
        try:
            c.read_sdo("can0", 1, 0x5555)
            raise AssertionError("0x5555 was read")
        except SdoAbortError as e:
            expect(e.code == grpc.StatusCode.NOT_FOUND and e.reason == "SDO_ABORT", e)
            expect((e.abort_code, e.index, e.subindex, e.from_node, e.node)
                   == (0x06020000, 0x5555, 0, True, 1), vars(e))
            expect(e.abort_name == "object does not exist in the object dictionary", e.abort_name)
            abort = e.abort_code
        print(f"ok sdo: {r.value!r}, heartbeat {hb.value} ms, abort 0x{abort:08X}")

        # An SDO session: pipelined futures, answered per node in order;
        # an abort fails its future only.
        with c.sdo_session("can0") as s:
            w = s.write(1, 0x1017, 0, hb.value, DataType.UNSIGNED16)
            reads = [s.read(n, 0x1017, 0, DataType.UNSIGNED16) for n in (1, 2) for _ in range(20)]
            bad = s.read(1, 0x5555)
            after = s.read(1, 0x1008)
            expect(w.result(timeout=10) == 2, "session wrote 2")
            expect(reads[0].result(timeout=10).value == hb.value, "session read back")
            expect(all(isinstance(f.result(timeout=10).value, int) for f in reads), "session reads")
            try:
                bad.result(timeout=10)
                raise AssertionError("0x5555 was read in a session")
            except SdoAbortError as e:
                expect((e.reason, e.abort_code, e.node) == ("SDO_ABORT", 0x06020000, 1), vars(e))
            expect(after.result(timeout=10).value == "cangate sim drive", "the session goes on")
        print("ok sdo session")

        # Axes: a move under a lease, released on exit.
        names = [a.name for a in c.list_axes()]
        expect({"X", "Y", "Z"} <= set(names), names)
        x = c.axis("X")
        with x.control(name="python client test", ttl_ms=500) as ax:
            expect("python client test" in ax.holder, ax.holder)
            ax.enable(wait=True)
            # The drive's signals and touch probe (X: the demo's drive maps them).
            r = ax.arm_touch_probe("rising")
            expect(r.outcome == axes_pb2.OUTCOME_COMPLETED and "0x60B8 = 0x0011" in r.detail, r)
            expect(x.get().status.HasField("digital_inputs"), "0x60FD carried")
            # Longer than the TTL: the lease stays alive by the renewals.
            r = ax.move(2.0, velocity=2.0, wait=True)
            expect(r.outcome == axes_pb2.OUTCOME_COMPLETED, r)
            st = x.get().status
            expect(abs(st.position - 2.0) < 0.01, st)
            expect("python client test" in st.controlled_by, st)
        expect(x.get().status.controlled_by == "", "released on exit")
        print(f"ok lease: moved X to {st.position:.3f} over more than its TTL")

        # An exception in the block stops the axis and releases the lease.
        try:
            with x.control(name="python client test") as ax:
                ax.move(-150.0, velocity=20.0)
                time.sleep(0.2)
                raise RuntimeError("the program failed")
        except RuntimeError:
            pass
        st = wait_until(
            x.states(),
            lambda u: u.WhichOneof("update") == "status"
            and u.status.activity == axes_pb2.AXIS_ACTIVITY_IDLE,
            "X at rest after the stop",
        ).status
        expect(st.position > -100.0 and st.controlled_by == "", st)
        print(f"ok exception in the lease block: X stopped at {st.position:.3f}, released")

        # A set-point stream: X and Y out by 1 mm and back (cosine), a
        # point per ms sent ahead of time; the stream ends at rest.
        import math

        def there_and_back():
            for k0 in range(0, 1001, 50):
                yield [
                    (k * 1000, [0.5 - 0.5 * math.cos(2 * math.pi * k / 1000.0)] * 2)
                    for k in range(k0, min(k0 + 50, 1001))
                ]

        with c.control("X", "Y", name="python client test") as ax:
            ax.enable("X", wait=True)
            ax.enable("Y", wait=True)
            start = [c.axis(a).get().status.demand_position for a in ("X", "Y")]
            statuses = list(ax.stream_setpoints(
                ([(t, [p[0] + start[0], p[1] + start[1]]) for t, p in b] for b in there_and_back()),
                depth_ms=100,
                status_period_ms=20,
            ))
            last = statuses[-1]
            expect(last.ended == "CLIENT_ENDED", last)
            expect(last.counters.received == 1001 and last.counters.refused == 0, last.counters)
            peak = max(s.commanded_positions[1] for s in statuses)
            expect(peak > 0.5, peak)
        print(f"ok set-point stream: {last.counters.played} points played, peak {peak:.3f}")

        # A stream of velocities to the spindle S (csv): up to 10 rev/s at
        # 50 rev/s² and back to rest, one point per ms.
        def spin():
            for k0 in range(0, 501, 50):
                yield [
                    (k * 1000, [min(50.0 * k / 1000.0, 10.0, 50.0 * (500 - k) / 1000.0)])
                    for k in range(k0, min(k0 + 50, 501))
                ]

        with c.control("S", name="python client test") as ax:
            ax.enable("S", wait=True)
            start = c.axis("S").get().status.demand_position
            statuses = list(ax.stream_setpoints(spin(), depth_ms=100, status_period_ms=20, velocities=True))
            last = statuses[-1]
            expect(last.ended == "CLIENT_ENDED", last)
            expect(last.counters.received == 501 and last.counters.refused == 0, last.counters)
            turns = last.commanded_positions[0] - start
            expect(abs(turns - 3.0) < 0.05, turns)
        print(f"ok velocity stream: {turns:.3f} rev")

        # Node events: NMT state changes of the I/O node.
        flip = [False]

        def nmt():
            flip[0] = not flip[0]
            c.send_nmt("can0", 3, "preop" if flip[0] else "start")

        ev = wait_until(
            c.node_events("can0", [3]),
            lambda e: e.WhichOneof("event") == "state_changed",
            "a state change of node 3",
            poke=nmt,
        )
        c.send_nmt("can0", 3, "start")
        print(f"ok node events: {ev.state_changed}".replace("\n", " "))

        # Handwheel feed: the simulated wheel turned in manual mode.
        c.set_handwheel_mode("hw1", manual=True)
        turn = handwheel_pb2.TurnHandwheelRequest(handwheel="hw1", detents=1, axis=handwheel_pb2.WHEEL_AXIS_Y)
        feed = wait_until(
            c.feed(["hw1"]),
            lambda f: f.units > 0,
            "a feed event",
            poke=lambda: c.simulator_stub.TurnHandwheel(turn, timeout=5),
        )
        c.set_handwheel_mode("hw1", manual=False)
        expect(feed.handwheel == "hw1" and feed.direction == 1, feed)
        print(f"ok feed: {feed.units} units on {handwheel_pb2.WheelAxis.Name(feed.axis)}")

        # The frame stream (the gateway's own SYNC: transmitted).
        frames = wait_until(
            c.stream_frames("can0", [(0x080, 0x7FF)], include_transmitted=True),
            lambda f: isinstance(f, cangate.Frame),
            "a SYNC frame",
        )
        expect(frames.id == 0x80 and frames.timestamp_ns > 0, frames)
        print("ok frame stream: SYNC")
    print("client api: all checks passed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
