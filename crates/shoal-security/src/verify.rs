//! Verifying envelopes: certificate chain, validity, revocation, freshness, replay and the
//! signature; and [`Gate`], which adds the access policy and counts refusals.

use std::collections::HashMap;
use std::sync::Arc;

use ed25519_dalek::Signature;
use tracing::debug;

use crate::cert::{CertError, CertId, Certificate, TrustAnchor, Validity};
use crate::envelope::{Credential, Envelope};
use crate::identity::Identity;
use crate::policy::Policy;
use crate::reject::{Rejection, RejectionCounts};
use crate::replay::ReplayWindow;
use crate::revocation::RevocationList;

/// How strict a [`Verifier`] is about time and how much it remembers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VerifierConfig {
    /// Oldest message accepted, by the receiver's clock (ms). Default 30 s: DDS delivers
    /// in well under a second, and a looser bound only widens what a replay could reuse.
    pub max_age_ms: i64,
    /// How far ahead of the receiver's clock a timestamp may be (ms). Default 5 s of
    /// clock skew between station and vehicles.
    pub max_future_ms: i64,
    /// Counters remembered per sender certificate. Default 1024, because one sender's
    /// topics travel on separate DDS writers and may arrive interleaved out of order.
    pub replay_window: u32,
    /// Certificates remembered for compact envelopes. Default 4096; the least useful entry
    /// is forgotten beyond it (the sender's next full envelope brings it back).
    pub max_known_certificates: usize,
}

impl Default for VerifierConfig {
    fn default() -> Self {
        Self {
            max_age_ms: 30_000,
            max_future_ms: 5_000,
            replay_window: 1024,
            max_known_certificates: 4096,
        }
    }
}

/// Who sent a verified envelope.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VerifiedSender {
    /// The authenticated identity (from the certificate).
    pub identity: Identity,
    /// The certificate's serial number (hex).
    pub serial: String,
    /// The certificate's id.
    pub cert_id: CertId,
}

/// Checks envelopes against the station CA, the revocation list and per-sender replay
/// windows. Verifying updates the replay windows (`&mut self`): threads share one verifier
/// behind a `Mutex`, never a copy each, or a replay could pass one copy after another.
#[derive(Debug)]
pub struct Verifier {
    anchor: TrustAnchor,
    revocations: RevocationList,
    config: VerifierConfig,
    /// Leaf certificates already shown to chain to the anchor, by id.
    known: HashMap<CertId, Arc<Certificate>>,
    windows: HashMap<CertId, ReplayWindow>,
}

impl Verifier {
    /// A verifier trusting `anchor`, refusing what `revocations` lists.
    pub fn new(anchor: TrustAnchor, revocations: RevocationList, config: VerifierConfig) -> Self {
        Self {
            anchor,
            revocations,
            config,
            known: HashMap::new(),
            windows: HashMap::new(),
        }
    }

    /// The configuration.
    pub fn config(&self) -> &VerifierConfig {
        &self.config
    }

    /// Replaces the revocation list (after the station revokes or rotates a certificate).
    pub fn set_revocations(&mut self, revocations: RevocationList) {
        self.revocations = revocations;
    }

    /// The revocation list in force.
    pub fn revocations(&self) -> &RevocationList {
        &self.revocations
    }

    /// Teaches the verifier a certificate so compact envelopes from it verify; it must
    /// chain to the anchor. Dates and revocation are still checked per message.
    pub fn add_certificate(&mut self, cert: Certificate) -> Result<(), CertError> {
        self.anchor.verify_issued(&cert)?;
        self.remember(Arc::new(cert));
        Ok(())
    }

    fn remember(&mut self, cert: Arc<Certificate>) {
        if self.known.len() >= self.config.max_known_certificates.max(1)
            && !self.known.contains_key(&cert.id())
        {
            // Forget a certificate with no replay state first (never used), else any: the
            // cache only saves work, correctness does not depend on it.
            let victim = self
                .known
                .keys()
                .find(|id| !self.windows.contains_key(id))
                .or_else(|| self.known.keys().next())
                .copied();
            if let Some(id) = victim {
                self.known.remove(&id);
            }
        }
        self.known.insert(cert.id(), cert);
    }

    /// The sender's certificate, checked to chain to the anchor (cached by id).
    fn certificate(&mut self, credential: &Credential) -> Result<Arc<Certificate>, Rejection> {
        let id = credential.cert_id();
        if let Some(cert) = self.known.get(&id) {
            return Ok(Arc::clone(cert));
        }
        let Credential::Certificate(der) = credential else {
            return Err(Rejection::UnknownCertificate(id));
        };
        let cert = Certificate::from_der(der).map_err(Rejection::BadCertificate)?;
        match self.anchor.verify_issued(&cert) {
            Ok(()) => {}
            Err(CertError::Untrusted) => return Err(Rejection::UntrustedCertificate),
            Err(e) => return Err(Rejection::BadCertificate(e)),
        }
        let cert = Arc::new(cert);
        self.remember(Arc::clone(&cert));
        Ok(cert)
    }

