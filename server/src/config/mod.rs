//! Server configuration: a TOML file (or the embedded demo) plus
//! `CANGATE_…` environment overrides, validated before anything starts.
//!
//! Environment variables map onto keys with `__` between levels:
//! `CANGATE_LISTEN=0.0.0.0:50051`, `CANGATE_LOG__FORMAT=json`. The
//! variables the command-line client reads (`CANGATE_SERVER`,
//! `CANGATE_TOKEN`, `CANGATE_CA`, `CANGATE_CERT`, `CANGATE_KEY`) and
//! `CANGATE_CONFIG` are not configuration keys and are ignored here; any
//! other `CANGATE_` variable is ignored with a warning on stderr.
//!
//! One file per section; [`Config::validate`] (in `validate.rs`) holds the
//! checks across sections. This module names nothing else of the server.

use cangate_axis::AxisSpec;
use serde::{Deserialize, Serialize};
use std::collections::{HashMap, HashSet};
use std::net::SocketAddr;

mod axis;
mod bridge;
mod bus;
mod canopen;
mod cansmc;
mod cia309;
mod handwheel;
mod security;
mod socketcand;
mod validate;
mod web;

pub use axis::*;
pub use bridge::*;
pub use bus::*;
pub use canopen::*;
pub use cansmc::*;
pub use cia309::*;
pub use handwheel::*;
pub use security::*;
pub use socketcand::*;
pub use web::*;

/// The embedded demo configuration, used when no configuration file is given.
pub const DEMO_CONFIG: &str = include_str!("../../../deploy/demo.toml");

/// Environment variables that override configuration keys (a trailing `__`
/// stands for every key below that table).
const ENV_KEYS: &[&str] = &[
    "CANGATE_LISTEN",
    "CANGATE_METRICS_LISTEN",
    "CANGATE_SHUTDOWN_TIMEOUT_MS",
    "CANGATE_RT_PRIORITY",
    "CANGATE_GRPC_RT_PRIORITY",
    "CANGATE_HANDOVER_SPIN_US",
    "CANGATE_SECURITY__",
    "CANGATE_SOCKETCAND__",
    "CANGATE_CIA309__",
    "CANGATE_WEB__",
    "CANGATE_LOG__",
];

