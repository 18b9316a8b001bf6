//! `cangate sim …`: the Simulator service (`handwheel.proto`): simulated
//! devices, virtual-bus faults, and turning a simulated handwheel.

use super::{App, Context, Result, hex_bytes, int_arg, label, node_id, print_json, probability};
use cangate_client::{NodeId, pb};
use clap::{Args, Subcommand, ValueEnum};

/// `cangate sim …`
#[derive(Args, Debug)]
pub(crate) struct SimArgs {
    #[command(subcommand)]
    verb: SimVerb,
}

#[derive(Subcommand, Debug)]
enum SimVerb {
    /// Turn a simulated handwheel: `cangate sim turn hw1 -20 --axis X
    /// --mult 10` (the wheel sends feed in manual mode).
    Turn(TurnArgs),
    /// The gateway's simulated devices.
    List,
    /// Show a virtual bus's faults, or replace them: `cangate sim faults
    /// can0 --drop 0.01 --drop-id 0x77F --delay-us 500` (`--clear`: none).
    Faults(FaultArgs),
    /// Force a virtual bus off (`--recover`: back to error-active).
    BusOff {
        /// A virtual bus.
        bus: String,
        /// Recover instead.
        #[arg(long)]
        recover: bool,
    },
    /// Cut a simulated device's power: `cangate sim power-cycle can0 1
    /// --off-ms 500`; it boots with its power-on defaults.
    PowerCycle {
        /// The bus.
        bus: String,
        /// The node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// How long the power stays off.
        #[arg(long, value_name = "MS", default_value_t = 100)]
        off_ms: u32,
    },
    /// Make a simulated device send an EMCY: `cangate sim emcy can0 4
    /// 0x5000 --register 0x01 --data 0102`.
    Emcy {
        /// The bus.
        bus: String,
        /// The node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// The error code (0x… or decimal).
        #[arg(value_parser = int_arg)]
        code: u32,
        /// The error register (default: generic error).
        #[arg(long, value_parser = int_arg, default_value = "0")]
        register: u32,
        /// Manufacturer bytes as hex, at most 5 (e.g. 0102).
        #[arg(long, value_parser = bytes_arg)]
        data: Option<Bytes>,
    },
    /// Raise a fault in a simulated drive: `cangate sim drive-fault can0 1
    /// 0x2310`.
    DriveFault {
        /// The bus.
        bus: String,
        /// The node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// The fault's EMCY code (0x1000..=0xFFFF).
        #[arg(value_parser = int_arg)]
        code: u32,
    },
    /// Set the inputs of a simulated I/O node: `cangate sim inputs can0 3
    /// --digital 0x01,0x80 --analogue 1000,-5`.
    Inputs {
        /// The bus.
        bus: String,
        /// The node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// Digital input bytes for 0x6000 sub 1, 2, …
        #[arg(long, value_delimiter = ',', value_parser = byte_arg)]
        digital: Vec<u8>,
        /// Analogue inputs for 0x6401 sub 1, 2, …
        #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
        analogue: Vec<i32>,
    },
    /// Arm faults of a simulated device's next program download (each acts
    /// once): `cangate sim program-faults can0 5 --flash-error 5`,
    /// `--abort-at 10000 [--abort-code 0x06060000]`, `--no-boot`; none
    /// given: clear them.
    ProgramFaults {
        /// The bus.
        bus: String,
        /// The node id.
        #[arg(value_parser = node_id)]
        node: NodeId,
        /// The flashing ends with this error code in 0x1F57 (1..=127, e.g.
        /// 5 flash write error).
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=127))]
        flash_error: Option<u32>,
        /// The node aborts the data download once this many bytes arrived.
        #[arg(long, value_name = "BYTES")]
        abort_at: Option<u64>,
        /// The abort code of --abort-at (default 0x06060000).
        #[arg(long, value_parser = int_arg, requires = "abort_at")]
        abort_code: Option<u32>,
        /// The start is confirmed but the node never boots.
        #[arg(long)]
        no_boot: bool,
    },
}

