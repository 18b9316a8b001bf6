//! The TLS client configuration of an `mqtts://` bridge (ring provider,
//! as the rest of the gateway).

use crate::config::BridgeConfig;
use rustls_pki_types::pem::PemObject;
use rustls_pki_types::{CertificateDer, PrivateKeyDer};
use std::path::Path;
use std::sync::Arc;
use tokio_rustls::rustls;

/// The system's CA bundle, when the bridge names no `ca`.
const SYSTEM_ROOTS: &str = "/etc/ssl/certs/ca-certificates.crt";

fn certs(what: &str, path: &Path) -> Result<Vec<CertificateDer<'static>>, String> {
    let pem = std::fs::read(path).map_err(|e| format!("{what} {}: {e}", path.display()))?;
    let certs = CertificateDer::pem_slice_iter(&pem)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| format!("{what} {}: {e}", path.display()))?;
    if certs.is_empty() {
        return Err(format!(
            "{what} {}: no CERTIFICATE in the file",
            path.display()
        ));
    }
    Ok(certs)
}

/// The rustls client configuration: the broker verified against `ca` (or
/// the system's roots), with the client certificate when given.
pub(super) fn client_config(b: &BridgeConfig) -> Result<Arc<rustls::ClientConfig>, String> {
    let ca = b.ca.as_deref().unwrap_or(Path::new(SYSTEM_ROOTS));
    let mut roots = rustls::RootCertStore::empty();
    for c in certs("ca", ca)? {
        roots
            .add(c)
            .map_err(|e| format!("ca {}: {e}", ca.display()))?;
    }
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let builder = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| e.to_string())?
        .with_root_certificates(roots);
    let config = match (&b.cert, &b.key) {
        (Some(cert), Some(key)) => {
            let chain = certs("cert", cert)?;
            // The key's content is never part of a message.
            let key = PrivateKeyDer::from_pem_file(key)
                .map_err(|_| format!("key {}: not a readable PEM private key", key.display()))?;
            builder
                .with_client_auth_cert(chain, key)
                .map_err(|e| format!("cert/key: {e}"))?
        }
        _ => builder.with_no_client_auth(),
    };
    Ok(Arc::new(config))
}
