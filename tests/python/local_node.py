#!/usr/bin/env python3
"""A CANopen device on a SocketCAN interface, made with python-canopen.

Run by tests/tests/canopen_python_peer.rs (inside vcan-vm when the host has no
vcan0) as an independent implementation of the device side of CiA 301:
python-canopen's ``LocalNode`` answers SDO (expedited and segmented; it has
no block transfer) from the object dictionary in ``device.eds``, follows NMT
commands and produces its heartbeat (with the kernel's broadcast manager).

Protocol with the test, one line each:

stdout
  ``READY``                         set up, boot-up sent, heartbeat running
  ``WRITE iiii:ss <hex>``           an SDO download the device stored
  ``NMT <state>``                   state after an NMT command for this node
  ``LOST <n>``                      (--interface cangate) frames the gateway
                                    dropped for the device, before BYE
  ``BYE``                           clean exit follows
stdin
  ``QUIT`` or end of input          shut down

Everything else (logging, tracebacks) goes to stderr. The process also ends
by itself after ``--max-seconds``, so a test that dies cannot leave it on
the bus for ever.

With ``--interface cangate`` (tests/tests/python_package.rs) the device is
not on SocketCAN but attached to a bus of a cangate gateway through the
cangate python-can interface (CANGATE_SERVER, CANGATE_TOKEN), receiving only
its SDO requests and NMT commands (gateway-side filters).
"""

import argparse
import os
import sys
import threading
import time


def say(line: str) -> None:
    # One write per line and an explicit flush: the test reads line by line
    # from a pipe, and the notifier thread prints concurrently.
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def main() -> int:
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--interface", default="socketcan", help="python-can interface")
    ap.add_argument("--node-id", type=int, default=42)
    ap.add_argument("--eds", default=os.path.join(here, "device.eds"))
    ap.add_argument("--max-seconds", type=float, default=300.0)
    ap.add_argument("--verbose", action="store_true", help="python-canopen logging to stderr")
    args = ap.parse_args()

    if args.verbose:
        import logging

        logging.basicConfig(level=logging.INFO, stream=sys.stderr)

    import canopen  # slow under TCG: several seconds

    network = canopen.Network()
    if args.interface == "cangate":
        # Only what a CANopen slave needs: its SDO requests and NMT.
        filters = [
            {"can_id": 0x600 + args.node_id, "can_mask": 0x7FF, "extended": False},
            {"can_id": 0x000, "can_mask": 0x7FF, "extended": False},
        ]
        network.connect(interface="cangate", channel=args.channel, can_filters=filters)
    else:
        network.connect(interface=args.interface, channel=args.channel)
    node = canopen.LocalNode(args.node_id, args.eds)

    def on_write(index, subindex, od, data, **_):
        say(f"WRITE {index:04X}:{subindex:02X} {bytes(data).hex()}")

    node.add_write_callback(on_write)
    network.add_node(node)

    # Subscribed after the node's own NMT handler (the network calls
    # subscribers in order), so the state printed is the new one.
    def on_nmt(can_id, data, timestamp):
        if len(data) >= 2 and data[1] in (0, args.node_id):
            say(f"NMT {node.nmt.state}")

    network.subscribe(0, on_nmt)

    # CiA 301 start-up: INITIALISING sends the boot-up frame (0x700+id, 00);
    # the automatic transition to PRE-OPERATIONAL starts the heartbeat with
    # the period in 0x1017 (an SDO write of 0x1017 changes or stops it).
    node.nmt.state = "INITIALISING"
    node.nmt.state = "PRE-OPERATIONAL"
    say("READY")

    # stdin commands in a thread, so the deadline below still applies.
    done = threading.Event()

    def commands():
        for line in sys.stdin:
            if line.strip() == "QUIT":
                break
            if line.strip():
                print(f"local_node: unknown command {line!r}", file=sys.stderr)
        done.set()

    threading.Thread(target=commands, daemon=True).start()
    finished = done.wait(args.max_seconds)
    if not finished:
        print(f"local_node: --max-seconds {args.max_seconds} reached", file=sys.stderr)

    node.nmt.stop_heartbeat()
    lost = getattr(network.bus, "frames_lost", None)
    network.disconnect()
    if lost is not None:
        say(f"LOST {lost}")
    say("BYE")
    return 0 if finished else 3


if __name__ == "__main__":
    sys.exit(main())
