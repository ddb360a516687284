//! Modem drivers: the [`ModemDriver`] trait and its EvoLogics AT and EviNS NL
//! implementations over TCP.
//!
//! A driver keeps **one message in flight**: the modem does not queue and a new instant
//! message cancels a pending one (docs/acoustic.md#at-interface), so the caller (the
//! [`crate::link`] layer) keeps the queue and hands over one frame at a time with
//! [`ModemDriver::transmit`], which resolves to the frame's [`Outcome`]. A background task
//! owns the TCP connection: it waits for each command's reply before the next (as the modem
//! requires), retries after `BUSY`, maps `DELIVEREDIM` / `FAILEDIM` / `CANCELEDIM` (or
//! `NL,delivered` / `NL,failed`) to outcomes, and reconnects when the connection drops,
//! re-sending the frame in flight so nothing the caller queued is lost.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU16, Ordering};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{Mutex, mpsc, oneshot};
use tokio::time::Instant;
use tracing::{debug, info, warn};

use crate::at::{AtCommand, FrameParser, Notification};
use crate::nl::{NlCommand, NlEvent, NlEventParser};

/// A frame to send.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OutFrame {
    /// Destination address (255 = broadcast).
    pub dst: u8,
    /// Payload (one or more PDUs).
    pub data: Vec<u8>,
    /// Ask the receiving modem to acknowledge (ignored for broadcast).
    pub ack: bool,
    /// Send as burst data (`AT*SEND`) instead of an instant message.
    pub burst: bool,
}

/// What became of a transmitted frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Outcome {
    /// The destination acknowledged it.
    Delivered,
    /// Sent without acknowledgement (no confirmation either way).
    Sent,
    /// No acknowledgement came (`FAILEDIM`): it may or may not have arrived.
    Failed,
    /// The modem cancelled it (`CANCELEDIM`), e.g. after a reset.
    Canceled,
}

/// A received frame with the metadata the modem reports.
#[derive(Debug, Clone, PartialEq)]
pub struct RxFrame {
    /// Sender address.
    pub src: u8,
    /// Destination address.
    pub dst: u8,
    /// Payload.
    pub data: Vec<u8>,
    /// Received signal strength, dB, where the protocol reports it.
    pub rssi: Option<i32>,
    /// Signal integrity, where the protocol reports it.
    pub integrity: Option<u32>,
}

/// Why a frame could not be transmitted; the frame is handed back so the caller can retry.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TransmitError {
    /// The modem answered with an error (e.g. `ERROR WRONG DESTINATION ADDRESS`).
    #[error("modem rejected the frame: {reason}")]
    Rejected {
        /// The frame.
        frame: OutFrame,
        /// The modem's reply.
        reason: String,
    },
    /// The driver has stopped.
    #[error("driver stopped")]
    Closed {
        /// The frame.
        frame: OutFrame,
    },
}

/// An acoustic modem as the link layer sees it.
pub trait ModemDriver: Send + Sync {
    /// Sends one frame and resolves when its fate is known. Only one call should be
    /// pending at a time; the modem does not queue.
    fn transmit(
        &self,
        frame: OutFrame,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send;
    /// The next received frame; `None` once the driver has stopped.
    fn receive(&self) -> impl Future<Output = Option<RxFrame>> + Send;
    /// The modem's own address, once learnt.
    fn local_address(&self) -> Option<u8>;
    /// Whether the TCP connection to the modem is currently up.
    fn is_connected(&self) -> bool;
}

/// Timing of a TCP driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriverConfig {
    /// Modem address (AT or NL port).
    pub addr: SocketAddr,
    /// Wait before reconnecting after the connection dropped or failed.
    pub reconnect_delay: Duration,
    /// Wait before re-sending after a `BUSY` reply.
    pub busy_retry: Duration,
    /// Longest wait for a command's reply before the connection is considered dead.
    pub reply_timeout: Duration,
    /// Longest wait for a delivery report before the frame counts as failed.
    pub report_timeout: Duration,
    /// Instant-message bit rate, bit/s (976 for the S2C,
    /// docs/acoustic.md#frame-sizes-and-bit-rates): with `air_overhead`, how long an
    /// unacknowledged frame occupies the modem.
    pub im_bit_rate: f64,
    /// Fixed on-air overhead per frame (preamble, guard).
    pub air_overhead: Duration,
}