    /// Every check except recording the counter: chain, dates, revocation, freshness,
    /// replay (read-only) and signature. Cheap checks run first, so junk costs little.
    pub fn authenticate(
        &mut self,
        env: &Envelope,
        now_ms: i64,
    ) -> Result<VerifiedSender, Rejection> {
        let ca = self.anchor.certificate();
        if ca.validity_at(now_ms) == Validity::Expired {
            return Err(Rejection::CaExpired {
                not_after_ms: ca.not_after_ms(),
            });
        }
        let cert = self.certificate(env.credential())?;
        match cert.validity_at(now_ms) {
            Validity::Valid => {}
            Validity::Expired => {
                return Err(Rejection::CertificateExpired {
                    serial: cert.serial().to_owned(),
                    not_after_ms: cert.not_after_ms(),
                });
            }
            Validity::NotYetValid => {
                return Err(Rejection::CertificateNotYetValid {
                    serial: cert.serial().to_owned(),
                    not_before_ms: cert.not_before_ms(),
                });
            }
        }
        if self.revocations.is_revoked(cert.serial()) {
            return Err(Rejection::Revoked {
                serial: cert.serial().to_owned(),
            });
        }
        let age_ms = now_ms.saturating_sub(env.timestamp_ms());
        if age_ms > self.config.max_age_ms {
            return Err(Rejection::Stale { age_ms });
        }
        if age_ms < -self.config.max_future_ms {
            return Err(Rejection::FromFuture {
                ahead_ms: age_ms.saturating_neg(),
            });
        }
        if let Some(window) = self.windows.get(&cert.id()) {
            window.check(env.counter()).map_err(Rejection::Replayed)?;
        }
        let signature = Signature::from_bytes(env.signature());
        cert.public_key()
            .verify_strict(&env.signed_bytes(cert.id()), &signature)
            .map_err(|_| Rejection::BadSignature)?;
        // verify_issued already required an identity; keep the invariant explicit.
        let identity = cert
            .identity()
            .cloned()
            .ok_or(Rejection::BadCertificate(CertError::NoIdentity))?;
        Ok(VerifiedSender {
            identity,
            serial: cert.serial().to_owned(),
            cert_id: cert.id(),
        })
    }

    /// Records the counter of an authenticated envelope; refuses it if it was replayed.
    pub fn commit(&mut self, sender: &VerifiedSender, env: &Envelope) -> Result<(), Rejection> {
        let size = self.config.replay_window;
        self.windows
            .entry(sender.cert_id)
            .or_insert_with(|| ReplayWindow::new(size))
            .accept(env.counter())
            .map_err(Rejection::Replayed)
    }

    /// Checks an envelope fully and records its counter.
    pub fn verify(&mut self, env: &Envelope, now_ms: i64) -> Result<VerifiedSender, Rejection> {
        let sender = self.authenticate(env, now_ms)?;
        self.commit(&sender, env)?;
        Ok(sender)
    }
}

/// An envelope that passed every check.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Admitted {
    /// Who sent it.
    pub sender: VerifiedSender,
    /// The envelope (topic, payload, timestamp, counter).
    pub envelope: Envelope,
}

/// The receive path for IP links: decode, verify, check the policy, count refusals.
#[derive(Debug)]
pub struct Gate {
    verifier: Verifier,
    policy: Policy,
    counts: RejectionCounts,
}

impl Gate {
    /// A gate with this verifier and policy.
    pub fn new(verifier: Verifier, policy: Policy) -> Self {
        Self {
            verifier,
            policy,
            counts: RejectionCounts::new(),
        }
    }

    /// Admits the envelope in `wire` or says why not.
    ///
    /// `instance_key` decodes the payload for its topic and returns the vehicle id the
    /// sample speaks for ([`crate::VehicleOwned::owner_vehicle`]), or why it cannot. The
    /// counter is recorded only once the policy allowed the message.
    pub fn admit<F>(
        &mut self,
        wire: &[u8],
        now_ms: i64,
        instance_key: F,
    ) -> Result<Admitted, Rejection>
    where
        F: FnOnce(&str, &[u8]) -> Result<String, String>,
    {
        let result = self.check(wire, now_ms, instance_key);
        if let Err(rejection) = &result {
            self.counts.record(rejection);
            debug!(reason = %rejection.reason(), detail = %rejection, "envelope rejected");
        }
        result
    }

    fn check<F>(&mut self, wire: &[u8], now_ms: i64, instance_key: F) -> Result<Admitted, Rejection>
    where
        F: FnOnce(&str, &[u8]) -> Result<String, String>,
    {
        let envelope = Envelope::decode(wire)?;
        let sender = self.verifier.authenticate(&envelope, now_ms)?;
        let instance = instance_key(envelope.topic(), envelope.payload())
            .map_err(Rejection::MalformedPayload)?;
        self.policy
            .check(&sender.identity, envelope.topic(), &instance)?;
        self.verifier.commit(&sender, &envelope)?;
        Ok(Admitted { sender, envelope })
    }

    /// Refusals so far, by reason.
    pub fn counts(&self) -> &RejectionCounts {
        &self.counts
    }

    /// The verifier (to add certificates or replace the revocation list).
    pub fn verifier_mut(&mut self) -> &mut Verifier {
        &mut self.verifier
    }

    /// Replaces the policy (after the operator edits it).
    pub fn set_policy(&mut self, policy: Policy) {
        self.policy = policy;
    }
}
