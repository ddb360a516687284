//! OMG DDS Security 1.1 on IP links, through Cyclone DDS's built-in plugins (PKI-DH
//! authentication, Permissions access control, AES-GCM-GMAC cryptography), linked into
//! the process.
//!
//! A participant with [`Credentials`] is created with the standard `dds.sec.*` properties
//! pointing at its enclave's files. Cyclone then authenticates every remote participant
//! against the identity CA, checks its signed permissions for every endpoint it creates or
//! matches, and encrypts what the governance document says. A vehicle's writers publish
//! in its own partition (`shoal.vehicle.<id>`), the only one its permissions allow; a
//! subscriber then knows which authenticated vehicle a sample came from and refuses one
//! that speaks about another vehicle ([`crate::ReadError::Impersonation`]).

use std::collections::{BTreeMap, HashSet};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Mutex, RwLock};

use shoal_security::dds::{Enclave, VEHICLE_PARTITION_PREFIX, names, vehicle_partition};

/// The partitions every Shoal reader listens to: the default one (the station's writers,
/// and unmodified vehicles when security is off) and every vehicle's own.
pub(crate) const READ_PARTITIONS: [&str; 2] = ["", "shoal.vehicle.*"];

/// Who a participant is on a secured bus.
#[derive(Debug, Clone)]
pub struct Credentials {
    enclave: Enclave,
    vehicle_id: Option<String>,
}

impl Credentials {
    /// The station's credentials: it publishes in the default partition.
    pub fn station(enclave: Enclave) -> Self {
        Self {
            enclave,
            vehicle_id: None,
        }
    }

    /// A vehicle's credentials: it publishes in its own partition.
    pub fn vehicle(enclave: Enclave, vehicle_id: &str) -> Self {
        Self {
            enclave,
            vehicle_id: Some(vehicle_id.to_string()),
        }
    }

    /// The enclave the participant loads.
    pub fn enclave(&self) -> &Enclave {
        &self.enclave
    }

    /// The partition this participant's writers use.
    pub(crate) fn writer_partition(&self) -> Option<String> {
        self.vehicle_id.as_deref().map(vehicle_partition)
    }

    /// The participant QoS properties that turn the plugins on.
    pub(crate) fn properties(&self) -> Vec<(String, String)> {
        let file = |name: &str| uri(&self.enclave.file(name));
        let mut p: Vec<(String, String)> = [
            ("dds.sec.auth.library.path", "dds_security_auth".to_string()),
            ("dds.sec.auth.library.init", "init_authentication".into()),
            (
                "dds.sec.auth.library.finalize",
                "finalize_authentication".into(),
            ),
            ("dds.sec.crypto.library.path", "dds_security_crypto".into()),
            ("dds.sec.crypto.library.init", "init_crypto".into()),
            ("dds.sec.crypto.library.finalize", "finalize_crypto".into()),
            ("dds.sec.access.library.path", "dds_security_ac".into()),
            ("dds.sec.access.library.init", "init_access_control".into()),
            (
                "dds.sec.access.library.finalize",
                "finalize_access_control".into(),
            ),
            ("dds.sec.auth.identity_ca", file(names::IDENTITY_CA)),
            ("dds.sec.auth.identity_certificate", file(names::CERT)),
            ("dds.sec.auth.private_key", file(names::KEY)),
            ("dds.sec.access.permissions_ca", file(names::PERMISSIONS_CA)),
            ("dds.sec.access.governance", file(names::GOVERNANCE)),
            ("dds.sec.access.permissions", file(names::PERMISSIONS)),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v))
        .collect();
        if let Some(crl) = self.enclave.crl() {
            p.push(("org.eclipse.cyclonedds.sec.auth.crl".into(), uri(crl)));
        }
        p
    }
}

fn uri(path: &Path) -> String {
    let abs = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    format!("file:{}", abs.display())
}

/// The vehicle a writer's partitions name, if it publishes in one vehicle's partition.
pub(crate) fn partition_vehicle(partitions: &[String]) -> Option<String> {
    match partitions {
        [one] => one
            .strip_prefix(VEHICLE_PARTITION_PREFIX)
            .map(str::to_string),
        _ => None,
    }
}

/// What a subscriber refuses by publisher: samples about another vehicle than the one
/// whose partition they came in, and samples from revoked vehicles.
#[derive(Debug, Default)]
pub(crate) struct PublisherGuard {
    revoked: RwLock<HashSet<String>>,
    impersonations: AtomicU64,
    revoked_refused: AtomicU64,
}

impl PublisherGuard {
    pub(crate) fn set_revoked(&self, vehicles: HashSet<String>) {
        *self
            .revoked
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = vehicles;
    }

