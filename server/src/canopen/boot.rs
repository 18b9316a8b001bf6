//! The boot procedure (CiA 302) of a bus's configured nodes: checked,
//! configured where they differ, started; again at every boot-up, and for
//! a node that was not there, when it is heard or at the next retry.

use super::*;
use std::collections::BTreeSet;

/// How often a configured node that did not answer its first boot read is
/// tried again (CiA 302 retries absent slaves): a node that is switched
/// on or plugged in sends a boot-up and is booted at once, but one on a
/// segment that was disconnected, or one that was already running and
/// only now reachable, sends none. One SDO read per absent node and period.
pub(super) const ABSENT_NODE_RETRY: Duration = Duration::from_secs(2);

/// Runs the boot procedure (CiA 302) of configured nodes: at the start of
/// the master for every one of them, whether or not it sends a boot-up (a
/// node running before the gateway started is adopted: checked, its
/// configuration written where it differs, started, without a reset), and
/// again whenever one boots up. A node that did not answer is adopted the
/// same way as soon as it is heard (a heartbeat, a state), else tried again
/// every [`ABSENT_NODE_RETRY`]. One boot per node at a time: a boot-up
/// during a boot starts it afresh (the node lost what was written).
pub(super) async fn run_boot_supervisor(
    master: CanopenBus,
    mut events: broadcast::Receiver<NodeEvent>,
    plans: Vec<(NodeId, Arc<BootPlan>)>,
    cancel: CancellationToken,
) {
    let mut running: HashMap<NodeId, tokio::task::AbortHandle> = HashMap::new();
    // Nodes whose last boot found nothing there, told by the boot tasks.
    let mut absent: BTreeSet<NodeId> = BTreeSet::new();
    let (absent_tx, mut absent_rx) = mpsc::unbounded_channel::<(NodeId, bool)>();
    let mut retry = tokio::time::interval(ABSENT_NODE_RETRY);
    retry.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    retry.reset();
    let start = |running: &mut HashMap<NodeId, tokio::task::AbortHandle>,
                 node: NodeId,
                 plan: Arc<BootPlan>,
                 adopt: bool| {
        if let Some(previous) = running.remove(&node) {
            previous.abort();
        }
        let m = master.clone();
        let absent_tx = absent_tx.clone();
        let span = tracing::info_span!("node", node = node.get());
        let task = tokio::spawn(async move {
            let result = boot_node(&m, node, &plan, adopt).await;
            let _ = absent_tx.send((node, matches!(result, Ok(BootResult::Absent))));
            match result {
                Ok(BootResult::Started { confirmed }) => {
                    match confirmed {
                        Some(state) => {
                            tracing::info!(adopt, %state, "node booted and started")
                        }
                        None => {
                            tracing::warn!(adopt, "node booted and NMT start sent; it reported no state to confirm it started")
                        }
                    }
                    m.emit(node, NodeEventKind::BootCompleted { adopted: adopt });
                }
                Ok(BootResult::Absent) => {
                    tracing::info!(
                        "node does not answer; it is booted when it boots up or is heard, and tried again every {} s",
                        ABSENT_NODE_RETRY.as_secs()
                    );
                }
                Ok(BootResult::Rebooted) => {}
                Ok(BootResult::Identified) => tracing::debug!("node identified"),
                Err(reason) => {
                    tracing::warn!(%reason, "boot procedure failed");
                    m.emit(node, NodeEventKind::BootFailed { reason });
                }
            }
        }
        .instrument(span));
        running.insert(node, task.abort_handle());
    };
    for (node, plan) in &plans {
        start(&mut running, *node, plan.clone(), true);
    }
    let plan_of = |node: NodeId| {
        plans
            .iter()
            .find(|(n, _)| *n == node)
            .map(|(_, p)| p.clone())
    };
    loop {
        let ev = tokio::select! {
            _ = cancel.cancelled() => break,
            ev = events.recv() => ev,
            Some((node, is_absent)) = absent_rx.recv() => {
                if is_absent {
                    absent.insert(node);
                } else {
                    absent.remove(&node);
                }
                continue;
            }
            _ = retry.tick() => {
                for node in std::mem::take(&mut absent) {
                    if let Some(plan) = plan_of(node) {
                        start(&mut running, node, plan, true);
                    }
                }
                continue;
            }
        };
        let ev = match ev {
            Ok(ev) => ev,
            Err(broadcast::error::RecvError::Lagged(n)) => {
                // A boot-up among them would leave its node unconfigured
                // and not started: say so (an NMT reset of the node, or of
                // all, runs the procedure again).
                tracing::warn!(
                    missed = n,
                    "boot supervisor missed node events; a node that booted meanwhile may need an NMT reset"
                );
                continue;
            }
            Err(broadcast::error::RecvError::Closed) => break,
        };
        let adopt = match ev.kind {
            NodeEventKind::BootUp => false,
            // Heard without a boot-up: it is there now, and running.
            NodeEventKind::StateChanged { .. } | NodeEventKind::HeartbeatRecovered { .. }
                if absent.remove(&ev.node) =>
            {
                true
            }
            _ => continue,
        };
        let Some(plan) = plan_of(ev.node) else {
            continue;
        };
        start(&mut running, ev.node, plan, adopt);
    }
    for (_, task) in running {
        task.abort();
    }
}

