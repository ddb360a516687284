//! This site's signing key and the remote sites' certificates, for the end-to-end
//! signatures of [`crate::signed`]: the files of `[federation.tls]`, with the libraries
//! Zenoh's TLS link already uses (rustls 0.23 with ring, and its WebPKI).
//!
//! A remote site's certificate must chain to one of `tls.trusted_cas`, carry the
//! clientAuth usage (as every site certificate does) and name the site as its common name,
//! the same rules as on a TLS link; it is taken from the site's identity frame and checked
//! again for its dates at every use.

use std::collections::HashMap;
use std::time::Duration;

use rustls::SignatureScheme;
use rustls::crypto::WebPkiSupportedAlgorithms;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer, TrustAnchor, UnixTime};
use rustls::sign::Signer;

use tracing::warn;

use crate::config::{ConfigError, TlsConfig, invalid};
use crate::signed::{self, SignatureError, Verify};
use crate::tls::leaf_checks;

/// The schemes this site signs with, by its key's type.
const SCHEMES: &[SignatureScheme] = &[
    SignatureScheme::ED25519,
    SignatureScheme::ECDSA_NISTP256_SHA256,
    SignatureScheme::ECDSA_NISTP384_SHA384,
    SignatureScheme::RSA_PSS_SHA256,
];

fn algorithms() -> WebPkiSupportedAlgorithms {
    rustls::crypto::ring::default_provider().signature_verification_algorithms
}

fn read(key: &str, path: &std::path::Path) -> Result<Vec<u8>, ConfigError> {
    std::fs::read(path).map_err(|e| invalid(key, format!("cannot read {}: {e}", path.display())))
}

fn certificates(key: &str, path: &std::path::Path) -> Result<Vec<Vec<u8>>, ConfigError> {
    let bytes = read(key, path)?;
    CertificateDer::pem_slice_iter(&bytes)
        .map(|c| c.map(|c| c.to_vec()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| {
            invalid(
                key,
                format!("{}: not PEM certificates: {e}", path.display()),
            )
        })
}

/// This site's key, signing the lease records and orders it publishes.
pub(crate) struct SiteSigner {
    /// The key with its scheme, chosen once.
    signer: Box<dyn Signer>,
    identity: Vec<u8>,
}

impl std::fmt::Debug for SiteSigner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        // Never the key.
        f.debug_struct("SiteSigner")
            .field("identity_bytes", &self.identity.len())
            .finish_non_exhaustive()
    }
}

impl SiteSigner {
    /// The key and certificate chain of `tls` (checked at start by `tls::check_files`).
    pub(crate) fn load(tls: &TlsConfig) -> Result<Self, ConfigError> {
        let chain = certificates("tls.certificate", &tls.certificate)?;
        let bytes = read("tls.private_key", &tls.private_key)?;
        let bad = |problem: String| {
            invalid(
                "tls.private_key",
                format!("{}: {problem}", tls.private_key.display()),
            )
        };
        let der = PrivateKeyDer::from_pem_slice(&bytes)
            .map_err(|e| bad(format!("no PEM private key: {e}")))?;
        let key = rustls::crypto::ring::sign::any_supported_type(&der)
            .map_err(|e| bad(format!("cannot sign with it: {e}")))?;
        let signer = key.choose_scheme(SCHEMES).ok_or_else(|| {
            bad(format!(
                "a {:?} key signs with none of Ed25519, ECDSA P-256 or P-384, RSA-PSS",
                key.algorithm()
            ))
        })?;
        Ok(Self {
            signer,
            identity: signed::encode_identity(&chain),
        })
    }

    /// Signs `frame` for `key_expr` in place ([`signed::seal`]).
    pub(crate) fn seal(&self, key_expr: &str, frame: &mut Vec<u8>) -> Result<(), rustls::Error> {
        signed::seal(frame, key_expr, |message| {
            Ok((u16::from(self.signer.scheme()), self.signer.sign(message)?))
        })
    }

    /// The identity frame this site answers `shoal/<site>/identity` with.
    pub(crate) fn identity(&self) -> &[u8] {
        &self.identity
    }
}

/// `frame` for `key`, signed when this site signs; `None` (logged) if signing failed.
pub(crate) fn sealed(
    signer: Option<&SiteSigner>,
    key: &str,
    mut frame: Vec<u8>,
) -> Option<Vec<u8>> {
    let Some(signer) = signer else {
        return Some(frame);
    };
    match signer.seal(key, &mut frame) {
        Ok(()) => Some(frame),
        Err(e) => {
            warn!(key, error = %e, "not sent: cannot sign it");
            None
        }
    }
}

