//! `shoal record` and `shoal replay`: Shoal topics into MCAP files and back onto DDS
//! (docs/recorder.md); and the acoustic recording `[recorder] acoustic` asks of every CDT
//! this process runs.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use shoal_converter::FrameTap;
use shoal_dds::{Credentials, PubSub};
use shoal_recorder::{
    AcousticRecorder, Identity, Publishers, Recorder, RecorderConfig, ReplayOptions, ReplayStats,
    Replayer, Speed,
};
use shoal_security::dds::{DdsKeystore, Enclave, Grant};
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
    /// (internal) Publish only this vehicle's samples, under its identity: a secure
    /// replay starts one such process per vehicle.
    #[arg(long, hide = true, value_name = "ID")]
    pub as_vehicle: Option<String>,
    /// (internal) The wall-clock instant, in ms since 1970, the first message is due.
    #[arg(long, hide = true, value_name = "MS")]
    pub start_at_unix_ms: Option<u64>,
}

/// The shared start a parent replay passed (`--start-at-unix-ms`): within a minute of now,
/// as the parent sets it a few seconds ahead; anything else is not from a parent replay.
fn start_instant(ms: u64) -> Result<std::time::SystemTime> {
    let at = std::time::UNIX_EPOCH + Duration::from_millis(ms);
    let now = std::time::SystemTime::now();
    let off = match at.duration_since(now) {
        Ok(ahead) => ahead,
        Err(behind) => behind.duration(),
    };
    if off > Duration::from_secs(60) {
        bail!(
            "--start-at-unix-ms {ms} is {} s from now; a replay's shared start is within a minute",
            off.as_secs()
        );
    }
    Ok(at)
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

/// The acoustic recorder `[recorder] acoustic` asks for, started, and the tap to give the
/// CDT (docs/recorder.md, "Acoustic frames"); `None` when it is off.
pub fn start_acoustic(config: &RecorderConfig) -> Result<Option<(AcousticRecorder, FrameTap)>> {
    if !config.acoustic {
        return Ok(None);
    }
    let started = AcousticRecorder::start(config).with_context(|| {
        format!(
            "cannot start recording the acoustic link ([recorder] acoustic) into {}",
            config.directory.display()
        )
    })?;
    info!(
        directory = %config.directory.display(),
        prefix = %shoal_recorder::acoustic::acoustic_prefix(config),
        "recording the acoustic link's frames and events ([recorder] acoustic)"
    );
    Ok(Some(started))
}

/// Stops an acoustic recorder (once its CDT has stopped) and logs what it wrote; a
/// failure is logged, not returned: the files stay readable up to their last chunk.
pub async fn stop_acoustic(recorder: AcousticRecorder) {
    match recorder.stop().await {
        Ok(s) => info!(
            files = s.files,
            messages = s.messages,
            bytes = s.bytes,
            dropped = s.dropped,
            "acoustic recording closed"
        ),
        Err(e) => warn!(
            error = %e,
            "acoustic recording failed; its files are readable up to their last chunk"
        ),
    }
}

/// A secure replay starts at most this many vehicle processes.
const MAX_REPLAY_VEHICLES: usize = 256;

/// How long the vehicle processes of a secure replay get to join the domain before the
/// first message is due.
const JOIN_GRACE: Duration = Duration::from_secs(3);

/// A vehicle's identity from the station's key store, never one issued for the occasion,
/// so a recording cannot make this host mint identities for vehicle ids it merely names.
fn stored_vehicle_enclave(cfg: &ShoalConfig, vehicle: &str) -> Result<Enclave> {
    let security = &cfg.security;
    let dir = crate::keys::dds_dir(&security.store);
    let store = DdsKeystore::open(&dir, crate::keys::keystore_options(security))
        .with_context(|| format!("the DDS Security keystore {}", dir.display()))?;
    store
        .enclave(&Grant::Vehicle(vehicle.to_string()))
        .with_context(|| {
            format!(
                "cannot publish as vehicle {vehicle:?}: the key store {} has no identity for it (replay publishes only as vehicles already issued one)",
                security.store.display()
            )
        })
}

/// A vehicle's participant for a replay: its identity from the key store, or from its
/// bundle on a vehicle's host.
fn vehicle_participant(cfg: &ShoalConfig, vehicle: &str) -> Result<PubSub> {
    let credentials = if cfg.security.bundle.as_os_str().is_empty() {
        Credentials::vehicle(stored_vehicle_enclave(cfg, vehicle)?, vehicle)
    } else {
        crate::keys::vehicle(&cfg.security, vehicle)
            .with_context(|| format!("cannot publish as vehicle {vehicle:?}"))?
    };
    PubSub::with_credentials(&cfg.dds, credentials)
        .with_context(|| format!("cannot join DDS securely as vehicle {vehicle:?}"))
}

/// Whether the key store holds `vehicle`'s identity, checked before any process starts so
/// that a missing one is named at once (a bundle is checked by the vehicle's process).
fn check_vehicle_identity(cfg: &ShoalConfig, vehicle: &str) -> Result<()> {
    if cfg.security.bundle.as_os_str().is_empty() {
        stored_vehicle_enclave(cfg, vehicle)?;
    }
    Ok(())
}

/// One vehicle process of a secure replay.
struct VehicleProcess {
    vehicle: String,
    child: tokio::process::Child,
}

/// Starts a process publishing `vehicle`'s samples of the same replay.
fn spawn_vehicle(
    config_file: Option<&std::path::Path>,
    args: &ReplayArgs,
    vehicle: &str,
    start_at_ms: u64,
) -> Result<VehicleProcess> {
    let exe = std::env::current_exe().context("cannot find the shoal executable")?;
    let mut cmd = tokio::process::Command::new(exe);
    if let Some(c) = config_file {
        cmd.arg("--config").arg(c);
    }
    cmd.arg("replay")
        .arg(&args.path)
        .args(["--speed", &args.speed])
        .args(["--as-vehicle", vehicle])
        .args(["--start-at-unix-ms", &start_at_ms.to_string()])
        .kill_on_drop(true);
    if args.repeat {
        cmd.arg("--loop");
    }
    if args.with_tasks {
        cmd.arg("--with-tasks");
    }
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start the replay process of vehicle {vehicle:?}"))?;
    Ok(VehicleProcess {
        vehicle: vehicle.to_string(),
        child,
    })
}

/// `shoal replay`. Without DDS Security one participant publishes everything. With it,
/// each identity publishes from its own process (Cyclone DDS holds one per process): this
/// one the station's samples, one started per vehicle that vehicle's, all keeping one
/// pace from a shared start instant.
pub async fn replay(
    cfg: &ShoalConfig,
    config_file: Option<&std::path::Path>,
    args: ReplayArgs,
) -> Result<()> {
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
    let mut options = ReplayOptions {
        speed,
        include_tasks: args.with_tasks,
        ..ReplayOptions::default()
    };
    let mut vehicles = Vec::new();
    let (publishers, who) = if !cfg.security.enabled {
        (
            Publishers::insecure(Arc::new(station_participant(cfg, "the replay")?))?,
            "replay".to_string(),
        )
    } else if let Some(vehicle) = &args.as_vehicle {
        options.start_at = args.start_at_unix_ms.map(start_instant).transpose()?;
        let pubsub = vehicle_participant(cfg, vehicle)?;
        info!(vehicle = %vehicle, "replaying as this vehicle");
        (
            Publishers::secure(Arc::new(pubsub), Identity::Vehicle(vehicle.clone())),
            format!("replay as {vehicle}"),
        )
    } else {
        let ids =
            shoal_recorder::publishing_vehicles(&args.path, args.with_tasks, MAX_REPLAY_VEHICLES)
                .context("cannot replay")?;
        for id in &ids {
            check_vehicle_identity(cfg, id)?;
        }
        let grace = JOIN_GRACE + Duration::from_millis(20 * ids.len() as u64);
        let start_at = std::time::SystemTime::now() + grace;
        let start_at_ms = start_at
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default()
            .as_millis() as u64;
        options.start_at = Some(std::time::UNIX_EPOCH + Duration::from_millis(start_at_ms));
        for id in &ids {
            vehicles.push(spawn_vehicle(config_file, &args, id, start_at_ms)?);
        }
        let pubsub = station_participant(cfg, "the replay")?;
        (
            Publishers::secure(Arc::new(pubsub), Identity::Station),
            "replay".to_string(),
        )
    };
    let mut replayer = Replayer::new(publishers, options);
    let label = who.clone();
    replayer.on_progress(PROGRESS_EVERY, move |s| print_stats(&label, "progress", s));
    // Said once, by the process that reads for everyone (each vehicle's process skips
    // the same channels).
    if args.as_vehicle.is_none() {
        let label = who.clone();
        replayer.on_skipped_channels(move |file, topics| {
            eprintln!(
                "shoal {label}: note: {}: skipping {} (not Shoal DDS topics; not replayed)",
                file.display(),
                topics.join(", ")
            );
        });
    }
    let mut damaged = Vec::new();
    let run = async {
        loop {
            damaged = replayer.replay_path(&args.path, &shutdown).await?;
            print_stats(&who, "pass done", &replayer.stats());
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
    print_stats(&who, "done", &s);
    let mut failed = Vec::new();
    for mut v in vehicles {
        // Stopped here (Ctrl-C reaches the vehicle processes too; a SIGTERM does not):
        // they stop with it.
        if shutdown.is_cancelled() {
            let _ = v.child.start_kill();
        }
        let status = tokio::select! {
            status = v.child.wait() => status,
            () = shutdown.cancelled() => {
                let _ = v.child.start_kill();
                v.child.wait().await
            }
        }
        .with_context(|| format!("the replay process of vehicle {:?}", v.vehicle))?;
        if shutdown.is_cancelled() {
            continue;
        }
        if !status.success() {
            failed.push(v.vehicle);
        }
    }
    for e in &damaged {
        eprintln!("shoal {who}: {e}");
    }
    if !failed.is_empty() {
        bail!("the replay processes of {failed:?} failed (their errors are above)");
    }
    if !damaged.is_empty() {
        bail!(
            "{} file(s) could not be read to their end (everything before the offset named was replayed)",
            damaged.len()
        );
    }
    Ok(())
}

fn print_stats(who: &str, what: &str, s: &ReplayStats) {
    eprintln!(
        "shoal {who}: {what}: {} files, {} read, {} published, {} invalid, {} undecodable, {} unknown, {} task assignments held back, {} failed",
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shared_start_far_from_now_is_refused() {
        let now_ms = u64::try_from(shoal_model::now_ms()).unwrap();
        assert!(start_instant(now_ms + 3_000).is_ok());
        assert!(start_instant(now_ms - 3_000).is_ok());
        for far in [0, now_ms + 3_600_000, now_ms - 3_600_000, u64::MAX / 2] {
            let err = start_instant(far).unwrap_err().to_string();
            assert!(err.contains("within a minute"), "{err}");
        }
    }
}
