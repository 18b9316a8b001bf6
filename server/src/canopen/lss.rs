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
//!
//! Two guards keep LSS off the running machine:
//!
//! - **A node-ID in use is not given to another device**
//!   ([`CanopenBus::check_node_id_free`]): an id heard in the last minute
//!   ([`super::heard`]), the id of an axis's drive, or an id configured for
//!   a device of another identity (or of none the configuration can tell)
//!   is refused unless the caller forces it. Two devices with one id take
//!   each other's SDO answers, PDOs and controlwords.
//! - **An enabled axis's drive is not reached** ([`CanopenBus::check_lss_reach`]):
//!   switch global to the configuration state (every device, the drives
//!   with LSS too), and the commands for whatever device is in that state,
//!   are refused while an axis of the bus is enabled or moving; so is
//!   addressing the identity of such a drive. Fastscan and the identify
//!   commands only reach unconfigured devices or only ask, and pass.

use super::drive_guard::AxisActive;
use super::{CanopenBus, CanopenError, Command};
use cangate_canopen::lss::{
    InquireWhat, LssCommand, LssError, LssIdentity, LssMode, LssOutcome, UNCONFIGURED_NODE_ID,
};
use cangate_canopen::nmt::NmtCommand;
use cangate_canopen::{NodeId, ObjectAddress};
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

/// Which devices an LSS operation reaches (see [`CanopenBus::check_lss_reach`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssReach {
    /// Every device, or whichever devices are in the configuration state.
    AllDevices,
    /// The device with this identity.
    Identity(LssIdentity),
}

/// The most fastscan searches one assignment by serial runs.
const MAX_SEARCHES: usize = 127;

/// The fastscan step of an assignment by serial number (bounded below by
/// the bus, [`CanopenBus::min_fastscan_step`]).
const ASSIGN_STEP: Duration = Duration::from_millis(20);

impl CanopenBus {
    /// The shortest fastscan step this bus can answer in
    /// ([`cangate_canopen::lss::min_fastscan_step`] at its bitrate).
    pub fn min_fastscan_step(&self) -> Duration {
        cangate_canopen::lss::min_fastscan_step(self.handle.info().bitrate)
    }

    /// Refuses an LSS operation reaching `reach` while it could reach the
    /// drive of an enabled or moving axis: every device while any axis of
    /// the bus is active; a device by identity when it is an active axis's
    /// drive, or when an active drive's identity is not known (it was not
    /// read at its boot).
    pub fn check_lss_reach(&self, reach: LssReach, operation: &str) -> Result<(), AxisActive> {
        let active = self.drive_guard.active_drives();
        let facts = self.facts.read().expect("facts lock");
        for (node, axis) in active {
            let hit = match reach {
                LssReach::AllDevices => true,
                LssReach::Identity(id) => facts
                    .get(&node)
                    .and_then(|f| f.identity)
                    .is_none_or(|known| LssIdentity::from_parts(known) == id),
            };
            if hit {
                return Err(AxisActive {
                    bus: self.bus.clone(),
                    node,
                    axis,
                    operation: format!("LSS {operation} (which reaches the drive)"),
                });
            }
        }
        Ok(())
    }

    /// Refuses node-ID `node` for a device (of `identity` when known) when
    /// another device uses it: heard in the last minute, the drive of an
    /// axis, or configured for a device of another identity (or of one the
    /// configuration cannot tell).
    pub fn check_node_id_free(
        &self,
        node: NodeId,
        identity: Option<LssIdentity>,
    ) -> Result<(), CanopenError> {
        self.check_node_id_unused(node)?;
        self.check_node_id_meant_for(node, identity)
    }

    fn node_id_in_use(&self, node: NodeId, why: String) -> CanopenError {
        CanopenError::LssNodeIdInUse {
            bus: self.bus.clone(),
            node: node.get(),
            why,
        }
    }

    /// Refuses `node` when it was heard in the last minute or drives an
    /// axis.
    fn check_node_id_unused(&self, node: NodeId) -> Result<(), CanopenError> {
        let in_use = |why| self.node_id_in_use(node, why);
        if let Some(axis) = self.drive_guard.axis_of(node) {
            return Err(in_use(format!(
                "it is configured as the drive of axis {axis}"
            )));
        }
        if let Some(ago) = self.heard.in_use(node) {
            return Err(in_use(format!(
                "node {node} sent a frame {:.1} s ago",
                ago.as_secs_f64()
            )));
        }
        Ok(())
    }

    /// Refuses `node` when it is configured for a device other than one of
    /// `identity` (or when either cannot be told).
    fn check_node_id_meant_for(
        &self,
        node: NodeId,
        identity: Option<LssIdentity>,
    ) -> Result<(), CanopenError> {
        let in_use = |why| self.node_id_in_use(node, why);
        let facts = self.facts.read().expect("facts lock");
        let Some(f) = facts.get(&node).filter(|f| f.configured) else {
            return Ok(());
        };
        let eds_u32 = |sub: u8| {
            f.eds.as_ref().and_then(|e| {
                e.od.get(ObjectAddress::new(0x1018, sub))
                    .and_then(|v| v.default_for_node(node))
                    .and_then(|v| v.as_u32())
            })
        };
        let plan = f.boot.as_deref();
        let vendor = plan.and_then(|p| p.vendor_id).or_else(|| eds_u32(1));
        let product = plan.and_then(|p| p.product_code).or_else(|| eds_u32(2));
        let name = if f.name.is_empty() {
            String::new()
        } else {
            format!(" ({})", f.name)
        };
        match (identity, vendor, product) {
            (Some(id), Some(v), Some(p)) if id.vendor_id == v && id.product_code == p => Ok(()),
            (Some(id), Some(v), Some(p)) => Err(in_use(format!(
                "it is configured{name} for vendor 0x{v:08X} product 0x{p:08X}, and this \
                 device is vendor 0x{:08X} product 0x{:08X}",
                id.vendor_id, id.product_code
            ))),
            _ => Err(in_use(format!(
                "it is configured{name}, and the configuration has no vendor-ID and product \
                 code (boot check or EDS) to tell this device is the one meant"
            ))),
        }
    }