/// Environment variables with our prefix that belong to the client, not to
/// the server's configuration.
const CLIENT_VARIABLES: &[&str] = &[
    "CANGATE_SERVER",
    "CANGATE_TOKEN",
    "CANGATE_CA",
    "CANGATE_CERT",
    "CANGATE_KEY",
    "CANGATE_CONFIG",
];

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// gRPC listen address.
    #[serde(default = "default_listen")]
    pub listen: SocketAddr,
    /// Prometheus endpoint (`GET /metrics`), e.g. `127.0.0.1:9464`; none
    /// when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metrics_listen: Option<SocketAddr>,
    /// Bound of the motion-safe shutdown on SIGTERM/SIGINT: moving axes get
    /// this long to come to rest before the rest of the gateway closes, ms
    /// (default 5000).
    #[serde(default = "default_shutdown_timeout_ms")]
    pub shutdown_timeout_ms: u64,
    /// `SCHED_FIFO` priority (1..=99) of the gateway's bus thread
    /// (`gateway-bus`: bus owners, CANopen masters, axis tasks) and of the
    /// CANopen SYNC producer threads, so that a frame is handled (and a
    /// SYNC sent) without waiting for other processes' time slices;
    /// 0 (default): the default policy. Its work per frame is bounded.
    /// Needs root or `CAP_SYS_NICE` (else a warning).
    #[serde(default, skip_serializing_if = "is_zero_u8")]
    pub rt_priority: u8,
    /// `SCHED_FIFO` priority (1..=99) of every thread of the gRPC runtime
    /// (streams, handwheel tasks); 0 (default): the default policy. Cuts
    /// the stream latency tail on a busy host, but a saturated gRPC
    /// runtime then starves every other process on its cores, local
    /// clients included: only for a host sized for the stream load.
    #[serde(default, skip_serializing_if = "is_zero_u8")]
    pub grpc_rt_priority: u8,
    /// How long, µs, a caller off the bus thread (a gRPC handler, an
    /// embedding application) polls for its SDO answer before it sleeps,
    /// and the bus thread stays awake after its request, when this bus's
    /// recent answers came that fast (a virtual bus; a real bus answers
    /// slower and nobody spins). Saves two thread wake-ups per request;
    /// 0: always sleep. Default 100, at most 10000.
    #[serde(default = "default_handover_spin_us")]
    pub handover_spin_us: u64,
    /// The socketcand listener (`[socketcand]`); absent: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub socketcand: Option<SocketcandConfig>,
    /// The CiA 309-3 ASCII gateway listener (`[cia309]`); absent: off.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cia309: Option<Cia309Config>,
    /// Browser access: gRPC-Web CORS origins and the dashboard (`[web]`).
    #[serde(default)]
    pub web: WebConfig,
    /// Security settings.
    #[serde(default)]
    pub security: SecurityConfig,
    /// Logging.
    #[serde(default)]
    pub log: LogConfig,
    /// The CAN buses the gateway owns.
    #[serde(default, rename = "bus")]
    pub buses: Vec<BusConfig>,
    /// CANopen masters, one per bus at most.
    #[serde(default, rename = "canopen", skip_serializing_if = "Vec::is_empty")]
    pub canopen: Vec<CanopenConfig>,
    /// Axes (CiA 402 drives on CANopen buses).
    #[serde(default, rename = "axis", skip_serializing_if = "Vec::is_empty")]
    pub axes: Vec<AxisConfig>,
    /// CNC handwheels (CANopen nodes) and their axis bindings.
    #[serde(default, rename = "handwheel", skip_serializing_if = "Vec::is_empty")]
    pub handwheels: Vec<HandwheelConfig>,
    /// CANsmc masters (dual-bus motion control), their slaves and axes.
    #[serde(default, rename = "cansmc", skip_serializing_if = "Vec::is_empty")]
    pub cansmc: Vec<CansmcConfig>,
    /// Publishers of the gateway's streams to message brokers
    /// (`[[bridge]]`, docs/bridge.md).
    #[serde(default, rename = "bridge", skip_serializing_if = "Vec::is_empty")]
    pub bridges: Vec<BridgeConfig>,
}

fn is_zero_u8(v: &u8) -> bool {
    *v == 0
}

fn default_shutdown_timeout_ms() -> u64 {
    5000
}

fn default_handover_spin_us() -> u64 {
    100
}

fn default_listen() -> SocketAddr {
    SocketAddr::from(([127, 0, 0, 1], 50051))
}

/// Log output.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LogConfig {
    /// `human` or `json` (one JSON object per line).
    #[serde(default)]
    pub format: LogFormat,
    /// Filter in `tracing` EnvFilter syntax, e.g. `info,cangate_can=debug`.
    /// `RUST_LOG` overrides it.
    #[serde(default = "default_level")]
    pub level: String,
}

impl Default for LogConfig {
    fn default() -> Self {
        LogConfig {
            format: LogFormat::Human,
            level: default_level(),
        }
    }
}

fn default_level() -> String {
    "info".to_string()
}

/// Log format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Human,
    /// One JSON object per line.
    Json,
}

