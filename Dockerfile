# cangate gateway image.
#
#   docker build -t cangate .
#   docker run --rm cangate                      # the embedded demo
#   # real CAN: host network so that the container sees can0, config mounted
#   docker run --rm --network host --read-only --cap-drop ALL \
#       -v $PWD/deploy/examples/hardware.toml:/etc/cangate/cangate.toml:ro \
#       cangate --config /etc/cangate/cangate.toml
#
# deploy/compose.yaml and deploy/kubernetes/ run the same image.
#
# Without arguments the image runs the embedded demo (virtual buses,
# simulated devices). Like every configuration it listens on loopback, here
# the container's own, so it is reachable only from inside the container
# (`docker exec <container> cangate buses`). The gateway has no
# authentication yet and refuses a network address unless told to accept
# the risk; to publish the demo port (deploy/compose.yaml does this):
#
#   docker run --rm -p 127.0.0.1:50051:50051 \
#       -e CANGATE_LISTEN=0.0.0.0:50051 -e CANGATE_SECURITY__INSECURE=true cangate
#
# Stopping: the server stops moving axes (bounded 5 s), then closes streams
# and buses (bounded 10 s); give it `docker stop -t 20`.
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
# Graceful shutdown on SIGTERM (at most 15 s, see above).
STOPSIGNAL SIGTERM
# A real gRPC round trip (the Bus service's ListBuses) with the bundled
# client: no extra probe binary in the image. Kubernetes uses its native
# grpc probe against grpc.health.v1 instead (deploy/kubernetes/).
HEALTHCHECK --interval=10s --timeout=3s --start-period=5s --retries=3 \
    CMD ["cangate", "--server", "http://127.0.0.1:50051", "buses"]
# No arguments: the embedded demo.
ENTRYPOINT ["cangate-server"]
