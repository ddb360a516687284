//! `shoal keys` (the station's key store) and the credentials the daemons load when
//! `[security]` is on.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use std::collections::HashSet;

use anyhow::{Context, Result, bail};
use shoal_dds::{Credentials, PubSub};
use shoal_security::dds::{DdsKeystore, Enclave, Grant, KeystoreOptions, names as dds_names};
use shoal_security::store::CertStatus;
use shoal_security::{KeyStore, RevokeReason, SiteName};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::config::SecurityConfig;

/// `shoal keys ...`.
#[derive(Debug, clap::Args)]
pub struct KeysArgs {
    /// The key store directory (default: security.store).
    #[arg(long, value_name = "DIR", global = true)]
    dir: Option<PathBuf>,
    #[command(subcommand)]
    command: KeysCommand,
}

/// What to do with the key store.
#[derive(Debug, clap::Subcommand)]
enum KeysCommand {
    /// Create the store: a station CA (Ed25519, 10 years), the station's certificate
    /// (1 year) and an empty revocation list.
    Init {
        /// The station's name in its certificate.
        #[arg(long, default_value = "ccs")]
        station: String,
    },
    /// Issue a certificate and an acoustic key to each vehicle named.
    Issue {
        /// Vehicle ids.
        #[arg(required = true)]
        vehicles: Vec<String>,
    },
    /// List every certificate with its standing (active, expired, revoked).
    List,
    /// Revoke a vehicle's certificate (a running station picks it up within
    /// security.crl_check_s) and delete its keys from the store.
    Revoke {
        /// Vehicle id.
        vehicle: String,
        /// Why (recorded in the revocation list).
        #[arg(long, value_enum, default_value = "unspecified")]
        reason: Reason,
    },
    /// Replace a vehicle's certificate and acoustic key; the old certificate is revoked.
    Rotate {
        /// Vehicle id.
        vehicle: String,
    },
    /// Write what a vehicle needs into DEST (0700): CA and station certificates, the
    /// revocation list, its certificate, key and acoustic key. Point the vehicle's
    /// security.bundle at it.
    Export {
        /// Vehicle id.
        vehicle: String,
        /// Destination directory (created).
        dest: PathBuf,
    },
    /// Renew the station's certificates, its DDS Security identity included (the old ones
    /// are revoked as superseded); restart the station afterwards.
    RenewStation,
    /// Issue this site's federation certificate ([federation.tls]) from the station CA:
    /// common name SITE (what remote sites' access control knows it by), valid for each
    /// --name (the host in the tls/<host>:<port> endpoints other sites connect to). Writes
    /// DIR/SITE.key (0600), DIR/SITE.crt and DIR/SITE-ca.crt, the CA certificate to send
    /// to the remote sites for their tls.trusted_cas.
    SiteCert {
        /// This site's name ([federation] site).
        site: String,
        /// A DNS name or IP address this site listens on; repeat for several. A site that
        /// only connects still needs one (its certificate's name is not checked then).
        #[arg(long = "name", value_name = "HOST", required = true)]
        names: Vec<String>,
        /// Destination directory (created 0700 if missing); default: <store>/federation.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// Sign the governance again from [security.governance] (which topics are encrypted,
    /// signed or open) and copy it into every enclave; export each vehicle's bundle again
    /// and restart every participant: all must hold the same governance.
    Governance,
}

/// RFC 5280 revocation reasons.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum Reason {
    Unspecified,
    KeyCompromise,
    Superseded,
    CessationOfOperation,
}

impl From<Reason> for RevokeReason {
    fn from(r: Reason) -> Self {
        match r {
            Reason::Unspecified => Self::Unspecified,
            Reason::KeyCompromise => Self::KeyCompromise,
            Reason::Superseded => Self::Superseded,
            Reason::CessationOfOperation => Self::CessationOfOperation,
        }
    }
}

/// The UTC calendar date of a time in ms since the Unix epoch, e.g. `2026-11-21`.
pub(crate) fn utc_date(ms: i64) -> String {
    match time::OffsetDateTime::from_unix_timestamp(ms.div_euclid(1000)) {
        Ok(t) => format!("{:04}-{:02}-{:02}", t.year(), u8::from(t.month()), t.day()),
        Err(_) => "(date out of range)".to_string(),
    }
}

use utc_date as date;

