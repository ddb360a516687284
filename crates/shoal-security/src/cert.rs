//! Ed25519 keys and X.509 certificates: issuing them (rcgen, with our own key so no C crypto
//! library is linked), parsing them (x509-parser) and checking that the station CA issued them
//! (ed25519-dalek over the to-be-signed bytes).
//!
//! Shoal's PKI has exactly two levels: a self-signed station CA and leaf certificates for the
//! station and each vehicle. Every certificate is Ed25519 (RFC 8410): one algorithm keeps the
//! verifier small, and Ed25519 signatures are 64 bytes, fast, and deterministic.

use std::fmt;
use std::path::Path;

use ed25519_dalek::{Signature, Signer as _, SigningKey, VerifyingKey};
use rcgen::{
    BasicConstraints, CertificateParams, DistinguishedName, DnType, ExtendedKeyUsagePurpose, IsCa,
    Issuer, KeyIdMethod, KeyUsagePurpose, SanType, SerialNumber,
};
use sha2::{Digest, Sha256};
use x509_parser::oid_registry::OID_SIG_ED25519;
use zeroize::Zeroizing;

use crate::files::{self, FileError, FileProblem};
use crate::identity::{Identity, IdentityError};
use crate::util::{self, RandomError};

/// PEM label of certificates.
pub const CERT_PEM_LABEL: &str = "CERTIFICATE";
/// PEM label of PKCS#8 private keys.
pub const KEY_PEM_LABEL: &str = "PRIVATE KEY";
/// Organisation written in every subject, so Shoal certificates are recognisable in tools.
const ORGANISATION: &str = "Shoal";

/// DER prefix of an RFC 8410 PKCS#8 v1 Ed25519 private key; the 32-byte seed follows.
///
/// SEQUENCE { INTEGER 0, SEQUENCE { OID 1.3.101.112 }, OCTET STRING { OCTET STRING (32) } },
/// exactly what `openssl genpkey -algorithm ed25519` writes, so keys move between tools.
const PKCS8_ED25519_PREFIX: [u8; 16] = [
    0x30, 0x2e, 0x02, 0x01, 0x00, 0x30, 0x05, 0x06, 0x03, 0x2b, 0x65, 0x70, 0x04, 0x22, 0x04, 0x20,
];

/// An Ed25519 private key; the secret is wiped from memory when dropped.
pub struct PrivateKey {
    signing: SigningKey,
    public: [u8; 32],
}

impl fmt::Debug for PrivateKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never print the secret; the public half identifies the key well enough.
        write!(f, "PrivateKey(public {})", hex::encode(self.public))
    }
}

impl PrivateKey {
    /// A new key from the operating system's random source.
    pub fn generate() -> Result<Self, RandomError> {
        let mut seed = Zeroizing::new([0u8; 32]);
        util::random(seed.as_mut())?;
        Ok(Self::from_seed(&seed))
    }

    fn from_seed(seed: &[u8; 32]) -> Self {
        let signing = SigningKey::from_bytes(seed);
        let public = signing.verifying_key().to_bytes();
        Self { signing, public }
    }

    /// The public key.
    pub fn verifying_key(&self) -> VerifyingKey {
        self.signing.verifying_key()
    }

    /// PKCS#8 PEM text (`-----BEGIN PRIVATE KEY-----`), wiped when dropped.
    pub fn to_pem(&self) -> Zeroizing<String> {
        let mut der = Zeroizing::new(Vec::with_capacity(48));
        der.extend_from_slice(&PKCS8_ED25519_PREFIX);
        der.extend_from_slice(self.signing.as_bytes());
        Zeroizing::new(pem::encode(&pem::Pem::new(KEY_PEM_LABEL, der.to_vec())))
    }

