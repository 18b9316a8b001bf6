"""Connecting to the gateway: address, TLS and the bearer token, shared by
the client and the python-can interface."""

from __future__ import annotations

import os
from typing import Any, Callable, Optional

import grpc

#: Where the gateway listens unless told otherwise (as the `cangate` CLI).
DEFAULT_SERVER = "http://127.0.0.1:50051"


def resolve(server: Optional[str], token: Optional[str]) -> tuple[str, Optional[str]]:
    """The server and token from the arguments, else from ``CANGATE_SERVER``
    and ``CANGATE_TOKEN``, else the default address and no token."""
    server = server or os.environ.get("CANGATE_SERVER") or DEFAULT_SERVER
    if token is None:
        token = os.environ.get("CANGATE_TOKEN") or None
    return server, token


def _read(path: Optional[str]) -> Optional[bytes]:
    if path is None:
        return None
    with open(path, "rb") as f:
        return f.read()


def open_channel(
    server: str,
    token: Optional[str] = None,
    *,
    ca: Optional[str] = None,
    cert: Optional[str] = None,
    key: Optional[str] = None,
) -> grpc.Channel:
    """A channel to `server` ("host:port", "http://host:port" or
    "https://host:port"). TLS with https, or when `ca` (a PEM file of the CA
    to trust) or a client certificate (`cert` and `key`, PEM files) is given;
    plaintext otherwise. Every call carries ``authorization: Bearer <token>``
    when a token is given."""
    tls = server.startswith("https://") or ca is not None or cert is not None
    target = server.split("://", 1)[1] if "://" in server else server
    target = target.rstrip("/")
    options = [
        # The gateway's default [security.limits] max_message_bytes.
        ("grpc.max_receive_message_length", 4 * 1024 * 1024),
    ]
    if tls:
        if (cert is None) != (key is None):
            raise ValueError("a client certificate needs both cert and key")
        creds = grpc.ssl_channel_credentials(
            root_certificates=_read(ca),
            private_key=_read(key),
            certificate_chain=_read(cert),
        )
        channel = grpc.secure_channel(target, creds, options=options)
    else:
        channel = grpc.insecure_channel(target, options=options)
    if token:
        channel = grpc.intercept_channel(channel, _BearerToken(token))
    return channel


class _Details(grpc.ClientCallDetails):  # type: ignore[misc]
    def __init__(self, base: grpc.ClientCallDetails, metadata: list) -> None:
        self.method = base.method
        self.timeout = base.timeout
        self.metadata = metadata
        self.credentials = base.credentials
        self.wait_for_ready = getattr(base, "wait_for_ready", None)
        self.compression = getattr(base, "compression", None)


class _BearerToken(
    grpc.UnaryUnaryClientInterceptor,
    grpc.UnaryStreamClientInterceptor,
    grpc.StreamUnaryClientInterceptor,
    grpc.StreamStreamClientInterceptor,
):
    """Adds the bearer token to every call, on plaintext channels too (gRPC
    call credentials need TLS; the gateway accepts tokens on loopback)."""

    def __init__(self, token: str) -> None:
        self._header = ("authorization", f"Bearer {token}")

    def __repr__(self) -> str:
        return "_BearerToken(<redacted>)"

    def _add(self, details: grpc.ClientCallDetails) -> grpc.ClientCallDetails:
        metadata = list(details.metadata or [])
        metadata.append(self._header)
        return _Details(details, metadata)

    def _call(self, continuation: Callable, details: Any, request: Any) -> Any:
        return continuation(self._add(details), request)

    intercept_unary_unary = _call
    intercept_unary_stream = _call
    intercept_stream_unary = _call
    intercept_stream_stream = _call
