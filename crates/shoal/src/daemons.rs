//! The long-running commands: `station`, `vehicle`, and `up` which starts them all.
//! `station` and `up` are the station side (the `console` feature); the rest is the
//! vehicle side, which builds without it.

use std::path::Path;
#[cfg(feature = "console")]
use std::process::Stdio;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use shoal_dds::PubSub;
#[cfg(feature = "console")]
use shoal_history::History;
use shoal_model::Validate;
use shoal_proxy::sim::{SimSpec, SimVehicle};
#[cfg(feature = "console")]
use shoal_station::Station;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::config::ShoalConfig;

/// A token cancelled on Ctrl-C, SIGTERM, or (if asked) when standard input closes.
pub fn shutdown_signal(exit_on_stdin_close: bool) -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        let mut term =
            match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
                Ok(s) => s,
                Err(e) => {
                    warn!(error = %e, "cannot watch SIGTERM; only Ctrl-C stops this process");
                    let _ = tokio::signal::ctrl_c().await;
                    t.cancel();
                    return;
                }
            };
        let stdin_closed = async {
            if exit_on_stdin_close {
                // A plain thread, not `tokio::io::stdin`: that read runs on the runtime's
                // blocking pool, and dropping the runtime waits for it, so a process that
                // failed at start would hang until its parent closed the pipe.
                let (tx, rx) = tokio::sync::oneshot::channel::<()>();
                let spawned = std::thread::Builder::new()
                    .name("stdin-watch".into())
                    .spawn(move || {
                        let mut buf = [0u8; 64];
                        let mut stdin = std::io::stdin().lock();
                        while matches!(std::io::Read::read(&mut stdin, &mut buf), Ok(n) if n > 0) {}
                        let _ = tx.send(());
                    });
                match spawned {
                    Ok(_) => {
                        let _ = rx.await;
                    }
                    Err(e) => {
                        warn!(error = %e, "cannot watch stdin; only signals stop this process");
                        std::future::pending::<()>().await;
                    }
                }
            } else {
                std::future::pending::<()>().await;
            }
        };
        tokio::select! {
            _ = tokio::signal::ctrl_c() => info!("Ctrl-C: stopping"),
            _ = term.recv() => info!("SIGTERM: stopping"),
            () = stdin_closed => info!("parent went away: stopping"),
        }
        t.cancel();
    });
    token
}

fn warn_if_not_loopback(cfg: &ShoalConfig) {
    if !cfg.dds.is_loopback_only() {
        info!(interfaces = ?cfg.dds.interfaces, "DDS uses non-loopback interfaces: traffic may leave this host");
    }
}

/// Says loudly, on the terminal and in the log, that security is off.
fn warn_insecure(who: &str) {
    let msg = format!(
        "SECURITY IS OFF for {who}: any process on this DDS domain can command vehicles, \
         impersonate them and read every position. Use this only in a lab."
    );
    eprintln!("shoal: WARNING: {msg}");
    warn!("{msg}");
}

/// The station's participant (also the CDT's on the station side): with `[security]` on
/// (the default), OMG DDS Security with the station's identity, the key store created on
/// first run, and revocations applied live.
fn station_dds(cfg: &ShoalConfig, shutdown: &CancellationToken) -> Result<Arc<PubSub>> {
    warn_if_not_loopback(cfg);
    if !cfg.security.enabled {
        if !cfg.dds.is_loopback_only() && !cfg.security.allow_insecure_network {
            bail!(
                "refusing to run the station insecure on non-loopback interfaces ({:?}): turn security on, or set security.allow_insecure_network = true for lab work with unmodified third-party vehicles",
                cfg.dds.interfaces
            );
        }
        warn_insecure("the station");
        return Ok(Arc::new(PubSub::new(&cfg.dds).context("cannot join DDS")?));
    }
    let credentials = crate::keys::station(&cfg.security)?;
    let dds = Arc::new(
        PubSub::with_credentials(&cfg.dds, credentials).context("cannot join DDS securely")?,
    );
    crate::keys::watch_revocations(
        Arc::clone(&dds),
        &cfg.security,
        Duration::from_secs(u64::from(cfg.security.crl_check_s)),
        shutdown.clone(),
    );
    Ok(dds)
}