/// `sim turn WHEEL DETENTS …`
#[derive(Args, Debug)]
struct TurnArgs {
    /// Simulated handwheel name.
    wheel: String,
    /// Signed detents (negative: the other way).
    #[arg(allow_negative_numbers = true, value_name = "DETENTS")]
    detents: i32,
    /// Set the axis selector first (X Y Z W V; default: keep).
    #[arg(long, ignore_case = true)]
    axis: Option<AxisArg>,
    /// Set the multiplier first: 1, 10 or 100 (default: keep).
    #[arg(long, value_name = "1|10|100", value_parser = multiplier)]
    mult: Option<u32>,
    /// Lose each feed frame of this turn with this probability (0..1).
    #[arg(long, value_name = "P", value_parser = probability)]
    loss: Option<f64>,
    /// Never lose more than this many frames in a row (default: the
    /// gateway's, 14, the most a nibble counter detects).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    max_consecutive_loss: Option<u32>,
}

/// `sim faults BUS …`
#[derive(Args, Debug)]
struct FaultArgs {
    /// A virtual bus.
    bus: String,
    /// Drop each frame with this probability (0..1).
    #[arg(long = "drop", value_name = "P", value_parser = probability)]
    drop_probability: Option<f64>,
    /// Drop every frame with this identifier (repeatable).
    #[arg(long = "drop-id", value_name = "ID", value_parser = int_arg)]
    drop_ids: Vec<u32>,
    /// Deliver every frame this many µs late.
    #[arg(long, value_name = "US")]
    delay_us: Option<u64>,
    /// Remove every drop and delay fault.
    #[arg(long, conflicts_with_all = ["drop_probability", "drop_ids", "delay_us"])]
    clear: bool,
}

/// The wheel's axis selector as typed (any case).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
#[value(rename_all = "UPPER")]
enum AxisArg {
    /// X.
    X,
    /// Y.
    Y,
    /// Z.
    Z,
    /// W.
    W,
    /// V.
    V,
}

impl AxisArg {
    fn pb(self) -> pb::WheelAxis {
        match self {
            AxisArg::X => pb::WheelAxis::X,
            AxisArg::Y => pb::WheelAxis::Y,
            AxisArg::Z => pb::WheelAxis::Z,
            AxisArg::W => pb::WheelAxis::W,
            AxisArg::V => pb::WheelAxis::V,
        }
    }
}

fn multiplier(text: &str) -> Result<u32, String> {
    match text.parse::<u32>() {
        Ok(m @ (1 | 10 | 100)) => Ok(m),
        _ => Err(format!("{text:?} is not 1, 10 or 100")),
    }
}

/// Bytes typed as hex.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Bytes(Vec<u8>);

fn bytes_arg(text: &str) -> Result<Bytes, String> {
    hex_bytes(text).map(Bytes)
}

fn byte_arg(text: &str) -> Result<u8, String> {
    let v = int_arg(text)?;
    u8::try_from(v).map_err(|_| format!("{text:?} does not fit a byte"))
}

fn device_text(d: &pb::SimulatedDevice) -> String {
    format!(
        "{} node {} ({}): {}{}",
        d.bus,
        d.node,
        label::<pb::SimulatedDeviceKind>(d.kind),
        d.nmt_state,
        if d.powered { "" } else { " (power off)" }
    )
}

fn faults_text(f: &pb::BusFaults) -> String {
    let ids: Vec<String> = f.drop_ids.iter().map(|id| format!("{id:#x}")).collect();
    format!(
        "{}: drop {} ids [{}] delay {} µs{}  ({} frames dropped so far)",
        f.bus,
        f.drop_probability,
        ids.join(", "),
        f.delay_us,
        if f.bus_off { "  BUS-OFF" } else { "" },
        f.dropped_by_fault
    )
}