impl DriverConfig {
    /// Defaults for a real-time link: reconnect after 1 s, retry busy after 0.5 s, 5 s for
    /// a reply, 60 s for a delivery report.
    pub fn new(addr: SocketAddr) -> Self {
        Self {
            addr,
            reconnect_delay: Duration::from_secs(1),
            busy_retry: Duration::from_millis(500),
            reply_timeout: Duration::from_secs(5),
            report_timeout: Duration::from_secs(60),
            im_bit_rate: 976.0,
            air_overhead: Duration::from_millis(100),
        }
    }

    /// How long a frame of `len` bytes stays on air: an unacknowledged frame is reported
    /// sent only then, because the modem cannot take another one before (it does not
    /// queue: docs/acoustic.md#at-interface) and the link must still be free to choose what
    /// goes next.
    pub fn air_time(&self, len: usize) -> Duration {
        #[allow(clippy::cast_precision_loss)]
        let bits = (len * 8) as f64;
        self.air_overhead + Duration::from_secs_f64(bits / self.im_bit_rate.max(1.0))
    }

    /// Scales every duration (for emulators running faster than real time).
    pub fn scaled(mut self, factor: f64) -> Self {
        let s = |d: Duration| Duration::from_secs_f64((d.as_secs_f64() * factor).max(0.001));
        self.reconnect_delay = s(self.reconnect_delay);
        self.busy_retry = s(self.busy_retry);
        self.reply_timeout = s(self.reply_timeout);
        self.report_timeout = s(self.report_timeout);
        self.air_overhead = s(self.air_overhead);
        self.im_bit_rate /= factor.max(1e-6);
        self
    }
}

/// What a protocol reader produced, protocol-independent.
#[derive(Debug)]
enum WireEvent {
    Address(u8),
    Accepted,
    Busy,
    Rejected(String),
    Delivered,
    Failed,
    Canceled,
    Received(RxFrame),
    Ignored,
}

/// A modem protocol as the driver engine needs it.
trait Wire: Send + 'static {
    const NAME: &'static str;
    fn hello(&self) -> Vec<u8>;
    fn send(&self, f: &OutFrame) -> Vec<u8>;
    fn push(&mut self, bytes: &[u8]);
    fn next(&mut self) -> Option<WireEvent>;
    fn reset(&mut self);
}

/// The EvoLogics AT protocol.
#[derive(Debug, Default)]
struct AtWire {
    parser: FrameParser,
}

impl Wire for AtWire {
    const NAME: &'static str = "at";

    fn hello(&self) -> Vec<u8> {
        AtCommand::GetLocalAddress.to_bytes()
    }

    fn send(&self, f: &OutFrame) -> Vec<u8> {
        if f.burst {
            AtCommand::SendBurst {
                dst: f.dst,
                data: f.data.clone(),
            }
            .to_bytes()
        } else {
            AtCommand::SendIm {
                dst: f.dst,
                ack: f.ack && f.dst != crate::at::BROADCAST,
                data: f.data.clone(),
            }
            .to_bytes()
        }
    }

    fn push(&mut self, bytes: &[u8]) {
        self.parser.push(bytes);
    }

    fn next(&mut self) -> Option<WireEvent> {
        let frame = self.parser.next()?;
        let text = frame.text();
        Some(match frame.cmd.as_str() {
            "AT" => match Notification::parse(&frame.body) {
                Some(Notification::RecvIm(r) | Notification::Recv(r)) => {
                    WireEvent::Received(RxFrame {
                        src: r.src,
                        dst: r.dst,
                        data: r.data,
                        rssi: Some(r.rssi),
                        integrity: Some(r.integrity),
                    })
                }
                Some(Notification::DeliveredIm(_) | Notification::Delivered { .. }) => {
                    WireEvent::Delivered
                }
                Some(Notification::FailedIm(_) | Notification::Failed { .. }) => WireEvent::Failed,
                Some(Notification::CanceledIm(_)) => WireEvent::Canceled,
                // A bare-`AT` reply such as the error for garbage input.
                _ if text.starts_with("ERROR") => WireEvent::Rejected(text),
                _ => WireEvent::Ignored,
            },
            "AT?AL" => text
                .trim()
                .parse()
                .map_or(WireEvent::Ignored, WireEvent::Address),
            "AT*SENDIM" | "AT*SEND" => {
                if text == "OK" {
                    WireEvent::Accepted
                } else if text.starts_with("BUSY") {
                    WireEvent::Busy
                } else {
                    WireEvent::Rejected(text)
                }
            }
            _ => WireEvent::Ignored,
        })
    }