    pub(crate) fn is_revoked(&self, vehicle: &str) -> bool {
        self.revoked
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .contains(vehicle)
    }

    pub(crate) fn count_impersonation(&self) {
        self.impersonations.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn count_revoked(&self) {
        self.revoked_refused.fetch_add(1, Ordering::Relaxed);
    }

    pub(crate) fn impersonations(&self) -> u64 {
        self.impersonations.load(Ordering::Relaxed)
    }

    pub(crate) fn revoked(&self) -> u64 {
        self.revoked_refused.load(Ordering::Relaxed)
    }
}

/// Authentication handshakes Cyclone refused in this process, by reason.
static HANDSHAKE_REFUSALS: Mutex<BTreeMap<&'static str, u64>> = Mutex::new(BTreeMap::new());

/// The reason a refused handshake is counted under: the certificate's dates, its
/// revocation, a chain to another CA, the permissions, or anything else.
fn handshake_reason(message: &str) -> &'static str {
    let m = message.to_ascii_lowercase();
    if m.contains("expired") || m.contains("not yet valid") || m.contains("validity") {
        "expired"
    } else if m.contains("revoked") {
        "revoked"
    } else if m.contains("permission") || m.contains("governance") {
        "permissions"
    } else if m.contains("verif")
        || m.contains("issuer")
        || m.contains("trust")
        || m.contains("signature failure")
    {
        "untrusted"
    } else {
        "other"
    }
}

/// Counts a Cyclone log record if it reports a refused authentication handshake (the
/// plugins log them as warnings: "Validate remote identity failed: ...", "Process
/// handshake failed: ...").
pub(crate) fn note_handshake(message: &str) {
    let refused = message.contains("Validate remote identity failed")
        || (message.contains("handshake") && message.contains("failed"));
    if !refused {
        return;
    }
    let reason = handshake_reason(message);
    let mut m = HANDSHAKE_REFUSALS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    *m.entry(reason).or_default() += 1;
}

/// Authentication handshakes DDS Security refused in this process so far, by reason
/// (`expired`, `revoked`, `untrusted`, `permissions`, `other`): participants that never
/// got in, so no sample of theirs reaches a subscriber to be refused there.
pub fn handshake_refusals() -> BTreeMap<&'static str, u64> {
    HANDSHAKE_REFUSALS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .clone()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refused_handshakes_are_counted_by_reason_and_nothing_else_is() {
        let before = handshake_refusals();
        let count = |m: &BTreeMap<&str, u64>, k| m.get(k).copied().unwrap_or(0);
        note_handshake("Validate remote identity failed: Certificate expired");
        note_handshake(
            "Process handshake failed: certificate verify failed: unable to get local issuer certificate",
        );
        // What Cyclone says when a participant from another CA answers the station.
        note_handshake(
            "Begin handshake reply failed: Certificate not valid: error: certificate signature failure; subject: /CN=x",
        );
        note_handshake("Remote secure participant 1:2:3:1c1 not allowed");
        let after = handshake_refusals();
        assert_eq!(count(&after, "expired"), count(&before, "expired") + 1);
        assert_eq!(count(&after, "untrusted"), count(&before, "untrusted") + 2);
        assert_eq!(
            after.values().sum::<u64>(),
            before.values().sum::<u64>() + 3
        );
    }

    #[test]
    fn partition_names_the_vehicle_only_when_alone() {
        assert_eq!(
            partition_vehicle(&["shoal.vehicle.auv-1".into()]).as_deref(),
            Some("auv-1")
        );
        assert_eq!(partition_vehicle(&[]), None);
        assert_eq!(partition_vehicle(&["x".into()]), None);
        assert_eq!(
            partition_vehicle(&["shoal.vehicle.a".into(), "shoal.vehicle.b".into()]),
            None
        );
    }

    #[test]
    fn properties_name_every_file_as_a_uri() {
        let c = Credentials::vehicle(
            Enclave::new(
                "/ks/enclaves/shoal/vehicle/auv-1",
                Some("/ks/crl.pem".into()),
            ),
            "auv-1",
        );
        let p = c.properties();
        let get = |k: &str| p.iter().find(|(n, _)| n == k).map(|(_, v)| v.as_str());
        assert_eq!(
            get("dds.sec.auth.identity_certificate"),
            Some("file:/ks/enclaves/shoal/vehicle/auv-1/cert.pem")
        );
        assert_eq!(
            get("org.eclipse.cyclonedds.sec.auth.crl"),
            Some("file:/ks/crl.pem")
        );
        assert_eq!(c.writer_partition().as_deref(), Some("shoal.vehicle.auv-1"));
    }
}
