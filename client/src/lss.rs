//! The Lss service (CiA 305 layer setting services): find unconfigured
//! devices by fastscan, inquire and give them node-IDs.

use crate::error::Error;
use crate::sdo::NodeId;
use crate::{Client, pb};
use std::time::Duration;

/// Which device [`Lss::assign_node_id`] configures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LssDevice {
    /// By its whole identity (0x1018:01..=04).
    Identity(pb::LssIdentity),
    /// The unconfigured device with this serial number (the gateway finds
    /// it by fastscan).
    Serial(u32),
}

/// The LSS master of one bus ([`Client::lss`]). Cheap to clone. Every
/// call is one bus-global LSS operation; a call while another runs on the
/// bus fails with [`Error::Refused`] reason `LSS_BUSY`.
#[derive(Clone, Debug)]
pub struct Lss {
    client: Client,
    bus: String,
}

/// The longest a fastscan is given beyond the request timeout.
const FASTSCAN_EXTRA: Duration = Duration::from_secs(120);

impl Client {
    /// The LSS master of `bus` (no call is made here).
    pub fn lss(&self, bus: &str) -> Lss {
        Lss {
            client: self.clone(),
            bus: bus.to_string(),
        }
    }

    /// The generated Lss client.
    pub fn lss_client(&self) -> pb::lss_client::LssClient<crate::Transport> {
        pb::lss_client::LssClient::new(self.channel())
    }
}

fn ms(d: Option<Duration>) -> u32 {
    d.map_or(0, |d| d.as_millis().min(u128::from(u32::MAX)) as u32)
}

impl Lss {
    /// The bus name.
    pub fn bus(&self) -> &str {
        &self.bus
    }

    /// Every unconfigured device by fastscan, lowest identity first.
    /// `step_time`: how long each step listens (the gateway's default, 20
    /// ms, when `None`); 133 steps per device.
    pub async fn fastscan(
        &self,
        step_time: Option<Duration>,
    ) -> Result<Vec<pb::LssIdentity>, Error> {
        let req = pb::FastscanRequest {
            bus: self.bus.clone(),
            step_time_ms: ms(step_time),
            max_devices: 0,
        };
        let r = self
            .client
            .call(
                "Fastscan",
                Some(FASTSCAN_EXTRA),
                self.client.lss_client().fastscan(req),
            )
            .await?;
        Ok(r.devices)
    }

    /// The identity and active node-ID (255: none) of the device with
    /// `identity`, else of the only device on the bus.
    pub async fn inquire(
        &self,
        identity: Option<pb::LssIdentity>,
    ) -> Result<(pb::LssIdentity, u32), Error> {
        let req = pb::InquireRequest {
            bus: self.bus.clone(),
            identity,
            timeout_ms: 0,
        };
        let r = self
            .client
            .call("Inquire", None, self.client.lss_client().inquire(req))
            .await?;
        Ok((r.identity.unwrap_or_default(), r.node_id))
    }

    /// Gives a device node-ID `node`, storing it in the device when
    /// `store`; the device then boots up with it. An id in use (heard on
    /// the bus in the last minute, an axis's drive's, configured for
    /// another device) is refused with [`Error::Refused`] reason
    /// `NODE_ID_IN_USE`.
    pub async fn assign_node_id(
        &self,
        device: LssDevice,
        node: NodeId,
        store: bool,
    ) -> Result<pb::AssignNodeIdResponse, Error> {
        self.assign(device, node, store, false).await
    }

    /// [`Lss::assign_node_id`] even when the id is in use: the device then
    /// shares it with another one, unless that one is gone.
    pub async fn assign_node_id_forced(
        &self,
        device: LssDevice,
        node: NodeId,
        store: bool,
    ) -> Result<pb::AssignNodeIdResponse, Error> {
        self.assign(device, node, store, true).await
    }