/// A vehicle's proxy options: its reporting rate, and its task ledger where `[vehicle]`
/// says, so a task runs at most once across restarts.
fn vehicle_options(cfg: &ShoalConfig, rate_hz: f64) -> shoal_proxy::ProxyOptions {
    shoal_proxy::ProxyOptions {
        state_rate_hz: rate_hz,
        max_task_age: Some(Duration::from_secs(u64::from(cfg.vehicle.max_task_age_s))),
        ledger_dir: Some(cfg.vehicle.state_dir.clone()),
        ..shoal_proxy::ProxyOptions::default()
    }
}

/// A vehicle's participant: with `[security]` on (the default), OMG DDS Security with its
/// own identity, publishing in its own partition.
fn vehicle_dds(cfg: &ShoalConfig, vehicle_id: &str) -> Result<Arc<PubSub>> {
    warn_if_not_loopback(cfg);
    let dds = if cfg.security.enabled {
        let credentials = crate::keys::vehicle(&cfg.security, vehicle_id)?;
        PubSub::with_credentials(&cfg.dds, credentials).context("cannot join DDS securely")?
    } else {
        warn_insecure(&format!("vehicle {vehicle_id}"));
        PubSub::new(&cfg.dds).context("cannot join DDS")?
    };
    Ok(Arc::new(dds))
}

/// `shoal station`; `scenario` (a file, a shipped scenario's name or `none`) names the
/// missions it starts on their timeline.
#[cfg(feature = "console")]
pub async fn station(cfg: ShoalConfig, scenario: &str, exit_on_stdin_close: bool) -> Result<()> {
    // Read before anything starts: a bad scenario is one line and no station.
    let scenario = match crate::scenario::resolve(scenario)? {
        Some(source) => Some(crate::scenario::load(&source)?),
        None => None,
    };
    let shutdown = shutdown_signal(exit_on_stdin_close);
    let listener = tokio::net::TcpListener::bind(cfg.console.listen)
        .await
        .with_context(|| format!("cannot listen on console.listen = {}", cfg.console.listen))?;
    let history = History::open(&cfg.history).with_context(|| {
        format!(
            "cannot open the history store at {}",
            cfg.history.path.display()
        )
    })?;
    let dds = station_dds(&cfg, &shutdown)?;
    let foxglove = if cfg.foxglove.enabled {
        let bridge =
            shoal_foxglove::Bridge::start(Arc::clone(&dds), cfg.foxglove.clone(), shutdown.clone())
                .await
                .context("cannot start the Foxglove bridge ([foxglove])")?;
        info!("Foxglove bridge: ws://{}/api/foxglove", cfg.console.listen);
        Some(bridge)
    } else {
        None
    };
    // On the station's own participant: one identity per process, and it reads every
    // vehicle's partition.
    let recorder = if cfg.recorder.enabled {
        let recorder = shoal_recorder::Recorder::start(&dds, &cfg.recorder).with_context(|| {
            format!(
                "cannot start recording ([recorder]) into {}",
                cfg.recorder.directory.display()
            )
        })?;
        info!(directory = %cfg.recorder.directory.display(), "recording every topic ([recorder])");
        Some(recorder)
    } else {
        None
    };
    let station =
        Station::new(cfg.station.clone(), dds, history).context("cannot start the station")?;
    if !cfg.traffic.inputs.is_empty() {
        let picture = shoal_traffic::TrafficPicture::spawn(cfg.traffic.clone(), shutdown.clone())
            .context("cannot start the [traffic] inputs")?;
        info!(inputs = ?cfg.traffic.inputs, "vessel traffic: reading AIS and NMEA 0183");
        // A fresh station has no picture yet, so this cannot be refused.
        let _ = station.handle().attach_traffic(picture);
    }
    if let Some(scenario) = scenario {
        if !scenario.faults.is_empty() {
            warn!(
                faults = scenario.faults.len(),
                "the scenario's faults are injected only by `shoal scenario run`; this station runs its missions alone"
            );
        }
        let handle = station.handle();
        let stop = shutdown.clone();
        tokio::spawn(async move { handle.run_scenario(scenario, stop).await });
    }
    let federation = if cfg.federation.enabled {
        let mut fed = cfg.federation.clone();
        fed.lease.state_file = crate::federation::lease_file(&fed, &cfg.history);
        Some(crate::federation::start(fed, station.handle(), shutdown.clone()).await?)
    } else {
        None
    };
    let api = tokio::spawn(shoal_console::serve_with_bridge(
        listener,
        station.handle(),
        cfg.console.clone(),
        foxglove,
        shutdown.clone(),
    ));
    let report = station
        .run(shutdown.clone())
        .await
        .context("station failed")?;
    shutdown.cancel();
    if let Ok(Err(e)) = api.await {
        warn!(error = %e, "HTTP API stopped with an error");
    }
    if let Some(f) = federation {
        let _ = f.await;
    }
    if let Some(recorder) = recorder {
        match recorder.stop().await {
            Ok(s) => info!(
                files = s.files,
                messages = s.messages,
                bytes = s.bytes,
                dropped = s.dropped,
                "recording closed"
            ),
            Err(e) => {
                warn!(error = %e, "recording failed; its files are readable up to their last chunk");
            }
        }
    }
    info!(
        accepted = report.stats.states_accepted,
        rejected = report.stats.total_rejected(),
        committed = report.history_committed,
        "station stopped"
    );
    Ok(())
}

