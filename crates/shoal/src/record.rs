//! `shoal record` and `shoal replay`: Shoal topics into MCAP files and back onto DDS
//! (docs/recorder.md).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use shoal_dds::{Credentials, PubSub};
use shoal_recorder::{
    Publishers, Recorder, RecorderConfig, ReplayOptions, ReplayStats, Replayer, Speed,
};
use shoal_security::dds::{DdsKeystore, Grant};
use tracing::{info, warn};

use crate::config::ShoalConfig;

/// How often progress is printed.
const PROGRESS_EVERY: Duration = Duration::from_secs(3);

/// Flags of `shoal record`.
#[derive(Debug, clap::Args)]
pub struct RecordArgs {
    /// Directory the MCAP files are written in (created if missing).
    #[arg(long, value_name = "DIR", default_value = "recordings")]
    pub output: PathBuf,
    /// Start a new file once one holds this many MiB.
    #[arg(long, value_name = "N", default_value_t = 512)]
    pub max_file_mb: u64,
    /// Keep the recorder's files (PREFIX-*.mcap in the directory) under this many MiB:
    /// the oldest are deleted after each file is closed. At least twice --max-file-mb.
    #[arg(long, value_name = "N", default_value_t = 16384)]
    pub max_total_mb: u64,
    /// Start a new file once one has been open this many seconds.
    #[arg(long, value_name = "N", default_value_t = 3600)]
    pub max_file_seconds: u64,
    /// DDS topic names to record (default: every Shoal topic), e.g. shoal/state_vector.
    #[arg(long, value_name = "TOPIC", num_args = 1..)]
    pub topics: Vec<String>,
    /// File names are PREFIX-YYYYmmddTHHMMSSZ-N.mcap.
    #[arg(long, default_value = "shoal")]
    pub prefix: String,
}

/// Flags of `shoal replay`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// An MCAP file, or a directory whose .mcap files are replayed in recording order.
    pub path: PathBuf,
    /// Times the recorded pace, 1 to 100, or `max` for no waiting at all.
    #[arg(long, default_value = "1")]
    pub speed: String,
    /// Start again from the beginning when the end is reached, until Ctrl-C.
    #[arg(long = "loop")]
    pub repeat: bool,
    /// Also publish recorded task assignments. Off by default: a replayed assignment
    /// commands whichever live vehicle carries that id.
    #[arg(long)]
    pub with_tasks: bool,
}

/// The participant the recorder reads with: the station's identity (it reads every
/// partition) with security on, a plain one with security off.
fn station_participant(cfg: &ShoalConfig, who: &str) -> Result<PubSub> {
    if !cfg.security.enabled {
        if !cfg.dds.is_loopback_only() && !cfg.security.allow_insecure_network {
            bail!(
                "refusing to run {who} insecure on non-loopback interfaces ({:?}): turn security on, or set security.allow_insecure_network = true for lab work",
                cfg.dds.interfaces
            );
        }
        eprintln!("shoal: WARNING: SECURITY IS OFF for {who}: use this only in a lab.");
        warn!("security is off for {who}");
        return PubSub::new(&cfg.dds).context("cannot join DDS");
    }
    let credentials = crate::keys::station(&cfg.security)?;
    PubSub::with_credentials(&cfg.dds, credentials).context("cannot join DDS securely")
}

/// `shoal record`.
pub async fn record(cfg: &ShoalConfig, args: RecordArgs) -> Result<()> {
    let config = RecorderConfig {
        directory: args.output,
        prefix: args.prefix,
        max_file_bytes: args.max_file_mb.saturating_mul(1024 * 1024),
        max_file_seconds: args.max_file_seconds,
        max_total_bytes: args.max_total_mb.saturating_mul(1024 * 1024),
        topics: args.topics,
        ..RecorderConfig::default()
    };
    config.check().context("cannot record")?;
    let shutdown = crate::daemons::shutdown_signal(false);
    let dds = station_participant(cfg, "the recorder")?;
    let recorder = Recorder::start(&dds, &config)
        .with_context(|| format!("cannot start recording into {}", config.directory.display()))?;
    info!(directory = %config.directory.display(), "recording; Ctrl-C stops");
    let mut tick = tokio::time::interval(PROGRESS_EVERY);
    tick.tick().await;
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            _ = tick.tick() => {
                let s = recorder.stats();
                eprintln!(
                    "shoal record: {} files, {} messages, {} bytes, {} dropped",
                    s.files, s.messages, s.bytes, s.dropped
                );
                if recorder.failed() {
                    break;
                }
            }
        }
    }
    let s = recorder.stop().await.context(
        "recording failed; the files written so far are readable up to their last chunk",
    )?;
    eprintln!(
        "shoal record: done: {} files, {} messages, {} bytes, {} dropped, {} refused",
        s.files, s.messages, s.bytes, s.dropped, s.refused
    );
    Ok(())
}

