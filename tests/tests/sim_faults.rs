//! Fault injection end to end: virtual-bus faults from the configuration
//! and through the Simulator service (drop by identifier and probability,
//! delay, bus-off), and device faults (power cycle, EMCY, drive fault, I/O
//! inputs), each seen the way the gateway sees a real failure.

use cangate_client::pb;
use cangate_tests::*;
use std::time::{Duration, Instant};
use tonic::Code;

/// A drive (axis X, node 1) and the I/O node (node 4).
const CONFIG: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 1
eds = "builtin:drive"
simulate = true
heartbeat_timeout_ms = 300

[[canopen.node]]
id = 4
eds = "builtin:io"
simulate = true
heartbeat_timeout_ms = 300
boot = true

[[axis]]
name = "X"
bus = "can0"
node = 1
counts_per_unit = 1000.0
max_velocity = 100.0
max_acceleration = 1000.0
"#;

type Sim = pb::simulator_client::SimulatorClient<cangate_client::Transport>;

async fn setup(config: &str) -> (cangate_server::RunningServer, cangate_client::Client, Sim) {
    let server = start_server(config).await;
    let c = client(&server).await;
    let sim = pb::simulator_client::SimulatorClient::new(c.channel());
    (server, c, sim)
}

/// The next node event matching `f` (bounded).
async fn next_event(
    events: &mut tonic::Streaming<pb::NodeEvent>,
    f: impl Fn(&pb::node_event::Event) -> bool,
) -> pb::NodeEvent {
    let t0 = Instant::now();
    loop {
        let left = WAIT.saturating_sub(t0.elapsed());
        let ev = tokio::time::timeout(left, events.message())
            .await
            .expect("the node event in time")
            .expect("stream ok")
            .expect("stream not ended");
        if ev.event.as_ref().is_some_and(&f) {
            return ev;
        }
    }
}

