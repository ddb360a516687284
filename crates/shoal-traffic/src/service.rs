//! The I/O layer: UDP listeners and TCP clients feeding one shared `Picture`, on tokio.

use std::io;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use tokio::io::AsyncReadExt;
use tokio::net::{TcpStream, UdpSocket};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::config::{ConfigError, Input, TrafficConfig};
use crate::cpa::{ApproachWindow, OwnVehicle, VesselApproach};
use crate::framing::{LineSplitter, Piece};
use crate::picture::{OwnShipView, Picture, TargetView, TrafficStats};

/// Why the traffic picture could not start.
#[derive(Debug, thiserror::Error)]
pub enum TrafficError {
    /// The configuration is invalid.
    #[error("traffic configuration: {0}")]
    Config(#[from] ConfigError),
    /// A UDP input could not bind its address.
    #[error("cannot listen on udp://{addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// The OS error.
        source: io::Error,
    },
    /// `spawn` was called outside a tokio runtime.
    #[error("the traffic picture must be started inside a tokio runtime")]
    NoRuntime,
}

/// Starts the traffic picture's inputs.
#[derive(Debug)]
pub struct TrafficPicture;

/// A running traffic picture: read its state, feed it lines; clones share it.
#[derive(Clone, Debug)]
pub struct TrafficHandle {
    inner: Arc<Inner>,
}

#[derive(Debug)]
struct Inner {
    picture: Mutex<Picture>,
    udp_addrs: Vec<SocketAddr>,
    tasks: Mutex<Vec<JoinHandle<()>>>,
    // The token given to `spawn`; each input task holds a clone.
    cancel: CancellationToken,
}

/// Largest UDP datagram read (the IPv4 maximum).
const DATAGRAM_MAX: usize = 65_536;

impl TrafficPicture {
    /// Validates `config`, binds the UDP inputs and starts one task per input; they stop
    /// when `cancel` is cancelled. Must be called inside a tokio runtime.
    pub fn spawn(
        config: TrafficConfig,
        cancel: CancellationToken,
    ) -> Result<TrafficHandle, TrafficError> {
        config.validate()?;
        let runtime = tokio::runtime::Handle::try_current().map_err(|_| TrafficError::NoRuntime)?;
        let mut sockets = Vec::new();
        for input in &config.inputs {
            if let Input::Udp(addr) = input {
                let bind = || -> io::Result<UdpSocket> {
                    let s = std::net::UdpSocket::bind(addr)?;
                    s.set_nonblocking(true)?;
                    let _guard = runtime.enter();
                    UdpSocket::from_std(s)
                };
                let socket = bind().map_err(|source| TrafficError::Bind {
                    addr: *addr,
                    source,
                })?;
                sockets.push(socket);
            }
        }
        let udp_addrs = sockets.iter().filter_map(|s| s.local_addr().ok()).collect();
        let inner = Arc::new(Inner {
            picture: Mutex::new(Picture::new(&config)),
            udp_addrs,
            tasks: Mutex::new(Vec::new()),
            cancel,
        });
        let config = Arc::new(config);
        let cancel = &inner.cancel;
        let mut tasks = Vec::new();
        for socket in sockets {
            tasks.push(runtime.spawn(udp_input(
                socket,
                Arc::clone(&inner),
                config.max_line_len,
                cancel.clone(),
            )));
        }
        for input in &config.inputs {
            if let Input::Tcp { host, port } = input {
                tasks.push(runtime.spawn(tcp_input(
                    host.clone(),
                    *port,
                    Arc::clone(&inner),
                    Arc::clone(&config),
                    cancel.clone(),
                )));
            }
        }
        *lock(&inner.tasks) = tasks;
        info!(inputs = config.inputs.len(), "traffic picture started");
        Ok(TrafficHandle { inner })
    }
}

