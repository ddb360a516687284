//! `shoal modem-emu`: N virtual acoustic modems in one process, in one simulated sea.
//!
//! Each modem is a TCP server on 127.0.0.1 speaking the EvoLogics S2C AT interface
//! (docs/acoustic.md#at-interface) and a second one speaking the EviNS NL protocol
//! (docs/acoustic.md#nl-protocol). Transmissions go through a shared [`sea`]: propagation
//! delay `d / c` (Mackenzie), air time from bit rate and length, PER from the
//! [`crate::channel`] model (Rayleigh fading by default) drawn from a seeded PRNG, half
//! duplex (a transmitting modem hears nothing) and collisions (overlapping arrivals at a
//! receiver are both lost). Positions come from the config and can be moved at run time
//! with [`EmulatorHandle::set_position`], e.g. from vehicles' live state.
//!
//! Entry points: [`Emulator::start`] (returns a handle with the bound addresses) and
//! [`run`] (start and wait for shutdown), both taking a shutdown future.
//!
//! Shoal-specific choices (see `docs/deviations.md`): a destination that is not a node of
//! the sea gets `ERROR WRONG DESTINATION ADDRESS` (a real modem would transmit and report
//! `FAILEDIM`); bytes outside `+++` commands get `+++AT:18:ERROR WRONG FORMAT` (a real
//! modem in data mode would transmit them); NL payloads travel as IM or burst with the
//! 4-byte NL header counted in air time but not carried; routing tables are stored but
//! every packet goes direct (Shoal relays above the modem: [`crate::relay`]); an optional
//! hard range (`max_range_m`) beyond which nothing is heard, for relay chains.

mod sea;

use std::future::Future;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};

use serde::{Deserialize, Serialize};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinSet;
use tokio::time::Instant;
use tracing::{debug, info, warn};

use crate::at::{self, CommandParser};
use crate::channel::ChannelModel;
use crate::nl::NlCommandParser;
use sea::{Sea, Timer, Timers};

/// Emulator configuration; every field has a default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EmulatorConfig {
    /// PRNG seed: the same seed and the same traffic give the same losses.
    pub seed: u64,
    /// Wall-clock seconds per simulated second (0.1 runs ten times faster than real time).
    pub time_scale: f64,
    /// Channel physics.
    pub channel: ChannelModel,
    /// Use this PER for every packet instead of the channel model (for tests/benchmarks).
    pub fixed_per: Option<f64>,
    /// Instant message bit rate, bit/s (976 for S2C, docs/acoustic.md#frame-sizes-and-bit-rates).
    pub im_bit_rate: f64,
    /// Burst bit rate, bit/s.
    pub burst_bit_rate: f64,
    /// Per-packet on-air overhead (preamble, guard), seconds.
    pub preamble_s: f64,
    /// Instant-message retries after the first attempt (`AT!RI`).
    pub im_retries: u8,
    /// Beyond this distance, metres, a packet neither arrives nor interferes, whatever
    /// the channel model or `fixed_per` says: a relay chain's far end is then out of the
    /// station's range for certain (docs/acoustic.md#multi-hop-relays). `None`: the
    /// channel model alone decides.
    pub max_range_m: Option<f64>,
    /// The modems.
    pub modems: Vec<ModemConfig>,
}

impl Default for EmulatorConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            time_scale: 1.0,
            channel: ChannelModel::default(),
            fixed_per: None,
            im_bit_rate: 976.0,
            burst_bit_rate: 13_900.0,
            // With 64 bytes at 976 bit/s this gives ~0.6 s; a 10-byte IM ~0.18 s, in the
            // 0.14–0.20 s docs/acoustic.md#frame-sizes-and-bit-rates gives for a short IM.
            preamble_s: 0.1,
            im_retries: 2,
            max_range_m: None,
            modems: Vec::new(),
        }
    }
}

