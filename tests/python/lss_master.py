#!/usr/bin/env python3
"""python-canopen's LSS master (``network.lss``) on a bus of a cangate gateway.

Run by tests/tests/lss_python_peer.rs as an independent implementation of
the master side of CiA 305, attached through the cangate python-can
interface (CANGATE_SERVER) and receiving only LSS answers (0x7E4). It drives
the gateway's simulated unconfigured device: fastscan, configure node-ID,
store configuration, inquire, and back to the waiting state, which gives the
device its new node-ID.

stdout, one line each:
  ``READY``                                  attached
  ``FOUND <vendor> <product> <revision> <serial>``  fastscan's identity (hex)
  ``INQUIRE <node-id> <vendor> <serial>``    inquire before the switch back
  ``CONFIGURED <node-id>``                   configured, stored, back to waiting
  ``FAILED <why>``                           a step failed
  ``BYE``                                    clean exit follows
stdin
  ``QUIT`` or end of input                   shut down
"""

import argparse
import sys
import threading


def say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channel", default="can0")
    ap.add_argument("--node-id", type=int, default=20)
    ap.add_argument("--response-timeout", type=float, default=0.15)
    ap.add_argument("--max-seconds", type=float, default=200.0)
    args = ap.parse_args()

    import canopen
    from canopen import lss

    network = canopen.Network()
    filters = [{"can_id": 0x7E4, "can_mask": 0x7FF, "extended": False}]
    network.connect(interface="cangate", channel=args.channel, can_filters=filters)
    master = network.lss
    # Every fastscan bit without an answer waits this long.
    master.RESPONSE_TIMEOUT = args.response_timeout
    say("READY")
    status = 0
    try:
        master.send_switch_state_global(master.WAITING_STATE)
        ok, ident = master.fast_scan()
        if not ok:
            raise RuntimeError("fast_scan found no device")
        say("FOUND " + " ".join(f"{v:08x}" for v in ident))
        # fast_scan leaves the device in the configuration state.
        before = master.inquire_node_id()
        vendor = master.inquire_lss_address(lss.CS_INQUIRE_VENDOR_ID)
        serial = master.inquire_lss_address(lss.CS_INQUIRE_SERIAL_NUMBER)
        say(f"INQUIRE {before} {vendor:08x} {serial:08x}")
        master.configure_node_id(args.node_id)
        master.store_configuration()
        master.send_switch_state_global(master.WAITING_STATE)
        say(f"CONFIGURED {args.node_id}")
    except Exception as e:  # reported to the test, which fails with it
        say(f"FAILED {type(e).__name__}: {e}")
        status = 1

    done = threading.Event()

    def commands():
        for line in sys.stdin:
            if line.strip() == "QUIT":
                break
        done.set()

    threading.Thread(target=commands, daemon=True).start()
    done.wait(args.max_seconds)
    network.disconnect()
    say("BYE")
    return status


if __name__ == "__main__":
    sys.exit(main())
