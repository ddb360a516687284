//! OMG DDS Security 1.1 credentials: the keystore `shoal keys` keeps for IP links, laid out
//! like an SROS2 keystore so a secure ROS 2 system and Shoal can share its CAs.
//!
//! ```text
//! <dir>/public/identity_ca.cert.pem       the CA that issues participants' identities
//! <dir>/public/permissions_ca.cert.pem    the CA that signs governance and permissions
//! <dir>/private/*.key.pem                 the two CAs' keys (0600)
//! <dir>/enclaves/governance.{xml,p7s}     the domain's governance, signed
//! <dir>/enclaves/shoal/station/           the station's enclave
//! <dir>/enclaves/shoal/vehicle/<id>/      one enclave per vehicle
//! <dir>/crl.pem, revoked.toml             the identity CA's revocation list and its source
//! ```
//!
//! Each enclave holds what a participant loads (the SROS2 file names): `cert.pem`,
//! `key.pem`, `identity_ca.cert.pem`, `permissions_ca.cert.pem`, `governance.p7s`,
//! `permissions.xml` and `permissions.p7s`. The plugins of Cyclone DDS, Fast DDS and RTI
//! Connext read these files directly; [`Enclave::check`] reads them first so that a bad
//! file is reported by name before a participant is created half-secured.

mod documents;
mod pki;

use std::fs;
use std::path::{Path, PathBuf};

use openssl::error::ErrorStack;
use openssl::pkey::{PKey, Private};
use openssl::x509::{X509, X509Crl};
use serde::{Deserialize, Serialize};

pub use documents::{
    GovernanceOptions, Grant, Protection, VEHICLE_PARTITION_PREFIX, VEHICLE_TOPICS, governance,
    permissions, vehicle_partition,
};

use crate::files::{self, FileError, FileProblem};
use crate::identity::Identity;

/// Organisation written in every subject.
const ORGANISATION: &str = "Shoal";

/// File names of an enclave and of the keystore, as SROS2 names them.
pub mod names {
    /// The participant's identity certificate.
    pub const CERT: &str = "cert.pem";
    /// The participant's private key.
    pub const KEY: &str = "key.pem";
    /// The identity CA certificate.
    pub const IDENTITY_CA: &str = "identity_ca.cert.pem";
    /// The permissions CA certificate.
    pub const PERMISSIONS_CA: &str = "permissions_ca.cert.pem";
    /// The signed governance document.
    pub const GOVERNANCE: &str = "governance.p7s";
    /// The permissions document, readable.
    pub const PERMISSIONS_XML: &str = "permissions.xml";
    /// The signed permissions document.
    pub const PERMISSIONS: &str = "permissions.p7s";
    /// The identity CA's key, under `private/`.
    pub const IDENTITY_CA_KEY: &str = "identity_ca.key.pem";
    /// The permissions CA's key, under `private/`.
    pub const PERMISSIONS_CA_KEY: &str = "permissions_ca.key.pem";
    /// The identity CA's revocation list.
    pub const CRL: &str = "crl.pem";
    /// What the revocation list is made from.
    pub const REVOKED: &str = "revoked.toml";
}

