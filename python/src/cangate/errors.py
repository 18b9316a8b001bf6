"""Errors of the gateway as python exceptions, decoded from the gRPC richer
error model (see "The error model" in proto/cangate/v1/canopen.proto)."""

from __future__ import annotations

from typing import Optional

import grpc
from google.rpc import error_details_pb2
from grpc_status import rpc_status

from cangate.v1 import canopen_pb2

#: ErrorInfo.domain of every error the gateway makes.
DOMAIN = "cangate.v1"


class CangateError(Exception):
    """A call failed: the gRPC status `code` (a ``grpc.StatusCode``), the
    server's `message`, and from its ``google.rpc.ErrorInfo`` the stable
    `reason` ("BUS_NOT_FOUND", "SDO_ABORT", ...; the code's name when the
    status has no details) and its `metadata`."""

    def __init__(
        self,
        code: grpc.StatusCode,
        message: str,
        reason: str,
        metadata: Optional[dict] = None,
    ) -> None:
        super().__init__(f"{code.name}: {message}" if message else code.name)
        self.code = code
        self.message = message
        self.reason = reason
        self.metadata: dict = dict(metadata or {})


class SdoAbortError(CangateError):
    """An SDO transfer was aborted (reasons SDO_ABORT, SDO_TIMEOUT,
    SDO_PROTOCOL_ERROR, SDO_CANCELLED, SDO_NOT_SENT): the CiA 301 `abort_code`
    and its `abort_name`, the object (`index`, `subindex`), and whether the
    node sent the abort (`from_node`) or the gateway did (timeout, protocol
    error, a request the CAN interface could not send)."""

    def __init__(
        self,
        code: grpc.StatusCode,
        message: str,
        reason: str,
        metadata: dict,
        details: Optional[canopen_pb2.SdoAbortDetails],
    ) -> None:
        super().__init__(code, message, reason, metadata)
        if details is not None:
            self.abort_code: int = details.code
            self.abort_name: str = details.name
            self.index: int = details.index
            self.subindex: int = details.subindex
            self.from_node: bool = details.from_node
        else:
            self.abort_code = int(metadata.get("abort_code", "0"), 16)
            self.abort_name = metadata.get("abort_name", "")
            self.index = int(metadata.get("index", "0"), 16)
            self.subindex = int(metadata.get("subindex", "0"))
            self.from_node = metadata.get("aborted_by") == "node"
        node = metadata.get("node", "")
        self.node: Optional[int] = int(node) if node.isdigit() else None


_SDO_REASONS = {
    "SDO_ABORT",
    "SDO_TIMEOUT",
    "SDO_PROTOCOL_ERROR",
    "SDO_CANCELLED",
    "SDO_NOT_SENT",
}


def from_rpc_error(err: grpc.RpcError) -> CangateError:
    """The python exception of a failed call."""
    code = err.code() if hasattr(err, "code") else grpc.StatusCode.UNKNOWN
    message = err.details() if hasattr(err, "details") else str(err)
    reason, metadata, sdo = code.name, {}, None
    try:
        status = rpc_status.from_call(err)
    except ValueError:
        status = None  # a status whose details disagree with the call's
    if status is not None:
        for detail in status.details:
            if detail.Is(error_details_pb2.ErrorInfo.DESCRIPTOR):
                info = error_details_pb2.ErrorInfo()
                detail.Unpack(info)
                reason, metadata = info.reason, dict(info.metadata)
            elif detail.Is(canopen_pb2.SdoAbortDetails.DESCRIPTOR):
                sdo = canopen_pb2.SdoAbortDetails()
                detail.Unpack(sdo)
    if reason in _SDO_REASONS:
        return SdoAbortError(code, message or "", reason, metadata, sdo)
    return CangateError(code, message or "", reason, metadata)


def from_session_error(err: "canopen_pb2.SdoSessionError") -> CangateError:
    """The python exception of a failed request of an SDO session: the
    same as the unary call's (`err` carries its status's code, message,
    ErrorInfo reason and metadata, and SDO abort)."""
    code = next((c for c in grpc.StatusCode if c.value[0] == err.code), grpc.StatusCode.UNKNOWN)
    sdo = err.abort if err.HasField("abort") else None
    if err.reason in _SDO_REASONS:
        return SdoAbortError(code, err.message, err.reason, dict(err.metadata), sdo)
    return CangateError(code, err.message, err.reason, dict(err.metadata))
