# cangate gateway image.
#
#   docker build -t cangate .
#   docker run --rm -p 127.0.0.1:50051:50051 cangate     # the embedded demo
#   # real CAN: host network so the container sees can0, config mounted
#   docker run --rm --network host --read-only --cap-drop ALL \
#       -v $PWD/deploy/examples/hardware.toml:/etc/cangate/cangate.toml:ro \
#       cangate --config /etc/cangate/cangate.toml
#
# deploy/compose.yaml and deploy/kubernetes/ run the same image.
#
# Without arguments the image runs the embedded demo (virtual buses,
# simulated devices) on 0.0.0.0:50051, so that a published port reaches it.
# Arguments replace that default: with --config the file's `listen` applies
# (loopback in the examples; add `--listen 0.0.0.0:50051` or set
# CANGATE_LISTEN when the port must be reachable from outside the container).
#
# The build runs the same cargo command as CI (--locked). protox compiles
# the .proto files in Rust, so no protoc is needed.

FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release --locked -p cangate-server -p cangate-client

FROM debian:bookworm-slim
ARG VERSION=0.1.0
ARG REVISION=unknown
LABEL org.opencontainers.image.title="cangate" \
      org.opencontainers.image.description="gRPC gateway between CAN buses (SocketCAN, CANopen) and remote clients" \
      org.opencontainers.image.version="${VERSION}" \
      org.opencontainers.image.revision="${REVISION}" \
      org.opencontainers.image.licenses="MIT OR Apache-2.0" \
      org.opencontainers.image.source="https://example.invalid/cangate" \
      org.opencontainers.image.base.name="docker.io/library/debian:bookworm-slim"
# A fixed numeric uid/gid: Kubernetes' runAsNonRoot can only verify a
# numeric USER, and the manifests in deploy/ use the same ids.
RUN groupadd --system --gid 10001 cangate \
    && useradd --system --uid 10001 --gid 10001 --no-create-home \
       --home-dir /nonexistent --shell /usr/sbin/nologin cangate
COPY --from=build /src/target/release/cangate-server /usr/local/bin/cangate-server
COPY --from=build /src/target/release/cangate /usr/local/bin/cangate
USER 10001:10001
EXPOSE 50051
# The server shuts down gracefully on SIGTERM within 10 s; give it
# `docker stop -t 15` (compose: stop_grace_period) to finish.
STOPSIGNAL SIGTERM
# A real gRPC round trip (the Bus service's ListBuses) with the bundled
# client: no extra probe binary in the image. Kubernetes uses its native
# grpc probe against grpc.health.v1 instead (deploy/kubernetes/).
HEALTHCHECK --interval=10s --timeout=3s --start-period=5s --retries=3 \
    CMD ["cangate", "--server", "http://127.0.0.1:50051", "buses"]
ENTRYPOINT ["cangate-server"]
CMD ["--listen", "0.0.0.0:50051"]
