//! `Canopen.SdoSession`: pipelined SDO reads and writes on one stream.

use crate::error::{ERROR_DOMAIN, Error};
use crate::sdo::{DataType, NodeId, Object, SdoOptions, SdoValue};
use crate::{Canopen, pb};
use futures::channel::mpsc;
use futures::future::{BoxFuture, FutureExt};
use prost::Message;
use std::collections::HashMap;
use std::future::Future;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::oneshot;
use tonic_types::pb as rpc;

type Answer = Result<pb::sdo_session_answer::Result, Error>;
type Pending = Arc<Mutex<Option<HashMap<u64, oneshot::Sender<Answer>>>>>;

/// A session of SDO requests on one stream ([`Canopen::sdo_session`]).
///
/// [`SdoSession::read`] and [`SdoSession::write`] send their request when
/// called and return a future of the answer, so several can be
/// outstanding: requests to one node are answered in the order they were
/// made, those to different nodes concurrently. The gateway holds at most
/// 64 outstanding; beyond that the transport holds further requests back.
///
/// Dropping the session cancels what is outstanding (the gateway aborts
/// those transfers; their futures fail); [`SdoSession::close`] waits for
/// every answer first.
#[derive(Debug)]
pub struct SdoSession {
    bus: String,
    tx: Option<mpsc::UnboundedSender<pb::SdoSessionRequest>>,
    pending: Pending,
    next_id: AtomicU64,
    reader: tokio::task::JoinHandle<()>,
}

impl Canopen {
    /// Opens an SDO session on this bus.
    pub async fn sdo_session(&self) -> Result<SdoSession, Error> {
        let (tx, requests) = mpsc::unbounded();
        let mut answers = self
            .client()
            .call(
                "SdoSession",
                None,
                self.client().canopen_client().sdo_session(requests),
            )
            .await?;
        let pending: Pending = Arc::new(Mutex::new(Some(HashMap::new())));
        let table = pending.clone();
        let reader = tokio::spawn(async move {
            let end = loop {
                match answers.message().await {
                    Ok(Some(a)) => {
                        let waiter = table
                            .lock()
                            .expect("pending lock")
                            .as_mut()
                            .and_then(|p| p.remove(&a.id));
                        if let (Some(w), Some(r)) = (waiter, a.result) {
                            let _ = w.send(match r {
                                pb::sdo_session_answer::Result::Error(e) => Err(session_error(e)),
                                r => Ok(r),
                            });
                        }
                    }
                    Ok(None) => break None,
                    Err(status) => break Some(status),
                }
            };
            // The stream ended: what is still outstanding fails with why.
            let left = table.lock().expect("pending lock").take();
            for (_, w) in left.into_iter().flatten() {
                let _ = w.send(Err(match &end {
                    Some(status) => Error::from(status.clone()),
                    None => ended(),
                }));
            }
        });
        Ok(SdoSession {
            bus: self.bus().to_string(),
            tx: Some(tx),
            pending,
            next_id: AtomicU64::new(1),
            reader,
        })
    }
}

fn ended() -> Error {
    Error::Transport {
        message: "the SDO session ended before the answer".into(),
    }
}

/// A session answer's error as the error of the unary call: the same
/// status (code, message, ErrorInfo, SdoAbortDetails) typed as
/// `Error::from(Status)` types it.
fn session_error(e: pb::SdoSessionError) -> Error {
    let info = rpc::ErrorInfo {
        reason: e.reason,
        domain: ERROR_DOMAIN.to_string(),
        metadata: e.metadata.into_iter().collect(),
    };
    let mut parts = vec![(
        "type.googleapis.com/google.rpc.ErrorInfo",
        info.encode_to_vec(),
    )];
    if let Some(a) = e.abort {
        parts.push((crate::error::SDO_ABORT_DETAILS_TYPE_URL, a.encode_to_vec()));
    }
    let mut body = rpc::Status {
        code: e.code,
        message: e.message.clone(),
        details: Vec::new(),
    };
    for (type_url, value) in parts {
        // A google.protobuf.Any (its type comes from tonic-types' Status).
        body.details.push(Default::default());
        let any = body.details.last_mut().expect("just pushed");
        any.type_url = type_url.to_string();
        any.value = value;
    }
    Error::from(tonic::Status::with_details(
        tonic::Code::from(e.code),
        e.message,
        body.encode_to_vec().into(),
    ))
}

