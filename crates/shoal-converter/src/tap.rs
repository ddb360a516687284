//! The frame tap: a copy of a CDT's acoustic traffic for whoever records it.
//!
//! A CDT given a [`FrameTap`] ([`crate::CdtConfig::tap`]) reports through it every PDU it
//! hands to the link layer, every frame the modem delivers to it and every fate the link
//! reports for a message (delivered, sent, expired, dropped), each stamped with the wall
//! clock. The tap is a bounded queue that never makes the CDT wait: when the reader is
//! behind and the queue is full, the record is dropped and counted ([`FrameTap::dropped`]).
//! `shoal-recorder` reads the other end ([`TapQueue`]) into MCAP files
//! (docs/recorder.md, "Acoustic frames").

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TryRecvError, TrySendError};
use std::time::Duration;

use shoal_acoustic::link::{Class, LinkEvent, MessageId};

/// What became of a message the link layer had, as its [`LinkEvent`] says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum MessageFate {
    /// The destination's modem acknowledged it.
    Delivered,
    /// Sent without asking for an acknowledgement.
    Sent,
    /// Its TTL ran out before it was delivered.
    Expired,
    /// The link dropped it (queue full, superseded, refused by the modem, too large).
    Dropped,
}

impl MessageFate {
    /// The message and its fate a link event reports; `None` for a received frame.
    pub fn of(event: &LinkEvent) -> Option<(MessageId, Self)> {
        match event {
            LinkEvent::Delivered(id) => Some((*id, Self::Delivered)),
            LinkEvent::Sent(id) => Some((*id, Self::Sent)),
            LinkEvent::Expired(id) => Some((*id, Self::Expired)),
            LinkEvent::Dropped(id) => Some((*id, Self::Dropped)),
            _ => None,
        }
    }

    /// Its lower-case name (`delivered`, `sent`, `expired`, `dropped`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Delivered => "delivered",
            Self::Sent => "sent",
            Self::Expired => "expired",
            Self::Dropped => "dropped",
        }
    }
}

/// One thing a CDT did on its acoustic link.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum TapEvent {
    /// A PDU handed to the link layer. The link packs it, with others for the same
    /// destination, into a modem frame when its turn comes; what became of it follows as
    /// a [`TapEvent::Fate`] with the same `message_id`.
    Sent {
        /// Destination address.
        dst: u8,
        /// Its link class.
        class: Class,
        /// The link's id for it.
        message_id: MessageId,
        /// The encoded PDU.
        bytes: Vec<u8>,
    },
    /// A frame the modem delivered (after the tag check and relay envelope, if any: the
    /// PDUs as their sender packed them).
    Received {
        /// Sender address.
        src: u8,
        /// Destination address.
        dst: u8,
        /// The frame.
        bytes: Vec<u8>,
        /// RSSI, dB, where the modem reports it.
        rssi: Option<i32>,
        /// Signal integrity, where the modem reports it.
        integrity: Option<u32>,
    },
    /// What became of a message.
    Fate {
        /// The link's id for it (as in its [`TapEvent::Sent`]).
        message_id: MessageId,
        /// What became of it.
        fate: MessageFate,
    },
}

/// A [`TapEvent`] with when and where it happened.
#[derive(Debug, Clone, PartialEq)]
pub struct TapRecord {
    /// When the CDT saw it, ns since the Unix epoch (wall clock).
    pub time_ns: u64,
    /// The CDT's own clock then, ms since the Unix epoch: a scenario run's simulated
    /// time, otherwise the wall clock.
    pub converter_ms: i64,
    /// The reporting CDT's acoustic address.
    pub local: u8,
    /// What happened.
    pub event: TapEvent,
}

impl TapRecord {
    /// `event` at the CDT with address `local`, stamped now.
    pub fn now(local: u8, converter_ms: i64, event: TapEvent) -> Self {
        let time_ns = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
        Self {
            time_ns,
            converter_ms,
            local,
            event,
        }
    }
}

/// The sending end of a frame tap: cheap to clone, never blocks.
#[derive(Clone)]
pub struct FrameTap {
    tx: SyncSender<TapRecord>,
    dropped: Arc<AtomicU64>,
}

impl std::fmt::Debug for FrameTap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameTap")
            .field("dropped", &self.dropped())
            .finish_non_exhaustive()
    }
}

