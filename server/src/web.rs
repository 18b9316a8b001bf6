//! The built-in dashboard's static files, served at `/` on the gRPC
//! listener (`[web] enabled`): the bundle built from `web/` and committed
//! in `web/dist/`, embedded in the binary so that running the server needs
//! no Node.
//!
//! A tower layer outermost on the listener answers `GET` and `HEAD` itself
//! (gRPC and gRPC-Web calls are always `POST`, CORS preflights `OPTIONS`):
//! the known files with their content type and a strict
//! `Content-Security-Policy` (scripts, styles and API calls from this
//! origin only; no inline script, no framing), anything else 404. With the
//! dashboard disabled every `GET` is 404. Nothing here passes the security
//! layer: the files are public, the data behind them is not (the page
//! calls the API with the user's token).

use bytes::Bytes;
use http::{HeaderValue, Method, Request, Response, StatusCode, header};
use std::task::{Context, Poll};
use tonic::body::Body;

/// One embedded file.
struct Asset {
    path: &'static str,
    content_type: &'static str,
    body: &'static [u8],
}

/// The files of `web/dist/` (see `scripts/web-build`).
const ASSETS: &[Asset] = &[
    Asset {
        path: "/",
        content_type: "text/html; charset=utf-8",
        body: include_bytes!("../../web/dist/index.html"),
    },
    Asset {
        path: "/index.html",
        content_type: "text/html; charset=utf-8",
        body: include_bytes!("../../web/dist/index.html"),
    },
    Asset {
        path: "/app.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_bytes!("../../web/dist/app.js"),
    },
    Asset {
        path: "/app.css",
        content_type: "text/css; charset=utf-8",
        body: include_bytes!("../../web/dist/app.css"),
    },
];

/// The policy of every answer: everything from this origin only, no
/// inline script, no plug-ins, not framed by other pages. `connect-src
/// 'self'` covers the page's gRPC-Web calls to the gateway.
pub const CONTENT_SECURITY_POLICY: &str = "default-src 'none'; script-src 'self'; \
     style-src 'self'; img-src 'self' data:; connect-src 'self'; base-uri 'none'; \
     form-action 'none'; frame-ancestors 'none'";

/// The layer (see the module documentation).
#[derive(Debug, Clone, Copy)]
pub struct StaticLayer {
    enabled: bool,
}

impl StaticLayer {
    /// Serves the dashboard when `enabled`, else answers every `GET` 404.
    pub fn new(enabled: bool) -> Self {
        StaticLayer { enabled }
    }
}

impl<S> tower::Layer<S> for StaticLayer {
    type Service = StaticService<S>;
    fn layer(&self, inner: S) -> Self::Service {
        StaticService {
            inner,
            enabled: self.enabled,
        }
    }
}

/// See [`StaticLayer`].
#[derive(Debug, Clone)]
pub struct StaticService<S> {
    inner: S,
    enabled: bool,
}

/// The answer to a `GET`/`HEAD` of `path`.
fn answer(enabled: bool, path: &str, head: bool) -> Response<Body> {
    let asset = enabled
        .then(|| ASSETS.iter().find(|a| a.path == path))
        .flatten();
    let (status, content_type, body): (_, _, &'static [u8]) = match asset {
        Some(a) => (StatusCode::OK, a.content_type, a.body),
        None => (
            StatusCode::NOT_FOUND,
            "text/plain; charset=utf-8",
            b"not found\n",
        ),
    };
    let mut resp = Response::new(if head {
        Body::empty()
    } else {
        Body::new(http_body_util::Full::new(Bytes::from_static(body)))
    });
    *resp.status_mut() = status;
    let h = resp.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(content_type));
    h.insert(header::CONTENT_LENGTH, HeaderValue::from(body.len()));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CONTENT_SECURITY_POLICY),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    // A new server binary brings a new bundle: always revalidate.
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    resp
}

impl<S> tower::Service<Request<Body>> for StaticService<S>
where
    S: tower::Service<Request<Body>, Response = Response<Body>>,
    S::Future: Send + 'static,
{
    type Response = Response<Body>;
    type Error = S::Error;
    type Future =
        futures::future::Either<std::future::Ready<Result<Response<Body>, S::Error>>, S::Future>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: Request<Body>) -> Self::Future {
        let m = req.method();
        if m == Method::GET || m == Method::HEAD {
            let resp = answer(self.enabled, req.uri().path(), m == Method::HEAD);
            return futures::future::Either::Left(std::future::ready(Ok(resp)));
        }
        futures::future::Either::Right(self.inner.call(req))
    }
}

