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
//!
//! The next frame is handed over a little before the modem is free (`handover_lead`), so
//! the channel does not idle between frames, but the driver holds it until the frame on
//! air ends: until then the caller may take it back ([`ModemDriver::transmit_withdrawable`])
//! and send an emergency instead (docs/acoustic.md#channel-use-and-emergency-latency).

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU16, Ordering};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{Mutex, Notify, mpsc, oneshot};
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
    /// The caller withdrew the frame before the modem took it: it was never on air.
    #[error("frame withdrawn before the modem took it")]
    Withdrawn {
        /// The frame.
        frame: OutFrame,
    },
}

impl TransmitError {
    /// The same error carrying `frame` instead: a wrapping driver hands back the caller's
    /// frame, not what it made of it (sealed, enveloped), so a retry wraps it afresh.
    #[must_use]
    pub fn with_frame(self, frame: OutFrame) -> Self {
        match self {
            Self::Rejected { reason, .. } => Self::Rejected { frame, reason },
            Self::Withdrawn { .. } => Self::Withdrawn { frame },
            Self::Closed { .. } => Self::Closed { frame },
        }
    }
}

/// Hands `wrapped`, what a wrapping driver made of the caller's `frame`, to `inner`,
/// withdrawably when `withdrawal` is given; an error carries `frame` back (see
/// [`TransmitError::with_frame`]).
pub async fn transmit_wrapped<D: ModemDriver>(
    inner: &D,
    wrapped: OutFrame,
    withdrawal: Option<Withdrawal>,
    frame: OutFrame,
) -> Result<Outcome, TransmitError> {
    let sent = match withdrawal {
        Some(w) => inner.transmit_withdrawable(wrapped, w).await,
        None => inner.transmit(wrapped).await,
    };
    sent.map_err(|e| e.with_frame(frame))
}

/// A request to take back a frame handed to [`ModemDriver::transmit_withdrawable`]: shared
/// between the caller, who [`request`](Self::request)s it, and the driver, which honours it
/// only while the modem has not taken the frame (there is no abort of a frame on air).
#[derive(Debug, Clone, Default)]
pub struct Withdrawal(Arc<WithdrawalState>);

#[derive(Debug, Default)]
struct WithdrawalState {
    requested: AtomicBool,
    wake: Notify,
}

impl Withdrawal {
    /// A withdrawal not (yet) requested.
    pub fn new() -> Self {
        Self::default()
    }

    /// Asks for the frame back; the pending transmit then resolves to
    /// [`TransmitError::Withdrawn`], or to its usual outcome if the modem already took it.
    pub fn request(&self) {
        self.0.requested.store(true, Ordering::SeqCst);
        // One waiter (the driver task); a stored permit covers a request made while it is
        // not waiting.
        self.0.wake.notify_one();
    }

    /// Whether the frame has been asked back.
    pub fn is_requested(&self) -> bool {
        self.0.requested.load(Ordering::SeqCst)
    }

    /// Resolves once the frame has been asked back.
    async fn requested(&self) {
        while !self.is_requested() {
            self.0.wake.notified().await;
        }
    }
}