    async fn assign(
        &self,
        device: LssDevice,
        node: NodeId,
        store: bool,
        force: bool,
    ) -> Result<pb::AssignNodeIdResponse, Error> {
        let device = Some(match device {
            LssDevice::Identity(i) => pb::assign_node_id_request::Device::Identity(i),
            LssDevice::Serial(s) => pb::assign_node_id_request::Device::Serial(s),
        });
        let req = pb::AssignNodeIdRequest {
            bus: self.bus.clone(),
            device,
            node_id: node.into(),
            store,
            timeout_ms: 0,
            force,
        };
        self.client
            .call(
                "AssignNodeId",
                Some(FASTSCAN_EXTRA),
                self.client.lss_client().assign_node_id(req),
            )
            .await
    }

    /// Switches every device to the waiting or configuration state.
    pub async fn switch_global(&self, mode: pb::LssMode) -> Result<(), Error> {
        let req = pb::SwitchGlobalRequest {
            bus: self.bus.clone(),
            mode: mode as i32,
        };
        self.client
            .call(
                "SwitchGlobal",
                None,
                self.client.lss_client().switch_global(req),
            )
            .await?;
        Ok(())
    }

    /// Switches the device with `identity` to the configuration state.
    pub async fn switch_selective(&self, identity: pb::LssIdentity) -> Result<(), Error> {
        let req = pb::SwitchSelectiveRequest {
            bus: self.bus.clone(),
            identity: Some(identity),
            timeout_ms: 0,
        };
        self.client
            .call(
                "SwitchSelective",
                None,
                self.client.lss_client().switch_selective(req),
            )
            .await?;
        Ok(())
    }

    /// Configures the node-ID (1..=127, 255: none) of the device in the
    /// configuration state.
    pub async fn configure_node_id(&self, node_id: u32) -> Result<(), Error> {
        let req = pb::ConfigureNodeIdRequest {
            bus: self.bus.clone(),
            node_id,
            timeout_ms: 0,
            force: false,
        };
        self.client
            .call(
                "ConfigureNodeId",
                None,
                self.client.lss_client().configure_node_id(req),
            )
            .await?;
        Ok(())
    }

    /// Configures the bit timing (table, index) of the device in the
    /// configuration state.
    pub async fn configure_bit_timing(&self, table: u8, index: u8) -> Result<(), Error> {
        let req = pb::ConfigureBitTimingRequest {
            bus: self.bus.clone(),
            table: table.into(),
            index: index.into(),
            timeout_ms: 0,
        };
        self.client
            .call(
                "ConfigureBitTiming",
                None,
                self.client.lss_client().configure_bit_timing(req),
            )
            .await?;
        Ok(())
    }

    /// Activates the configured bit timing after `switch_delay_ms`.
    pub async fn activate_bit_timing(&self, switch_delay_ms: u16) -> Result<(), Error> {
        let req = pb::ActivateBitTimingRequest {
            bus: self.bus.clone(),
            switch_delay_ms: switch_delay_ms.into(),
        };
        self.client
            .call(
                "ActivateBitTiming",
                None,
                self.client.lss_client().activate_bit_timing(req),
            )
            .await?;
        Ok(())
    }

    /// Makes the device in the configuration state store its node-ID and
    /// bit timing.
    pub async fn store_configuration(&self) -> Result<(), Error> {
        let req = pb::StoreConfigurationRequest {
            bus: self.bus.clone(),
            timeout_ms: 0,
        };
        self.client
            .call(
                "StoreConfiguration",
                None,
                self.client.lss_client().store_configuration(req),
            )
            .await?;
        Ok(())
    }

    /// Whether any device without a node-ID is there.
    pub async fn identify_non_configured(&self) -> Result<bool, Error> {
        let req = pb::IdentifyNonConfiguredRequest {
            bus: self.bus.clone(),
            timeout_ms: 0,
        };
        let r = self
            .client
            .call(
                "IdentifyNonConfigured",
                None,
                self.client.lss_client().identify_non_configured(req),
            )
            .await?;
        Ok(r.present)
    }
}
