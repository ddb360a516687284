//! What several benchmarks share: DDS participants and helper processes, the sample
//! they send, percentiles, memory readings, the machine and date a result is stamped with.

use std::process::Stdio;
use std::sync::Arc;

use anyhow::{Context, Result};
use shoal_dds::PubSub;
use shoal_history::{History, HistoryConfig};
use shoal_model::{StateVector, now_ms};
use shoal_station::{Station, StationConfig};

use crate::config::ShoalConfig;

/// Topic of the throughput and soak samples.
pub(super) const THROUGHPUT: &str = "shoal/bench/throughput";

/// A participant for a measurement: insecure, or with a station identity from the DDS
/// keystore under `security.store` when `security.enabled` (only `shoal bench security`
/// and the helper processes it starts turn it on).
pub(super) fn dds(cfg: &ShoalConfig, domain: u16) -> Result<Arc<PubSub>> {
    let keystore = cfg
        .security
        .enabled
        .then(|| crate::keys::dds_dir(&cfg.security.store));
    super::security::participant(
        cfg,
        domain,
        keystore.as_deref(),
        &shoal_security::dds::Grant::Station,
    )
}

/// A state vector whose timestamp carries a sequence number (and stays valid).
pub(super) fn sample(vehicle: &str, seq: u64, step: u32) -> StateVector {
    StateVector {
        vehicle_id: vehicle.to_string(),
        timestamp_ms: 1_700_000_000_000 + i64::try_from(seq).unwrap_or(0),
        latitude_deg: 63.44,
        longitude_deg: 10.4,
        depth_m: f64::from(step),
        altitude_m: 12.0,
        speed_mps: 1.5,
        yaw_deg: 90.0,
        pitch_deg: 1.0,
        roll_deg: -1.0,
        battery_pct: 77.0,
    }
}

pub(super) fn seq_of(s: &StateVector) -> u64 {
    u64::try_from(s.timestamp_ms - 1_700_000_000_000).unwrap_or(0)
}

/// Starts `shoal bench <args>` as a helper process that stops when our stdin pipe closes,
/// with security on or off as `cfg` has it.
pub(super) fn helper(cfg: &ShoalConfig, args: &[String]) -> Result<tokio::process::Child> {
    let exe = std::env::current_exe()?;
    tokio::process::Command::new(exe)
        .arg("bench")
        .args(args)
        .env("SHOAL_SECURITY__ENABLED", cfg.security.enabled.to_string())
        .env("SHOAL_SECURITY__STORE", &cfg.security.store)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .context("cannot start the helper process")
}

/// Percentile of sorted values (nearest rank).
pub(super) fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        clippy::cast_precision_loss
    )]
    let i = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

/// A count with thousands separated by commas (`92,024`), as the reports print counts.
pub(super) fn grouped(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::with_capacity(digits.len() + digits.len() / 3);
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

pub(super) fn machine() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let cpus = std::thread::available_parallelism().map_or(0, std::num::NonZero::get);
    format!("{} ({cpus} cores)", host.trim())
}

pub(super) fn date() -> String {
    utc_date(now_ms())
}

// Lives with `shoal keys`, which the vehicle side builds without the benchmarks.
use crate::keys::utc_date;

pub(super) fn rss_mb() -> f64 {
    rss_mb_of("self")
}

/// Resident memory of a process (`self` or a pid), MB.
pub(super) fn rss_mb_of(pid: &str) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|kb| kb.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

pub(super) fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("shoal-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// A station for a measurement: the configured one, with its history in `db` and no
/// periodic summary in the output.
pub(super) fn bench_station(
    cfg: &ShoalConfig,
    domain: u16,
    db: &std::path::Path,
) -> Result<Station> {
    let history = History::open(&HistoryConfig {
        path: db.to_path_buf(),
        ..cfg.history.clone()
    })?;
    Ok(Station::new(
        StationConfig {
            summary_interval_s: 0.0,
            ..cfg.station.clone()
        },
        dds(cfg, domain)?,
        history,
    )?)
}

/// Starts `shoal <args>` with a domain, stopping when our stdin pipe closes.
pub(super) fn child(args: &[&str], domain: u16) -> Result<tokio::process::Child> {
    let exe = std::env::current_exe()?;
    tokio::process::Command::new(exe)
        .args(args)
        .arg("--exit-on-stdin-close")
        .env("SHOAL_DDS__DOMAIN_ID", domain.to_string())
        // The benchmarks' own participants are insecure; `shoal swarm` must be too.
        .env("SHOAL_SECURITY__ENABLED", "false")
        .env("SHOAL_CONSOLE__AUTH__ENABLED", "false")
        .env("RUST_LOG", "warn,cyclonedds=error")
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .with_context(|| format!("cannot start shoal {}", args.join(" ")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_are_grouped_by_thousands() {
        assert_eq!(grouped(0), "0");
        assert_eq!(grouped(999), "999");
        assert_eq!(grouped(1_000), "1,000");
        assert_eq!(grouped(92_024), "92,024");
        assert_eq!(grouped(1_234_567), "1,234,567");
    }
}