/// A remote site's certificate, as checked.
#[derive(Debug)]
struct Known {
    leaf: CertificateDer<'static>,
    not_before_ms: i64,
    not_after_ms: i64,
}

/// The remote sites' certificates, checked against `tls.trusted_cas`.
#[derive(Debug)]
pub(crate) struct SiteCertificates {
    anchors: Vec<TrustAnchor<'static>>,
    known: HashMap<String, Known>,
}

impl SiteCertificates {
    /// The trust anchors of `tls.trusted_cas` and no site known yet.
    pub(crate) fn load(tls: &TlsConfig) -> Result<Self, ConfigError> {
        let key = "tls.trusted_cas";
        let mut anchors = Vec::new();
        for (i, der) in certificates(key, &tls.trusted_cas)?.into_iter().enumerate() {
            let der = CertificateDer::from(der);
            let anchor = webpki::anchor_from_trusted_cert(&der).map_err(|e| {
                invalid(
                    key,
                    format!("{}: certificate {}: {e}", tls.trusted_cas.display(), i + 1),
                )
            })?;
            anchors.push(anchor.to_owned());
        }
        Ok(Self {
            anchors,
            known: HashMap::new(),
        })
    }

    fn identity_error(site: &str, problem: impl Into<String>) -> SignatureError {
        SignatureError::Identity {
            site: site.to_owned(),
            problem: problem.into(),
        }
    }
}

fn unix_time(now_ms: i64) -> UnixTime {
    UnixTime::since_unix_epoch(Duration::from_millis(u64::try_from(now_ms).unwrap_or(0)))
}

impl Verify for SiteCertificates {
    fn knows(&self, site: &str, now_ms: i64) -> bool {
        self.known
            .get(site)
            .is_some_and(|k| (k.not_before_ms..=k.not_after_ms).contains(&now_ms))
    }

    fn verify(
        &self,
        site: &str,
        scheme: u16,
        message: &[u8],
        signature: &[u8],
        now_ms: i64,
    ) -> Result<(), SignatureError> {
        if !self.knows(site, now_ms) {
            return Err(SignatureError::UnknownSigner(site.to_owned()));
        }
        let known = &self.known[site];
        let algs = algorithms()
            .mapping
            .iter()
            .find(|(s, _)| u16::from(*s) == scheme)
            .map(|(_, algs)| *algs)
            .ok_or(SignatureError::Scheme(scheme))?;
        let leaf = webpki::EndEntityCert::try_from(&known.leaf).map_err(|_| SignatureError::Bad)?;
        if algs
            .iter()
            .any(|alg| leaf.verify_signature(*alg, message, signature).is_ok())
        {
            Ok(())
        } else {
            Err(SignatureError::Bad)
        }
    }

    fn learn(&mut self, site: &str, chain: &[&[u8]], now_ms: i64) -> Result<(), SignatureError> {
        let (leaf, intermediates) = chain
            .split_first()
            .ok_or_else(|| Self::identity_error(site, "no certificate"))?;
        let (not_before_ms, not_after_ms) =
            leaf_checks(leaf, site).map_err(|p| Self::identity_error(site, p))?;
        let leaf = CertificateDer::from(leaf.to_vec());
        let intermediates: Vec<CertificateDer<'static>> = intermediates
            .iter()
            .map(|c| CertificateDer::from(c.to_vec()))
            .collect();
        let ee = webpki::EndEntityCert::try_from(&leaf)
            .map_err(|e| Self::identity_error(site, format!("not a certificate: {e}")))?;
        ee.verify_for_usage(
            algorithms().all,
            &self.anchors,
            &intermediates,
            unix_time(now_ms),
            webpki::KeyUsage::client_auth(),
            None,
            None,
        )
        .map_err(|e| {
            Self::identity_error(
                site,
                format!("not a site certificate of a trusted CA valid now ({e})"),
            )
        })?;
        self.known.insert(
            site.to_owned(),
            Known {
                leaf,
                not_before_ms,
                not_after_ms,
            },
        );
        Ok(())
    }

