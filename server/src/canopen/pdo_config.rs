//! A node's PDOs read and changed at run time: the communication and
//! mapping parameters read over SDO, and the CiA 301 write sequence of
//! [`PdoConfig::sdo_writes_leaving`]. After a change the master decodes
//! (TPDO) or encodes (RPDO) the PDO with its new layout at once: its TPDO
//! routes and its bus subscription follow the new COB-ID.

use super::{CanopenBus, CanopenError, TpdoRoute, master_selector};
use cangate_canopen::master::SdoRequest;
use cangate_canopen::pdo::{PdoConfig, PdoKind, parameter_name};
use cangate_canopen::sdo::{SdoError, TransferOptions, TransferOutcome};
use cangate_canopen::{NodeId, ObjectAddress};
use std::sync::atomic::AtomicU64;

/// A PDO as a node holds it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodePdo {
    /// Its parameters.
    pub config: PdoConfig,
    /// Valid: the node sends (TPDO) or accepts (RPDO) it.
    pub enabled: bool,
}

/// Why a PDO could not be read or changed.
#[derive(Debug, thiserror::Error)]
pub enum PdoConfigError {
    /// The node is an axis's drive: its PDOs are the axis's process data.
    #[error(
        "node {0} is an axis's drive: its PDOs carry the axis's process data and cannot be \
         changed through the CANopen API"
    )]
    AxisDrive(NodeId),
    /// The configuration itself is invalid (too long, bad number).
    #[error(transparent)]
    Invalid(#[from] cangate_canopen::pdo::PdoError),
    /// An SDO transfer on one of the PDO's parameter objects failed.
    #[error("{addr} ({what}): {source}")]
    Object {
        /// The object.
        addr: ObjectAddress,
        /// What it is ("COB-ID", "mapping entry 2").
        what: String,
        /// The failure.
        source: CanopenError,
    },
}

impl PdoConfigError {
    fn at(addr: ObjectAddress, source: CanopenError) -> PdoConfigError {
        PdoConfigError::Object {
            addr,
            what: parameter_name(addr).unwrap_or_default(),
            source,
        }
    }

    /// The SDO failure underneath, if any (for the status code).
    pub fn sdo(&self) -> Option<&CanopenError> {
        match self {
            PdoConfigError::Object { source, .. } => Some(source),
            _ => None,
        }
    }
}

/// An SDO abort that says the object or sub-index does not exist.
fn does_not_exist(e: &CanopenError) -> bool {
    matches!(e, CanopenError::Sdo(SdoError::Aborted { code, .. })
        if matches!(code.0, 0x0602_0000 | 0x0609_0011))
}

impl CanopenBus {
    async fn upload_u32(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        opts: TransferOptions,
        caller: &str,
    ) -> Result<u32, CanopenError> {
        let req = SdoRequest::Upload { addr, opts };
        match self.client_sdo(node, req, caller).await? {
            TransferOutcome::Uploaded(b) => {
                let mut v = [0u8; 4];
                let n = b.len().min(4);
                v[..n].copy_from_slice(&b[..n]);
                Ok(u32::from_le_bytes(v))
            }
            TransferOutcome::Downloaded => Ok(0),
        }
    }

