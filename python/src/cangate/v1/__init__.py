"""Generated protobuf messages and gRPC stubs of the cangate API (package
``cangate.v1``), one module pair per .proto file: ``bus_pb2`` /
``bus_pb2_grpc``, ``canopen_pb2``, ``axes_pb2``, ``handwheel_pb2``,
``cansmc_pb2``. Do not edit the generated modules: run
``python/generate_stubs.py``.
"""
