//! Signed envelopes for IP links: a sample's bytes with the sender's certificate (or its id),
//! topic, timestamp, counter and an Ed25519 signature over all of them.
//!
//! # Wire form (version 1), all integers big-endian
//!
//! ```text
//! u8        version = 1
//! u8        credential kind: 0 = certificate follows, 1 = certificate id follows
//!   kind 0: u16 length (1..=4096), then the DER certificate
//!   kind 1: 16 bytes: the first 16 bytes of SHA-256 of the DER certificate
//! u8        topic length (1..=255), then the topic name in UTF-8
//! i64       timestamp, ms since the Unix epoch
//! u64       counter, strictly increasing per sender
//! u32       payload length (0..=1 MiB), then the payload (the sample, e.g. CDR bytes)
//! [u8; 64]  Ed25519 signature
//! ```
//!
//! The signature covers `"shoal-envelope-v1" | certificate id | topic length | topic |
//! timestamp | counter | payload length | payload`. It covers the certificate id rather
//! than the credential field, so the full and compact forms of one message carry the same
//! signature, and swapping in another certificate breaks it. Nothing may follow the
//! signature: one message has exactly one encoding.

use std::path::Path;

use crate::cert::{CertError, CertId, Certificate, PrivateKey};
use crate::files::{FileError, FileProblem};
use crate::identity::Identity;

/// Current wire version.
pub const VERSION: u8 = 1;
/// Longest topic name, in bytes.
pub const MAX_TOPIC_LEN: usize = 255;
/// Largest payload, in bytes.
pub const MAX_PAYLOAD_LEN: usize = 1 << 20;
/// Largest embedded certificate, in bytes (Shoal's are about 350).
pub const MAX_CERT_LEN: usize = 4096;
/// Signature length.
pub const SIGNATURE_LEN: usize = 64;
/// Bytes an envelope adds to a payload, besides the topic name and certificate/id:
/// version, kind, topic length, timestamp, counter, payload length, signature.
pub const FIXED_OVERHEAD: usize = 1 + 1 + 1 + 8 + 8 + 4 + SIGNATURE_LEN;
/// Domain-separation prefix of the signed bytes.
const DOMAIN: &[u8] = b"shoal-envelope-v1";

const KIND_CERTIFICATE: u8 = 0;
const KIND_ID: u8 = 1;

/// How an envelope names its signer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Credential {
    /// The full DER certificate: any verifier trusting the CA can check it.
    Certificate(Vec<u8>),
    /// The certificate id: the verifier must already know the certificate (about 330 bytes
    /// smaller per message).
    Id(CertId),
}

impl Credential {
    /// The id of the certificate this credential names.
    pub fn cert_id(&self) -> CertId {
        match self {
            Self::Certificate(der) => CertId::of_der(der),
            Self::Id(id) => *id,
        }
    }

    fn encoded_len(&self) -> usize {
        match self {
            Self::Certificate(der) => 2 + der.len(),
            Self::Id(_) => 16,
        }
    }
}

/// A signed message, as decoded or as produced by [`SigningIdentity::sign`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Envelope {
    credential: Credential,
    topic: String,
    timestamp_ms: i64,
    counter: u64,
    payload: Vec<u8>,
    signature: [u8; SIGNATURE_LEN],
}

/// Why bytes are not an envelope.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The input ends inside a field.
    #[error("truncated: {field} needs {needed} more bytes")]
    Truncated {
        /// The field being read.
        field: &'static str,
        /// Bytes missing.
        needed: usize,
    },
    /// A version this decoder does not know.
    #[error("unsupported version {0}")]
    UnsupportedVersion(u8),
    /// A credential kind other than 0 or 1.
    #[error("unknown credential kind {0}")]
    UnknownCredential(u8),
    /// An embedded certificate of length 0 or over [`MAX_CERT_LEN`].
    #[error("certificate length {0} outside 1..={MAX_CERT_LEN}")]
    CertificateLength(usize),
    /// An empty topic.
    #[error("empty topic")]
    EmptyTopic,
    /// The topic is not UTF-8.
    #[error("topic is not UTF-8")]
    TopicNotUtf8,
    /// A payload over [`MAX_PAYLOAD_LEN`].
    #[error("payload length {0} exceeds {MAX_PAYLOAD_LEN}")]
    PayloadTooLarge(usize),
    /// Bytes follow the signature.
    #[error("{0} bytes follow the signature")]
    TrailingBytes(usize),
}

/// Why a message could not be signed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SignError {
    /// The topic is empty or longer than [`MAX_TOPIC_LEN`] bytes.
    #[error("topic length {0} outside 1..={MAX_TOPIC_LEN}")]
    TopicLength(usize),
    /// The payload is larger than [`MAX_PAYLOAD_LEN`].
    #[error("payload length {0} exceeds {MAX_PAYLOAD_LEN}")]
    PayloadTooLarge(usize),
}

