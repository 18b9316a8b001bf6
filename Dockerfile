# cangate gateway image.
#
#   docker build -t cangate .
#   docker run -p 50051:50051 cangate            # the embedded demo
#   docker run --network host -v $PWD/cangate.toml:/etc/cangate.toml \
#       cangate --config /etc/cangate.toml        # real CAN (host network for can0)
#
# The build runs the same cargo command as CI (--locked). protox compiles
# the .proto files in Rust, so no protoc is needed.

FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY . .
RUN cargo build --release --locked -p cangate-server -p cangate-client

FROM debian:bookworm-slim
RUN useradd --system --uid 10001 --no-create-home cangate
COPY --from=build /src/target/release/cangate-server /usr/local/bin/cangate-server
COPY --from=build /src/target/release/cangate /usr/local/bin/cangate
USER cangate
# Inside a container the gateway must listen on all interfaces to be
# reachable through the published port.
ENV CANGATE_LISTEN=0.0.0.0:50051
EXPOSE 50051
HEALTHCHECK --interval=10s --timeout=3s CMD ["cangate", "--server", "http://127.0.0.1:50051", "buses"]
ENTRYPOINT ["cangate-server"]