/// `cangate sim …`
pub(crate) async fn run(app: &App, args: SimArgs) -> Result<()> {
    let c = &app.client;
    let sim = || c.simulator_client();
    match args.verb {
        SimVerb::Turn(t) => {
            let req = pb::TurnHandwheelRequest {
                handwheel: t.wheel.clone(),
                detents: t.detents,
                axis: t.axis.map_or(pb::WheelAxis::Unspecified, AxisArg::pb) as i32,
                multiplier: t.mult.unwrap_or(0),
                loss: t.loss.unwrap_or(0.0),
                max_consecutive_loss: t.max_consecutive_loss.unwrap_or(0),
            };
            let r = c
                .call("TurnHandwheel", None, sim().turn_handwheel(req))
                .await
                .ctx(format!("turning {}", t.wheel))?;
            let mut text = format!(
                "{}: turned {:+} detents, {} units pending",
                t.wheel, t.detents, r.pending_units
            );
            if r.discarded_units > 0 {
                text.push_str(&format!(
                    ", {} discarded (the wheel sends feed only in manual mode)",
                    r.discarded_units
                ));
            }
            app.show(text, &r)
        }
        SimVerb::List => {
            let r = c
                .call(
                    "ListSimulatedDevices",
                    None,
                    sim().list_simulated_devices(pb::ListSimulatedDevicesRequest {}),
                )
                .await
                .ctx("listing the simulated devices")?;
            if app.json {
                return print_json(&r);
            }
            let lines: Vec<String> = r.devices.iter().map(device_text).collect();
            app.line(if lines.is_empty() {
                "no simulated devices".to_string()
            } else {
                lines.join("\n")
            })
        }
        SimVerb::Faults(f) => {
            let changing = f.clear
                || f.drop_probability.is_some()
                || !f.drop_ids.is_empty()
                || f.delay_us.is_some();
            let what = format!("faults of {}", f.bus);
            let r = if changing {
                let req = pb::SetBusFaultsRequest {
                    bus: f.bus.clone(),
                    drop_probability: f.drop_probability.unwrap_or(0.0),
                    drop_ids: f.drop_ids,
                    delay_us: f.delay_us.unwrap_or(0),
                };
                c.call("SetBusFaults", None, sim().set_bus_faults(req))
                    .await
            } else {
                let req = pb::GetBusFaultsRequest { bus: f.bus.clone() };
                c.call("GetBusFaults", None, sim().get_bus_faults(req))
                    .await
            }
            .ctx(what)?;
            app.show(faults_text(&r), &r)
        }
        SimVerb::BusOff { bus, recover } => {
            let req = pb::SetBusOffRequest {
                bus: bus.clone(),
                bus_off: !recover,
            };
            let r = c
                .call("SetBusOff", None, sim().set_bus_off(req))
                .await
                .ctx(format!("bus-off of {bus}"))?;
            app.show(faults_text(&r), &r)
        }
        SimVerb::PowerCycle { bus, node, off_ms } => {
            let req = pb::PowerCycleDeviceRequest {
                bus: bus.clone(),
                node: node.into(),
                off_ms,
            };
            let r = c
                .call("PowerCycleDevice", None, sim().power_cycle_device(req))
                .await
                .ctx(format!("power cycle of {bus} node {node}"))?;
            app.show(
                format!(
                    "{}: power off for {off_ms} ms, then it boots",
                    device_text(&r)
                ),
                &r,
            )
        }
        SimVerb::Emcy {
            bus,
            node,
            code,
            register,
            data,
        } => {
            let req = pb::SendEmcyRequest {
                bus: bus.clone(),
                node: node.into(),
                code,
                error_register: register,
                manufacturer: data.map(|b| b.0).unwrap_or_default(),
            };
            let r = c
                .call("SendEmcy", None, sim().send_emcy(req))
                .await
                .ctx(format!("EMCY of {bus} node {node}"))?;
            app.show(format!("{}: sent EMCY {code:#06x}", device_text(&r)), &r)
        }
        SimVerb::DriveFault { bus, node, code } => {
            let req = pb::RaiseDriveFaultRequest {
                bus: bus.clone(),
                node: node.into(),
                code,
            };
            let r = c
                .call("RaiseDriveFault", None, sim().raise_drive_fault(req))
                .await
                .ctx(format!("drive fault of {bus} node {node}"))?;
            app.show(format!("{}: fault {code:#06x} raised", device_text(&r)), &r)
        }
        SimVerb::Inputs {
            bus,
            node,
            digital,
            analogue,
        } => {
            let req = pb::SetIoInputsRequest {
                bus: bus.clone(),
                node: node.into(),
                digital,
                analogue,
            };
            let r = c
                .call("SetIoInputs", None, sim().set_io_inputs(req))
                .await
                .ctx(format!("inputs of {bus} node {node}"))?;
            let digital: Vec<String> = r.digital.iter().map(|b| format!("{b:#04x}")).collect();
            app.show(
                format!(
                    "{bus} node {node}: digital [{}] analogue {:?}",
                    digital.join(", "),
                    r.analogue
                ),
                &r,
            )
        }
        SimVerb::ProgramFaults {
            bus,
            node,
            flash_error,
            abort_at,
            abort_code,
            no_boot,
        } => {
            let req = pb::SetProgramFaultsRequest {
                bus: bus.clone(),
                node: node.into(),
                flash_error: flash_error.unwrap_or(0),
                abort_at_byte: abort_at,
                abort_code: abort_code.unwrap_or(0),
                no_boot,
            };
            let r = c
                .call("SetProgramFaults", None, sim().set_program_faults(req))
                .await
                .ctx(format!("program faults of {bus} node {node}"))?;
            let mut armed = Vec::new();
            if r.flash_error != 0 {
                armed.push(format!("flash error {}", r.flash_error));
            }
            if let Some(at) = r.abort_at_byte {
                armed.push(format!("abort 0x{:08X} at byte {at}", r.abort_code));
            }
            if r.no_boot {
                armed.push("no boot-up after the start".into());
            }
            if armed.is_empty() {
                armed.push("none".into());
            }
            app.show(
                format!(
                    "{bus} node {node}: program 0x{:08X} {}, {} downloads; next download faults: {}",
                    r.identification,
                    if r.running { "running" } else { "stopped" },
                    r.downloads,
                    armed.join(", ")
                ),
                &r,
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Cli, Command};
    use super::*;
    use clap::Parser;

    fn verb(argv: &[&str]) -> SimVerb {
        let mut all = vec!["cangate", "sim"];
        all.extend_from_slice(argv);
        match Cli::try_parse_from(&all) {
            Ok(Cli {
                command: Command::Sim(a),
                ..
            }) => a.verb,
            Ok(other) => panic!("{other:?}"),
            Err(e) => panic!("{all:?}: {e}"),
        }
    }

    #[test]
    fn turn_takes_negative_detents() {
        let SimVerb::Turn(t) = verb(&["turn", "hw1", "-20", "--axis", "y", "--mult", "10"]) else {
            panic!()
        };
        assert_eq!(
            (t.detents, t.axis, t.mult),
            (-20, Some(AxisArg::Y), Some(10))
        );
        assert!(
            Cli::try_parse_from(["cangate", "sim", "turn", "hw1", "1", "--mult", "5"]).is_err()
        );
    }

    #[test]
    fn fault_verbs() {
        let SimVerb::Faults(f) = verb(&["faults", "can0", "--drop", "0.5", "--drop-id", "0x77F"])
        else {
            panic!()
        };
        assert_eq!((f.drop_probability, f.drop_ids), (Some(0.5), vec![0x77F]));
        assert!(
            Cli::try_parse_from(["cangate", "sim", "faults", "can0", "--clear", "--drop", "1"])
                .is_err()
        );
        let SimVerb::Emcy { code, data, .. } =
            verb(&["emcy", "can0", "4", "0x5000", "--data", "0102"])
        else {
            panic!()
        };
        assert_eq!((code, data), (0x5000, Some(Bytes(vec![1, 2]))));
        let SimVerb::Inputs {
            digital, analogue, ..
        } = verb(&[
            "inputs",
            "can0",
            "3",
            "--digital",
            "0x01,0x80",
            "--analogue",
            "1000,-5",
        ])
        else {
            panic!()
        };
        assert_eq!((digital, analogue), (vec![1, 0x80], vec![1000, -5]));
    }
}