/// Locks, taking over a mutex poisoned by a panicking holder (the picture has no
/// invariant a half-done update can break beyond one target's fields).
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl TrafficHandle {
    /// All live targets, by MMSI.
    pub fn targets(&self) -> Vec<TargetView> {
        lock(&self.inner.picture).targets(Instant::now())
    }

    /// One target.
    pub fn target(&self, mmsi: u32) -> Option<TargetView> {
        lock(&self.inner.picture).target_view(mmsi, Instant::now())
    }

    /// The own ship, once any GGA, RMC, HDT or VDO was read.
    pub fn own_ship(&self) -> Option<OwnShipView> {
        lock(&self.inner.picture).own_ship(Instant::now())
    }

    /// The counters.
    pub fn stats(&self) -> TrafficStats {
        lock(&self.inner.picture).stats()
    }

    /// Feeds one NMEA line as if an input had received it; returns whether it changed the
    /// picture.
    pub fn ingest_line(&self, line: &str) -> bool {
        lock(&self.inner.picture).ingest_line(line.as_bytes(), Instant::now())
    }

    /// Every (vehicle, target) pair inside `window`, targets dead-reckoned to now.
    pub fn approaches(
        &self,
        vehicles: &[OwnVehicle],
        window: ApproachWindow,
    ) -> Vec<VesselApproach> {
        lock(&self.inner.picture).approaches(vehicles, Instant::now(), window)
    }

    /// The addresses the UDP inputs are bound to (the real port when configured with 0).
    pub fn udp_addrs(&self) -> &[SocketAddr] {
        &self.inner.udp_addrs
    }

    /// Waits for the input tasks to end (after the cancellation token fired).
    pub async fn join(&self) {
        let tasks = std::mem::take(&mut *lock(&self.inner.tasks));
        for t in tasks {
            if let Err(e) = t.await {
                warn!(%e, "traffic input task failed");
            }
        }
    }
}

async fn udp_input(
    socket: UdpSocket,
    inner: Arc<Inner>,
    max_line: usize,
    cancel: CancellationToken,
) {
    let mut buf = vec![0u8; DATAGRAM_MAX];
    let mut splitter = LineSplitter::new(max_line);
    loop {
        let received = tokio::select! {
            () = cancel.cancelled() => break,
            r = socket.recv_from(&mut buf) => r,
        };
        match received {
            Ok((n, from)) => {
                debug!(%from, bytes = n, "traffic datagram");
                let now = Instant::now();
                let mut p = lock(&inner.picture);
                p.stats_mut().udp_datagrams += 1;
                let data = buf.get(..n).unwrap_or_default();
                // A datagram holds whole lines: its end ends the last one.
                splitter.push(data, |piece| feed(&mut p, piece, now));
                splitter.finish(|piece| feed(&mut p, piece, now));
            }
            Err(e) => {
                // ICMP errors and the like: not fatal for a listener; avoid a hot loop.
                debug!(%e, "traffic UDP receive error");
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        }
    }
}

fn feed(p: &mut Picture, piece: Piece<'_>, now: Instant) {
    match piece {
        Piece::Line(l) => {
            p.ingest_line(l, now);
        }
        Piece::TooLong => p.note_too_long(),
    }
}

/// Connects to an NMEA server and reads its lines, reconnecting with exponential back-off.
async fn tcp_input(
    host: String,
    port: u16,
    inner: Arc<Inner>,
    config: Arc<TrafficConfig>,
    cancel: CancellationToken,
) {
    let min = Duration::from_millis(config.reconnect_min_ms);
    let max = Duration::from_millis(config.reconnect_max_ms);
    let mut backoff = min;
    let mut buf = vec![0u8; 8192];
    loop {
        let connect = tokio::time::timeout(max.max(min), TcpStream::connect((host.as_str(), port)));
        let stream = tokio::select! {
            () = cancel.cancelled() => return,
            r = connect => r,
        };
        match stream {
            Ok(Ok(mut stream)) => {
                info!(%host, port, "traffic TCP input connected");
                lock(&inner.picture).stats_mut().tcp_connects += 1;
                let mut splitter = LineSplitter::new(config.max_line_len);
                let mut got_data = false;
                loop {
                    let read = tokio::select! {
                        () = cancel.cancelled() => return,
                        r = stream.read(&mut buf) => r,
                    };
                    let now = Instant::now();
                    match read {
                        Ok(0) | Err(_) => {
                            let mut p = lock(&inner.picture);
                            splitter.finish(|piece| feed(&mut p, piece, now));
                            p.stats_mut().tcp_failures += 1;
                            break;
                        }
                        Ok(n) => {
                            got_data = true;
                            let mut p = lock(&inner.picture);
                            let data = buf.get(..n).unwrap_or_default();
                            splitter.push(data, |piece| feed(&mut p, piece, now));
                        }
                    }
                }
                warn!(%host, port, "traffic TCP input disconnected");
                // A server that accepts and hangs up at once must not be hammered.
                if got_data {
                    backoff = min;
                }
            }
            Ok(Err(e)) => {
                debug!(%host, port, %e, "traffic TCP connect failed");
                lock(&inner.picture).stats_mut().tcp_failures += 1;
            }
            Err(_) => {
                debug!(%host, port, "traffic TCP connect timed out");
                lock(&inner.picture).stats_mut().tcp_failures += 1;
            }
        }
        tokio::select! {
            () = cancel.cancelled() => return,
            () = tokio::time::sleep(backoff) => {}
        }
        backoff = (backoff * 2).min(max);
    }
}
