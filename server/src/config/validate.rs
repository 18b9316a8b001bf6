//! The checks serde cannot make, across sections: unique names, references
//! between sections, sensible values.

use super::*;

impl Config {
    /// Checks what serde cannot: unique names, sensible values.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.security
            .validate()
            .map_err(|m| Section::Security.error(m))?;
        self.web.validate().map_err(|m| Section::Web.error(m))?;
        // A gateway that moves axes must not be reachable from the network
        // without authentication unless someone said so explicitly.
        if !self.listen.ip().is_loopback()
            && !self.security.insecure
            && !self.security.authentication()
        {
            return Err(ConfigError::Unauthenticated {
                listen: self.listen,
            });
        }
        let mut names = HashSet::new();
        let mut interfaces = HashSet::new();
        for b in &self.buses {
            if b.name.is_empty() {
                return Err(Section::Bus.error("a bus has an empty name".into()));
            }
            if !names.insert(b.name.as_str()) {
                return Err(ConfigError::Duplicate {
                    kind: "bus",
                    name: b.name.clone(),
                });
            }
            if b.backend == BackendChoice::Socketcan && !interfaces.insert(b.interface()) {
                return Err(bus_error(
                    b,
                    format!(
                        "SocketCAN interface {:?} is already used by another bus",
                        b.interface()
                    ),
                ));
            }
            if b.bitrate == Some(0) || b.data_bitrate == Some(0) {
                return Err(bus_error(b, "bitrate must be positive".into()));
            }
            if b.bit_timing && b.bitrate.is_none() {
                return Err(bus_error(b, "bit_timing needs a bitrate".into()));
            }
            b.fault_check().map_err(|m| Section::Bus.error(m))?;
            b.tx_shares().map_err(|m| Section::Bus.error(m))?;
            if b.backend == BackendChoice::Socketcan && (b.bit_timing || b.queue.is_some()) {
                return Err(bus_error(
                    b,
                    "bit_timing and queue apply to virtual buses only".into(),
                ));
            }
            if b.backend != BackendChoice::Socketcan
                && (b.receive_buffer.is_some()
                    || b.transmit_queue.is_some()
                    || b.transmit_timeout_ms.is_some())
            {
                return Err(bus_error(
                    b,
                    "receive_buffer, transmit_queue and transmit_timeout_ms apply to SocketCAN \
                     buses only"
                        .into(),
                ));
            }
            for (key, value, range) in [
                ("receive_buffer", b.receive_buffer, 1024..=64 << 20),
                ("transmit_queue", b.transmit_queue, 1..=65536),
                (
                    "transmit_timeout_ms",
                    b.transmit_timeout_ms.map(|v| v as usize),
                    1..=10_000,
                ),
            ] {
                if let Some(v) = value
                    && !range.contains(&v)
                {
                    return Err(bus_error(
                        b,
                        format!(
                            "{key} = {v} is out of range ({}..={})",
                            range.start(),
                            range.end()
                        ),
                    ));
                }
            }
        }
        let mut masters = HashSet::new();
        for c in &self.canopen {
            let Some(bus) = self.buses.iter().find(|b| b.name == c.bus) else {
                return Err(ConfigError::UnknownBus {
                    section: "[[canopen]]",
                    bus: c.bus.clone(),
                });
            };
            c.check().map_err(|m| Section::Canopen.error(m))?;
            if !masters.insert(c.bus.as_str()) {
                return Err(ConfigError::Bus {
                    bus: c.bus.clone(),
                    problem: "two [[canopen]] sections name it".into(),
                });
            }
            let mut ids = HashSet::new();
            for n in &c.nodes {
                let node_error = |problem: &str| ConfigError::Node {
                    bus: c.bus.clone(),
                    node: n.id,
                    problem: problem.to_string(),
                };
                if !(1..=127).contains(&n.id) {
                    return Err(node_error("the node id is out of range (1..=127)"));
                }
                n.guarding_check().map_err(|problem| ConfigError::Bus {
                    bus: c.bus.clone(),
                    problem,
                })?;
                if !ids.insert(n.id) {
                    return Err(node_error("configured twice"));
                }
                if n.simulate && bus.backend != BackendChoice::Virtual {
                    return Err(node_error("can only be simulated on a virtual bus"));
                }
                if n.sim_lss.is_some() && !n.simulate {
                    return Err(node_error(
                        "sim_lss describes a simulated device; add simulate = true",
                    ));
                }
                if let Some(sim) = &n.sim {
                    if !n.simulate {
                        return Err(node_error(
                            "sim describes a simulated device; add simulate = true",
                        ));
                    }
                    sim.check(n.id).map_err(|problem| ConfigError::Bus {
                        bus: c.bus.clone(),
                        problem,
                    })?;
                }
                if n.simulate && n.eds.is_none() && n.dcf.is_none() {
                    return Err(node_error("a simulated node needs an eds"));
                }
                let invalid = |problem: String| node_error(&problem);
                n.load_eds().map_err(invalid)?;
                let backs_axis = self.axes.iter().any(|a| a.bus == c.bus && a.node == n.id);
                if n.dcf.is_some() && !n.boot && !backs_axis {
                    return Err(invalid(
                        "dcf is applied by the boot procedure: set boot = true".into(),
                    ));
                }
                n.load_dcf().map_err(invalid)?;
                let node =
                    cangate_canopen::NodeId::new(n.id).map_err(|e| invalid(e.to_string()))?;
                for p in &n.tpdo {
                    p.to_pdo(cangate_canopen::pdo::PdoKind::Tpdo, node)
                        .map_err(invalid)?;
                }
                for p in &n.rpdo {
                    p.to_pdo(cangate_canopen::pdo::PdoKind::Rpdo, node)
                        .map_err(invalid)?;
                }
                for w in &n.writes {
                    parse_object(&w.object).map_err(invalid)?;
                    let ty: cangate_canopen::value::DataType =
                        w.ty.parse()
                            .map_err(|e| invalid(format!("write {}: {e}", w.object)))?;
                    cangate_canopen::value::Value::parse(ty, &w.value)
                        .map_err(|e| invalid(format!("write {}: {e}", w.object)))?;
                }
            }
        }
        let mut wheel_names = HashSet::new();
        for h in &self.handwheels {
            h.validate(self).map_err(|m| Section::Handwheel.error(m))?;
            if !wheel_names.insert(h.name.as_str()) {
                return Err(ConfigError::Duplicate {
                    kind: "handwheel",
                    name: h.name.clone(),
                });
            }
        }
        let mut axis_names = HashSet::new();
        let mut axis_nodes = std::collections::HashMap::new();
        for a in &self.axes {
            a.validate(self).map_err(|m| Section::Axis.error(m))?;
            if !axis_names.insert(a.name.as_str()) {
                return Err(ConfigError::Duplicate {
                    kind: "axis",
                    name: a.name.clone(),
                });
            }
            if let Some(other) = axis_nodes.insert((a.bus.as_str(), a.node, a.drive_axis), &a.name)
            {
                return Err(Section::Axis.error(format!(
                    "axis {}: drive_axis {} of node {} on bus {:?} already backs axis {other}; \
                     give each axis of a multi-axis drive its own drive_axis (0..=7)",
                    a.name, a.drive_axis, a.node, a.bus
                )));
            }
        }
        // The further axes of multi-axis drives take blocks of eight
        // COB-IDs from 0x680..=0x6DF (the predefined connection set has
        // none for them).
        let mut further: std::collections::HashMap<&str, u16> = Default::default();
        for a in self.axes.iter().filter(|a| a.drive_axis > 0) {
            let n = further.entry(a.bus.as_str()).or_default();
            *n += 1;
            if *n > cangate_axis::process_data::FURTHER_AXIS_BLOCKS {
                return Err(Section::Axis.error(format!(
                    "axis {}: more than {} axes with drive_axis above 0 on bus {:?}: their PDOs \
                     take eight COB-IDs each from 0x680..=0x6DF, and that range is full",
                    a.name,
                    cangate_axis::process_data::FURTHER_AXIS_BLOCKS,
                    a.bus
                )));
            }
        }
        if self.shutdown_timeout_ms == 0 || self.shutdown_timeout_ms > 600_000 {
            return Err(ConfigError::OutOfRange {
                key: "shutdown_timeout_ms",
                value: self.shutdown_timeout_ms,
                range: "between 1 and 600000",
            });
        }
        if self.handover_spin_us > 10_000 {
            return Err(ConfigError::OutOfRange {
                key: "handover_spin_us",
                value: self.handover_spin_us,
                range: "at most 10000 (0: off)",
            });
        }
        for (key, v) in [
            ("rt_priority", self.rt_priority),
            ("grpc_rt_priority", self.grpc_rt_priority),
        ] {
            if v > 99 {
                return Err(ConfigError::OutOfRange {
                    key,
                    value: u64::from(v),
                    range: "0 (off) or 1..=99",
                });
            }
        }
        let mut smc_names = HashSet::new();
        let mut smc_buses = HashSet::new();
        for c in &self.cansmc {
            c.validate(&self.buses)
                .map_err(|m| Section::Cansmc.error(m))?;
            if !smc_names.insert(c.name.as_str()) {
                return Err(ConfigError::Duplicate {
                    kind: "cansmc",
                    name: c.name.clone(),
                });
            }
            for bus in [&c.command_bus, &c.status_bus] {
                if !smc_buses.insert(bus.as_str()) || masters.contains(bus.as_str()) {
                    return Err(Section::Cansmc.error(format!(
                        "cansmc {}: bus {bus:?} is already used by another master",
                        c.name
                    )));
                }
            }
            for a in &c.axes {
                if !axis_names.insert(a.name.as_str()) {
                    return Err(ConfigError::Duplicate {
                        kind: "axis",
                        name: a.name.clone(),
                    });
                }
            }
        }
        if let Some(s) = &self.socketcand {
            s.check(
                self.security.authentication(),
                !self.security.tokens.is_empty(),
            )
            .map_err(|m| Section::Socketcand.error(m))?;
            for b in &s.buses {
                if !self.buses.iter().any(|c| &c.name == b) {
                    return Err(Section::Socketcand.error(format!(
                        "[socketcand] buses names {b:?}, which is not configured"
                    )));
                }
            }
            if s.listen.port() != 0
                && (s.listen == self.listen || self.metrics_listen == Some(s.listen))
            {
                return Err(Section::Socketcand.error(format!(
                    "[socketcand] listen = {} is already the address of another listener",
                    s.listen
                )));
            }
        }
        if let Some(c) = &self.cia309 {
            c.check(
                self.security.authentication(),
                !self.security.tokens.is_empty(),
            )
            .map_err(|m| Section::Cia309.error(m))?;
            for b in &c.buses {
                if !self.canopen.iter().any(|m| &m.bus == b) {
                    return Err(Section::Cia309.error(format!(
                        "[cia309] buses names {b:?}, which has no CANopen master ([[canopen]])"
                    )));
                }
            }
            let others = [Some(self.listen), self.metrics_listen]
                .into_iter()
                .flatten()
                .chain(self.socketcand.as_ref().map(|s| s.listen));
            if c.listen.port() != 0 && others.into_iter().any(|a| a == c.listen) {
                return Err(Section::Cia309.error(format!(
                    "[cia309] listen = {} is already the address of another listener",
                    c.listen
                )));
            }
        }
        let mut bridges = HashSet::new();
        for b in &self.bridges {
            b.check().map_err(|m| Section::Bridge.error(m))?;
            if !bridges.insert(b.name.as_str()) {
                return Err(ConfigError::Duplicate {
                    kind: "bridge",
                    name: b.name.clone(),
                });
            }
            for bus in &b.buses {
                if !self.buses.iter().any(|c| &c.name == bus) {
                    return Err(Section::Bridge.error(format!(
                        "[[bridge]] {:?}: buses names {bus:?}, which is not configured",
                        b.name
                    )));
                }
            }
            let axes = self.axis_specs().unwrap_or_default();
            for a in &b.axes {
                if !axes.iter().any(|s| &s.name == a) {
                    return Err(Section::Bridge.error(format!(
                        "[[bridge]] {:?}: axes names {a:?}, which is not configured",
                        b.name
                    )));
                }
            }
        }
        Ok(())
    }
}

/// A problem of bus `b`.
fn bus_error(b: &BusConfig, problem: String) -> ConfigError {
    ConfigError::Bus {
        bus: b.name.clone(),
        problem,
    }
}
