//! Simulated CANsmc slaves of a configuration (`simulate = true`).

use crate::config::CansmcSlaveConfig;
use cangate_cansmc::SmcAddress;
use cangate_sim::cansmc_runner::CansmcSlaveHandle;
use cangate_sim::cansmc_slave::{SimCansmcSlave, SimCansmcSlaveOptions};

/// The simulated slave of `cfg`, with the default servo model: 10 000
/// counts per revolution, 3000 r/min, the reference switch at 5 000
/// counts from power-up.
pub fn slave_for(cfg: &CansmcSlaveConfig) -> Result<CansmcSlaveHandle, String> {
    let address = SmcAddress::new(cfg.address).map_err(|e| e.to_string())?;
    let mut options = SimCansmcSlaveOptions::new(address);
    options.encoder_velocity = cfg.sim_encoder_velocity;
    options.home_reference = 5_000;
    options.seed = u64::from(cfg.address);
    Ok(CansmcSlaveHandle::new(SimCansmcSlave::new(options)))
}