/// The participants a replay publishes through. With security on, each vehicle's samples
/// go out under that vehicle's own identity from the key store (or its bundle): never
/// one issued for the occasion, so a recording cannot make this host mint identities for
/// vehicle ids it merely names.
fn publishers(cfg: &ShoalConfig) -> Result<Publishers> {
    let station = Arc::new(station_participant(cfg, "the replay")?);
    if !cfg.security.enabled {
        return Ok(Publishers::insecure(station)?);
    }
    let security = cfg.security.clone();
    let dds = cfg.dds.clone();
    Ok(Publishers::per_vehicle(station, move |vehicle: &str| {
        vehicle_participant(&security, &dds, vehicle)
    }))
}

fn vehicle_participant(
    security: &crate::config::SecurityConfig,
    dds: &shoal_dds::DdsConfig,
    vehicle: &str,
) -> Result<PubSub, Box<dyn std::error::Error + Send + Sync>> {
    let credentials = if security.bundle.as_os_str().is_empty() {
        let dir = crate::keys::dds_dir(&security.store);
        let store = DdsKeystore::open(&dir, crate::keys::keystore_options(security))
            .map_err(|e| format!("the DDS Security keystore {}: {e}", dir.display()))?;
        let enclave = store.enclave(&Grant::Vehicle(vehicle.to_string())).map_err(|e| {
            format!(
                "{e}: the key store {} has no identity for it (replay publishes only as vehicles already issued one)",
                security.store.display()
            )
        })?;
        Credentials::vehicle(enclave, vehicle)
    } else {
        crate::keys::vehicle(security, vehicle).map_err(|e| format!("{e:#}"))?
    };
    Ok(PubSub::with_credentials(dds, credentials)?)
}

/// `shoal replay`.
pub async fn replay(cfg: &ShoalConfig, args: ReplayArgs) -> Result<()> {
    let speed = if args.speed == "max" {
        Speed::AsFastAsPossible
    } else {
        let factor: f64 = args
            .speed
            .parse()
            .with_context(|| format!("--speed {:?} is not a number or `max`", args.speed))?;
        Speed::factor(factor)
            .with_context(|| format!("--speed must be 1 to 100 (or max), not {factor}"))?
    };
    // Nothing is published before the files are known to exist.
    shoal_recorder::mcap_files(&args.path).context("cannot replay")?;
    let shutdown = crate::daemons::shutdown_signal(false);
    let options = ReplayOptions {
        speed,
        include_tasks: args.with_tasks,
        ..ReplayOptions::default()
    };
    let mut replayer = Replayer::new(publishers(cfg)?, options);
    replayer.on_progress(PROGRESS_EVERY, |s| print_stats("progress", s));
    let mut damaged = Vec::new();
    let run = async {
        loop {
            damaged = replayer.replay_path(&args.path, &shutdown).await?;
            print_stats("pass done", &replayer.stats());
            if !args.repeat || shutdown.is_cancelled() {
                break;
            }
        }
        anyhow::Ok(())
    };
    run.await.context("replay failed")?;
    // Reliable samples still in flight get their acknowledgements before the
    // participants go.
    tokio::time::sleep(Duration::from_secs(1)).await;
    let s = replayer.stats();
    print_stats("done", &s);
    for e in &damaged {
        eprintln!("shoal replay: {e}");
    }
    if !damaged.is_empty() {
        bail!(
            "{} file(s) could not be read to their end (everything before the offset named was replayed)",
            damaged.len()
        );
    }
    Ok(())
}

fn print_stats(what: &str, s: &ReplayStats) {
    eprintln!(
        "shoal replay: {what}: {} files, {} read, {} published, {} invalid, {} undecodable, {} unknown, {} task assignments held back, {} failed",
        s.files,
        s.read,
        s.published,
        s.invalid,
        s.undecodable,
        s.unknown,
        s.tasks_skipped,
        s.write_failed
    );
}
