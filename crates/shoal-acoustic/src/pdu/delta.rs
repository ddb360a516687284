//! Keyframe + delta coding of State Vectors (docs/acoustic.md#compact-messages).
//!
//! The sender codes each state against the last keyframe the receiver *acknowledged*, so a
//! lost delta never corrupts later ones and a lost keyframe only costs keyframes until one
//! gets through. Keyframes carry a 4-bit sequence number that deltas name.
//!
//! A [predictive](DeltaEncoder::predictive) encoder also codes each state as residuals from
//! the keyframe's dead-reckoning prediction ([`PredictedDelta`], delta layout 2) and sends
//! whichever delta is smaller; the decoder reads both layouts.

use std::collections::HashMap;

use super::{DecodeError, EncodeError, Pdu, PredictedDelta, StateDelta, StateKeyframe};

/// Sender side: chooses keyframe or delta for each state of one vehicle.
#[derive(Debug, Clone)]
pub struct DeltaEncoder {
    /// The acknowledged keyframe and its serial (keyframes sent before it).
    acked: Option<(u64, StateKeyframe)>,
    pending: Vec<(u64, StateKeyframe)>,
    /// Keyframes sent so far; a keyframe's seq is its serial modulo 16.
    sent: u64,
    next_seq: u8,
    refresh_after_s: u32,
    last_was_keyframe: bool,
    predictive: bool,
}

impl Default for DeltaEncoder {
    fn default() -> Self {
        Self::new()
    }
}

impl DeltaEncoder {
    /// Keyframes still awaiting an ack that are remembered (older ones are forgotten).
    const MAX_PENDING: usize = 4;
    /// Delta size (bytes) from which a predictive encoder re-anchors with a keyframe.
    const REANCHOR_BYTES: usize = 8;
    /// Age (s) of the acknowledged keyframe before a large delta re-anchors: a younger
    /// one has just been acknowledged, and a keyframe would cost more than it saves.
    const REANCHOR_AFTER_S: u32 = 10;

    /// An encoder with no acknowledged keyframe yet; refreshes the keyframe after 90 s.
    pub fn new() -> Self {
        Self {
            acked: None,
            pending: Vec::new(),
            sent: 0,
            next_seq: 0,
            refresh_after_s: 90,
            last_was_keyframe: false,
            predictive: false,
        }
    }

    /// An encoder that also sends predicted deltas (layout 2, message id
    /// [`super::id::PREDICTED_DELTA`]) when they are smaller than layout-1 deltas. Only for
    /// receivers whose [`DeltaDecoder`] is given them: a build that predates layout 2
    /// refuses them as an unknown message.
    pub fn predictive() -> Self {
        Self {
            predictive: true,
            ..Self::new()
        }
    }

    /// Changes how old (seconds) the acknowledged keyframe may get before a fresh keyframe
    /// is sent proactively (deltas reach at most 127 s).
    pub fn with_refresh_after(mut self, seconds: u32) -> Self {
        self.refresh_after_s = seconds;
        self
    }

    /// The PDU to send for `state`: a delta when the last acknowledged keyframe is close
    /// enough, a keyframe otherwise (or, every other message, when it is getting old).
    pub fn encode(&mut self, state: &StateKeyframe) -> Result<Pdu, EncodeError> {
        // Once 16 keyframes have followed the acknowledged one, the receiver may hold a
        // newer keyframe under the same 4-bit seq: a delta naming it would decode against
        // the wrong reference, so a keyframe goes instead.
        if let Some((serial, key)) = &self.acked
            && self.sent - serial <= 16
            && let Some((d, dt_s)) = self.smallest_delta(key, state)
        {
            // A predicted delta that has grown large (the vehicle turned or changed its dive
            // since the keyframe) is cheaper re-anchored: one keyframe, then small deltas.
            let grown = self.predictive
                && dt_s >= Self::REANCHOR_AFTER_S
                && super::encode_sized(&d).is_ok_and(|e| e.bytes.len() >= Self::REANCHOR_BYTES);
            let stale = dt_s >= self.refresh_after_s || grown;
            if !stale || self.last_was_keyframe {
                self.last_was_keyframe = false;
                return Ok(d);
            }
        }
        let mut k = state.quantised()?;
        k.seq = self.next_seq;
        self.next_seq = (self.next_seq + 1) % 16;
        self.pending.push((self.sent, k.clone()));
        self.sent += 1;
        if self.pending.len() > Self::MAX_PENDING {
            self.pending.remove(0);
        }
        self.last_was_keyframe = true;
        Ok(Pdu::StateKeyframe(k))
    }