/// A configuration that cannot be used, by what is wrong with it.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read or parsed (includes unknown keys, with
    /// their name).
    #[error("configuration: {0}")]
    Load(#[from] config::ConfigError),
    /// The gRPC listener is reachable from the network without
    /// authentication, and nobody accepted the risk.
    #[error(
        "configuration: listen = {listen} is reachable from the network without authentication: \
         anyone who reaches it can move the axes. Configure [[security.tokens]] or \
         [[security.clients]], listen on 127.0.0.1 (and tunnel), or accept the risk with \
         [security] insecure = true (env CANGATE_SECURITY__INSECURE=true)"
    )]
    Unauthenticated {
        /// The configured address.
        listen: SocketAddr,
    },
    /// Two sections of one kind have the same name.
    #[error("configuration: {kind} {name:?} is configured twice")]
    Duplicate {
        /// What kind of section ("bus", "axis", …).
        kind: &'static str,
        /// The name.
        name: String,
    },
    /// A section names a bus that is not configured.
    #[error("configuration: {section} names bus {bus:?}, which is not configured")]
    UnknownBus {
        /// Where the name is (`[[canopen]]`, …).
        section: &'static str,
        /// The name.
        bus: String,
    },
    /// A bus, or what uses it, is configured wrongly.
    #[error("configuration: bus {bus:?}: {problem}")]
    Bus {
        /// Bus name.
        bus: String,
        /// What is wrong.
        problem: String,
    },
    /// A CANopen node is configured wrongly.
    #[error("configuration: bus {bus:?}: node {node}: {problem}")]
    Node {
        /// Bus name.
        bus: String,
        /// Node-ID as configured.
        node: u32,
        /// What is wrong.
        problem: String,
    },
    /// A top-level value is out of its range.
    #[error("configuration: {key} = {value} must be {range}")]
    OutOfRange {
        /// The key.
        key: &'static str,
        /// Its value.
        value: u64,
        /// What it must be.
        range: &'static str,
    },
    /// A section's own checks failed; the message names the section and
    /// the key.
    #[error("configuration: {message}")]
    Section {
        /// The section.
        section: Section,
        /// What is wrong.
        message: String,
    },
}

/// A kind of configuration section (see [`ConfigError::Section`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Section {
    /// `[security]`.
    Security,
    /// `[web]`.
    Web,
    /// `[[bus]]`.
    Bus,
    /// `[[canopen]]`.
    Canopen,
    /// `[[handwheel]]`.
    Handwheel,
    /// `[[axis]]`.
    Axis,
    /// `[[cansmc]]`.
    Cansmc,
    /// `[socketcand]`.
    Socketcand,
    /// `[cia309]`.
    Cia309,
    /// `[[bridge]]`.
    Bridge,
}

impl Section {
    /// The error of this section's check that failed with `message`.
    pub fn error(self, message: String) -> ConfigError {
        ConfigError::Section {
            section: self,
            message,
        }
    }
}

impl Config {
    /// Loads `path` (or the embedded demo when `None`), applies the
    /// `CANGATE_…` environment, and validates.
    pub fn load(path: Option<&std::path::Path>) -> Result<Config, ConfigError> {
        let mut env = HashMap::new();
        for (k, v) in std::env::vars() {
            if !k.starts_with("CANGATE_") || CLIENT_VARIABLES.contains(&k.as_str()) {
                continue;
            }
            // Only the keys that can be overridden from the environment are
            // taken; other CANGATE_ variables belong to other tools (tests,
            // scripts) and must not break start-up, but a typo is reported.
            if ENV_KEYS
                .iter()
                .any(|p| k == *p || (p.ends_with("__") && k.starts_with(p)))
            {
                env.insert(k, v);
            } else {
                eprintln!(
                    "cangate-server: ignoring environment variable {k}: not a configuration \
                     override (those are {})",
                    ENV_KEYS.join(", ")
                );
            }
        }
        Self::load_with_env(path, env)
    }