impl SdoSession {
    /// Sends a request; the future of its answer.
    fn request(
        &self,
        request: pb::sdo_session_request::Request,
    ) -> impl Future<Output = Answer> + use<> {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let (w, r) = oneshot::channel();
        let sent = match self.pending.lock().expect("pending lock").as_mut() {
            Some(p) => {
                p.insert(id, w);
                self.tx.as_ref().is_some_and(|tx| {
                    tx.unbounded_send(pb::SdoSessionRequest {
                        id,
                        request: Some(request),
                    })
                    .is_ok()
                })
            }
            None => false,
        };
        async move {
            if !sent {
                return Err(ended());
            }
            r.await.unwrap_or_else(|_| Err(ended()))
        }
    }

    /// Reads an object (by address or name, as [`Canopen::read_object`]);
    /// sent at once, answered by the returned future.
    pub fn read(
        &self,
        node: NodeId,
        object: impl Into<Object>,
        ty: DataType,
    ) -> BoxFuture<'static, Result<SdoValue, Error>> {
        self.read_with(node, object, ty, SdoOptions::default())
    }

    /// [`SdoSession::read`] with transfer options.
    pub fn read_with(
        &self,
        node: NodeId,
        object: impl Into<Object>,
        ty: DataType,
        options: SdoOptions,
    ) -> BoxFuture<'static, Result<SdoValue, Error>> {
        let (index, subindex, object) = object.into().fields();
        let answer = self.request(pb::sdo_session_request::Request::Read(pb::ReadSdoRequest {
            bus: self.bus.clone(),
            node: node.into(),
            index,
            subindex,
            r#type: ty as i32,
            options: Some(options.to_pb()),
            object,
        }));
        async move {
            match answer.await? {
                pb::sdo_session_answer::Result::Read(r) => match r.value {
                    Some(v) => SdoValue::from_pb(&v),
                    None => Ok(SdoValue::Domain(r.raw)),
                },
                other => Err(unexpected(other)),
            }
        }
        .boxed()
    }

    /// Writes a typed value (as [`Canopen::write_object`]); sent at once,
    /// answered by the returned future with the bytes written.
    pub fn write(
        &self,
        node: NodeId,
        object: impl Into<Object>,
        value: impl Into<SdoValue>,
    ) -> BoxFuture<'static, Result<u32, Error>> {
        self.write_request(pb::WriteSdoRequest {
            node: node.into(),
            data: Some(pb::write_sdo_request::Data::Value(value.into().to_pb())),
            ..self.write_target(object.into())
        })
    }

    /// Sends a WriteSdo request as it is (raw bytes, `force`, options;
    /// its `bus` is set to the session's).
    pub fn write_request(
        &self,
        req: pb::WriteSdoRequest,
    ) -> BoxFuture<'static, Result<u32, Error>> {
        let answer = self.request(pb::sdo_session_request::Request::Write(
            pb::WriteSdoRequest {
                bus: self.bus.clone(),
                ..req
            },
        ));
        async move {
            match answer.await? {
                pb::sdo_session_answer::Result::Write(w) => Ok(w.bytes),
                other => Err(unexpected(other)),
            }
        }
        .boxed()
    }

    fn write_target(&self, object: Object) -> pb::WriteSdoRequest {
        let (index, subindex, object) = object.fields();
        pb::WriteSdoRequest {
            bus: self.bus.clone(),
            index,
            subindex,
            object,
            ..Default::default()
        }
    }

    /// Ends the session after every outstanding request is answered.
    pub async fn close(mut self) {
        self.tx = None;
        let _ = (&mut self.reader).await;
    }
}

fn unexpected(r: pb::sdo_session_answer::Result) -> Error {
    Error::Transport {
        message: format!("the gateway answered an SDO session request with {r:?}"),
    }
}

impl Drop for SdoSession {
    /// Cancels the stream: the gateway aborts the outstanding transfers.
    fn drop(&mut self) {
        self.reader.abort();
    }
}
