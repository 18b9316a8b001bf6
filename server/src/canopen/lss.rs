//! LSS (CiA 305) on a bus's CANopen master: the commands run inside the
//! master task (its sans-IO [`cangate_canopen::master::Master`] owns the
//! [`cangate_canopen::lss::LssMaster`]), so their frames go through the bus
//! like SDO does; this module composes them into operations.
//!
//! LSS is bus-global, so a bus runs one LSS *operation* (one command, or a
//! sequence such as [`LssSession::assign_node_id`]) at a time: an
//! [`LssSession`] holds the bus for its operation, and asking for a second
//! one while it lives fails at once with [`CanopenError::LssBusy`] rather
//! than waiting (the devices' LSS state is what the other operation is
//! changing).

use super::{CanopenBus, CanopenError, Command};
use cangate_canopen::NodeId;
use cangate_canopen::lss::{
    InquireWhat, LssCommand, LssError, LssIdentity, LssMode, LssOutcome, UNCONFIGURED_NODE_ID,
};
use cangate_canopen::nmt::NmtCommand;
use std::time::Duration;
use tokio::sync::oneshot;

/// The bus held for one LSS operation; released on drop.
pub struct LssSession {
    bus: CanopenBus,
}

impl Drop for LssSession {
    fn drop(&mut self) {
        *self.bus.lss_operation.lock().expect("LSS lock") = None;
    }
}

/// Which device [`LssSession::assign_node_id`] configures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssTarget {
    /// By its whole identity.
    Identity(LssIdentity),
    /// The unconfigured device with this serial number (found by fastscan).
    Serial(u32),
}

/// What [`LssSession::assign_node_id`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Assigned {
    /// The device.
    pub identity: LssIdentity,
    /// Its node-ID before (255: none).
    pub previous: u8,
    /// Stored in the device.
    pub stored: bool,
}

impl CanopenBus {
    /// Holds the bus for the LSS operation `operation` (a name for
    /// messages), or fails with [`CanopenError::LssBusy`] when another one
    /// runs.
    pub fn lss_session(&self, operation: &'static str) -> Result<LssSession, CanopenError> {
        let mut running = self.lss_operation.lock().expect("LSS lock");
        if let Some(op) = *running {
            return Err(CanopenError::LssBusy {
                bus: self.bus.clone(),
                operation: op,
            });
        }
        *running = Some(operation);
        Ok(LssSession { bus: self.clone() })
    }
}

impl LssSession {
    /// Runs one LSS command in the master task.
    pub async fn run(
        &self,
        command: LssCommand,
        timeout: Duration,
    ) -> Result<LssOutcome, CanopenError> {
        let name = command.name();
        let (reply, rx) = oneshot::channel();
        self.bus
            .commands
            .send(Command::Lss {
                command,
                timeout,
                reply,
            })
            .await
            .map_err(|_| CanopenError::Stopped)?;
        let r = rx.await.map_err(|_| CanopenError::Stopped)?;
        let result = match &r {
            Ok(_) => "ok",
            Err(LssError::Timeout { .. }) => "timeout",
            Err(LssError::Refused { .. }) => "refused",
            Err(LssError::Protocol { .. }) => "protocol_error",
            Err(LssError::Busy { .. }) => "busy",
            Err(LssError::Invalid { .. }) => "invalid",
        };
        metrics::counter!("cangate_lss_commands_total", "bus" => self.bus.bus.clone(), "command" => name, "result" => result)
            .increment(1);
        if let Err(e) = &r {
            tracing::debug!(bus = %self.bus.bus, error = %e, "LSS command failed");
        }
        Ok(r?)
    }

    /// Every unconfigured device in the waiting state by fastscan (lowest
    /// identity first), then every device back to the waiting state (also
    /// after a failed scan).
    pub async fn fastscan(
        &self,
        step_time: Duration,
        max_nodes: usize,
    ) -> Result<Vec<LssIdentity>, CanopenError> {
        let found = self
            .run(
                LssCommand::Fastscan {
                    step_time,
                    max_nodes,
                },
                step_time,
            )
            .await;
        self.run(LssCommand::SwitchGlobal(LssMode::Waiting), step_time)
            .await?;
        match found? {
            LssOutcome::Found(ids) => Ok(ids),
            other => Err(unexpected("fastscan", other)),
        }
    }

    /// The identity and active node-ID of the device with `identity`, else
    /// of the only device (all switched to configuration); every device
    /// is back in waiting afterwards.
    pub async fn inquire(
        &self,
        identity: Option<LssIdentity>,
        timeout: Duration,
    ) -> Result<(LssIdentity, u8), CanopenError> {
        let r = self.inquire_in_configuration(identity, timeout).await;
        self.run(LssCommand::SwitchGlobal(LssMode::Waiting), timeout)
            .await?;
        r
    }

