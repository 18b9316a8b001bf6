//! The real SocketCAN end-to-end test: the gateway in-process on a kernel
//! `vcan0`, driven by the real gRPC client on one side and by can-utils
//! (`cansend`, `candump`) and `ip link` on the other.
//!
//! Everything else in this crate runs on the in-process virtual bus. This
//! test is the only one that proves the SocketCAN backend against a real
//! kernel: frame conversion both ways (classic, extended, remote, CAN FD with
//! BRS), kernel receive timestamps, clients as bus participants (SendFrames
//! and an Attach stream: their frames reach other processes and the other
//! streams, marked, never twice), and the down/up reconnect logic.
//!
//! # Where it runs
//!
//! Most development hosts and CI containers have no CAN support in their
//! kernel, so the test picks one of three outcomes:
//!
//! 1. `/sys/class/net/vcan0` exists: run the checks right here. This is also
//!    what happens inside the VM below.
//! 2. Otherwise (and not already inside the VM, where `CANGATE_VM=1`):
//!    re-run this very test binary, limited to this test, inside a
//!    throw-away QEMU guest with the vcan driver (the repository's
//!    `scripts/vcan-vm`, or the command prefix in `CANGATE_VCAN_RUNNER`),
//!    stream its output and require exit status 0 and a "1 passed" summary.
//! 3. Neither is possible (no QEMU and we are not allowed to install it, or
//!    the VM itself fails with status 125): print why and pass as skipped -
//!    unless `CI=true`, where the same situation fails the test, so that CI
//!    can never silently stop exercising real SocketCAN.
//!
//! Every wait is bounded, so a regression shows up as a failure with a
//! message, never as a hung test run.

#[path = "common/vcan.rs"]
mod vcan;

use anyhow::{Context, Result, anyhow, bail, ensure};
use cangate_client::can::Frame;
use cangate_client::pb;
use cangate_client::pb::stream_event::Event;
use std::collections::VecDeque;
use std::io::{BufRead, BufReader};

use std::process::{Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};
use tokio::sync::mpsc;

/// Must equal the function name below: the VM re-runs exactly this test.
const TEST_NAME: &str = "socketcan_vcan_end_to_end";
const IFACE: &str = "vcan0";
const BUS: &str = "can0";
/// `CANFD_MTU`: an interface with the classic MTU (16) rejects FD frames.
const CANFD_MTU: u32 = 72;

/// One budget for the whole scenario; the individual waits below are much
/// shorter, this only catches something we forgot to bound.
const SCENARIO_LIMIT: Duration = Duration::from_secs(120);
/// Generous per-event waits: under QEMU's TCG (no KVM) starting a process
/// alone takes ~0.1-0.3 s, and a loaded CI runner can be slower still.
const EVENT_WAIT: Duration = Duration::from_secs(10);
/// The backend notices a down link by polling its flags every 250 ms (the
/// socket's ENETDOWN does not wake a pending read), so 5 s is a lot of slack.
const DOWN_WAIT: Duration = Duration::from_secs(5);
/// Coming back is paced by the reconnect backoff (100 ms doubling, at most
/// 5 s), so allow one full maximum backoff period plus slack.
const UP_WAIT: Duration = Duration::from_secs(12);
#[test]
fn socketcan_vcan_end_to_end() {
    match vcan::plan(IFACE) {
        vcan::Plan::Here => run_here(),
        vcan::Plan::Vm(runner) => vcan::run_in_vm(&runner, TEST_NAME, &[]),
        vcan::Plan::Unavailable(reason) => vcan::skip_or_fail(TEST_NAME, &reason),
    }
}

// ------------------------------------------------------------ the checks

fn run_here() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("tokio runtime");
    let started = Instant::now();
    let result = rt.block_on(async {
        tokio::time::timeout(SCENARIO_LIMIT, scenario())
            .await
            .unwrap_or_else(|_| {
                Err(anyhow!(
                    "the scenario did not finish within {SCENARIO_LIMIT:?}"
                ))
            })
    });
    // Don't let a wedged task keep the process alive after a failure.
    rt.shutdown_timeout(Duration::from_secs(1));
    if let Err(e) = result {
        panic!("{e:?}");
    }
    eprintln!(
        "{TEST_NAME}: all checks passed in {:.2} s",
        started.elapsed().as_secs_f64()
    );
}