/// Runs `shoal keys ...`; prints what it did on standard output.
pub fn run(args: KeysArgs, cfg: &SecurityConfig) -> Result<()> {
    let dir = args.dir.unwrap_or_else(|| cfg.store.clone());
    let open = || KeyStore::open(&dir).context("cannot open the key store");
    let open_dds = || {
        DdsKeystore::open(&dds_dir(&dir), keystore_options(cfg))
            .context("cannot open the DDS Security keystore (shoal keys init makes it)")
    };
    match args.command {
        KeysCommand::Init { station } => {
            let store = KeyStore::init(&dir, &station).context("cannot create the key store")?;
            let dds = DdsKeystore::create(&dds_dir(&dir), keystore_options(cfg), now_s())
                .context("cannot create the DDS Security keystore")?;
            dds.issue(&Grant::Station, now_s())
                .context("cannot issue the station's identity")?;
            println!(
                "key store created in {} for station {:?}; CA valid until {}",
                dir.display(),
                station,
                date(store.trust_anchor().certificate().not_after_ms())
            );
            println!(
                "DDS Security keystore (identity CA, permissions CA, governance, the station's enclave) in {}",
                dds_dir(&dir).display()
            );
            println!("next: shoal keys issue <vehicle-id>...");
        }
        KeysCommand::Issue { vehicles } => {
            let mut store = open()?;
            let dds = open_dds()?;
            for v in vehicles {
                let enclave = dds
                    .issue(&Grant::Vehicle(v.clone()), now_s())
                    .with_context(|| format!("cannot issue {v:?}'s DDS Security identity"))?;
                let info = enclave
                    .check(now_s())
                    .with_context(|| format!("{v:?}'s new enclave"))?;
                println!(
                    "{v}: DDS Security identity {} (serial {}) until {}, enclave {}",
                    info.common_name,
                    info.serial,
                    info.not_after,
                    enclave.dir().display()
                );
                let issued = store
                    .issue_vehicle(&v)
                    .with_context(|| format!("cannot issue a certificate to {v:?}"))?;
                println!(
                    "{}: certificate {} valid until {}, acoustic key {}",
                    issued.identity,
                    issued.certificate.serial(),
                    date(issued.certificate.not_after_ms()),
                    issued.acoustic_key_fingerprint
                );
            }
        }
        KeysCommand::List => {
            let store = open()?;
            println!(
                "{:<24} {:<34} {:<10} {:<10} STATUS",
                "IDENTITY", "SERIAL", "FROM", "UNTIL"
            );
            for e in store.list().context("cannot list the key store")? {
                let status = match e.status {
                    CertStatus::Active => "active".to_string(),
                    CertStatus::Expired => "expired".to_string(),
                    CertStatus::NotYetValid => "not yet valid".to_string(),
                    CertStatus::Revoked(r) => {
                        format!("revoked {} ({})", date(r.revoked_ms), r.reason.as_str())
                    }
                };
                println!(
                    "{:<24} {:<34} {:<10} {:<10} {status}",
                    e.identity.to_string(),
                    e.serial,
                    date(e.not_before_ms),
                    date(e.not_after_ms)
                );
            }
        }
        KeysCommand::Revoke { vehicle, reason } => {
            let mut store = open()?;
            let dds = open_dds()?;
            let revoked = dds
                .revoke(&Grant::Vehicle(vehicle.clone()), now_s())
                .with_context(|| format!("cannot revoke {vehicle:?}'s DDS Security identity"))?;
            println!(
                "revoked {vehicle}'s DDS Security certificate {} (a running station refuses it within security.crl_check_s; participants that start later refuse its handshake)",
                revoked.serial
            );
            let serial = store
                .revoke(&vehicle, reason.into())
                .with_context(|| format!("cannot revoke {vehicle:?}"))?;
            println!("revoked {vehicle}'s certificate {serial}; its keys are deleted");
        }
        KeysCommand::Rotate { vehicle } => {
            let mut store = open()?;
            let dds = open_dds()?;
            let enclave = dds
                .rotate(&Grant::Vehicle(vehicle.clone()), now_s())
                .with_context(|| format!("cannot rotate {vehicle:?}'s DDS Security identity"))?;
            println!(
                "{vehicle}: new DDS Security identity in {}",
                enclave.dir().display()
            );
            let issued = store
                .rotate(&vehicle)
                .with_context(|| format!("cannot rotate {vehicle:?}"))?;
            println!(
                "{}: new certificate {}, new acoustic key {}; export it to the vehicle again",
                issued.identity,
                issued.certificate.serial(),
                issued.acoustic_key_fingerprint
            );
        }
        KeysCommand::Export { vehicle, dest } => {
            let store = open()?;
            export(&store, &open_dds()?, &vehicle, &dest)?;
            println!(
                "{vehicle}'s bundle written to {} (keep it on the vehicle only)",
                dest.display()
            );
        }
        KeysCommand::SiteCert { site, names, out } => {
            let store = open()?;
            let names = names
                .iter()
                .map(|n| SiteName::parse(n).map_err(anyhow::Error::msg))
                .collect::<Result<Vec<_>>>()
                .context("--name")?;
            let dest = out.unwrap_or_else(|| dir.join("federation"));
            let cert = store
                .issue_site(&site, &names, &dest)
                .with_context(|| format!("cannot issue site {site:?}'s certificate"))?;
            println!(
                "site {site}: certificate {} valid until {}",
                cert.serial(),
                date(cert.not_after_ms())
            );
            let file = |suffix: &str| dest.join(format!("{site}{suffix}")).display().to_string();
            println!(
                "[federation.tls] certificate = {:?}, private_key = {:?}",
                file(".crt"),
                file(".key")
            );
            println!(
                "send {} to the remote sites (their tls.trusted_cas); put theirs in yours",
                file("-ca.crt")
            );
        }
        KeysCommand::Governance => {
            let dds = open_dds()?;
            dds.sign_governance()
                .context("cannot sign the governance document")?;
            let n = dds
                .refresh_enclaves()
                .context("cannot copy the governance into the enclaves")?;
            println!(
                "governance signed ({}) and copied into {n} enclaves; export every vehicle's bundle again (shoal keys export) and restart the station and every vehicle",
                cfg.governance
            );
        }
        KeysCommand::RenewStation => {
            let mut store = open()?;
            let dds = open_dds()?;
            let enclave = dds
                .rotate(&Grant::Station, now_s())
                .context("cannot renew the station's DDS Security identity")?;
            println!(
                "station DDS Security identity renewed in {} (the old certificate is revoked as superseded)",
                enclave.dir().display()
            );
            let cert = store
                .renew_station()
                .context("cannot renew the station certificate")?;
            println!(
                "station certificate {} valid until {}; restart the station",
                cert.serial(),
                date(cert.not_after_ms())
            );
        }
    }
    Ok(())
}