    /// Like [`Config::load`] with an explicit environment (for tests).
    pub fn load_with_env(
        path: Option<&std::path::Path>,
        env: HashMap<String, String>,
    ) -> Result<Config, ConfigError> {
        let builder = config::Config::builder();
        let builder = match path {
            Some(p) => builder.add_source(config::File::from(p).format(config::FileFormat::Toml)),
            None => builder.add_source(config::File::from_str(
                DEMO_CONFIG,
                config::FileFormat::Toml,
            )),
        };
        let cfg: Config = builder
            .add_source(
                config::Environment::with_prefix("CANGATE")
                    .prefix_separator("_")
                    .separator("__")
                    .try_parsing(true)
                    .source(Some(env)),
            )
            .build()?
            .try_deserialize()?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Parses TOML text (no environment), and validates.
    pub fn from_toml(text: &str) -> Result<Config, ConfigError> {
        let cfg: Config = config::Config::builder()
            .add_source(config::File::from_str(text, config::FileFormat::Toml))
            .build()?
            .try_deserialize()?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Every axis as the runtime describes it ([`AxisSpec`]): the
    /// `[[axis]]` entries in order, then each `[[cansmc]]` master's axes.
    /// An axis's position here is its index at run time.
    pub fn axis_specs(&self) -> Result<Vec<AxisSpec>, String> {
        let cia402 = self.axes.iter().map(AxisSpec::try_from);
        let cansmc = (self.cansmc.iter()).flat_map(|m| m.axes.iter().map(move |a| a.spec(m)));
        cia402.chain(cansmc).collect()
    }

    /// The embedded demo.
    pub fn demo() -> Config {
        Self::from_toml(DEMO_CONFIG).expect("the embedded demo configuration is valid")
    }

    /// The effective configuration as TOML (for `--print-config`).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).unwrap_or_else(|e| format!("# cannot render: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demo_is_valid_and_has_the_demo_buses() {
        let c = Config::demo();
        let names: Vec<_> = c.buses.iter().map(|b| b.name.as_str()).collect();
        assert_eq!(names, ["can0", "smc0", "smc1"]);
        let nodes: Vec<_> = c.canopen[0].nodes.iter().map(|n| n.id).collect();
        assert_eq!(nodes, [1, 2, 3, 4, 5, 10, 20]);
        assert_eq!(c.handwheels[0].name, "hw1");
        assert_eq!(c.listen, default_listen());
        let axes: Vec<_> = c.axes.iter().map(|a| (a.name.as_str(), a.node)).collect();
        assert_eq!(axes, [("X", 1), ("Y", 2), ("Z", 4), ("S", 5)]);
        assert_eq!(
            c.axes[3].drive_mode(),
            cangate_axis::DriveMode::CyclicVelocity
        );
        assert_eq!(c.canopen[0].sync_period_us, 10_000);
    }

    const AXIS_BASE: &str = r#"
[[bus]]
name = "can0"
backend = "virtual"
[[canopen]]
bus = "can0"
[[canopen.node]]
id = 1
eds = "builtin:drive"
"#;

    fn axis_err(axis: &str) -> String {
        Config::from_toml(&format!("{AXIS_BASE}[[axis]]\n{axis}"))
            .unwrap_err()
            .to_string()
    }

    #[test]
    fn axis_configuration_mistakes_are_named() {
        let ok = "name = \"X\"\nbus = \"can0\"\nnode = 1\ncounts_per_unit = 1000.0\n\
                  max_velocity = 10.0\nmax_acceleration = 100.0\n";
        Config::from_toml(&format!("{AXIS_BASE}[[axis]]\n{ok}")).unwrap();
        let e = axis_err(&ok.replace("node = 1", "node = 9"));
        assert!(e.contains("node 9 is not configured"), "{e}");
        let e = axis_err(&ok.replace("bus = \"can0\"", "bus = \"can9\""));
        assert!(e.contains("has no [[canopen]] master"), "{e}");
        let e = axis_err(&format!("{ok}position_mode = \"cyclic\"\n"));
        assert!(e.contains("needs a SYNC: set sync_period_us"), "{e}");
        let e = axis_err(&format!("{ok}min_position = 5.0\nmax_position = -5.0\n"));
        assert!(e.contains("must be below max_position"), "{e}");
        let e = axis_err(&format!("{ok}min_position = 5.0\n"));
        assert!(e.contains("give both"), "{e}");
        let e = axis_err(&ok.replace("counts_per_unit = 1000.0", "counts_per_unit = 0.0"));
        assert!(e.contains("counts_per_unit"), "{e}");
        let e = axis_err(&format!("{ok}default_velocity = 20.0\n"));
        assert!(e.contains("exceeds max_velocity"), "{e}");
        // Values no drive or dead-man can honour are refused at start-up.
        let e = axis_err(&format!("{ok}jog_deadman_ms = 4294967295\n"));
        assert!(
            e.contains("jog_deadman_ms = 4294967295 is above the maximum of 10000 ms"),
            "{e}"
        );
        let e = axis_err(&ok.replace("max_acceleration = 100.0", "max_acceleration = 1e308"));
        assert!(
            e.contains("max_acceleration = 1e308") && e.contains("counts/s²"),
            "{e}"
        );
        let e = axis_err(&format!("{ok}homing_timeout_ms = 9223372036854775807\n"));
        assert!(e.contains("homing_timeout_ms"), "{e}");
        // The SDO fallback: profile position only, a sane poll period.
        let sdo = format!("{ok}process_data = \"sdo\"\n");
        Config::from_toml(&format!("{AXIS_BASE}[[axis]]\n{sdo}")).unwrap();
        let e = Config::from_toml(&format!(
            "{}[[axis]]\n{sdo}position_mode = \"cyclic\"\n",
            AXIS_BASE.replace(
                "bus = \"can0\"\n[[canopen.node]]",
                "bus = \"can0\"\nsync_period_us = 1000\n[[canopen.node]]"
            )
        ))
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("process_data = \"sdo\" needs position_mode = \"profile\""),
            "{e}"
        );
        let e = axis_err(&format!("{sdo}sdo_poll_ms = 0\n"));
        assert!(e.contains("sdo_poll_ms must be 1..=10000"), "{e}");
        let e = axis_err(&format!("{ok}process_data = \"rpc\"\n"));
        assert!(e.contains("rpc") && e.contains("process_data"), "{e}");
        let two = format!(
            "{AXIS_BASE}[[axis]]\n{ok}[[axis]]\n{}",
            ok.replace("\"X\"", "\"Y\"")
        );
        let e = Config::from_toml(&two).unwrap_err().to_string();
        assert!(
            e.contains("drive_axis 0 of node 1 on bus \"can0\" already backs axis X"),
            "{e}"
        );
        assert!(e.contains("its own drive_axis"), "{e}");
    }

