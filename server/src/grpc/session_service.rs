//! The Session service: the caller's own identity and role, as the
//! security layer established them for this call.

use cangate_proto::v1 as pb;
use cangate_proto::v1::session_server::Session;
use tonic::{Request, Response, Status};

/// Answers who the caller is.
#[derive(Debug, Clone)]
pub struct SessionService {
    authentication: bool,
    viewers_may_stop: bool,
}

impl SessionService {
    /// `authentication`: the gateway has tokens or client certificates
    /// configured; `viewers_may_stop`: `[security] viewers_may_stop`.
    pub fn new(authentication: bool, viewers_may_stop: bool) -> Self {
        SessionService {
            authentication,
            viewers_may_stop,
        }
    }
}

fn role_to_pb(role: crate::security::Role) -> pb::CallerRole {
    match role {
        crate::security::Role::Viewer => pb::CallerRole::Viewer,
        crate::security::Role::Operator => pb::CallerRole::Operator,
        crate::security::Role::Engineer => pb::CallerRole::Engineer,
    }
}

#[tonic::async_trait]
impl Session for SessionService {
    async fn get_caller(
        &self,
        req: Request<pb::GetCallerRequest>,
    ) -> Result<Response<pb::Caller>, Status> {
        // Every call passes the security layer, which puts the identity
        // in; without one (the service used without that layer) the caller
        // is what authentication off makes everyone.
        let caller = match req.extensions().get::<crate::security::Identity>() {
            Some(id) => pb::Caller {
                name: id.name.clone(),
                role: role_to_pb(id.role) as i32,
                method: id.method.to_string(),
                authentication: self.authentication,
                may_stop: id.role >= crate::security::Role::Operator || self.viewers_may_stop,
            },
            None => pb::Caller {
                name: "anonymous".into(),
                role: pb::CallerRole::Engineer as i32,
                method: "none".into(),
                authentication: self.authentication,
                may_stop: true,
            },
        };
        Ok(Response::new(caller))
    }
}