/// A reader over untrusted bytes: every read is bounds-checked and never panics.
struct Reader<'a> {
    rest: &'a [u8],
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, field: &'static str) -> Result<&'a [u8], DecodeError> {
        if self.rest.len() < n {
            return Err(DecodeError::Truncated {
                field,
                needed: n - self.rest.len(),
            });
        }
        let (head, tail) = self.rest.split_at(n);
        self.rest = tail;
        Ok(head)
    }

    fn array<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], DecodeError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.take(N, field)?);
        Ok(out)
    }

    fn u8(&mut self, field: &'static str) -> Result<u8, DecodeError> {
        Ok(self.array::<1>(field)?[0])
    }
}

impl Envelope {
    /// Decodes the wire form; never panics, whatever the input.
    pub fn decode(bytes: &[u8]) -> Result<Self, DecodeError> {
        let mut r = Reader { rest: bytes };
        let version = r.u8("version")?;
        if version != VERSION {
            return Err(DecodeError::UnsupportedVersion(version));
        }
        let credential = match r.u8("credential kind")? {
            KIND_CERTIFICATE => {
                let len = usize::from(u16::from_be_bytes(r.array("certificate length")?));
                if len == 0 || len > MAX_CERT_LEN {
                    return Err(DecodeError::CertificateLength(len));
                }
                Credential::Certificate(r.take(len, "certificate")?.to_vec())
            }
            KIND_ID => Credential::Id(CertId(r.array("certificate id")?)),
            other => return Err(DecodeError::UnknownCredential(other)),
        };
        let topic_len = usize::from(r.u8("topic length")?);
        if topic_len == 0 {
            return Err(DecodeError::EmptyTopic);
        }
        let topic = std::str::from_utf8(r.take(topic_len, "topic")?)
            .map_err(|_| DecodeError::TopicNotUtf8)?
            .to_owned();
        let timestamp_ms = i64::from_be_bytes(r.array("timestamp")?);
        let counter = u64::from_be_bytes(r.array("counter")?);
        let payload_len = u32::from_be_bytes(r.array("payload length")?);
        let payload_len = usize::try_from(payload_len).unwrap_or(usize::MAX);
        if payload_len > MAX_PAYLOAD_LEN {
            return Err(DecodeError::PayloadTooLarge(payload_len));
        }
        let payload = r.take(payload_len, "payload")?.to_vec();
        let signature = r.array::<SIGNATURE_LEN>("signature")?;
        if !r.rest.is_empty() {
            return Err(DecodeError::TrailingBytes(r.rest.len()));
        }
        Ok(Self {
            credential,
            topic,
            timestamp_ms,
            counter,
            payload,
            signature,
        })
    }

    /// The wire form.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.encoded_len());
        out.push(VERSION);
        match &self.credential {
            Credential::Certificate(der) => {
                out.push(KIND_CERTIFICATE);
                // Lengths were bounded when the envelope was made (sign or decode).
                out.extend_from_slice(&u16::try_from(der.len()).unwrap_or(u16::MAX).to_be_bytes());
                out.extend_from_slice(der);
            }
            Credential::Id(id) => {
                out.push(KIND_ID);
                out.extend_from_slice(&id.0);
            }
        }
        out.push(u8::try_from(self.topic.len()).unwrap_or(u8::MAX));
        out.extend_from_slice(self.topic.as_bytes());
        out.extend_from_slice(&self.timestamp_ms.to_be_bytes());
        out.extend_from_slice(&self.counter.to_be_bytes());
        out.extend_from_slice(
            &u32::try_from(self.payload.len())
                .unwrap_or(u32::MAX)
                .to_be_bytes(),
        );
        out.extend_from_slice(&self.payload);
        out.extend_from_slice(&self.signature);
        out
    }

    /// Length of the wire form.
    pub fn encoded_len(&self) -> usize {
        FIXED_OVERHEAD + self.credential.encoded_len() + self.topic.len() + self.payload.len()
    }

    /// How the envelope names its signer.
    pub fn credential(&self) -> &Credential {
        &self.credential
    }

    /// The topic name.
    pub fn topic(&self) -> &str {
        &self.topic
    }

    /// The sender's timestamp, ms since the Unix epoch.
    pub fn timestamp_ms(&self) -> i64 {
        self.timestamp_ms
    }

    /// The sender's counter.
    pub fn counter(&self) -> u64 {
        self.counter
    }

    /// The payload (the sample's bytes).
    pub fn payload(&self) -> &[u8] {
        &self.payload
    }

    /// The payload, by value.
    pub fn into_payload(self) -> Vec<u8> {
        self.payload
    }

    /// The signature bytes.
    pub fn signature(&self) -> &[u8; SIGNATURE_LEN] {
        &self.signature
    }

    /// The same message naming its signer by certificate id only.
    pub fn to_compact(&self) -> Self {
        Self {
            credential: Credential::Id(self.credential.cert_id()),
            ..self.clone()
        }
    }

    /// The bytes the signature covers.
    pub(crate) fn signed_bytes(&self, cert_id: CertId) -> Vec<u8> {
        signed_bytes(
            cert_id,
            &self.topic,
            self.timestamp_ms,
            self.counter,
            &self.payload,
        )
    }
}