/// The hosts a browser request may name (`Host`, or `:authority` over
/// HTTP/2), against DNS rebinding: a page of `attacker.test` whose name
/// the attacker re-points at the gateway's address is same-origin with
/// itself, so the browser lets it call the gateway, but its requests
/// still name `attacker.test`. Allowed: loopback names (`localhost`,
/// `*.localhost`, any loopback address), the listen address, the address
/// the connection came in on (a listener on `0.0.0.0` is reachable by
/// each of the host's addresses), and `[web] allowed_hosts`; the port is
/// not compared.
#[derive(Debug, Clone)]
pub struct AllowedHosts {
    listen: std::net::IpAddr,
    /// Lower-case host names or addresses, without port.
    configured: std::sync::Arc<[String]>,
}

impl AllowedHosts {
    /// The hosts for a listener on `listen` with `[web] allowed_hosts`.
    pub fn new(listen: std::net::IpAddr, configured: &[String]) -> Self {
        AllowedHosts {
            listen,
            configured: configured.iter().map(|h| host_part(h)).collect(),
        }
    }

    /// Whether `authority` (`host[:port]`) may be served on a connection
    /// that came in at `local`.
    pub fn allows(&self, authority: &str, local: Option<std::net::IpAddr>) -> bool {
        let host = host_part(authority);
        if host == "localhost" || host.ends_with(".localhost") {
            return true;
        }
        if let Ok(ip) = host.parse::<std::net::IpAddr>()
            && (ip.is_loopback()
                || (ip == self.listen && !ip.is_unspecified())
                || Some(ip) == local)
        {
            return true;
        }
        self.configured.contains(&host)
    }
}

/// The host of `host[:port]` or `[v6][:port]`, lower-case, without a
/// trailing dot and without the brackets of an IPv6 address.
fn host_part(authority: &str) -> String {
    let a = authority.trim();
    let host = match a.strip_prefix('[') {
        Some(rest) => rest.split(']').next().unwrap_or(""),
        None => match a.rsplit_once(':') {
            Some((h, port)) if !h.contains(':') && port.bytes().all(|b| b.is_ascii_digit()) => h,
            _ => a,
        },
    };
    host.trim_end_matches('.').to_ascii_lowercase()
}

/// Whether a request can come from a browser: HTTP/1.x (browsers speak
/// gRPC-Web and load pages over it), an `Origin` header (a browser sends
/// it with every `POST`), or a gRPC-Web content type. A native gRPC call
/// (HTTP/2, `application/grpc`, no `Origin`) cannot come from a page:
/// browsers speak HTTP/2 only over TLS, where a rebound name fails the
/// certificate check, and always send `Origin` with a `POST`.
fn from_a_browser<B>(req: &Request<B>) -> bool {
    req.version() < http::Version::HTTP_2
        || req.headers().contains_key(header::ORIGIN)
        || is_grpc_web(req)
}

fn is_grpc_web<B>(req: &Request<B>) -> bool {
    req.headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|ct| ct.starts_with("application/grpc-web"))
}

/// Refuses browser requests that name a host not in [`AllowedHosts`]
/// (outermost on the listener, so that neither the dashboard nor the API
/// answers them): HTTP 403, or a gRPC(-Web) `PERMISSION_DENIED` with
/// reason `HOST_NOT_ALLOWED`, naming the setting that allows the host.
#[derive(Debug, Clone)]
pub struct HostCheckLayer {
    hosts: AllowedHosts,
}

impl HostCheckLayer {
    /// The layer for `hosts`.
    pub fn new(hosts: AllowedHosts) -> Self {
        HostCheckLayer { hosts }
    }
}

impl<S> tower::Layer<S> for HostCheckLayer {
    type Service = HostCheckService<S>;
    fn layer(&self, inner: S) -> Self::Service {
        HostCheckService {
            inner,
            hosts: self.hosts.clone(),
        }
    }
}

/// See [`HostCheckLayer`].
#[derive(Debug, Clone)]
pub struct HostCheckService<S> {
    inner: S,
    hosts: AllowedHosts,
}

impl<S> HostCheckService<S> {
    /// The first host the request names that is not allowed.
    fn refused_host<B>(&self, req: &Request<B>) -> Option<String> {
        if !from_a_browser(req) {
            return None;
        }
        let local = req
            .extensions()
            .get::<crate::security::tls::ConnInfo>()
            .and_then(|c| c.local_addr)
            .map(|a| a.ip());
        let authority = req.uri().authority().map(|a| a.as_str().to_string());
        let host = req
            .headers()
            .get_all(header::HOST)
            .iter()
            .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned());
        authority
            .into_iter()
            .chain(host)
            .find(|h| !self.hosts.allows(h, local))
    }
}

