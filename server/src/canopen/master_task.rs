//! The master task of one bus: it owns the sans-IO [`Master`], feeds it the
//! frames it subscribed to and its ticks, sends what it asks, answers the
//! commands of the [`CanopenBus`] handle, and publishes node events and
//! PDOs.

use super::*;
use cangate_can::ArrivalClock;

struct Pending {
    reply: oneshot::Sender<Result<TransferOutcome, SdoError>>,
}

/// Everything the master task owns.
pub(super) struct MasterTask {
    pub(super) master: Master,
    pub(super) bus: BusHandle,
    pub(super) sub: cangate_can::Subscription,
    pub(super) commands: mpsc::Receiver<Command>,
    pub(super) events: broadcast::Sender<NodeEvent>,
    /// The TPDOs the master counts and publishes (not a `CanopenBus`: its
    /// command sender would keep the task's own command queue open).
    pub(super) tpdos: TpdoRoutes,
    pub(super) pdos: broadcast::Sender<PdoUpdate>,
    pub(super) facts: Arc<RwLock<BTreeMap<NodeId, NodeFacts>>>,
    pub(super) handover: handover::Handover,
    /// Notes every node's frames (see [`heard`]).
    pub(super) heard: Arc<heard::HeardNodes>,
    pub(super) cancel: CancellationToken,
}

/// What the master task subscribes to: what the sans-IO master reads (EMCY,
/// SDO responses, heartbeats; not the SYNC, which it ignores) and the
/// configured TPDOs no axis task reads itself. Leaving out the rest (SYNC,
/// RPDOs, the axes' TPDOs: nearly all of a cyclic bus's traffic) spares the
/// task a wake-up per frame batch.
pub(super) fn master_selector(configured: &BTreeMap<NodeId, NodeFacts>) -> FrameSelector {
    use cangate_canopen::ids::cob;
    let mut filters = Filter::standard_range(cob::EMCY + 1, cob::EMCY + 0x7F);
    filters.extend(Filter::standard_range(cob::SDO_TX + 1, cob::SDO_TX + 0x7F));
    filters.extend(Filter::standard_range(
        cob::HEARTBEAT + 1,
        cob::HEARTBEAT + 0x7F,
    ));
    // LSS answers (CiA 305).
    filters.push(Filter::exact_standard(
        cangate_canopen::lss::LSS_RESPONSE_COB_ID,
    ));
    for f in configured.values().filter(|f| !f.tpdos_read_by_axis) {
        filters.extend(f.tpdos.iter().map(|p| Filter::exact_standard(p.cob_id)));
    }
    FrameSelector {
        filters,
        error_frames: false,
        transmitted: false,
    }
}

type LssReply =
    oneshot::Sender<Result<cangate_canopen::lss::LssOutcome, cangate_canopen::lss::LssError>>;

