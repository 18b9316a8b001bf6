//! The Canopen service: nodes, NMT, scan, SDO (typed), node events.

use crate::error::Error;
use crate::sdo::{DataType, NodeId, Object, ObjectAddress, SdoOptions, SdoValue};
use crate::streams::{self, EventStream};
use crate::{Client, pb};
use std::time::Duration;

/// What a PDO configuration call may wait for beyond the request timeout:
/// a dozen SDO transfers with the node.
const PDO_CONFIG_WAIT: Duration = Duration::from_secs(10);

/// What a DCF export may wait for beyond the request timeout: an SDO read
/// of every object of a large dictionary.
const DCF_EXPORT_WAIT: Duration = Duration::from_secs(120);

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

    pub(crate) fn client(&self) -> &Client {
        &self.client
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

    /// Sends an NMT command to one node. A command that takes the drive
    /// of an enabled axis out of operational is refused
    /// (`FAILED_PRECONDITION`, reason `AXIS_ACTIVE`); see [`Self::nmt_forced`].
    pub async fn nmt(&self, node: NodeId, command: pb::NmtCommand) -> Result<(), Error> {
        self.send_nmt(node.into(), command, false).await
    }

    /// Sends an NMT command to every node (broadcast, node 0); refused
    /// like [`Self::nmt`] while an axis is enabled.
    pub async fn nmt_all(&self, command: pb::NmtCommand) -> Result<(), Error> {
        self.send_nmt(0, command, false).await
    }

    /// Sends an NMT command to one node (`None`: every node) even when it
    /// takes an enabled axis's drive out of operational: the axis faults.
    /// Only a client with the engineer role may.
    pub async fn nmt_forced(
        &self,
        node: Option<NodeId>,
        command: pb::NmtCommand,
    ) -> Result<(), Error> {
        self.send_nmt(node.map_or(0, u32::from), command, true)
            .await
    }

    async fn send_nmt(&self, node: u32, command: pb::NmtCommand, force: bool) -> Result<(), Error> {
        let req = pb::SendNmtRequest {
            bus: self.bus.clone(),
            node,
            command: command as i32,
            force,
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
        let r = self.read_response(node, &addr.into(), ty, options).await?;
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
            .read_response(node, &addr.into(), DataType::Unspecified, options)
            .await?;
        Ok(r.raw)
    }

    /// Reads an object given by address or by name (resolved by the
    /// gateway with the node's EDS: `"Manufacturer device name"`,
    /// `"Identity object.Serial number"`), as `ty`
    /// ([`DataType::Unspecified`]: the EDS type).
    pub async fn read_object(
        &self,
        node: NodeId,
        object: impl Into<Object>,
        ty: DataType,
    ) -> Result<SdoValue, Error> {
        let r = self
            .read_response(node, &object.into(), ty, SdoOptions::default())
            .await?;
        match r.value {
            Some(v) => SdoValue::from_pb(&v),
            None => Ok(SdoValue::Domain(r.raw)),
        }
    }

    async fn read_response(
        &self,
        node: NodeId,
        object: &Object,
        ty: DataType,
        options: SdoOptions,
    ) -> Result<pb::ReadSdoResponse, Error> {
        let (index, subindex, object) = object.fields();
        let req = pb::ReadSdoRequest {
            bus: self.bus.clone(),
            node: node.into(),
            index,
            subindex,
            r#type: ty as i32,
            options: Some(options.to_pb()),
            object,
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
        self.write_data(node, &addr.into(), data, options).await
    }

    /// Writes a typed value to an object given by address or by name
    /// (see [`Canopen::read_object`]).
    pub async fn write_object(
        &self,
        node: NodeId,
        object: impl Into<Object>,
        value: impl Into<SdoValue>,
    ) -> Result<u32, Error> {
        let data = pb::write_sdo_request::Data::Value(value.into().to_pb());
        self.write_data(node, &object.into(), data, SdoOptions::default())
            .await
    }

    /// Writes a value typed as a person types it (`"100"`, `"0x64"`,
    /// `"-5"`, `"true"`, text for strings, hex bytes) to an object given
    /// by address or by name: the gateway takes the type from the node's
    /// EDS (INVALID_ARGUMENT when the EDS does not have the object).
    pub async fn write_text(
        &self,
        node: NodeId,
        object: impl Into<Object>,
        text: &str,
    ) -> Result<u32, Error> {
        let data = pb::write_sdo_request::Data::Value(pb::Value {
            r#type: DataType::Unspecified as i32,
            value: Some(pb::value::Value::StringValue(text.to_string())),
        });
        self.write_data(node, &object.into(), data, SdoOptions::default())
            .await
    }

    /// The node's object dictionary from its EDS (no SDO transfer): every
    /// sub-object with name, type, access, default and limits.
    pub async fn objects(&self, node: NodeId) -> Result<Vec<pb::ObjectInfo>, Error> {
        let req = pb::ListObjectsRequest {
            bus: self.bus.clone(),
            node: node.into(),
        };
        let r = self
            .client
            .call(
                "ListObjects",
                None,
                self.client.canopen_client().list_objects(req),
            )
            .await?;
        Ok(r.objects)
    }

    /// A node's PDOs as the node holds them (read over SDO): `kind`
    /// `None` for both, `pdo` 0 for every PDO (those its EDS lists, else
    /// 1..=4).
    pub async fn pdo_config(
        &self,
        node: NodeId,
        kind: Option<pb::PdoKind>,
        pdo: u32,
    ) -> Result<Vec<pb::PdoConfiguration>, Error> {
        let req = pb::ReadPdoConfigRequest {
            bus: self.bus.clone(),
            node: node.into(),
            kind: kind.unwrap_or(pb::PdoKind::Unspecified) as i32,
            pdo,
            options: None,
        };
        let r = self
            .client
            .call(
                "ReadPdoConfig",
                Some(PDO_CONFIG_WAIT),
                self.client.canopen_client().read_pdo_config(req),
            )
            .await?;
        Ok(r.pdos)
    }

    /// Changes one PDO of a node (CiA 301 sequence); the gateway decodes
    /// or encodes the PDO with the new layout at once.
    pub async fn configure_pdo(
        &self,
        node: NodeId,
        pdo: pb::PdoConfiguration,
    ) -> Result<pb::ConfigurePdoResponse, Error> {
        let req = pb::ConfigurePdoRequest {
            bus: self.bus.clone(),
            node: node.into(),
            pdo: Some(pdo),
            options: None,
        };
        self.client
            .call(
                "ConfigurePdo",
                Some(PDO_CONFIG_WAIT),
                self.client.canopen_client().configure_pdo(req),
            )
            .await
    }

    /// The node's live values as a DCF (every readable object of its EDS
    /// read over SDO); the objects left out are listed in the response.
    pub async fn export_dcf(&self, node: NodeId) -> Result<pb::ExportDcfResponse, Error> {
        let req = pb::ExportDcfRequest {
            bus: self.bus.clone(),
            node: node.into(),
            options: None,
        };
        self.client
            .call(
                "ExportDcf",
                Some(DCF_EXPORT_WAIT),
                self.client.canopen_client().export_dcf(req),
            )
            .await
    }

    /// The bus's SYNC and TIME producers.
    pub async fn sync_status(&self) -> Result<pb::SyncStatus, Error> {
        let req = pb::GetSyncRequest {
            bus: self.bus.clone(),
        };
        self.client
            .call("GetSync", None, self.client.canopen_client().get_sync(req))
            .await
    }

    /// Starts/stops the SYNC producer, or changes its period or counter
    /// (`None`: unchanged).
    pub async fn set_sync(
        &self,
        running: Option<bool>,
        period: Option<Duration>,
        counter_overflow: Option<u8>,
    ) -> Result<pb::SyncStatus, Error> {
        let req = pb::SetSyncRequest {
            bus: self.bus.clone(),
            running,
            period_us: period.map(|p| u32::try_from(p.as_micros()).unwrap_or(u32::MAX)),
            counter_overflow: counter_overflow.map(u32::from),
        };
        self.client
            .call("SetSync", None, self.client.canopen_client().set_sync(req))
            .await
    }

    /// Sends a TIME now (`send_now`) and/or sets the TIME period
    /// (`Some(Duration::ZERO)` stops periodic TIMEs, `None` leaves it).
    pub async fn set_time(
        &self,
        send_now: bool,
        period: Option<Duration>,
    ) -> Result<pb::SetTimeResponse, Error> {
        let req = pb::SetTimeRequest {
            bus: self.bus.clone(),
            send_now,
            period_ms: period.map(|p| u32::try_from(p.as_millis()).unwrap_or(u32::MAX)),
        };
        self.client
            .call("SetTime", None, self.client.canopen_client().set_time(req))
            .await
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
        self.write_data(node, &addr.into(), data, options).await
    }

    async fn write_data(
        &self,
        node: NodeId,
        object: &Object,
        data: pb::write_sdo_request::Data,
        options: SdoOptions,
    ) -> Result<u32, Error> {
        let (index, subindex, object) = object.fields();
        let req = pb::WriteSdoRequest {
            bus: self.bus.clone(),
            node: node.into(),
            index,
            subindex,
            data: Some(data),
            options: Some(options.to_pb()),
            object,
            force: false,
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
