//! Shutdown with open streams: the cancellation the signal handler fires
//! ends the server promptly, and every stream ends cleanly (no error).

mod common;

use common::*;
use std::time::Duration;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_ends_streams_cleanly_and_promptly() {
    let server = start_server(ONE_BUS).await;
    let mut a = client(&server).await;
    let mut b = client(&server).await;
    let (mut s1, _) = open_stream(&mut a, stream_request("can0", vec![])).await;
    let (mut s2, _) = open_stream(&mut b, stream_request("can0", vec![])).await;
    let addr = server.addr;
    let started = std::time::Instant::now();
    // What SIGINT/SIGTERM do in cangate-server's main.
    server.shutdown();
    for s in [&mut s1, &mut s2] {
        let end = tokio::time::timeout(WAIT, s.message())
            .await
            .expect("stream ends in time");
        assert!(
            matches!(end, Ok(None)),
            "stream ends cleanly with OK, got {end:?}"
        );
    }
    server
        .wait(Duration::from_secs(5))
        .await
        .expect("server stops within 5 s");
    assert!(started.elapsed() < Duration::from_secs(5));
    // The listener is closed once it has stopped.
    assert!(
        cangate_client::connect(&format!("http://{addr}"))
            .await
            .is_err()
    );
}
