//! `cangate-server`: the gateway process.

use cangate_server::config::{Config, LogFormat};
use clap::Parser;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

/// Exit status when axes were still moving at the end of
/// `shutdown_timeout_ms` and had to be quick-stopped through their
/// controlword (1 is every other failure).
const EXIT_AXES_NOT_AT_REST: u8 = 3;

/// cangate: CAN bus gateway with a gRPC API. Without --config it runs the
/// embedded demo (virtual buses, simulated devices, no hardware).
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Configuration file (TOML). Default: the embedded demo.
    #[arg(long, short, env = "CANGATE_CONFIG")]
    config: Option<PathBuf>,
    /// Listen address, overriding the configuration (e.g. 0.0.0.0:50051).
    #[arg(long)]
    listen: Option<std::net::SocketAddr>,
    /// Print the effective configuration (after environment overrides) and exit.
    #[arg(long)]
    print_config: bool,
}

fn init_logging(config: &Config) {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(&config.log.level));
    // Colours for a person at a terminal only: a log redirected to a file
    // or a journal keeps plain text (and NO_COLOR turns them off anyway).
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr())
        && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty());
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(ansi)
        .with_writer(std::io::stderr);
    match config.log.format {
        LogFormat::Json => builder.json().init(),
        LogFormat::Human => builder.init(),
    }
}

/// SIGINT/SIGTERM listeners. They are installed *before* the server starts
/// (and logs "listening"): a supervisor that sends SIGTERM as soon as it sees
/// that line must get a graceful shutdown, not the default action (death by
/// signal) — CI caught exactly that race.
struct ShutdownSignals {
    #[cfg(unix)]
    term: Option<tokio::signal::unix::Signal>,
    #[cfg(unix)]
    int: Option<tokio::signal::unix::Signal>,
}

impl ShutdownSignals {
    fn install() -> Self {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{SignalKind, signal};
            ShutdownSignals {
                term: signal(SignalKind::terminate()).ok(),
                int: signal(SignalKind::interrupt()).ok(),
            }
        }
        #[cfg(not(unix))]
        ShutdownSignals {}
    }

    async fn wait(mut self) {
        #[cfg(unix)]
        {
            async fn recv(s: &mut Option<tokio::signal::unix::Signal>) {
                match s {
                    Some(s) => {
                        s.recv().await;
                    }
                    None => std::future::pending::<()>().await,
                }
            }
            if self.term.is_none() && self.int.is_none() {
                let _ = tokio::signal::ctrl_c().await;
                return;
            }
            tokio::select! {
                _ = recv(&mut self.term) => {},
                _ = recv(&mut self.int) => {},
            }
        }
        #[cfg(not(unix))]
        let _ = tokio::signal::ctrl_c().await;
    }
}

/// Re-reads the TLS certificate, key and client CA on every SIGHUP; new
/// connections use them, open ones and the buses are untouched. A failed
/// reload keeps the old files' configuration and logs why.
fn spawn_tls_reload_on_sighup(tls: cangate_server::security::TlsReloader) {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let mut hup = match signal(SignalKind::hangup()) {
            Ok(s) => s,
            Err(e) => {
                tracing::error!("cannot listen for SIGHUP (no TLS reload): {e}");
                return;
            }
        };
        tokio::spawn(async move {
            while hup.recv().await.is_some() {
                match tls.reload() {
                    Ok(()) => tracing::info!("SIGHUP: TLS certificate, key and client CA reloaded"),
                    Err(e) => tracing::error!(
                        "SIGHUP: TLS reload failed, keeping the old configuration: {e}"
                    ),
                }
            }
        });
    }
    #[cfg(not(unix))]
    let _ = tls;
}

fn main() -> ExitCode {
    let args = Args::parse();
    let mut config = match Config::load(args.config.as_deref()) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("cangate-server: {e}");
            return ExitCode::from(2);
        }
    };
    if let Some(listen) = args.listen {
        config.listen = listen;
        // The same rules as a configured address (e.g. a network address
        // needs [security] insecure = true).
        if let Err(e) = config.validate() {
            eprintln!("cangate-server: {e}");
            return ExitCode::from(2);
        }
    }
    if args.print_config {
        print!("{}", config.to_toml());
        return ExitCode::SUCCESS;
    }
    init_logging(&config);
    // The gRPC runtime, built here rather than by `#[tokio::main]` so that
    // its threads can get `grpc_rt_priority` as they start.
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .on_thread_start(cangate_server::realtime::on_grpc_thread_start(
            config.grpc_rt_priority,
        ))
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("cangate-server: cannot start the runtime: {e}");
            return ExitCode::from(1);
        }
    };
    runtime.block_on(serve(args.config.is_none(), config))
}

async fn serve(demo: bool, config: Config) -> ExitCode {
    if demo {
        tracing::info!("no --config given: running the embedded demo configuration");
    }
    if config.security.insecure {
        tracing::warn!(
            listen = %config.listen,
            "[security] insecure = true: the gRPC API is open to anyone who can reach {}",
            config.listen
        );
    }
    let signals = ShutdownSignals::install();
    let server = match cangate_server::start(&config).await {
        Ok(s) => s,
        Err(e) => {
            tracing::error!("{e}");
            eprintln!("cangate-server: {e}");
            return ExitCode::from(1);
        }
    };
    if let Some(tls) = server.tls_reloader() {
        spawn_tls_reload_on_sighup(tls);
    }
    signals.wait().await;
    tracing::info!("shutting down");
    // Moving axes are brought to rest before the buses close.
    let not_at_rest = server
        .shutdown_safely(Duration::from_millis(config.shutdown_timeout_ms))
        .await;
    match server.wait(Duration::from_secs(10)).await {
        // A supervisor (systemd, Kubernetes) must see that the machine was
        // left in motion: the axes were quick-stopped, not stopped as
        // configured.
        Ok(()) if !not_at_rest.is_empty() => ExitCode::from(EXIT_AXES_NOT_AT_REST),
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{e}");
            ExitCode::from(1)
        }
    }
}