/// Why a keystore operation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DdsKeyError {
    /// A file is missing, unreadable, malformed, expired, not signed by the CA...
    #[error(transparent)]
    File(#[from] FileError),
    /// OpenSSL failed while making something.
    #[error("{what} failed: {source}")]
    Crypto {
        /// What was being made.
        what: &'static str,
        /// OpenSSL's errors.
        source: ErrorStack,
    },
    /// The keystore directory already holds CAs.
    #[error("{}: already holds a DDS Security keystore", .0.display())]
    Exists(PathBuf),
    /// The enclave already exists (rotate or revoke it instead).
    #[error("{0} already has an active certificate: rotate or revoke it instead")]
    EnclaveExists(String),
    /// No such enclave.
    #[error("{0} has no credentials in this keystore")]
    UnknownEnclave(String),
    /// A vehicle id that is not an identifier.
    #[error(transparent)]
    BadName(#[from] crate::identity::IdentityError),
}

fn crypto(what: &'static str) -> impl FnOnce(ErrorStack) -> DdsKeyError {
    move |source| DdsKeyError::Crypto { what, source }
}

/// How long what the keystore issues lasts, and how the governance protects topics.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct KeystoreOptions {
    /// Validity of the two CAs, days.
    pub ca_days: u32,
    /// Validity of identity certificates and permissions, days.
    pub cert_days: u32,
    /// Validity of each revocation list, days: participants refuse everyone once the list
    /// they load is past it, so `shoal keys` re-signs it on every change.
    pub crl_days: u32,
    /// Which topics are encrypted, signed or open.
    pub governance: GovernanceOptions,
}

impl Default for KeystoreOptions {
    fn default() -> Self {
        Self {
            ca_days: 3650,
            cert_days: 365,
            crl_days: 365,
            governance: GovernanceOptions::default(),
        }
    }
}

/// One revoked certificate.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Revoked {
    /// Its serial number, hex.
    pub serial: String,
    /// The enclave it was issued to.
    pub enclave: String,
    /// When it was revoked, Unix seconds.
    pub at_s: i64,
}

#[derive(Debug, Default, Serialize, Deserialize)]
struct RevokedFile {
    #[serde(default)]
    revoked: Vec<Revoked>,
}

/// The files one participant loads.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Enclave {
    dir: PathBuf,
    crl: Option<PathBuf>,
}

/// What [`Enclave::check`] read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EnclaveInfo {
    /// The certificate's common name (the enclave name).
    pub common_name: String,
    /// The certificate's serial number, hex.
    pub serial: String,
    /// The certificate's end of validity, as OpenSSL prints it.
    pub not_after: String,
}

fn read_cert(path: &Path) -> Result<X509, FileError> {
    let text = files::read_public(path)?;
    X509::from_pem(text.as_bytes())
        .map_err(|e| FileError::new(path, FileProblem::BadCertificate(e.to_string())))
}