/// How a boot procedure ended, when it did not fail.
enum BootResult {
    /// Checked, configured and NMT start sent; what the node reported
    /// after (`None`: nothing; a refusal to start is a failure).
    Started { confirmed: Option<NmtState> },
    /// The node did not answer its first read: nothing there yet (it is
    /// booted when it boots up).
    Absent,
    /// It booted up during the procedure (a fresh one runs).
    Rebooted,
    /// A node without a boot plan: its device type and identity read.
    Identified,
}

/// The consecutive boot writes of one PDO (its communication and mapping
/// parameters), compared and written as a whole; every other write stands
/// alone.
fn write_groups(writes: &[(ObjectAddress, Vec<u8>)]) -> Vec<&[(ObjectAddress, Vec<u8>)]> {
    // (direction, PDO number) of a PDO parameter index.
    let pdo = |index: u16| match index {
        0x1400..=0x15FF => Some((0, index - 0x1400)),
        0x1600..=0x17FF => Some((0, index - 0x1600)),
        0x1800..=0x19FF => Some((1, index - 0x1800)),
        0x1A00..=0x1BFF => Some((1, index - 0x1A00)),
        _ => None,
    };
    let mut groups = Vec::new();
    let mut start = 0;
    for i in 1..=writes.len() {
        let same = i < writes.len()
            && pdo(writes[i].0.index).is_some()
            && pdo(writes[i].0.index) == pdo(writes[start].0.index);
        if !same {
            groups.push(&writes[start..i]);
            start = i;
        }
    }
    groups
}

/// The value a node answered equals the one to write: the same bytes, an
/// expedited answer without a size padded with zeros.
fn same_value(got: &[u8], want: &[u8]) -> bool {
    got.len() >= want.len()
        && got[..want.len()] == *want
        && got[want.len()..].iter().all(|&b| b == 0)
}