/// An acoustic modem as the link layer sees it.
pub trait ModemDriver: Send + Sync {
    /// Sends one frame and resolves when its fate is known. Only one call should be
    /// pending at a time; the modem does not queue.
    fn transmit(
        &self,
        frame: OutFrame,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send;
    /// [`Self::transmit`], except that the frame is handed back as
    /// [`TransmitError::Withdrawn`] if `withdrawal` is requested before the modem took it
    /// (the link layer does so to send an emergency first). The default never withdraws: a
    /// wrapping driver forwards this to its inner driver to keep the feature.
    fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send {
        drop(withdrawal);
        self.transmit(frame)
    }
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
    /// How long before an unacknowledged frame leaves the air it is reported sent, so the
    /// caller's next frame is already at the driver when the modem frees up. The driver
    /// holds that frame until then, withdrawable; with a caller that cannot withdraw, an
    /// alarm queued in this lead waits for one more frame, so it stays short.
    pub handover_lead: Duration,
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
    /// Defaults for a real-time link: reconnect after 1 s, retry busy after 0.5 s, hand
    /// over 20 ms before the modem frees up, 5 s for a reply, 60 s for a delivery report.
    pub fn new(addr: SocketAddr) -> Self {
        Self {
            addr,
            reconnect_delay: Duration::from_secs(1),
            busy_retry: Duration::from_millis(500),
            handover_lead: Duration::from_millis(20),
            reply_timeout: Duration::from_secs(5),
            report_timeout: Duration::from_secs(60),
            im_bit_rate: 976.0,
            air_overhead: Duration::from_millis(100),
        }
    }

    /// How long a frame of `len` bytes stays on air: the next frame is held until then,
    /// because the modem cannot take another one before (it does not queue:
    /// docs/acoustic.md#at-interface), and an unacknowledged frame is reported sent only
    /// `handover_lead` before then, so the link is still free to choose what goes next.
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
        self.handover_lead = s(self.handover_lead);
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

/// One frame handed to the background task.
#[derive(Debug)]
struct Job {
    frame: OutFrame,
    reply: oneshot::Sender<Result<Outcome, TransmitError>>,
    withdrawal: Option<Withdrawal>,
    /// Written and not yet answered: the modem may have taken it.
    unanswered: bool,
    /// The modem answered `OK` to it once (it went on air at least once).
    accepted: bool,
}

impl Job {
    /// The caller's withdrawal, while the modem cannot have taken the frame: never written,
    /// or answered `BUSY` every time (a write whose reply died with the connection may have
    /// gone on air, so it counts as taken).
    fn withdrawal_open(&self, phase: Phase) -> Option<&Withdrawal> {
        let untaken = matches!(phase, Phase::ToSend | Phase::Held | Phase::BusyWait)
            && !self.unanswered
            && !self.accepted;
        self.withdrawal.as_ref().filter(|_| untaken)
    }

    /// Whether the caller asked the frame back and the modem cannot have taken it.
    fn withdrawable(&self, phase: Phase) -> bool {
        self.withdrawal_open(phase)
            .is_some_and(Withdrawal::is_requested)
    }
}

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

    async fn transmit(
        &self,
        frame: OutFrame,
        withdrawal: Option<Withdrawal>,
    ) -> Result<Outcome, TransmitError> {
        let (tx, rx) = oneshot::channel();
        let job = Job {
            frame: frame.clone(),
            reply: tx,
            withdrawal,
            unanswered: false,
            accepted: false,
        };
        if let Err(mpsc::error::SendError(job)) = self.jobs.send(job).await {
            return Err(TransmitError::Closed { frame: job.frame });
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
    /// Handed over while the previous frame is still on air: held (and withdrawable) until
    /// the deadline, when the modem is free, instead of being answered `BUSY`.
    Held,
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
    // When the last frame the modem accepted leaves the air (counted from its `OK`, so a
    // little late rather than early).
    let mut free_at = Instant::now();
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
            if let Some((job, phase, _)) = current.as_ref()
                && job.withdrawable(*phase)
            {
                debug!(proto = W::NAME, "frame withdrawn before the modem took it");
                let frame = job.frame.clone();
                finish(&mut current, Err(TransmitError::Withdrawn { frame }));
            }
            if !hello_pending
                && let Some((job, phase, deadline)) = current.as_mut()
                && *phase == Phase::ToSend
            {
                if stream.write_all(&wire.send(&job.frame)).await.is_err() {
                    // It may have reached the modem: never withdraw it now.
                    job.unanswered = true;
                    break 'conn;
                }
                job.unanswered = true;
                *phase = Phase::AwaitReply;
                *deadline = Instant::now() + cfg.reply_timeout;
            }
            let deadline = match (&current, hello_pending) {
                (_, true) => Some(hello_deadline),
                (Some((_, _, d)), false) => Some(*d),
                (None, false) => None,
            };
            let idle = current.is_none();
            // Woken when the caller asks back a frame the modem has not taken yet.
            let withdrawal = current
                .as_ref()
                .and_then(|(j, p, _)| j.withdrawal_open(*p).cloned());
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
                            ev => handle_reply::<W>(ev, &mut current, &mut free_at, &cfg, expect_reports, &mut hello_pending),
                        }
                    }
                }
                job = jobs.recv(), if idle => match job {
                    Some(job) => {
                        // The modem does not queue and answers `BUSY` while on air: keep
                        // the frame here until it is free, where the caller can still
                        // take it back.
                        let now = Instant::now();
                        current = Some(if now < free_at {
                            (job, Phase::Held, free_at)
                        } else {
                            (job, Phase::ToSend, now)
                        });
                    }
                    None => return,
                },
                () = requested_opt(withdrawal.as_ref()) => {}
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
                        Some(Phase::BusyWait | Phase::Held) => {
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

async fn requested_opt(withdrawal: Option<&Withdrawal>) {
    match withdrawal {
        Some(w) => w.requested().await,
        None => std::future::pending().await,
    }
}

fn finish(current: &mut Option<(Job, Phase, Instant)>, result: Result<Outcome, TransmitError>) {
    if let Some((job, _, _)) = current.take() {
        // The caller may have given up waiting; that is fine.
        let _ = job.reply.send(result);
    }
}

/// Applies a reply or delivery report to the frame in flight.
fn handle_reply<W: Wire>(
    ev: WireEvent,
    current: &mut Option<(Job, Phase, Instant)>,
    free_at: &mut Instant,
    cfg: &DriverConfig,
    expect_reports: bool,
    hello_pending: &mut bool,
) {
    let Some((job, phase, deadline)) = current.as_mut() else {
        if let WireEvent::Rejected(r) = ev {
            // E.g. the reply to a hello an old modem did not understand.
            *hello_pending = false;
            debug!(proto = W::NAME, reply = %r, "error reply with nothing in flight");
        }
        return;
    };
    let frame = &job.frame;
    let wants_report = expect_reports && frame.ack && frame.dst != crate::at::BROADCAST;
    if *phase == Phase::AwaitReply
        && matches!(
            ev,
            WireEvent::Accepted | WireEvent::Busy | WireEvent::Rejected(_)
        )
    {
        job.unanswered = false;
    }
    match (ev, *phase) {
        (WireEvent::Accepted, Phase::AwaitReply) => {
            job.accepted = true;
            let air = cfg.air_time(frame.data.len());
            *free_at = Instant::now() + air;
            if wants_report {
                *phase = Phase::AwaitReport;
                *deadline = Instant::now() + cfg.report_timeout;
            } else {
                // Report it sent a short lead before it ends, so the caller's next frame
                // is here when the modem frees up; that frame is held until then, and the
                // caller may still swap it for an alarm (`Phase::Held`).
                *phase = Phase::OnAir;
                *deadline = *free_at - air.min(cfg.handover_lead);
            }
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
        self.engine.transmit(frame, None)
    }

    fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send {
        self.engine.transmit(frame, Some(withdrawal))
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
        self.engine.transmit(frame, None)
    }

    fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> impl Future<Output = Result<Outcome, TransmitError>> + Send {
        self.engine.transmit(frame, Some(withdrawal))
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

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use tokio::net::TcpListener;

    use super::*;
    use crate::at::{self, AtCommand, CommandParser};
    use crate::link::{self, Class, LinkConfig, Outgoing};

    /// An instant message the modem took, and when.
    type Taken = (Instant, Vec<u8>);

    /// A scripted S2C on 127.0.0.1: answers the address query; takes an instant message
    /// when nothing is on air (`OK`, then `DELIVEREDIM` at once if it asks for an ack) and
    /// answers `BUSY` while one is, for [`slow_modem`]'s air time. Reports every frame it
    /// took.
    async fn fake_s2c() -> (SocketAddr, mpsc::UnboundedReceiver<Taken>) {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = listener.local_addr().unwrap();
        let air = slow_modem(addr);
        let (taken_tx, taken) = mpsc::unbounded_channel();
        tokio::spawn(async move {
            let Ok((mut s, _)) = listener.accept().await else {
                return;
            };
            let mut parser = CommandParser::new();
            let mut on_air_until = Instant::now();
            let mut buf = [0u8; 1024];
            loop {
                for cmd in parser.by_ref() {
                    let mut out = Vec::new();
                    match cmd {
                        Ok(AtCommand::GetLocalAddress) => out = at::reply("AT?AL", b"1"),
                        Ok(AtCommand::SendIm { dst, ack, data }) => {
                            let now = Instant::now();
                            if now < on_air_until {
                                out = at::reply("AT*SENDIM", b"BUSY TRANSMITTING");
                            } else {
                                on_air_until = now + air.air_time(data.len());
                                let _ = taken_tx.send((now, data));
                                out.extend(at::reply("AT*SENDIM", b"OK"));
                                if ack {
                                    out.extend(at::notification(
                                        format!("DELIVEREDIM,{dst}").as_bytes(),
                                    ));
                                }
                            }
                        }
                        other => panic!("unexpected command {other:?}"),
                    }
                    if s.write_all(&out).await.is_err() {
                        return;
                    }
                }
                match s.read(&mut buf).await {
                    Ok(0) | Err(_) => return,
                    Ok(n) => parser.push(&buf[..n]),
                }
            }
        });
        (addr, taken)
    }

    /// A driver configuration whose 60-byte frame is 0.6 s on air (0.1 s + 480 bits at
    /// 960 bit/s), with the real-time defaults otherwise (`busy_retry` 0.5 s).
    fn slow_modem(addr: SocketAddr) -> DriverConfig {
        DriverConfig {
            im_bit_rate: 960.0,
            ..DriverConfig::new(addr)
        }
    }

    fn frame(data: &[u8], ack: bool) -> OutFrame {
        OutFrame {
            dst: 2,
            data: data.to_vec(),
            ack,
            burst: false,
        }
    }

    /// A frame handed over while another is on air is held, and withdrawn on request
    /// without the modem ever seeing it; one the modem took goes on to its usual outcome.
    #[tokio::test]
    async fn a_frame_is_withdrawn_only_while_the_modem_has_not_taken_it() {
        let (addr, mut taken) = fake_s2c().await;
        let cfg = DriverConfig {
            handover_lead: Duration::from_millis(400),
            ..slow_modem(addr)
        };
        let d = AtDriver::start(cfg);
        let a = frame(&[1; 60], false);
        assert_eq!(d.transmit(a.clone()).await.unwrap(), Outcome::Sent);
        let (t_a, got) = next_taken(&mut taken).await;
        assert_eq!(got, a.data);
        // A is still on air for about 0.4 s: B waits at the driver.
        let b = frame(&[2; 10], false);
        let w = Withdrawal::new();
        let pending = d.transmit_withdrawable(b.clone(), w.clone());
        let ask = async {
            tokio::time::sleep(Duration::from_millis(100)).await;
            w.request();
        };
        let (out, ()) = tokio::join!(pending, ask);
        match out {
            Err(TransmitError::Withdrawn { frame }) => assert_eq!(frame, b),
            other => panic!("{other:?}"),
        }
        // The next frame goes when A is off air; B never did.
        let c = frame(&[3; 10], false);
        let w = Withdrawal::new();
        let pending = d.transmit_withdrawable(c.clone(), w.clone());
        let ask = async {
            let (t_c, got) = next_taken(&mut taken).await;
            // Too late: the modem has it.
            w.request();
            (t_c, got)
        };
        let (out, (t_c, got)) = tokio::join!(pending, ask);
        assert_eq!(out.unwrap(), Outcome::Sent);
        assert_eq!(got, c.data);
        assert!(t_c >= t_a + cfg.air_time(60), "{:?}", t_c - t_a);
        assert!(taken.try_recv().is_err());
    }

    async fn next_taken(taken: &mut mpsc::UnboundedReceiver<Taken>) -> Taken {
        tokio::time::timeout(Duration::from_secs(10), taken.recv())
            .await
            .expect("the modem took no frame")
            .expect("fake modem gone")
    }

    /// Frames the modem takes until the first full one (the link may start with the first
    /// PDU alone, before the rest are queued); the last one is the full frame.
    async fn until_full(taken: &mut mpsc::UnboundedReceiver<Taken>) -> Vec<Taken> {
        let mut frames = vec![next_taken(taken).await];
        while frames.last().is_some_and(|(_, d)| d.len() < 60) {
            frames.push(next_taken(taken).await);
        }
        frames
    }

    /// A saturating link over a driver on the fake modem, and its sender.
    fn telemetry_link(cfg: DriverConfig) -> link::LinkSender {
        let mut link_cfg = LinkConfig::default();
        link_cfg.telemetry.max_len = 1000;
        // Its events are not needed: the fake modem reports what went on air.
        let (tx, _) = link::start(AtDriver::start(cfg), link_cfg, std::future::pending());
        tx
    }

    fn outgoing(class: Class, pdu: Vec<u8>) -> Outgoing {
        Outgoing {
            dst: 2,
            class,
            pdu,
            supersede_key: None,
        }
    }

    /// The driver handed the modem its next frame one busy-poll interval (0.5 s by
    /// default) before the frame on air ended, so an alarm queued then waited for one more
    /// telemetry frame (1.616 s against the 1.453 s bound in `shoal bench acoustic`).
    #[tokio::test]
    async fn an_alarm_queued_in_the_last_busy_poll_of_a_frame_goes_next() {
        let (addr, mut taken) = fake_s2c().await;
        let cfg = slow_modem(addr);
        let link = telemetry_link(cfg);
        for i in 1..=24u8 {
            link.send(outgoing(Class::Telemetry, vec![i; 10]))
                .await
                .unwrap();
        }
        let (t1, _) = until_full(&mut taken).await.pop().unwrap();
        // Inside the frame's last 0.5 s and well before its last 20 ms.
        tokio::time::sleep_until(t1 + Duration::from_millis(350)).await;
        let alarm = vec![0xee; 5];
        link.send(outgoing(Class::Emergency, alarm.clone()))
            .await
            .unwrap();
        let (t2, second) = next_taken(&mut taken).await;
        assert_eq!(
            second, alarm,
            "the alarm waited behind another telemetry frame"
        );
        // And it went as soon as the frame on air was over.
        let after = t2.duration_since(t1);
        assert!(
            after < cfg.air_time(60) + Duration::from_millis(150),
            "{after:?}"
        );
    }

    /// With a long hand-over lead the next telemetry frame is already at the driver when
    /// the alarm comes: it is withdrawn (the modem never had it), the alarm goes first, and
    /// every telemetry PDU still goes on air exactly once.
    #[tokio::test]
    async fn a_held_telemetry_frame_gives_way_to_an_alarm_and_nothing_is_lost_or_repeated() {
        let (addr, mut taken) = fake_s2c().await;
        let cfg = DriverConfig {
            handover_lead: Duration::from_millis(400),
            ..slow_modem(addr)
        };
        let link = telemetry_link(cfg);
        for i in 1..=24u8 {
            link.send(outgoing(Class::Telemetry, vec![i; 10]))
                .await
                .unwrap();
        }
        let before = until_full(&mut taken).await;
        let t1 = before.last().unwrap().0;
        // The next frame was handed over at 0.2 s and is held until 0.6 s.
        tokio::time::sleep_until(t1 + Duration::from_millis(350)).await;
        let alarm = vec![0xee; 5];
        link.send(outgoing(Class::Emergency, alarm.clone()))
            .await
            .unwrap();
        let (_, second) = next_taken(&mut taken).await;
        assert_eq!(second, alarm);
        let mut seen = std::collections::BTreeMap::<u8, usize>::new();
        let count = |seen: &mut std::collections::BTreeMap<u8, usize>, data: &[u8]| {
            for pdu in data.chunks(10) {
                *seen.entry(pdu[0]).or_default() += 1;
            }
        };
        for (_, data) in &before {
            count(&mut seen, data);
        }
        while seen.values().sum::<usize>() < 24 {
            count(&mut seen, &next_taken(&mut taken).await.1);
        }
        // Nothing more goes on air.
        let more = tokio::time::timeout(Duration::from_secs(1), taken.recv()).await;
        assert!(more.is_err(), "{more:?}");
        assert_eq!(seen.len(), 24, "{seen:?}");
        assert!(seen.values().all(|&n| n == 1), "{seen:?}");
    }
}
