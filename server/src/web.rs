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

#[cfg(test)]
mod tests {
    use super::*;

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
