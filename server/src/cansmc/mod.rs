//! The CANsmc masters at run time: one dedicated cycle thread per master
//! ([`cycle_thread`]) runs the sans-IO [`cangate_cansmc::master::Master`]
//! on its two buses, the axes its slaves back
//! ([`cangate_axis::cansmc::CansmcAxis`]) and the cycle-time statistics;
//! [`CansmcMaster`] is the handle the gRPC `Cansmc` service and the axis
//! layer use.

pub mod cycle_thread;
pub mod jitter;

pub use crate::axis_runner::AxisPort;
use crate::not_found::NotFound;
use cangate_can::BusHandle;
use cangate_cansmc::SmcAddress;
use cangate_cansmc::master::{MasterCounters, Phase, SlaveCounters, SlaveState};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{broadcast, oneshot};
use tokio_util::sync::CancellationToken;

pub use crate::config::CansmcConfig;
pub use jitter::JitterStats;

/// What a slave looks like from outside.
#[derive(Debug, Clone, PartialEq)]
pub struct SlaveView {
    /// Address.
    pub address: u8,
    /// Configured name.
    pub name: String,
    /// Whether the master needs it to start.
    pub required: bool,
    /// State.
    pub state: SlaveState,
    /// From its DCT.
    pub device_type: Option<u16>,
    /// From its DCT.
    pub firmware_version: Option<u16>,
    /// Raw DTSW of its latest valid DT.
    pub status_word: Option<u16>,
    /// Counters.
    pub counters: SlaveCounters,
    /// Consecutive misses now.
    pub consecutive_misses: u32,
    /// The axis it backs.
    pub axis: Option<String>,
}

/// The state of one master, published by its cycle thread.
#[derive(Debug, Clone, PartialEq)]
pub struct CansmcStatus {
    /// Phase.
    pub phase: Phase,
    /// Latest cycle number of P2.
    pub cycle: u64,
    /// Master counters.
    pub counters: MasterCounters,
    /// Slaves in address order.
    pub slaves: Vec<SlaveView>,
    /// MST start-time jitter since P2 began.
    pub jitter: JitterStats,
    /// Why the latest start failed, if it did.
    pub start_error: Option<String>,
    /// Times the master went through P0 (1 + restarts).
    pub starts: u64,
}

/// Something that happened on a master, for logs and streams.
#[derive(Debug, Clone, PartialEq)]
pub enum CansmcEvent {
    /// Phase change.
    Phase(Phase),
    /// For people (slave connected, missing, lost, recovered, rejects).
    Slave {
        /// Address.
        address: u8,
        /// What.
        what: String,
    },
}

pub(crate) enum Request {
    Parameter {
        address: SmcAddress,
        number: u16,
        write: Option<i32>,
        reply: oneshot::Sender<Result<i32, CansmcError>>,
    },
    Restart {
        reply: oneshot::Sender<()>,
    },
}

struct Inner {
    config: CansmcConfig,
    bitrate: u32,
    requests: std::sync::mpsc::Sender<Request>,
    status: Arc<Mutex<CansmcStatus>>,
    events: broadcast::Sender<CansmcEvent>,
    /// Whether the cycle thread still runs.
    running: Arc<AtomicBool>,
}

/// A running CANsmc master. Cheap to clone.
#[derive(Clone)]
pub struct CansmcMaster {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for CansmcMaster {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CansmcMaster")
            .field("name", &self.inner.config.name)
            .finish()
    }
}

impl CansmcMaster {
    /// Starts the cycle thread of `config` on its two buses.
    pub fn start(
        config: &CansmcConfig,
        bitrate: u32,
        command_bus: BusHandle,
        status_bus: BusHandle,
        axes: Option<AxisPort>,
        cancel: CancellationToken,
    ) -> Result<(CansmcMaster, std::thread::JoinHandle<()>), String> {
        let (requests, rx) = std::sync::mpsc::channel();
        let (events, _) = broadcast::channel(1024);
        let status = Arc::new(Mutex::new(CansmcStatus {
            phase: Phase::Idle,
            cycle: 0,
            counters: MasterCounters::default(),
            slaves: Vec::new(),
            jitter: JitterStats::default(),
            start_error: None,
            starts: 0,
        }));
        let running = Arc::new(AtomicBool::new(true));
        let thread = cycle_thread::spawn(cycle_thread::Setup {
            config: config.clone(),
            bitrate,
            command_bus,
            status_bus,
            requests: rx,
            axes,
            status: status.clone(),
            events: events.clone(),
            cancel,
            running: running.clone(),
        })?;
        Ok((
            CansmcMaster {
                inner: Arc::new(Inner {
                    config: config.clone(),
                    bitrate,
                    requests,
                    status,
                    events,
                    running,
                }),
            },
            thread,
        ))
    }

