//! Frame authentication on the acoustic link: [`TaggedDriver`] wraps any [`ModemDriver`]
//! and seals every outgoing frame with a counter and a truncated HMAC-SHA256 tag
//! (`shoal_security::AcousticTagger`, per-vehicle keys, 32- or 64-bit tags), and opens
//! every incoming one, dropping frames that are forged, tampered with, replayed or from an
//! address without a key. Refusals are counted by reason.
//!
//! The tag costs [`TaggedDriver::overhead`] bytes of every frame (8 or 12 of a 64-byte
//! instant message), so the link layer above must fill frames to
//! `MAX_FRAME - overhead`: [`TaggedDriver::frame_budget`].

use std::sync::{Arc, Mutex};

use shoal_security::{AcousticTagger, RejectionCounts};
use tracing::debug;

use crate::driver::{
    ModemDriver, OutFrame, Outcome, RxFrame, TransmitError, Withdrawal, transmit_wrapped,
};

/// A modem driver whose frames carry an authentication tag.
pub struct TaggedDriver<D> {
    inner: D,
    tagger: Mutex<AcousticTagger>,
    refused: Arc<Mutex<RejectionCounts>>,
}

impl<D> std::fmt::Debug for TaggedDriver<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TaggedDriver").finish_non_exhaustive()
    }
}

impl<D: ModemDriver> TaggedDriver<D> {
    /// Seals and opens `inner`'s frames with `tagger` (its keys set for every peer).
    pub fn new(inner: D, tagger: AcousticTagger) -> Self {
        Self {
            inner,
            tagger: Mutex::new(tagger),
            refused: Arc::new(Mutex::new(RejectionCounts::new())),
        }
    }

    /// Bytes the counter and tag add to each frame.
    pub fn overhead(&self) -> usize {
        self.tagger.lock().map(|t| t.overhead()).unwrap_or(0)
    }

    /// The largest content a frame of `max_frame` bytes can carry once tagged.
    pub fn frame_budget(&self, max_frame: usize) -> usize {
        max_frame.saturating_sub(self.overhead())
    }

    /// Received frames refused so far, by reason (shared: readable after the driver moved
    /// into the link task).
    pub fn refused(&self) -> Arc<Mutex<RejectionCounts>> {
        Arc::clone(&self.refused)
    }
}

impl<D: ModemDriver> TaggedDriver<D> {
    /// Seals `frame` and hands it to the inner driver, withdrawably when `withdrawal` is
    /// given.
    async fn send(
        &self,
        frame: OutFrame,
        withdrawal: Option<Withdrawal>,
    ) -> Result<Outcome, TransmitError> {
        let sealed = match self.tagger.lock() {
            Ok(mut t) => t.seal(frame.dst, &frame.data).map_err(|e| e.to_string()),
            Err(_) => Err("tagger lock poisoned".to_string()),
        };
        let data = match sealed {
            Ok(d) => d,
            Err(reason) => return Err(TransmitError::Rejected { frame, reason }),
        };
        let tagged = OutFrame {
            data,
            ..frame.clone()
        };
        // On failure (or withdrawal) hand back the frame as the caller gave it: a retry is
        // sealed again with a fresh counter, so the receiver's replay window accepts it.
        transmit_wrapped(&self.inner, tagged, withdrawal, frame).await
    }
}

impl<D: ModemDriver> ModemDriver for TaggedDriver<D> {
    async fn transmit(&self, frame: OutFrame) -> Result<Outcome, TransmitError> {
        self.send(frame, None).await
    }

    async fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> Result<Outcome, TransmitError> {
        self.send(frame, Some(withdrawal)).await
    }

    async fn receive(&self) -> Option<RxFrame> {
        loop {
            let f = self.inner.receive().await?;
            let opened = match self.tagger.lock() {
                Ok(mut t) => t
                    .open(f.src, f.dst, &f.data)
                    .map(<[u8]>::to_vec)
                    .map_err(Some),
                Err(_) => Err(None),
            };
            match opened {
                Ok(data) => return Some(RxFrame { data, ..f }),
                Err(Some(rejection)) => {
                    debug!(src = f.src, reason = %rejection.reason(), "acoustic frame refused");
                    if let Ok(mut c) = self.refused.lock() {
                        c.record(&rejection);
                    }
                }
                Err(None) => return None,
            }
        }
    }

    fn local_address(&self) -> Option<u8> {
        self.inner.local_address()
    }

    fn is_connected(&self) -> bool {
        self.inner.is_connected()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use shoal_security::{AcousticKey, TagSize};

    use super::*;

    /// A modem that gives every frame back once its withdrawal was asked for.
    struct Yielding;

    impl ModemDriver for Yielding {
        async fn transmit(&self, _frame: OutFrame) -> Result<Outcome, TransmitError> {
            Ok(Outcome::Sent)
        }

        async fn transmit_withdrawable(
            &self,
            frame: OutFrame,
            withdrawal: Withdrawal,
        ) -> Result<Outcome, TransmitError> {
            if withdrawal.is_requested() {
                Err(TransmitError::Withdrawn { frame })
            } else {
                Ok(Outcome::Sent)
            }
        }

        async fn receive(&self) -> Option<RxFrame> {
            None
        }

        fn local_address(&self) -> Option<u8> {
            Some(1)
        }

        fn is_connected(&self) -> bool {
            true
        }
    }

    #[tokio::test]
    async fn a_withdrawn_frame_comes_back_as_the_caller_gave_it_not_sealed() {
        let mut tagger = AcousticTagger::new(1, TagSize::Bits64, 1);
        tagger.set_key(2, &AcousticKey::from_bytes([7; 32]));
        let driver = TaggedDriver::new(Yielding, tagger);
        let frame = OutFrame {
            dst: 2,
            data: vec![1, 2, 3],
            ack: false,
            burst: false,
        };
        let w = Withdrawal::new();
        assert!(matches!(
            driver.transmit_withdrawable(frame.clone(), w.clone()).await,
            Ok(Outcome::Sent)
        ));
        w.request();
        match driver.transmit_withdrawable(frame.clone(), w).await {
            Err(TransmitError::Withdrawn { frame: back }) => assert_eq!(back, frame),
            other => panic!("not withdrawn: {other:?}"),
        }
    }
}
