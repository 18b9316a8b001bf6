#!/usr/bin/env python3
"""SDO reference benchmark: python `canopen` reading from a python `canopen`
LocalNode over python-can's in-process ``virtual`` interface.

Two networks share one virtual channel, as a master and a device would share
a bus: the master's ``RemoteNode`` runs the SDO client, the device's
``LocalNode`` the SDO server (each network has its own python-can notifier
thread, so every request and every response crosses a thread boundary, like
frames between two processes on a real bus).

Both nodes use the object dictionary of the simulated drive
(crates/canopen/eds/cangate-drive.eds); 0x1008 is set to a 40-character
string so that reading it is a segmented transfer (initiate + 6 segments),
exactly like the Rust side of the benchmark.

Measured: N sequential reads (after a warm-up) of
- ``expedited``: 0x1017:00 (UNSIGNED16, one round trip);
- ``segmented``: 0x1008:00 (40-char VISIBLE_STRING, 7 round trips).

Each read is timed with ``time.perf_counter_ns``; reads/s is N divided by
the wall time of the whole loop.

    python3 bench/python/sdo_reference.py            # human-readable
    python3 bench/python/sdo_reference.py --json     # one JSON object
"""

import argparse
import json
import math
import os
import sys
import time

try:
    import can  # noqa: F401  (python-can, the virtual interface)
    import canopen
except ImportError as e:  # pragma: no cover - reported to the Rust runner
    print(
        json.dumps({"error": f"missing python package: {e.name}"})
        if "--json" in sys.argv
        else f"missing python package: {e.name}; "
        "run: python3 -m pip install -r bench/python/requirements.txt",
        file=sys.stdout if "--json" in sys.argv else sys.stderr,
    )
    sys.exit(3)

NODE_ID = 5
DEVICE_NAME_40 = "cangate sim drive / 40-char device name!"
assert len(DEVICE_NAME_40) == 40

HERE = os.path.dirname(os.path.abspath(__file__))
EDS = os.path.normpath(
    os.path.join(HERE, "..", "..", "crates", "canopen", "eds", "cangate-drive.eds")
)


def object_dictionary():
    """The drive's EDS if it is there, else the two objects we read."""
    if os.path.exists(EDS):
        return canopen.import_od(EDS, NODE_ID)
    od = canopen.ObjectDictionary()
    hb = canopen.objectdictionary.ODVariable("Producer heartbeat time", 0x1017, 0)
    hb.data_type = canopen.objectdictionary.UNSIGNED16
    hb.access_type = "rw"
    hb.default = 1000
    od.add_object(hb)
    name = canopen.objectdictionary.ODVariable("Manufacturer device name", 0x1008, 0)
    name.data_type = canopen.objectdictionary.VISIBLE_STRING
    name.access_type = "const"
    name.default = "cangate sim drive"
    od.add_object(name)
    return od


def percentile(sorted_ns, q):
    """Nearest-rank percentile (as hdrhistogram's value_at_quantile)."""
    if not sorted_ns:
        return 0
    rank = max(1, math.ceil(q * len(sorted_ns)))
    return sorted_ns[min(rank, len(sorted_ns)) - 1]


def measure(read, n, warmup):
    for _ in range(warmup):
        read()
    samples = [0] * n
    clock = time.perf_counter_ns
    start = clock()
    for i in range(n):
        t0 = clock()
        read()
        samples[i] = clock() - t0
    total = clock() - start
    samples.sort()
    return {
        "n": n,
        "p50_us": percentile(samples, 0.50) / 1000.0,
        "p99_us": percentile(samples, 0.99) / 1000.0,
        "max_us": samples[-1] / 1000.0,
        "mean_us": sum(samples) / n / 1000.0,
        "reads_per_s": n / (total / 1e9),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-n", "--reads", type=int, default=2000, help="timed reads per case")
    ap.add_argument("--warmup", type=int, default=200, help="untimed reads before each case")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--channel", default=f"cangate-sdo-ref-{os.getpid()}")
    args = ap.parse_args()

    device_net = canopen.Network()
    device_net.connect(interface="virtual", channel=args.channel, receive_own_messages=False)
    master_net = canopen.Network()
    master_net.connect(interface="virtual", channel=args.channel, receive_own_messages=False)
    try:
        local = canopen.LocalNode(NODE_ID, object_dictionary())
        local.set_data(0x1008, 0, DEVICE_NAME_40.encode("ascii"), check_writable=False)
        device_net.add_node(local)
        remote = canopen.RemoteNode(NODE_ID, object_dictionary())
        master_net.add_node(remote)
        sdo = remote.sdo
        sdo.RESPONSE_TIMEOUT = 1.0

        # Sanity: the values are what the Rust side reads.
        hb = sdo.upload(0x1017, 0)
        name = sdo.upload(0x1008, 0)
        if len(hb) != 2 or name != DEVICE_NAME_40.encode("ascii"):
            raise SystemExit(f"unexpected values: 0x1017={hb!r} 0x1008={name!r}")

        result = {
            "implementation": f"python-canopen {canopen.__version__} / python-can {can.__version__} "
            f"(virtual), CPython {sys.version.split()[0]}",
            "expedited": measure(lambda: sdo.upload(0x1017, 0), args.reads, args.warmup),
            "segmented": measure(lambda: sdo.upload(0x1008, 0), args.reads, args.warmup),
        }
    finally:
        master_net.disconnect()
        device_net.disconnect()

    if args.json:
        print(json.dumps(result))
    else:
        print(result["implementation"])
        for case in ("expedited", "segmented"):
            r = result[case]
            print(
                f"{case:10} n={r['n']}  p50 {r['p50_us']:8.1f} us  p99 {r['p99_us']:8.1f} us  "
                f"{r['reads_per_s']:9.0f} reads/s"
            )


if __name__ == "__main__":
    main()