/// The drive supports the modes its axis is configured in (`required`,
/// bits of 0x6502): a drive that says it lacks one fails its boot, naming
/// the mode and what it has. A drive that cannot tell (no 0x6502) is taken
/// at its word that the configuration fits; a mode it lacks then shows as
/// a mode switch that times out.
fn check_supported_modes(
    node: NodeId,
    required: u32,
    read: Result<u32, (bool, String)>,
) -> Result<(), String> {
    use cangate_canopen::cia402::ModeOfOperation;
    let got = match read {
        Ok(v) => v,
        Err((_, e)) => {
            tracing::warn!(node = node.get(), error = %e, "0x6502 supported drive modes not readable: the axis's mode is not checked");
            return Ok(());
        }
    };
    if got & required == required {
        return Ok(());
    }
    let names = |mask: u32| {
        ModeOfOperation::supported(mask)
            .map(|m| m.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    Err(format!(
        "the drive does not support the axis's mode {} (0x6502 supported drive modes is \
         0x{got:08X}: {}); configure its axis with a mode it has",
        names(required & !got),
        names(got)
    ))
}

async fn boot_node(
    m: &CanopenBus,
    node: NodeId,
    plan: &BootPlan,
    adopt: bool,
) -> Result<BootResult, String> {
    let opts = cangate_canopen::sdo::TransferOptions::default();
    let read = |addr: ObjectAddress| async move {
        match m.sdo(node, SdoRequest::Upload { addr, opts }).await {
            Ok(TransferOutcome::Uploaded(b)) => Ok(b),
            Ok(_) => Err((false, format!("reading {addr}: no data"))),
            Err(e) => {
                let timeout = matches!(
                    e,
                    CanopenError::Sdo(SdoError::Timeout { .. } | SdoError::NotSent { .. })
                );
                Err((timeout, format!("reading {addr}: {e}")))
            }
        }
    };
    let read_u32 = |index: u16, sub: u8| async move {
        let addr = ObjectAddress::new(index, sub);
        match read(addr).await? {
            b if b.len() == 4 => Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            _ => Err((false, format!("reading {addr}: not a 32-bit value"))),
        }
    };
    let mismatch = |what: &str, index: u16, sub: u8, got: u32, want: u32| {
        format!("{what} mismatch: 0x{index:04X}:{sub:02X} is 0x{got:08X}, configured 0x{want:08X}")
    };
    // The device type and identity are read whether or not they are
    // checked, so that GetNode shows them after every boot (0x1000 and
    // 0x1018:01 are mandatory; the other identity entries read as 0 where
    // the node lacks them).
    let device_type = read_u32(0x1000, 0).await;
    if let Ok(v) = device_type {
        m.learn(node, |f| f.device_type = Some(v));
    }
    let silent = matches!(device_type, Err((true, _)));
    if silent && (adopt || plan.identify_only) {
        // Found nothing at the gateway's start: the node is off or still
        // initialising; its boot-up brings it here again.
        return Ok(BootResult::Absent);
    }
    let mut identity = None;
    if !silent {
        let mut read = [0u32; 4];
        let mut vendor_read = false;
        for sub in 1..=4u8 {
            match read_u32(0x1018, sub).await {
                Ok(v) => {
                    read[usize::from(sub - 1)] = v;
                    vendor_read |= sub == 1;
                }
                Err(_) if sub == 1 => break,
                Err(_) => {}
            }
        }
        if vendor_read {
            identity = Some(read);
            m.learn(node, |f| f.identity = Some(read));
        }
    }
    if plan.identify_only {
        return Ok(BootResult::Identified);
    }
    if let Some(want) = plan.device_type {
        let got = device_type.map_err(|(_, e)| e)?;
        if got != want {
            return Err(mismatch("device type", 0x1000, 0, got, want));
        }
    }
    let identity_checks = [
        (1u8, plan.vendor_id, "vendor id"),
        (2u8, plan.product_code, "product code"),
    ];
    for (sub, expected, what) in identity_checks {
        if let Some(want) = expected {
            // Read again for the error message when the first read failed.
            let got = match identity {
                Some(id) if sub == 1 || id[usize::from(sub - 1)] != 0 => id[usize::from(sub - 1)],
                _ => read_u32(0x1018, sub).await.map_err(|(_, e)| e)?,
            };
            if got != want {
                return Err(mismatch(what, 0x1018, sub, got, want));
            }
        }
    }
    for &(drive_axis, required) in &plan.required_modes {
        let index = cangate_canopen::cia402::profile_index(0x6502, drive_axis);
        let supported = read_u32(index, 0).await;
        if let Ok(v) = supported {
            // The axis refuses a run-time change to a mode not in it.
            m.learn(node, |f| {
                f.supported_drive_modes[usize::from(drive_axis)] = Some(v);
            });
        }
        check_supported_modes(node, required, supported)?;
    }
    for group in write_groups(&plan.writes) {
        if adopt {
            // A running node is not reconfigured where it already holds the
            // configuration (a PDO rewritten is invalid meanwhile): the
            // final value of each object the group writes is compared.
            let mut finals: Vec<(ObjectAddress, &[u8])> = Vec::new();
            for (addr, data) in group {
                finals.retain(|(a, _)| a != addr);
                finals.push((*addr, data));
            }
            let mut holds = true;
            for (addr, want) in finals {
                holds = matches!(read(addr).await, Ok(got) if same_value(&got, want));
                if !holds {
                    break;
                }
            }
            if holds {
                continue;
            }
        }
        for (addr, data) in group {
            m.sdo(
                node,
                SdoRequest::Download {
                    addr: *addr,
                    data: data.clone(),
                    opts,
                },
            )
            .await
            .map_err(|e| format!("writing {addr}: {e}"))?;
        }
    }
    // How the node's state after the start is learnt: its heartbeat, its
    // guarding answers, else one node guarding request (unless that would
    // start its life guarding).
    let (guarded, monitored) = {
        let facts = m.facts.read().expect("facts lock");
        let f = facts.get(&node);
        (
            f.and_then(|f| f.guarding),
            f.and_then(|f| f.heartbeat_timeout),
        )
    };
    let slack = Duration::from_millis(200);
    let period = match guarded {
        Some(_) => 0,
        None => match read(ObjectAddress::new(0x1017, 0)).await {
            Ok(b) if b.len() >= 2 => u64::from(u16::from_le_bytes([b[0], b[1]])),
            _ => 0,
        },
    };
    // A report sent before the node saw the start may still show the old
    // state: the wait spans two report periods.
    let (reports, probe, wait) = match guarded {
        Some((guard_time, _)) => (true, false, guard_time * 2 + slack),
        None if period > 0 => {
            let wait = Duration::from_millis(period) * 2 + slack;
            (true, false, monitored.map_or(wait, |t| t.max(wait)))
        }
        None => {
            let life_guarding = read_u32(0x100C, 0).await.is_ok_and(|v| v & 0xFFFF != 0)
                && matches!(
                    read(ObjectAddress::new(0x100D, 0)).await,
                    Ok(b) if b.first().is_some_and(|&f| f != 0)
                );
            (false, !life_guarding, m.sdo_timeout.max(slack))
        }
    };
    let state = m
        .confirm_state(node, true, probe, wait)
        .await
        .map_err(|e| format!("NMT start: {e}"))?;
    if !reports {
        // No heartbeat, not guarded: GetNode shows what the probe found,
        // else what was commanded.
        m.learn(node, |f| {
            f.boot_state = Some(state.unwrap_or(NmtState::Operational));
        });
    }
    match state {
        Some(NmtState::Initialising) => Ok(BootResult::Rebooted),
        Some(NmtState::Operational) | None => Ok(BootResult::Started { confirmed: state }),
        Some(other) => Err(format!(
            "NMT start sent, but the node still reports {other}: it did not start"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_drive_without_the_configured_mode_fails_its_boot_saying_why() {
        let node = NodeId::new(5).unwrap();
        let csp = 1 << 7;
        // PP, PV, HM, IP, CSV: no CSP.
        let e = check_supported_modes(node, csp, Ok(0x165)).unwrap_err();
        assert!(
            e.contains("does not support the axis's mode cyclic synchronous position")
                && e.contains("0x00000165"),
            "{e}"
        );
        assert!(check_supported_modes(node, csp, Ok(0x3ED)).is_ok());
        // A drive that cannot tell is taken at its word.
        assert!(check_supported_modes(node, csp, Err((false, "abort".into()))).is_ok());
    }
}