/// `shoal vehicle --sim ...`.
pub async fn vehicle(cfg: &ShoalConfig, spec: SimSpec, exit_on_stdin_close: bool) -> Result<()> {
    if !(spec.rate_hz > 0.0 && spec.rate_hz <= 100.0) {
        bail!(
            "--rate must be in (0, 100] state vectors per second, not {}",
            spec.rate_hz
        );
    }
    let probe = SimVehicle::new(&spec, shoal_model::now_ms());
    probe
        .announcement
        .validate()
        .with_context(|| format!("vehicle {:?} cannot be announced", spec.id))?;
    probe
        .state(shoal_model::now_ms())
        .validate()
        .context("start position is invalid")?;
    let dds = vehicle_dds(cfg, &spec.id)?;
    let shutdown = shutdown_signal(exit_on_stdin_close);
    let options = vehicle_options(cfg, spec.rate_hz);
    shoal_proxy::run_sim_on(spec, cfg.fleet.sim.clone(), options, dds, shutdown)
        .await
        .context("simulated vehicle failed")
}

#[cfg(feature = "console")]
struct Child {
    name: String,
    child: tokio::process::Child,
}

#[cfg(feature = "console")]
fn spawn(
    exe: &Path,
    config: Option<&Path>,
    env: &[(String, String)],
    name: &str,
    args: &[String],
) -> Result<Child> {
    let mut cmd = tokio::process::Command::new(exe);
    if let Some(c) = config {
        cmd.arg("--config").arg(c);
    }
    cmd.envs(env.iter().cloned());
    cmd.args(args)
        .arg("--exit-on-stdin-close")
        .stdin(Stdio::piped())
        .kill_on_drop(true);
    let child = cmd
        .spawn()
        .with_context(|| format!("cannot start {name}"))?;
    Ok(Child {
        name: name.to_string(),
        child,
    })
}

/// `shoal acoustic-demo` (started by `shoal up`).
pub async fn acoustic_demo(
    cfg: &ShoalConfig,
    scenario: Option<&str>,
    exit_on_stdin_close: bool,
) -> Result<()> {
    let shutdown = shutdown_signal(exit_on_stdin_close);
    let demo = acoustic_demo_config(scenario)?;
    info!(
        vehicles = demo.vehicles.len(),
        "acoustic demo: submerged AUV -> emulated modem -> CDT on the relay -> station"
    );
    let cdt_dds = station_dds(cfg, &shutdown)?;
    let keys = if cfg.security.enabled {
        let ids: Vec<&str> = demo.vehicles.iter().map(|v| v.sim.id.as_str()).collect();
        Some(crate::keys::acoustic_keys(&cfg.security, &ids)?)
    } else {
        None
    };
    let (recorder, tap) = crate::record::start_acoustic(&cfg.recorder)?.unzip();
    let run = crate::relay::run_acoustic_demo(demo, cdt_dds, keys, tap, shutdown)
        .await
        .context("acoustic demo failed");
    // The relay has stopped, its CDT's tap with it: the recorder closes at once.
    if let Some(recorder) = recorder {
        crate::record::stop_acoustic(recorder).await;
    }
    run
}