async fn scenario() -> Result<()> {
    let t0 = Instant::now();
    let step = |name: &str| eprintln!("[{:>6.2} s] {name}", t0.elapsed().as_secs_f64());
    for tool in ["ip", "cansend", "candump"] {
        if vcan::find_on_path(tool).is_none() {
            bail!("`{tool}` is not on PATH (packages iproute2 and can-utils)");
        }
    }

    // Brought back up on every exit path, so a failed run on a developer's
    // native vcan0 does not leave it down.
    let mut link = LinkGuard { down: false };
    prepare_fd_interface(&mut link).await?;

    step("starting the gateway on vcan0");
    let config = cangate_server::Config::from_toml(&format!(
        "listen = \"127.0.0.1:0\"\n\
         [[bus]]\n\
         name = \"{BUS}\"\n\
         backend = \"socketcan\"\n\
         interface = \"{IFACE}\"\n\
         fd = true\n"
    ))
    .map_err(|e| anyhow!("{e}"))?;
    let server = cangate_server::start(&config).await?;
    let mut client = tokio::time::timeout(
        EVENT_WAIT,
        cangate_client::connect(&format!("http://{}", server.addr)),
    )
    .await
    .context("connecting timed out")??;

    let info = client.get_bus(BUS).await?;
    ensure!(info.fd, "the bus should be configured for CAN FD: {info:?}");
    ensure!(
        info.backend == pb::BackendKind::Socketcan as i32 && info.interface == IFACE,
        "unexpected bus description: {info:?}"
    );
    ensure!(
        info.status.as_ref().map(|s| s.state) == Some(pb::BusState::Up as i32),
        "an up vcan0 should be reported UP: {info:?}"
    );

    // Received frames only: the gateway's own transmissions must not come
    // back as RX (the kernel does not loop them back to the sending socket;
    // if it ever did, the stream would show every sent frame twice).
    let mut rx = Events::open(&mut client, "rx", stream_request(vec![], false)).await?;
    // Transmitted frames too, filtered to id 0x123, to see the TX direction.
    let tx_filter = pb::FrameFilter {
        id: 0x123,
        mask: 0x7FF,
        format: pb::IdFormat::Standard as i32,
        invert: false,
    };
    let mut txs = Events::open(&mut client, "tx", stream_request(vec![tx_filter], true)).await?;

    // (a) A frame from another process on the bus reaches a gRPC stream.
    step("(a) cansend -> gRPC stream");
    cansend("123#DEADBEEF").await?;
    let f = rx
        .frame("123#DEADBEEF from cansend", |f| f.id == 0x123)
        .await?;
    ensure!(
        f.data == [0xDE, 0xAD, 0xBE, 0xEF] && !f.extended && !f.fd && !f.remote && !f.error,
        "wrong frame: {f:?}"
    );
    ensure!(
        f.direction == pb::Direction::Rx as i32,
        "should be RX: {f:?}"
    );
    check_timestamp(&f)?;

    // (b) Frames sent over gRPC reach another process on the bus. candump is
    // started first; a real process needs an unknown time to bind its
    // socket (long under TCG), so instead of sleeping we send a marker frame
    // until candump prints it.
    step("(b) gRPC send -> candump (classic, extended, remote)");
    let mut dump = Candump::spawn()?;
    dump.wait_ready(&mut client, &mut rx).await?;
    let classic: Vec<Frame> = ["123#CAFE", "1F334455#0102", "123#R4", "7FF#"]
        .iter()
        .map(|s| s.parse().expect("valid frame text"))
        .collect();
    rx.sent.extend(classic.iter().map(Frame::to_string));
    let sent = client.send(BUS, &classic).await?;
    ensure!(
        sent == classic.len() as u32,
        "sent {sent} of {}",
        classic.len()
    );
    dump.expect_in_order(&classic).await?;

    // The gateway delivers our 0x123 frames to its streams as a client's
    // (received, marked with their sender; the extended 0x1F334455 and the
    // 0x7FF frames are filtered out), with a nonzero time: loopback done by
    // the gateway, not by the kernel.
    let f = txs
        .frame("our 123#CAFE as a client's", |f| {
            f.origin == pb::FrameOrigin::Client as i32
        })
        .await?;
    ensure!(
        key_pb(&f) == "123#CAFE" && f.sender.is_some(),
        "first client frame should be 123#CAFE with its sender: {f:?}"
    );
    ensure!(f.timestamp_ns > 0, "client frame without timestamp: {f:?}");
    let f = txs
        .frame("our 123#R4 as a client's", |f| {
            f.origin == pb::FrameOrigin::Client as i32
        })
        .await?;
    ensure!(
        key_pb(&f) == "123#R4",
        "second client frame should be 123#R4: {f:?}"
    );

    // (c) CAN FD both ways: 12 bytes with BRS, and a full 64-byte frame
    // without BRS on an extended id (the largest thing vcan carries).
    step("(c) CAN FD: gRPC -> candump, cansend -> gRPC stream");
    let fd: Vec<Frame> = [
        "123##1112233445566778899AABBCC".to_string(),
        format!("1ABCDEF0##0{}", "A5".repeat(64)),
    ]
    .iter()
    .map(|s| s.parse().expect("valid frame text"))
    .collect();
    rx.sent.extend(fd.iter().map(Frame::to_string));
    client.send(BUS, &fd).await?;
    dump.expect_in_order(&fd).await?;
    drop(dump);

    cansend("456##1000102030405060708090A0B0C0D0E0F").await?;
    let f = rx
        .frame("456##1... from cansend", |f| f.id == 0x456)
        .await?;
    ensure!(
        f.fd && f.brs && !f.esi && !f.extended && f.data == (0u8..16).collect::<Vec<_>>(),
        "wrong FD frame: {f:?}"
    );
    ensure!(
        f.direction == pb::Direction::Rx as i32,
        "should be RX: {f:?}"
    );
    check_timestamp(&f)?;

    // (c2) A client attached as a bus participant: what it sends reaches
    // another process (candump) and the other streams as a client's frame
    // (loopback by the gateway, not by the kernel), its own frame comes back
    // because it asked, and another process's frame reaches it as another
    // node's.
    step("(c2) Attach: attached client -> candump and streams, cansend -> attached client");
    let mut node = client
        .attach(
            BUS,
            &cangate_client::AttachOptions {
                filters: vec!["2A0:7F0".parse().expect("valid filter")],
                receive_own: true,
                fd: true,
                ..Default::default()
            },
        )
        .await?;
    let mut dump = Candump::spawn()?;
    dump.wait_ready(&mut client, &mut rx).await?;
    let mine: Frame = "2A5#A77AC4ED".parse().expect("valid frame text");
    rx.sent.push(mine.to_string());
    node.sender.send(&[mine]).await?;
    dump.expect_in_order(&[mine]).await?;
    drop(dump);
    let f = rx
        .frame("the attached client's 2A5#A77AC4ED", |f| f.id == 0x2A5)
        .await?;
    ensure!(
        f.origin == pb::FrameOrigin::Client as i32
            && f.sender.as_ref().map(|s| s.id) == Some(node.sender_id),
        "should be the attached client's frame: {f:?}"
    );
    let (own, _) = attached_frame(&mut node, |f| f.raw_id() == 0x2A5).await?;
    ensure!(own, "its own frame should come back as its own");
    cansend("2A6#0102").await?;
    let (own, origin) = attached_frame(&mut node, |f| f.raw_id() == 0x2A6).await?;
    ensure!(
        !own && origin == pb::FrameOrigin::Bus,
        "another process's frame should be another node's: {origin:?}"
    );
    drop(node);

    // (d) The interface goes away under the gateway and comes back.
    step("(d) ip link set vcan0 down");
    let down_at = Instant::now();
    link.set(false).await?;
    let st = rx.state(pb::BusState::Down, DOWN_WAIT).await?;
    step(&format!(
        "    stream reported DOWN after {:.0} ms",
        down_at.elapsed().as_secs_f64() * 1e3
    ));
    ensure!(st.since_ns > 0, "state change without a time: {st:?}");
    wait_bus_state(&mut client, pb::BusState::Down, DOWN_WAIT).await?;
    let frame: Frame = "123#01".parse().expect("valid frame text");
    match client.send(BUS, &[frame]).await {
        Err(e) if e.code() == Some(tonic::Code::FailedPrecondition) => {}
        other => bail!("sending on a down bus should fail with FAILED_PRECONDITION, got {other:?}"),
    }

    step("(d) ip link set vcan0 up");
    let up_at = Instant::now();
    link.set(true).await?;
    rx.state(pb::BusState::Up, UP_WAIT).await?;
    step(&format!(
        "    stream reported UP after {:.0} ms",
        up_at.elapsed().as_secs_f64() * 1e3
    ));
    wait_bus_state(&mut client, pb::BusState::Up, EVENT_WAIT).await?;
    // The reconnected socket really receives and sends again.
    cansend("321#0BAD").await?;
    let f = rx
        .frame("321#0BAD after the reconnect", |f| f.id == 0x321)
        .await?;
    ensure!(
        key_pb(&f) == "321#0BAD",
        "wrong frame after reconnect: {f:?}"
    );
    check_timestamp(&f)?;
    let good: Frame = "123#600D".parse().expect("valid frame text");
    rx.sent.push(good.to_string());
    client.send(BUS, &[good]).await?;
    let f = txs
        .frame("123#600D as a client's after the reconnect", |f| {
            key_pb(f) == "123#600D"
        })
        .await?;
    ensure!(
        f.direction == pb::Direction::Rx as i32 && f.origin == pb::FrameOrigin::Client as i32,
        "should be a client's frame, received: {f:?}"
    );

    // (e) A clean shutdown ends the open streams and stops everything
    // within the limit, even with the client still connected.
    step("(e) shutdown");
    server.shutdown();
    rx.expect_end().await?;
    txs.expect_end().await?;
    server
        .wait(Duration::from_secs(5))
        .await
        .map_err(|e| anyhow!("shutdown: {e}"))?;
    drop(client);
    step("done");
    Ok(())
}

