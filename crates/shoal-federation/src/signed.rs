//! End-to-end signatures on command-lease records and orders, with no network and no
//! cryptography of its own: the signature block of a frame, the bytes a signature covers,
//! the identity frame a site answers with its certificate chain, and the samples held
//! while a signer's certificate is on its way.
//!
//! Why: a Zenoh link authenticates only its next hop. Through a router (a shore in
//! `mode = "router"`, or a `zenohd`) a ship's session trusts that router with every other
//! site's data. A lease record or an order signed with the key of its maker's
//! `[federation.tls]` certificate is checked against that site's own certificate,
//! whatever hops it crossed: a router can drop it, not forge or alter it.
//!
//! A signed frame is the unsigned frame with bit 7 of its kind byte set ([`SIGNED`]),
//! followed by the signature, its scheme (TLS `SignatureScheme` code, u16) and the
//! signature's length (u16), little-endian like the rest of the encoding:
//!
//! ```text
//! frame (kind | 0x80) | signature | scheme u16 | length u16
//! ```
//!
//! The signature covers [`CONTEXT`], the key expression the frame is published under (it
//! names the signing site, the vehicle, and for an order the home site), a zero byte, and
//! the frame with its flag set. A record cannot be moved to another key or vehicle.

use std::collections::{HashMap, VecDeque};
use std::fmt;

use crate::wire::{DecodeError, KIND_IDENTITY, VERSION};

/// Bit 7 of the kind byte: the frame ends with a signature block.
pub const SIGNED: u8 = 0x80;
/// What a signature covers first, so that it means nothing in any other protocol.
pub const CONTEXT: &[u8] = b"shoal-federation signed frame v1\0";
/// Certificates in an identity frame, at most (leaf and intermediates).
pub const MAX_CHAIN: usize = 4;
/// An identity frame's size, at most.
pub const MAX_IDENTITY_BYTES: usize = 16 * 1024;
/// Samples held per site while its certificate is asked for, at most.
pub const HELD_PER_SITE: usize = 2048;
/// Bytes held per site while its certificate is asked for, at most.
pub const HELD_BYTES_PER_SITE: usize = 1024 * 1024;

/// Why a signed sample was not taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SignatureError {
    /// This site requires signatures and the frame has none.
    #[error("not signed (this site requires end-to-end signatures with TLS)")]
    Unsigned,
    /// The signature block does not fit the frame.
    #[error("malformed signature block")]
    Malformed,
    /// A signature scheme this site does not verify.
    #[error("signature scheme 0x{0:04x} is not supported")]
    Scheme(u16),
    /// The signature does not verify with the signing site's certificate.
    #[error("the signature does not match the signing site's certificate")]
    Bad,
    /// The signing site's certificate is not known (yet).
    #[error("no certificate known for site {0}")]
    UnknownSigner(String),
    /// The identity frame a site answered with is refused.
    #[error("identity of site {site} refused: {problem}")]
    Identity {
        /// The site.
        site: String,
        /// Why, e.g. "not issued by a trusted CA".
        problem: String,
    },
}

impl SignatureError {
    /// A stable short code for counters, e.g. `signature:unsigned`.
    pub fn reason(&self) -> &'static str {
        match self {
            Self::Unsigned => "signature:unsigned",
            Self::Malformed => "signature:malformed",
            Self::Scheme(_) => "signature:scheme",
            Self::Bad => "signature:bad",
            Self::UnknownSigner(_) => "signature:unknown_signer",
            Self::Identity { .. } => "signature:identity",
        }
    }
}

/// The remote sites' certificates, checked against this site's trusted CAs.
pub trait Verify: Send + fmt::Debug {
    /// Whether a certificate of `site` is known and valid at `now_ms`.
    fn knows(&self, site: &str, now_ms: i64) -> bool;
    /// Checks `signature` (`scheme`) over `message` with `site`'s certificate.
    fn verify(
        &self,
        site: &str,
        scheme: u16,
        message: &[u8],
        signature: &[u8],
        now_ms: i64,
    ) -> Result<(), SignatureError>;
    /// Takes `site`'s certificate chain (leaf first) once it chains to a trusted CA, names
    /// `site` and is valid at `now_ms`.
    fn learn(&mut self, site: &str, chain: &[&[u8]], now_ms: i64) -> Result<(), SignatureError>;
    /// Forgets `site`'s certificate: its session came up again, perhaps with a new one.
    fn forget(&mut self, site: &str);
}