    /// Decodes an RFC 8410 PKCS#8 v1 Ed25519 key.
    pub fn from_pkcs8_der(der: &[u8]) -> Result<Self, String> {
        let seed = der
            .strip_prefix(&PKCS8_ED25519_PREFIX[..])
            .and_then(|s| <&[u8; 32]>::try_from(s).ok())
            .ok_or_else(|| {
                "not an Ed25519 PKCS#8 key (expected the 48-byte form `openssl genpkey -algorithm ed25519` writes)"
                    .to_owned()
            })?;
        Ok(Self::from_seed(seed))
    }

    /// Loads a PKCS#8 PEM key file, refusing it when group/others can read it.
    pub fn load(path: &Path) -> Result<Self, FileError> {
        let text = files::read_secret(path)?;
        let block = files::parse_pem(path, &text, KEY_PEM_LABEL)?;
        let der = Zeroizing::new(block.into_contents());
        Self::from_pkcs8_der(&der).map_err(|e| FileError::new(path, FileProblem::BadKey(e)))
    }
}

impl rcgen::PublicKeyData for PrivateKey {
    fn der_bytes(&self) -> &[u8] {
        // For Ed25519 the SubjectPublicKeyInfo bit string is the raw 32-byte key (RFC 8410 §4).
        &self.public
    }

    fn algorithm(&self) -> &'static rcgen::SignatureAlgorithm {
        &rcgen::PKCS_ED25519
    }
}

impl rcgen::SigningKey for PrivateKey {
    fn sign(&self, msg: &[u8]) -> Result<Vec<u8>, rcgen::Error> {
        Ok(self.signing.sign(msg).to_bytes().to_vec())
    }
}

/// Why a certificate is not one Shoal accepts.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CertError {
    /// The DER does not parse as an X.509 certificate.
    #[error("not an X.509 certificate: {0}")]
    Parse(String),
    /// Bytes follow the certificate.
    #[error("{0} bytes follow the certificate")]
    TrailingBytes(usize),
    /// Signed or keyed with another algorithm than Ed25519.
    #[error("not an Ed25519 certificate (Shoal issues and accepts only Ed25519)")]
    NotEd25519,
    /// The subject public key is not a valid Ed25519 point.
    #[error("its public key is not a valid Ed25519 key")]
    BadPublicKey,
    /// The `urn:shoal:` SAN is malformed, repeated, or disagrees with the common name.
    #[error("bad identity: {0}")]
    BadIdentity(String),
    /// A leaf certificate without a Shoal identity.
    #[error("has no urn:shoal: subject alternative name")]
    NoIdentity,
    /// Not issued by the trusted CA (other issuer name, or the signature does not verify).
    #[error("not issued by the trusted station CA")]
    Untrusted,
    /// A CA certificate where a leaf is needed, or a leaf where the CA is needed.
    #[error("{0}")]
    WrongKind(&'static str),
}

impl From<IdentityError> for CertError {
    fn from(e: IdentityError) -> Self {
        Self::BadIdentity(e.to_string())
    }
}

/// A parsed Ed25519 X.509 certificate with the fields Shoal uses; owns its DER.
#[derive(Clone)]
pub struct Certificate {
    der: Vec<u8>,
    serial: String,
    common_name: String,
    identity: Option<Identity>,
    public_key: VerifyingKey,
    not_before_ms: i64,
    not_after_ms: i64,
    is_ca: bool,
    issuer_raw: Vec<u8>,
    subject_raw: Vec<u8>,
    tbs: Vec<u8>,
    signature: Option<Signature>,
}

impl fmt::Debug for Certificate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Certificate")
            .field("serial", &self.serial)
            .field("common_name", &self.common_name)
            .field("identity", &self.identity)
            .field("not_before", &util::rfc3339(self.not_before_ms))
            .field("not_after", &util::rfc3339(self.not_after_ms))
            .field("is_ca", &self.is_ca)
            .finish_non_exhaustive()
    }
}

