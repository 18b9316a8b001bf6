#!/usr/bin/env python3
"""python-can's ``bus.send_periodic()`` on the cangate interface: the job
runs in the gateway (Attach's AttachCyclic), and the task python-can
returns changes its data, stops, starts again, and ends with the program.

Run by tests/tests/python_package.rs against a gateway with a virtual bus
can0 (CANGATE_SERVER, CANGATE_TOKEN), which watches can0 with its own
client. The script prints a line after each step and waits for the test's
go-ahead on stdin:

- ``READY``, ``OPEN`` (the bus is open); on ``GO``, ``STARTED``: a job on
  0x3A0 with data 01, every 20 ms;
- on ``MODIFY``: new data 02, ``MODIFIED``;
- on ``STOP``: the task stopped, then one frame 0x3A0 FF sent (it comes
  after every frame of the job), ``STOPPED``;
- on ``DIE``: a job on 0x3A1 started (``DYING``); on ``EXIT`` the process
  ends without stopping it or shutting the bus down.

Any failed check raises.
"""

import os
import sys

import can
from can.broadcastmanager import ModifiableCyclicTaskABC, RestartableCyclicTaskABC


def say(line):
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def wait_for(word):
    line = sys.stdin.readline().strip()
    assert line == word, f"expected {word!r}, got {line!r}"


def main():
    say("READY")
    bus = can.Bus(interface="cangate", channel="can0")
    # A period the gateway does not run is refused, not quietly changed.
    try:
        bus.send_periodic(can.Message(arbitration_id=0x3AF, is_extended_id=False), 0.0001)
        raise AssertionError("a 0.1 ms period was accepted")
    except can.CanOperationError as e:
        assert "INVALID_ARGUMENT" in str(e), str(e)
    msg = can.Message(arbitration_id=0x3A0, is_extended_id=False, data=b"\x01")
    say("OPEN")
    wait_for("GO")
    task = bus.send_periodic(msg, 0.02)
    assert isinstance(task, ModifiableCyclicTaskABC), type(task)
    assert isinstance(task, RestartableCyclicTaskABC), type(task)
    say("STARTED")
    wait_for("MODIFY")
    task.modify_data(can.Message(arbitration_id=0x3A0, is_extended_id=False, data=b"\x02"))
    say("MODIFIED")
    wait_for("STOP")
    task.stop()
    bus.send(can.Message(arbitration_id=0x3A0, is_extended_id=False, data=b"\xff"))
    say("STOPPED")
    wait_for("DIE")
    bus.send_periodic(can.Message(arbitration_id=0x3A1, is_extended_id=False, data=b"\x03"), 0.01)
    say("DYING")
    wait_for("EXIT")
    # Gone without a goodbye: no stop, no shutdown.
    os._exit(0)


if __name__ == "__main__":
    sys.exit(main())
