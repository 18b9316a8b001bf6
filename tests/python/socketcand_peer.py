"""python-can's `socketcand` interface (and python `canopen` over it)
against cangate's socketcand endpoint; driven by tests/tests/socketcand.rs.

    socketcand_peer.py HOST PORT CHANNEL MODE

CHANNEL goes verbatim into `< open CHANNEL >`: "can0", or "can0 TOKEN".
Every line printed is one observation the test checks; the last line is
"DONE" when the scenario ran to its end. Exit status 0 unless python
itself failed.
"""

import logging
import sys
import time

import can


def out(*words):
    print(*words, flush=True)


def bus_for(host, port, channel, **kwargs):
    return can.Bus(interface="socketcand", host=host, port=int(port), channel=channel, **kwargs)


def send(host, port, channel):
    """Two frames, standard and extended, then a clean shutdown."""
    bus = bus_for(host, port, channel)
    out("OPEN")
    bus.send(can.Message(arbitration_id=0x123, data=[1, 2, 3], is_extended_id=False))
    bus.send(can.Message(arbitration_id=0x1ABCDEF0, data=[0xDE, 0xAD], is_extended_id=True))
    bus.send(can.Message(arbitration_id=0x7FF, data=[], is_extended_id=False))
    out("SENT 3")
    # Wait for the test to have seen them before closing.
    sys.stdin.readline()
    bus.shutdown()


def receive(host, port, channel):
    """Frames sent by a gRPC client, through python-can's (software)
    filters: 0x321 (standard) and 0x1BADCAFE (extended) only."""
    filters = [
        {"can_id": 0x321, "can_mask": 0x7FF, "extended": False},
        {"can_id": 0x1BADCAFE, "can_mask": 0x1FFFFFFF, "extended": True},
    ]
    bus = bus_for(host, port, channel, can_filters=filters)
    out("READY")
    got = 0
    deadline = time.monotonic() + 20
    while got < 3 and time.monotonic() < deadline:
        msg = bus.recv(timeout=1.0)
        if msg is None:
            continue
        got += 1
        out(
            "RX",
            f"{msg.arbitration_id:X}",
            "ext" if msg.is_extended_id else "std",
            msg.data.hex() or "-",
            f"{msg.timestamp:.6f}",
        )
    bus.shutdown()


def unfiltered(host, port, channel):
    """The demo bus's own traffic (SYNC, heartbeats, PDOs) arrives too."""
    bus = bus_for(host, port, channel)
    ids = set()
    deadline = time.monotonic() + 5
    # Until the master's SYNC (0x80) and two more identifiers were seen.
    while (len(ids) < 3 or 0x80 not in ids) and time.monotonic() < deadline:
        msg = bus.recv(timeout=1.0)
        if msg is not None:
            ids.add(msg.arbitration_id)
    out("IDS", " ".join(f"{i:X}" for i in sorted(ids)))
    bus.shutdown()


class ErrorLines(logging.Handler):
    """The `< error ... >` lines python-can received (it logs every read at
    DEBUG; its CanError names only what it failed to parse)."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.lines = []

    def emit(self, record):
        text = record.getMessage()
        start = text.find("< error ")
        if start >= 0:
            self.lines.append(text[start : text.index(">", start) + 1])


def refused_send(host, port, channel):
    """A send the gateway refuses comes back as an `< error ... >` line,
    which python-can's next recv raises as a CanError (python-can reads
    `< error ... >` as an error frame `< error CLASS SECS.USECS >` and
    fails on the text)."""
    errors = ErrorLines()
    logger = logging.getLogger("can.interfaces.socketcand.socketcand")
    logger.setLevel(logging.DEBUG)
    logger.addHandler(errors)
    bus = bus_for(host, port, channel)
    out("OPEN")
    bus.send(can.Message(arbitration_id=0x124, data=[9], is_extended_id=False))
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        try:
            bus.recv(timeout=0.5)
        except can.CanError:
            out("REFUSED", errors.lines[-1] if errors.lines else "no error line")
            break
    bus.shutdown()


def refused_open(host, port, channel):
    try:
        bus = bus_for(host, port, channel)
    except can.CanError as e:
        out("REFUSED", str(e).splitlines()[0])
        return
    out("OPEN")
    bus.shutdown()


def sdo(host, port, channel, node_id):
    """SDO client of python canopen over python-can's socketcand bus
    against a simulated node of the gateway (the I/O module)."""
    import canopen

    bus = bus_for(host, port, channel)
    network = canopen.Network(bus)
    network.connect()
    node = canopen.RemoteNode(int(node_id), canopen.ObjectDictionary())
    network.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0
    # Segmented upload: the device name (longer than 4 bytes).
    name = node.sdo.upload(0x1008, 0)
    out("UPLOAD 1008", name.decode("ascii", "replace").replace(" ", "_"))
    # Expedited upload: vendor id.
    vendor = node.sdo.upload(0x1018, 1)
    out("UPLOAD 1018.1", vendor.hex())
    # Expedited download, then read back.
    node.sdo.download(0x6200, 1, bytes([0x5A]))
    out("READBACK 6200.1", node.sdo.upload(0x6200, 1).hex())
    # Segmented download (forced), then read back.
    node.sdo.download(0x6200, 2, bytes([0xA5]), force_segment=True)
    out("READBACK 6200.2", node.sdo.upload(0x6200, 2).hex())
    # An abort from the device: no such object.
    try:
        node.sdo.upload(0x5FFF, 0)
        out("NO ABORT")
    except canopen.SdoAbortedError as e:
        out("ABORT", f"{e.code:08X}")
    network.disconnect()


def main():
    host, port, channel, mode, *rest = sys.argv[1:]
    {
        "send": send,
        "receive": receive,
        "unfiltered": unfiltered,
        "refused_send": refused_send,
        "refused_open": refused_open,
        "sdo": sdo,
    }[mode](host, port, channel, *rest)
    out("DONE")


if __name__ == "__main__":
    main()