impl Certificate {
    /// Parses a DER certificate; everything but the issuer's signature is checked here.
    pub fn from_der(der: &[u8]) -> Result<Self, CertError> {
        let (rest, x509) = x509_parser::parse_x509_certificate(der)
            .map_err(|e| CertError::Parse(e.to_string()))?;
        if !rest.is_empty() {
            return Err(CertError::TrailingBytes(rest.len()));
        }
        if x509.signature_algorithm.algorithm != OID_SIG_ED25519
            || x509.tbs_certificate.signature.algorithm != OID_SIG_ED25519
            || x509.public_key().algorithm.algorithm != OID_SIG_ED25519
        {
            return Err(CertError::NotEd25519);
        }
        let key_bytes = <[u8; 32]>::try_from(&x509.public_key().subject_public_key.data[..])
            .map_err(|_| CertError::BadPublicKey)?;
        let public_key =
            VerifyingKey::from_bytes(&key_bytes).map_err(|_| CertError::BadPublicKey)?;
        // Only the TBS part is signed, and the parser is lenient with what surrounds it: demand
        // the one DER form an Ed25519 signer produces, so a certificate has one encoding and
        // therefore one id.
        if !is_canonical_signed(
            der,
            x509.tbs_certificate.as_ref(),
            &x509.signature_value.data,
        ) {
            return Err(CertError::Parse(
                "not the canonical DER of an Ed25519-signed certificate".into(),
            ));
        }
        let signature = Signature::from_slice(&x509.signature_value.data).ok();
        let common_name = x509
            .subject()
            .iter_common_name()
            .next()
            .and_then(|cn| cn.as_str().ok())
            .unwrap_or_default()
            .to_owned();
        let identity = identity_of(&x509, &common_name)?;
        let validity = x509.validity();
        Ok(Self {
            der: der.to_vec(),
            serial: hex::encode(x509.raw_serial()),
            common_name,
            identity,
            public_key,
            not_before_ms: validity.not_before.timestamp().saturating_mul(1000),
            not_after_ms: validity.not_after.timestamp().saturating_mul(1000),
            is_ca: x509.is_ca(),
            issuer_raw: x509.issuer().as_raw().to_vec(),
            subject_raw: x509.subject().as_raw().to_vec(),
            tbs: x509.tbs_certificate.as_ref().to_vec(),
            signature,
        })
    }

    /// Parses one PEM `CERTIFICATE` block.
    pub fn from_pem(text: &str) -> Result<Self, CertError> {
        let block = pem::parse(text).map_err(|e| CertError::Parse(format!("not PEM: {e}")))?;
        if block.tag() != CERT_PEM_LABEL {
            return Err(CertError::Parse(format!(
                "PEM block labelled {:?}, expected {CERT_PEM_LABEL:?}",
                block.tag()
            )));
        }
        Self::from_der(block.contents())
    }

    /// Loads a PEM certificate file.
    pub fn load(path: &Path) -> Result<Self, FileError> {
        let text = files::read_public(path)?;
        let block = files::parse_pem(path, &text, CERT_PEM_LABEL)?;
        Self::from_der(block.contents())
            .map_err(|e| FileError::new(path, FileProblem::BadCertificate(e.to_string())))
    }

    /// PEM text.
    pub fn to_pem(&self) -> String {
        pem::encode(&pem::Pem::new(CERT_PEM_LABEL, self.der.clone()))
    }

    /// The DER bytes.
    pub fn der(&self) -> &[u8] {
        &self.der
    }

    /// The serial number as lower-case hex, as the revocation list names it.
    pub fn serial(&self) -> &str {
        &self.serial
    }

    /// The subject common name.
    pub fn common_name(&self) -> &str {
        &self.common_name
    }

    /// The Shoal identity from the `urn:shoal:` SAN; `None` for the CA.
    pub fn identity(&self) -> Option<&Identity> {
        self.identity.as_ref()
    }

    /// The subject's Ed25519 public key.
    pub fn public_key(&self) -> &VerifyingKey {
        &self.public_key
    }

