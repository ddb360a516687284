//! The revocation list: a standard X.509 CRL signed by the station CA, so `openssl crl` can
//! read it and nobody can add or drop an entry without the CA key.

use std::collections::BTreeMap;
use std::path::Path;

use rcgen::{CertificateRevocationListParams, KeyIdMethod, RevokedCertParams, SerialNumber};
use x509_parser::oid_registry::OID_SIG_ED25519;
use x509_parser::x509::ReasonCode;

use crate::cert::{Certificate, PrivateKey, TrustAnchor, is_canonical_signed, issuer, key_id};
use crate::files::{self, FileError, FileProblem};
use crate::util;

/// PEM label of the revocation list.
pub const CRL_PEM_LABEL: &str = "X509 CRL";

/// Why a certificate was revoked (the RFC 5280 reason codes Shoal uses).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum RevokeReason {
    /// No reason given.
    Unspecified,
    /// The private key (or the vehicle) may be in someone else's hands.
    KeyCompromise,
    /// Replaced by a new certificate (rotation).
    Superseded,
    /// The vehicle left the fleet.
    CessationOfOperation,
}

impl RevokeReason {
    fn to_rcgen(self) -> rcgen::RevocationReason {
        match self {
            Self::Unspecified => rcgen::RevocationReason::Unspecified,
            Self::KeyCompromise => rcgen::RevocationReason::KeyCompromise,
            Self::Superseded => rcgen::RevocationReason::Superseded,
            Self::CessationOfOperation => rcgen::RevocationReason::CessationOfOperation,
        }
    }

    fn from_code(code: ReasonCode) -> Self {
        if code == ReasonCode::KeyCompromise {
            Self::KeyCompromise
        } else if code == ReasonCode::Superseded {
            Self::Superseded
        } else if code == ReasonCode::CessationOfOperation {
            Self::CessationOfOperation
        } else {
            Self::Unspecified
        }
    }

    /// A short name for listings, e.g. `superseded`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Unspecified => "unspecified",
            Self::KeyCompromise => "key-compromise",
            Self::Superseded => "superseded",
            Self::CessationOfOperation => "cessation-of-operation",
        }
    }
}

/// One revoked certificate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Revoked {
    /// When the CA revoked it, ms since the Unix epoch (whole seconds).
    pub revoked_ms: i64,
    /// Why.
    pub reason: RevokeReason,
}

/// The set of revoked certificate serial numbers, as signed by the CA.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RevocationList {
    number: u64,
    this_update_ms: i64,
    next_update_ms: i64,
    entries: BTreeMap<String, Revoked>,
}

/// Why a revocation list was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CrlError {
    /// Not PEM, or not an X.509 CRL.
    #[error("not an X.509 revocation list: {0}")]
    Parse(String),
    /// Signed by another key or issuer than the station CA, or not with Ed25519.
    #[error("its signature does not verify against the station CA")]
    BadSignature,
}

impl RevocationList {
    /// An empty list (number 0); a freshly initialised store signs and writes one.
    pub fn empty(now_ms: i64, validity_ms: i64) -> Self {
        Self {
            number: 0,
            this_update_ms: now_ms,
            next_update_ms: now_ms.saturating_add(validity_ms),
            entries: BTreeMap::new(),
        }
    }

    /// Whether the certificate with this serial (lower-case hex) is revoked.
    pub fn is_revoked(&self, serial: &str) -> bool {
        self.entries.contains_key(serial)
    }

    /// The entry for a serial number, if revoked.
    pub fn get(&self, serial: &str) -> Option<&Revoked> {
        self.entries.get(serial)
    }

    /// All entries, by serial number.
    pub fn entries(&self) -> impl Iterator<Item = (&str, &Revoked)> {
        self.entries.iter().map(|(s, r)| (s.as_str(), r))
    }

    /// How many certificates are revoked.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether nothing is revoked.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The CRL number: grows by one each time the CA signs a new list.
    pub fn number(&self) -> u64 {
        self.number
    }

    /// When this list was signed.
    pub fn this_update_ms(&self) -> i64 {
        self.this_update_ms
    }

    /// When the CA promised a newer list by; past it the list is stale (the store re-signs).
    pub fn next_update_ms(&self) -> i64 {
        self.next_update_ms
    }

    /// A copy with `serial` added (if not already there), to be signed with [`Self::sign`].
    pub(crate) fn with_revoked(&self, serial: &str, revoked: Revoked) -> Self {
        let mut next = self.clone();
        next.entries.entry(serial.to_owned()).or_insert(revoked);
        next
    }

    /// Signs this list as CRL number `self.number + 1`, dated `now_ms`, valid for
    /// `validity_ms`; returns the new list and its PEM text.
    pub(crate) fn sign(
        &self,
        ca: &Certificate,
        ca_key: &PrivateKey,
        now_ms: i64,
        validity_ms: i64,
    ) -> Result<(Self, String), rcgen::Error> {
        let revoked_certs = self
            .entries
            .iter()
            .filter_map(|(serial, r)| {
                // Serials come from certificates we parsed, so they are hex; skip defensively.
                Some(RevokedCertParams {
                    serial_number: SerialNumber::from(hex::decode(serial).ok()?),
                    revocation_time: util::datetime(r.revoked_ms),
                    reason_code: Some(r.reason.to_rcgen()),
                    invalidity_date: None,
                })
            })
            .collect();
        let number = self.number.saturating_add(1);
        let params = CertificateRevocationListParams {
            this_update: util::datetime(now_ms),
            next_update: util::datetime(now_ms.saturating_add(validity_ms.max(1000))),
            crl_number: SerialNumber::from(number),
            issuing_distribution_point: None,
            revoked_certs,
            key_identifier_method: KeyIdMethod::PreSpecified(key_id(ca_key)),
        };
        let crl = params.signed_by(&issuer(ca, ca_key))?;
        let text = crl.pem()?;
        let signed = Self {
            number,
            this_update_ms: now_ms.div_euclid(1000) * 1000,
            next_update_ms: now_ms
                .saturating_add(validity_ms.max(1000))
                .div_euclid(1000)
                * 1000,
            entries: self.entries.clone(),
        };
        Ok((signed, text))
    }

