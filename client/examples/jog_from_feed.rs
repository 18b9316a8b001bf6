//! Jogs an axis from a handwheel's feed, holding a control lease: the feed
//! is streamed in 50 ms windows; each unit moves the axis's target by
//! `--per-unit`, and every 50 ms the axis is jogged at the velocity that
//! covers the distance from its position (read back from each jog's
//! answer) to the target in 200 ms, at most the axis's maximum; so it
//! follows the wheel and stops when it has caught up. The
//! lease is renewed in the background and released at the end.
//!
//! ```sh
//! cargo run -p cangate-server &                      # the demo on 127.0.0.1:50051
//! cargo run -p cangate-client --example jog_from_feed -- --axis Z --turn 40
//! # or turn the simulated wheel yourself meanwhile:
//! cangate sim turn hw1 20 --axis Z --mult 10
//! ```
//!
//! Options: `--server ADDR`, `--wheel NAME` (hw1), `--axis NAME` (Z: the
//! demo's wheel has no binding of its own for it), `--per-unit MM` (0.01),
//! `--seconds S` (10), `--turn DETENTS` (turn the simulated wheel on
//! selector Z, multiplier 10, after a second; gateways with simulated
//! wheels only).

use cangate_client::{ConnectOptions, Error, HandwheelMode, pb};
use futures::StreamExt;
use std::time::{Duration, Instant};

/// Feed window and jog period.
const WINDOW: Duration = Duration::from_millis(50);
/// The axis covers the distance still to go in about this time.
const CATCH_UP: Duration = Duration::from_millis(200);
/// Closer than this (user units) counts as caught up.
const CLOSE: f64 = 1e-3;

#[tokio::main]
async fn main() {
    if let Err(e) = run().await {
        eprintln!("jog_from_feed: {e}");
        std::process::exit(1);
    }
}

async fn run() -> Result<(), Box<dyn std::error::Error>> {
    let mut server = std::env::var("CANGATE_SERVER").unwrap_or_else(|_| "127.0.0.1:50051".into());
    let (mut wheel, mut axis) = ("hw1".to_string(), "Z".to_string());
    let (mut per_unit, mut seconds, mut turn) = (0.01, 10.0, 0);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--server" => server = value()?,
            "--wheel" => wheel = value()?,
            "--axis" => axis = value()?,
            "--per-unit" => per_unit = value()?.parse()?,
            "--seconds" => seconds = value()?.parse()?,
            "--turn" => turn = value()?.parse()?,
            other => return Err(format!("unknown argument {other:?}").into()),
        }
    }
    let options = ConnectOptions {
        request_timeout: Some(Duration::from_secs(10)),
        ..Default::default()
    };
    let client = cangate_client::connect_with(&server, &options).await?;
    let max_velocity = client.axis(&axis).await?.max_velocity;

    let lease = client
        .acquire_control_as(&[axis.as_str()], Duration::from_secs(2), "jog_from_feed")
        .await?;
    println!("control of {axis} as {}", lease.holder());
    client.enable(&axis, &lease.options().wait(true)).await?;
    let before = client.handwheel(&wheel).await?.mode;
    client
        .set_handwheel_mode(&wheel, HandwheelMode::Manual)
        .await?;
    let mut feed = client
        .handwheel_feed(&[wheel.as_str()], Some(WINDOW))
        .await?;
    if turn != 0 {
        let (c, w) = (client.clone(), wheel.clone());
        tokio::spawn(async move {
            tokio::time::sleep(Duration::from_secs(1)).await;
            if let Err(e) = c
                .turn_simulated_handwheel(&w, turn, pb::WheelAxis::Z, 10)
                .await
            {
                eprintln!("turning {w}: {e}");
            }
        });
    }

    let jog = lease.jog_options();
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    let mut tick = tokio::time::interval(WINDOW);
    let mut position = client.axis_status(&axis).await?.position;
    let mut target = position;
    let mut jogging = false;
    let mut units_total = 0u64;
    let result: Result<(), Error> = async {
        while Instant::now() < end {
            tokio::select! {
                event = feed.next() => match event {
                    Some(Ok(e)) => {
                        units_total += u64::from(e.units);
                        target += f64::from(e.direction) * f64::from(e.units) * per_unit;
                    }
                    Some(Err(e)) => return Err(e),
                    None => return Ok(()),
                },
                _ = tick.tick() => {
                    let to_go = target - position;
                    if to_go.abs() < CLOSE {
                        if jogging {
                            client.jog(&axis, 0.0, &jog).await?;
                            println!("caught up with the wheel at {position:.3}: jog stopped");
                            jogging = false;
                        }
                        continue;
                    }
                    let v = (to_go / CATCH_UP.as_secs_f64()).clamp(-max_velocity, max_velocity);
                    let r = client.jog(&axis, v, &jog).await?;
                    if let Some(s) = r.status {
                        position = s.position;
                    }
                    println!("{to_go:+9.3} to go -> jog {v:+8.3}/s at {position:9.3}");
                    jogging = true;
                }
                lost = lease.lost() => {
                    println!("lease lost: {:?}", lost.last_error);
                    return Ok(());
                }
                _ = tokio::signal::ctrl_c() => return Ok(()),
            }
        }
        Ok(())
    }
    .await;

    // Leave things as they were: axis at rest, wheel mode, control.
    let stop = client.stop(&axis, true).await;
    if let Ok(mode) = HandwheelMode::try_from(before)
        && mode != HandwheelMode::Unspecified
    {
        client.set_handwheel_mode(&wheel, mode).await?;
    }
    let status = lease.status();
    let released = lease.release().await?;
    println!(
        "{units_total} feed units; lease renewed {} times; released {released:?}",
        status.renewals
    );
    result?;
    stop?;
    Ok(())
}
