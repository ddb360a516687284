//! Pieces the VDT and the CDT share: starting the link, scaling time, PDU helpers.

use std::time::Duration;

use futures::{Stream, StreamExt};
use shoal_acoustic::driver::ModemDriver;
use shoal_acoustic::link::{self, LinkEvent, LinkSender};
use shoal_acoustic::pdu::{self, Pdu};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;
use tracing::warn;

use crate::config::LinkSettings;
use crate::error::ConverterError;

/// Simulated seconds → wall-clock duration.
pub(crate) fn wall(sim_s: f64, time_scale: f64) -> Duration {
    Duration::from_secs_f64((sim_s * time_scale).max(0.0))
}

/// Starts the link layer over `driver`, with every duration scaled to wall-clock time.
pub(crate) fn start_link<D: ModemDriver + 'static>(
    driver: D,
    settings: &LinkSettings,
    time_scale: f64,
    shutdown: &CancellationToken,
) -> Result<(LinkSender, mpsc::Receiver<LinkEvent>), ConverterError> {
    let cfg = settings.link_config()?.scaled(time_scale);
    Ok(link::start(driver, cfg, shutdown.clone().cancelled_owned()))
}

/// Supersede keys: a newer queued message with the same key replaces the older one.
pub(crate) fn supersede_key(kind: u8, address: u8, extra: u32) -> u64 {
    (u64::from(kind) << 40) | (u64::from(address) << 32) | u64::from(extra)
}

/// Kinds of supersede keys.
pub(crate) mod key {
    pub(crate) const STATE: u8 = 1;
    pub(crate) const ANNOUNCEMENT: u8 = 2;
    pub(crate) const TASK_STATUS: u8 = 3;
    pub(crate) const ENVIRONMENT: u8 = 4;
    pub(crate) const KEYFRAME_ACK: u8 = 5;
    pub(crate) const KEYFRAME_MISSING: u8 = 6;
}

/// The encoded bytes of a PDU, or `None` (logged) if it does not encode.
pub(crate) fn encode(p: &Pdu) -> Option<Vec<u8>> {
    match pdu::encode(p) {
        Ok(b) => Some(b),
        Err(e) => {
            warn!(pdu = p.name(), error = %e, "PDU not encodable; not sent");
            None
        }
    }
}

/// The next item of an optional stream; pending forever when there is none, and the
/// stream is forgotten once it ends.
pub(crate) async fn next_opt<S: Stream + Unpin>(s: &mut Option<S>) -> Option<S::Item> {
    match s {
        Some(stream) => {
            let item = stream.next().await;
            if item.is_none() {
                *s = None;
            }
            item
        }
        None => std::future::pending().await,
    }
}

/// A small wrapping counter (task and event numbers, 0..=255).
#[derive(Debug, Default)]
pub(crate) struct Counter(u8);

impl Counter {
    pub(crate) fn next(&mut self) -> u8 {
        let n = self.0;
        self.0 = self.0.wrapping_add(1);
        n
    }
}
