//! The TLS files of `[federation.tls]`, checked at start as Zenoh's TLS link
//! (zenoh-link-tls: rustls 0.23, ring provider) will load them.
//!
//! Zenoh reads these files only when it opens a link: a bad file on a site that connects
//! would show only as a refused connection logged at every retry. So each file is read and
//! parsed here first, with the same library, and a start-up error names the key, the file
//! and the problem (never the key's content).

use std::path::Path;

use crate::config::{ConfigError, TlsConfig, invalid};

/// Checks the three files of `tls` for site `site` at `now_ms`; returns when this site's
/// certificate expires (ms since the Unix epoch).
///
/// - `tls.certificate`: PEM certificates (leaf first), the leaf's common name is `site`
///   and it is valid now;
/// - `tls.private_key`: a PEM private key, not readable by group or others, that rustls
///   accepts as the key of that certificate;
/// - `tls.trusted_cas`: at least one PEM CA certificate, each usable as a trust anchor.
#[cfg(feature = "transport")]
pub(crate) fn check_files(site: &str, tls: &TlsConfig, now_ms: i64) -> Result<i64, ConfigError> {
    use std::sync::Arc;

    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, PrivateKeyDer};

    let provider = Arc::new(rustls::crypto::ring::default_provider());

    let (key, path) = ("tls.certificate", &tls.certificate);
    let bytes = read_bytes(path, key)?;
    let chain = CertificateDer::pem_slice_iter(&bytes)
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| bad(key, path, format!("not PEM certificates: {e}")))?;
    let leaf = chain
        .first()
        .ok_or_else(|| bad(key, path, "holds no PEM CERTIFICATE block"))?;
    let (not_before_ms, not_after_ms) = leaf_checks(leaf, site).map_err(|p| bad(key, path, p))?;
    if now_ms < not_before_ms {
        return Err(bad(key, path, "not valid yet (check this host's clock)"));
    }
    if now_ms > not_after_ms {
        return Err(bad(
            key,
            path,
            "expired: issue a new one (shoal keys site-cert)",
        ));
    }

    let (key, path) = ("tls.private_key", &tls.private_key);
    private_to_owner(path, key)?;
    let bytes = read_bytes(path, key)?;
    let private = PrivateKeyDer::from_pem_slice(&bytes)
        .map_err(|e| bad(key, path, format!("no PEM private key: {e}")))?;
    rustls::ServerConfig::builder_with_provider(Arc::clone(&provider))
        .with_protocol_versions(&[&rustls::version::TLS13])
        .map_err(|e| bad(key, path, e.to_string()))?
        .with_no_client_auth()
        .with_single_cert(chain, private)
        .map_err(|e| {
            bad(
                key,
                path,
                format!("refused with {}: {e}", tls.certificate.display()),
            )
        })?;

    let (key, path) = ("tls.trusted_cas", &tls.trusted_cas);
    let bytes = read_bytes(path, key)?;
    let mut roots = rustls::RootCertStore::empty();
    for (i, cert) in CertificateDer::pem_slice_iter(&bytes).enumerate() {
        let cert = cert.map_err(|e| bad(key, path, format!("not PEM certificates: {e}")))?;
        roots
            .add(cert)
            .map_err(|e| bad(key, path, format!("certificate {}: {e}", i + 1)))?;
    }
    if roots.is_empty() {
        return Err(bad(key, path, "holds no PEM CERTIFICATE block"));
    }
    rustls::server::WebPkiClientVerifier::builder_with_provider(Arc::new(roots), provider)
        .build()
        .map_err(|e| bad(key, path, e.to_string()))?;
    Ok(not_after_ms)
}

/// Without the transport (the fuzz build) the files are only read.
#[cfg(not(feature = "transport"))]
pub(crate) fn check_files(_site: &str, tls: &TlsConfig, _now_ms: i64) -> Result<i64, ConfigError> {
    private_to_owner(&tls.private_key, "tls.private_key")?;
    for (key, path) in [
        ("tls.certificate", &tls.certificate),
        ("tls.private_key", &tls.private_key),
        ("tls.trusted_cas", &tls.trusted_cas),
    ] {
        read_bytes(path, key)?;
    }
    Ok(i64::MAX)
}

/// The leaf's validity (ms) after checking its common name is the site's.
#[cfg(feature = "transport")]
pub(crate) fn leaf_checks(der: &[u8], site: &str) -> Result<(i64, i64), String> {
    let (_, x509) = x509_parser::parse_x509_certificate(der)
        .map_err(|e| format!("not an X.509 certificate: {e}"))?;
    let cn = x509
        .subject()
        .iter_common_name()
        .next()
        .and_then(|cn| cn.as_str().ok())
        .unwrap_or("");
    if cn != site {
        return Err(format!(
            "its common name is {cn:?}, not this site's name {site:?} (the name remote \
             sites' access control knows it by)"
        ));
    }
    let v = x509.validity();
    Ok((
        v.not_before.timestamp().saturating_mul(1000),
        v.not_after.timestamp().saturating_mul(1000),
    ))
}