pub(super) async fn run_master(task: MasterTask) {
    let MasterTask {
        mut master,
        bus,
        mut sub,
        mut commands,
        events,
        tpdos,
        pdos,
        facts,
        handover,
        heard,
        cancel,
    } = task;
    let origin = Instant::now();
    let origin_wall = Timestamp::now();
    let mut clock = ArrivalClock::default();
    let mut pending: HashMap<RequestId, Pending> = HashMap::new();
    let mut lss_pending: HashMap<RequestId, LssReply> = HashMap::new();
    let mut confirm_pending: HashMap<RequestId, oneshot::Sender<Option<NmtState>>> = HashMap::new();
    let mut next_id: RequestId = 1;
    let mut items = Vec::with_capacity(256);
    let mut gc = tokio::time::interval(Duration::from_millis(100));
    gc.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let far = Duration::from_secs(3600);
    // One cancellation future for the whole loop: a fresh one per turn
    // registers with and unregisters from the token's waiter list at every
    // wake-up of this hot task.
    let cancelled = cancel.cancelled();
    tokio::pin!(cancelled);
    // Requests the interface gave up end their transfers at once (see
    // `Master::on_unsent`).
    let mut unsent = bus.subscribe_unsent();
    loop {
        let mut out = Output::default();
        // The clock only when nothing is due (a clock read is a system
        // call on some hosts, and this runs at every wake-up).
        let deadline = origin
            + master
                .next_deadline()
                .unwrap_or_else(|| origin.elapsed() + far);
        tokio::select! {
            biased;
            _ = &mut cancelled => break,
            n = sub.recv_many(&mut items, 256) => {
                if n == 0 {
                    break;
                }
                let now = origin.elapsed();
                let wall_now = Timestamp::now();
                for item in items.drain(..) {
                    match item {
                        BusItem::Frame { frame, .. } => {
                            heard.record(frame.raw_id(), frame.is_extended());
                            // When it arrived, not when this task got to it:
                            // a held-up gateway must not judge a node's
                            // heartbeat late for its own delay.
                            let at = clock.frame_time(now, &frame, wall_now);
                            master.on_frame(&frame, at, &mut out);
                            relay_tpdo(&tpdos, &pdos, &frame);
                        }
                        BusItem::Lost(n) => tracing::warn!(lost = n, "CANopen master missed frames (overloaded)"),
                        BusItem::State(_) => {}
                    }
                }
            }
            given_up = unsent.recv() => match given_up {
                Ok(frame) => master.on_unsent(&frame, clock.time(origin.elapsed()), &mut out),
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    // Those transfers end at their own timeouts instead.
                    tracing::warn!(frames = n, "CANopen master missed notices of frames the interface gave up");
                }
                // Only with the bus, which `bus` holds.
                Err(broadcast::error::RecvError::Closed) => break,
            },
            cmd = commands.recv() => {
                let Some(cmd) = cmd else { break };
                let now = clock.time(origin.elapsed());
                match cmd {
                    Command::Sdo { node, priority, req, reply, spins } => {
                        if spins {
                            handover.spinning_caller_arrived();
                        }
                        let id = next_id;
                        next_id += 1;
                        pending.insert(id, Pending { reply });
                        master.sdo_as(id, node, priority, req, now, &mut out);
                    }
                    Command::Nmt { cmd, target, reply } => {
                        let r = bus.send(vec![nmt_frame(cmd, target)]).await;
                        let _ = reply.send(r);
                    }
                    Command::Transfers { reply } => {
                        let _ = reply.send(master.transfers());
                    }
                    Command::Snapshot { reply } => {
                        let _ = reply.send(snapshot(&master, &facts, origin_wall, now));
                    }
                    Command::ConfirmState { node, start, probe, timeout, reply } => {
                        let id = next_id;
                        next_id += 1;
                        confirm_pending.insert(id, reply);
                        if start {
                            // Ahead of the probe, in one batch, the
                            // confirmation already waiting: a node that
                            // tells its new state at once is heard.
                            out.frames.push(nmt_frame(NmtCommand::Start, Some(node)));
                        }
                        master.confirm_state(id, node, probe, timeout, now, &mut out);
                    }
                    Command::Lss { command, timeout, reply } => {
                        let id = next_id;
                        next_id += 1;
                        lss_pending.insert(id, reply);
                        master.lss(id, command, timeout, now, &mut out);
                    }
                }
            }
            _ = tokio::time::sleep_until(deadline.into()) => {
                master.on_tick(clock.time(origin.elapsed()), &mut out);
            }
            _ = gc.tick() => {
                // Callers that gave up (client cancelled, deadline) free
                // their node's SDO channel for the next request.
                let gone: Vec<RequestId> = pending
                    .iter()
                    .filter(|(_, p)| p.reply.is_closed())
                    .map(|(id, _)| *id)
                    .collect();
                for id in gone {
                    pending.remove(&id);
                    master.cancel(id, clock.time(origin.elapsed()), &mut out);
                }
                lss_pending.retain(|id, reply| {
                    let open = !reply.is_closed();
                    if !open {
                        master.lss_cancel(*id);
                    }
                    open
                });
                confirm_pending.retain(|id, reply| {
                    let open = !reply.is_closed();
                    if !open {
                        master.confirm_cancel(*id);
                    }
                    open
                });
            }
        }
        if !out.frames.is_empty()
            && let Err(e) = submit_master_frames(&bus, std::mem::take(&mut out.frames)).await
        {
            tracing::warn!(error = %e, "CANopen master could not send");
        }
        for ev in out.events {
            count_event(bus.name(), &ev);
            if let MasterEvent::LssCompleted { id, result } = ev {
                if let Some(reply) = lss_pending.remove(&id) {
                    let _ = reply.send(result);
                }
                continue;
            }
            if let MasterEvent::StateConfirmed { id, state, .. } = ev {
                if let Some(reply) = confirm_pending.remove(&id) {
                    let _ = reply.send(state);
                }
                continue;
            }
            handle_event(ev, &master, &mut pending, &events, &facts);
        }
    }
    tracing::info!("CANopen master stopped");
}