    /// Start of validity, ms since the Unix epoch.
    pub fn not_before_ms(&self) -> i64 {
        self.not_before_ms
    }

    /// End of validity, ms since the Unix epoch.
    pub fn not_after_ms(&self) -> i64 {
        self.not_after_ms
    }

    /// The DER of the subject name, which certificates it issues carry as their issuer.
    pub(crate) fn subject_raw(&self) -> &[u8] {
        &self.subject_raw
    }

    /// Whether the basic-constraints extension makes it a CA.
    pub fn is_ca(&self) -> bool {
        self.is_ca
    }

    /// Where `now_ms` lies relative to the validity period.
    pub fn validity_at(&self, now_ms: i64) -> Validity {
        if now_ms < self.not_before_ms {
            Validity::NotYetValid
        } else if now_ms > self.not_after_ms {
            Validity::Expired
        } else {
            Validity::Valid
        }
    }

    /// Whether `key` signed this certificate.
    pub(crate) fn is_signed_by(&self, key: &VerifyingKey) -> bool {
        self.signature
            .is_some_and(|sig| key.verify_strict(&self.tbs, &sig).is_ok())
    }

    /// Whether `key` is the private half of this certificate's public key.
    pub fn matches_key(&self, key: &PrivateKey) -> bool {
        key.verifying_key() == self.public_key
    }

    /// Checks the validity period at `now_ms`, as a file error for loaders.
    pub(crate) fn check_dates(&self, path: &Path, now_ms: i64) -> Result<(), FileError> {
        match self.validity_at(now_ms) {
            Validity::Valid => Ok(()),
            Validity::Expired => Err(FileError::new(
                path,
                FileProblem::Expired(util::rfc3339(self.not_after_ms)),
            )),
            Validity::NotYetValid => Err(FileError::new(
                path,
                FileProblem::NotYetValid(util::rfc3339(self.not_before_ms)),
            )),
        }
    }
}

/// DER of `AlgorithmIdentifier { id-Ed25519 }` (no parameters, RFC 8410 §3).
const ED25519_ALGORITHM_DER: [u8; 7] = [0x30, 0x05, 0x06, 0x03, 0x2b, 0x65, 0x70];

/// Whether `der` is exactly `SEQUENCE { tbs, AlgorithmIdentifier Ed25519, BIT STRING sig }`
/// in DER, with a 64-byte signature: the only encoding of a signed object Shoal accepts.
pub(crate) fn is_canonical_signed(der: &[u8], tbs: &[u8], sig: &[u8]) -> bool {
    if sig.len() != 64 {
        return false;
    }
    let body_len = tbs.len() + ED25519_ALGORITHM_DER.len() + 3 + sig.len();
    let mut expected = Vec::with_capacity(body_len + 4);
    expected.push(0x30);
    match body_len {
        0..=0x7f => expected.push(body_len as u8),
        0x80..=0xff => expected.extend([0x81, body_len as u8]),
        0x100..=0xffff => expected.extend([0x82, (body_len >> 8) as u8, body_len as u8]),
        _ => return false,
    }
    expected.extend_from_slice(tbs);
    expected.extend_from_slice(&ED25519_ALGORITHM_DER);
    // BIT STRING, 65 content octets: 0 unused bits, then the signature.
    expected.extend([0x03, 0x41, 0x00]);
    expected.extend_from_slice(sig);
    expected == der
}

/// Where a time lies relative to a certificate's validity period.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Validity {
    /// Within the period.
    Valid,
    /// Before `not_before`.
    NotYetValid,
    /// After `not_after`.
    Expired,
}