    /// The smaller of the layout-1 and (if predictive) layout-2 deltas from `key` to
    /// `state`, with its `dt_s`; the older layout on a tie, as more receivers read it.
    fn smallest_delta(&self, key: &StateKeyframe, state: &StateKeyframe) -> Option<(Pdu, u32)> {
        let old = StateDelta::between(key, state).map(|d| (d.dt_s, Pdu::StateDelta(d)));
        let new = self
            .predictive
            .then(|| PredictedDelta::between(key, state))
            .flatten()
            .map(|d| (d.dt_s, Pdu::PredictedDelta(d)));
        let size = |p: &Pdu| super::encode_sized(p).map_or(usize::MAX, |e| e.bytes.len());
        let best = match (old, new) {
            (Some(o), Some(n)) => Some(if size(&n.1) < size(&o.1) { n } else { o }),
            (o, n) => o.or(n),
        };
        best.map(|(dt, p)| (p, dt))
    }

    /// Records that the receiver got keyframe `seq`; returns false for an unknown seq.
    pub fn acknowledge(&mut self, seq: u8) -> bool {
        match self.pending.iter().position(|(_, k)| k.seq == seq) {
            Some(i) => {
                let (serial, k) = self.pending.remove(i);
                // Keyframes sent before the acknowledged one are now useless.
                self.pending
                    .retain(|(_, p)| p.seconds_of_day >= k.seconds_of_day);
                self.acked = Some((serial, k));
                true
            }
            None => false,
        }
    }

    /// The receiver reports that it does not hold keyframe `seq`, which a delta named (it
    /// restarted, or lost its keyframes): if that is the acknowledged reference, forget it
    /// so the next state goes as a keyframe. A report about an older reference is stale
    /// and changes nothing. Returns whether the reference was dropped.
    pub fn reference_unknown(&mut self, seq: u8) -> bool {
        if self.acked.as_ref().is_some_and(|(_, k)| k.seq == seq) {
            self.acked = None;
            self.last_was_keyframe = false;
            true
        } else {
            false
        }
    }

    /// The keyframe deltas are currently coded against, if any.
    pub fn reference(&self) -> Option<&StateKeyframe> {
        self.acked.as_ref().map(|(_, k)| k)
    }
}

/// Receiver side: remembers keyframes per vehicle and expands deltas.
#[derive(Debug, Clone, Default)]
pub struct DeltaDecoder {
    keys: HashMap<(u8, u8), StateKeyframe>,
}

impl DeltaDecoder {
    /// A decoder that has seen no keyframe.
    pub fn new() -> Self {
        Self::default()
    }

    /// The full state carried by a keyframe or delta PDU (either layout); `Ok(None)` for
    /// other PDUs. A delta whose keyframe this decoder does not hold is refused
    /// ([`DecodeError::UnknownKeyframe`]), never guessed at.
    pub fn decode(&mut self, pdu: &Pdu) -> Result<Option<StateKeyframe>, DecodeError> {
        match pdu {
            Pdu::StateKeyframe(k) => {
                self.keys.insert((k.vehicle, k.seq), k.clone());
                Ok(Some(k.clone()))
            }
            Pdu::StateDelta(d) => {
                let key = self.keys.get(&(d.vehicle, d.keyframe_seq)).ok_or(
                    DecodeError::UnknownKeyframe {
                        vehicle: d.vehicle,
                        seq: d.keyframe_seq,
                    },
                )?;
                Ok(Some(d.apply(key)))
            }
            Pdu::PredictedDelta(d) => {
                let key = self.keys.get(&(d.vehicle, d.keyframe_seq)).ok_or(
                    DecodeError::UnknownKeyframe {
                        vehicle: d.vehicle,
                        seq: d.keyframe_seq,
                    },
                )?;
                d.apply(key).map(Some)
            }
            _ => Ok(None),
        }
    }
}