    async fn inquire_in_configuration(
        &self,
        identity: Option<LssIdentity>,
        timeout: Duration,
    ) -> Result<(LssIdentity, u8), CanopenError> {
        match identity {
            Some(id) => {
                self.run(LssCommand::SwitchGlobal(LssMode::Waiting), timeout)
                    .await?;
                self.run(LssCommand::SwitchSelective(id), timeout).await?;
            }
            None => {
                self.run(LssCommand::SwitchGlobal(LssMode::Configuration), timeout)
                    .await?;
            }
        }
        self.read_identity(timeout).await
    }

    async fn read_identity(&self, timeout: Duration) -> Result<(LssIdentity, u8), CanopenError> {
        let mut parts = [0u32; 4];
        let what = [
            InquireWhat::VendorId,
            InquireWhat::ProductCode,
            InquireWhat::Revision,
            InquireWhat::Serial,
            InquireWhat::NodeId,
        ];
        let mut node = UNCONFIGURED_NODE_ID;
        for (i, w) in what.into_iter().enumerate() {
            let v = match self.run(LssCommand::Inquire(w), timeout).await? {
                LssOutcome::Value(v) => v,
                other => return Err(unexpected("inquire", other)),
            };
            match parts.get_mut(i) {
                Some(p) => *p = v,
                None => node = v as u8,
            }
        }
        Ok((LssIdentity::from_parts(parts), node))
    }

    /// Gives a device node-ID `node`: (fastscan for a serial), switch
    /// selective, inquire its node-ID, configure, store if asked, back to
    /// waiting (an unconfigured device takes the id at once), and an NMT
    /// reset communication to the device's old node-ID if it had one.
    pub async fn assign_node_id(
        &self,
        target: LssTarget,
        node: NodeId,
        store: bool,
        timeout: Duration,
    ) -> Result<Assigned, CanopenError> {
        let identity = match target {
            LssTarget::Identity(id) => id,
            LssTarget::Serial(serial) => {
                let found = self.fastscan(Duration::from_millis(20), 127).await?;
                match found.iter().find(|id| id.serial == serial) {
                    Some(id) => *id,
                    None => {
                        return Err(CanopenError::LssDeviceNotFound {
                            bus: self.bus.bus.clone(),
                            serial,
                            found: if found.is_empty() {
                                "no unconfigured device".into()
                            } else {
                                found
                                    .iter()
                                    .map(|i| format!("serial 0x{:08X}", i.serial))
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            },
                        });
                    }
                }
            }
        };
        let configured = self.configure(identity, node, store, timeout).await;
        // Whatever happened, the devices go back to waiting: that applies
        // the new id of a device that had none.
        self.run(LssCommand::SwitchGlobal(LssMode::Waiting), timeout)
            .await?;
        let previous = configured?;
        if previous != UNCONFIGURED_NODE_ID
            && previous != node.get()
            && let Ok(old) = NodeId::new(u32::from(previous))
        {
            self.bus
                .nmt(NmtCommand::ResetCommunication, Some(old))
                .await?;
        }
        tracing::info!(
            bus = %self.bus.bus,
            node = node.get(),
            previous,
            stored = store,
            %identity,
            "LSS: node-ID given"
        );
        Ok(Assigned {
            identity,
            previous,
            stored: store,
        })
    }

    async fn configure(
        &self,
        identity: LssIdentity,
        node: NodeId,
        store: bool,
        timeout: Duration,
    ) -> Result<u8, CanopenError> {
        self.run(LssCommand::SwitchGlobal(LssMode::Waiting), timeout)
            .await?;
        self.run(LssCommand::SwitchSelective(identity), timeout)
            .await?;
        let previous = match self
            .run(LssCommand::Inquire(InquireWhat::NodeId), timeout)
            .await?
        {
            LssOutcome::Value(v) => v as u8,
            other => return Err(unexpected("inquire node-ID", other)),
        };
        self.run(LssCommand::ConfigureNodeId(node.get()), timeout)
            .await?;
        if store {
            self.run(LssCommand::StoreConfiguration, timeout).await?;
        }
        Ok(previous)
    }
}

fn unexpected(command: &'static str, outcome: LssOutcome) -> CanopenError {
    CanopenError::Lss(cangate_canopen::lss::LssError::Protocol {
        command,
        reason: format!("unexpected outcome {outcome:?}"),
    })
}
