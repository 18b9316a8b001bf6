//! Arming touch probe 1 of a CiA 402 axis: the touch probe function
//! (0x60B8) written by SDO under the axis's lease. The probe's status and
//! latched positions come with the process data (TPDO3, TPDO4; see
//! [`cangate_axis::process_data::with_signal_tpdos`]) and the axis turns
//! each latch into an event ([`cangate_axis::AxisEvent::TouchProbe`]).
//! SDO, not PDO: arming is rare, and a confirmed write answers the caller
//! with the drive's word that it took it.

use super::{Axes, AxisError, Caller, CommandResult};
use cangate_axis::signals::{ProbeEdges, touch_probe_function};
use cangate_axis::{CommandError, DriveSpec, Outcome};
use cangate_canopen::cia402::{objects as obj, on_axis};
use cangate_canopen::master::SdoRequest;
use cangate_canopen::sdo::TransferOptions;

impl Axes {
    /// Arms touch probe 1 of axis `i` for `edges` (first event only, or
    /// `continuous`), or switches it off ([`ProbeEdges::Off`]); returns
    /// once the drive confirmed the write.
    ///
    /// # Errors
    /// [`AxisError::Lease`] without control of the axis;
    /// [`AxisError::Refused`] for a CANsmc axis, a drive whose process data
    /// carries no touch probe status, a lost node or one not heard yet;
    /// [`AxisError::Sdo`] when the write failed.
    pub async fn arm_touch_probe(
        &self,
        i: usize,
        edges: ProbeEdges,
        continuous: bool,
        caller: &Caller,
    ) -> Result<CommandResult, AxisError> {
        if self.closing() {
            return Err(AxisError::ShuttingDown);
        }
        let name = self.name(i).to_string();
        if !caller.lease.is_empty() {
            self.check_lease_owner(&caller.lease, caller.identity.as_deref())?;
        }
        let holder = self.authorize(i, &caller.lease)?;
        let entry = &self.axes[i];
        let (DriveSpec::Cia402(drive), Some((master, _))) = (&entry.spec.drive, &entry.cyclic)
        else {
            return Err(CommandError::DriveUnavailable(format!(
                "axis {name} is no CiA 402 axis: it has no touch probe"
            ))
            .into());
        };
        let carried = master.tpdos(drive.node).iter().any(|p| {
            p.mapping
                .iter()
                .any(|m| m.addr == on_axis(obj::TOUCH_PROBE_STATUS, drive.drive_axis))
        });
        if !carried {
            return Err(CommandError::DriveUnavailable(format!(
                "axis {name}: the drive's process data carries no touch probe status (0x60B9): \
                 its EDS has no 0x60B9 or no TPDO3, or its process data goes by SDO; a latch \
                 would never be seen"
            ))
            .into());
        }
        let Some((snapshot, _)) = self.latest(i) else {
            return Err(CommandError::DriveUnavailable(format!(
                "axis {name}: no process data from the drive yet"
            ))
            .into());
        };
        if let Some(reason) = &snapshot.node_lost {
            return Err(CommandError::DriveUnavailable(format!(
                "axis {name}: the drive's node is lost ({reason})"
            ))
            .into());
        }
        let function = touch_probe_function(edges, continuous);
        let req = SdoRequest::Download {
            addr: on_axis(obj::TOUCH_PROBE_FUNCTION, drive.drive_axis),
            data: function.to_le_bytes().to_vec(),
            opts: TransferOptions::default(),
        };
        let result = master
            .client_sdo(drive.node, req, &caller.name)
            .await
            .map_err(|error| AxisError::Sdo {
                node: drive.node,
                error,
            });
        let detail = match edges {
            ProbeEdges::Off => format!("touch probe 1 switched off (0x60B8 = 0x{function:04X})"),
            _ => format!(
                "touch probe 1 armed on the {} edge{}, {} (0x60B8 = 0x{function:04X})",
                match edges {
                    ProbeEdges::Rising => "rising",
                    ProbeEdges::Falling => "falling",
                    _ => "rising and falling",
                },
                if edges == ProbeEdges::Both { "s" } else { "" },
                if continuous {
                    "every event"
                } else {
                    "first event only"
                }
            ),
        };
        tracing::info!(
            target: "cangate::audit",
            peer = %caller.name,
            %holder,
            axis = %name,
            command = "arm touch probe",
            result = %match &result {
                Ok(_) => detail.clone(),
                Err(e) => format!("failed: {e}"),
            },
            "axis command"
        );
        result?;
        Ok(CommandResult {
            outcome: Some(Outcome::Completed),
            detail,
            snapshot,
        })
    }
}
