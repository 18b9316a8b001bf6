//! The Canopen service: nodes, NMT, scan, SDO (typed), node events.

use crate::error::Error;
use crate::sdo::{DataType, NodeId, ObjectAddress, SdoOptions, SdoValue};
use crate::streams::{self, EventStream};
use crate::{Client, pb};
use std::time::Duration;

/// The CANopen master of one bus ([`Client::canopen`]). Cheap to clone.
#[derive(Clone, Debug)]
pub struct Canopen {
    client: Client,
    bus: String,
}

impl Client {
    /// The CANopen master of `bus` (no call is made here).
    pub fn canopen(&self, bus: &str) -> Canopen {
        Canopen {
            client: self.clone(),
            bus: bus.to_string(),
        }
    }

    /// Reads an object over SDO (the generated request and response; see
    /// [`Canopen::read`] for the typed one).
    pub async fn read_sdo(
        &mut self,
        req: pb::ReadSdoRequest,
    ) -> Result<pb::ReadSdoResponse, Error> {
        self.call("ReadSdo", None, self.canopen_client().read_sdo(req))
            .await
    }

    /// Writes an object over SDO (the generated request and response; see
    /// [`Canopen::write`] for the typed one).
    pub async fn write_sdo(
        &mut self,
        req: pb::WriteSdoRequest,
    ) -> Result<pb::WriteSdoResponse, Error> {
        self.call("WriteSdo", None, self.canopen_client().write_sdo(req))
            .await
    }
}

impl Canopen {
    /// The bus name.
    pub fn bus(&self) -> &str {
        &self.bus
    }

    /// The nodes the master knows (configured and heard of), by id.
    pub async fn nodes(&self) -> Result<Vec<pb::Node>, Error> {
        let req = pb::ListNodesRequest {
            bus: self.bus.clone(),
        };
        let r = self
            .client
            .call(
                "ListNodes",
                None,
                self.client.canopen_client().list_nodes(req),
            )
            .await?;
        Ok(r.nodes)
    }

    /// One node: NMT state, heartbeat, identity, errors.
    pub async fn node(&self, node: NodeId) -> Result<pb::Node, Error> {
        let req = pb::GetNodeRequest {
            bus: self.bus.clone(),
            node: node.into(),
        };
        self.client
            .call("GetNode", None, self.client.canopen_client().get_node(req))
            .await
    }

    /// Sends an NMT command to one node.
    pub async fn nmt(&self, node: NodeId, command: pb::NmtCommand) -> Result<(), Error> {
        self.send_nmt(node.into(), command).await
    }

    /// Sends an NMT command to every node (broadcast, node 0).
    pub async fn nmt_all(&self, command: pb::NmtCommand) -> Result<(), Error> {
        self.send_nmt(0, command).await
    }

    async fn send_nmt(&self, node: u32, command: pb::NmtCommand) -> Result<(), Error> {
        let req = pb::SendNmtRequest {
            bus: self.bus.clone(),
            node,
            command: command as i32,
        };
        self.client
            .call("SendNmt", None, self.client.canopen_client().send_nmt(req))
            .await?;
        Ok(())
    }

    /// The nodes that answer an SDO read of 0x1000, with name and identity;
    /// `timeout` per node (`None`: 100 ms; at most 10 s).
    pub async fn scan(&self, timeout: Option<Duration>) -> Result<Vec<pb::Node>, Error> {
        let req = pb::ScanNetworkRequest {
            bus: self.bus.clone(),
            timeout_ms: timeout.map_or(0, millis),
        };
        let r = self
            .client
            .call(
                "ScanNetwork",
                None,
                self.client.canopen_client().scan_network(req),
            )
            .await?;
        Ok(r.nodes)
    }

    /// Reads an object as `ty`. With [`DataType::Unspecified`] the node's
    /// EDS type is used when the gateway knows it, else the bytes come as
    /// [`SdoValue::Domain`].
    pub async fn read(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        ty: DataType,
    ) -> Result<SdoValue, Error> {
        self.read_with(node, addr, ty, SdoOptions::default()).await
    }

    /// [`Canopen::read`] with transfer options (timeout, block transfer).
    pub async fn read_with(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        ty: DataType,
        options: SdoOptions,
    ) -> Result<SdoValue, Error> {
        let r = self.read_response(node, addr, ty, options).await?;
        match r.value {
            Some(v) => SdoValue::from_pb(&v),
            None => Ok(SdoValue::Domain(r.raw)),
        }
    }

    /// Reads an object's bytes as they are.
    pub async fn read_bytes(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        options: SdoOptions,
    ) -> Result<Vec<u8>, Error> {
        let r = self
            .read_response(node, addr, DataType::Unspecified, options)
            .await?;
        Ok(r.raw)
    }

    async fn read_response(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        ty: DataType,
        options: SdoOptions,
    ) -> Result<pb::ReadSdoResponse, Error> {
        let req = pb::ReadSdoRequest {
            bus: self.bus.clone(),
            node: node.into(),
            index: addr.index.into(),
            subindex: addr.sub.into(),
            r#type: ty as i32,
            options: Some(options.to_pb()),
        };
        self.client
            .call("ReadSdo", None, self.client.canopen_client().read_sdo(req))
            .await
    }

    /// Writes a typed value (encoded per its type by the gateway); the
    /// number of bytes written.
    pub async fn write(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        value: impl Into<SdoValue>,
    ) -> Result<u32, Error> {
        self.write_with(node, addr, value, SdoOptions::default())
            .await
    }

    /// [`Canopen::write`] with transfer options (timeout, block transfer).
    pub async fn write_with(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        value: impl Into<SdoValue>,
        options: SdoOptions,
    ) -> Result<u32, Error> {
        let data = pb::write_sdo_request::Data::Value(value.into().to_pb());
        self.write_data(node, addr, data, options).await
    }

    /// Writes bytes as they are.
    pub async fn write_bytes(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        bytes: Vec<u8>,
        options: SdoOptions,
    ) -> Result<u32, Error> {
        let data = pb::write_sdo_request::Data::Raw(bytes);
        self.write_data(node, addr, data, options).await
    }

    async fn write_data(
        &self,
        node: NodeId,
        addr: ObjectAddress,
        data: pb::write_sdo_request::Data,
        options: SdoOptions,
    ) -> Result<u32, Error> {
        let req = pb::WriteSdoRequest {
            bus: self.bus.clone(),
            node: node.into(),
            index: addr.index.into(),
            subindex: addr.sub.into(),
            data: Some(data),
            options: Some(options.to_pb()),
        };
        let r = self
            .client
            .call(
                "WriteSdo",
                None,
                self.client.canopen_client().write_sdo(req),
            )
            .await?;
        Ok(r.bytes)
    }

    /// Node events (boot-up, state changes, heartbeat lost/back, EMCY) of
    /// `nodes` (empty: all) as they happen.
    pub async fn events(&self, nodes: &[NodeId]) -> Result<EventStream<pb::NodeEvent>, Error> {
        let req = pb::StreamNodeEventsRequest {
            bus: self.bus.clone(),
            nodes: nodes.iter().map(|n| u32::from(*n)).collect(),
        };
        let s = self
            .client
            .call(
                "StreamNodeEvents",
                None,
                self.client.canopen_client().stream_node_events(req),
            )
            .await?;
        Ok(streams::map(s, |e| e))
    }
}

/// A duration in whole milliseconds for a request field (at least 1 when
/// not zero, saturating).
pub(crate) fn millis(d: Duration) -> u32 {
    if d.is_zero() {
        return 0;
    }
    u32::try_from(d.as_millis()).unwrap_or(u32::MAX).max(1)
}