    /// Runs one LSS command for an API client, behind the guards that
    /// keep LSS off the running machine: a command that reaches every
    /// device (switch global to configuration, and the configuration
    /// commands, which reach whichever device is in that state) or a
    /// device by identity is refused while it could reach an active axis's
    /// drive ([`CanopenBus::check_lss_reach`]); a node-ID another device
    /// uses is refused ([`CanopenBus::check_node_id_free`]) unless `force`.
    /// Fastscan, inquire and identify only ask, and pass.
    pub async fn client_lss(
        &self,
        command: LssCommand,
        timeout: Duration,
        force: bool,
    ) -> Result<LssOutcome, CanopenError> {
        let reach = match &command {
            LssCommand::SwitchGlobal(LssMode::Configuration)
            | LssCommand::ConfigureNodeId(_)
            | LssCommand::ConfigureBitTiming { .. }
            | LssCommand::ActivateBitTiming { .. }
            | LssCommand::StoreConfiguration => Some(LssReach::AllDevices),
            LssCommand::SwitchSelective(id) => Some(LssReach::Identity(*id)),
            _ => None,
        };
        if let Some(reach) = reach {
            self.check_lss_reach(reach, command.name())?;
        }
        if !force
            && let LssCommand::ConfigureNodeId(id) = command
            && let Ok(node) = NodeId::new(u32::from(id))
        {
            // The device in the configuration state is not known here.
            self.check_node_id_free(node, None)?;
        }
        let session = self.lss_session(command.name())?;
        session.run(command, timeout).await
    }

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
    /// Refused when the id is in use ([`CanopenBus::check_node_id_free`])
    /// unless `force`, and when the device is an active axis's drive.
    pub async fn assign_node_id(
        &self,
        target: LssTarget,
        node: NodeId,
        store: bool,
        force: bool,
        timeout: Duration,
    ) -> Result<Assigned, CanopenError> {
        if !force {
            // What needs no identity is refused before anything is sent.
            self.bus.check_node_id_unused(node)?;
        }
        let identity = match target {
            LssTarget::Identity(id) => {
                self.bus
                    .check_lss_reach(LssReach::Identity(id), "assign node-ID")?;
                id
            }
            LssTarget::Serial(serial) => self.find_serial(serial).await?,
        };
        if !force && let Err(e) = self.bus.check_node_id_meant_for(node, Some(identity)) {
            // The scan may have left devices in the configuration state.
            self.run(LssCommand::SwitchGlobal(LssMode::Waiting), timeout)
                .await?;
            return Err(e);
        }
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

    /// The identity of the unconfigured device with `serial`, by fastscans
    /// of one device each: a device found (and not the one) stays in the
    /// configuration state and out of the next search, until a search
    /// finds nothing more, or finds again a device found before (one that
    /// answers fastscan until it has a node-ID, as CANopenNode's does,
    /// hides the devices above it). The device found is left in the
    /// configuration state; every device is back in waiting when it is not
    /// found.
    async fn find_serial(&self, serial: u32) -> Result<LssIdentity, CanopenError> {
        let step = ASSIGN_STEP.max(self.bus.min_fastscan_step());
        let mut found: Vec<LssIdentity> = Vec::new();
        let mut repeated = None;
        for _ in 0..MAX_SEARCHES {
            let scan = LssCommand::Fastscan {
                step_time: step,
                max_nodes: 1,
            };
            let ids = match self.run(scan, step).await {
                Ok(LssOutcome::Found(ids)) => ids,
                Ok(other) => return Err(unexpected("fastscan", other)),
                Err(e) => {
                    self.run(LssCommand::SwitchGlobal(LssMode::Waiting), step)
                        .await?;
                    return Err(e);
                }
            };
            let Some(id) = ids.first().copied() else {
                break;
            };
            if id.serial == serial {
                return Ok(id);
            }
            if found.contains(&id) {
                repeated = Some(id);
                break;
            }
            found.push(id);
        }
        self.run(LssCommand::SwitchGlobal(LssMode::Waiting), step)
            .await?;
        let mut text = if found.is_empty() {
            "no unconfigured device".to_string()
        } else {
            found
                .iter()
                .map(|i| format!("serial 0x{:08X}", i.serial))
                .collect::<Vec<_>>()
                .join(", ")
        };
        if let Some(id) = repeated {
            text.push_str(&format!(
                "; serial 0x{:08X} keeps answering fastscan until it has a node-ID and hides \
                 the devices above it: give it its id first",
                id.serial
            ));
        }
        Err(CanopenError::LssDeviceNotFound {
            bus: self.bus.bus.clone(),
            serial,
            found: text,
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