impl EmulatorConfig {
    /// A relay chain: the modems `chain` (address, name), first to last, on a line
    /// heading east from (`latitude_deg`, `longitude_deg`), `spacing_m` apart, with a
    /// range of 1.5 spacings: each hears only its neighbours, so only the chain reaches
    /// from one end to the other (docs/acoustic.md#multi-hop-relays).
    pub fn relay_chain(
        chain: &[(u8, &str)],
        latitude_deg: f64,
        longitude_deg: f64,
        spacing_m: f64,
    ) -> Self {
        let frame = shoal_model::geo::LocalFrame::new(shoal_model::GeoPoint {
            latitude_deg,
            longitude_deg,
        });
        let modems = chain
            .iter()
            .zip(0u32..)
            .map(|(&(address, name), i)| {
                let at = frame.to_geo(f64::from(i) * spacing_m, 0.0);
                ModemConfig {
                    address,
                    name: name.to_owned(),
                    latitude_deg: at.latitude_deg,
                    longitude_deg: at.longitude_deg,
                    depth_m: 20.0,
                    ..ModemConfig::default()
                }
            })
            .collect();
        Self {
            max_range_m: Some(1.5 * spacing_m),
            modems,
            ..Self::default()
        }
    }
}

/// One virtual modem.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ModemConfig {
    /// Acoustic address, 1..=254.
    pub address: u8,
    /// Label for logs and the status line.
    pub name: String,
    /// AT port on 127.0.0.1 (0 = any free port; real modems use 9200).
    pub at_port: u16,
    /// NL port on 127.0.0.1 (0 = any free port).
    pub nl_port: u16,
    /// Initial latitude, degrees.
    pub latitude_deg: f64,
    /// Initial longitude, degrees.
    pub longitude_deg: f64,
    /// Initial depth, metres.
    pub depth_m: f64,
}

impl Default for ModemConfig {
    fn default() -> Self {
        Self {
            address: 1,
            name: String::new(),
            at_port: 0,
            nl_port: 0,
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 5.0,
        }
    }
}

/// A position in the simulated sea.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Position {
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
    /// Depth, metres.
    pub depth_m: f64,
}

/// Counters of one directed link, for the live status line.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct LinkStats {
    /// Sender address.
    pub src: u8,
    /// Receiver address.
    pub dst: u8,
    /// Packets addressed to `dst` (or broadcast) that reached it physically.
    pub frames: u64,
    /// Received intact.
    pub delivered: u64,
    /// Lost to the channel (PER draw).
    pub lost: u64,
    /// Lost to a collision with another arrival.
    pub collisions: u64,
    /// Lost because the receiver was transmitting (half duplex).
    pub half_duplex: u64,
    /// Lost because the sender or the receiver was silent (a failed modem, an outage).
    pub outage: u64,
}

/// Why the emulator could not start or an operation failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EmulatorError {
    /// A port could not be bound.
    #[error("cannot bind 127.0.0.1:{port}: {source}")]
    Bind {
        /// The port.
        port: u16,
        /// The OS error.
        source: std::io::Error,
    },
    /// The configuration is unusable.
    #[error("invalid emulator config: {0}")]
    Config(String),
    /// No modem has this address.
    #[error("no modem with address {0}")]
    UnknownAddress(u8),
}

/// Where one modem listens.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ModemEndpoints {
    /// Acoustic address (as configured).
    pub address: u8,
    /// Label.
    pub name: String,
    /// AT interface.
    pub at: SocketAddr,
    /// NL interface.
    pub nl: SocketAddr,
}

type Shared = Arc<Mutex<Sea>>;

fn lock(s: &Shared) -> MutexGuard<'_, Sea> {
    // A panic while holding the lock would be a bug; keep serving with the inner state.
    s.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A running emulator.
#[derive(Debug)]
pub struct EmulatorHandle {
    sea: Shared,
    modems: Vec<ModemEndpoints>,
    stop: watch::Sender<bool>,
    tasks: JoinSet<()>,
}

impl EmulatorHandle {
    /// The modems and their bound addresses.
    pub fn modems(&self) -> &[ModemEndpoints] {
        &self.modems
    }

    /// Moves a modem (e.g. to a vehicle's latest State Vector).
    pub fn set_position(
        &self,
        address: u8,
        latitude_deg: f64,
        longitude_deg: f64,
        depth_m: f64,
    ) -> Result<(), EmulatorError> {
        if !(latitude_deg.is_finite() && longitude_deg.is_finite() && depth_m.is_finite()) {
            return Err(EmulatorError::Config("position must be finite".into()));
        }
        let mut sea = lock(&self.sea);
        let i = sea
            .index_of(address)
            .ok_or(EmulatorError::UnknownAddress(address))?;
        if let Some(n) = sea.nodes.get_mut(i) {
            n.pos = Position {
                latitude_deg,
                longitude_deg,
                depth_m,
            };
        }
        Ok(())
    }