/// Sends the master's frames. Several SDO requests to one node in one
/// batch are an SDO block download's sub-block: bulk data, paced to the
/// bus's bulk share behind the gateway's own frames (see
/// [`cangate_can::budget`]), in their order; the rest goes at once.
async fn submit_master_frames(
    bus: &BusHandle,
    frames: Vec<cangate_can::Frame>,
) -> Result<(), cangate_can::SendFailure> {
    use cangate_canopen::ids::cob;
    let sdo_request = |f: &cangate_can::Frame| {
        !f.is_extended() && (cob::SDO_RX + 1..=cob::SDO_RX + 0x7F).contains(&(f.raw_id() as u16))
    };
    let repeated = |f: &cangate_can::Frame| frames.iter().filter(|o| o.id() == f.id()).count() > 1;
    let (bulk, own): (Vec<_>, Vec<_>) = frames
        .iter()
        .copied()
        .partition(|f| sdo_request(f) && repeated(f));
    if !own.is_empty() {
        bus.submit(own).await?;
    }
    if !bulk.is_empty() {
        bus.submit_as(cangate_can::TxClass::Bulk, bulk).await?;
    }
    Ok(())
}

/// See [`CanopenBus::relay_tpdo`].
pub(super) fn relay_tpdo(
    routes: &RwLock<HashMap<u16, TpdoRoute>>,
    pdos: &broadcast::Sender<PdoUpdate>,
    frame: &cangate_can::Frame,
) {
    if frame.is_extended() {
        return;
    }
    let routes = routes.read().expect("TPDO routes lock");
    let Some(route) = routes.get(&(frame.raw_id() as u16)) else {
        return;
    };
    route.count.fetch_add(1, Ordering::Relaxed);
    *route.last.lock().unwrap_or_else(|p| p.into_inner()) = Some(*frame);
    if pdos.receiver_count() > 0 {
        publish_pdo(pdos, route.node, &route.cfg, route.eds.as_deref(), frame);
    }
}

fn publish_pdo(
    pdos: &broadcast::Sender<PdoUpdate>,
    node: NodeId,
    cfg: &PdoConfig,
    eds: Option<&Eds>,
    frame: &cangate_can::Frame,
) {
    let od = eds.map(|e| &e.od);
    match cfg.decode(od, frame.data()) {
        Ok(values) => {
            let values = values
                .into_iter()
                .map(|(m, v)| {
                    let name = od
                        .and_then(|od| od.get(m.addr))
                        .map(|v| v.name.clone())
                        .unwrap_or_default();
                    (m, v, name)
                })
                .collect();
            let _ = pdos.send(PdoUpdate {
                node,
                kind: cfg.kind,
                num: cfg.num,
                cob_id: cfg.cob_id,
                at: frame.timestamp(),
                values,
            });
        }
        Err(e) => tracing::debug!(node = node.get(), pdo = cfg.num, error = %e, "undecodable TPDO"),
    }
}

/// The event counters of the Prometheus endpoint.
fn count_event(bus: &str, ev: &MasterEvent) {
    match ev {
        MasterEvent::Heartbeat(HeartbeatEvent::HeartbeatLost { node, .. })
        | MasterEvent::Guarding(GuardingEvent::Lost { node, .. }) => {
            metrics::counter!("cangate_heartbeat_lost_total", "bus" => bus.to_string(), "node" => node.get().to_string())
                .increment(1);
        }
        MasterEvent::Emcy(EmcyEvent::Error(e)) => {
            metrics::counter!("cangate_emcy_total", "bus" => bus.to_string(), "node" => e.node.get().to_string())
                .increment(1);
        }
        MasterEvent::SdoResponseIgnored { node } => {
            metrics::counter!("cangate_sdo_responses_ignored_total", "bus" => bus.to_string(), "node" => node.get().to_string())
                .increment(1);
        }
        _ => {}
    }
}