/// The refusal of a request naming `host`.
fn host_refusal<B>(req: &Request<B>, host: &str) -> Response<Body> {
    let shown: String = host.chars().take(100).collect();
    let message = format!(
        "requests for host {shown:?} are not served: a page under a name the gateway does not          know could be a DNS rebinding attack; to reach the gateway by this name, add it to          [web] allowed_hosts in the gateway's configuration"
    );
    tracing::debug!(host = %shown, "request refused: host not allowed");
    let content_type = req.headers().get(header::CONTENT_TYPE).cloned();
    if content_type
        .as_ref()
        .and_then(|v| v.to_str().ok())
        .is_some_and(|ct| ct.starts_with("application/grpc"))
    {
        let status =
            crate::security::refused(tonic::Code::PermissionDenied, "HOST_NOT_ALLOWED", message);
        let mut resp = status.into_http::<Body>();
        // A trailers-only answer, in the caller's own content type
        // (gRPC-Web clients read the status from these headers).
        if let Some(ct) = content_type {
            resp.headers_mut().insert(header::CONTENT_TYPE, ct);
        }
        return resp;
    }
    let mut resp = Response::new(Body::new(http_body_util::Full::new(Bytes::from(
        message + "\n",
    ))));
    *resp.status_mut() = StatusCode::FORBIDDEN;
    resp.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/plain; charset=utf-8"),
    );
    resp
}

impl<S> tower::Service<Request<Body>> for HostCheckService<S>
where
    S: tower::Service<Request<Body>, Response = Response<Body>>,
    S::Future: Send + 'static,
{
    type Response = Response<Body>;
    type Error = S::Error;
    type Future =
        futures::future::Either<std::future::Ready<Result<Response<Body>, S::Error>>, S::Future>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: Request<Body>) -> Self::Future {
        if let Some(host) = self.refused_host(&req) {
            let resp = host_refusal(&req, &host);
            return futures::future::Either::Left(std::future::ready(Ok(resp)));
        }
        futures::future::Either::Right(self.inner.call(req))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hosts_are_loopback_names_the_listen_address_the_local_address_or_configured() {
        let any: std::net::IpAddr = "0.0.0.0".parse().unwrap();
        let lan: std::net::IpAddr = "192.168.1.20".parse().unwrap();
        let h = AllowedHosts::new(any, &["Gateway.Example:8443".into(), "10.0.0.9".into()]);
        for ok in [
            "localhost",
            "localhost:50051",
            "LOCALHOST.",
            "dash.localhost:3000",
            "127.0.0.1",
            "127.0.0.1:50051",
            "[::1]",
            "[::1]:50051",
            "gateway.example",
            "gateway.example:50051",
            "10.0.0.9:1",
        ] {
            assert!(h.allows(ok, None), "{ok}");
        }
        for bad in [
            "attacker.test",
            "attacker.test:50051",
            "localhost.attacker.test",
            "0.0.0.0",
            "192.168.1.20",
            "",
            "gateway.example.attacker.test",
        ] {
            assert!(!h.allows(bad, None), "{bad}");
        }
        // The address the connection came in on.
        assert!(h.allows("192.168.1.20:50051", Some(lan)));
        // A listener on one address is reachable by it.
        assert!(AllowedHosts::new(lan, &[]).allows("192.168.1.20:50051", None));
    }

    #[test]
    fn only_browser_requests_are_checked() {
        let req = |version, origin: bool, ct: &str| {
            let mut b = Request::builder()
                .version(version)
                .uri("http://attacker.test/cangate.v1.Bus/ListBuses")
                .header(header::CONTENT_TYPE, ct);
            if origin {
                b = b.header(header::ORIGIN, "http://attacker.test");
            }
            b.body(()).unwrap()
        };
        use http::Version;
        assert!(!from_a_browser(&req(
            Version::HTTP_2,
            false,
            "application/grpc"
        )));
        assert!(from_a_browser(&req(
            Version::HTTP_2,
            true,
            "application/grpc"
        )));
        assert!(from_a_browser(&req(
            Version::HTTP_2,
            false,
            "application/grpc-web+proto"
        )));
        assert!(from_a_browser(&req(
            Version::HTTP_11,
            false,
            "application/grpc"
        )));
    }

    #[test]
    fn files_have_their_types_and_unknown_paths_are_404() {
        let r = answer(true, "/", false);
        assert_eq!(r.status(), StatusCode::OK);
        assert_eq!(
            r.headers()[header::CONTENT_TYPE],
            "text/html; charset=utf-8"
        );
        assert!(r.headers().contains_key(header::CONTENT_SECURITY_POLICY));
        assert_eq!(
            answer(true, "/app.js", false).headers()[header::CONTENT_TYPE],
            "text/javascript; charset=utf-8"
        );
        assert_eq!(answer(true, "/nope", false).status(), StatusCode::NOT_FOUND);
        assert_eq!(
            answer(true, "/../Cargo.toml", false).status(),
            StatusCode::NOT_FOUND
        );
        assert_eq!(answer(false, "/", false).status(), StatusCode::NOT_FOUND);
        // The page loads its script and style from files, never inline
        // (the policy would refuse them).
        let html = std::str::from_utf8(ASSETS[0].body).unwrap();
        assert!(html.contains("src=\"/app.js\""), "{html}");
        assert!(!html.contains("<script>"), "no inline script");
    }
}
