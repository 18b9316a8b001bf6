//! The Cansmc service: masters, status, slave parameters.

use crate::error::Error;
use crate::{Client, pb};

impl Client {
    /// Every CANsmc master, briefly.
    pub async fn list_cansmc_masters(&mut self) -> Result<Vec<pb::CansmcMasterInfo>, Error> {
        let r = self
            .call(
                "ListMasters",
                None,
                self.cansmc_client().list_masters(pb::ListMastersRequest {}),
            )
            .await?;
        Ok(r.masters)
    }

    /// The full state of a CANsmc master ("" = the gateway's only one).
    pub async fn cansmc_status(&mut self, master: &str) -> Result<pb::CansmcStatus, Error> {
        self.smc_status(master).await
    }

    /// The full state of a CANsmc master ("" = the gateway's only one):
    /// phase, counters, slaves, cycle jitter.
    pub async fn smc_status(&self, master: &str) -> Result<pb::CansmcStatus, Error> {
        let req = pb::GetCansmcStatusRequest {
            master: master.to_string(),
        };
        self.call("GetStatus", None, self.cansmc_client().get_status(req))
            .await
    }

    /// Reads parameter `number` of slave `address` of a master ("" = the
    /// only one); needs the master in P2.
    pub async fn read_smc_parameter(
        &self,
        master: &str,
        address: u8,
        number: u16,
    ) -> Result<i32, Error> {
        let req = pb::ReadParameterRequest {
            master: master.to_string(),
            address: address.into(),
            number: number.into(),
        };
        let r = self
            .call(
                "ReadParameter",
                None,
                self.cansmc_client().read_parameter(req),
            )
            .await?;
        Ok(r.value)
    }
}
