//! `cangate lease …`: control leases as tokens a shell can hold.
//!
//! `lease acquire X Y` takes control and prints the token (the lease is
//! kept: this process exits without releasing it); it lapses after its TTL
//! unless renewed (`lease renew`, or any axis command given `--lease`,
//! which renews it while it runs). `lease release` gives control back.

use super::{App, Context, Result, positive};
use cangate_client::pb;
use clap::{Args, Subcommand};
use std::time::Duration;

/// `cangate lease …`
#[derive(Args, Debug)]
pub(crate) struct LeaseArgs {
    #[command(subcommand)]
    verb: LeaseVerb,
}

#[derive(Subcommand, Debug)]
enum LeaseVerb {
    /// Take control of axes (all or none) and print the lease token:
    /// `export CANGATE_LEASE=$(cangate lease acquire X Y --ttl-ms 30000)`.
    Acquire {
        /// The axes.
        #[arg(required = true)]
        axes: Vec<String>,
        /// Time to live in ms (the gateway clamps it to 100..=60000); the
        /// lease lapses this long after its latest renewal.
        #[arg(long, value_name = "MS", default_value_t = 10_000,
              value_parser = clap::value_parser!(u32).range(1..))]
        ttl_ms: u32,
        /// The name others see as the holder (with this client's address).
        #[arg(long, default_value = "cangate-cli")]
        name: String,
        /// Keep the lease here instead of printing it: renew it until
        /// Ctrl-C (or --for), then release it.
        #[arg(long)]
        hold: bool,
        /// With --hold: release after this many seconds.
        #[arg(long = "for", value_name = "SECONDS", value_parser = positive, requires = "hold")]
        for_secs: Option<f64>,
    },
    /// Renew a lease now (its TTL starts again).
    Renew {
        /// The lease token.
        #[arg(env = "CANGATE_LEASE", hide_env_values = true)]
        token: String,
    },
    /// Release a lease: the axes are free again (they keep their state).
    Release {
        /// The lease token.
        #[arg(env = "CANGATE_LEASE", hide_env_values = true)]
        token: String,
    },
}

/// `cangate lease …`
pub(crate) async fn run(app: &App, args: LeaseArgs) -> Result<()> {
    match args.verb {
        LeaseVerb::Acquire {
            axes,
            ttl_ms,
            name,
            hold,
            for_secs,
        } => {
            let names: Vec<&str> = axes.iter().map(String::as_str).collect();
            let what = format!("taking control of {}", names.join(", "));
            let ttl = Duration::from_millis(u64::from(ttl_ms));
            let lease = app
                .client
                .acquire_control_as(&names, ttl, &name)
                .await
                .ctx(what.clone())?;
            if !hold {
                let kept = lease.keep();
                return app.show(&kept.lease, &kept);
            }
            if !app.json {
                eprintln!(
                    "holding control of {} (lease renewed every {} ms) until Ctrl-C",
                    lease.axes().join(", "),
                    lease.ttl().as_millis() / 3
                );
            }
            let ended = tokio::select! {
                _ = super::ctrl_c() => None,
                _ = super::sleep_opt(for_secs) => None,
                s = lease.lost() => Some(s),
            };
            if let Some(s) = ended {
                let why = s
                    .last_error
                    .map_or_else(|| "the lease lapsed".to_string(), |e| e.to_string());
                return Err(super::Failure::failed(what, format!("control lost: {why}")));
            }
            let axes = lease.release().await.ctx("releasing control")?;
            app.show(
                format!("released: {}", axes.join(", ")),
                &pb::ReleaseControlResponse { axes },
            )
        }
        LeaseVerb::Renew { token } => {
            let lease = app
                .client
                .renew_control(&token)
                .await
                .ctx("renewing the lease")?;
            app.show(
                format!(
                    "renewed: {} (held by {}, lapses in {} ms)",
                    lease.axes.join(", "),
                    lease.holder,
                    lease.ttl_ms
                ),
                &lease,
            )
        }
        LeaseVerb::Release { token } => {
            let axes = app
                .client
                .release_control(&token)
                .await
                .ctx("releasing the lease")?;
            app.show(
                format!("released: {}", axes.join(", ")),
                &pb::ReleaseControlResponse { axes },
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use clap::Parser;

    #[test]
    fn acquire_takes_axes_and_a_ttl() {
        let cli = Cli::try_parse_from(["cangate", "lease", "acquire", "X", "Y", "--ttl-ms", "500"])
            .unwrap();
        let Command::Lease(LeaseArgs {
            verb: LeaseVerb::Acquire { axes, ttl_ms, .. },
        }) = cli.command
        else {
            panic!()
        };
        assert_eq!(
            (axes.as_slice(), ttl_ms),
            (&["X".to_string(), "Y".to_string()][..], 500)
        );
        assert!(Cli::try_parse_from(["cangate", "lease", "acquire"]).is_err());
        assert!(Cli::try_parse_from(["cangate", "lease", "release", "tok"]).is_ok());
    }
}