/// The identity named by the certificate's single `urn:shoal:` SAN URI, which the common
/// name must repeat (so tools that show only the CN show the same name).
fn identity_of(
    x509: &x509_parser::certificate::X509Certificate<'_>,
    common_name: &str,
) -> Result<Option<Identity>, CertError> {
    let san = x509
        .subject_alternative_name()
        .map_err(|e| CertError::BadIdentity(format!("unreadable subject alternative name: {e}")))?;
    let mut found: Option<Identity> = None;
    for name in san.iter().flat_map(|s| s.value.general_names.iter()) {
        if let x509_parser::extensions::GeneralName::URI(uri) = name
            && uri.starts_with(crate::identity::URN_PREFIX)
        {
            if found.is_some() {
                return Err(CertError::BadIdentity(
                    "more than one urn:shoal: name".into(),
                ));
            }
            found = Some(Identity::from_uri(uri)?);
        }
    }
    if let Some(id) = &found
        && id.name() != common_name
    {
        return Err(CertError::BadIdentity(format!(
            "common name {common_name:?} differs from the SAN name {:?}",
            id.name()
        )));
    }
    Ok(found)
}

/// The station CA certificate that every other certificate must chain to.
#[derive(Debug, Clone)]
pub struct TrustAnchor {
    cert: Certificate,
}

impl TrustAnchor {
    /// Accepts `cert` as the anchor if it is a self-signed Ed25519 CA certificate.
    pub fn new(cert: Certificate) -> Result<Self, CertError> {
        if !cert.is_ca {
            return Err(CertError::WrongKind(
                "not a CA certificate (basic constraints CA:FALSE or absent)",
            ));
        }
        if cert.issuer_raw != cert.subject_raw || !cert.is_signed_by(&cert.public_key) {
            return Err(CertError::WrongKind(
                "the CA certificate is not self-signed",
            ));
        }
        Ok(Self { cert })
    }

    /// Loads the CA certificate from a PEM file, refusing it when it is not valid at `now_ms`.
    pub fn load(path: &Path, now_ms: i64) -> Result<Self, FileError> {
        let cert = Certificate::load(path)?;
        let anchor = Self::new(cert)
            .map_err(|e| FileError::new(path, FileProblem::BadCertificate(e.to_string())))?;
        anchor.cert.check_dates(path, now_ms)?;
        Ok(anchor)
    }

    /// The CA certificate.
    pub fn certificate(&self) -> &Certificate {
        &self.cert
    }

    /// Checks that the CA issued `leaf` (issuer name and signature) and that it is a leaf
    /// with a Shoal identity. Dates and revocation are the caller's to check.
    pub fn verify_issued(&self, leaf: &Certificate) -> Result<(), CertError> {
        if leaf.issuer_raw != self.cert.subject_raw || !leaf.is_signed_by(&self.cert.public_key) {
            return Err(CertError::Untrusted);
        }
        if leaf.is_ca {
            return Err(CertError::WrongKind(
                "a CA certificate where a leaf certificate is needed",
            ));
        }
        if leaf.identity.is_none() {
            return Err(CertError::NoIdentity);
        }
        Ok(())
    }
}

