//! Finding the nodes on a bus: every node id 1..=127 is asked for its
//! device type (0x1000) at once; each node that answers is asked for its
//! name (0x1008) and identity (0x1018:01..04), and what is learnt goes
//! into the master's node facts.

use super::CanopenBus;
use cangate_canopen::master::SdoRequest;
use cangate_canopen::sdo::{TransferOptions, TransferOutcome};
use cangate_canopen::{NodeId, ObjectAddress};
use std::time::Duration;

impl CanopenBus {
    /// Scans the bus for nodes, each SDO answer awaited at most `timeout`,
    /// as `caller` (the SDO queue per caller applies). Returns the nodes
    /// that answered, in id order.
    pub async fn scan(&self, timeout: Duration, caller: &str) -> Vec<NodeId> {
        let probes = (1..=127u32).map(|n| async move {
            let node = NodeId::new(n).expect("1..=127");
            let device_type = self.read_u32(node, 0x1000, 0, timeout, caller).await?;
            Some((node, device_type))
        });
        let found: Vec<(NodeId, u32)> = futures::future::join_all(probes)
            .await
            .into_iter()
            .flatten()
            .collect();
        for &(node, device_type) in &found {
            let name = match self
                .client_sdo(node, upload(0x1008, 0, timeout), caller)
                .await
            {
                Ok(TransferOutcome::Uploaded(b)) => Some(
                    String::from_utf8_lossy(&b)
                        .trim_end_matches('\0')
                        .to_string(),
                ),
                _ => None,
            };
            let mut identity = [0u32; 4];
            let mut have_identity = true;
            for (i, slot) in identity.iter_mut().enumerate() {
                match self
                    .read_u32(node, 0x1018, i as u8 + 1, timeout, caller)
                    .await
                {
                    Some(v) => *slot = v,
                    None => {
                        have_identity = false;
                        break;
                    }
                }
            }
            self.learn(node, |f| {
                f.device_type = Some(device_type);
                if name.is_some() {
                    f.device_name = name.clone();
                }
                if have_identity {
                    f.identity = Some(identity);
                }
            });
        }
        found.into_iter().map(|(n, _)| n).collect()
    }

    /// A 32-bit object of `node`, or none (no answer, an abort, too short).
    async fn read_u32(
        &self,
        node: NodeId,
        index: u16,
        sub: u8,
        timeout: Duration,
        caller: &str,
    ) -> Option<u32> {
        match self
            .client_sdo(node, upload(index, sub, timeout), caller)
            .await
        {
            Ok(TransferOutcome::Uploaded(b)) if b.len() >= 4 => {
                Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            }
            _ => None,
        }
    }
}

fn upload(index: u16, sub: u8, timeout: Duration) -> SdoRequest {
    SdoRequest::Upload {
        addr: ObjectAddress::new(index, sub),
        opts: TransferOptions::default().with_timeout(timeout),
    }
}