    fn forget(&mut self, site: &str) {
        self.known.remove(site);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tls::tests::site_files;
    use crate::wire::{KIND_LEASE, VERSION};

    const KEY: &str = "shoal/ship/leases/auv-1";

    fn chain(tls: &TlsConfig) -> Vec<Vec<u8>> {
        certificates("tls.certificate", &tls.certificate).unwrap()
    }

    fn learn(v: &mut SiteCertificates, site: &str, tls: &TlsConfig) -> Result<(), SignatureError> {
        let chain = chain(tls);
        let refs: Vec<&[u8]> = chain.iter().map(Vec::as_slice).collect();
        v.learn(site, &refs, shoal_model::now_ms())
    }

    fn check(
        v: &SiteCertificates,
        site: &str,
        key: &str,
        bytes: &[u8],
    ) -> Result<Vec<u8>, SignatureError> {
        let opened = signed::open(key, bytes)?.ok_or(SignatureError::Unsigned)?;
        v.verify(
            site,
            opened.scheme,
            &opened.message,
            opened.signature,
            shoal_model::now_ms(),
        )?;
        Ok(opened.frame)
    }

    #[test]
    fn a_sealed_frame_verifies_with_the_sites_certificate_and_nothing_else() {
        let (_dir, ship) = site_files("ship");
        let signer = SiteSigner::load(&ship).unwrap();
        let frame = vec![VERSION, KIND_LEASE, 1, 2, 3];
        let mut sealed = frame.clone();
        signer.seal(KEY, &mut sealed).unwrap();
        // Ed25519: 64 bytes of signature and 4 of scheme and length.
        assert_eq!(sealed.len(), frame.len() + 68);

        let mut v = SiteCertificates::load(&ship).unwrap();
        assert_eq!(
            check(&v, "ship", KEY, &sealed),
            Err(SignatureError::UnknownSigner("ship".into()))
        );
        learn(&mut v, "ship", &ship).unwrap();
        assert!(v.knows("ship", shoal_model::now_ms()));
        assert_eq!(check(&v, "ship", KEY, &sealed).unwrap(), frame);

        // Any byte changed, or another key expression: refused.
        for i in 0..sealed.len() - 4 {
            let mut t = sealed.clone();
            t[i] ^= 0x01;
            assert!(check(&v, "ship", KEY, &t).is_err(), "byte {i}");
        }
        assert_eq!(
            check(&v, "ship", "shoal/ship/leases/auv-2", &sealed),
            Err(SignatureError::Bad)
        );

        // The identity frame carries the chain.
        let id = signed::decode_identity(signer.identity()).unwrap();
        assert_eq!(
            id,
            chain(&ship).iter().map(Vec::as_slice).collect::<Vec<_>>()
        );
    }

    #[test]
    fn a_certificate_of_another_ca_or_naming_another_site_is_not_learnt() {
        let (_dir, ship) = site_files("ship");
        let (_other_dir, other_ca) = site_files("ship");
        let mut v = SiteCertificates::load(&ship).unwrap();
        // Same name, another CA: a forger with a CA of its own.
        let e = learn(&mut v, "ship", &other_ca).unwrap_err();
        assert_eq!(e.reason(), "signature:identity");
        assert!(e.to_string().contains("trusted CA"), "{e}");
        // A genuine certificate offered as another site's.
        let e = learn(&mut v, "shore", &ship).unwrap_err();
        assert!(e.to_string().contains("common name"), "{e}");
        assert!(!v.knows("ship", shoal_model::now_ms()));
        // Garbage.
        let e = v
            .learn("ship", &[b"junk"], shoal_model::now_ms())
            .unwrap_err();
        assert_eq!(e.reason(), "signature:identity");
        // Learnt, then forgotten.
        learn(&mut v, "ship", &ship).unwrap();
        v.forget("ship");
        assert!(!v.knows("ship", shoal_model::now_ms()));
    }

    #[test]
    fn a_signature_made_with_another_key_of_the_same_name_is_refused() {
        let (_dir, ship) = site_files("ship");
        let (_other_dir, impostor) = site_files("ship");
        let mut sealed = vec![VERSION, KIND_LEASE, 9];
        SiteSigner::load(&impostor)
            .unwrap()
            .seal(KEY, &mut sealed)
            .unwrap();
        let mut v = SiteCertificates::load(&ship).unwrap();
        learn(&mut v, "ship", &ship).unwrap();
        assert_eq!(check(&v, "ship", KEY, &sealed), Err(SignatureError::Bad));
        // An unknown scheme code.
        let n = sealed.len();
        sealed[n - 4..n - 2].copy_from_slice(&0xfefe_u16.to_le_bytes());
        assert_eq!(
            check(&v, "ship", KEY, &sealed),
            Err(SignatureError::Scheme(0xfefe))
        );
    }

    #[test]
    fn an_expired_certificate_is_not_known() {
        let (_dir, ship) = site_files("ship");
        let mut v = SiteCertificates::load(&ship).unwrap();
        learn(&mut v, "ship", &ship).unwrap();
        let later = shoal_model::now_ms() + 4000 * 86_400_000;
        assert!(!v.knows("ship", later));
        let e = v.verify("ship", 0x0807, b"m", &[0; 64], later).unwrap_err();
        assert_eq!(e, SignatureError::UnknownSigner("ship".into()));
    }
}
