//! Signed samples on IP links: what a participant with security on sends and admits.
//!
//! Every Shoal topic `shoal/x` has a signed twin `shoal/x/signed` of type
//! `shoal::SignedSample { @key string key; sequence<octet> envelope; }` (see `idl/shoal.idl`).
//! The envelope (`shoal-security`) holds the sample's CDR bytes, the model topic name, a
//! timestamp, a counter, the sender's certificate and an Ed25519 signature. A participant
//! with security on writes only the twin, and admits from it only what the [`Gate`]
//! accepts (chain to the station CA, revocation list, dates, freshness, replay window,
//! publish policy); samples still arriving on the plain topic are counted as unsigned and
//! dropped. Standard DDS Security (the OMG plugins) is not used: see `docs/deviations.md`.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use serde::{Deserialize, Serialize};
use shoal_model::Validated;
use shoal_security::{Gate, RejectionCounts, SigningIdentity, envelope::counter_start_from_clock};

use crate::error::SendError;
use crate::topics::TopicType;

/// The DDS type name of a signed sample, as in `idl/shoal.idl`.
pub const SIGNED_TYPE_NAME: &str = "shoal::SignedSample";

/// The signed twin of a topic name.
pub fn signed_topic(topic: &str) -> String {
    format!("{topic}/signed")
}

/// The wire form of a signed sample.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct SignedWire {
    /// The model sample's instance key as text, so a signed topic keeps the plain topic's
    /// per-instance history (keep-last per vehicle).
    pub(crate) key: String,
    /// An encoded `shoal_security::Envelope`.
    pub(crate) envelope: Vec<u8>,
}

impl SignedWire {
    /// The key field, as `idl/shoal.idl` declares it.
    pub(crate) const KEY_FIELDS: &'static [&'static str] = &["key"];
}

/// Refusals of a secure participant so far.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct SecurityCounts {
    /// Signed samples the gate refused, by reason.
    pub refused: RejectionCounts,
    /// Samples that arrived on a plain (unsigned) topic, by topic.
    pub unsigned: BTreeMap<&'static str, u64>,
}

impl SecurityCounts {
    /// Every refusal, signed or not.
    pub fn total(&self) -> u64 {
        self.refused.total() + self.unsigned.values().sum::<u64>()
    }
}

/// A participant's credentials: who it signs as, and the gate it admits samples through.
pub struct Security {
    identity: SigningIdentity,
    counter: AtomicU64,
    gate: Mutex<Gate>,
    unsigned: Mutex<BTreeMap<&'static str, u64>>,
}

impl std::fmt::Debug for Security {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Security")
            .field("identity", self.identity.identity())
            .finish_non_exhaustive()
    }
}

/// Why a signed sample was not delivered.
#[derive(Debug)]
pub(crate) enum Refused {
    /// The gate refused it (reason code, detail).
    Gate(&'static str, String),
    /// It verified but its payload failed validation (the sample, for the quarantine).
    Invalid(shoal_model::ValidationError, String),
}

impl Security {
    /// Signs as `identity` and admits through `gate`.
    pub fn new(identity: SigningIdentity, gate: Gate) -> Self {
        Self {
            identity,
            // Continues above what this identity sent before a restart (see the function).
            counter: AtomicU64::new(counter_start_from_clock(shoal_model::now_ms())),
            gate: Mutex::new(gate),
            unsigned: Mutex::new(BTreeMap::new()),
        }
    }

    /// Who this participant signs as.
    pub fn identity(&self) -> &shoal_security::Identity {
        self.identity.identity()
    }

    /// Refusals so far.
    pub fn counts(&self) -> SecurityCounts {
        SecurityCounts {
            refused: self
                .gate
                .lock()
                .map(|g| g.counts().clone())
                .unwrap_or_default(),
            unsigned: self.unsigned.lock().map(|u| u.clone()).unwrap_or_default(),
        }
    }

    /// Replaces the revocation list (after `shoal keys revoke`).
    pub fn set_revocations(&self, crl: shoal_security::RevocationList) {
        if let Ok(mut g) = self.gate.lock() {
            g.verifier_mut().set_revocations(crl);
        }
    }

    /// Wraps a valid sample of `T` in a signed envelope.
    pub(crate) fn seal<T: TopicType>(&self, sample: &T) -> Result<SignedWire, SendError> {
        let payload = crate::to_cdr_le(sample)?;
        let counter = self.counter.fetch_add(1, Ordering::Relaxed);
        let envelope = self
            .identity
            .sign(T::TOPIC, &payload, shoal_model::now_ms(), counter)
            .map_err(SendError::Sign)?;
        Ok(SignedWire {
            key: sample.key_text(),
            envelope: envelope.encode(),
        })
    }

    /// Admits a signed sample of `T`: verified, allowed by the policy, decoded and valid.
    pub(crate) fn open<T: TopicType>(&self, wire: &SignedWire) -> Result<Validated<T>, Refused> {
        let mut decoded: Option<T> = None;
        let admitted = {
            let mut gate = self
                .gate
                .lock()
                .map_err(|_| Refused::Gate("internal", "gate lock poisoned".into()))?;
            gate.admit(&wire.envelope, shoal_model::now_ms(), |topic, payload| {
                if topic != T::TOPIC {
                    return Err(format!("signed for {topic}, sent on {}", T::TOPIC));
                }
                let sample: T = crate::from_cdr(payload).map_err(|e| e.to_string())?;
                let owner = sample
                    .owner_vehicle()
                    .ok_or_else(|| format!("{} has no owning vehicle", T::TOPIC))?
                    .to_owned();
                decoded = Some(sample);
                Ok(owner)
            })
        };
        if let Err(rejection) = admitted {
            return Err(Refused::Gate(
                rejection.reason().as_str(),
                rejection.to_string(),
            ));
        }
        let sample = decoded.ok_or_else(|| Refused::Gate("internal", "no payload".into()))?;
        match Validated::new(sample) {
            Ok(sample) => Ok(sample),
            Err((e, sample)) => Err(Refused::Invalid(
                e,
                serde_json::to_string(&sample).unwrap_or_else(|e| format!("\"{e}\"")),
            )),
        }
    }

    /// Counts a sample that arrived unsigned on `topic`.
    pub(crate) fn count_unsigned(&self, topic: &'static str) {
        if let Ok(mut u) = self.unsigned.lock() {
            *u.entry(topic).or_default() += 1;
        }
    }
}