fn now_s() -> i64 {
    shoal_model::now_ms().div_euclid(1000)
}

/// The directory of the DDS Security keystore inside a key store.
pub fn dds_dir(store: &Path) -> PathBuf {
    store.join("dds")
}

/// The DDS keystore's options from `[security]`: the governance it signs.
pub(crate) fn keystore_options(cfg: &SecurityConfig) -> KeystoreOptions {
    KeystoreOptions {
        governance: cfg.governance.clone(),
        ..KeystoreOptions::default()
    }
}

/// The key store at `cfg.store`, created on first run (the acoustic keys' store and the
/// DDS Security keystore with the station's enclave); an older store without the DDS
/// keystore gets one.
pub fn open_or_create_store(cfg: &SecurityConfig) -> Result<(KeyStore, DdsKeystore)> {
    let store = if cfg.store.join(shoal_security::store::STORE_FILE).exists() {
        KeyStore::open(&cfg.store).with_context(|| {
            format!(
                "security: the key store {} cannot be used",
                cfg.store.display()
            )
        })?
    } else {
        info!(dir = %cfg.store.display(), "creating the key store (first run; shoal keys init)");
        KeyStore::init(&cfg.store, "ccs").with_context(|| {
            format!(
                "security: cannot create the key store in {}",
                cfg.store.display()
            )
        })?
    };
    let dir = dds_dir(&cfg.store);
    let dds = DdsKeystore::open_or_create(&dir, keystore_options(cfg), now_s())
        .with_context(|| format!("security: the DDS Security keystore {}", dir.display()))?;
    dds.issue_if_missing(&Grant::Station, now_s())
        .context("security: cannot issue the station's identity")?;
    Ok((store, dds))
}