    /// Reads PDO `num` of `kind` from the node; `None` when the node has
    /// no such PDO. Optional parameters the node lacks (inhibit time,
    /// event timer) read as 0.
    pub async fn read_pdo(
        &self,
        node: NodeId,
        kind: PdoKind,
        num: u16,
        opts: TransferOptions,
        caller: &str,
    ) -> Result<Option<NodePdo>, PdoConfigError> {
        let comm = kind.comm_index(num);
        let map = kind.map_index(num);
        let read = |addr: ObjectAddress| async move {
            self.upload_u32(node, addr, opts, caller)
                .await
                .map_err(|e| (addr, e))
        };
        let optional = |addr: ObjectAddress| async move {
            match self.upload_u32(node, addr, opts, caller).await {
                Err(e) if does_not_exist(&e) => Ok(0),
                r => r.map_err(|e| PdoConfigError::at(addr, e)),
            }
        };
        let cob = match read(ObjectAddress::new(comm, 1)).await {
            Ok(v) => v,
            Err((_, e)) if does_not_exist(&e) => return Ok(None),
            Err((addr, e)) => return Err(PdoConfigError::at(addr, e)),
        };
        let transmission_type = optional(ObjectAddress::new(comm, 2)).await? as u8;
        let inhibit = if kind == PdoKind::Tpdo {
            optional(ObjectAddress::new(comm, 3)).await? as u16
        } else {
            0
        };
        let event_timer = optional(ObjectAddress::new(comm, 5)).await? as u16;
        let count = read(ObjectAddress::new(map, 0))
            .await
            .map_err(|(a, e)| PdoConfigError::at(a, e))?
            .min(64);
        let mut entries = Vec::with_capacity(count as usize);
        for sub in 1..=count as u8 {
            entries.push(
                read(ObjectAddress::new(map, sub))
                    .await
                    .map_err(|(a, e)| PdoConfigError::at(a, e))?,
            );
        }
        let (config, enabled) = PdoConfig::from_parameters(
            kind,
            num,
            cob,
            transmission_type,
            inhibit,
            event_timer,
            &entries,
        );
        Ok(Some(NodePdo { config, enabled }))
    }

    /// Writes `pdo` to the node with the CiA 301 sequence and, once it is
    /// written, decodes or encodes the PDO with it (a disabled PDO is no
    /// longer decoded or encodable). Returns the writes done. A failure
    /// names the object; the PDO stays invalid on the node then, and the
    /// master stops decoding it.
    pub async fn configure_pdo(
        &self,
        node: NodeId,
        pdo: &NodePdo,
        opts: TransferOptions,
        caller: &str,
    ) -> Result<Vec<(ObjectAddress, Vec<u8>)>, PdoConfigError> {
        if self.is_axis_drive(node) {
            return Err(PdoConfigError::AxisDrive(node));
        }
        let writes = pdo.config.sdo_writes_leaving(pdo.enabled)?;
        for (i, (addr, data)) in writes.iter().enumerate() {
            let req = SdoRequest::Download {
                addr: *addr,
                data: data.clone(),
                opts,
            };
            if let Err(e) = self.client_sdo(node, req, caller).await {
                // The first write made the PDO invalid on the node.
                if i > 0 {
                    self.adopt_pdo(node, &pdo.config, false);
                }
                return Err(PdoConfigError::at(*addr, e));
            }
        }
        self.adopt_pdo(node, &pdo.config, pdo.enabled);
        Ok(writes)
    }

    fn is_axis_drive(&self, node: NodeId) -> bool {
        self.facts
            .read()
            .expect("facts lock")
            .get(&node)
            .is_some_and(|f| f.tpdos_read_by_axis)
    }

    /// Makes `cfg` the master's view of the node's PDO (or forgets the PDO
    /// when it is not `enabled`): its facts, the TPDO routes, and the
    /// master's subscription.
    fn adopt_pdo(&self, node: NodeId, cfg: &PdoConfig, enabled: bool) {
        let mut facts = self.facts.write().expect("facts lock");
        let f = facts.entry(node).or_default();
        let list = match cfg.kind {
            PdoKind::Tpdo => &mut f.tpdos,
            PdoKind::Rpdo => &mut f.rpdos,
        };
        let old = list
            .iter()
            .position(|p| p.num == cfg.num)
            .map(|i| list.remove(i));
        if enabled {
            list.push(cfg.clone());
            list.sort_by_key(|p| p.num);
        }
        if cfg.kind == PdoKind::Rpdo {
            return;
        }
        let eds = f.eds.clone();
        {
            let mut routes = self.tpdos.write().expect("TPDO routes lock");
            if let Some(old) = old {
                routes.remove(&old.cob_id);
            }
            if enabled {
                routes.insert(
                    cfg.cob_id,
                    TpdoRoute {
                        node,
                        cfg: cfg.clone(),
                        eds,
                        count: AtomicU64::new(0),
                        last: std::sync::Mutex::new(None),
                    },
                );
            }
        }
        if !self
            .handle
            .reselect(&self.master_sub, master_selector(&facts))
        {
            tracing::warn!(bus = %self.bus, "the master's subscription has ended");
        }
    }
}