    /// The axes of a multi-axis drive: each its own drive_axis (0..=7),
    /// one the drive's EDS has.
    #[test]
    fn axes_of_one_drive_node_need_distinct_drive_axes_it_has() {
        let base = AXIS_BASE.replace("builtin:drive", "builtin:drive2");
        let axis = |name: &str, extra: &str| {
            format!(
                "[[axis]]\nname = \"{name}\"\nbus = \"can0\"\nnode = 1\ncounts_per_unit = 1000.0\n\
                 max_velocity = 10.0\nmax_acceleration = 100.0\n{extra}"
            )
        };
        let c = Config::from_toml(&format!(
            "{base}{}{}",
            axis("A", ""),
            axis("B", "drive_axis = 1\n")
        ))
        .unwrap();
        assert_eq!(
            c.axes.iter().map(|a| a.drive_axis).collect::<Vec<_>>(),
            [0, 1]
        );
        let e = Config::from_toml(&format!(
            "{base}{}{}",
            axis("A", "drive_axis = 1\n"),
            axis("B", "drive_axis = 1\n")
        ))
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("axis B: drive_axis 1 of node 1 on bus \"can0\" already backs axis A"),
            "{e}"
        );
        let e = Config::from_toml(&format!("{base}{}", axis("A", "drive_axis = 8\n")))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("drive_axis 8 is more than a drive node has (0..=7"),
            "{e}"
        );
        // The one-axis drive has no second axis.
        let e = Config::from_toml(&format!("{AXIS_BASE}{}", axis("A", "drive_axis = 1\n")))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("node 1's EDS has no such axis (no statusword 0x6841)"),
            "{e}"
        );
    }

    #[test]
    fn the_handover_spin_is_100_us_by_default_can_be_off_and_is_bounded() {
        assert_eq!(Config::from_toml("").unwrap().handover_spin_us, 100);
        let c = Config::from_toml("handover_spin_us = 0\n").unwrap();
        assert_eq!(c.handover_spin_us, 0);
        let e = Config::from_toml("handover_spin_us = 20000\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("handover_spin_us = 20000") && e.contains("10000"),
            "{e}"
        );
    }

    #[test]
    fn real_time_priorities_are_off_by_default_and_bounded() {
        let c = Config::from_toml("").unwrap();
        assert_eq!((c.rt_priority, c.grpc_rt_priority), (0, 0));
        let c = Config::from_toml("rt_priority = 10\ngrpc_rt_priority = 5\n").unwrap();
        assert_eq!((c.rt_priority, c.grpc_rt_priority), (10, 5));
        for key in ["rt_priority", "grpc_rt_priority"] {
            let e = Config::from_toml(&format!("{key} = 100\n"))
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&format!("{key} = 100 must be 0 (off) or 1..=99")),
                "{e}"
            );
        }
    }

    #[test]
    fn receive_coalescing_needs_a_bit_timed_virtual_bus_and_is_bounded() {
        let bus = |extra: &str| {
            format!("[[bus]]\nname = \"can0\"\nbackend = \"virtual\"\nbitrate = 1000000\n{extra}")
        };
        let c = Config::from_toml(&bus("bit_timing = true\nrx_coalesce_us = 500\n")).unwrap();
        assert_eq!(c.buses[0].rx_coalesce_us, 500);
        let e = Config::from_toml(&bus("rx_coalesce_us = 500\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("bit_timing = true only"), "{e}");
        let e = Config::from_toml(&bus("bit_timing = true\nrx_coalesce_us = 20000\n"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("exceeds 10000"), "{e}");
    }

    #[test]
    fn non_loopback_listen_needs_insecure() {
        let e = Config::from_toml("listen = \"0.0.0.0:50051\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("without authentication") && e.contains("insecure = true"),
            "{e}"
        );
        let c =
            Config::from_toml("listen = \"0.0.0.0:50051\"\n[security]\ninsecure = true\n").unwrap();
        assert!(c.security.insecure);
        let env = HashMap::from([
            ("CANGATE_LISTEN".to_string(), "0.0.0.0:1".to_string()),
            ("CANGATE_SECURITY__INSECURE".to_string(), "true".to_string()),
        ]);
        assert!(Config::load_with_env(None, env).is_ok());
        Config::from_toml("listen = \"[::1]:50051\"\n").unwrap();
    }

    #[test]
    fn security_section_shape_and_checks() {
        let hash = crate::security::auth::hash_token("t");
        let text = format!(
            "listen = \"0.0.0.0:50051\"\n[[security.tokens]]\nname = \"hmi-1\"\nrole = \"operator\"\n\
             sha256 = \"{hash}\"\n[security.limits]\nburst = 10\n"
        );
        // Authentication configured: a network address is fine.
        let c = Config::from_toml(&text).unwrap();
        assert_eq!(c.security.tokens[0].role, crate::security::Role::Operator);
        assert_eq!(c.security.limits.burst, 10);
        assert_eq!(c.security.limits.requests_per_second_per_client, 200);
        assert_eq!(Config::from_toml(&c.to_toml()).unwrap(), c);
        let env = HashMap::from([(
            "CANGATE_SECURITY__LIMITS__BURST".to_string(),
            "100".to_string(),
        )]);
        let c = Config::load_with_env(None, env).unwrap();
        assert_eq!(c.security.limits.burst, 100);
        for (bad, why) in [
            (text.replace(&hash, "abc"), "64 hex digits"),
            (text.replace("operator", "admin"), "admin"),
            (
                "[[security.clients]]\nsubject_cn = \"a\"\nrole = \"viewer\"\n".to_string(),
                "client_ca",
            ),
            (
                "[security.tls]\ncert = \"c\"\nkey = \"k\"\nrequire_client_cert = true\n"
                    .to_string(),
                "needs client_ca",
            ),
        ] {
            let e = Config::from_toml(&bad).unwrap_err().to_string();
            assert!(e.contains(why), "{why}: {e}");
        }
    }

    #[test]
    fn unknown_keys_are_named() {
        let err = Config::from_toml("listen = \"127.0.0.1:1\"\nlisen = 3\n").unwrap_err();
        assert!(err.to_string().contains("lisen"), "{err}");
        let err = Config::from_toml("[[bus]]\nname = \"a\"\nbackend = \"virtual\"\nbitrat = 5\n")
            .unwrap_err();
        assert!(err.to_string().contains("bitrat"), "{err}");
    }

    #[test]
    fn duplicate_bus_is_refused() {
        let err = Config::from_toml(
            "[[bus]]\nname = \"a\"\nbackend = \"virtual\"\n[[bus]]\nname = \"a\"\nbackend = \"virtual\"\n",
        )
        .unwrap_err();
        assert!(
            err.to_string().contains("\"a\" is configured twice"),
            "{err}"
        );
    }

    /// A start-up refusal says by its variant what went wrong, not only by
    /// its message.
    #[test]
    fn refusals_are_typed_by_what_went_wrong() {
        let bus = "[[bus]]\nname = \"a\"\nbackend = \"virtual\"\n";
        assert!(matches!(
            Config::from_toml(&format!("{bus}{bus}")),
            Err(ConfigError::Duplicate { kind: "bus", ref name }) if name == "a"
        ));
        assert!(matches!(
            Config::from_toml("listen = \"0.0.0.0:50051\"\n"),
            Err(ConfigError::Unauthenticated { .. })
        ));
        assert!(matches!(
            Config::from_toml("shutdown_timeout_ms = 0\n"),
            Err(ConfigError::OutOfRange {
                key: "shutdown_timeout_ms",
                value: 0,
                ..
            })
        ));
        assert!(matches!(
            Config::from_toml("[[canopen]]\nbus = \"nope\"\n"),
            Err(ConfigError::UnknownBus { ref bus, .. }) if bus == "nope"
        ));
        assert!(matches!(
            Config::from_toml(&format!(
                "{bus}[[canopen]]\nbus = \"a\"\n[[canopen.node]]\nid = 200\n"
            )),
            Err(ConfigError::Node { node: 200, .. })
        ));
        assert!(matches!(
            Config::from_toml(&format!("{bus}[web]\nallowed_origins = [\"*\"]\n")),
            Err(ConfigError::Section {
                section: Section::Web,
                ..
            })
        ));
    }

    #[test]
    fn environment_overrides_and_client_variables_are_ignored() {
        let env = HashMap::from([
            ("CANGATE_LISTEN".to_string(), "127.0.0.1:6000".to_string()),
            ("CANGATE_LOG__FORMAT".to_string(), "json".to_string()),
            ("CANGATE_RT_PRIORITY".to_string(), "20".to_string()),
            ("CANGATE_GRPC_RT_PRIORITY".to_string(), "10".to_string()),
            (
                "CANGATE_SHUTDOWN_TIMEOUT_MS".to_string(),
                "2500".to_string(),
            ),
        ]);
        let c = Config::load_with_env(None, env).unwrap();
        assert_eq!(c.listen.port(), 6000);
        assert_eq!(c.log.format, LogFormat::Json);
        assert_eq!((c.rt_priority, c.grpc_rt_priority), (20, 10));
        assert_eq!(c.shutdown_timeout_ms, 2500);
    }

    #[test]
    fn print_config_round_trips() {
        let c = Config::demo();
        assert_eq!(Config::from_toml(&c.to_toml()).unwrap(), c);
    }
}
