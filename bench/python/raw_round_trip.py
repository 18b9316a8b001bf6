"""One raw CAN round trip at a time through a gateway, as a python-can
program sees it: `peer_bench` (bench/src/bin/peer_bench.rs) runs this
script once per gateway, with the same code for both, and only the
python-can interface differs:

    python raw_round_trip.py socketcand --host 127.0.0.1 --port 29536 --channel vcan0
    python raw_round_trip.py cangate --server http://127.0.0.1:50051 --channel can0
    python raw_round_trip.py socketcan --channel vcan0      # no gateway: the floor

A responder on the bus answers each frame 0x100 with a frame 0x101 carrying
the same data. The script connects, then reads block sizes from stdin, one
per line; for each it sends that many frames 0x100 one after another, each
with a fresh 8-byte sequence number, waits for the matching 0x101, and
prints one JSON line {"ns": [...]} with the round-trip times. Staying
connected between blocks lets the caller alternate the two gateways in
blocks without paying python's start-up in the figures. "ready" is printed
once connected and warmed up.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time

import can

REQUEST_ID = 0x100
RESPONSE_ID = 0x101
# A lost frame must not hang the benchmark; no sane round trip takes this.
TIMEOUT_S = 5.0


def open_bus(args: argparse.Namespace) -> can.BusABC:
    if args.interface == "socketcand":
        # tcp_tune: TCP_NODELAY and TCP_QUICKACK, python-can's low-latency
        # setting for socketcand (off by default): the peer at its best.
        return can.Bus(
            interface="socketcand",
            host=args.host,
            port=args.port,
            channel=args.channel,
            tcp_tune=True,
        )
    if args.interface == "socketcan":
        # No gateway: python-can on the kernel interface itself, the floor
        # under both gateways' figures.
        return can.Bus(interface="socketcan", channel=args.channel)
    return can.Bus(interface="cangate", server=args.server, channel=args.channel)


def round_trip(bus: can.BusABC, seq: int, via: str) -> int:
    data = seq.to_bytes(8, "little")
    start = time.perf_counter_ns()
    bus.send(can.Message(arbitration_id=REQUEST_ID, data=data, is_extended_id=False))
    deadline = time.monotonic() + TIMEOUT_S
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(f"{via}: no response to round trip {seq} within {TIMEOUT_S} s")
        msg = bus.recv(timeout=left)
        # Anything else on the bus (or a late answer) is not this answer.
        if msg is not None and msg.arbitration_id == RESPONSE_ID and bytes(msg.data) == data:
            return time.perf_counter_ns() - start


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("interface", choices=["socketcand", "cangate", "socketcan"])
    p.add_argument("--channel", required=True)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=29536)
    p.add_argument("--server", default="http://127.0.0.1:50051")
    p.add_argument("--warmup", type=int, default=50)
    args = p.parse_args()
    # python-can's socketcand interface warns whenever a TCP read ends in
    # the middle of a frame, which is normal for a stream; errors still show.
    logging.basicConfig(level=logging.ERROR)

    bus = open_bus(args)
    seq = 0
    try:
        for _ in range(args.warmup):
            seq += 1
            round_trip(bus, seq, args.interface)
        print("ready", flush=True)
        for line in sys.stdin:
            n = int(line)
            ns = []
            for _ in range(n):
                seq += 1
                ns.append(round_trip(bus, seq, args.interface))
            print(json.dumps({"ns": ns}), flush=True)
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