/// What the acoustic demo runs: the acoustic vehicles and relay of `scenario` (a file or a
/// shipped name) when it has any, the demo's own AUV otherwise.
fn acoustic_demo_config(scenario: Option<&str>) -> Result<crate::relay::AcousticDemoConfig> {
    let Some(source) = scenario
        .map(crate::scenario::resolve)
        .transpose()?
        .flatten()
    else {
        return Ok(crate::relay::AcousticDemoConfig::default());
    };
    let s = crate::scenario::load(&source)?;
    Ok(crate::relay::AcousticDemoConfig::from_scenario(&s).unwrap_or_default())
}

/// Waits for a child asked to stop; kills it after 10 s.
#[cfg(feature = "console")]
async fn stop_child(mut c: Child) {
    match tokio::time::timeout(Duration::from_secs(10), c.child.wait()).await {
        Ok(Ok(status)) if status.success() => {}
        Ok(Ok(status)) => warn!(child = %c.name, %status, "stopped with an error"),
        Ok(Err(e)) => warn!(child = %c.name, error = %e, "cannot wait for it"),
        Err(_) => {
            warn!(child = %c.name, "did not stop within 10 s; killing it");
            let _ = c.child.kill().await;
        }
    }
}

/// What `shoal up` starts besides the station.
#[cfg(feature = "console")]
#[derive(Debug, Clone)]
pub struct UpOptions {
    /// No simulated vehicles at all.
    pub no_fleet: bool,
    /// Lightweight vehicles in a `shoal swarm` process.
    pub sim_vehicles: usize,
    /// `--scenario`: a file, a shipped scenario's name, `none`, or not given.
    pub scenario: Option<String>,
}

/// What `shoal up` runs: the fleet it starts and the scenario (as `--scenario` names it to
/// the station) whose missions the station starts.
#[cfg(feature = "console")]
fn up_plan(
    cfg: &ShoalConfig,
    scenario: Option<&str>,
    no_fleet: bool,
) -> Result<(Vec<SimSpec>, Option<String>)> {
    let configured = cfg.fleet.vehicles.clone();
    let chosen = match scenario {
        Some(value) => crate::scenario::resolve(value)?,
        None if no_fleet => None,
        // A user's own fleet is not replaced by vehicles they did not ask for.
        None if configured != crate::config::FleetConfig::default().vehicles => {
            info!(
                vehicles = configured.len(),
                "the configuration lists its own [[fleet.vehicles]]: starting them with no scenario (--scenario FILE runs one)"
            );
            None
        }
        None => Some(crate::scenario::Source::Shipped(shoal_scenario::DEFAULT)),
    };
    let Some(source) = chosen else {
        return Ok((configured, None));
    };
    let s = crate::scenario::load(&source)?;
    info!(scenario = %source, "{}", crate::scenario::summary(&s));
    let fleet = crate::scenario::fleet(&s);
    let acoustic: Vec<&str> = s.acoustic_vehicles().map(|v| v.id.as_str()).collect();
    if !acoustic.is_empty() && (no_fleet || !cfg.fleet.acoustic_demo) {
        warn!(
            vehicles = %acoustic.join(","),
            "the scenario's acoustic vehicles are not started: [fleet] acoustic_demo is off (or --no-fleet); `shoal scenario run` carries them over the emulated acoustic network"
        );
    }
    let arg = match source {
        crate::scenario::Source::Shipped(name) => name.to_owned(),
        crate::scenario::Source::File(path) => path,
    };
    Ok((fleet, Some(arg)))
}

/// `shoal swarm`.
pub async fn swarm(
    cfg: &ShoalConfig,
    spec: shoal_proxy::swarm::SwarmSpec,
    exit_on_stdin_close: bool,
) -> Result<()> {
    spec.check()?;
    if cfg.security.enabled {
        bail!(
            "shoal swarm runs many vehicles on one participant, which no vehicle's permissions allow: run it with --insecure (it is for scale tests)"
        );
    }
    warn_if_not_loopback(cfg);
    let dds = Arc::new(PubSub::new(&cfg.dds).context("cannot join DDS")?);
    let shutdown = shutdown_signal(exit_on_stdin_close);
    shoal_proxy::swarm::run_swarm(spec, dds, shutdown)
        .await
        .context("swarm failed")
}