fn read_bytes(path: &Path, key: &str) -> Result<Vec<u8>, ConfigError> {
    std::fs::read(path).map_err(|e| invalid(key, format!("cannot read {}: {e}", path.display())))
}

/// Refuses a private key that group or others may read (as the station's key store does).
fn private_to_owner(path: &Path, key: &str) -> Result<(), ConfigError> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt as _;
        let meta = std::fs::metadata(path)
            .map_err(|e| invalid(key, format!("cannot read {}: {e}", path.display())))?;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            return Err(bad(
                key,
                path,
                format!("mode {mode:o} lets others read the private key: chmod 600"),
            ));
        }
    }
    #[cfg(not(unix))]
    let _ = (path, key);
    Ok(())
}

fn bad(key: &str, path: &Path, problem: impl std::fmt::Display) -> ConfigError {
    invalid(key, format!("{}: {problem}", path.display()))
}

#[cfg(test)]
#[cfg(feature = "transport")]
pub(crate) mod tests {
    use super::*;

    const DAY: i64 = 86_400_000;

    /// A directory with a site certificate, its key and a CA bundle, issued as `shoal keys
    /// site-cert` does (the station key store's Ed25519 CA).
    pub(crate) fn site_files(site: &str) -> (tempfile::TempDir, TlsConfig) {
        let dir = tempfile::tempdir().unwrap();
        let store = shoal_security::KeyStore::init(&dir.path().join("store"), "ccs").unwrap();
        let out = dir.path().join("fed");
        let names = [shoal_security::SiteName::parse("127.0.0.1").unwrap()];
        store.issue_site(site, &names, &out).unwrap();
        let tls = TlsConfig {
            enabled: true,
            certificate: out.join(format!("{site}.crt")),
            private_key: out.join(format!("{site}.key")),
            trusted_cas: out.join(format!("{site}-ca.crt")),
            verify_name: true,
        };
        (dir, tls)
    }

    fn now() -> i64 {
        shoal_model::now_ms()
    }

    #[test]
    fn the_station_cas_ed25519_site_certificate_is_accepted_by_rustls() {
        let (_dir, tls) = site_files("ship");
        let until = check_files("ship", &tls, now()).unwrap();
        assert!(until > now() + 300 * DAY, "{until}");
    }

    #[test]
    fn each_bad_file_is_named_with_its_key() {
        let (dir, tls) = site_files("ship");
        let error = |edit: &dyn Fn(&mut TlsConfig)| {
            let mut t = tls.clone();
            edit(&mut t);
            check_files("ship", &t, now()).unwrap_err().to_string()
        };
        let missing = dir.path().join("missing.pem");
        let e = error(&|t| t.certificate = missing.clone());
        assert!(
            e.starts_with("federation.tls.certificate: cannot read"),
            "{e}"
        );
        assert!(e.contains("missing.pem"), "{e}");
        let e = error(&|t| t.trusted_cas = missing.clone());
        assert!(
            e.starts_with("federation.tls.trusted_cas: cannot read"),
            "{e}"
        );

        let junk = dir.path().join("junk.pem");
        std::fs::write(&junk, "not a pem file\n").unwrap();
        {
            use std::os::unix::fs::PermissionsExt as _;
            std::fs::set_permissions(&junk, std::fs::Permissions::from_mode(0o600)).unwrap();
        }
        let e = error(&|t| t.certificate = junk.clone());
        assert!(e.starts_with("federation.tls.certificate:"), "{e}");
        assert!(e.contains("no PEM CERTIFICATE"), "{e}");
        let e = error(&|t| t.trusted_cas = junk.clone());
        assert!(e.starts_with("federation.tls.trusted_cas:"), "{e}");

        // Another site's key: rustls refuses the pair.
        let (_other_dir, other) = site_files("ship");
        let e = error(&|t| t.private_key = other.private_key.clone());
        assert!(e.starts_with("federation.tls.private_key:"), "{e}");
        assert!(e.contains("refused with"), "{e}");
        // A key file others can read.
        let open = dir.path().join("open.key");
        std::fs::copy(&tls.private_key, &open).unwrap();
        {
            use std::os::unix::fs::PermissionsExt as _;
            std::fs::set_permissions(&open, std::fs::Permissions::from_mode(0o644)).unwrap();
        }
        let e = error(&|t| t.private_key = open.clone());
        assert!(e.contains("chmod 600"), "{e}");
        // No key in the file.
        let e = error(&|t| t.private_key = junk.clone());
        assert!(e.starts_with("federation.tls.private_key:"), "{e}");
        assert!(e.contains("no PEM private key"), "{e}");
    }

    #[test]
    fn the_certificate_must_name_this_site_and_be_valid_now() {
        let (_dir, tls) = site_files("ship");
        let e = check_files("shore", &tls, now()).unwrap_err().to_string();
        assert!(e.contains("its common name is \"ship\""), "{e}");
        let e = check_files("ship", &tls, now() + 400 * DAY)
            .unwrap_err()
            .to_string();
        assert!(e.contains("expired"), "{e}");
        let e = check_files("ship", &tls, now() - DAY)
            .unwrap_err()
            .to_string();
        assert!(e.contains("not valid yet"), "{e}");
    }
}
