//! A node's live values as a DCF: every readable object of its EDS read
//! over SDO and written into the EDS text
//! ([`cangate_canopen::dcf::write_dcf`]).

use super::{CanopenBus, CanopenError};
use cangate_canopen::eds::Commissioning;
use cangate_canopen::master::SdoRequest;
use cangate_canopen::sdo::{TransferOptions, TransferOutcome};
use cangate_canopen::value::{DataType, Value};
use cangate_canopen::{NodeId, ObjectAddress};
use std::collections::BTreeMap;

/// A DCF of a node's live values.
#[derive(Debug, Clone)]
pub struct DcfExport {
    /// The DCF text.
    pub text: String,
    /// Objects read and written into it.
    pub read: usize,
    /// Objects left out, with why (write-only, DOMAIN, an SDO abort).
    pub skipped: Vec<(ObjectAddress, String)>,
}

/// Why no DCF could be made.
#[derive(Debug, thiserror::Error)]
pub enum DcfExportError {
    /// The gateway has no EDS for the node.
    #[error("node {0} has no EDS, so its objects are unknown (give it one with `eds`)")]
    NoEds(NodeId),
    /// A failure that stops the whole export (the node went silent, the
    /// master stopped, the caller's queue is full).
    #[error(transparent)]
    Canopen(#[from] CanopenError),
}

impl CanopenBus {
    /// Reads every readable object of the node's EDS and writes the values
    /// into the EDS text. An object the node refuses (SDO abort) is
    /// skipped and listed; a timeout ends the export (the node is gone).
    pub async fn export_dcf(
        &self,
        node: NodeId,
        opts: TransferOptions,
        caller: &str,
    ) -> Result<DcfExport, DcfExportError> {
        let (eds, text, name) = {
            let facts = self.facts.read().expect("facts lock");
            let f = facts.get(&node);
            match (
                f.and_then(|f| f.eds.clone()),
                f.and_then(|f| f.eds_text.clone()),
            ) {
                (Some(eds), Some(text)) => (eds, text, f.map(|f| f.name.clone())),
                _ => return Err(DcfExportError::NoEds(node)),
            }
        };
        let mut values = BTreeMap::new();
        let mut skipped = Vec::new();
        for var in eds.od.variables() {
            let addr = var.address;
            if !var.access.is_readable() {
                skipped.push((addr, "write-only".to_string()));
                continue;
            }
            if var.data_type == DataType::Domain {
                skipped.push((addr, "DOMAIN (not kept in a DCF)".to_string()));
                continue;
            }
            let req = SdoRequest::Upload { addr, opts };
            let bytes = match self.client_sdo(node, req, caller).await {
                Ok(TransferOutcome::Uploaded(b)) => b,
                Ok(TransferOutcome::Downloaded) => continue,
                Err(CanopenError::Sdo(e @ cangate_canopen::sdo::SdoError::Aborted { .. })) => {
                    skipped.push((addr, e.to_string()));
                    continue;
                }
                Err(e) => return Err(e.into()),
            };
            // An expedited upload without a size gives 4 bytes: a
            // fixed-size type takes its own.
            let bytes = match var.data_type.fixed_size() {
                Some(n) if bytes.len() > n => &bytes[..n],
                _ => &bytes[..],
            };
            match Value::decode(var.data_type, bytes) {
                Ok(v) => {
                    values.insert(addr, v);
                }
                Err(e) => skipped.push((addr, format!("the node's value does not decode: {e}"))),
            }
        }
        let commissioning = Commissioning {
            node_id: Some(node),
            node_name: name.filter(|n| !n.is_empty()),
            baud_rate: self.handle.info().bitrate.map(|b| b / 1000),
            network_name: Some(self.bus.clone()),
            ..Commissioning::default()
        };
        let read = values.len();
        Ok(DcfExport {
            text: cangate_canopen::dcf::write_dcf(&text, &eds.od, &values, &commissioning),
            read,
            skipped,
        })
    }
}
