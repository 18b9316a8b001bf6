#!/usr/bin/env python3
"""Generates the gRPC stubs of the cangate package from the .proto contract.

    python generate_stubs.py          # rewrite src/cangate/v1/*_pb2*.py{,i}
    python generate_stubs.py --check  # fail if the committed stubs differ

Needs grpcio-tools (``pip install grpcio-tools==1.85.1``, the version the
committed stubs were made with; see pyproject.toml). The .proto files live in
``../proto/proto/cangate/v1`` and declare ``package cangate.v1``, so with
``-I ../proto/proto`` protoc writes ``cangate/v1/bus_pb2.py`` and the gRPC
modules import ``from cangate.v1 import bus_pb2``: exactly this package's
layout (``src/cangate/v1``), no import rewriting needed.
"""

import argparse
import filecmp
import glob
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
PROTO_ROOT = os.path.normpath(os.path.join(HERE, "..", "proto", "proto"))
SRC = os.path.join(HERE, "src")
PACKAGE_DIR = os.path.join("cangate", "v1")
GENERATED = ("*_pb2.py", "*_pb2_grpc.py", "*_pb2.pyi")


def generate(out: str) -> None:
    """Runs protoc (grpcio-tools) on every .proto file into `out`."""
    from grpc_tools import protoc

    protos = sorted(glob.glob(os.path.join(PROTO_ROOT, PACKAGE_DIR, "*.proto")))
    if not protos:
        raise SystemExit(f"no .proto files under {PROTO_ROOT}")
    # Relative names, so the generated files name "cangate/v1/bus.proto" and
    # not this machine's paths.
    rel = [os.path.relpath(p, PROTO_ROOT) for p in protos]
    cwd = os.getcwd()
    out = os.path.abspath(out)
    os.chdir(PROTO_ROOT)
    try:
        rc = protoc.main(
            [
                "grpc_tools.protoc",
                "-I.",
                f"--python_out={out}",
                f"--pyi_out={out}",
                f"--grpc_python_out={out}",
                *rel,
            ]
        )
    finally:
        os.chdir(cwd)
    if rc != 0:
        raise SystemExit(f"protoc failed with exit status {rc}")


def generated_files(root: str) -> set:
    """The generated files under root/cangate/v1, by name."""
    names = set()
    for pattern in GENERATED:
        names.update(os.path.basename(p) for p in glob.glob(os.path.join(root, PACKAGE_DIR, pattern)))
    return names


def check() -> int:
    """0 when the committed stubs are what the .proto files generate now."""
    with tempfile.TemporaryDirectory(prefix="cangate-stubs-") as tmp:
        generate(tmp)
        fresh = generated_files(tmp)
        committed = generated_files(SRC)
        problems = [f"missing: {n}" for n in sorted(fresh - committed)]
        problems += [f"stale (no .proto makes it): {n}" for n in sorted(committed - fresh)]
        for name in sorted(fresh & committed):
            a = os.path.join(tmp, PACKAGE_DIR, name)
            b = os.path.join(SRC, PACKAGE_DIR, name)
            if not filecmp.cmp(a, b, shallow=False):
                problems.append(f"differs: {name}")
    if problems:
        print("the committed stubs in python/src/cangate/v1 do not match the .proto files:")
        for p in problems:
            print(f"  {p}")
        print("regenerate them: python python/generate_stubs.py")
        return 1
    print(f"stubs up to date: {len(fresh)} files match {PROTO_ROOT}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="compare instead of writing")
    args = ap.parse_args()
    if args.check:
        return check()
    for name in generated_files(SRC):
        os.remove(os.path.join(SRC, PACKAGE_DIR, name))
    generate(SRC)
    print(f"generated {len(generated_files(SRC))} files into {os.path.join(SRC, PACKAGE_DIR)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