/// Waits (bounded) until node `node`'s boot procedure completed.
async fn wait_operational(c: &cangate_client::Client, node: u32) {
    let t0 = Instant::now();
    loop {
        let n = get_node(c, node).await;
        if n.state == pb::NmtState::Operational as i32 {
            return;
        }
        assert!(t0.elapsed() < WAIT, "node {node} not operational: {n:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[test]
fn config_keys_are_validated() {
    let bad = |extra: &str, backend: &str| {
        let text = format!("[[bus]]\nname = \"can0\"\nbackend = \"{backend}\"\n{extra}\n");
        cangate_server::Config::from_toml(&text)
            .expect_err(extra)
            .to_string()
    };
    assert!(bad("drop_probability = 1.5", "virtual").contains("not a probability"));
    assert!(bad("drop_ids = [0x40000000]", "virtual").contains("no CAN identifier"));
    assert!(bad("delay_us = 20000000", "virtual").contains("10 s"));
    assert!(bad("drop_ids = [0x701]", "socketcan").contains("virtual buses only"));
    assert!(bad("drop_probabilty = 0.5", "virtual").contains("drop_probabilty"));
    cangate_server::Config::from_toml(
        "[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\ndrop_probability = 0.5\n\
         drop_ids = [0x701]\ndelay_us = 100\nfault_seed = 7\n",
    )
    .expect("valid fault keys");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn configured_drop_by_id_applies_from_start_up() {
    let config = CONFIG.replace(
        "backend = \"virtual\"\n",
        "backend = \"virtual\"\ndrop_ids = [0x704]\n",
    );
    let (_server, c, mut sim) = setup(&config).await;
    let f = sim
        .get_bus_faults(pb::GetBusFaultsRequest { bus: "can0".into() })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(f.drop_ids, [0x704]);
    // Node 4's heartbeat (and boot-up) never reach the gateway: it is never
    // heard of, while node 1 is.
    let t0 = Instant::now();
    loop {
        let f = sim
            .get_bus_faults(pb::GetBusFaultsRequest { bus: "can0".into() })
            .await
            .unwrap()
            .into_inner();
        if f.dropped_by_fault >= 3 {
            break;
        }
        assert!(t0.elapsed() < WAIT, "{f:?}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Node 1 boots and is started; node 4 is never heard of.
    wait_operational(&c, 1).await;
    let n4 = get_node(&c, 4).await;
    assert_eq!(n4.state, pb::NmtState::Unknown as i32, "{n4:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bus_faults_at_run_time_drop_delay_and_bus_off() {
    let (_server, mut c, mut sim) = setup(CONFIG).await;
    wait_operational(&c, 4).await;
    let mut events = node_events(&c, vec![4]).await;
    // Drop node 4's heartbeat: the gateway loses it.
    let f = sim
        .set_bus_faults(pb::SetBusFaultsRequest {
            bus: "can0".into(),
            drop_ids: vec![0x704],
            ..Default::default()
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(f.drop_ids, [0x704]);
    next_event(&mut events, |e| {
        matches!(e, pb::node_event::Event::HeartbeatLost(_))
    })
    .await;
    // Cleared: it comes back.
    sim.set_bus_faults(pb::SetBusFaultsRequest {
        bus: "can0".into(),
        ..Default::default()
    })
    .await
    .unwrap();
    next_event(&mut events, |e| {
        matches!(e, pb::node_event::Event::HeartbeatRecovered(_))
    })
    .await;
    // A delay of 150 ms on every delivery: an SDO round trip takes two.
    sim.set_bus_faults(pb::SetBusFaultsRequest {
        bus: "can0".into(),
        delay_us: 150_000,
        ..Default::default()
    })
    .await
    .unwrap();
    let t0 = Instant::now();
    c.read_sdo(pb::ReadSdoRequest {
        bus: "can0".into(),
        node: 4,
        index: 0x1000,
        subindex: 0,
        r#type: 0,
        options: Some(pb::SdoOptions {
            timeout_ms: 2000,
            block: false,
        }),
        object: String::new(),
    })
    .await
    .expect("SDO read through the delay");
    assert!(
        t0.elapsed() >= Duration::from_millis(290),
        "answered in {:?} despite 2 × 150 ms delay",
        t0.elapsed()
    );
    sim.set_bus_faults(pb::SetBusFaultsRequest {
        bus: "can0".into(),
        ..Default::default()
    })
    .await
    .unwrap();
    // Bus-off: sends fail, the bus reports it; recovered, they work.
    let f = sim
        .set_bus_off(pb::SetBusOffRequest {
            bus: "can0".into(),
            bus_off: true,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(f.bus_off);
    let frame =
        cangate_client::can::Frame::new(cangate_client::can::CanId::standard(0x123).unwrap(), &[1])
            .unwrap();
    assert!(c.send("can0", std::slice::from_ref(&frame)).await.is_err());
    let f = sim
        .set_bus_off(pb::SetBusOffRequest {
            bus: "can0".into(),
            bus_off: false,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(!f.bus_off);
    // The bus task takes the recovery up asynchronously (as a controller
    // needs its recovery sequence): sends work again within a bound.
    let deadline = tokio::time::Instant::now() + cangate_tests::WAIT;
    loop {
        match c.send("can0", std::slice::from_ref(&frame)).await {
            Ok(_) => break,
            Err(_) if tokio::time::Instant::now() < deadline => {
                tokio::time::sleep(std::time::Duration::from_millis(10)).await;
            }
            Err(e) => panic!("not recovered within {:?}: {e}", cangate_tests::WAIT),
        }
    }
    // Refusals say why.
    let e = sim
        .set_bus_faults(pb::SetBusFaultsRequest {
            bus: "can0".into(),
            drop_probability: 1.5,
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    let e = sim
        .get_bus_faults(pb::GetBusFaultsRequest { bus: "nope".into() })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");
    assert!(e.message().contains("can0"), "{e:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn device_faults_power_cycle_emcy_drive_fault_and_inputs() {
    let (_server, c, mut sim) = setup(CONFIG).await;
    wait_operational(&c, 4).await;
    let list = sim
        .list_simulated_devices(pb::ListSimulatedDevicesRequest {})
        .await
        .unwrap()
        .into_inner()
        .devices;
    let kinds: Vec<(u32, i32)> = list.iter().map(|d| (d.node, d.kind)).collect();
    assert_eq!(
        kinds,
        [
            (1, pb::SimulatedDeviceKind::Drive as i32),
            (4, pb::SimulatedDeviceKind::Node as i32)
        ]
    );
    let mut events = node_events(&c, vec![1, 4]).await;

    // EMCY from the I/O node.
    sim.send_emcy(pb::SendEmcyRequest {
        bus: "can0".into(),
        node: 4,
        code: 0x5000,
        error_register: 0x81,
        manufacturer: vec![1, 2],
    })
    .await
    .unwrap();
    let ev = next_event(&mut events, |e| matches!(e, pb::node_event::Event::Emcy(_))).await;
    let Some(pb::node_event::Event::Emcy(emcy)) = ev.event else {
        unreachable!()
    };
    assert_eq!((ev.node, emcy.code, emcy.register), (4, 0x5000, 0x81));
    assert_eq!(emcy.manufacturer, [1, 2, 0, 0, 0]);

    // Inputs: the I/O node's TPDO carries them.
    let mut pdos = c
        .canopen_client()
        .stream_pdo(pb::StreamPdoRequest {
            bus: "can0".into(),
            nodes: vec![4],
        })
        .await
        .unwrap()
        .into_inner();
    let r = sim
        .set_io_inputs(pb::SetIoInputsRequest {
            bus: "can0".into(),
            node: 4,
            digital: vec![0xA5, 0x01],
            analogue: vec![-1234],
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(r.digital, [0xA5, 0x01]);
    assert_eq!(r.analogue[0], -1234);
    let t0 = Instant::now();
    loop {
        let m = tokio::time::timeout(WAIT, pdos.message())
            .await
            .expect("a TPDO in time")
            .unwrap()
            .unwrap();
        let digital: Vec<_> = m
            .values
            .iter()
            .filter(|v| v.index == 0x6000)
            .map(|v| v.value.clone())
            .collect();
        let carries = |sub: u32, want: u64| {
            m.values.iter().any(|v| {
                v.index == 0x6000
                    && v.subindex == sub
                    && v.value.as_ref().is_some_and(
                        |x| matches!(x.value, Some(pb::value::Value::UintValue(u)) if u == want),
                    )
            })
        };
        if carries(1, 0xA5) && carries(2, 0x01) {
            break;
        }
        assert!(t0.elapsed() < WAIT, "TPDO without the inputs: {digital:?}");
    }

    // A drive fault: the axis reports it with its code.
    sim.raise_drive_fault(pb::RaiseDriveFaultRequest {
        bus: "can0".into(),
        node: 1,
        code: 0x2310,
    })
    .await
    .unwrap();
    let mut axes = c.axes_client();
    let t0 = Instant::now();
    loop {
        let st = axes
            .get_axis(pb::GetAxisRequest { axis: "X".into() })
            .await
            .unwrap()
            .into_inner()
            .status
            .unwrap();
        if st.fault_code == 0x2310 {
            break;
        }
        assert!(t0.elapsed() < WAIT, "{st:?}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    // A power cycle: silent (heartbeat lost), then it boots again.
    let d = sim
        .power_cycle_device(pb::PowerCycleDeviceRequest {
            bus: "can0".into(),
            node: 4,
            off_ms: 600,
        })
        .await
        .unwrap()
        .into_inner();
    assert!(!d.powered);
    assert_eq!(d.nmt_state, "off");
    next_event(&mut events, |e| {
        matches!(e, pb::node_event::Event::HeartbeatLost(_))
    })
    .await;
    let e = sim
        .send_emcy(pb::SendEmcyRequest {
            bus: "can0".into(),
            node: 4,
            code: 0x5000,
            ..Default::default()
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    let ev = next_event(&mut events, |e| {
        matches!(e, pb::node_event::Event::BootUp(_))
    })
    .await;
    assert_eq!(ev.node, 4);
    // The boot procedure starts it again.
    wait_operational(&c, 4).await;

    // What a device cannot do is refused with the reason.
    let e = sim
        .raise_drive_fault(pb::RaiseDriveFaultRequest {
            bus: "can0".into(),
            node: 4,
            code: 0x2310,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    assert!(e.message().contains("drive"), "{e:?}");
    let e = sim
        .set_io_inputs(pb::SetIoInputsRequest {
            bus: "can0".into(),
            node: 1,
            digital: vec![1],
            analogue: vec![],
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    let e = sim
        .set_io_inputs(pb::SetIoInputsRequest {
            bus: "can0".into(),
            node: 4,
            digital: vec![1, 2, 3],
            analogue: vec![],
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    let e = sim
        .power_cycle_device(pb::PowerCycleDeviceRequest {
            bus: "can0".into(),
            node: 9,
            off_ms: 10,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::NotFound, "{e:?}");
    assert!(e.message().contains("can0 node 4"), "{e:?}");
    let e = sim
        .power_cycle_device(pb::PowerCycleDeviceRequest {
            bus: "can0".into(),
            node: 4,
            off_ms: 3_600_000,
        })
        .await
        .unwrap_err();
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
}
