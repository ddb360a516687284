//! Optional TLS for the console (`[console.tls]`): rustls with the ring provider, a
//! certificate chain and its key from PEM files. With it, the session cookie is `Secure`
//! and the console's own origin is `https://...`.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use tokio_rustls::TlsAcceptor;
use tokio_rustls::rustls::pki_types::pem::PemObject;
use tokio_rustls::rustls::pki_types::{CertificateDer, PrivateKeyDer};
use tokio_rustls::rustls::{self, ServerConfig};

/// The `[console.tls]` section: serve the console over HTTPS. Both files empty (the
/// default): plain HTTP.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TlsConfig {
    /// The certificate chain, PEM, the console's own certificate first.
    pub cert: PathBuf,
    /// Its private key, PEM (PKCS#8, PKCS#1 or SEC1).
    pub key: PathBuf,
}

impl TlsConfig {
    /// True when TLS is configured (a certificate or a key is named).
    pub fn enabled(&self) -> bool {
        !self.cert.as_os_str().is_empty() || !self.key.as_os_str().is_empty()
    }
}

/// Why TLS cannot be set up.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TlsError {
    /// Only one of the two files is named.
    #[error("[console.tls] needs both cert and key")]
    Incomplete,
    /// A file cannot be read or holds no usable PEM item.
    #[error("[console.tls] {what} {path}: {why}")]
    File {
        /// `cert` or `key`.
        what: &'static str,
        /// The file.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// rustls refused the pair (the key does not match the certificate, say).
    #[error("[console.tls]: {0}")]
    Rustls(#[from] rustls::Error),
}

fn file_error(what: &'static str, path: &Path, why: &dyn std::fmt::Display) -> TlsError {
    TlsError::File {
        what,
        path: path.to_owned(),
        why: why.to_string(),
    }
}

/// The acceptor for `config`, or `None` when TLS is off.
pub(crate) fn acceptor(config: &TlsConfig) -> Result<Option<TlsAcceptor>, TlsError> {
    if !config.enabled() {
        return Ok(None);
    }
    if config.cert.as_os_str().is_empty() || config.key.as_os_str().is_empty() {
        return Err(TlsError::Incomplete);
    }
    let certs = CertificateDer::pem_file_iter(&config.cert)
        .map_err(|e| file_error("cert", &config.cert, &e))?
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| file_error("cert", &config.cert, &e))?;
    if certs.is_empty() {
        return Err(file_error("cert", &config.cert, &"no CERTIFICATE in it"));
    }
    let key = PrivateKeyDer::from_pem_file(&config.key)
        .map_err(|e| file_error("key", &config.key, &e))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut server = ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()?
        .with_no_client_auth()
        .with_single_cert(certs, key)?;
    // The console serves HTTP/1.1 only (its own hyper loop).
    server.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Some(TlsAcceptor::from(Arc::new(server))))
}