/// Why issuing a certificate failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum IssueError {
    /// No randomness for the key or serial number.
    #[error(transparent)]
    Random(#[from] RandomError),
    /// rcgen refused the parameters.
    #[error("building the certificate failed: {0}")]
    Build(#[from] rcgen::Error),
    /// The issued certificate did not parse back (a bug, reported rather than hidden).
    #[error("the issued certificate does not parse: {0}")]
    Reparse(#[from] CertError),
}

/// A random positive 16-byte serial number (RFC 5280 §4.1.2.2 allows up to 20 octets).
pub(crate) fn random_serial() -> Result<Vec<u8>, RandomError> {
    let mut serial = vec![0u8; 16];
    util::random(&mut serial)?;
    // Positive and without a leading zero octet, so the DER INTEGER is exactly these bytes
    // and the serial's hex reads the same in the certificate and in the revocation list.
    serial[0] = (serial[0] & 0x7f).max(1);
    Ok(serial)
}

/// The subject key identifier: SHA-256 of the public key truncated to 160 bits (RFC 7093 §2).
pub(crate) fn key_id(key: &PrivateKey) -> Vec<u8> {
    Sha256::digest(key.public)[..20].to_vec()
}

fn base_params(
    cn: &str,
    key: &PrivateKey,
    not_before_ms: i64,
    not_after_ms: i64,
) -> Result<CertificateParams, RandomError> {
    let mut params = CertificateParams::default();
    params.distinguished_name = distinguished_name(cn);
    params.not_before = util::datetime(not_before_ms);
    params.not_after = util::datetime(not_after_ms);
    params.serial_number = Some(SerialNumber::from(random_serial()?));
    params.key_identifier_method = KeyIdMethod::PreSpecified(key_id(key));
    Ok(params)
}

/// Issues the self-signed station CA certificate.
pub(crate) fn self_signed_ca(
    key: &PrivateKey,
    station: &str,
    not_before_ms: i64,
    not_after_ms: i64,
) -> Result<Certificate, IssueError> {
    let mut params = base_params(
        &format!("{station} Shoal CA"),
        key,
        not_before_ms,
        not_after_ms,
    )?;
    // Path length 0: the CA signs leaves only, never a sub-CA.
    params.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    params.key_usages = ca_key_usages();
    let cert = params.self_signed(key)?;
    Ok(Certificate::from_der(cert.der())?)
}

/// An rcgen issuer for the CA certificate and key.
///
/// The CA's name is rebuilt the way [`self_signed_ca`] wrote it (rcgen encodes a name
/// deterministically); [`issue_leaf`] checks the result chains, so a CA made by another tool
/// with a differently encoded name fails loudly instead of issuing unverifiable certificates.
pub(crate) fn issuer<'a>(
    ca: &Certificate,
    ca_key: &'a PrivateKey,
) -> Issuer<'static, &'a PrivateKey> {
    let mut params = CertificateParams::default();
    params.distinguished_name = distinguished_name(ca.common_name());
    params.key_identifier_method = KeyIdMethod::PreSpecified(key_id(ca_key));
    params.key_usages = ca_key_usages();
    Issuer::new(params, ca_key)
}

fn ca_key_usages() -> Vec<KeyUsagePurpose> {
    vec![
        KeyUsagePurpose::KeyCertSign,
        KeyUsagePurpose::CrlSign,
        KeyUsagePurpose::DigitalSignature,
    ]
}

fn distinguished_name(cn: &str) -> DistinguishedName {
    let mut dn = DistinguishedName::new();
    dn.push(DnType::OrganizationName, ORGANISATION);
    dn.push(DnType::CommonName, cn);
    dn
}

/// Issues a leaf certificate for `identity`'s public key, signed by the CA.
pub(crate) fn issue_leaf(
    ca: &Certificate,
    ca_key: &PrivateKey,
    subject_key: &PrivateKey,
    identity: &Identity,
    not_before_ms: i64,
    not_after_ms: i64,
) -> Result<Certificate, IssueError> {
    let mut params = base_params(identity.name(), subject_key, not_before_ms, not_after_ms)?;
    params.is_ca = IsCa::ExplicitNoCa;
    params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    params.use_authority_key_identifier_extension = true;
    let uri = identity
        .uri()
        .try_into()
        .map_err(|e: rcgen::Error| IssueError::Build(e))?;
    params.subject_alt_names = vec![SanType::URI(uri)];
    let cert = params.signed_by(subject_key, &issuer(ca, ca_key))?;
    let cert = Certificate::from_der(cert.der())?;
    if cert.issuer_raw != ca.subject_raw || !cert.is_signed_by(&ca.public_key) {
        return Err(IssueError::Reparse(CertError::Untrusted));
    }
    Ok(cert)
}

/// A name a site's federation certificate is valid for: what the sites that connect to it
/// write as the host of its endpoint (`tls/<host>:<port>`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SiteName {
    /// A DNS name, e.g. `shore.example.org`.
    Dns(String),
    /// An IP address, e.g. `203.0.113.5`.
    Ip(std::net::IpAddr),
}