    /// Parses a PEM CRL and checks that the station CA signed it.
    pub fn from_pem(text: &str, anchor: &TrustAnchor) -> Result<Self, CrlError> {
        let block = pem::parse(text).map_err(|e| CrlError::Parse(format!("not PEM: {e}")))?;
        if block.tag() != CRL_PEM_LABEL {
            return Err(CrlError::Parse(format!(
                "PEM block labelled {:?}, expected {CRL_PEM_LABEL:?}",
                block.tag()
            )));
        }
        Self::from_der(block.contents(), anchor)
    }

    /// Parses a DER CRL and checks that the station CA signed it.
    pub fn from_der(der: &[u8], anchor: &TrustAnchor) -> Result<Self, CrlError> {
        let (rest, crl) =
            x509_parser::parse_x509_crl(der).map_err(|e| CrlError::Parse(e.to_string()))?;
        if !rest.is_empty() {
            return Err(CrlError::Parse(format!(
                "{} bytes follow the list",
                rest.len()
            )));
        }
        let ca = anchor.certificate();
        let signature = ed25519_dalek::Signature::from_slice(&crl.signature_value.data)
            .map_err(|_| CrlError::BadSignature)?;
        if crl.signature_algorithm.algorithm != OID_SIG_ED25519
            || !is_canonical_signed(der, crl.tbs_cert_list.as_ref(), &crl.signature_value.data)
            || crl.issuer().as_raw() != ca.subject_raw()
            || ca
                .public_key()
                .verify_strict(crl.tbs_cert_list.as_ref(), &signature)
                .is_err()
        {
            return Err(CrlError::BadSignature);
        }
        let entries = crl
            .iter_revoked_certificates()
            .map(|r| {
                let reason = r.reason_code().map_or(RevokeReason::Unspecified, |(_, c)| {
                    RevokeReason::from_code(c)
                });
                (
                    hex::encode(r.raw_serial()),
                    Revoked {
                        revoked_ms: r.revocation_date.timestamp().saturating_mul(1000),
                        reason,
                    },
                )
            })
            .collect();
        let number = crl
            .crl_number()
            .and_then(|n| u64::try_from(n).ok())
            .unwrap_or(0);
        Ok(Self {
            number,
            this_update_ms: crl.last_update().timestamp().saturating_mul(1000),
            next_update_ms: crl
                .next_update()
                .map_or(i64::MAX, |t| t.timestamp().saturating_mul(1000)),
            entries,
        })
    }

    /// Loads and checks a PEM CRL file.
    pub fn load(path: &Path, anchor: &TrustAnchor) -> Result<Self, FileError> {
        let text = files::read_public(path)?;
        let block = files::parse_pem(path, &text, CRL_PEM_LABEL)?;
        Self::from_der(block.contents(), anchor).map_err(|e| {
            let problem = match e {
                CrlError::BadSignature => FileProblem::BadSignature,
                CrlError::Parse(m) => FileProblem::Invalid(format!("not an X.509 CRL: {m}")),
            };
            FileError::new(path, problem)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cert::self_signed_ca;

    const T0: i64 = 1_780_000_000_000;
    const DAY: i64 = 86_400_000;

    #[test]
    fn signed_list_round_trips_and_detects_tampering() {
        let key = PrivateKey::generate().unwrap();
        let ca = self_signed_ca(&key, "ccs", T0 - DAY, T0 + 100 * DAY).unwrap();
        let anchor = TrustAnchor::new(ca.clone()).unwrap();
        let serial = "7f0102030405060708090a0b0c0d0e0f";
        let list = RevocationList::empty(T0, DAY).with_revoked(
            serial,
            Revoked {
                revoked_ms: T0,
                reason: RevokeReason::Superseded,
            },
        );
        let (signed, text) = list.sign(&ca, &key, T0, 30 * DAY).unwrap();
        assert_eq!(signed.number(), 1);
        let back = RevocationList::from_pem(&text, &anchor).unwrap();
        assert_eq!(back, signed);
        assert!(back.is_revoked(serial));
        assert_eq!(back.get(serial).unwrap().reason, RevokeReason::Superseded);
        assert!(!back.is_revoked("01"));

        // Any flipped byte is refused: either it no longer parses or the signature fails.
        let der = pem::parse(&text).unwrap().into_contents();
        for i in 0..der.len() {
            let mut bad = der.clone();
            bad[i] ^= 0x01;
            assert!(RevocationList::from_der(&bad, &anchor).is_err(), "byte {i}");
        }

        // Another CA's list is refused.
        let other_key = PrivateKey::generate().unwrap();
        let other = self_signed_ca(&other_key, "ccs", T0 - DAY, T0 + DAY).unwrap();
        let (_, forged) = RevocationList::empty(T0, DAY)
            .sign(&other, &other_key, T0, DAY)
            .unwrap();
        assert_eq!(
            RevocationList::from_pem(&forged, &anchor),
            Err(CrlError::BadSignature)
        );
    }
}