    /// Fails a modem (`silent`), or brings it back: a silent modem puts nothing on air
    /// and hears nothing, as in a modem failure or a link outage.
    pub fn set_silent(&self, address: u8, silent: bool) -> Result<(), EmulatorError> {
        let mut sea = lock(&self.sea);
        let i = sea
            .index_of(address)
            .ok_or(EmulatorError::UnknownAddress(address))?;
        if let Some(n) = sea.nodes.get_mut(i) {
            n.silent = silent;
        }
        Ok(())
    }

    /// Simulated seconds each modem has spent transmitting, by address: what it took of
    /// the one shared channel.
    pub fn airtime(&self) -> Vec<(u8, f64)> {
        lock(&self.sea)
            .nodes
            .iter()
            .map(|n| (n.address, n.air_s))
            .collect()
    }

    /// A modem's current position.
    pub fn position(&self, address: u8) -> Option<Position> {
        let sea = lock(&self.sea);
        sea.index_of(address)
            .and_then(|i| sea.nodes.get(i))
            .map(|n| n.pos)
    }

    /// Per-link counters (frames, delivered, lost, collisions, half duplex).
    pub fn stats(&self) -> Vec<LinkStats> {
        lock(&self.sea).stats()
    }

    /// Asks every task to stop.
    pub fn shutdown(&self) {
        let _ = self.stop.send(true);
    }

    /// Waits until every server task has stopped (after shutdown).
    pub async fn stopped(mut self) {
        while self.tasks.join_next().await.is_some() {}
    }
}

/// The emulator's entry point.
#[derive(Debug)]
pub struct Emulator;

impl Emulator {
    /// Binds every modem's AT and NL port on 127.0.0.1 and starts serving; stops when
    /// `shutdown` completes or [`EmulatorHandle::shutdown`] is called.
    pub async fn start(
        config: EmulatorConfig,
        shutdown: impl Future<Output = ()> + Send + 'static,
    ) -> Result<EmulatorHandle, EmulatorError> {
        validate(&config)?;
        let sea: Shared = Arc::new(Mutex::new(Sea::new(&config, Instant::now())));
        let (stop, stop_rx) = watch::channel(false);
        let mut tasks = JoinSet::new();
        let mut modems = Vec::new();
        for (i, m) in config.modems.iter().enumerate() {
            let at_l = bind(m.at_port).await?;
            let nl_l = bind(m.nl_port).await?;
            let ep = ModemEndpoints {
                address: m.address,
                name: m.name.clone(),
                at: at_l.local_addr().map_err(|source| EmulatorError::Bind {
                    port: m.at_port,
                    source,
                })?,
                nl: nl_l.local_addr().map_err(|source| EmulatorError::Bind {
                    port: m.nl_port,
                    source,
                })?,
            };
            info!(address = m.address, at = %ep.at, nl = %ep.nl, "virtual modem listening");
            modems.push(ep);
            tasks.spawn(accept_loop(at_l, sea.clone(), i, false, stop_rx.clone()));
            tasks.spawn(accept_loop(nl_l, sea.clone(), i, true, stop_rx.clone()));
        }
        let stop2 = stop.clone();
        tokio::spawn(async move {
            shutdown.await;
            let _ = stop2.send(true);
        });
        Ok(EmulatorHandle {
            sea,
            modems,
            stop,
            tasks,
        })
    }
}