impl SiteName {
    /// An IP address if `s` parses as one, otherwise a DNS name (RFC 1123 labels of
    /// letters, digits and `-`, dot-separated, at most 253 bytes; no wildcard).
    pub fn parse(s: &str) -> Result<Self, String> {
        if let Ok(ip) = s.parse() {
            return Ok(Self::Ip(ip));
        }
        let label_ok = |l: &str| {
            (1..=63).contains(&l.len())
                && l.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-')
                && !l.starts_with('-')
                && !l.ends_with('-')
        };
        if s.len() <= 253 && s.split('.').all(label_ok) {
            Ok(Self::Dns(s.to_ascii_lowercase()))
        } else {
            Err(format!("{s:?} is neither an IP address nor a DNS name"))
        }
    }
}

/// Issues a site's federation certificate (TLS over Zenoh, both as the side that listens
/// and the side that connects): CN = the site name, which Zenoh's access control reads
/// (`cert_common_names`); SANs = the names it listens on, which the connecting side's
/// rustls checks; extended key usage serverAuth and clientAuth. No `urn:shoal:` identity:
/// a site is not a station or vehicle of this station's fleet.
pub(crate) fn issue_site_leaf(
    ca: &Certificate,
    ca_key: &PrivateKey,
    subject_key: &PrivateKey,
    site: &str,
    names: &[SiteName],
    not_before_ms: i64,
    not_after_ms: i64,
) -> Result<Certificate, IssueError> {
    let mut params = base_params(site, subject_key, not_before_ms, not_after_ms)?;
    params.is_ca = IsCa::ExplicitNoCa;
    params.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    params.extended_key_usages = vec![
        ExtendedKeyUsagePurpose::ServerAuth,
        ExtendedKeyUsagePurpose::ClientAuth,
    ];
    params.use_authority_key_identifier_extension = true;
    let mut sans = Vec::with_capacity(names.len());
    for name in names {
        sans.push(match name {
            SiteName::Dns(dns) => SanType::DnsName(dns.as_str().try_into()?),
            SiteName::Ip(ip) => SanType::IpAddress(*ip),
        });
    }
    params.subject_alt_names = sans;
    let cert = params.signed_by(subject_key, &issuer(ca, ca_key))?;
    let cert = Certificate::from_der(cert.der())?;
    if cert.issuer_raw != ca.subject_raw || !cert.is_signed_by(&ca.public_key) {
        return Err(IssueError::Reparse(CertError::Untrusted));
    }
    Ok(cert)
}

#[cfg(test)]
mod tests {
    use super::*;

    const DAY: i64 = 86_400_000;
    const T0: i64 = 1_780_000_000_000;

    fn ca() -> (PrivateKey, Certificate) {
        let key = PrivateKey::generate().unwrap();
        let cert = self_signed_ca(&key, "ccs", T0 - DAY, T0 + 3650 * DAY).unwrap();
        (key, cert)
    }

    #[test]
    fn issued_leaf_chains_to_the_ca_and_names_its_identity() {
        let (ca_key, ca_cert) = ca();
        let anchor = TrustAnchor::new(ca_cert.clone()).unwrap();
        assert!(anchor.certificate().identity().is_none());
        let key = PrivateKey::generate().unwrap();
        let id = Identity::vehicle("auv-1").unwrap();
        let leaf = issue_leaf(&ca_cert, &ca_key, &key, &id, T0, T0 + 365 * DAY).unwrap();
        anchor.verify_issued(&leaf).unwrap();
        assert_eq!(leaf.identity(), Some(&id));
        assert_eq!(leaf.common_name(), "auv-1");
        assert!(leaf.matches_key(&key));
        assert!(!leaf.is_ca());
        assert_eq!(leaf.serial().len(), 32);
        assert_eq!(leaf.validity_at(T0 + DAY), Validity::Valid);
        assert_eq!(leaf.validity_at(T0 - 1), Validity::NotYetValid);
        assert_eq!(leaf.validity_at(T0 + 366 * DAY), Validity::Expired);
        // PEM round trip keeps everything.
        let again = Certificate::from_pem(&leaf.to_pem()).unwrap();
        assert_eq!(again.der(), leaf.der());
        assert_eq!(again.serial(), leaf.serial());
    }

