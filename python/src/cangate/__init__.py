"""Python client of the cangate gRPC CAN gateway.

- :class:`Client`: a thin typed client (buses, CANopen SDO/NMT/events, axes
  with a control lease, handwheel feed).
- ``can.Bus(interface="cangate", channel="can0")``: a python-can interface
  on the gateway's ``Bus.Attach`` (:class:`cangate.can_interface.CangateBus`).
- :mod:`cangate.v1`: the generated protobuf messages and gRPC stubs.

The server is ``server=`` or ``CANGATE_SERVER`` (default
``http://127.0.0.1:50051``), the token ``token=`` or ``CANGATE_TOKEN``.
"""

from cangate.client import (
    AxisHandle,
    Client,
    DataType,
    Frame,
    FramesLost,
    Lease,
    SdoSession,
    SdoValue,
    Stream,
)
from cangate.errors import CangateError, SdoAbortError

__version__ = "0.1.0"

__all__ = [
    "AxisHandle",
    "CangateError",
    "Client",
    "DataType",
    "Frame",
    "FramesLost",
    "Lease",
    "SdoAbortError",
    "SdoSession",
    "SdoValue",
    "Stream",
]