/// `shoal up`: a station and the configured fleet, each its own process (its own DDS
/// participant, as on real vehicles), stopped together.
#[cfg(feature = "console")]
pub async fn up(config: Option<&Path>, cfg: &ShoalConfig, opts: UpOptions) -> Result<()> {
    let UpOptions {
        no_fleet,
        sim_vehicles,
        scenario,
    } = opts;
    let (fleet, scenario) = up_plan(cfg, scenario.as_deref(), no_fleet)?;
    let secure = cfg.security.enabled;
    if secure && sim_vehicles > 0 {
        bail!(
            "--sim-vehicles needs --insecure (swarm vehicles share one participant, which no vehicle's permissions allow)"
        );
    }
    let exe = std::env::current_exe().context("cannot find the shoal executable")?;
    let shutdown = shutdown_signal(false);
    let mut station_env = Vec::new();
    if !secure {
        warn_insecure("the station and every vehicle `shoal up` starts");
        station_env.push(("SHOAL_SECURITY__ENABLED".to_string(), "false".to_string()));
    }
    let mut bundles = std::collections::HashMap::new();
    // The acoustic demo runs the scenario's acoustic vehicles when it has any.
    let demo = acoustic_demo_config(scenario.as_deref())?;
    if secure {
        let mut ids: Vec<&str> = Vec::new();
        if !no_fleet {
            ids.extend(fleet.iter().map(|v| v.id.as_str()));
            if cfg.fleet.acoustic_demo {
                ids.extend(demo.vehicles.iter().map(|v| v.sim.id.as_str()));
            }
        }
        bundles = crate::keys::prepare_fleet(&cfg.security, &ids)?;
        station_env.push(("SHOAL_SECURITY__ENABLED".to_string(), "true".to_string()));
    }
    let mut station_args = vec!["station".to_string()];
    if let Some(s) = &scenario {
        station_args.extend(["--scenario".to_string(), s.clone()]);
    }
    let mut children = vec![spawn(&exe, config, &station_env, "station", &station_args)?];
    // Vehicles start once the API answers, so the station hears their announcements live.
    let addr = cfg.console.listen;
    // A station that stops (bad credentials, a port in use) has said why on stderr: say
    // so at once rather than waiting out the timeout. `try_wait`, not `wait`: waiting
    // closes the child's stdin, which tells it to stop.
    let station = &mut children[0].child;
    let ready = async {
        loop {
            if tokio::net::TcpStream::connect(addr).await.is_ok() {
                return Ok(());
            }
            if let Some(status) = station
                .try_wait()
                .context("cannot watch the station process")?
            {
                bail!("the station stopped ({status}) before opening its API; its error is above");
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    };
    tokio::select! {
        () = shutdown.cancelled() => {}
        r = tokio::time::timeout(Duration::from_secs(30), ready) => match r {
            Ok(started) => started?,
            Err(_) => bail!("the station did not open its API on {addr} within 30 s"),
        },
    }
    if !no_fleet {
        for v in &fleet {
            let mut args = vec![
                "vehicle".to_string(),
                "--sim".into(),
                v.kind.as_str().into(),
                "--id".into(),
                v.id.clone(),
                "--lat".into(),
                v.latitude_deg.to_string(),
                "--lon".into(),
                v.longitude_deg.to_string(),
                "--rate".into(),
                v.rate_hz.to_string(),
                "--battery".into(),
                v.battery_pct.to_string(),
            ];
            // The scenario's [environment] is the ocean the vehicle samples.
            if let Some(s) = &scenario {
                args.extend(["--scenario".to_string(), s.clone()]);
            }
            let mut env = station_env.clone();
            if let Some(dir) = bundles.get(&v.id) {
                env.push((
                    "SHOAL_SECURITY__BUNDLE".to_string(),
                    dir.display().to_string(),
                ));
            }
            children.push(spawn(&exe, config, &env, &v.id, &args)?);
        }
    }
    if cfg.fleet.acoustic_demo && !no_fleet {
        let mut args = vec!["acoustic-demo".to_string()];
        if let Some(s) = &scenario {
            args.extend(["--scenario".to_string(), s.clone()]);
        }
        children.push(spawn(&exe, config, &station_env, "acoustic demo", &args)?);
    }
    if sim_vehicles > 0 {
        children.push(spawn(
            &exe,
            config,
            &station_env,
            "swarm",
            &[
                "swarm".to_string(),
                "--count".into(),
                sim_vehicles.to_string(),
            ],
        )?);
    }
    info!(
        vehicles = children.len() - 1,
        "Shoal is up. Console: http://{addr}/  API: http://{addr}/api/fleet  Ctrl-C stops everything."
    );
    // Run until Ctrl-C, or until a child dies on its own (then stop the rest too).
    let mut failed = None;
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            () = tokio::time::sleep(Duration::from_millis(500)) => {
                for c in &mut children {
                    if let Ok(Some(status)) = c.child.try_wait() {
                        failed = Some(format!("{} exited ({status})", c.name));
                    }
                }
                if failed.is_some() {
                    break;
                }
            }
        }
    }
    // Closing their stdin asks the children to stop cleanly: vehicles first, the station
    // last, so the station records everything the vehicles sent before they left.
    let station = children.remove(0);
    for v in &mut children {
        drop(v.child.stdin.take());
    }
    for v in children {
        stop_child(v).await;
    }
    let mut station = station;
    drop(station.child.stdin.take());
    stop_child(station).await;
    match failed {
        Some(f) => bail!("{f}; stopped the rest"),
        None => {
            info!("all stopped");
            Ok(())
        }
    }
}