/// The station's DDS Security credentials (the key store is created on first run).
pub fn station(cfg: &SecurityConfig) -> Result<Credentials> {
    let (_, dds) = open_or_create_store(cfg)?;
    let enclave = dds
        .enclave(&Grant::Station)
        .context("security: the station's enclave")?;
    Ok(Credentials::station(enclave))
}

/// A vehicle's DDS Security credentials: from its bundle (`security.bundle`, written by
/// `shoal keys export`), or, on the station's host, from the key store (issued on first
/// use).
pub fn vehicle(cfg: &SecurityConfig, vehicle_id: &str) -> Result<Credentials> {
    if !cfg.bundle.as_os_str().is_empty() {
        let dir = dds_dir(&cfg.bundle);
        if !dir.join(dds_names::CERT).exists() {
            bail!(
                "security.bundle {} holds no DDS Security credentials ({} is missing): on the station run `shoal keys export {vehicle_id} DIR` again",
                cfg.bundle.display(),
                dir.join(dds_names::CERT).display()
            );
        }
        let enclave = Enclave::new(&dir, Some(dir.join(dds_names::CRL)));
        let info = enclave
            .check(now_s())
            .with_context(|| format!("security.bundle {} cannot be used", cfg.bundle.display()))?;
        let expected = Grant::Vehicle(vehicle_id.to_string()).enclave_name();
        if info.common_name != expected {
            bail!(
                "security.bundle {} holds the identity {:?}, not vehicle {vehicle_id:?}'s ({expected:?})",
                cfg.bundle.display(),
                info.common_name
            );
        }
        return Ok(Credentials::vehicle(enclave, vehicle_id));
    }
    let dir = dds_dir(&cfg.store);
    if !dir.join("private").exists() {
        bail!(
            "security is on but vehicle {vehicle_id:?} has no credentials: on the station run `shoal keys export {vehicle_id} DIR` and point security.bundle (or SHOAL_SECURITY__BUNDLE) at DIR, or start it with --insecure for lab work"
        );
    }
    let dds = DdsKeystore::open(&dir, keystore_options(cfg))
        .with_context(|| format!("security: the DDS Security keystore {}", dir.display()))?;
    let enclave = dds
        .issue_if_missing(&Grant::Vehicle(vehicle_id.to_string()), now_s())
        .with_context(|| format!("security: cannot issue {vehicle_id:?}'s identity"))?;
    Ok(Credentials::vehicle(enclave, vehicle_id))
}

/// For `shoal up`: the key store (created if missing), credentials and an acoustic key for
/// each vehicle that has none, and a fresh bundle per vehicle next to the store. Returns
/// each vehicle's bundle directory.
#[cfg(feature = "console")]
pub fn prepare_fleet(
    cfg: &SecurityConfig,
    vehicle_ids: &[&str],
) -> Result<std::collections::HashMap<String, PathBuf>> {
    let (mut store, dds) = open_or_create_store(cfg)?;
    let known = store.vehicles().context("cannot list the key store")?;
    let bundles_dir = cfg
        .store
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .join("bundles");
    let mut out = std::collections::HashMap::new();
    for id in vehicle_ids {
        if !known.iter().any(|k| k == id) {
            store
                .issue_vehicle(id)
                .with_context(|| format!("cannot issue an acoustic key to {id:?}"))?;
        }
        dds.issue_if_missing(&Grant::Vehicle((*id).to_string()), now_s())
            .with_context(|| format!("cannot issue {id:?}'s identity"))?;
        let dest = bundles_dir.join(id);
        export(&store, &dds, id, &dest)?;
        out.insert((*id).to_string(), dest);
    }
    Ok(out)
}

/// Writes what vehicle `id` loads into `dest`: its acoustic key and CA files, and its DDS
/// Security enclave with the revocation list under `dest/dds`.
fn export(store: &KeyStore, dds: &DdsKeystore, id: &str, dest: &Path) -> Result<()> {
    store
        .export_vehicle(id, dest)
        .with_context(|| format!("cannot export {id:?}'s bundle"))?;
    let enclave = dds
        .enclave(&Grant::Vehicle(id.to_string()))
        .with_context(|| format!("cannot export {id:?}'s DDS Security enclave"))?;
    let to = dds_dir(dest);
    std::fs::create_dir_all(&to).with_context(|| format!("cannot create {}", to.display()))?;
    for name in [
        dds_names::CERT,
        dds_names::KEY,
        dds_names::IDENTITY_CA,
        dds_names::PERMISSIONS_CA,
        dds_names::GOVERNANCE,
        dds_names::PERMISSIONS,
        dds_names::PERMISSIONS_XML,
    ] {
        copy_file(&enclave.file(name), &to.join(name), name == dds_names::KEY)?;
    }
    copy_file(&dds.crl_path(), &to.join(dds_names::CRL), false)?;
    Ok(())
}