/// A signed frame, opened: the frame as an unsigned one (its flag cleared), the bytes
/// the signature covers, and the signature.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Opened<'a> {
    /// The frame without its signature block, kind flag cleared: what the decoders read.
    pub frame: Vec<u8>,
    /// What the signature covers.
    pub message: Vec<u8>,
    /// The scheme code.
    pub scheme: u16,
    /// The signature.
    pub signature: &'a [u8],
}

/// The bytes a signature covers for `frame` (its flag set) under `key_expr`.
pub fn message(key_expr: &str, frame: &[u8]) -> Vec<u8> {
    let mut m = Vec::with_capacity(CONTEXT.len() + key_expr.len() + 1 + frame.len());
    m.extend_from_slice(CONTEXT);
    m.extend_from_slice(key_expr.as_bytes());
    m.push(0);
    m.extend_from_slice(frame);
    m
}

/// Signs `frame` (an encoded frame) in place for `key_expr`: sets its flag and appends the
/// block. `sign` returns the scheme code and the signature of the bytes it is given.
pub fn seal<E>(
    frame: &mut Vec<u8>,
    key_expr: &str,
    sign: impl FnOnce(&[u8]) -> Result<(u16, Vec<u8>), E>,
) -> Result<(), E> {
    if let Some(kind) = frame.get_mut(1) {
        *kind |= SIGNED;
    }
    let (scheme, signature) = sign(&message(key_expr, frame))?;
    // Signatures of the schemes rustls signs with are at most 512 bytes (RSA-4096).
    let len = u16::try_from(signature.len()).unwrap_or(u16::MAX);
    frame.extend_from_slice(&signature);
    frame.extend(scheme.to_le_bytes());
    frame.extend(len.to_le_bytes());
    Ok(())
}

/// Whether `bytes` carries a signature block.
pub fn is_signed(bytes: &[u8]) -> bool {
    bytes.get(1).is_some_and(|k| k & SIGNED != 0)
}

/// Opens a signed frame published under `key_expr`; `None` for an unsigned one.
pub fn open<'a>(key_expr: &str, bytes: &'a [u8]) -> Result<Option<Opened<'a>>, SignatureError> {
    if !is_signed(bytes) {
        return Ok(None);
    }
    let (rest, tail) = bytes
        .split_last_chunk::<4>()
        .ok_or(SignatureError::Malformed)?;
    let scheme = u16::from_le_bytes([tail[0], tail[1]]);
    let len = usize::from(u16::from_le_bytes([tail[2], tail[3]]));
    // At least the version and kind bytes before the signature.
    let body_len = rest
        .len()
        .checked_sub(len)
        .filter(|n| *n >= 2)
        .ok_or(SignatureError::Malformed)?;
    let (signed, signature) = rest.split_at(body_len);
    let mut frame = signed.to_vec();
    frame[1] &= !SIGNED;
    Ok(Some(Opened {
        frame,
        message: message(key_expr, signed),
        scheme,
        signature,
    }))
}

/// Encodes an identity frame: a site's certificate chain (DER, leaf first).
pub fn encode_identity(chain: &[Vec<u8>]) -> Vec<u8> {
    let mut out = vec![VERSION, KIND_IDENTITY, chain.len().min(MAX_CHAIN) as u8];
    for der in chain.iter().take(MAX_CHAIN) {
        // A certificate over 64 KiB would make the frame too large to be taken anyway.
        out.extend((der.len().min(usize::from(u16::MAX)) as u16).to_le_bytes());
        out.extend_from_slice(der);
    }
    out
}

/// Decodes an identity frame into its certificates (DER, leaf first).
pub fn decode_identity(bytes: &[u8]) -> Result<Vec<&[u8]>, DecodeError> {
    if bytes.len() > MAX_IDENTITY_BYTES {
        return Err(DecodeError::Range {
            field: "identity",
            value: bytes.len() as i64,
        });
    }
    let [version, kind, count, rest @ ..] = bytes else {
        return Err(DecodeError::Truncated { field: "count" });
    };
    let mut rest: &[u8] = rest;
    if *version != VERSION {
        return Err(DecodeError::Version(*version));
    }
    if *kind != KIND_IDENTITY {
        return Err(DecodeError::Kind {
            expected: KIND_IDENTITY,
            found: *kind,
        });
    }
    if *count == 0 || usize::from(*count) > MAX_CHAIN {
        return Err(DecodeError::Range {
            field: "count",
            value: i64::from(*count),
        });
    }
    let mut chain = Vec::with_capacity(usize::from(*count));
    for _ in 0..*count {
        let (len, after) = rest
            .split_first_chunk::<2>()
            .ok_or(DecodeError::Truncated { field: "length" })?;
        let len = usize::from(u16::from_le_bytes(*len));
        if after.len() < len {
            return Err(DecodeError::Truncated {
                field: "certificate",
            });
        }
        let (der, after) = after.split_at(len);
        chain.push(der);
        rest = after;
    }
    if !rest.is_empty() {
        return Err(DecodeError::Trailing(rest.len()));
    }
    Ok(chain)
}