/// The command-line settings of `shoal vehicle --proxy ...`.
#[derive(Debug)]
pub struct ProxyFlags {
    /// Vehicle id.
    pub id: String,
    /// `--address`.
    pub address: Option<String>,
    /// `--bind`.
    pub bind: Option<String>,
    /// `--namespace`.
    pub namespace: Option<String>,
    /// `--rmw`.
    pub rmw: Option<crate::RmwKind>,
    /// `--proxy-config`.
    pub config_file: Option<std::path::PathBuf>,
    /// `--rate`.
    pub rate_hz: f64,
}

/// Reads a proxy's settings from `--proxy-config`, or its defaults.
fn proxy_settings<T: serde::de::DeserializeOwned + Default>(file: Option<&Path>) -> Result<T> {
    let Some(path) = file else {
        return Ok(T::default());
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read proxy settings {}", path.display()))?;
    let de = toml::Deserializer::parse(&text)
        .with_context(|| format!("proxy settings {}", path.display()))?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        let inner = e.inner().to_string();
        let first = inner.lines().next().unwrap_or_default().to_string();
        anyhow::anyhow!(
            "proxy settings {}: invalid value at `{}`: {first}",
            path.display(),
            e.path()
        )
    })
}

fn socket_addr(flag: &str, value: &str) -> Result<std::net::SocketAddr> {
    value
        .parse()
        .with_context(|| format!("{flag} {value:?} is not HOST:PORT (an IP address and a port)"))
}