    fn reset(&mut self) {
        self.parser = FrameParser::new();
    }
}

/// The EviNS NL protocol.
#[derive(Debug, Default)]
struct NlWire {
    parser: NlEventParser,
}

impl Wire for NlWire {
    const NAME: &'static str = "nl";

    fn hello(&self) -> Vec<u8> {
        NlCommand::GetAddress.to_bytes()
    }

    fn send(&self, f: &OutFrame) -> Vec<u8> {
        NlCommand::Send {
            kind: None,
            dst: f.dst,
            data: f.data.clone(),
        }
        .to_bytes()
    }

    fn push(&mut self, bytes: &[u8]) {
        self.parser.push(bytes);
    }

    fn next(&mut self) -> Option<WireEvent> {
        Some(match self.parser.next()? {
            NlEvent::SendOk => WireEvent::Accepted,
            NlEvent::SendBusy => WireEvent::Busy,
            NlEvent::SendError => WireEvent::Rejected("NL,send,error".into()),
            NlEvent::NoRouting => WireEvent::Rejected("NL,error,norouting".into()),
            NlEvent::Error(r) => WireEvent::Rejected(format!("NL,error,{r}")),
            NlEvent::Recv { src, dst, data } => WireEvent::Received(RxFrame {
                src,
                dst,
                data,
                rssi: None,
                integrity: None,
            }),
            NlEvent::Delivered { .. } => WireEvent::Delivered,
            NlEvent::Failed { .. } => WireEvent::Failed,
            NlEvent::Address(a) => WireEvent::Address(a),
            _ => WireEvent::Ignored,
        })
    }

    fn reset(&mut self) {
        self.parser = NlEventParser::new();
    }
}

type Job = (OutFrame, oneshot::Sender<Result<Outcome, TransmitError>>);

/// Shared state between a driver handle and its background task.
#[derive(Debug)]
struct Status {
    address: AtomicU16,
    connected: AtomicBool,
}

/// The protocol-independent part of a TCP driver: a handle to the background task.
#[derive(Debug)]
struct Engine {
    jobs: mpsc::Sender<Job>,
    rx: Mutex<mpsc::Receiver<RxFrame>>,
    status: Arc<Status>,
}

const NO_ADDRESS: u16 = u16::MAX;

impl Engine {
    fn start<W: Wire + Default>(cfg: DriverConfig, expect_reports: bool) -> Self {
        let (jobs, job_rx) = mpsc::channel(1);
        let (rx_tx, rx) = mpsc::channel(256);
        let status = Arc::new(Status {
            address: AtomicU16::new(NO_ADDRESS),
            connected: AtomicBool::new(false),
        });
        tokio::spawn(run::<W>(cfg, expect_reports, job_rx, rx_tx, status.clone()));
        Self {
            jobs,
            rx: Mutex::new(rx),
            status,
        }
    }

    async fn transmit(&self, frame: OutFrame) -> Result<Outcome, TransmitError> {
        let (tx, rx) = oneshot::channel();
        if let Err(mpsc::error::SendError((frame, _))) = self.jobs.send((frame.clone(), tx)).await {
            return Err(TransmitError::Closed { frame });
        }
        rx.await.unwrap_or(Err(TransmitError::Closed { frame }))
    }

    async fn receive(&self) -> Option<RxFrame> {
        self.rx.lock().await.recv().await
    }

    fn local_address(&self) -> Option<u8> {
        u8::try_from(self.status.address.load(Ordering::Relaxed)).ok()
    }

    fn is_connected(&self) -> bool {
        self.status.connected.load(Ordering::Relaxed)
    }
}

/// Where the frame in flight is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    /// Must be (re)written to the modem.
    ToSend,
    /// Written; waiting for the command's reply.
    AwaitReply,
    /// Accepted; waiting for the delivery report.
    AwaitReport,
    /// The modem was busy; re-send at the deadline.
    BusyWait,
    /// Accepted without acknowledgement; on air until the deadline, then reported sent.
    OnAir,
}

