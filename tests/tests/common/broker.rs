//! What the plant bridge's tests share (`bridge_mqtt.rs`, `bridge_nats.rs`):
//! a broker process each test starts on a free loopback port with a
//! directory of its own, stopped by its PID; and the gateway they bridge.

use std::path::PathBuf;
use std::process::{Child, Command};
use std::time::{Duration, Instant};

/// A broker process: its port, its directory (configuration, store, log;
/// removed at the end) and the running child, killed at the end.
pub struct BrokerProcess {
    pub port: u16,
    pub dir: PathBuf,
    pub child: Option<Child>,
}

impl BrokerProcess {
    /// A free loopback port and an empty directory for the test `name` of
    /// broker `kind`; nothing runs yet.
    pub fn prepare(kind: &str, name: &str) -> BrokerProcess {
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free loopback port")
            .port();
        let dir =
            std::env::temp_dir().join(format!("cangate-{kind}-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("the broker's directory");
        BrokerProcess {
            port,
            dir,
            child: None,
        }
    }

    /// Runs `command` and waits (at most `deadline`) until it listens on
    /// the port; a child that exits first fails the test with `log()`.
    pub fn run(&mut self, mut command: Command, deadline: Duration, log: impl Fn() -> String) {
        let mut child = command.spawn().expect("the broker starts");
        let until = Instant::now() + deadline;
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            if let Ok(Some(status)) = child.try_wait() {
                panic!("the broker exited ({status}): {}", log());
            }
            assert!(
                Instant::now() < until,
                "the broker listens within {deadline:?}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        self.child = Some(child);
    }

    /// Sends `signal` (`-TERM`, `-KILL`) to the broker by its PID and
    /// waits for it to exit.
    pub fn signal(&mut self, signal: &str) {
        if let Some(mut c) = self.child.take() {
            let _ = Command::new("kill")
                .args([signal, &c.id().to_string()])
                .status();
            let _ = c.wait();
        }
    }
}

impl Drop for BrokerProcess {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// One bus with a simulated CANopen node (5), and a bridge to `url`
/// publishing as `gateway`, with `extra` lines in its section.
pub fn bridge_config(url: &str, gateway: &str, extra: &str) -> String {
    format!(
        r#"
[[bus]]
name = "can0"
backend = "virtual"

[[canopen]]
bus = "can0"

[[canopen.node]]
id = 5
eds = "builtin:io"
simulate = true

[[bridge]]
name = "{gateway}"
url = "{url}"
gateway = "{gateway}"
{extra}
"#
    )
}

/// The gateway of `toml` (without `listen`), on a free port.
pub async fn start_gateway(toml: &str) -> cangate_server::RunningServer {
    let text = format!("listen = \"127.0.0.1:0\"\n{toml}");
    let config = cangate_server::Config::from_toml(&text).expect("test configuration is valid");
    cangate_server::start(&config).await.expect("server starts")
}
