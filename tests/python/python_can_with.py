#!/usr/bin/env python3
"""python-can's plainest use of the cangate interface: messages sent in a
``with can.Bus(...)`` block, and nothing else. Every message ``send``
accepted reaches the bus before the block ends, whether ``send`` waited
for the gateway's confirmation (the default) or only queued the message
(``confirm_send=False``); a message the gateway refuses is raised, by its
``send`` or by the shutdown at the end of the block.

Run by tests/tests/python_package.rs against a gateway with a virtual bus
can0 (CANGATE_SERVER, CANGATE_TOKEN), which watches can0 with its own
client and checks the frames. Prints ``READY`` once imported, ``SENT
<n>`` after each block and ``REFUSED <message>`` for the refusals; any
failed check raises.
"""

import sys

import can

N = 15


def say(line):
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def frames(first_id):
    return [
        can.Message(arbitration_id=first_id + i, is_extended_id=False, data=bytes([i, 0x5A]))
        for i in range(N)
    ]


def main():
    say("READY")
    # The program: send, and leave the block.
    with can.Bus(interface="cangate", channel="can0") as bus:
        for m in frames(0x200):
            bus.send(m)
    say(f"SENT {N}")
    # Queued only: the end of the block sends them.
    with can.Bus(interface="cangate", channel="can0", confirm_send=False) as bus:
        for m in frames(0x300):
            bus.send(m)
    say(f"SENT {N}")
    # A refused message is raised by its send ...
    with can.Bus(interface="cangate", channel="can0") as bus:
        try:
            bus.send(can.Message(arbitration_id=0x800, is_extended_id=False, data=b"\x01"))
            raise AssertionError("an 11-bit id 0x800 was accepted")
        except can.CanOperationError as e:
            assert "INVALID_FRAME" in str(e), str(e)
            say(f"REFUSED {e}")
    # ... or, queued only, by the end of the block.
    try:
        with can.Bus(interface="cangate", channel="can0", confirm_send=False) as bus:
            bus.send(can.Message(arbitration_id=0x800, is_extended_id=False, data=b"\x01"))
        raise AssertionError("the refusal was not raised at shutdown")
    except can.CanOperationError as e:
        assert "INVALID_FRAME" in str(e), str(e)
        say(f"REFUSED {e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