/// `shoal vehicle --proxy mavlink|imc|ros2 ...`: joins a real vehicle's software to DDS.
pub async fn proxy(
    cfg: &ShoalConfig,
    kind: crate::ProxyKind,
    flags: ProxyFlags,
    exit_on_stdin_close: bool,
) -> Result<()> {
    use shoal_proxy::{imc, mavlink, ros2, run_proxy};
    if !(flags.rate_hz > 0.0 && flags.rate_hz <= 100.0) {
        bail!(
            "--rate must be in (0, 100] state vectors per second, not {}",
            flags.rate_hz
        );
    }
    if !shoal_model::is_identifier(&flags.id, shoal_model::MAX_VEHICLE_ID_LEN) {
        bail!(
            "--id {:?}: 1..=32 letters, digits, '_', '-' or '.'",
            flags.id
        );
    }
    if flags.rmw.is_some() && kind != crate::ProxyKind::Ros2 {
        bail!("--rmw is for --proxy ros2");
    }
    let options = vehicle_options(cfg, flags.rate_hz);
    let file = flags.config_file.as_deref();
    let shutdown = shutdown_signal(exit_on_stdin_close);
    match kind {
        crate::ProxyKind::Mavlink => {
            let mut c: mavlink::MavlinkConfig = proxy_settings(file)?;
            c.vehicle_id.clone_from(&flags.id);
            if let Some(a) = flags.address {
                c.address = a;
            }
            info!(address = %c.address, "MAVLink proxy starting");
            let adapter = mavlink::MavlinkAdapter::connect(c)
                .await
                .context("MAVLink proxy")?;
            run_proxy(adapter, vehicle_dds(cfg, &flags.id)?, options, shutdown)
                .await
                .context("MAVLink proxy stopped")
        }
        crate::ProxyKind::Imc => {
            let mut c: imc::ImcConfig = proxy_settings(file)?;
            c.vehicle_id.clone_from(&flags.id);
            if let Some(a) = &flags.address {
                c.vehicle = socket_addr("--address", a)?;
            }
            if let Some(b) = &flags.bind {
                c.bind = socket_addr("--bind", b)?;
            }
            info!(bind = %c.bind, vehicle = %c.vehicle, "IMC proxy starting");
            let adapter = imc::ImcAdapter::bind(c).await.context("IMC proxy")?;
            run_proxy(adapter, vehicle_dds(cfg, &flags.id)?, options, shutdown)
                .await
                .context("IMC proxy stopped")
        }
        crate::ProxyKind::Ros2 => {
            let mut c: ros2::Ros2Config = proxy_settings(file)?;
            c.vehicle_id.clone_from(&flags.id);
            if let Some(ns) = flags.namespace {
                c.namespace = ns;
            }
            match flags.rmw {
                Some(crate::RmwKind::Dds) => c.rmw = ros2::Rmw::Dds,
                Some(crate::RmwKind::Zenoh) => c.rmw = ros2::Rmw::Zenoh,
                None => {}
            }
            info!(namespace = %c.namespace, rmw = ?c.rmw, "ROS 2 proxy starting");
            // Shoal's own side is on DDS either way; over rmw_zenoh the vehicle's topics are
            // on a Zenoh session of the adapter's.
            let participant = vehicle_dds(cfg, &flags.id)?;
            let adapter = match c.rmw {
                ros2::Rmw::Dds => ros2::Ros2Adapter::new(Arc::clone(&participant), c),
                ros2::Rmw::Zenoh => ros2::Ros2Adapter::zenoh(c).await,
            }
            .context("ROS 2 proxy")?;
            run_proxy(adapter, participant, options, shutdown)
                .await
                .context("ROS 2 proxy stopped")
        }
    }
}

#[cfg(all(test, feature = "console"))]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn ids(fleet: &[SimSpec]) -> Vec<&str> {
        fleet.iter().map(|v| v.id.as_str()).collect()
    }

    /// The default scenario drives the default fleet; a configured fleet is kept, with no
    /// missions, unless a scenario is asked for by name.
    #[test]
    fn up_runs_the_default_scenario_unless_the_fleet_is_configured_or_none_is_asked() {
        let cfg = ShoalConfig::default();
        let (fleet, s) = up_plan(&cfg, None, false).unwrap();
        assert_eq!(ids(&fleet), ["auv-1", "auv-2", "usv-1", "rov-1"]);
        assert_eq!(fleet, cfg.fleet.vehicles);
        assert_eq!(s.as_deref(), Some("sea-trial"));
        let (fleet, s) = up_plan(&cfg, Some("none"), false).unwrap();
        assert_eq!(fleet, cfg.fleet.vehicles);
        assert_eq!(s, None);
        assert_eq!(up_plan(&cfg, None, true).unwrap().1, None);

        let mut own = ShoalConfig::default();
        own.fleet.vehicles.truncate(1);
        own.fleet.vehicles[0].id = "mine-1".into();
        let (fleet, s) = up_plan(&own, None, false).unwrap();
        assert_eq!(ids(&fleet), ["mine-1"]);
        assert_eq!(s, None);
        let (fleet, s) = up_plan(&own, Some("harbour-survey"), false).unwrap();
        assert!(ids(&fleet).contains(&"auv-3"));
        assert_eq!(s.as_deref(), Some("harbour-survey"));
        assert!(up_plan(&own, Some("no-such.toml"), false).is_err());
    }
}
