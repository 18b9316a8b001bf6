"""One raw CAN round trip at a time through a gateway, as a python-can
program sees it: `peer_bench` (bench/src/bin/peer_bench.rs) runs this
script once per gateway, with the same code for each, and only the
python-can interface differs:

    python raw_round_trip.py socketcand --request-id 0x100 --host 127.0.0.1 --port 29536 --channel vcan0
    python raw_round_trip.py cangate --request-id 0x102 --server http://127.0.0.1:50051 --channel can0
    python raw_round_trip.py socketcan --request-id 0x104 --channel vcan0   # no gateway: the floor

A responder on the bus answers each frame with an even identifier
0x100..0x10E with the next identifier and the same data. The script
connects, then reads block sizes from stdin, one per line; for each it
sends that many request frames one after another, each with a fresh 8-byte
sequence number, waits for the matching answer, and prints one JSON line
{"ns": [...]} with the round-trip times. Staying connected between blocks
lets the caller alternate the gateways in blocks without paying python's
start-up in the figures. "ready" is printed once connected and warmed up.

Each instance has its own identifiers and receives only its answers (the
filter is applied by the kernel, the gateway or, for socketcand, which
forwards every frame, by python-can), and drops whatever queued up while
the other instances had their turn before timing a block: a block measures
round trips, not the backlog of the others' traffic.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time

import can

# A lost frame must not hang the benchmark; no sane round trip takes this.
TIMEOUT_S = 5.0


def open_bus(args: argparse.Namespace) -> can.BusABC:
    filters = [{"can_id": args.request_id + 1, "can_mask": 0x7FF, "extended": False}]
    if args.interface == "socketcand":
        # tcp_tune: TCP_NODELAY and TCP_QUICKACK, python-can's low-latency
        # setting for socketcand (off by default): the peer at its best.
        return can.Bus(
            interface="socketcand",
            host=args.host,
            port=args.port,
            channel=args.channel,
            tcp_tune=True,
            can_filters=filters,
        )
    if args.interface == "socketcan":
        return can.Bus(interface="socketcan", channel=args.channel, can_filters=filters)
    return can.Bus(
        interface="cangate", server=args.server, channel=args.channel, can_filters=filters
    )


def drain(bus: can.BusABC) -> None:
    while bus.recv(timeout=0) is not None:
        pass


def round_trip(bus: can.BusABC, args: argparse.Namespace, seq: int) -> int:
    data = seq.to_bytes(8, "little")
    start = time.perf_counter_ns()
    bus.send(can.Message(arbitration_id=args.request_id, data=data, is_extended_id=False))
    deadline = time.monotonic() + TIMEOUT_S
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError(
                f"{args.interface}: no answer to round trip {seq} within {TIMEOUT_S} s"
            )
        msg = bus.recv(timeout=left)
        # A late answer to an earlier round trip is not this one's.
        if msg is not None and bytes(msg.data) == data:
            return time.perf_counter_ns() - start


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("interface", choices=["socketcand", "cangate", "socketcan"])
    p.add_argument("--channel", required=True)
    p.add_argument("--request-id", type=lambda s: int(s, 0), required=True)
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=29536)
    p.add_argument("--server", default="http://127.0.0.1:50051")
    p.add_argument("--warmup", type=int, default=50)
    args = p.parse_args()
    if args.request_id % 2 or not 0x100 <= args.request_id <= 0x10E:
        p.error("--request-id: an even identifier 0x100..0x10E (the responder's range)")
    # python-can's socketcand interface warns whenever a TCP read ends in
    # the middle of a frame, which is normal for a stream; errors still show.
    logging.basicConfig(level=logging.ERROR)

    bus = open_bus(args)
    seq = 0
    try:
        for _ in range(args.warmup):
            seq += 1
            round_trip(bus, args, seq)
        print("ready", flush=True)
        for line in sys.stdin:
            n = int(line)
            drain(bus)
            ns = []
            for _ in range(n):
                seq += 1
                ns.append(round_trip(bus, args, seq))
            print(json.dumps({"ns": ns}), flush=True)
    finally:
        bus.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
