//! The `cangate.v1.Simulator` RPCs beyond TurnHandwheel: virtual-bus faults
//! and device faults, over [`crate::simulation::Simulation`]. The service
//! type (`SimulatorService`) lives with the handwheels, whose wheels it
//! turns; its methods call these.

use super::error::ApiError;
use crate::convert::simulation::{device_pb, faults_pb};
use crate::gateway::Gateway;
use crate::simulation::{BusFaults, SimulationError};
use cangate_proto::v1 as pb;
use std::time::Duration;
use tonic::{Response, Status};

/// Default length of a power cut when the request gives none.
const DEFAULT_POWER_CUT: Duration = Duration::from_millis(100);

type Reply<T> = Result<Response<T>, Status>;

fn api_error(e: SimulationError) -> Status {
    let api = match e {
        SimulationError::NoBus { bus, known } => ApiError::NotFound {
            kind: "bus",
            name: bus,
            hint: format!(" (buses: {known})"),
        },
        SimulationError::NoDevice { bus, node, known } => ApiError::NotFound {
            kind: "simulated device",
            name: format!("node {node} on bus {bus}"),
            hint: format!(" (simulated: {known})"),
        },
        SimulationError::Invalid(m) => ApiError::InvalidArgument(m),
        e @ (SimulationError::NotVirtual(_)
        | SimulationError::Unsupported { .. }
        | SimulationError::NotNow { .. }) => ApiError::FailedPrecondition(e.to_string()),
    };
    api.into()
}

fn u16_arg(what: &str, v: u32) -> Result<u16, Status> {
    u16::try_from(v).map_err(|_| {
        ApiError::InvalidArgument(format!("{what} {v:#x} does not fit 16 bits")).into()
    })
}

/// ListSimulatedDevices.
pub fn list(g: &Gateway) -> Reply<pb::ListSimulatedDevicesResponse> {
    Ok(Response::new(pb::ListSimulatedDevicesResponse {
        devices: g
            .simulation()
            .devices()
            .into_iter()
            .map(device_pb)
            .collect(),
    }))
}

/// SetBusFaults.
pub fn set_bus_faults(g: &Gateway, r: pb::SetBusFaultsRequest) -> Reply<pb::BusFaults> {
    if !r.drop_probability.is_finite() {
        return Err(ApiError::InvalidArgument(format!(
            "drop_probability {} is not a probability (0..=1)",
            r.drop_probability
        ))
        .into());
    }
    let faults = BusFaults {
        drop_probability: r.drop_probability,
        drop_ids: r.drop_ids,
        delay: Duration::from_micros(r.delay_us),
    };
    g.simulation()
        .set_faults(&r.bus, faults)
        .map(|f| Response::new(faults_pb(f)))
        .map_err(api_error)
}

/// GetBusFaults.
pub fn get_bus_faults(g: &Gateway, r: pb::GetBusFaultsRequest) -> Reply<pb::BusFaults> {
    g.simulation()
        .faults(&r.bus)
        .map(|f| Response::new(faults_pb(f)))
        .map_err(api_error)
}

/// SetBusOff.
pub fn set_bus_off(g: &Gateway, r: pb::SetBusOffRequest) -> Reply<pb::BusFaults> {
    g.simulation()
        .set_bus_off(&r.bus, r.bus_off)
        .map(|f| Response::new(faults_pb(f)))
        .map_err(api_error)
}

/// PowerCycleDevice.
pub fn power_cycle(g: &Gateway, r: pb::PowerCycleDeviceRequest) -> Reply<pb::SimulatedDevice> {
    let off = match r.off_ms {
        0 => DEFAULT_POWER_CUT,
        ms => Duration::from_millis(u64::from(ms)),
    };
    g.simulation()
        .power_cycle(&r.bus, r.node, off)
        .map(|d| Response::new(device_pb(d)))
        .map_err(api_error)
}

