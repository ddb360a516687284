//! The station's key store on disk: CA, station and vehicle certificates and keys,
//! per-vehicle acoustic keys and the revocation list; and the bundle a vehicle carries.
//!
//! # Layout
//!
//! ```text
//! <dir>/                       0700
//!   shoal-keys.toml            station name and validity settings
//!   ca.crt        ca.key       station CA (self-signed); the key is 0600
//!   station.crt   station.key  the station's own identity
//!   revoked.crl                X.509 CRL signed by the CA
//!   vehicles/<id>/             0700, one per vehicle with an active certificate
//!     vehicle.crt vehicle.key  its identity (SAN urn:shoal:vehicle:<id>)
//!     acoustic.key             256-bit key for the acoustic link, 0600
//!   retired/<serial>.crt       certificates revoked or replaced, kept for `list`
//! ```
//!
//! A vehicle bundle ([`KeyStore::export_vehicle`], loaded by [`VehicleBundle::load`]) holds
//! `ca.crt`, `station.crt`, `revoked.crl`, `vehicle.crt`, `vehicle.key` and `acoustic.key`.

use std::fs;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use tracing::{info, warn};

use crate::acoustic::AcousticKey;
use crate::cert::{
    CertError, Certificate, IssueError, PrivateKey, SiteName, TrustAnchor, Validity, issue_leaf,
    issue_site_leaf, self_signed_ca,
};
use crate::files::{self, FileError, FileProblem};
use crate::identity::{Identity, IdentityError, Role};
use crate::revocation::{RevocationList, RevokeReason, Revoked};
use crate::util::RandomError;

/// The store's settings file.
pub const STORE_FILE: &str = "shoal-keys.toml";
/// CA certificate file.
pub const CA_CERT: &str = "ca.crt";
/// CA private key file.
pub const CA_KEY: &str = "ca.key";
/// Station certificate file.
pub const STATION_CERT: &str = "station.crt";
/// Station private key file.
pub const STATION_KEY: &str = "station.key";
/// Revocation list file.
pub const CRL_FILE: &str = "revoked.crl";
/// Vehicle certificate file (in the vehicle's directory or bundle).
pub const VEHICLE_CERT: &str = "vehicle.crt";
/// Vehicle private key file.
pub const VEHICLE_KEY: &str = "vehicle.key";
/// Vehicle acoustic key file.
pub const ACOUSTIC_KEY: &str = "acoustic.key";
const VEHICLES_DIR: &str = "vehicles";
const RETIRED_DIR: &str = "retired";
const FORMAT: u32 = 1;
const DAY_MS: i64 = 86_400_000;
/// Leaf certificates start this long before issue, so a vehicle whose clock is a little
/// behind the station's accepts them at once.
const BACKDATE_MS: i64 = 10 * 60 * 1000;

/// Validity periods for a new store.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoreOptions {
    /// Days the CA certificate is valid. Default 3650: renewing a CA means re-issuing
    /// every certificate in the fleet.
    pub ca_validity_days: u32,
    /// Days station and vehicle certificates are valid. Default 365.
    pub cert_validity_days: u32,
    /// Days a signed revocation list is current; the store re-signs a stale one on open.
    /// Default 30.
    pub crl_validity_days: u32,
}

