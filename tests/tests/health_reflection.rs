//! gRPC health and reflection are served, so standard tools (grpcurl,
//! grpc_health_probe, Kubernetes probes) work against the gateway.

use cangate_tests::*;
use tonic_health::pb::HealthCheckRequest;
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::health_client::HealthClient;
use tonic_reflection::pb::v1::ServerReflectionRequest;
use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_and_reflection() {
    let server = start_server(ONE_BUS).await;
    let c = client(&server).await;
    let mut health = HealthClient::new(c.channel());
    for service in ["", "cangate.v1.Bus", "cangate.v1.Canopen"] {
        let r = health
            .check(HealthCheckRequest {
                service: service.into(),
            })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(r.status, ServingStatus::Serving as i32, "{service:?}");
    }

    let mut reflection = ServerReflectionClient::new(c.channel());
    let req = ServerReflectionRequest {
        host: String::new(),
        message_request: Some(MessageRequest::ListServices(String::new())),
    };
    let mut stream = reflection
        .server_reflection_info(tokio_stream::iter([req]))
        .await
        .unwrap()
        .into_inner();
    let resp = stream.message().await.unwrap().unwrap();
    let Some(MessageResponse::ListServicesResponse(list)) = resp.message_response else {
        panic!("{resp:?}")
    };
    let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
    for want in [
        "cangate.v1.Bus",
        "cangate.v1.Canopen",
        "grpc.health.v1.Health",
    ] {
        assert!(
            names.iter().any(|n| n == want),
            "{want} missing from {names:?}"
        );
    }
    server.shutdown();
}

/// Tools that speak only the older `grpc.reflection.v1alpha` (Python's
/// grpcio-reflection, older grpcurl, GUIs) are served too, with the same
/// answers, and can resolve a service's file.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reflection_is_served_as_v1alpha_too() {
    use alpha::server_reflection_request::MessageRequest as AlphaRequest;
    use alpha::server_reflection_response::MessageResponse as AlphaResponse;
    use tonic_reflection::pb::v1alpha as alpha;
    let server = start_server(ONE_BUS).await;
    let c = client(&server).await;
    let mut reflection = alpha::server_reflection_client::ServerReflectionClient::new(c.channel());
    let requests = [
        alpha::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(AlphaRequest::ListServices(String::new())),
        },
        alpha::ServerReflectionRequest {
            host: String::new(),
            message_request: Some(AlphaRequest::FileContainingSymbol("cangate.v1.Axes".into())),
        },
    ];
    let mut stream = reflection
        .server_reflection_info(tokio_stream::iter(requests))
        .await
        .expect("v1alpha reflection is served")
        .into_inner();
    let resp = stream.message().await.unwrap().unwrap();
    let Some(AlphaResponse::ListServicesResponse(list)) = resp.message_response else {
        panic!("{resp:?}")
    };
    let names: Vec<String> = list.service.into_iter().map(|s| s.name).collect();
    assert!(
        names.iter().any(|n| n == "cangate.v1.Axes"),
        "cangate.v1.Axes missing from {names:?}"
    );
    let resp = stream.message().await.unwrap().unwrap();
    let Some(AlphaResponse::FileDescriptorResponse(files)) = resp.message_response else {
        panic!("{resp:?}")
    };
    assert!(!files.file_descriptor_proto.is_empty());
    server.shutdown();
}