/// SendEmcy.
pub fn send_emcy(g: &Gateway, r: pb::SendEmcyRequest) -> Reply<pb::SimulatedDevice> {
    let code = u16_arg("EMCY code", r.code)?;
    let register = u8::try_from(r.error_register).map_err(|_| {
        Status::from(ApiError::InvalidArgument(format!(
            "error register {:#x} does not fit 8 bits",
            r.error_register
        )))
    })?;
    if r.manufacturer.len() > 5 {
        return Err(ApiError::InvalidArgument(format!(
            "{} manufacturer bytes, at most 5 fit an EMCY",
            r.manufacturer.len()
        ))
        .into());
    }
    let mut manufacturer = [0u8; 5];
    manufacturer[..r.manufacturer.len()].copy_from_slice(&r.manufacturer);
    g.simulation()
        .send_emcy(&r.bus, r.node, code, register, manufacturer)
        .map(|d| Response::new(device_pb(d)))
        .map_err(api_error)
}

/// RaiseDriveFault.
pub fn raise_drive_fault(g: &Gateway, r: pb::RaiseDriveFaultRequest) -> Reply<pb::SimulatedDevice> {
    let code = u16_arg("fault code", r.code)?;
    g.simulation()
        .raise_drive_fault(&r.bus, r.node, code)
        .map(|d| Response::new(device_pb(d)))
        .map_err(api_error)
}

/// SetIoInputs.
pub fn set_io_inputs(g: &Gateway, r: pb::SetIoInputsRequest) -> Reply<pb::SetIoInputsResponse> {
    let analogue = r
        .analogue
        .iter()
        .map(|&v| {
            i16::try_from(v).map_err(|_| {
                Status::from(ApiError::InvalidArgument(format!(
                    "analogue input {v} is outside -32768..=32767"
                )))
            })
        })
        .collect::<Result<Vec<i16>, Status>>()?;
    let (device, digital, analogue) = g
        .simulation()
        .set_io_inputs(&r.bus, r.node, &r.digital, &analogue)
        .map_err(api_error)?;
    Ok(Response::new(pb::SetIoInputsResponse {
        device: Some(device_pb(device)),
        digital,
        analogue: analogue.into_iter().map(i32::from).collect(),
    }))
}

/// SetProgramFaults.
pub fn set_program_faults(g: &Gateway, r: pb::SetProgramFaultsRequest) -> Reply<pb::ProgramFaults> {
    let flash_error = match r.flash_error {
        0 => None,
        e @ 1..=127 => Some(e as u8),
        e => {
            return Err(ApiError::InvalidArgument(format!(
                "flash_error {e} is outside 1..=127 (0: none)"
            ))
            .into());
        }
    };
    let code = match r.abort_code {
        0 => cangate_canopen::sdo::AbortCode::HARDWARE_ERROR,
        c => cangate_canopen::sdo::AbortCode(c),
    };
    let abort_at = match r.abort_at_byte {
        None => None,
        Some(n) => Some((
            usize::try_from(n).map_err(|_| {
                Status::from(ApiError::InvalidArgument(format!(
                    "abort_at_byte {n} is too large"
                )))
            })?,
            code,
        )),
    };
    let faults = cangate_sim::program::ProgramFaults {
        flash_error,
        abort_at,
        no_boot: r.no_boot,
    };
    let p = g
        .simulation()
        .set_program_faults(&r.bus, r.node, faults)
        .map_err(api_error)?;
    let armed = p.faults();
    Ok(Response::new(pb::ProgramFaults {
        bus: r.bus,
        node: r.node,
        flash_error: armed.flash_error.map_or(0, u32::from),
        abort_at_byte: armed.abort_at.map(|(n, _)| n as u64),
        abort_code: armed.abort_at.map_or(0, |(_, c)| c.get()),
        no_boot: armed.no_boot,
        identification: p.identification(),
        running: p.running(),
        downloads: p.downloads(),
    }))
}
