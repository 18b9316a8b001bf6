"""A standard gRPC client reads cangate's errors (the richer error model).

Run by tests/tests/python_rich_errors.rs against a gateway it started:

    python rich_errors.py PROTO_ROOT HOST:PORT

Generates the Python stubs of PROTO_ROOT/cangate/v1/*.proto with
grpcio-tools into a temporary directory (nothing generated is kept), makes
calls that fail, and decodes each error as any gRPC client would: the
google.rpc.Status of `grpc-status-details-bin` with
grpc_status.rpc_status.from_call, its google.rpc.ErrorInfo, and for SDO
errors the cangate.v1.SdoAbortDetails packed as an Any. Prints one line per
checked error; any mismatch raises (non-zero exit with a traceback).
"""

import glob
import os
import signal
import sys
import tempfile

import grpc
import grpc_tools
from google.rpc import code_pb2, error_details_pb2
from grpc_status import rpc_status
from grpc_tools import protoc

DOMAIN = "cangate.v1"
CALL_TIMEOUT_S = 10


def generate_stubs(proto_root, out):
    files = sorted(glob.glob(os.path.join(proto_root, "cangate", "v1", "*.proto")))
    assert files, f"no .proto files under {proto_root}"
    well_known = os.path.join(os.path.dirname(grpc_tools.__file__), "_proto")
    rc = protoc.main(
        [
            "grpc_tools.protoc",
            f"-I{proto_root}",
            f"-I{well_known}",
            f"--python_out={out}",
            f"--grpc_python_out={out}",
            *files,
        ]
    )
    assert rc == 0, f"protoc failed with {rc}"
    sys.path.insert(0, out)


def fails(call, request):
    """The RpcError of a call that must fail."""
    try:
        call(request, timeout=CALL_TIMEOUT_S)
    except grpc.RpcError as err:
        return err
    raise AssertionError(f"{request} succeeded; expected an error")


def decode(err, code, reason):
    """The rich status of `err`: checks its code, message and ErrorInfo;
    returns (status, ErrorInfo metadata as a dict)."""
    assert err.code().value[0] == code, f"code {err.code()}, expected {code}: {err}"
    status = rpc_status.from_call(err)
    assert status is not None, f"no google.rpc.Status in {err}"
    assert status.code == code, status
    assert status.message == err.details(), (status.message, err.details())
    infos = []
    for detail in status.details:
        if detail.Is(error_details_pb2.ErrorInfo.DESCRIPTOR):
            info = error_details_pb2.ErrorInfo()
            assert detail.Unpack(info)
            infos.append(info)
    assert len(infos) == 1, f"expected one ErrorInfo: {status}"
    info = infos[0]
    assert info.domain == DOMAIN, info
    assert info.reason == reason, f"reason {info.reason!r}, expected {reason!r}"
    return status, dict(info.metadata)


def sdo_abort(status, canopen_pb2):
    found = []
    for detail in status.details:
        if detail.Is(canopen_pb2.SdoAbortDetails.DESCRIPTOR):
            d = canopen_pb2.SdoAbortDetails()
            assert detail.Unpack(d)
            found.append(d)
    assert len(found) == 1, f"expected one SdoAbortDetails: {status}"
    assert (
        status.details[1].type_url == "type.googleapis.com/cangate.v1.SdoAbortDetails"
    ), status.details[1].type_url
    return found[0]


def trailer(err, key):
    return dict(err.trailing_metadata() or ()).get(key)


def main():
    proto_root, address = sys.argv[1], sys.argv[2]
    # Never outlive the test that started us.
    signal.alarm(120)
    with tempfile.TemporaryDirectory(prefix="cangate-stubs-") as out:
        generate_stubs(proto_root, out)
        from cangate.v1 import (  # noqa: E402 (generated above)
            bus_pb2,
            bus_pb2_grpc,
            canopen_pb2,
            canopen_pb2_grpc,
        )

        with grpc.insecure_channel(address) as channel:
            canopen = canopen_pb2_grpc.CanopenStub(channel)
            bus = bus_pb2_grpc.BusStub(channel)

            # A node abort: the object does not exist.
            err = fails(
                canopen.ReadSdo,
                canopen_pb2.ReadSdoRequest(bus="can0", node=1, index=0x5555, subindex=0),
            )
            status, meta = decode(err, code_pb2.NOT_FOUND, "SDO_ABORT")
            assert meta == {
                "abort_code": "0x06020000",
                "abort_name": "object does not exist in the object dictionary",
                "node": "1",
                "index": "0x5555",
                "subindex": "0",
                "aborted_by": "node",
            }, meta
            d = sdo_abort(status, canopen_pb2)
            assert (d.code, d.index, d.subindex, d.from_node) == (0x06020000, 0x5555, 0, True), d
            assert d.name == meta["abort_name"], d
            assert trailer(err, "cangate-sdo-abort") == (
                "0x06020000 object does not exist in the object dictionary"
            ), err.trailing_metadata()
            print(f"ok ReadSdo 0x5555: {err.code().name} {meta['abort_code']} {d.name}")

            # A node abort: writing a read-only object.
            err = fails(
                canopen.WriteSdo,
                canopen_pb2.WriteSdoRequest(
                    bus="can0", node=1, index=0x1000, subindex=0, raw=b"\x01\x02\x03\x04"
                ),
            )
            status, meta = decode(err, code_pb2.FAILED_PRECONDITION, "SDO_ABORT")
            assert meta["abort_code"] == "0x06010002" and meta["index"] == "0x1000", meta
            d = sdo_abort(status, canopen_pb2)
            assert d.code == 0x06010002 and d.from_node, d
            print(f"ok WriteSdo 0x1000: {err.code().name} {meta['abort_code']} {d.name}")

            # The gateway's abort: a configured node that never answers.
            err = fails(
                canopen.ReadSdo,
                canopen_pb2.ReadSdoRequest(bus="can0", node=10, index=0x1000, subindex=0),
            )
            status, meta = decode(err, code_pb2.DEADLINE_EXCEEDED, "SDO_TIMEOUT")
            assert meta["abort_code"] == "0x05040000" and meta["aborted_by"] == "gateway", meta
            assert meta["node"] == "10", meta
            d = sdo_abort(status, canopen_pb2)
            assert d.code == 0x05040000 and not d.from_node, d
            print(f"ok ReadSdo node 10: {err.code().name} {meta['abort_code']} by gateway")

            # Not an SDO error: an unknown bus, named in the metadata.
            err = fails(bus.GetBus, bus_pb2.GetBusRequest(bus="nope"))
            status, meta = decode(err, code_pb2.NOT_FOUND, "BUS_NOT_FOUND")
            assert meta == {"kind": "bus", "name": "nope"}, meta
            assert len(status.details) == 1, status
            assert trailer(err, "cangate-sdo-abort") is None
            print(f"ok GetBus nope: {err.code().name} BUS_NOT_FOUND")

    print("rich errors: all checks passed")


if __name__ == "__main__":
    main()