/// The frame in cansend syntax, our comparison key (ignores timestamp and
/// direction; FD flags normalised to BRS/ESI).
fn key_pb(f: &pb::Frame) -> String {
    cangate_client::frame_from_pb(f).map_or_else(|| format!("{f:?}"), |f| f.to_string())
}

fn check_timestamp(f: &pb::Frame) -> Result<()> {
    // The backend stamps frames with the kernel's receive time
    // (SO_TIMESTAMPNS, wall clock). A zero would mean the stamp was lost; a
    // stamp far from now would mean a wrong clock or unit.
    let now = SystemTime::now().duration_since(UNIX_EPOCH)?.as_nanos() as u64;
    ensure!(f.timestamp_ns > 0, "frame without timestamp: {f:?}");
    ensure!(
        f.timestamp_ns.abs_diff(now) < 60_000_000_000,
        "timestamp {} is not within a minute of now ({now}): {f:?}",
        f.timestamp_ns
    );
    Ok(())
}

fn stream_request(
    filters: Vec<pb::FrameFilter>,
    include_transmitted: bool,
) -> pb::StreamFramesRequest {
    pb::StreamFramesRequest {
        bus: BUS.to_string(),
        filters,
        include_transmitted,
        include_error_frames: false,
        max_batch: 0,
        queue_length: 0,
        low_latency: false,
    }
}