    #[test]
    fn another_ca_is_not_trusted() {
        let (_, ca_cert) = ca();
        let (rogue_key, rogue_cert) = ca();
        let anchor = TrustAnchor::new(ca_cert).unwrap();
        let key = PrivateKey::generate().unwrap();
        let id = Identity::vehicle("auv-1").unwrap();
        let leaf = issue_leaf(&rogue_cert, &rogue_key, &key, &id, T0, T0 + DAY).unwrap();
        assert_eq!(anchor.verify_issued(&leaf), Err(CertError::Untrusted));
    }

    #[test]
    fn a_leaf_is_not_an_anchor() {
        let (ca_key, ca_cert) = ca();
        let key = PrivateKey::generate().unwrap();
        let id = Identity::station("ccs").unwrap();
        let leaf = issue_leaf(&ca_cert, &ca_key, &key, &id, T0, T0 + DAY).unwrap();
        assert!(matches!(
            TrustAnchor::new(leaf),
            Err(CertError::WrongKind(_))
        ));
    }

    #[test]
    fn private_keys_round_trip_through_pkcs8_pem() {
        let key = PrivateKey::generate().unwrap();
        let pem_text = key.to_pem();
        let block = pem::parse(pem_text.as_str()).unwrap();
        assert_eq!(block.tag(), KEY_PEM_LABEL);
        let back = PrivateKey::from_pkcs8_der(block.contents()).unwrap();
        assert_eq!(back.verifying_key(), key.verifying_key());
        assert!(PrivateKey::from_pkcs8_der(&block.contents()[1..]).is_err());
        assert!(!format!("{key:?}").contains(&hex::encode(key.signing.as_bytes())));
    }

    #[test]
    fn garbage_der_is_an_error_not_a_panic() {
        assert!(Certificate::from_der(&[]).is_err());
        assert!(Certificate::from_der(&[0x30, 0x03, 1, 2, 3]).is_err());
        let (_, ca_cert) = ca();
        let mut der = ca_cert.der().to_vec();
        der.push(0);
        assert_eq!(
            Certificate::from_der(&der).unwrap_err(),
            CertError::TrailingBytes(1)
        );
    }

    #[test]
    fn a_site_certificate_names_the_site_and_its_addresses() {
        let (ca_key, ca_cert) = ca();
        let key = PrivateKey::generate().unwrap();
        let names = [
            SiteName::parse("127.0.0.1").unwrap(),
            SiteName::parse("shore.example.org").unwrap(),
        ];
        assert_eq!(names[0], SiteName::Ip([127, 0, 0, 1].into()));
        let leaf = issue_site_leaf(&ca_cert, &ca_key, &key, "shore", &names, T0, T0 + DAY).unwrap();
        assert_eq!(leaf.common_name(), "shore");
        assert!(leaf.identity().is_none() && !leaf.is_ca());
        assert!(leaf.is_signed_by(ca_cert.public_key()));
        let (_, x509) = x509_parser::parse_x509_certificate(leaf.der()).unwrap();
        let san = x509.subject_alternative_name().unwrap().unwrap();
        assert_eq!(san.value.general_names.len(), 2);
        let eku = x509.extended_key_usage().unwrap().unwrap();
        assert!(eku.value.server_auth && eku.value.client_auth);
        // A name that is neither is refused before anything is issued.
        for bad in ["shore example", "", "-a.b", "*.example.org", "a..b"] {
            assert!(SiteName::parse(bad).is_err(), "{bad:?}");
        }
    }
}
