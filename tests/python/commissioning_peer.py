#!/usr/bin/env python3
"""python-canopen as an independent master beside the gateway's, checking
what the gateway's commissioning services did.

Run by tests/tests/canopen_python_commissioning.rs, attached to a bus of the
gateway through the cangate python-can interface (CANGATE_SERVER):

- reads TPDO ``--tpdo`` of node ``--node`` with python-canopen's PDO reader
  (its own SDO client, the node's EDS ``--eds``) and prints
  ``TPDO <n> cob=0x<id> enabled=<0|1> type=<t> inhibit=<100 µs> event=<ms>
  map=<iiii:ss/bits,...>``;
- sends one TIME with python-canopen's TimeProducer for ``--time`` (a Unix
  timestamp) and prints ``TIME SENT``;
- imports ``--dcf`` with python-canopen's EDS/DCF importer and prints
  ``DCF node=<id> bitrate=<bit/s> 1017=<value> 6081=<value> 1018:1=<value>``;
- prints ``BYE`` and exits.
"""

import argparse
import sys


def say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channel", default="can0")
    ap.add_argument("--node", type=int, required=True)
    ap.add_argument("--eds", required=True)
    ap.add_argument("--tpdo", type=int, required=True)
    ap.add_argument("--time", type=float, required=True)
    ap.add_argument("--dcf", required=True)
    args = ap.parse_args()

    import canopen

    network = canopen.Network()
    network.connect(interface="cangate", channel=args.channel)
    try:
        node = canopen.RemoteNode(args.node, args.eds)
        network.add_node(node)
        pdo = node.tpdo[args.tpdo]
        pdo.read(from_od=False)
        entries = ",".join(
            f"{v.index:04X}:{v.subindex:02X}/{v.length}" for v in pdo.map
        )
        say(
            f"TPDO {args.tpdo} cob=0x{pdo.cob_id:X} enabled={int(pdo.enabled)} "
            f"type={pdo.trans_type} inhibit={pdo.inhibit_time} event={pdo.event_timer} "
            f"map={entries}"
        )

        network.time.transmit(args.time)
        say("TIME SENT")
    finally:
        network.disconnect()

    od = canopen.import_od(args.dcf)
    say(
        f"DCF node={od.node_id} bitrate={od.bitrate} 1017={od[0x1017].value} "
        f"6081={od[0x6081].value} 1018:1={od[0x1018][1].value}"
    )
    say("BYE")
    return 0


if __name__ == "__main__":
    sys.exit(main())