/// Starts the emulator and runs it until `shutdown` completes.
pub async fn run(
    config: EmulatorConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> Result<(), EmulatorError> {
    let h = Emulator::start(config, shutdown).await?;
    h.stopped().await;
    Ok(())
}

fn validate(c: &EmulatorConfig) -> Result<(), EmulatorError> {
    let bad = |m: &str| Err(EmulatorError::Config(m.to_owned()));
    if !(c.time_scale.is_finite() && c.time_scale > 0.0) {
        return bad("time_scale must be > 0");
    }
    if !(c.im_bit_rate > 0.0 && c.burst_bit_rate > 0.0) {
        return bad("bit rates must be > 0");
    }
    if c.fixed_per.is_some_and(|p| !(0.0..=1.0).contains(&p)) {
        return bad("fixed_per must be in [0, 1]");
    }
    if c.max_range_m.is_some_and(|r| !(r.is_finite() && r > 0.0)) {
        return bad("max_range_m must be > 0");
    }
    let mut seen = std::collections::HashSet::new();
    for m in &c.modems {
        if m.address == 0 || m.address == at::BROADCAST {
            return bad("modem addresses must be 1..=254");
        }
        if !seen.insert(m.address) {
            return bad("duplicate modem address");
        }
    }
    Ok(())
}

async fn bind(port: u16) -> Result<TcpListener, EmulatorError> {
    // Loopback only: the emulator is a test and integration tool, never exposed.
    TcpListener::bind(("127.0.0.1", port))
        .await
        .map_err(|source| EmulatorError::Bind { port, source })
}

fn schedule(sea: &Shared, timers: Timers) {
    for (at, t) in timers {
        let sea = sea.clone();
        tokio::spawn(async move {
            tokio::time::sleep_until(at).await;
            let more = {
                let mut s = lock(&sea);
                let now = Instant::now();
                match t {
                    Timer::Resolve(id) => s.resolve(id, now),
                    Timer::Timeout { node, id } => s.timeout(node, id, now),
                }
            };
            schedule(&sea, more);
        });
    }
}

/// Completes once the stop flag is set (or its sender is gone).
pub(crate) async fn stopped(rx: &mut watch::Receiver<bool>) {
    // The guard `wait_for` returns is not `Send`: drop it before returning.
    let _ = rx.wait_for(|s| *s).await.map(|_| ());
}

async fn accept_loop(
    listener: TcpListener,
    sea: Shared,
    node: usize,
    nl: bool,
    mut stop: watch::Receiver<bool>,
) {
    let mut conns = JoinSet::new();
    loop {
        tokio::select! {
            r = listener.accept() => match r {
                Ok((stream, peer)) => {
                    debug!(node, nl, %peer, "client connected");
                    // Replies and notifications (OK, then DELIVERED or RECV) are short
                    // lines in quick succession: Nagle would hold the second for the
                    // client's delayed ACK.
                    let _ = stream.set_nodelay(true);
                    conns.spawn(serve(stream, sea.clone(), node, nl, stop.clone()));
                }
                Err(e) => warn!(error = %e, "accept failed"),
            },
            () = stopped(&mut stop) => break,
        }
    }
    conns.shutdown().await;
}

/// Serves one AT or NL client until it disconnects or the emulator stops. Bad input is
/// answered with the protocol's error replies; it never closes the connection. Input
/// buffering is bounded by the parsers (`at::MAX_COMMAND`, `nl::MAX_LINE`).
async fn serve(
    mut stream: TcpStream,
    sea: Shared,
    node: usize,
    nl: bool,
    mut stop: watch::Receiver<bool>,
) {
    let (tx, mut rx) = mpsc::channel::<Vec<u8>>(256);
    lock(&sea).add_client(node, nl, tx);
    let mut at_parser = CommandParser::new();
    let mut nl_parser = NlCommandParser::new();
    let mut buf = vec![0u8; 4096];
    loop {
        tokio::select! {
            r = stream.read(&mut buf) => {
                let n = match r {
                    Ok(0) | Err(_) => break,
                    Ok(n) => n,
                };
                let input = buf.get(..n).unwrap_or_default();
                let mut out = Vec::new();
                if nl {
                    nl_parser.push(input);
                    for item in nl_parser.by_ref() {
                        let reply = match item {
                            Ok(cmd) => {
                                let (reply, timers) = lock(&sea).nl_command(node, cmd, Instant::now());
                                schedule(&sea, timers);
                                reply
                            }
                            Err(rej) => rej.reply,
                        };
                        out.extend(reply.to_bytes());
                    }
                } else {
                    at_parser.push(input);
                    for item in at_parser.by_ref() {
                        match item {
                            Ok(cmd) => {
                                let name = cmd.name();
                                let (reply, timers) = lock(&sea).at_command(node, cmd, Instant::now());
                                schedule(&sea, timers);
                                out.extend(at::reply(name, reply.as_bytes()));
                            }
                            Err(rej) => out.extend(at::reply(&rej.cmd, rej.error.as_str().as_bytes())),
                        }
                    }
                }
                if !out.is_empty() && stream.write_all(&out).await.is_err() {
                    break;
                }
            }
            Some(note) = rx.recv() => {
                if stream.write_all(&note).await.is_err() {
                    break;
                }
            }
            () = stopped(&mut stop) => break,
        }
    }
    debug!(node, nl, "client disconnected");
}