fn signed_bytes(
    cert_id: CertId,
    topic: &str,
    timestamp_ms: i64,
    counter: u64,
    payload: &[u8],
) -> Vec<u8> {
    let mut m = Vec::with_capacity(DOMAIN.len() + 16 + 1 + topic.len() + 20 + payload.len());
    m.extend_from_slice(DOMAIN);
    m.extend_from_slice(&cert_id.0);
    m.push(u8::try_from(topic.len()).unwrap_or(u8::MAX));
    m.extend_from_slice(topic.as_bytes());
    m.extend_from_slice(&timestamp_ms.to_be_bytes());
    m.extend_from_slice(&counter.to_be_bytes());
    m.extend_from_slice(
        &u32::try_from(payload.len())
            .unwrap_or(u32::MAX)
            .to_be_bytes(),
    );
    m.extend_from_slice(payload);
    m
}

/// A counter start that survives restarts without storage: the clock in microseconds, so a
/// sender that restarts continues above what it sent before unless its clock went back or it
/// sent more than a million messages per second.
pub fn counter_start_from_clock(now_ms: i64) -> u64 {
    u64::try_from(now_ms).unwrap_or(0).saturating_mul(1000)
}

/// A certificate with its private key: what the station or a vehicle signs with.
pub struct SigningIdentity {
    identity: Identity,
    cert: Certificate,
    key: PrivateKey,
}

impl std::fmt::Debug for SigningIdentity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SigningIdentity")
            .field("identity", &self.identity)
            .field("certificate", &self.cert.id())
            .finish_non_exhaustive()
    }
}

impl SigningIdentity {
    /// Pairs a leaf certificate with its private key.
    pub fn new(cert: Certificate, key: PrivateKey) -> Result<Self, CertError> {
        if cert.is_ca() {
            return Err(CertError::WrongKind(
                "a CA certificate cannot sign messages; a leaf certificate is needed",
            ));
        }
        let identity = cert.identity().cloned().ok_or(CertError::NoIdentity)?;
        if !cert.matches_key(&key) {
            return Err(CertError::WrongKind(
                "the private key does not match the certificate",
            ));
        }
        Ok(Self {
            identity,
            cert,
            key,
        })
    }

    /// Loads a certificate and key file pair.
    pub fn load(cert_path: &Path, key_path: &Path) -> Result<Self, FileError> {
        let cert = Certificate::load(cert_path)?;
        let key = PrivateKey::load(key_path)?;
        if !cert.matches_key(&key) {
            return Err(FileError::new(
                key_path,
                FileProblem::KeyMismatch(cert_path.to_owned()),
            ));
        }
        Self::new(cert, key)
            .map_err(|e| FileError::new(cert_path, FileProblem::BadCertificate(e.to_string())))
    }

    /// Who this signs as.
    pub fn identity(&self) -> &Identity {
        &self.identity
    }

    /// The certificate.
    pub fn certificate(&self) -> &Certificate {
        &self.cert
    }

    /// Signs a sample, embedding the full certificate.
    pub fn sign(
        &self,
        topic: &str,
        payload: &[u8],
        timestamp_ms: i64,
        counter: u64,
    ) -> Result<Envelope, SignError> {
        self.sign_with(
            Credential::Certificate(self.cert.der().to_vec()),
            topic,
            payload,
            timestamp_ms,
            counter,
        )
    }

    /// Signs a sample naming the certificate by id only, for receivers that know it already.
    pub fn sign_compact(
        &self,
        topic: &str,
        payload: &[u8],
        timestamp_ms: i64,
        counter: u64,
    ) -> Result<Envelope, SignError> {
        self.sign_with(
            Credential::Id(self.cert.id()),
            topic,
            payload,
            timestamp_ms,
            counter,
        )
    }