/// The background task: connect, serve jobs one at a time, reconnect on failure. Ends when
/// the handle is dropped.
async fn run<W: Wire + Default>(
    cfg: DriverConfig,
    expect_reports: bool,
    mut jobs: mpsc::Receiver<Job>,
    rx_tx: mpsc::Sender<RxFrame>,
    status: Arc<Status>,
) {
    let mut wire = W::default();
    let mut current: Option<(Job, Phase, Instant)> = None;
    let mut buf = vec![0u8; 4096];
    loop {
        let mut stream = match TcpStream::connect(cfg.addr).await {
            Ok(s) => s,
            Err(e) => {
                debug!(proto = W::NAME, addr = %cfg.addr, error = %e, "modem connect failed");
                if jobs.is_closed() {
                    return;
                }
                tokio::time::sleep(cfg.reconnect_delay).await;
                continue;
            }
        };
        // Commands and replies are short lines: never hold one back for Nagle.
        let _ = stream.set_nodelay(true);
        info!(proto = W::NAME, addr = %cfg.addr, "connected to modem");
        status.connected.store(true, Ordering::Relaxed);
        wire.reset();
        // Learn the local address first; one command at a time (docs/acoustic.md#at-interface).
        let mut hello_pending = stream.write_all(&wire.hello()).await.is_ok();
        let mut hello_deadline = Instant::now() + cfg.reply_timeout;
        if let Some((_, phase, _)) = current.as_mut() {
            // Reconnected with a frame in flight: its reply or report died with the
            // connection, so send it again (the caller's queue is kept).
            *phase = Phase::ToSend;
        }
        'conn: loop {
            if !hello_pending
                && let Some(((frame, _), phase, deadline)) = current.as_mut()
                && *phase == Phase::ToSend
            {
                if stream.write_all(&wire.send(frame)).await.is_err() {
                    break 'conn;
                }
                *phase = Phase::AwaitReply;
                *deadline = Instant::now() + cfg.reply_timeout;
            }
            let deadline = match (&current, hello_pending) {
                (_, true) => Some(hello_deadline),
                (Some((_, _, d)), false) => Some(*d),
                (None, false) => None,
            };
            let idle = current.is_none();
            tokio::select! {
                r = stream.read(&mut buf) => {
                    let n = match r {
                        Ok(0) | Err(_) => break 'conn,
                        Ok(n) => n,
                    };
                    wire.push(buf.get(..n).unwrap_or_default());
                    while let Some(ev) = wire.next() {
                        match ev {
                            WireEvent::Received(f) => {
                                if rx_tx.try_send(f).is_err() {
                                    warn!(proto = W::NAME, "receive queue full, frame dropped");
                                }
                            }
                            WireEvent::Address(a) => {
                                status.address.store(u16::from(a), Ordering::Relaxed);
                                hello_pending = false;
                            }
                            ev => handle_reply::<W>(ev, &mut current, &cfg, expect_reports, &mut hello_pending),
                        }
                    }
                }
                job = jobs.recv(), if idle => match job {
                    Some(job) => current = Some((job, Phase::ToSend, Instant::now())),
                    None => return,
                },
                () = sleep_until_opt(deadline) => {
                    if hello_pending {
                        // An old modem may not know the query: carry on without it.
                        hello_pending = false;
                        hello_deadline = Instant::now();
                        continue;
                    }
                    match current.as_ref().map(|c| c.1) {
                        Some(Phase::AwaitReply) => {
                            warn!(proto = W::NAME, "no reply from modem; reconnecting");
                            break 'conn;
                        }
                        Some(Phase::AwaitReport) => finish(&mut current, Ok(Outcome::Failed)),
                        Some(Phase::OnAir) => finish(&mut current, Ok(Outcome::Sent)),
                        Some(Phase::BusyWait) => {
                            if let Some(c) = current.as_mut() {
                                c.1 = Phase::ToSend;
                            }
                        }
                        _ => {}
                    }
                }
            }
        }
        status.connected.store(false, Ordering::Relaxed);
        warn!(proto = W::NAME, addr = %cfg.addr, "modem connection lost; reconnecting");
        if jobs.is_closed() && current.is_none() {
            return;
        }
        tokio::time::sleep(cfg.reconnect_delay).await;
    }
}

async fn sleep_until_opt(deadline: Option<Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}

fn finish(current: &mut Option<(Job, Phase, Instant)>, result: Result<Outcome, TransmitError>) {
    if let Some(((_, reply), _, _)) = current.take() {
        // The caller may have given up waiting; that is fine.
        let _ = reply.send(result);
    }
}