/// A sample waiting for its signer's certificate: its key expression and payload.
pub type HeldSample = (String, Vec<u8>);

/// Signed samples held per site until the site's certificate arrives, bounded.
#[derive(Debug, Default)]
pub struct Awaiting {
    sites: HashMap<String, Held>,
}

#[derive(Debug, Default)]
struct Held {
    samples: VecDeque<HeldSample>,
    bytes: usize,
    asked: bool,
}

/// What holding a sample came to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Hold {
    /// Held; the certificate is to be asked for (nobody asked yet).
    AskNow,
    /// Held; the certificate was asked for already.
    Asked,
    /// Not held: the site's share is full.
    Full,
}

impl Awaiting {
    /// Holds a sample of `site`.
    pub fn hold(&mut self, site: &str, key: &str, payload: &[u8]) -> Hold {
        let held = self.sites.entry(site.to_owned()).or_default();
        if held.samples.len() >= HELD_PER_SITE
            || held.bytes + payload.len() + key.len() > HELD_BYTES_PER_SITE
        {
            return Hold::Full;
        }
        held.bytes += payload.len() + key.len();
        held.samples.push_back((key.to_owned(), payload.to_vec()));
        if held.asked {
            Hold::Asked
        } else {
            held.asked = true;
            Hold::AskNow
        }
    }

    /// Notes that `site`'s certificate will be asked for (its session came up).
    pub fn asking(&mut self, site: &str) {
        self.sites.entry(site.to_owned()).or_default().asked = true;
    }

    /// Everything held for `site`, in arrival order; asking is over.
    pub fn release(&mut self, site: &str) -> Vec<HeldSample> {
        self.sites
            .remove(site)
            .map(|h| h.samples.into())
            .unwrap_or_default()
    }

    /// The question for `site`'s certificate went unanswered: true when samples wait, so
    /// that it is asked again (the next held sample asks otherwise).
    pub fn unanswered(&mut self, site: &str) -> bool {
        match self.sites.get_mut(site) {
            Some(h) if !h.samples.is_empty() => true,
            Some(h) => {
                h.asked = false;
                false
            }
            None => false,
        }
    }

    /// Samples held, all sites.
    pub fn len(&self) -> usize {
        self.sites.values().map(|h| h.samples.len()).sum()
    }

    /// Whether nothing is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::{KIND_LEASE, VERSION};

    fn frame() -> Vec<u8> {
        vec![VERSION, KIND_LEASE, 1, 2, 3, 4]
    }

    fn fake_sign(m: &[u8]) -> Result<(u16, Vec<u8>), ()> {
        // Not a signature: enough to see what the seal covers.
        Ok((0x0807, m.iter().rev().take(64).copied().collect()))
    }

    #[test]
    fn a_sealed_frame_opens_into_the_frame_and_what_was_signed() {
        let key = "shoal/shore/leases/auv-1";
        let mut f = frame();
        let mut covered = Vec::new();
        seal(&mut f, key, |m| {
            covered = m.to_vec();
            fake_sign(m)
        })
        .unwrap();
        assert!(is_signed(&f));
        assert_eq!(f[1], KIND_LEASE | SIGNED);
        let opened = open(key, &f).unwrap().unwrap();
        assert_eq!(opened.frame, frame());
        assert_eq!(opened.message, covered);
        assert_eq!(opened.scheme, 0x0807);
        assert_eq!(opened.signature, fake_sign(&covered).unwrap().1.as_slice());
        assert!(covered.starts_with(CONTEXT));
        // Another key expression is another message.
        let moved = open("shoal/shore/leases/auv-2", &f).unwrap().unwrap();
        assert_ne!(moved.message, covered);
        // Unsigned frames are not opened.
        assert_eq!(open(key, &frame()).unwrap(), None);
    }

