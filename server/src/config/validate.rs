//! The checks serde cannot make, across sections: unique names, references
//! between sections, sensible values.

use super::*;

impl Config {
    /// Checks what serde cannot: unique names, sensible values.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.security.validate().map_err(ConfigError::Invalid)?;
        self.web.validate().map_err(ConfigError::Invalid)?;
        // A gateway that moves axes must not be reachable from the network
        // without authentication unless someone said so explicitly.
        if !self.listen.ip().is_loopback()
            && !self.security.insecure
            && !self.security.authentication()
        {
            return Err(ConfigError::Invalid(format!(
                "listen = {} is reachable from the network without authentication: anyone \
                 who reaches it can move the axes. Configure [[security.tokens]] or \
                 [[security.clients]], listen on 127.0.0.1 (and tunnel), or accept the risk \
                 with [security] insecure = true (env CANGATE_SECURITY__INSECURE=true)",
                self.listen
            )));
        }
        let mut names = HashSet::new();
        let mut interfaces = HashSet::new();
        for b in &self.buses {
            if b.name.is_empty() {
                return Err(ConfigError::Invalid("a bus has an empty name".into()));
            }
            if !names.insert(b.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?} is configured twice",
                    b.name
                )));
            }
            if b.backend == BackendChoice::Socketcan && !interfaces.insert(b.interface()) {
                return Err(ConfigError::Invalid(format!(
                    "SocketCAN interface {:?} is used by two buses",
                    b.interface()
                )));
            }
            if b.bitrate == Some(0) || b.data_bitrate == Some(0) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: bitrate must be positive",
                    b.name
                )));
            }
            if b.bit_timing && b.bitrate.is_none() {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: bit_timing needs a bitrate",
                    b.name
                )));
            }
            b.fault_check().map_err(ConfigError::Invalid)?;
            b.tx_shares().map_err(ConfigError::Invalid)?;
            if b.backend == BackendChoice::Socketcan && (b.bit_timing || b.queue.is_some()) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: bit_timing and queue apply to virtual buses only",
                    b.name
                )));
            }
            if b.backend != BackendChoice::Socketcan
                && (b.receive_buffer.is_some()
                    || b.transmit_queue.is_some()
                    || b.transmit_timeout_ms.is_some())
            {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?}: receive_buffer, transmit_queue and transmit_timeout_ms apply to \
                     SocketCAN buses only",
                    b.name
                )));
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
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: {key} = {v} is out of range ({}..={})",
                        b.name,
                        range.start(),
                        range.end()
                    )));
                }
            }
        }
        let mut masters = HashSet::new();
        for c in &self.canopen {
            let Some(bus) = self.buses.iter().find(|b| b.name == c.bus) else {
                return Err(ConfigError::Invalid(format!(
                    "[[canopen]] names bus {:?}, which is not configured",
                    c.bus
                )));
            };
            c.check().map_err(ConfigError::Invalid)?;
            if !masters.insert(c.bus.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "bus {:?} has two [[canopen]] sections",
                    c.bus
                )));
            }
            let mut ids = HashSet::new();
            for n in &c.nodes {
                if !(1..=127).contains(&n.id) {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node id {} is out of range (1..=127)",
                        c.bus, n.id
                    )));
                }
                n.guarding_check()
                    .map_err(|m| ConfigError::Invalid(format!("bus {:?}: {m}", c.bus)))?;
                if !ids.insert(n.id) {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node {} is configured twice",
                        c.bus, n.id
                    )));
                }
                if n.simulate && bus.backend != BackendChoice::Virtual {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node {} can only be simulated on a virtual bus",
                        c.bus, n.id
                    )));
                }
                if n.sim_lss.is_some() && !n.simulate {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: node {}: sim_lss describes a simulated device; add simulate = true",
                        c.bus, n.id
                    )));
                }
                if let Some(sim) = &n.sim {
                    if !n.simulate {
                        return Err(ConfigError::Invalid(format!(
                            "bus {:?}: node {}: sim describes a simulated device; add simulate = true",
                            c.bus, n.id
                        )));
                    }
                    sim.check(n.id)
                        .map_err(|m| ConfigError::Invalid(format!("bus {:?}: {m}", c.bus)))?;
                }
                if n.simulate && n.eds.is_none() && n.dcf.is_none() {
                    return Err(ConfigError::Invalid(format!(
                        "bus {:?}: simulated node {} needs an eds",
                        c.bus, n.id
                    )));
                }
                let invalid = |e: String| {
                    ConfigError::Invalid(format!("bus {:?}: node {}: {e}", c.bus, n.id))
                };
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
            h.validate(self).map_err(ConfigError::Invalid)?;
            if !wheel_names.insert(h.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "handwheel {:?} is configured twice",
                    h.name
                )));
            }
        }
        let mut axis_names = HashSet::new();
        let mut axis_nodes = HashSet::new();
        for a in &self.axes {
            a.validate(self).map_err(ConfigError::Invalid)?;
            if !axis_names.insert(a.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "axis {:?} is configured twice",
                    a.name
                )));
            }
            if !axis_nodes.insert((a.bus.as_str(), a.node)) {
                return Err(ConfigError::Invalid(format!(
                    "axis {}: node {} on bus {:?} already backs another axis",
                    a.name, a.node, a.bus
                )));
            }
        }
        if self.shutdown_timeout_ms == 0 || self.shutdown_timeout_ms > 600_000 {
            return Err(ConfigError::Invalid(format!(
                "shutdown_timeout_ms = {} must be between 1 and 600000",
                self.shutdown_timeout_ms
            )));
        }
        if self.handover_spin_us > 10_000 {
            return Err(ConfigError::Invalid(format!(
                "handover_spin_us = {} must be at most 10000 (0: off)",
                self.handover_spin_us
            )));
        }
        for (key, v) in [
            ("rt_priority", self.rt_priority),
            ("grpc_rt_priority", self.grpc_rt_priority),
        ] {
            if v > 99 {
                return Err(ConfigError::Invalid(format!(
                    "{key} = {v} must be 0 (off) or 1..=99"
                )));
            }
        }
        let mut smc_names = HashSet::new();
        let mut smc_buses = HashSet::new();
        for c in &self.cansmc {
            c.validate(&self.buses).map_err(ConfigError::Invalid)?;
            if !smc_names.insert(c.name.as_str()) {
                return Err(ConfigError::Invalid(format!(
                    "cansmc {:?} is configured twice",
                    c.name
                )));
            }
            for bus in [&c.command_bus, &c.status_bus] {
                if !smc_buses.insert(bus.as_str()) || masters.contains(bus.as_str()) {
                    return Err(ConfigError::Invalid(format!(
                        "cansmc {}: bus {bus:?} is already used by another master",
                        c.name
                    )));
                }
            }
            for a in &c.axes {
                if !axis_names.insert(a.name.as_str()) {
                    return Err(ConfigError::Invalid(format!(
                        "axis {:?} is configured twice",
                        a.name
                    )));
                }
            }
        }
        if let Some(s) = &self.socketcand {
            s.check(
                self.security.authentication(),
                !self.security.tokens.is_empty(),
            )
            .map_err(ConfigError::Invalid)?;
            for b in &s.buses {
                if !self.buses.iter().any(|c| &c.name == b) {
                    return Err(ConfigError::Invalid(format!(
                        "[socketcand] buses names {b:?}, which is not configured"
                    )));
                }
            }
            if s.listen.port() != 0
                && (s.listen == self.listen || self.metrics_listen == Some(s.listen))
            {
                return Err(ConfigError::Invalid(format!(
                    "[socketcand] listen = {} is already the address of another listener",
                    s.listen
                )));
            }
        }
        Ok(())
    }
}