fn copy_file(from: &Path, to: &Path, secret: bool) -> Result<()> {
    let bytes = std::fs::read(from).with_context(|| format!("cannot read {}", from.display()))?;
    let written = if secret {
        shoal_security::files::write_secret(to, &bytes)
    } else {
        shoal_security::files::write_public(to, &bytes)
    };
    written.with_context(|| format!("cannot write {}", to.display()))
}

/// The acoustic keys of `vehicle_ids` from the station's key store (the CDT runs at the
/// station's side), with 64-bit tags.
pub fn acoustic_keys(
    cfg: &SecurityConfig,
    vehicle_ids: &[&str],
) -> Result<shoal_converter::emulated_relay::AcousticKeys> {
    let store = KeyStore::open(&cfg.store).context("cannot open the key store")?;
    let mut keys = std::collections::HashMap::new();
    for id in vehicle_ids {
        let key = store
            .acoustic_key(id)
            .with_context(|| format!("no acoustic key for {id:?}: run `shoal keys issue {id}`"))?;
        keys.insert((*id).to_string(), key);
    }
    Ok(shoal_converter::emulated_relay::AcousticKeys {
        tag: shoal_security::TagSize::Bits64,
        keys,
    })
}

fn modified(path: &Path) -> Option<SystemTime> {
    std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// The vehicles whose DDS Security certificates the keystore lists as revoked.
fn revoked_vehicles(dds: &DdsKeystore) -> Result<HashSet<String>> {
    Ok(dds
        .revoked()?
        .into_iter()
        .filter_map(|r| {
            r.enclave
                .strip_prefix("/shoal/vehicle/")
                .map(str::to_string)
        })
        .collect())
}

/// Applies the keystore's revocations to a running station, and again whenever
/// `shoal keys revoke` changes them. DDS Security reads the revocation list only when a
/// participant starts, so the station itself refuses a revoked vehicle's samples (counted
/// as `security:revoked`) until both restart. A rotated vehicle's new certificate is not
/// refused: only vehicles whose enclave is gone are. An unreadable list is logged and
/// ignored (the previous one stays in force).
pub fn watch_revocations(
    pubsub: Arc<PubSub>,
    cfg: &SecurityConfig,
    every: Duration,
    shutdown: CancellationToken,
) {
    let dir = dds_dir(&cfg.store);
    let options = keystore_options(cfg);
    let apply = move |dds: &Arc<PubSub>| -> Result<usize> {
        let ks = DdsKeystore::open(&dir, options.clone())?;
        let active: HashSet<String> = ks
            .enclaves()?
            .into_iter()
            .filter_map(|g| g.vehicle_id().map(str::to_string))
            .collect();
        let revoked: HashSet<String> = revoked_vehicles(&ks)?
            .into_iter()
            .filter(|v| !active.contains(v))
            .collect();
        let n = revoked.len();
        dds.set_revoked_vehicles(revoked);
        Ok(n)
    };
    if let Err(e) = apply(&pubsub) {
        warn!(error = %format!("{e:#}"), "revocation list not applied");
    }
    let watched = dds_dir(&cfg.store).join(dds_names::REVOKED);
    tokio::spawn(async move {
        let mut seen = modified(&watched);
        loop {
            tokio::select! {
                () = shutdown.cancelled() => return,
                () = tokio::time::sleep(every) => {}
            }
            let now = modified(&watched);
            if now == seen {
                continue;
            }
            seen = now;
            match apply(&pubsub) {
                Ok(n) => info!(file = %watched.display(), revoked = n, "revocation list reloaded"),
                Err(e) => warn!(error = %format!("{e:#}"), "new revocation list ignored"),
            }
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_are_utc_calendar_days() {
        assert_eq!(date(0), "1970-01-01");
        assert_eq!(date(951_782_400_000), "2000-02-29");
        assert_eq!(date(1_795_219_200_000 - 1), "2026-11-20");
        assert_eq!(date(i64::MAX), "(date out of range)");
    }
}