fn handle_event(
    ev: MasterEvent,
    master: &Master,
    pending: &mut HashMap<RequestId, Pending>,
    events: &broadcast::Sender<NodeEvent>,
    facts: &RwLock<BTreeMap<NodeId, NodeFacts>>,
) {
    let (node, kind) = match ev {
        MasterEvent::SdoCompleted { id, result, .. } => {
            if let Some(p) = pending.remove(&id) {
                let _ = p.reply.send(result);
            }
            return;
        }
        MasterEvent::SdoRejected { id, error } => {
            // Dropping the reply tells the caller the request failed.
            pending.remove(&id);
            tracing::warn!(%error, "SDO request rejected");
            return;
        }
        MasterEvent::LssCompleted { .. } | MasterEvent::StateConfirmed { .. } => return,
        MasterEvent::SdoResponseIgnored { node } => {
            tracing::debug!(
                node = node.get(),
                "SDO response dropped: a late answer to an aborted transfer, or unsolicited"
            );
            return;
        }
        MasterEvent::Heartbeat(hb) => match hb {
            HeartbeatEvent::BootUp { node } => (node, NodeEventKind::BootUp),
            HeartbeatEvent::StateChanged { node, from, to } => {
                (node, NodeEventKind::StateChanged { from, to })
            }
            HeartbeatEvent::HeartbeatLost { node, timeout, .. } => {
                tracing::warn!(node = node.get(), ?timeout, "heartbeat lost");
                (
                    node,
                    NodeEventKind::HeartbeatLost {
                        timeout,
                        guarding: false,
                    },
                )
            }
            HeartbeatEvent::HeartbeatRecovered { node, state, after } => {
                tracing::info!(node = node.get(), ?after, "heartbeat recovered");
                (
                    node,
                    NodeEventKind::HeartbeatRecovered {
                        state,
                        after,
                        guarding: false,
                    },
                )
            }
            HeartbeatEvent::Malformed { node, .. } => {
                tracing::debug!(node = node.get(), "malformed heartbeat");
                return;
            }
        },
        MasterEvent::Guarding(g) => match g {
            GuardingEvent::BootUp { node } => (node, NodeEventKind::BootUp),
            GuardingEvent::StateChanged { node, from, to } => {
                (node, NodeEventKind::StateChanged { from, to })
            }
            GuardingEvent::Lost {
                node, life_time, ..
            } => {
                tracing::warn!(node = node.get(), ?life_time, "node guarding lost");
                (
                    node,
                    NodeEventKind::HeartbeatLost {
                        timeout: life_time,
                        guarding: true,
                    },
                )
            }
            GuardingEvent::Recovered { node, state, after } => {
                tracing::info!(node = node.get(), ?after, "node guarding recovered");
                (
                    node,
                    NodeEventKind::HeartbeatRecovered {
                        state,
                        after,
                        guarding: true,
                    },
                )
            }
            GuardingEvent::ToggleError {
                node,
                expected,
                data,
            } => {
                tracing::warn!(
                    node = node.get(),
                    expected,
                    data,
                    "node guarding toggle error"
                );
                (
                    node,
                    NodeEventKind::GuardingToggleError {
                        data,
                        expected,
                        count: master
                            .guarding()
                            .status(node)
                            .map_or(0, |s| s.toggle_errors),
                    },
                )
            }
            GuardingEvent::Malformed { node, .. } => {
                tracing::debug!(node = node.get(), "malformed node guarding answer");
                return;
            }
        },
        MasterEvent::Emcy(e) => match e {
            EmcyEvent::Error(emcy) | EmcyEvent::Reset { emcy, .. } => {
                tracing::warn!(
                    node = emcy.node.get(),
                    code = format!("0x{:04X}", emcy.code),
                    name = emcy.code_name(),
                    "EMCY"
                );
                (emcy.node, NodeEventKind::Emcy(emcy))
            }
            EmcyEvent::Malformed { .. } => return,
        },
    };
    facts.write().expect("facts lock").entry(node).or_default();
    // Stamped here, not for every event: an SDO answer (most events)
    // needs no wall-clock read.
    let at = Timestamp::now();
    let _ = events.send(NodeEvent { node, at, kind });
}

fn snapshot(
    master: &Master,
    facts: &RwLock<BTreeMap<NodeId, NodeFacts>>,
    origin_wall: Timestamp,
    now: Duration,
) -> Vec<NodeSnapshot> {
    // The master keeps monotonic times since `origin`; clients get wall time.
    let wall = |at: Duration| Timestamp(origin_wall.as_nanos() + at.as_nanos() as u64);
    let facts = facts.read().expect("facts lock");
    facts
        .iter()
        .map(|(&id, f)| {
            let hb = master.heartbeat().status(id);
            let guard = master.guarding().status(id);
            let emcy = master.emcy().node(id);
            let history: Vec<(Emcy, Timestamp)> = emcy
                .map(|e| e.history.iter().map(|r| (r.emcy, wall(r.at))).collect())
                .unwrap_or_default();
            let active = emcy.and_then(|e| e.active).map(|a| {
                let t = history
                    .iter()
                    .rev()
                    .find(|(h, _)| *h == a)
                    .map(|(_, t)| *t)
                    .unwrap_or_default();
                (a, t)
            });
            NodeSnapshot {
                id,
                facts: f.clone(),
                state: match guard {
                    Some(g) => g.state,
                    None => hb.and_then(|s| s.state),
                }
                .or(f.boot_state),
                heartbeat_age: match guard {
                    Some(g) => g.age(now),
                    None => hb.and_then(|s| s.age(now)),
                },
                heartbeat_lost: match guard {
                    Some(g) => g.lost,
                    None => hb.is_some_and(|s| s.lost),
                },
                guarding_toggle_errors: guard.map(|g| g.toggle_errors).unwrap_or(0),
                boot_ups: match guard {
                    Some(g) => g.boot_ups,
                    None => hb.map(|s| s.boot_ups).unwrap_or(0),
                },
                active_error: active,
                emcy_history: history,
            }
        })
        .collect()
}