/// Two taps are equal when they feed the same queue (configurations holding one compare).
impl PartialEq for FrameTap {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.dropped, &other.dropped)
    }
}

impl FrameTap {
    /// A tap whose queue holds at most `capacity` records (at least one), and its
    /// reading end.
    pub fn bounded(capacity: usize) -> (Self, TapQueue) {
        let (tx, rx) = std::sync::mpsc::sync_channel(capacity.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        (
            Self {
                tx,
                dropped: Arc::clone(&dropped),
            },
            TapQueue { rx, dropped },
        )
    }

    /// Queues `record`, or drops and counts it if the queue is full or its reader is gone:
    /// the converter never waits for a recorder.
    pub fn report(&self, record: TapRecord) {
        match self.tx.try_send(record) {
            Ok(()) => {}
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        }
    }

    /// Records dropped so far because the queue was full (or its reader had stopped).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

/// The reading end of a [`FrameTap`].
#[derive(Debug)]
pub struct TapQueue {
    rx: Receiver<TapRecord>,
    dropped: Arc<AtomicU64>,
}

impl TapQueue {
    /// The next record, waiting at most `timeout`; `Disconnected` once every tap is gone
    /// and the queue is empty.
    pub fn recv_timeout(&self, timeout: Duration) -> Result<TapRecord, RecvTimeoutError> {
        self.rx.recv_timeout(timeout)
    }

    /// The next record if one is queued.
    pub fn try_recv(&self) -> Result<TapRecord, TryRecvError> {
        self.rx.try_recv()
    }

    /// Records the taps dropped so far (the queue was full).
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    fn received(n: u8) -> TapRecord {
        TapRecord::now(
            1,
            0,
            TapEvent::Received {
                src: 2,
                dst: 1,
                bytes: vec![n],
                rssi: Some(-60),
                integrity: None,
            },
        )
    }

    #[test]
    fn a_full_queue_drops_and_counts_without_blocking() {
        let (tap, queue) = FrameTap::bounded(3);
        let started = std::time::Instant::now();
        for n in 0..10 {
            tap.report(received(n));
        }
        // try_send never waits; 10 reports take microseconds, not a reader's timeout.
        assert!(started.elapsed() < Duration::from_secs(1));
        assert_eq!((tap.dropped(), queue.dropped()), (7, 7));
        // The first three are kept, in order; the dropped ones were the newest.
        for n in 0..3 {
            let r = queue.try_recv().unwrap();
            assert!(matches!(r.event, TapEvent::Received { ref bytes, .. } if bytes == &[n]));
            assert!(r.time_ns > 1_700_000_000_000_000_000);
        }
        assert!(queue.try_recv().is_err());
        // Room again.
        tap.report(received(42));
        assert!(queue.try_recv().is_ok());
        assert_eq!(tap.dropped(), 7);
    }

    #[test]
    fn a_tap_without_a_reader_counts_its_records_as_dropped() {
        let (tap, queue) = FrameTap::bounded(8);
        let copy = tap.clone();
        assert_eq!(tap, copy);
        assert_ne!(tap, FrameTap::bounded(8).0);
        drop(queue);
        copy.report(received(1));
        assert_eq!(tap.dropped(), 1);
    }

    #[test]
    fn the_reader_sees_the_end_once_every_tap_is_gone() {
        let (tap, queue) = FrameTap::bounded(8);
        tap.report(received(1));
        drop(tap);
        assert!(queue.recv_timeout(Duration::from_millis(10)).is_ok());
        assert_eq!(
            queue.recv_timeout(Duration::from_millis(10)),
            Err(RecvTimeoutError::Disconnected)
        );
    }

    #[test]
    fn link_events_map_to_fates() {
        assert_eq!(
            MessageFate::of(&LinkEvent::Delivered(7)),
            Some((7, MessageFate::Delivered))
        );
        assert_eq!(
            MessageFate::of(&LinkEvent::Dropped(8)).map(|(_, f)| f.name()),
            Some("dropped")
        );
        let rx = LinkEvent::Received {
            src: 2,
            dst: 1,
            frame: vec![1],
            rssi: None,
            integrity: None,
        };
        assert_eq!(MessageFate::of(&rx), None);
    }
}