impl Default for StoreOptions {
    fn default() -> Self {
        Self {
            ca_validity_days: 3650,
            cert_validity_days: 365,
            crl_validity_days: 30,
        }
    }
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct StoreMeta {
    format: u32,
    station: String,
    validity: StoreOptions,
}

/// Why a key-store operation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// A file is missing, unreadable, too open, malformed, expired...
    #[error(transparent)]
    File(#[from] FileError),
    /// `init` on a directory that already holds a store.
    #[error("{}: already holds a key store ({STORE_FILE})", .0.display())]
    AlreadyInitialised(PathBuf),
    /// A station name or vehicle id that is not an identifier.
    #[error(transparent)]
    BadName(#[from] IdentityError),
    /// No active certificate for the vehicle.
    #[error("vehicle {id:?} has no active certificate in {}", dir.display())]
    UnknownVehicle {
        /// The store.
        dir: PathBuf,
        /// The vehicle id.
        id: String,
    },
    /// `issue_vehicle` for a vehicle that already has an active certificate.
    #[error("vehicle {0:?} already has an active certificate: rotate or revoke it instead")]
    VehicleExists(String),
    /// Issuing a certificate failed.
    #[error("issuing a certificate failed: {0}")]
    Issue(#[from] IssueError),
    /// Signing the revocation list failed.
    #[error("signing the revocation list failed: {0}")]
    Crl(#[from] rcgen::Error),
    /// No randomness for a key.
    #[error(transparent)]
    Random(#[from] RandomError),
    /// A federation site name or address that a site certificate cannot carry.
    #[error("{0}")]
    BadSite(String),
}

/// What `issue_vehicle` and `rotate` produced.
#[derive(Debug, Clone)]
pub struct IssuedVehicle {
    /// The vehicle.
    pub identity: Identity,
    /// Its new certificate.
    pub certificate: Certificate,
    /// Fingerprint of its new acoustic key (safe to show).
    pub acoustic_key_fingerprint: String,
}

/// A certificate's standing, for listings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CertStatus {
    /// Valid now and not revoked.
    Active,
    /// Past its validity.
    Expired,
    /// Not valid yet.
    NotYetValid,
    /// On the revocation list.
    Revoked(Revoked),
}

/// One certificate of the store, for `list`.
#[derive(Debug, Clone)]
pub struct CertEntry {
    /// Whose.
    pub identity: Identity,
    /// Serial number (hex).
    pub serial: String,
    /// Start of validity (ms).
    pub not_before_ms: i64,
    /// End of validity (ms).
    pub not_after_ms: i64,
    /// Standing now.
    pub status: CertStatus,
    /// The certificate file.
    pub path: PathBuf,
}

/// The station's key store.
#[derive(Debug)]
pub struct KeyStore {
    dir: PathBuf,
    station: Identity,
    options: StoreOptions,
    anchor: TrustAnchor,
    ca_key: PrivateKey,
    crl: RevocationList,
    /// When set, the store's clock (tests and tools that act "as of" a date).
    fixed_now_ms: Option<i64>,
}

fn days_ms(days: u32) -> i64 {
    i64::from(days) * DAY_MS
}

impl KeyStore {
    /// Creates a store in `dir` for `station_name` with default validity periods.
    pub fn init(dir: &Path, station_name: &str) -> Result<Self, StoreError> {
        Self::init_with(dir, station_name, &StoreOptions::default(), None)
    }

    /// Creates a store; `now_ms` fixes the store's clock (`None`: the system clock).
    pub fn init_with(
        dir: &Path,
        station_name: &str,
        options: &StoreOptions,
        now_ms: Option<i64>,
    ) -> Result<Self, StoreError> {
        let station = Identity::station(station_name)?;
        if dir.join(STORE_FILE).exists() {
            return Err(StoreError::AlreadyInitialised(dir.to_owned()));
        }
        files::create_private_dir(dir)?;
        let now = now_ms.unwrap_or_else(shoal_model::now_ms);
        let ca_key = PrivateKey::generate()?;
        let ca_cert = self_signed_ca(
            &ca_key,
            station.name(),
            now - BACKDATE_MS,
            now.saturating_add(days_ms(options.ca_validity_days)),
        )?;
        let anchor =
            TrustAnchor::new(ca_cert).map_err(|e| StoreError::Issue(IssueError::Reparse(e)))?;
        let mut store = Self {
            dir: dir.to_owned(),
            station,
            options: options.clone(),
            anchor,
            ca_key,
            crl: RevocationList::empty(now, days_ms(options.crl_validity_days)),
            fixed_now_ms: now_ms,
        };
        files::write_secret(&store.path(CA_KEY), store.ca_key.to_pem().as_bytes())?;
        files::write_public(
            &store.path(CA_CERT),
            store.anchor.certificate().to_pem().as_bytes(),
        )?;
        store.write_crl(&store.crl.clone())?;
        let station = store.station.clone();
        store.issue_to(
            &station,
            &store.path(STATION_CERT),
            &store.path(STATION_KEY),
        )?;
        let meta = StoreMeta {
            format: FORMAT,
            station: store.station.name().to_owned(),
            validity: options.clone(),
        };
        let body = toml::to_string(&meta).map_err(|e| {
            FileError::new(store.path(STORE_FILE), FileProblem::Invalid(e.to_string()))
        })?;
        let text = format!(
            "# Shoal key store: written by `init`; the station name and validity periods.\n{}\n",
            body.trim_end()
        );
        files::write_public(&store.path(STORE_FILE), text.as_bytes())?;
        info!(dir = %dir.display(), station = %store.station, "key store initialised");
        Ok(store)
    }

    /// Opens an existing store with the system clock.
    pub fn open(dir: &Path) -> Result<Self, StoreError> {
        Self::open_inner(dir, None)
    }

    /// Opens an existing store whose clock is fixed at `now_ms` for every later operation.
    pub fn open_at(dir: &Path, now_ms: i64) -> Result<Self, StoreError> {
        Self::open_inner(dir, Some(now_ms))
    }

    fn open_inner(dir: &Path, fixed_now_ms: Option<i64>) -> Result<Self, StoreError> {
        files::check_dir(dir)?;
        let now = fixed_now_ms.unwrap_or_else(shoal_model::now_ms);
        let meta_path = dir.join(STORE_FILE);
        let meta_text = files::read_public(&meta_path)?;
        let meta: StoreMeta = toml::from_str(&meta_text).map_err(|e| {
            let offset = e.span().map_or(0, |s| s.start).min(meta_text.len());
            let line = meta_text
                .get(..offset)
                .map_or(1, |t| t.matches('\n').count() + 1);
            FileError::new(
                &meta_path,
                FileProblem::Invalid(format!("line {line}: {}", e.message().trim())),
            )
        })?;
        if meta.format != FORMAT {
            return Err(FileError::new(
                &meta_path,
                FileProblem::Invalid(format!(
                    "format {} is not supported (expected {FORMAT})",
                    meta.format
                )),
            )
            .into());
        }
        let station = Identity::station(&meta.station)?;
        let ca_key = PrivateKey::load(&dir.join(CA_KEY))?;
        let ca_path = dir.join(CA_CERT);
        let anchor = TrustAnchor::load(&ca_path, now)?;
        if !anchor.certificate().matches_key(&ca_key) {
            return Err(FileError::new(dir.join(CA_KEY), FileProblem::KeyMismatch(ca_path)).into());
        }
        let crl = RevocationList::load(&dir.join(CRL_FILE), &anchor)?;
        let mut store = Self {
            dir: dir.to_owned(),
            station,
            options: meta.validity,
            anchor,
            ca_key,
            crl,
            fixed_now_ms,
        };
        if store.crl.next_update_ms() < now {
            // A stale list makes careful verifiers doubt it; the CA key is here, so renew.
            match store.write_crl(&store.crl.clone()) {
                Ok(()) => info!(dir = %dir.display(), "stale revocation list re-signed"),
                Err(e) => warn!(error = %e, "stale revocation list could not be re-signed"),
            }
        }
        Ok(store)
    }

    fn now(&self) -> i64 {
        self.fixed_now_ms.unwrap_or_else(shoal_model::now_ms)
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    fn vehicle_dir(&self, id: &str) -> PathBuf {
        self.dir.join(VEHICLES_DIR).join(id)
    }

    /// The store's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The station's identity.
    pub fn station(&self) -> &Identity {
        &self.station
    }

    /// The CA certificate as a trust anchor.
    pub fn trust_anchor(&self) -> &TrustAnchor {
        &self.anchor
    }

    /// The current revocation list.
    pub fn revocations(&self) -> &RevocationList {
        &self.crl
    }

    /// Signs `list` as the next CRL and writes it.
    fn write_crl(&mut self, list: &RevocationList) -> Result<(), StoreError> {
        let (signed, text) = list.sign(
            self.anchor.certificate(),
            &self.ca_key,
            self.now(),
            days_ms(self.options.crl_validity_days),
        )?;
        files::write_public(&self.path(CRL_FILE), text.as_bytes())?;
        self.crl = signed;
        Ok(())
    }

    /// Issues a key and certificate for `identity` and writes them (key first, certificate
    /// last: a certificate on disk always has its key next to it).
    fn issue_to(
        &self,
        identity: &Identity,
        cert_path: &Path,
        key_path: &Path,
    ) -> Result<Certificate, StoreError> {
        let key = PrivateKey::generate()?;
        let (not_before, not_after) = self.leaf_validity();
        let cert = issue_leaf(
            self.anchor.certificate(),
            &self.ca_key,
            &key,
            identity,
            not_before,
            not_after,
        )?;
        files::write_secret(key_path, key.to_pem().as_bytes())?;
        files::write_public(cert_path, cert.to_pem().as_bytes())?;
        Ok(cert)
    }

    /// A new leaf's validity, ms since the Unix epoch: back-dated a little for clocks
    /// behind ours, `cert_validity_days` long, and never beyond the CA that vouches for it.
    fn leaf_validity(&self) -> (i64, i64) {
        let now = self.now();
        let not_after = now
            .saturating_add(days_ms(self.options.cert_validity_days))
            .min(self.anchor.certificate().not_after_ms());
        (now - BACKDATE_MS, not_after)
    }

    /// Issues a federation site certificate (CN `site`, SANs `names`, serverAuth and
    /// clientAuth) from the station CA and writes, in `dest` (created 0700 if missing):
    /// `<site>.key` (0600), `<site>.crt`, and `<site>-ca.crt`, the CA certificate that
    /// remote sites add to their trusted CAs. Not recorded in the store: the files are
    /// the site's, and a new certificate replaces them (valid `cert_validity_days`, never
    /// beyond the CA).
    pub fn issue_site(
        &self,
        site: &str,
        names: &[SiteName],
        dest: &Path,
    ) -> Result<Certificate, StoreError> {
        if !shoal_model::is_identifier(site, shoal_model::MAX_VEHICLE_ID_LEN) {
            return Err(StoreError::BadSite(format!(
                "site name {site:?} is not an identifier (1 to 32 characters of A-Z a-z 0-9 _ . -)"
            )));
        }
        if names.is_empty() {
            return Err(StoreError::BadSite(format!(
                "site {site:?}: name at least one DNS name or IP address it listens on"
            )));
        }
        let key = PrivateKey::generate()?;
        let (not_before, not_after) = self.leaf_validity();
        let cert = issue_site_leaf(
            self.anchor.certificate(),
            &self.ca_key,
            &key,
            site,
            names,
            not_before,
            not_after,
        )?;
        if !dest.exists() {
            // An existing directory (e.g. /etc/shoal) keeps its mode.
            files::create_private_dir(dest)?;
        }
        files::write_secret(&dest.join(format!("{site}.key")), key.to_pem().as_bytes())?;
        files::write_public(&dest.join(format!("{site}.crt")), cert.to_pem().as_bytes())?;
        files::write_public(
            &dest.join(format!("{site}-ca.crt")),
            self.anchor.certificate().to_pem().as_bytes(),
        )?;
        info!(
            site,
            serial = cert.serial(),
            "federation site certificate issued"
        );
        Ok(cert)
    }

    fn active_cert_path(&self, id: &str) -> Result<PathBuf, StoreError> {
        Identity::vehicle(id)?;
        let path = self.vehicle_dir(id).join(VEHICLE_CERT);
        if path.exists() {
            Ok(path)
        } else {
            Err(StoreError::UnknownVehicle {
                dir: self.dir.clone(),
                id: id.to_owned(),
            })
        }
    }

    /// A vehicle's active certificate.
    pub fn vehicle_certificate(&self, id: &str) -> Result<Certificate, StoreError> {
        Ok(Certificate::load(&self.active_cert_path(id)?)?)
    }

    /// A vehicle's acoustic key.
    pub fn acoustic_key(&self, id: &str) -> Result<AcousticKey, StoreError> {
        self.active_cert_path(id)?;
        Ok(AcousticKey::load(&self.vehicle_dir(id).join(ACOUSTIC_KEY))?)
    }

    /// Ids of the vehicles with an active certificate, sorted.
    pub fn vehicles(&self) -> Result<Vec<String>, StoreError> {
        let dir = self.path(VEHICLES_DIR);
        let entries = match fs::read_dir(&dir) {
            Ok(e) => e,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(FileError::new(dir, FileProblem::Unreadable(e)).into()),
        };
        let mut ids = Vec::new();
        for entry in entries {
            let entry = entry.map_err(|e| FileError::new(&dir, FileProblem::Unreadable(e)))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            if Identity::vehicle(&name).is_err() {
                warn!(path = %entry.path().display(), "not a vehicle directory; ignored");
                continue;
            }
            if entry.path().join(VEHICLE_CERT).exists() {
                ids.push(name);
            }
        }
        ids.sort();
        Ok(ids)
    }

    /// Issues a certificate, private key and acoustic key for a new vehicle.
    pub fn issue_vehicle(&mut self, vehicle_id: &str) -> Result<IssuedVehicle, StoreError> {
        let identity = Identity::vehicle(vehicle_id)?;
        if self.vehicle_dir(vehicle_id).join(VEHICLE_CERT).exists() {
            return Err(StoreError::VehicleExists(vehicle_id.to_owned()));
        }
        let issued = self.write_vehicle(&identity)?;
        info!(vehicle = %identity, serial = %issued.certificate.serial(), "vehicle certificate issued");
        Ok(issued)
    }

    fn write_vehicle(&self, identity: &Identity) -> Result<IssuedVehicle, StoreError> {
        let vdir = self.vehicle_dir(identity.name());
        files::create_private_dir(&self.path(VEHICLES_DIR))?;
        files::create_private_dir(&vdir)?;
        let acoustic = AcousticKey::generate()?;
        files::write_secret(&vdir.join(ACOUSTIC_KEY), acoustic.to_pem().as_bytes())?;
        let certificate =
            self.issue_to(identity, &vdir.join(VEHICLE_CERT), &vdir.join(VEHICLE_KEY))?;
        Ok(IssuedVehicle {
            identity: identity.clone(),
            certificate,
            acoustic_key_fingerprint: acoustic.fingerprint(),
        })
    }

    /// Puts a vehicle's active certificate on the revocation list and retires its files;
    /// returns the revoked serial number. The vehicle may be issued a new certificate later.
    pub fn revoke(&mut self, vehicle_id: &str, reason: RevokeReason) -> Result<String, StoreError> {
        let cert_path = self.active_cert_path(vehicle_id)?;
        let cert = Certificate::load(&cert_path)?;
        self.retire(&cert, &cert_path, reason)?;
        let vdir = self.vehicle_dir(vehicle_id);
        for name in [VEHICLE_KEY, ACOUSTIC_KEY] {
            remove_if_present(&vdir.join(name))?;
        }
        // The directory may hold files we did not write; leave it then.
        let _ = fs::remove_dir(&vdir);
        warn!(vehicle = vehicle_id, serial = %cert.serial(), reason = reason.as_str(), "vehicle certificate revoked");
        Ok(cert.serial().to_owned())
    }

    /// Revokes first (the CRL is what protects), then moves the certificate to `retired/`.
    fn retire(
        &mut self,
        cert: &Certificate,
        cert_path: &Path,
        reason: RevokeReason,
    ) -> Result<(), StoreError> {
        let next = self.crl.with_revoked(
            cert.serial(),
            Revoked {
                revoked_ms: self.now().div_euclid(1000) * 1000,
                reason,
            },
        );
        self.write_crl(&next)?;
        let retired = self.path(RETIRED_DIR);
        files::create_private_dir(&retired)?;
        let target = retired.join(format!("{}.crt", cert.serial()));
        fs::rename(cert_path, &target)
            .map_err(|e| FileError::new(cert_path, FileProblem::Unwritable(e)))?;
        Ok(())
    }

    /// Replaces a vehicle's certificate, private key and acoustic key; the old certificate
    /// is revoked as superseded.
    pub fn rotate(&mut self, vehicle_id: &str) -> Result<IssuedVehicle, StoreError> {
        let cert_path = self.active_cert_path(vehicle_id)?;
        let old = Certificate::load(&cert_path)?;
        let identity = Identity::vehicle(vehicle_id)?;
        self.retire(&old, &cert_path, RevokeReason::Superseded)?;
        let issued = self.write_vehicle(&identity)?;
        info!(
            vehicle = %identity,
            old = %old.serial(),
            new = %issued.certificate.serial(),
            "vehicle keys rotated"
        );
        Ok(issued)
    }

    /// Replaces the station's certificate and key (before it expires, or if the key may be
    /// compromised); the old certificate is revoked as superseded.
    pub fn renew_station(&mut self) -> Result<Certificate, StoreError> {
        let cert_path = self.path(STATION_CERT);
        let old = Certificate::load(&cert_path)?;
        self.retire(&old, &cert_path, RevokeReason::Superseded)?;
        let station = self.station.clone();
        let cert = self.issue_to(&station, &cert_path, &self.path(STATION_KEY))?;
        info!(old = %old.serial(), new = %cert.serial(), "station certificate renewed");
        Ok(cert)
    }

    /// Every certificate in the store (station, vehicles, retired) with its standing.
    pub fn list(&self) -> Result<Vec<CertEntry>, StoreError> {
        let mut paths = vec![self.path(STATION_CERT)];
        for id in self.vehicles()? {
            paths.push(self.vehicle_dir(&id).join(VEHICLE_CERT));
        }
        let retired = self.path(RETIRED_DIR);
        if let Ok(entries) = fs::read_dir(&retired) {
            let mut r: Vec<PathBuf> = entries
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| p.extension().is_some_and(|e| e == "crt"))
                .collect();
            r.sort();
            paths.extend(r);
        }
        let now = self.now();
        let mut out = Vec::with_capacity(paths.len());
        for path in paths {
            let cert = Certificate::load(&path)?;
            let identity = cert.identity().cloned().ok_or_else(|| {
                FileError::new(
                    &path,
                    FileProblem::BadCertificate(CertError::NoIdentity.to_string()),
                )
            })?;
            let status = match (self.crl.get(cert.serial()), cert.validity_at(now)) {
                (Some(r), _) => CertStatus::Revoked(*r),
                (None, Validity::Valid) => CertStatus::Active,
                (None, Validity::Expired) => CertStatus::Expired,
                (None, Validity::NotYetValid) => CertStatus::NotYetValid,
            };
            out.push(CertEntry {
                identity,
                serial: cert.serial().to_owned(),
                not_before_ms: cert.not_before_ms(),
                not_after_ms: cert.not_after_ms(),
                status,
                path,
            });
        }
        // Station first, then by identity; a vehicle's history oldest first, the certificate
        // in use last (ties happen when a rotation falls in the same second).
        out.sort_by_key(|e| {
            (
                e.identity.role() != Role::Station,
                e.identity.clone(),
                e.not_before_ms,
                e.status == CertStatus::Active,
            )
        });
        Ok(out)
    }

    /// Writes what vehicle `vehicle_id` needs into `dest` (created 0700): CA and station
    /// certificates, the revocation list, and its own certificate, key and acoustic key.
    pub fn export_vehicle(&self, vehicle_id: &str, dest: &Path) -> Result<(), StoreError> {
        let cert_path = self.active_cert_path(vehicle_id)?;
        let vdir = self.vehicle_dir(vehicle_id);
        files::create_private_dir(dest)?;
        let copy_public = |from: &Path, name: &str| -> Result<(), StoreError> {
            let text = files::read_public(from)?;
            files::write_public(&dest.join(name), text.as_bytes())?;
            Ok(())
        };
        let copy_secret = |from: &Path, name: &str| -> Result<(), StoreError> {
            let text = files::read_secret(from)?;
            files::write_secret(&dest.join(name), text.as_bytes())?;
            Ok(())
        };
        copy_public(&self.path(CA_CERT), CA_CERT)?;
        copy_public(&self.path(STATION_CERT), STATION_CERT)?;
        copy_public(&self.path(CRL_FILE), CRL_FILE)?;
        copy_public(&cert_path, VEHICLE_CERT)?;
        copy_secret(&vdir.join(VEHICLE_KEY), VEHICLE_KEY)?;
        copy_secret(&vdir.join(ACOUSTIC_KEY), ACOUSTIC_KEY)?;
        Ok(())
    }
}

fn remove_if_present(path: &Path) -> Result<(), StoreError> {
    match fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(FileError::new(path, FileProblem::Unwritable(e)).into()),
    }
}

/// What a vehicle carries: trust in the station CA, its own identity and acoustic key.
#[derive(Debug)]
pub struct VehicleBundle {
    /// The station CA.
    pub anchor: TrustAnchor,
    /// The station's certificate.
    pub station: Certificate,
    /// The revocation list at export time.
    pub revocations: RevocationList,
    /// The vehicle's certificate (its private key, next to it, is checked to match).
    pub certificate: Certificate,
    /// The vehicle's acoustic key.
    pub acoustic_key: AcousticKey,
}

impl VehicleBundle {
    /// Loads a bundle written by [`KeyStore::export_vehicle`], checking every file.
    pub fn load(dir: &Path, now_ms: i64) -> Result<Self, StoreError> {
        files::check_dir(dir)?;
        let anchor = TrustAnchor::load(&dir.join(CA_CERT), now_ms)?;
        let revocations = RevocationList::load(&dir.join(CRL_FILE), &anchor)?;
        let station_path = dir.join(STATION_CERT);
        let station = Certificate::load(&station_path)?;
        anchor.verify_issued(&station).map_err(|e| {
            FileError::new(&station_path, FileProblem::BadCertificate(e.to_string()))
        })?;
        let cert_path = dir.join(VEHICLE_CERT);
        let certificate = Certificate::load(&cert_path)?;
        let key_path = dir.join(VEHICLE_KEY);
        if !certificate.matches_key(&PrivateKey::load(&key_path)?) {
            return Err(FileError::new(&key_path, FileProblem::KeyMismatch(cert_path)).into());
        }
        anchor
            .verify_issued(&certificate)
            .map_err(|_| FileError::new(&cert_path, FileProblem::BadSignature))?;
        certificate.check_dates(&cert_path, now_ms)?;
        if revocations.is_revoked(certificate.serial()) {
            return Err(FileError::new(
                &cert_path,
                FileProblem::Invalid(format!("certificate {} is revoked", certificate.serial())),
            )
            .into());
        }
        let acoustic_key = AcousticKey::load(&dir.join(ACOUSTIC_KEY))?;
        Ok(Self {
            anchor,
            station,
            revocations,
            certificate,
            acoustic_key,
        })
    }
}

#[cfg(test)]
mod tests {
    use std::os::unix::fs::PermissionsExt;

    use super::*;

    const T0: i64 = 1_780_000_000_000;

    fn mode(p: &Path) -> u32 {
        fs::metadata(p).unwrap().permissions().mode() & 0o777
    }

    fn new_store() -> (tempfile::TempDir, KeyStore) {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("keys");
        let store = KeyStore::init_with(&dir, "ccs", &StoreOptions::default(), Some(T0)).unwrap();
        (tmp, store)
    }

    #[test]
    fn secrets_are_0600_and_the_directory_0700() {
        let (_tmp, mut store) = new_store();
        store.issue_vehicle("auv-1").unwrap();
        let d = store.dir().to_owned();
        assert_eq!(mode(&d), 0o700);
        for secret in [
            d.join(CA_KEY),
            d.join(STATION_KEY),
            d.join("vehicles/auv-1").join(VEHICLE_KEY),
            d.join("vehicles/auv-1").join(ACOUSTIC_KEY),
        ] {
            assert_eq!(mode(&secret), 0o600, "{}", secret.display());
        }
        assert_eq!(mode(&d.join("vehicles/auv-1")), 0o700);
        for public in [d.join(CA_CERT), d.join(STATION_CERT), d.join(CRL_FILE)] {
            assert_eq!(mode(&public), 0o644, "{}", public.display());
        }
        KeyStore::open_at(&d, T0).unwrap();
    }

    #[test]
    fn a_group_readable_key_is_refused_naming_the_file() {
        let (_tmp, store) = new_store();
        let key = store.dir().join(CA_KEY);
        fs::set_permissions(&key, fs::Permissions::from_mode(0o644)).unwrap();
        let msg = KeyStore::open_at(store.dir(), T0).unwrap_err().to_string();
        assert!(msg.starts_with(&key.display().to_string()), "{msg}");
        assert!(msg.contains("0644") && msg.contains("chmod 600"), "{msg}");
    }

    #[test]
    fn load_errors_name_the_file_and_the_problem() {
        let (_tmp, store) = new_store();
        let d = store.dir().to_owned();

        let err = KeyStore::open_at(&d.join("nowhere"), T0)
            .unwrap_err()
            .to_string();
        assert_eq!(err, format!("{}: missing", d.join("nowhere").display()));

        fs::write(d.join(CA_CERT), "hello").unwrap();
        let err = KeyStore::open_at(&d, T0).unwrap_err().to_string();
        assert!(
            err.starts_with(&format!("{}: not PEM", d.join(CA_CERT).display())),
            "{err}"
        );

        // A key where the certificate should be.
        let key_pem = fs::read_to_string(d.join(STATION_KEY)).unwrap();
        fs::write(d.join(CA_CERT), &key_pem).unwrap();
        let err = KeyStore::open_at(&d, T0).unwrap_err().to_string();
        assert!(
            err.contains("labelled \"PRIVATE KEY\", expected \"CERTIFICATE\""),
            "{err}"
        );

        // The station certificate where the CA should be.
        fs::copy(d.join(STATION_CERT), d.join(CA_CERT)).unwrap();
        let err = KeyStore::open_at(&d, T0).unwrap_err().to_string();
        assert!(err.contains("not a CA certificate"), "{err}");
    }

    #[test]
    fn a_bad_settings_file_names_the_line() {
        let (_tmp, store) = new_store();
        let path = store.dir().join(STORE_FILE);
        let text = fs::read_to_string(&path).unwrap();
        fs::write(&path, text.replace("station = ", "colour = 1\nstation = ")).unwrap();
        let err = KeyStore::open_at(store.dir(), T0).unwrap_err().to_string();
        assert!(
            err.starts_with(&format!("{}: line 3:", path.display())),
            "{err}"
        );
        assert!(err.contains("unknown field `colour`"), "{err}");
    }

    #[test]
    fn an_expired_ca_is_refused_with_its_date() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("keys");
        let options = StoreOptions {
            ca_validity_days: 2,
            ..StoreOptions::default()
        };
        KeyStore::init_with(&dir, "ccs", &options, Some(T0)).unwrap();
        KeyStore::open_at(&dir, T0 + DAY_MS).unwrap();
        let err = KeyStore::open_at(&dir, T0 + 3 * DAY_MS)
            .unwrap_err()
            .to_string();
        assert!(
            err.starts_with(&format!(
                "{}: expired on 2026-",
                dir.join(CA_CERT).display()
            )),
            "{err}"
        );
    }

    #[test]
    fn a_tampered_revocation_list_is_refused() {
        let (_tmp, mut store) = new_store();
        store.issue_vehicle("auv-1").unwrap();
        store.revoke("auv-1", RevokeReason::KeyCompromise).unwrap();
        let path = store.dir().join(CRL_FILE);
        let mut der = pem::parse(fs::read_to_string(&path).unwrap())
            .unwrap()
            .into_contents();
        // Flip a bit inside the revoked serial number: an attacker un-revoking a vehicle.
        let at = der.len() / 3;
        der[at] ^= 0x01;
        fs::write(&path, pem::encode(&pem::Pem::new("X509 CRL", der))).unwrap();
        let err = KeyStore::open_at(store.dir(), T0).unwrap_err().to_string();
        assert!(err.starts_with(&path.display().to_string()), "{err}");
    }

    #[test]
    fn a_swapped_private_key_is_named() {
        let (tmp, mut store) = new_store();
        store.issue_vehicle("auv-1").unwrap();
        let bundle = tmp.path().join("auv-1");
        store.export_vehicle("auv-1", &bundle).unwrap();
        fs::copy(store.dir().join(STATION_KEY), bundle.join(VEHICLE_KEY)).unwrap();
        let err = VehicleBundle::load(&bundle, T0).unwrap_err().to_string();
        assert!(err.contains("does not match the certificate"), "{err}");
        assert!(
            err.starts_with(&bundle.join(VEHICLE_KEY).display().to_string()),
            "{err}"
        );
    }

    #[test]
    fn vehicle_certificates_name_the_vehicle() {
        let (_tmp, mut store) = new_store();
        let issued = store.issue_vehicle("auv-1").unwrap();
        let cert = &issued.certificate;
        assert_eq!(cert.common_name(), "auv-1");
        assert_eq!(cert.identity().unwrap().uri(), "urn:shoal:vehicle:auv-1");
        store.trust_anchor().verify_issued(cert).unwrap();
        assert!(cert.not_after_ms() <= T0 + 365 * DAY_MS);
        assert_eq!(
            store.acoustic_key("auv-1").unwrap().fingerprint(),
            issued.acoustic_key_fingerprint
        );
        assert!(matches!(
            store.issue_vehicle("auv-1"),
            Err(StoreError::VehicleExists(_))
        ));
        assert!(matches!(
            store.issue_vehicle("../x"),
            Err(StoreError::BadName(_))
        ));
        assert!(matches!(
            store.acoustic_key("auv-9"),
            Err(StoreError::UnknownVehicle { .. })
        ));
        assert_eq!(store.vehicles().unwrap(), vec!["auv-1".to_owned()]);
        assert!(matches!(
            KeyStore::init(store.dir(), "ccs"),
            Err(StoreError::AlreadyInitialised(_))
        ));
    }

    #[test]
    fn revocation_takes_effect_and_survives_reopening() {
        let (_tmp, mut store) = new_store();
        store.issue_vehicle("auv-1").unwrap();
        let cert = store.vehicle_certificate("auv-1").unwrap();

        let serial = store.revoke("auv-1", RevokeReason::KeyCompromise).unwrap();
        assert_eq!(serial, cert.serial());
        assert!(store.revocations().is_revoked(&serial));
        assert!(store.vehicles().unwrap().is_empty());
        assert!(!store.dir().join("vehicles/auv-1/vehicle.key").exists());
        assert!(matches!(
            store.vehicle_certificate("auv-1"),
            Err(StoreError::UnknownVehicle { .. })
        ));

        let reopened = KeyStore::open_at(store.dir(), T0).unwrap();
        assert!(reopened.revocations().is_revoked(&serial));
        let list = reopened.list().unwrap();
        let entry = list.iter().find(|e| e.serial == serial).unwrap();
        assert!(matches!(
            entry.status,
            CertStatus::Revoked(Revoked {
                reason: RevokeReason::KeyCompromise,
                ..
            })
        ));
        // The vehicle can be enrolled again with a fresh certificate.
        let again = store.issue_vehicle("auv-1").unwrap();
        assert_ne!(again.certificate.serial(), serial);
    }

    #[test]
    fn rotation_replaces_every_key_and_revokes_the_old_certificate() {
        let (_tmp, mut store) = new_store();
        let first = store.issue_vehicle("auv-1").unwrap();
        let second = store.rotate("auv-1").unwrap();
        assert_ne!(first.certificate.serial(), second.certificate.serial());
        assert_ne!(
            first.acoustic_key_fingerprint,
            second.acoustic_key_fingerprint
        );
        assert_ne!(
            first.certificate.public_key(),
            second.certificate.public_key()
        );
        let crl = store.revocations();
        assert_eq!(
            crl.get(first.certificate.serial()).unwrap().reason,
            RevokeReason::Superseded
        );
        assert!(!crl.is_revoked(second.certificate.serial()));
        assert_eq!(
            store.vehicle_certificate("auv-1").unwrap().serial(),
            second.certificate.serial()
        );

        let statuses: Vec<_> = store
            .list()
            .unwrap()
            .into_iter()
            .map(|e| {
                (
                    e.identity.to_string(),
                    matches!(e.status, CertStatus::Active),
                )
            })
            .collect();
        assert_eq!(
            statuses,
            vec![
                ("station:ccs".to_owned(), true),
                ("vehicle:auv-1".to_owned(), false),
                ("vehicle:auv-1".to_owned(), true),
            ]
        );
        assert!(matches!(
            store.rotate("auv-2"),
            Err(StoreError::UnknownVehicle { .. })
        ));
    }

    #[test]
    fn an_exported_bundle_loads_on_the_vehicle() {
        let (tmp, mut store) = new_store();
        store.issue_vehicle("auv-1").unwrap();
        let bundle_dir = tmp.path().join("auv-1");
        store.export_vehicle("auv-1", &bundle_dir).unwrap();
        assert_eq!(mode(&bundle_dir.join(VEHICLE_KEY)), 0o600);
        assert_eq!(mode(&bundle_dir.join(ACOUSTIC_KEY)), 0o600);
        let bundle = VehicleBundle::load(&bundle_dir, T0).unwrap();
        assert_eq!(bundle.certificate.identity().unwrap().name(), "auv-1");
        assert_eq!(bundle.station.identity().unwrap().name(), "ccs");
        assert_eq!(
            bundle.acoustic_key.fingerprint(),
            store.acoustic_key("auv-1").unwrap().fingerprint()
        );

        // A bundle whose certificate was revoked since refuses to load once the new list
        // reaches it.
        store
            .revoke("auv-1", RevokeReason::CessationOfOperation)
            .unwrap();
        fs::copy(store.dir().join(CRL_FILE), bundle_dir.join(CRL_FILE)).unwrap();
        let err = VehicleBundle::load(&bundle_dir, T0)
            .unwrap_err()
            .to_string();
        assert!(err.contains("is revoked"), "{err}");
    }

    #[test]
    fn a_stale_revocation_list_is_re_signed_on_open() {
        let (_tmp, store) = new_store();
        let first = store.revocations().number();
        let later = T0 + 40 * DAY_MS;
        let reopened = KeyStore::open_at(store.dir(), later).unwrap();
        assert_eq!(reopened.revocations().number(), first + 1);
        assert!(reopened.revocations().next_update_ms() > later);
    }

    #[test]
    fn a_site_certificate_comes_with_the_ca_to_trust() {
        let (dir, store) = new_store();
        let dest = dir.path().join("federation");
        let names = [SiteName::parse("127.0.0.1").unwrap()];
        let cert = store.issue_site("ship-1", &names, &dest).unwrap();
        assert_eq!(cert.common_name(), "ship-1");
        assert_eq!(mode(&dest.join("ship-1.key")), 0o600);
        let key = PrivateKey::load(&dest.join("ship-1.key")).unwrap();
        assert!(cert.matches_key(&key));
        let ca = Certificate::load(&dest.join("ship-1-ca.crt")).unwrap();
        assert_eq!(ca.der(), store.trust_anchor().certificate().der());
        assert!(cert.is_signed_by(ca.public_key()));
        assert!(matches!(
            store.issue_site("ship/1", &names, &dest),
            Err(StoreError::BadSite(_))
        ));
        assert!(matches!(
            store.issue_site("ship-1", &[], &dest),
            Err(StoreError::BadSite(_))
        ));
    }
}
