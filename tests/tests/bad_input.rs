//! Invalid requests are refused with the right code and a message naming
//! the problem, and nothing reaches the bus.

use cangate_client::pb;
use cangate_tests::*;
use tonic::Code;

fn frame(id: u32, extended: bool, data: &[u8]) -> pb::Frame {
    pb::Frame {
        id,
        extended,
        data: data.to_vec(),
        ..Default::default()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_requests_are_refused_and_nothing_is_sent() {
    let server = start_server(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nfd = true\n\
         [[bus]]\nname = \"classic\"\nbackend = \"virtual\"\n",
    )
    .await;
    let vbus = server.gateway().network().get("can0").unwrap();
    let mut device = vbus.connect(false);
    let mut c = client(&server).await;

    let cases: Vec<(&str, Vec<pb::Frame>, Code, &str)> = vec![
        (
            "can9",
            vec![frame(1, false, &[])],
            Code::NotFound,
            "bus \"can9\" not found",
        ),
        ("can0", vec![], Code::InvalidArgument, "batch is empty"),
        (
            "can0",
            vec![frame(0x100, false, &[1]), frame(0x800, false, &[])],
            Code::InvalidArgument,
            "frame 1: identifier 0x800 does not fit in 11 bits",
        ),
        (
            "can0",
            vec![frame(0x100, false, &[0; 9])],
            Code::InvalidArgument,
            "frame 0: 9 data bytes do not fit in a classic CAN frame",
        ),
        (
            "can0",
            vec![frame(0x2000_0000, true, &[])],
            Code::InvalidArgument,
            "does not fit in 29 bits",
        ),
        (
            "can0",
            vec![pb::Frame {
                fd: true,
                data: vec![0; 9],
                ..frame(1, false, &[])
            }],
            Code::InvalidArgument,
            "9 data bytes is not a valid CAN FD length",
        ),
        (
            "can0",
            vec![pb::Frame {
                remote: true,
                ..frame(1, false, &[1])
            }],
            Code::InvalidArgument,
            "remote frame carries no data",
        ),
        (
            "classic",
            vec![pb::Frame {
                fd: true,
                data: vec![0; 12],
                ..frame(1, false, &[])
            }],
            Code::InvalidArgument,
            "not configured for CAN FD",
        ),
    ];
    for (bus, frames, code, text) in cases {
        let err = c
            .send_pb(bus, frames.clone())
            .await
            .expect_err("must be refused");
        assert_eq!(err.code(), Some(code), "{bus} {frames:?}: {err}");
        assert!(
            err.to_string().contains(text),
            "message {err:?} should contain {text:?}"
        );
    }
    // Unknown bus for the other RPCs too.
    assert_eq!(
        c.get_bus("nope").await.unwrap_err().code(),
        Some(Code::NotFound)
    );
    let err = c
        .stream_frames(stream_request("nope", vec![]))
        .await
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::NotFound));

    // Nothing of any refused batch reached the bus (the valid first frame of
    // the 0x800 batch included).
    tokio::time::sleep(std::time::Duration::from_millis(100)).await;
    assert!(
        device.try_recv().is_none(),
        "a refused batch must not reach the bus"
    );
    let stats = server.gateway().bus("can0").unwrap().stats();
    assert_eq!(stats.tx_frames, 0);

    // Bus-off: FAILED_PRECONDITION, nothing sent.
    vbus.force_bus_off();
    tokio::time::timeout(WAIT, async {
        while c.get_bus("can0").await.unwrap().status.unwrap().state != pb::BusState::BusOff as i32
        {
            // Poll gently: the per-client rate limit applies to tests too.
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("bus-off is reported");
    let err = c
        .send_pb("can0", vec![frame(1, false, &[])])
        .await
        .unwrap_err();
    assert_eq!(err.code(), Some(Code::FailedPrecondition), "{err}");
    assert!(err.to_string().contains("bus-off"), "{err}");
    server.shutdown();
}

/// LSS requests that mean nothing on the bus (a SwitchGlobal mode other
/// than waiting or configuration, an identify range whose low end is above
/// its high end) are refused before any LSS frame goes out.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn meaningless_lss_requests_are_refused_before_the_bus() {
    let server = start_server(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\n[[canopen]]\nbus = \"can0\"\n\
         master_heartbeat_ms = 0\n",
    )
    .await;
    let stats = || server.gateway().bus("can0").unwrap().stats().tx_frames;
    let before = stats();
    let c = client(&server).await;
    let mut lss = c.lss_client();
    let s = lss
        .switch_global(pb::SwitchGlobalRequest {
            bus: "can0".into(),
            mode: 99,
        })
        .await
        .unwrap_err();
    assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
    assert!(s.message().contains("LSS mode 99"), "{}", s.message());
    let identify = |revision: (u32, u32), serial: (u32, u32)| pb::IdentifyRemoteRequest {
        bus: "can0".into(),
        vendor_id: 1,
        product_code: 2,
        revision_low: revision.0,
        revision_high: revision.1,
        serial_low: serial.0,
        serial_high: serial.1,
        timeout_ms: 0,
    };
    for (req, what) in [
        (
            identify((5, 1), (0, u32::MAX)),
            "revision range is inverted",
        ),
        (identify((0, 1), (9, 2)), "serial number range is inverted"),
    ] {
        let s = lss.identify_remote(req).await.unwrap_err();
        assert_eq!(s.code(), Code::InvalidArgument, "{s:?}");
        assert!(s.message().contains(what), "{}", s.message());
    }
    assert_eq!(
        stats(),
        before,
        "a refused LSS request must not reach the bus"
    );
    // The valid forms still go out.
    lss.switch_global(pb::SwitchGlobalRequest {
        bus: "can0".into(),
        mode: 0,
    })
    .await
    .unwrap();
    tokio::time::timeout(WAIT, async {
        while stats() == before {
            tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("a valid SwitchGlobal goes out");
    server.shutdown();
}