    fn sign_with(
        &self,
        credential: Credential,
        topic: &str,
        payload: &[u8],
        timestamp_ms: i64,
        counter: u64,
    ) -> Result<Envelope, SignError> {
        if topic.is_empty() || topic.len() > MAX_TOPIC_LEN {
            return Err(SignError::TopicLength(topic.len()));
        }
        if payload.len() > MAX_PAYLOAD_LEN {
            return Err(SignError::PayloadTooLarge(payload.len()));
        }
        let msg = signed_bytes(self.cert.id(), topic, timestamp_ms, counter, payload);
        let signature = self.key.sign(&msg).to_bytes();
        Ok(Envelope {
            credential,
            topic: topic.to_owned(),
            timestamp_ms,
            counter,
            payload: payload.to_vec(),
            signature,
        })
    }
}

/// Signs `payload` on `topic` as `identity` (full certificate embedded).
pub fn sign(
    identity: &SigningIdentity,
    topic: &str,
    payload: &[u8],
    timestamp_ms: i64,
    counter: u64,
) -> Result<Envelope, SignError> {
    identity.sign(topic, payload, timestamp_ms, counter)
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn arb_envelope() -> impl Strategy<Value = Envelope> {
        (
            prop_oneof![
                prop::collection::vec(any::<u8>(), 1..600).prop_map(Credential::Certificate),
                any::<[u8; 16]>().prop_map(|b| Credential::Id(CertId(b))),
            ],
            "[a-z/_]{1,40}",
            any::<i64>(),
            any::<u64>(),
            prop::collection::vec(any::<u8>(), 0..300),
            prop::collection::vec(any::<u8>(), 64..=64),
        )
            .prop_map(|(credential, topic, timestamp_ms, counter, payload, sig)| {
                let mut signature = [0u8; 64];
                signature.copy_from_slice(&sig);
                Envelope {
                    credential,
                    topic,
                    timestamp_ms,
                    counter,
                    payload,
                    signature,
                }
            })
    }

    proptest! {
        #[test]
        fn encode_decode_round_trips(env in arb_envelope()) {
            let bytes = env.encode();
            prop_assert_eq!(bytes.len(), env.encoded_len());
            prop_assert_eq!(Envelope::decode(&bytes).unwrap(), env);
        }

        #[test]
        fn garbage_never_panics_and_what_decodes_re_encodes(
            bytes in prop::collection::vec(any::<u8>(), 0..400),
        ) {
            if let Ok(env) = Envelope::decode(&bytes) {
                prop_assert_eq!(env.encode(), bytes);
            }
        }

        #[test]
        fn every_truncation_is_refused(env in arb_envelope(), cut in any::<prop::sample::Index>()) {
            let bytes = env.encode();
            let n = cut.index(bytes.len());
            prop_assert!(Envelope::decode(&bytes[..n]).is_err());
        }
    }

    #[test]
    fn limits_are_enforced() {
        let mut b = vec![VERSION, KIND_CERTIFICATE, 0, 0];
        assert_eq!(Envelope::decode(&b), Err(DecodeError::CertificateLength(0)));
        b = vec![VERSION, KIND_CERTIFICATE, 0x10, 0x01];
        assert_eq!(
            Envelope::decode(&b),
            Err(DecodeError::CertificateLength(4097))
        );
        b = vec![2];
        assert_eq!(
            Envelope::decode(&b),
            Err(DecodeError::UnsupportedVersion(2))
        );
        b = vec![VERSION, 9];
        assert_eq!(Envelope::decode(&b), Err(DecodeError::UnknownCredential(9)));
        b = vec![VERSION, KIND_ID];
        b.extend([0; 16]);
        b.push(0);
        assert_eq!(Envelope::decode(&b), Err(DecodeError::EmptyTopic));
        b.pop();
        b.extend([2, 0xff, 0xfe]);
        assert_eq!(Envelope::decode(&b), Err(DecodeError::TopicNotUtf8));
        b.truncate(b.len() - 3);
        b.extend([1, b'x']);
        b.extend([0; 16]);
        b.extend(u32::MAX.to_be_bytes());
        assert_eq!(
            Envelope::decode(&b),
            Err(DecodeError::PayloadTooLarge(u32::MAX as usize))
        );
        assert_eq!(
            Envelope::decode(&[]),
            Err(DecodeError::Truncated {
                field: "version",
                needed: 1
            })
        );
    }

    /// A lone version byte is a truncated envelope, not a read past the end.
    #[test]
    fn version_byte_alone_is_truncated() {
        assert!(matches!(
            Envelope::decode(&[0x01]),
            Err(DecodeError::Truncated {
                field: "credential kind",
                ..
            })
        ));
    }

    #[test]
    fn clock_counters_are_microseconds() {
        assert_eq!(counter_start_from_clock(1_000), 1_000_000);
        assert_eq!(counter_start_from_clock(-5), 0);
        assert_eq!(counter_start_from_clock(i64::MAX), u64::MAX);
    }
}