async fn wait_bus_state(
    client: &mut cangate_client::Client,
    want: pb::BusState,
    limit: Duration,
) -> Result<()> {
    let deadline = Instant::now() + limit;
    loop {
        let info = client.get_bus(BUS).await?;
        let state = info.status.as_ref().map(|s| s.state);
        if state == Some(want as i32) {
            return Ok(());
        }
        if Instant::now() > deadline {
            bail!("GetBus still reports {state:?} after {limit:?}, expected {want:?}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

// ------------------------------------------------------------ gRPC stream

/// A StreamFrames stream flattened into single events, with bounded waits.
struct Events {
    name: &'static str,
    stream: tonic::Streaming<pb::StreamFramesResponse>,
    queue: VecDeque<pb::StreamEvent>,
    /// Frames the gateway sent (cansend syntax): seeing one of them as RX
    /// means the gateway's own transmissions are echoed back.
    sent: Vec<String>,
}

impl Events {
    async fn open(
        client: &mut cangate_client::Client,
        name: &'static str,
        req: pb::StreamFramesRequest,
    ) -> Result<Events> {
        let stream = tokio::time::timeout(EVENT_WAIT, client.stream_frames(req))
            .await
            .with_context(|| format!("opening stream {name} timed out"))??;
        let mut ev = Events {
            name,
            stream,
            queue: VecDeque::new(),
            sent: Vec::new(),
        };
        // The first event is the current state. Once it has arrived the
        // subscription is registered, so nothing sent from now on can be
        // missed by this stream.
        match ev.next(Instant::now() + EVENT_WAIT).await? {
            Event::State(s) if s.state == pb::BusState::Up as i32 => Ok(ev),
            other => bail!("stream {name}: first event should be state UP, got {other:?}"),
        }
    }

    async fn next(&mut self, deadline: Instant) -> Result<Event> {
        loop {
            if let Some(ev) = self.queue.pop_front() {
                return ev
                    .event
                    .ok_or_else(|| anyhow!("stream {}: event without content", self.name));
            }
            let msg = tokio::time::timeout_at(deadline.into(), self.stream.message())
                .await
                .map_err(|_| anyhow!("stream {}: nothing arrived in time", self.name))?
                .with_context(|| format!("stream {} failed", self.name))?;
            match msg {
                Some(m) => self.queue.extend(m.events),
                None => bail!("stream {} ended unexpectedly", self.name),
            }
        }
    }

    /// The next frame matching `pred`. Other frames and state changes are
    /// skipped (a native vcan0 may carry foreign traffic) but reported; our
    /// own transmissions seen as another node's (the kernel's loopback to
    /// the gateway's own socket) and lost-frame notices are errors.
    async fn frame(&mut self, what: &str, pred: impl Fn(&pb::Frame) -> bool) -> Result<pb::Frame> {
        let deadline = Instant::now() + EVENT_WAIT;
        loop {
            let ev = self
                .next(deadline)
                .await
                .with_context(|| format!("waiting for {what}"))?;
            match ev {
                Event::Frame(f) if pred(&f) => return Ok(f),
                Event::Frame(f) => {
                    let key = key_pb(&f);
                    if f.origin == pb::FrameOrigin::Bus as i32 && self.sent.contains(&key) {
                        bail!(
                            "stream {}: the gateway's own frame {key} came back as RX \
                             (while waiting for {what})",
                            self.name
                        );
                    }
                    eprintln!(
                        "stream {}: skipping {key} while waiting for {what}",
                        self.name
                    );
                }
                // Streams opened before a down/up cycle carry its state
                // changes too; the checks for those read them explicitly.
                Event::State(s) => eprintln!("stream {}: passing state {s:?}", self.name),
                Event::Lost(l) => bail!(
                    "stream {}: lost frames {l:?} while waiting for {what}",
                    self.name
                ),
            }
        }
    }

    /// Waits for a state event; frames in between are fine.
    async fn state(&mut self, want: pb::BusState, limit: Duration) -> Result<pb::BusStatus> {
        let deadline = Instant::now() + limit;
        loop {
            match self.next(deadline).await.with_context(|| {
                format!(
                    "stream {}: no {want:?} state event within {limit:?}",
                    self.name
                )
            })? {
                Event::State(s) if s.state == want as i32 => return Ok(s),
                Event::State(s) => eprintln!("stream {}: passing state {s:?}", self.name),
                Event::Frame(f) => eprintln!("stream {}: skipping {}", self.name, key_pb(&f)),
                Event::Lost(l) => bail!("stream {}: lost frames {l:?}", self.name),
            }
        }
    }

    /// After shutdown: the stream must end (cleanly or with a status), not
    /// stay open.
    async fn expect_end(&mut self) -> Result<()> {
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            match tokio::time::timeout_at(deadline.into(), self.stream.message()).await {
                Err(_) => bail!("stream {} still open 5 s after shutdown", self.name),
                Ok(Ok(Some(_))) => continue, // events still in flight
                Ok(Ok(None)) => return Ok(()),
                Ok(Err(status)) => {
                    eprintln!("stream {} ended with {status:?}", self.name);
                    return Ok(());
                }
            }
        }
    }
}

// ------------------------------------------------------------ candump

/// A running `candump -L vcan0` whose lines arrive on a channel. Killed on
/// drop.
struct Candump {
    child: std::process::Child,
    lines: mpsc::UnboundedReceiver<String>,
}

/// Sent until candump shows it; the RX stream ignores it.
const MARKER: &str = "7FF#5EED";

impl Candump {
    fn spawn() -> Result<Candump> {
        let mut child = Command::new("candump")
            .args(["-L", IFACE])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .context("starting candump")?;
        let out = child.stdout.take().expect("piped stdout");
        let (tx, lines) = mpsc::unbounded_channel();
        // A plain thread: blocking reads, ends at EOF when candump dies.
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Ok(Candump { child, lines })
    }

    /// The next frame candump printed, as cansend text (normalised through
    /// our parser: candump -L writes `(time) vcan0 123##5AABB`, and the FD
    /// flag nibble includes the kernel's CANFD_FDF bit 0x4).
    async fn next(&mut self, deadline: Instant) -> Result<String> {
        let line = tokio::time::timeout_at(deadline.into(), self.lines.recv())
            .await
            .map_err(|_| anyhow!("candump printed nothing in time"))?
            .ok_or_else(|| anyhow!("candump exited"))?;
        let text = line
            .split_whitespace()
            .nth(2)
            .ok_or_else(|| anyhow!("unexpected candump line {line:?}"))?;
        let frame: Frame = text
            .parse()
            .map_err(|e| anyhow!("candump line {line:?}: {e}"))?;
        Ok(frame.to_string())
    }

    async fn wait_ready(
        &mut self,
        client: &mut cangate_client::Client,
        rx: &mut Events,
    ) -> Result<()> {
        let marker: Frame = MARKER.parse().expect("valid frame text");
        rx.sent.push(marker.to_string());
        let deadline = Instant::now() + EVENT_WAIT;
        while Instant::now() < deadline {
            client.send(BUS, &[marker]).await?;
            let wait = (Instant::now() + Duration::from_millis(300)).min(deadline);
            loop {
                match self.next(wait).await {
                    Ok(k) if k == MARKER => return Ok(()),
                    Ok(k) => eprintln!("candump: skipping {k} while waiting for the marker"),
                    Err(_) => break, // not listening yet: send again
                }
            }
        }
        bail!("candump did not show our marker frame within {EVENT_WAIT:?}")
    }

    /// candump shows exactly these frames, in this order (skipping late
    /// marker copies and foreign traffic in between).
    async fn expect_in_order(&mut self, frames: &[Frame]) -> Result<()> {
        let deadline = Instant::now() + EVENT_WAIT;
        for want in frames.iter().map(Frame::to_string) {
            loop {
                let got = self
                    .next(deadline)
                    .await
                    .with_context(|| format!("candump never showed {want}"))?;
                if got == want {
                    break;
                }
                if frames.iter().any(|f| f.to_string() == got) {
                    bail!("candump showed {got} out of order, expected {want} first");
                }
                eprintln!("candump: skipping {got} while waiting for {want}");
            }
        }
        Ok(())
    }
}

impl Drop for Candump {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

// ------------------------------------------------------------ subprocesses

/// Runs a short command off the async workers, with a time limit.
async fn run(program: &str, args: &[&str]) -> Result<std::process::Output> {
    let mut cmd = Command::new(program);
    cmd.args(args).stdin(Stdio::null());
    let shown = format!("{program} {}", args.join(" "));
    let job = tokio::task::spawn_blocking(move || cmd.output());
    tokio::time::timeout(EVENT_WAIT, job)
        .await
        .with_context(|| format!("`{shown}` did not finish in time"))?
        .context("joining a subprocess")?
        .with_context(|| format!("cannot run `{shown}`"))
}

async fn run_ok(program: &str, args: &[&str]) -> Result<()> {
    let out = run(program, args).await?;
    ensure!(
        out.status.success(),
        "`{program} {}` failed ({}): {}",
        args.join(" "),
        out.status,
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}

/// The next frame of an attachment that matches `pred`: whether it is the
/// client's own, and its origin. Other frames are skipped; losses and
/// refusals are errors.
async fn attached_frame(
    node: &mut cangate_client::Attachment,
    pred: impl Fn(&Frame) -> bool,
) -> Result<(bool, pb::FrameOrigin)> {
    use futures::StreamExt;
    let deadline = Instant::now() + EVENT_WAIT;
    loop {
        let ev = tokio::time::timeout_at(deadline.into(), node.events.next())
            .await
            .map_err(|_| anyhow!("the attached client got nothing in time"))?
            .ok_or_else(|| anyhow!("the attachment ended"))??;
        match ev {
            cangate_client::AttachEvent::Frame {
                frame, own, origin, ..
            } if pred(&frame) => return Ok((own, origin)),
            cangate_client::AttachEvent::Frame { .. } | cangate_client::AttachEvent::State(_) => {}
            other => bail!("the attached client got {other:?}"),
        }
    }
}

async fn cansend(frame: &str) -> Result<()> {
    run_ok("cansend", &[IFACE, frame]).await
}

/// `ip link ...` as root (in the VM we are root; on a native host without
/// root, passwordless sudo is the only non-interactive way).
async fn ip_link(args: &[&str]) -> Result<()> {
    let mut full = vec!["link"];
    full.extend_from_slice(args);
    let direct = run("ip", &full).await?;
    if direct.status.success() {
        return Ok(());
    }
    let mut sudo = vec!["-n", "ip"];
    sudo.extend_from_slice(&full);
    run_ok("sudo", &sudo).await.with_context(|| {
        format!(
            "`ip {}` failed ({}) and sudo -n did not help; this test needs root or passwordless sudo",
            full.join(" "),
            String::from_utf8_lossy(&direct.stderr).trim()
        )
    })
}

fn read_sys(attr: &str) -> Result<String> {
    let path = format!("/sys/class/net/{IFACE}/{attr}");
    Ok(std::fs::read_to_string(&path)
        .with_context(|| format!("reading {path}"))?
        .trim()
        .to_string())
}

/// Makes sure vcan0 carries CAN FD frames (MTU 72) and is up, before the
/// gateway opens it. Debian's vcan already starts with MTU 72, other kernels
/// or a hand-made `ip link add vcan0 type vcan` may give 16; the MTU can
/// only change while the link is down.
async fn prepare_fd_interface(link: &mut LinkGuard) -> Result<()> {
    let mtu: u32 = read_sys("mtu")?.parse().context("parsing the MTU")?;
    if mtu != CANFD_MTU {
        eprintln!("{IFACE} has MTU {mtu}; switching it to {CANFD_MTU} for CAN FD");
        link.set(false).await?;
        ip_link(&["set", IFACE, "mtu", &CANFD_MTU.to_string()]).await?;
    }
    link.set(true).await?;
    let mtu = read_sys("mtu")?;
    ensure!(mtu == CANFD_MTU.to_string(), "{IFACE} still has MTU {mtu}");
    Ok(())
}

/// Tracks whether we took vcan0 down, and brings it back up on drop (a
/// failing run on a native vcan0 must not leave the developer's interface
/// down).
struct LinkGuard {
    down: bool,
}

impl LinkGuard {
    async fn set(&mut self, up: bool) -> Result<()> {
        ip_link(&["set", IFACE, if up { "up" } else { "down" }]).await?;
        self.down = !up;
        Ok(())
    }
}

impl Drop for LinkGuard {
    fn drop(&mut self) {
        if self.down {
            let ok = Command::new("ip")
                .args(["link", "set", IFACE, "up"])
                .status()
                .is_ok_and(|s| s.success());
            if !ok {
                let _ = Command::new("sudo")
                    .args(["-n", "ip", "link", "set", IFACE, "up"])
                    .status();
            }
        }
    }
}