    /// Whether the master's cycle thread still runs: false once it has
    /// ended (after the shutdown token fired), its last frames submitted
    /// and its last status published.
    pub fn cycle_thread_running(&self) -> bool {
        self.inner.running.load(Ordering::Acquire)
    }

    /// The master's name.
    pub fn name(&self) -> &str {
        &self.inner.config.name
    }

    /// Its configuration.
    pub fn config(&self) -> &CansmcConfig {
        &self.inner.config
    }

    /// The bit rate of its channels.
    pub fn bitrate(&self) -> u32 {
        self.inner.bitrate
    }

    /// The latest published state.
    pub fn status(&self) -> CansmcStatus {
        self.inner.status.lock().expect("status lock").clone()
    }

    /// Subscribes to the master's events.
    pub fn events(&self) -> broadcast::Receiver<CansmcEvent> {
        self.inner.events.subscribe()
    }

    /// `a`, when it is one of this master's slaves.
    fn configured(&self, a: SmcAddress) -> Result<SmcAddress, CansmcError> {
        if !self
            .inner
            .config
            .slaves
            .iter()
            .any(|s| s.address == a.get())
        {
            let slaves: Vec<String> = (self.inner.config.slaves.iter())
                .map(|s| s.address.to_string())
                .collect();
            return Err(CansmcError::NotFound(NotFound {
                kind: "CANsmc slave",
                name: a.get().to_string(),
                hint: format!(" on master {} (slaves: {})", self.name(), slaves.join(", ")),
            }));
        }
        Ok(a)
    }

    /// Reads (`write` = None) or writes a parameter of a slave; bounded by
    /// the configured parameter timeout plus a cycle.
    pub async fn parameter(
        &self,
        address: SmcAddress,
        number: u16,
        write: Option<i32>,
    ) -> Result<i32, CansmcError> {
        let address = self.configured(address)?;
        let (reply, rx) = oneshot::channel();
        self.inner
            .requests
            .send(Request::Parameter {
                address,
                number,
                write,
                reply,
            })
            .map_err(|_| CansmcError::ShuttingDown)?;
        let bound = Duration::from_millis(self.inner.config.parameter_timeout_ms)
            + self.inner.config.cycle_time() * 4
            + Duration::from_millis(500);
        match tokio::time::timeout(bound, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(CansmcError::ShuttingDown),
            Err(_) => Err(CansmcError::NoAnswer(format!(
                "master {}: the cycle thread did not answer within {} ms",
                self.name(),
                bound.as_millis()
            ))),
        }
    }

    /// Goes back through P0 and P1; returns when the restart began.
    pub async fn restart(&self) -> Result<(), CansmcError> {
        let (reply, rx) = oneshot::channel();
        self.inner
            .requests
            .send(Request::Restart { reply })
            .map_err(|_| CansmcError::ShuttingDown)?;
        tokio::time::timeout(Duration::from_secs(2), rx)
            .await
            .map_err(|_| CansmcError::NoAnswer("the cycle thread did not answer".into()))?
            .map_err(|_| CansmcError::ShuttingDown)
    }
}

/// Why a CANsmc request failed, by reason.
#[derive(Debug, thiserror::Error)]
pub enum CansmcError {
    /// No such slave on this master.
    #[error(transparent)]
    NotFound(#[from] NotFound),
    /// The parameter service failed: refused, rejected, timed out, the
    /// slave missing or the master not running.
    #[error(transparent)]
    Parameter(#[from] cangate_cansmc::master::ParameterError),
    /// The cycle thread did not answer within the bound.
    #[error("{0}")]
    NoAnswer(String),
    /// The gateway is shutting down.
    #[error("the gateway is shutting down")]
    ShuttingDown,
}