fn read_key(path: &Path) -> Result<PKey<Private>, FileError> {
    let text = files::read_secret(path)?;
    PKey::private_key_from_pem(text.as_bytes())
        .map_err(|e| FileError::new(path, FileProblem::BadKey(e.to_string())))
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, FileError> {
    fs::read(path).map_err(|e| {
        let problem = if e.kind() == std::io::ErrorKind::NotFound {
            FileProblem::Missing
        } else {
            FileProblem::Unreadable(e)
        };
        FileError::new(path, problem)
    })
}

fn check_dates(path: &Path, cert: &X509, now_s: i64) -> Result<(), FileError> {
    let now = openssl::asn1::Asn1Time::from_unix(now_s)
        .map_err(|e| FileError::new(path, FileProblem::Invalid(e.to_string())))?;
    if cert.not_after() < now {
        return Err(FileError::new(
            path,
            FileProblem::Expired(cert.not_after().to_string()),
        ));
    }
    if cert.not_before() > now {
        return Err(FileError::new(
            path,
            FileProblem::NotYetValid(cert.not_before().to_string()),
        ));
    }
    Ok(())
}

impl Enclave {
    /// The enclave in `dir`, checked against the revocation list `crl` if given.
    pub fn new(dir: impl Into<PathBuf>, crl: Option<PathBuf>) -> Self {
        Self {
            dir: dir.into(),
            crl,
        }
    }

    /// The enclave's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// A file of the enclave by its name in [`names`].
    pub fn file(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// The identity CA's revocation list, if one is used.
    pub fn crl(&self) -> Option<&Path> {
        self.crl.as_deref()
    }

    /// Reads every file the plugins will read and checks what they will check (the
    /// certificate chains to the identity CA, is in its dates and not revoked; the key is
    /// the certificate's; both documents are signed by the permissions CA; the permissions
    /// name this certificate's subject). The first problem is returned naming its file.
    pub fn check(&self, now_s: i64) -> Result<EnclaveInfo, FileError> {
        let ca_path = self.file(names::IDENTITY_CA);
        let ca = read_cert(&ca_path)?;
        check_dates(&ca_path, &ca, now_s)?;
        let cert_path = self.file(names::CERT);
        let cert = read_cert(&cert_path)?;
        let ca_key = ca
            .public_key()
            .map_err(|e| FileError::new(&ca_path, FileProblem::BadCertificate(e.to_string())))?;
        if !cert.verify(&ca_key).unwrap_or(false) {
            return Err(FileError::new(
                &cert_path,
                FileProblem::Invalid(format!(
                    "not issued by the identity CA in {}",
                    ca_path.display()
                )),
            ));
        }
        check_dates(&cert_path, &cert, now_s)?;
        let serial = pki::serial_hex(&cert)
            .map_err(|e| FileError::new(&cert_path, FileProblem::BadCertificate(e.to_string())))?;
        if let Some(crl_path) = &self.crl {
            let crl = X509Crl::from_pem(&read_bytes(crl_path)?)
                .map_err(|e| FileError::new(crl_path, FileProblem::Invalid(e.to_string())))?;
            if !crl.verify(&ca_key).unwrap_or(false) {
                return Err(FileError::new(
                    crl_path,
                    FileProblem::Invalid("not signed by the identity CA".into()),
                ));
            }
            if let openssl::x509::CrlStatus::Revoked(_) = crl.get_by_cert(&cert) {
                return Err(FileError::new(
                    &cert_path,
                    FileProblem::Invalid(format!(
                        "revoked (serial {serial}, in {})",
                        crl_path.display()
                    )),
                ));
            }
        }
        let key_path = self.file(names::KEY);
        let key = read_key(&key_path)?;
        let cert_key = cert
            .public_key()
            .map_err(|e| FileError::new(&cert_path, FileProblem::BadCertificate(e.to_string())))?;
        if !key.public_eq(&cert_key) {
            return Err(FileError::new(
                &key_path,
                FileProblem::KeyMismatch(cert_path),
            ));
        }
        let pca_path = self.file(names::PERMISSIONS_CA);
        let pca = read_cert(&pca_path)?;
        check_dates(&pca_path, &pca, now_s)?;
        let unsigned = |path: &Path| {
            let p = path.to_path_buf();
            move |e: ErrorStack| {
                FileError::new(
                    p,
                    FileProblem::Invalid(format!(
                        "not an S/MIME document signed by the permissions CA ({e})"
                    )),
                )
            }
        };
        let gov_path = self.file(names::GOVERNANCE);
        pki::smime_verify(&pca, &read_bytes(&gov_path)?).map_err(unsigned(&gov_path))?;
        let perm_path = self.file(names::PERMISSIONS);
        let perms =
            pki::smime_verify(&pca, &read_bytes(&perm_path)?).map_err(unsigned(&perm_path))?;
        let common_name = pki::common_name_of(cert.subject_name()).ok_or_else(|| {
            FileError::new(
                &cert_path,
                FileProblem::BadCertificate("no common name".into()),
            )
        })?;
        let subject_text = pki::name_text(cert.subject_name()).unwrap_or_default();
        let subject = format!("<subject_name>{subject_text}</subject_name>");
        if !String::from_utf8_lossy(&perms).contains(&subject) {
            return Err(FileError::new(
                &perm_path,
                FileProblem::Invalid(format!(
                    "grants nothing to {subject_text} (the subject of {}); the certificate \
                     and the permissions were not issued together: issue them again \
                     (`shoal keys renew-station`, or `shoal keys rotate <vehicle>`)",
                    cert_path.display()
                )),
            ));
        }
        Ok(EnclaveInfo {
            common_name,
            serial,
            not_after: cert.not_after().to_string(),
        })
    }
}

/// The keystore: two CAs, the governance, and one enclave per participant.
#[derive(Debug)]
pub struct DdsKeystore {
    dir: PathBuf,
    options: KeystoreOptions,
}

impl DdsKeystore {
    /// Creates a keystore in `dir` (which must not hold one): both CAs and the signed
    /// governance document.
    pub fn create(dir: &Path, options: KeystoreOptions, now_s: i64) -> Result<Self, DdsKeyError> {
        if dir.join("public").join(names::IDENTITY_CA).exists() {
            return Err(DdsKeyError::Exists(dir.to_path_buf()));
        }
        files::create_private_dir(dir)?;
        files::create_private_dir(&dir.join("private"))?;
        files::create_private_dir(&dir.join("public"))?;
        files::create_private_dir(&dir.join("enclaves"))?;
        for (name, key_name, cn) in [
            (
                names::IDENTITY_CA,
                names::IDENTITY_CA_KEY,
                "Shoal identity CA",
            ),
            (
                names::PERMISSIONS_CA,
                names::PERMISSIONS_CA_KEY,
                "Shoal permissions CA",
            ),
        ] {
            let key = pki::new_key().map_err(crypto("generating a CA key"))?;
            let cert = pki::ca_certificate(&key, cn, now_s, options.ca_days)
                .map_err(crypto("issuing a CA certificate"))?;
            let pem = key
                .private_key_to_pem_pkcs8()
                .map_err(crypto("encoding a key"))?;
            files::write_secret(&dir.join("private").join(key_name), &pem)?;
            let pem = cert.to_pem().map_err(crypto("encoding a certificate"))?;
            files::write_public(&dir.join("public").join(name), &pem)?;
        }
        let store = Self {
            dir: dir.to_path_buf(),
            options,
        };
        store.sign_governance()?;
        store.write_crl(&[], now_s)?;
        Ok(store)
    }

    /// Opens the keystore in `dir`, with `options` for what it issues from now on.
    pub fn open(dir: &Path, options: KeystoreOptions) -> Result<Self, DdsKeyError> {
        read_cert(&dir.join("public").join(names::IDENTITY_CA))?;
        read_cert(&dir.join("public").join(names::PERMISSIONS_CA))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            options,
        })
    }

    /// Opens the keystore in `dir`, creating it first if it does not exist.
    pub fn open_or_create(
        dir: &Path,
        options: KeystoreOptions,
        now_s: i64,
    ) -> Result<Self, DdsKeyError> {
        if dir.join("public").join(names::IDENTITY_CA).exists() {
            Self::open(dir, options)
        } else {
            Self::create(dir, options, now_s)
        }
    }

    /// The keystore's directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The identity CA's revocation list.
    pub fn crl_path(&self) -> PathBuf {
        self.dir.join(names::CRL)
    }

    fn enclave_dir(&self, grant: &Grant) -> PathBuf {
        self.dir
            .join("enclaves")
            .join(grant.enclave_name().trim_start_matches('/'))
    }

    fn ca(&self, cert: &str, key: &str) -> Result<(X509, PKey<Private>), FileError> {
        Ok((
            read_cert(&self.dir.join("public").join(cert))?,
            read_key(&self.dir.join("private").join(key))?,
        ))
    }

    /// Writes the governance document, signed, from the options: after a change of
    /// [`GovernanceOptions`], call this and [`DdsKeystore::refresh_enclaves`].
    pub fn sign_governance(&self) -> Result<(), DdsKeyError> {
        let (pca, pca_key) = self.ca(names::PERMISSIONS_CA, names::PERMISSIONS_CA_KEY)?;
        let doc = governance(&self.options.governance);
        let signed = pki::smime_sign(&pca, &pca_key, doc.as_bytes())
            .map_err(crypto("signing governance"))?;
        let enclaves = self.dir.join("enclaves");
        files::write_public(&enclaves.join("governance.xml"), doc.as_bytes())?;
        files::write_public(&enclaves.join(names::GOVERNANCE), &signed)?;
        Ok(())
    }

    /// Copies the current governance and CA certificates into every enclave.
    pub fn refresh_enclaves(&self) -> Result<usize, DdsKeyError> {
        let mut n = 0;
        for grant in self.enclaves()? {
            self.copy_shared(&self.enclave_dir(&grant))?;
            n += 1;
        }
        Ok(n)
    }

    fn copy_shared(&self, dir: &Path) -> Result<(), DdsKeyError> {
        for (from, to) in [
            (
                self.dir.join("public").join(names::IDENTITY_CA),
                names::IDENTITY_CA,
            ),
            (
                self.dir.join("public").join(names::PERMISSIONS_CA),
                names::PERMISSIONS_CA,
            ),
            (
                self.dir.join("enclaves").join(names::GOVERNANCE),
                names::GOVERNANCE,
            ),
        ] {
            files::write_public(&dir.join(to), &read_bytes(&from)?)?;
        }
        Ok(())
    }

    /// Every enclave the keystore holds.
    pub fn enclaves(&self) -> Result<Vec<Grant>, DdsKeyError> {
        let mut out = Vec::new();
        if self
            .dir
            .join("enclaves/shoal/station")
            .join(names::CERT)
            .exists()
        {
            out.push(Grant::Station);
        }
        let vehicles = self.dir.join("enclaves/shoal/vehicle");
        if let Ok(entries) = fs::read_dir(&vehicles) {
            let mut ids: Vec<String> = entries
                .filter_map(Result::ok)
                .filter(|e| e.path().join(names::CERT).exists())
                .filter_map(|e| e.file_name().into_string().ok())
                .collect();
            ids.sort();
            out.extend(ids.into_iter().map(Grant::Vehicle));
        }
        Ok(out)
    }

    /// The enclave of `grant`, if it has been issued.
    pub fn enclave(&self, grant: &Grant) -> Result<Enclave, DdsKeyError> {
        let dir = self.enclave_dir(grant);
        if !dir.join(names::CERT).exists() {
            return Err(DdsKeyError::UnknownEnclave(grant.enclave_name()));
        }
        Ok(Enclave::new(dir, Some(self.crl_path())))
    }

    /// Issues `grant`'s enclave: a key, an identity certificate and signed permissions.
    pub fn issue(&self, grant: &Grant, now_s: i64) -> Result<Enclave, DdsKeyError> {
        if let Some(id) = grant.vehicle_id() {
            Identity::vehicle(id)?;
        }
        let dir = self.enclave_dir(grant);
        if dir.join(names::CERT).exists() {
            return Err(DdsKeyError::EnclaveExists(grant.enclave_name()));
        }
        self.write_enclave(grant, &dir, now_s)?;
        Ok(Enclave::new(dir, Some(self.crl_path())))
    }

    /// The enclave of `grant`, issuing it first if it does not exist.
    pub fn issue_if_missing(&self, grant: &Grant, now_s: i64) -> Result<Enclave, DdsKeyError> {
        match self.enclave(grant) {
            Ok(e) => Ok(e),
            Err(DdsKeyError::UnknownEnclave(_)) => self.issue(grant, now_s),
            Err(e) => Err(e),
        }
    }

    fn write_enclave(&self, grant: &Grant, dir: &Path, now_s: i64) -> Result<(), DdsKeyError> {
        let (ica, ica_key) = self.ca(names::IDENTITY_CA, names::IDENTITY_CA_KEY)?;
        let (pca, pca_key) = self.ca(names::PERMISSIONS_CA, names::PERMISSIONS_CA_KEY)?;
        let key = pki::new_key().map_err(crypto("generating a participant key"))?;
        let name = grant.enclave_name();
        let days = self.options.cert_days;
        let organisation = grant.organisation();
        let cert = pki::leaf_certificate(&ica, &ica_key, &key, (&name, &organisation), now_s, days)
            .map_err(crypto("issuing an identity certificate"))?;
        let doc = permissions(grant, now_s - 600, now_s + i64::from(days) * 86_400);
        let signed = pki::smime_sign(&pca, &pca_key, doc.as_bytes())
            .map_err(crypto("signing permissions"))?;
        files::create_private_dir(dir)?;
        let pem = key
            .private_key_to_pem_pkcs8()
            .map_err(crypto("encoding a key"))?;
        files::write_secret(&dir.join(names::KEY), &pem)?;
        let pem = cert.to_pem().map_err(crypto("encoding a certificate"))?;
        files::write_public(&dir.join(names::CERT), &pem)?;
        files::write_public(&dir.join(names::PERMISSIONS_XML), doc.as_bytes())?;
        files::write_public(&dir.join(names::PERMISSIONS), &signed)?;
        self.copy_shared(dir)
    }

    /// Revokes `grant`'s certificate: it goes on the revocation list, and its enclave is
    /// moved to `retired/`. Participants read the list when they start.
    pub fn revoke(&self, grant: &Grant, now_s: i64) -> Result<Revoked, DdsKeyError> {
        let enclave = self.enclave(grant)?;
        let cert = read_cert(&enclave.file(names::CERT))?;
        let serial = pki::serial_hex(&cert).map_err(crypto("reading a serial number"))?;
        let mut list = self.revoked()?;
        let entry = Revoked {
            serial,
            enclave: grant.enclave_name(),
            at_s: now_s,
        };
        list.push(entry.clone());
        self.write_crl(&list, now_s)?;
        let retired = self.dir.join("retired").join(format!(
            "{}-{}",
            grant
                .enclave_name()
                .trim_start_matches('/')
                .replace('/', "_"),
            entry.serial
        ));
        files::create_private_dir(retired.parent().unwrap_or(&self.dir))?;
        fs::rename(enclave.dir(), &retired)
            .map_err(|e| FileError::new(enclave.dir(), FileProblem::Unwritable(e)))?;
        Ok(entry)
    }

    /// Revokes `grant`'s certificate and issues a new enclave in its place.
    pub fn rotate(&self, grant: &Grant, now_s: i64) -> Result<Enclave, DdsKeyError> {
        self.revoke(grant, now_s)?;
        self.issue(grant, now_s)
    }

    /// The certificates revoked so far.
    pub fn revoked(&self) -> Result<Vec<Revoked>, DdsKeyError> {
        let path = self.dir.join(names::REVOKED);
        if !path.exists() {
            return Ok(Vec::new());
        }
        let text = files::read_public(&path)?;
        let file: RevokedFile = toml::from_str(&text)
            .map_err(|e| FileError::new(&path, FileProblem::Invalid(e.to_string())))?;
        Ok(file.revoked)
    }

    fn write_crl(&self, list: &[Revoked], now_s: i64) -> Result<(), DdsKeyError> {
        let (ica, ica_key) = self.ca(names::IDENTITY_CA, names::IDENTITY_CA_KEY)?;
        let serials: Vec<(String, i64)> = list.iter().map(|r| (r.serial.clone(), r.at_s)).collect();
        let crl = pki::crl(&ica, &ica_key, &serials, now_s, self.options.crl_days)
            .map_err(crypto("signing the revocation list"))?;
        let text = toml::to_string(&RevokedFile {
            revoked: list.to_vec(),
        })
        .map_err(|e| {
            FileError::new(
                self.dir.join(names::REVOKED),
                FileProblem::Invalid(e.to_string()),
            )
        })?;
        files::write_public(&self.dir.join(names::REVOKED), text.as_bytes())?;
        let pem = crl
            .to_pem()
            .map_err(crypto("encoding the revocation list"))?;
        files::write_public(&self.crl_path(), &pem)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests;