    #[test]
    fn a_block_that_does_not_fit_is_malformed() {
        let key = "shoal/shore/leases/auv-1";
        for bad in [
            vec![VERSION, KIND_LEASE | SIGNED],
            vec![VERSION, KIND_LEASE | SIGNED, 0, 0, 9, 0],
            vec![
                VERSION,
                KIND_LEASE | SIGNED,
                7,
                7,
                7,
                0x07,
                0x08,
                0xff,
                0xff,
            ],
            // A length that leaves less than the version and kind bytes.
            vec![VERSION, KIND_LEASE | SIGNED, 0x07, 0x08, 3, 0],
        ] {
            assert_eq!(open(key, &bad), Err(SignatureError::Malformed), "{bad:?}");
        }
    }

    #[test]
    fn an_identity_frame_round_trips_and_bad_ones_are_refused() {
        let chain = vec![vec![1u8; 300], vec![2u8; 5]];
        let bytes = encode_identity(&chain);
        let back = decode_identity(&bytes).unwrap();
        assert_eq!(back, vec![&chain[0][..], &chain[1][..]]);
        assert!(decode_identity(&bytes[..bytes.len() - 1]).is_err());
        let mut trailing = bytes.clone();
        trailing.push(0);
        assert_eq!(decode_identity(&trailing), Err(DecodeError::Trailing(1)));
        assert!(decode_identity(&encode_identity(&[])).is_err());
        let mut other = bytes.clone();
        other[1] = KIND_LEASE;
        assert!(matches!(
            decode_identity(&other),
            Err(DecodeError::Kind { .. })
        ));
        assert!(decode_identity(&vec![0u8; MAX_IDENTITY_BYTES + 1]).is_err());
    }

    proptest::proptest! {
        #[test]
        fn any_sealed_frame_opens_to_itself(
            body in proptest::collection::vec(proptest::prelude::any::<u8>(), 2..300),
            signature in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..600),
            scheme in proptest::prelude::any::<u16>(),
            vehicle in "[a-z0-9-]{1,32}",
        ) {
            let mut body = body;
            body[1] &= !SIGNED;
            let key = format!("shoal/ship/leases/{vehicle}");
            let mut sealed = body.clone();
            seal(&mut sealed, &key, |_| Ok::<_, ()>((scheme, signature.clone()))).unwrap();
            let opened = open(&key, &sealed).unwrap().unwrap();
            proptest::prop_assert_eq!(&opened.frame, &body);
            proptest::prop_assert_eq!(opened.signature, signature.as_slice());
            proptest::prop_assert_eq!(opened.scheme, scheme);
        }

        #[test]
        fn arbitrary_bytes_never_panic(
            bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..400),
        ) {
            let _ = open("shoal/ship/orders/shore/auv-1", &bytes);
            let _ = decode_identity(&bytes);
        }
    }

    #[test]
    fn held_samples_are_bounded_and_released_in_order() {
        let mut a = Awaiting::default();
        assert_eq!(a.hold("ship", "k1", b"one"), Hold::AskNow);
        assert_eq!(a.hold("ship", "k2", b"two"), Hold::Asked);
        assert_eq!(a.hold("shore", "k3", b"three"), Hold::AskNow);
        assert_eq!(a.len(), 3);
        assert_eq!(
            a.release("ship"),
            vec![
                ("k1".into(), b"one".to_vec()),
                ("k2".into(), b"two".to_vec())
            ]
        );
        assert_eq!(a.len(), 1);
        // Unanswered with samples waiting: ask again.
        assert!(a.unanswered("shore"));
        // By count.
        for i in 0..HELD_PER_SITE {
            assert_ne!(a.hold("ship", "k", &[0; 8]), Hold::Full, "{i}");
        }
        assert_eq!(a.hold("ship", "k", &[0; 8]), Hold::Full);
        // By bytes.
        assert_eq!(a.hold("big", "k", &[0; 600 * 1024]), Hold::AskNow);
        assert_eq!(a.hold("big", "k", &[0; 600 * 1024]), Hold::Full);
        // Asked at session start, nothing held: the first sample does not ask again.
        a.asking("quiet");
        assert_eq!(a.hold("quiet", "k", b"x"), Hold::Asked);
        a.release("quiet");
        a.asking("idle");
        assert!(!a.unanswered("idle"));
        assert_eq!(a.hold("idle", "k", b"x"), Hold::AskNow);
    }
}