/// Applies a reply or delivery report to the frame in flight.
fn handle_reply<W: Wire>(
    ev: WireEvent,
    current: &mut Option<(Job, Phase, Instant)>,
    cfg: &DriverConfig,
    expect_reports: bool,
    hello_pending: &mut bool,
) {
    let Some(((frame, _), phase, deadline)) = current.as_mut() else {
        if let WireEvent::Rejected(r) = ev {
            // E.g. the reply to a hello an old modem did not understand.
            *hello_pending = false;
            debug!(proto = W::NAME, reply = %r, "error reply with nothing in flight");
        }
        return;
    };
    let wants_report = expect_reports && frame.ack && frame.dst != crate::at::BROADCAST;
    match (ev, *phase) {
        (WireEvent::Accepted, Phase::AwaitReply) if wants_report => {
            *phase = Phase::AwaitReport;
            *deadline = Instant::now() + cfg.report_timeout;
        }
        (WireEvent::Accepted, Phase::AwaitReply) => {
            // Hand over one busy-poll interval before the frame ends, so the next frame is
            // at the modem when it frees up (the channel would idle otherwise), and no
            // earlier, so an alarm arriving meanwhile is not stuck behind another frame.
            *phase = Phase::OnAir;
            *deadline = Instant::now()
                + cfg
                    .air_time(frame.data.len())
                    .saturating_sub(cfg.busy_retry);
        }
        (WireEvent::Busy, Phase::AwaitReply) => {
            debug!(proto = W::NAME, "modem busy; will retry");
            *phase = Phase::BusyWait;
            *deadline = Instant::now() + cfg.busy_retry;
        }
        (WireEvent::Rejected(reason), Phase::AwaitReply) => {
            let frame = frame.clone();
            finish(current, Err(TransmitError::Rejected { frame, reason }));
        }
        (WireEvent::Delivered, Phase::AwaitReport) => finish(current, Ok(Outcome::Delivered)),
        (WireEvent::Failed, Phase::AwaitReport) => finish(current, Ok(Outcome::Failed)),
        (WireEvent::Canceled, Phase::AwaitReport | Phase::AwaitReply) => {
            finish(current, Ok(Outcome::Canceled));
        }
        (ev, p) => {
            debug!(proto = W::NAME, event = ?ev, phase = ?p, "unexpected modem event ignored");
        }
    }
}

/// Driver for an EvoLogics S2C modem's AT interface over TCP (docs/acoustic.md#at-interface).
#[derive(Debug)]
pub struct AtDriver {
    engine: Engine,
}

impl AtDriver {
    /// Starts the driver; it connects (and reconnects) in the background.
    pub fn start(cfg: DriverConfig) -> Self {
        Self {
            engine: Engine::start::<AtWire>(cfg, true),
        }
    }
}

impl ModemDriver for AtDriver {
    fn transmit(
        &self,
        frame: OutFrame,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send {
        self.engine.transmit(frame)
    }

    fn receive(&self) -> impl Future<Output = Option<RxFrame>> + Send {
        self.engine.receive()
    }

    fn local_address(&self) -> Option<u8> {
        self.engine.local_address()
    }

    fn is_connected(&self) -> bool {
        self.engine.is_connected()
    }
}

/// Driver for the EviNS network layer over TCP (docs/acoustic.md#nl-protocol).
#[derive(Debug)]
pub struct NlDriver {
    engine: Engine,
}

impl NlDriver {
    /// Starts the driver; `delivery_reports` says whether the NL protocol acknowledges
    /// (e.g. `staticrack`) so `NL,delivered`/`NL,failed` will follow each send.
    pub fn start(cfg: DriverConfig, delivery_reports: bool) -> Self {
        Self {
            engine: Engine::start::<NlWire>(cfg, delivery_reports),
        }
    }
}

impl ModemDriver for NlDriver {
    fn transmit(
        &self,
        frame: OutFrame,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send {
        self.engine.transmit(frame)
    }

    fn receive(&self) -> impl Future<Output = Option<RxFrame>> + Send {
        self.engine.receive()
    }

    fn local_address(&self) -> Option<u8> {
        self.engine.local_address()
    }

    fn is_connected(&self) -> bool {
        self.engine.is_connected()
    }
}
