//! `shoal keys` (the station's key store) and the credentials the daemons load when
//! `[security]` is on.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use anyhow::{Context, Result, bail};
use shoal_dds::{PubSub, Security};
use shoal_security::store::{CRL_FILE, CertStatus};
use shoal_security::{
    Gate, KeyStore, Policy, RevocationList, RevokeReason, TrustAnchor, VehicleBundle,
    VerifierConfig,
};
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
    /// Renew the station's certificate (the old one is revoked as superseded).
    RenewStation,
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
    match args.command {
        KeysCommand::Init { station } => {
            let store = KeyStore::init(&dir, &station).context("cannot create the key store")?;
            println!(
                "key store created in {} for station {:?}; CA valid until {}",
                dir.display(),
                station,
                date(store.trust_anchor().certificate().not_after_ms())
            );
            println!("next: shoal keys issue <vehicle-id>...; set [security] enabled = true");
        }
        KeysCommand::Issue { vehicles } => {
            let mut store = open()?;
            for v in vehicles {
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
            let serial = store
                .revoke(&vehicle, reason.into())
                .with_context(|| format!("cannot revoke {vehicle:?}"))?;
            println!("revoked {vehicle}'s certificate {serial}; its keys are deleted");
        }
        KeysCommand::Rotate { vehicle } => {
            let mut store = open()?;
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
            store
                .export_vehicle(&vehicle, &dest)
                .with_context(|| format!("cannot export {vehicle:?}"))?;
            println!(
                "{vehicle}'s bundle written to {} (keep it on the vehicle only)",
                dest.display()
            );
        }
        KeysCommand::RenewStation => {
            let mut store = open()?;
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

fn verifier_config(cfg: &SecurityConfig) -> VerifierConfig {
    VerifierConfig {
        max_age_ms: i64::from(cfg.max_age_s) * 1000,
        max_future_ms: i64::from(cfg.max_future_s) * 1000,
        ..VerifierConfig::default()
    }
}

fn policy(cfg: &SecurityConfig) -> Result<Policy> {
    if cfg.policy.as_os_str().is_empty() {
        return Ok(Policy::builtin());
    }
    Policy::load(&cfg.policy).context("security.policy")
}

/// The station's credentials from its key store, and what the revocation watcher needs.
pub struct StationKeys {
    /// Signs as the station; admits through the CA, CRL and policy.
    pub security: Security,
    /// The CA, to check a re-read revocation list.
    pub anchor: TrustAnchor,
    /// The revocation list file.
    pub crl_path: PathBuf,
}

/// Loads the station's credentials; every failure names the file and the problem.
pub fn station(cfg: &SecurityConfig) -> Result<StationKeys> {
    let store = KeyStore::open(&cfg.store).with_context(|| {
        format!(
            "security is on but the key store {} cannot be used (create it with `shoal keys init`)",
            cfg.store.display()
        )
    })?;
    let identity = store
        .station_identity()
        .context("security: the station's certificate")?;
    let gate = Gate::new(
        store
            .verifier(verifier_config(cfg))
            .context("security: the key store's certificates")?,
        policy(cfg)?,
    );
    Ok(StationKeys {
        security: Security::new(identity, gate),
        anchor: store.trust_anchor().clone(),
        crl_path: store.dir().join(CRL_FILE),
    })
}

/// Loads a vehicle's credentials from its bundle and checks they are `vehicle_id`'s.
pub fn vehicle(cfg: &SecurityConfig, vehicle_id: &str) -> Result<Security> {
    if cfg.bundle.as_os_str().is_empty() {
        bail!(
            "security is on but security.bundle is not set: on the station run `shoal keys export {vehicle_id} DIR` and point security.bundle (or SHOAL_SECURITY__BUNDLE) at DIR"
        );
    }
    let bundle = VehicleBundle::load(&cfg.bundle, shoal_model::now_ms()).with_context(|| {
        format!(
            "security is on but the vehicle bundle {} cannot be used",
            cfg.bundle.display()
        )
    })?;
    let name = bundle.identity.identity().name().to_owned();
    if name != vehicle_id {
        bail!(
            "security.bundle {} holds the certificate of {name:?}, not of vehicle {vehicle_id:?}",
            cfg.bundle.display()
        );
    }
    let gate = Gate::new(bundle.verifier(verifier_config(cfg)), policy(cfg)?);
    Ok(Security::new(bundle.identity, gate))
}

/// For `shoal up --secure`: the key store (created if missing), a certificate for each
/// vehicle that has none, and a fresh bundle per vehicle next to the store. Returns each
/// vehicle's bundle directory.
#[cfg(feature = "console")]
pub fn prepare_fleet(
    cfg: &SecurityConfig,
    vehicle_ids: &[&str],
) -> Result<std::collections::HashMap<String, PathBuf>> {
    let mut store = if cfg.store.join(shoal_security::store::STORE_FILE).exists() {
        KeyStore::open(&cfg.store).context("cannot open the key store")?
    } else {
        info!(dir = %cfg.store.display(), "creating the key store (shoal keys init)");
        KeyStore::init(&cfg.store, "ccs").context("cannot create the key store")?
    };
    let known = store.vehicles().context("cannot list the key store")?;
    let bundles_dir = cfg
        .store
        .parent()
        .unwrap_or_else(|| Path::new("."))
        .join("bundles");
    let mut out = std::collections::HashMap::new();
    for id in vehicle_ids {
        if !known.iter().any(|k| k == id) {
            let issued = store
                .issue_vehicle(id)
                .with_context(|| format!("cannot issue a certificate to {id:?}"))?;
            info!(
                vehicle = id,
                serial = issued.certificate.serial(),
                "certificate issued"
            );
        }
        let dest = bundles_dir.join(id);
        store
            .export_vehicle(id, &dest)
            .with_context(|| format!("cannot export {id:?}'s bundle"))?;
        out.insert((*id).to_string(), dest);
    }
    Ok(out)
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

/// Re-reads the revocation list when its file changes, so `shoal keys revoke` takes effect
/// in a running station. A list that does not verify is logged and ignored (the old one
/// stays in force).
pub fn watch_revocations(
    dds: Arc<PubSub>,
    anchor: TrustAnchor,
    crl_path: PathBuf,
    every: Duration,
    shutdown: CancellationToken,
) {
    tokio::spawn(async move {
        let mut seen = modified(&crl_path);
        loop {
            tokio::select! {
                () = shutdown.cancelled() => return,
                () = tokio::time::sleep(every) => {}
            }
            let now = modified(&crl_path);
            if now == seen {
                continue;
            }
            seen = now;
            match RevocationList::load(&crl_path, &anchor) {
                Ok(crl) => {
                    if let Some(s) = dds.security() {
                        s.set_revocations(crl);
                        info!(file = %crl_path.display(), "revocation list reloaded");
                    }
                }
                Err(e) => warn!(error = %e, "new revocation list ignored"),
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
