//! Authentication of acoustic modem frames with per-vehicle symmetric keys.
//!
//! Public-key signatures (64 bytes each) do not fit a 64-byte instant message, so frames on
//! the acoustic link carry a truncated HMAC-SHA256 tag instead, keyed with a 256-bit key
//! the station and one vehicle share. The sealed frame is
//!
//! ```text
//! +----------------------+-------------------+------------------------+
//! | frame (N bytes)      | counter (4, BE)   | tag (4 or 8 bytes)     |
//! +----------------------+-------------------+------------------------+
//! tag = HMAC-SHA256(key, "shoal-acoustic-v1" | src | dst | counter | frame)[..4 or 8]
//! ```
//!
//! `src` and `dst` are the modem addresses the modem reports (`RECVIM,...,<src>,<dst>,...`);
//! they are authenticated but not repeated in the frame, since the modem header carries
//! them already. The counter is the sender's, strictly increasing across everything it
//! sends; the receiver keeps a [`ReplayWindow`] per source address. The tag size is a
//! configuration both ends share, never a field of the frame, so an attacker cannot ask
//! for a shorter tag.
//!
//! Which key: a frame between the station and a vehicle uses that vehicle's key, looked up
//! by the *other* end's address (the destination when sending, the source when receiving).
//! A broadcast (destination 255) uses the key registered for [`BROADCAST`], a fleet key,
//! on both sides; without one, broadcasts are refused.

use std::collections::HashMap;
use std::fmt;
use std::path::Path;

use hmac::{Hmac, Mac};
use sha2::{Digest, Sha256};
use zeroize::Zeroizing;

use crate::files::{self, FileError, FileProblem};
use crate::reject::Rejection;
use crate::replay::ReplayWindow;
use crate::util::{self, RandomError};

/// The broadcast modem address (EvoLogics S2C: 255), and the key slot of the fleet key.
pub const BROADCAST: u8 = 255;
/// Bytes of the counter carried in each frame.
pub const COUNTER_LEN: usize = 4;
/// Bytes a frame grows by with a 32-bit tag: counter + tag.
pub const OVERHEAD_32: usize = COUNTER_LEN + 4;
/// Bytes a frame grows by with a 64-bit tag: counter + tag.
pub const OVERHEAD_64: usize = COUNTER_LEN + 8;
/// PEM label of an acoustic key file.
pub const KEY_PEM_LABEL: &str = "SHOAL ACOUSTIC KEY";
/// Domain-separation prefix of the MAC input, so these tags can never be valid elsewhere.
const DOMAIN: &[u8] = b"shoal-acoustic-v1";
/// The prefix of relay hop tags ([`AcousticTagger::for_relay_hops`]): a hop tag made with
/// the same key as an end-to-end tag can never pass for one, nor the reverse.
const HOP_DOMAIN: &[u8] = b"shoal-acoustic-hop-v1";
/// Start of the clock-based counter epoch: 2025-01-01T00:00:00Z in ms.
const COUNTER_EPOCH_MS: i64 = 1_735_689_600_000;
/// Counter values the clock advances per second (see [`counter_start_from_clock`]).
const COUNTER_TICKS_PER_S: i64 = 4;

/// How many bits of the HMAC a frame carries.
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum TagSize {
    /// 32-bit tags: forgery chance 2^-32 per attempt; for the slowest links.
    Bits32,
    /// 64-bit tags: forgery chance 2^-64 per attempt; the default.
    #[default]
    Bits64,
}

impl TagSize {
    /// Tag length in bytes.
    pub const fn tag_len(self) -> usize {
        match self {
            Self::Bits32 => 4,
            Self::Bits64 => 8,
        }
    }

    /// Bytes added to every frame: counter plus tag.
    pub const fn overhead(self) -> usize {
        COUNTER_LEN + self.tag_len()
    }

    /// Chance that one forged frame is accepted: 2^-bits.
    pub fn forgery_probability(self) -> f64 {
        match self {
            Self::Bits32 => 2f64.powi(-32),
            Self::Bits64 => 2f64.powi(-64),
        }
    }
}

/// A 256-bit symmetric key shared by the station and one vehicle; wiped when dropped.
#[derive(Clone)]
pub struct AcousticKey(Zeroizing<[u8; 32]>);

impl fmt::Debug for AcousticKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "AcousticKey(fingerprint {})", self.fingerprint())
    }
}

impl AcousticKey {
    /// A new key from the operating system's random source.
    pub fn generate() -> Result<Self, RandomError> {
        let mut key = Self(Zeroizing::new([0; 32]));
        util::random(key.0.as_mut())?;
        Ok(key)
    }

    /// A key from its 32 bytes.
    pub fn from_bytes(bytes: [u8; 32]) -> Self {
        Self(Zeroizing::new(bytes))
    }

    /// The first 8 bytes of SHA-256 of the key, in hex: safe to log, enough to tell keys apart.
    pub fn fingerprint(&self) -> String {
        hex::encode(&Sha256::digest(self.0.as_ref())[..8])
    }

    /// PEM text (`-----BEGIN SHOAL ACOUSTIC KEY-----`), wiped when dropped.
    pub fn to_pem(&self) -> Zeroizing<String> {
        Zeroizing::new(pem::encode(&pem::Pem::new(KEY_PEM_LABEL, self.0.to_vec())))
    }

    /// Loads a key file, refusing it when group/others can read it.
    pub fn load(path: &Path) -> Result<Self, FileError> {
        let text = files::read_secret(path)?;
        let block = files::parse_pem(path, &text, KEY_PEM_LABEL)?;
        let bytes = Zeroizing::new(block.into_contents());
        if bytes.len() != 32 {
            return Err(FileError::new(
                path,
                FileProblem::BadKey(format!(
                    "an acoustic key is 32 bytes, this one has {}",
                    bytes.len()
                )),
            ));
        }
        let mut key = Zeroizing::new([0u8; 32]);
        key.copy_from_slice(&bytes);
        Ok(Self(key))
    }
}

/// A counter start that survives restarts without storage: 4 ticks per second since
/// 2025-01-01, so a sender that restarts continues above anything it sent before as long as
/// its clock did not go back and it sent no more than 4 frames per second on average.
///
/// 32 bits of ticks last 34 years. A sender that can persist its counter should instead
/// start from the saved [`AcousticTagger::next_counter`] (or the larger of the two).
pub fn counter_start_from_clock(now_ms: i64) -> u32 {
    let ticks = now_ms.saturating_sub(COUNTER_EPOCH_MS).max(0) / 1000 * COUNTER_TICKS_PER_S;
    u32::try_from(ticks).unwrap_or(u32::MAX)
}

/// Why a frame could not be sealed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum SealError {
    /// No key for the destination (nor, for broadcasts, a fleet key).
    #[error("no acoustic key for address {0}")]
    NoKey(u8),
    /// The 32-bit counter is used up: rotate the key (which resets the counter).
    #[error("the frame counter is exhausted; rotate the acoustic key")]
    CounterExhausted,
}

struct Peer {
    /// HMAC already keyed: cloning it skips the key schedule on every frame.
    mac: Hmac<Sha256>,
    fingerprint: String,
}

/// Seals outgoing frames and opens incoming ones for one modem address.
pub struct AcousticTagger {
    local: u8,
    domain: &'static [u8],
    size: TagSize,
    next_counter: u64,
    window_size: u32,
    peers: HashMap<u8, Peer>,
    windows: HashMap<u8, ReplayWindow>,
}

impl fmt::Debug for AcousticTagger {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let keys: HashMap<u8, &str> = self
            .peers
            .iter()
            .map(|(a, p)| (*a, p.fingerprint.as_str()))
            .collect();
        f.debug_struct("AcousticTagger")
            .field("local", &self.local)
            .field("size", &self.size)
            .field("next_counter", &self.next_counter)
            .field("keys", &keys)
            .finish_non_exhaustive()
    }
}

impl AcousticTagger {
    /// A tagger for the modem at `local_address`, with tags of `size`, whose first sealed
    /// frame carries `counter_start` (see [`counter_start_from_clock`]).
    pub fn new(local_address: u8, size: TagSize, counter_start: u32) -> Self {
        Self {
            local: local_address,
            domain: DOMAIN,
            size,
            next_counter: u64::from(counter_start),
            window_size: ReplayWindow::DEFAULT_SIZE,
            peers: HashMap::new(),
            windows: HashMap::new(),
        }
    }

    /// A tagger for the hop-by-hop seal of relay envelopes (docs/acoustic.md#multi-hop-relays):
    /// the same frame layout and keys looked up the same way (the neighbour's address), but
    /// a MAC input of its own, so hop tags and end-to-end tags never stand in for each other.
    pub fn for_relay_hops(local_address: u8, size: TagSize, counter_start: u32) -> Self {
        Self {
            domain: HOP_DOMAIN,
            ..Self::new(local_address, size, counter_start)
        }
    }

    /// Sets the replay window per source address (default 64 frames).
    pub fn with_replay_window(mut self, size: u32) -> Self {
        self.window_size = size;
        self
    }

    /// Registers the key shared with the modem at `peer` ([`BROADCAST`]: the fleet key).
    ///
    /// Replacing a key (rotation) also forgets that peer's replay window: the new key
    /// comes with a new counter sequence.
    pub fn set_key(&mut self, peer: u8, key: &AcousticKey) {
        // HMAC accepts keys of any length, so this cannot fail for a 32-byte key.
        let Ok(mac) = <Hmac<Sha256> as Mac>::new_from_slice(key.0.as_ref()) else {
            return;
        };
        self.peers.insert(
            peer,
            Peer {
                mac,
                fingerprint: key.fingerprint(),
            },
        );
        self.windows.remove(&peer);
    }

    /// Forgets the key shared with `peer` (a revoked vehicle).
    pub fn remove_key(&mut self, peer: u8) {
        self.peers.remove(&peer);
        self.windows.remove(&peer);
    }

    /// The tag size in use.
    pub fn tag_size(&self) -> TagSize {
        self.size
    }

    /// Bytes each sealed frame adds.
    pub fn overhead(&self) -> usize {
        self.size.overhead()
    }

    /// The counter the next sealed frame will carry; persist it to resume after a restart.
    pub fn next_counter(&self) -> u64 {
        self.next_counter
    }

    fn tag(&self, mac: &Hmac<Sha256>, src: u8, dst: u8, counter: u32, frame: &[u8]) -> [u8; 32] {
        let mut mac = mac.clone();
        mac.update(self.domain);
        mac.update(&[src, dst]);
        mac.update(&counter.to_be_bytes());
        mac.update(frame);
        mac.finalize().into_bytes().into()
    }

    /// Appends the counter and tag to `frame`, for sending to `dst`.
    pub fn seal(&mut self, dst: u8, frame: &[u8]) -> Result<Vec<u8>, SealError> {
        let peer = self.peers.get(&dst).ok_or(SealError::NoKey(dst))?;
        let counter = u32::try_from(self.next_counter).map_err(|_| SealError::CounterExhausted)?;
        let tag = self.tag(&peer.mac, self.local, dst, counter, frame);
        let mut out = Vec::with_capacity(frame.len() + self.overhead());
        out.extend_from_slice(frame);
        out.extend_from_slice(&counter.to_be_bytes());
        out.extend_from_slice(&tag[..self.size.tag_len()]);
        self.next_counter += 1;
        Ok(out)
    }

    /// Checks a frame received from `src` for `dst` and returns its content without the
    /// counter and tag. The replay window moves only for authentic frames.
    pub fn open<'a>(&mut self, src: u8, dst: u8, sealed: &'a [u8]) -> Result<&'a [u8], Rejection> {
        let overhead = self.overhead();
        if sealed.len() < overhead {
            return Err(Rejection::FrameTooShort {
                len: sealed.len(),
                min: overhead,
            });
        }
        // Frames to everyone are keyed with the fleet key; others with the sender's.
        let slot = if dst == BROADCAST { BROADCAST } else { src };
        let peer = self
            .peers
            .get(&slot)
            .ok_or(Rejection::NoKey { address: slot })?;
        let (frame, trailer) = sealed.split_at(sealed.len() - overhead);
        let (counter_bytes, tag) = trailer.split_at(COUNTER_LEN);
        let mut cb = [0u8; COUNTER_LEN];
        cb.copy_from_slice(counter_bytes);
        let counter = u32::from_be_bytes(cb);
        // The window is checked first (cheap) and updated last (only for authentic frames).
        let window_size = self.window_size;
        let window = self
            .windows
            .entry(src)
            .or_insert_with(|| ReplayWindow::new(window_size));
        window
            .check(u64::from(counter))
            .map_err(Rejection::Replayed)?;
        let mut mac = peer.mac.clone();
        mac.update(self.domain);
        mac.update(&[src, dst]);
        mac.update(&cb);
        mac.update(frame);
        // Constant-time comparison of the leading bytes.
        mac.verify_truncated_left(tag)
            .map_err(|_| Rejection::BadTag)?;
        window
            .accept(u64::from(counter))
            .map_err(Rejection::Replayed)?;
        Ok(frame)
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    const STATION: u8 = 1;
    const AUV: u8 = 7;

    fn pair(size: TagSize) -> (AcousticTagger, AcousticTagger) {
        let key = AcousticKey::generate().unwrap();
        let mut station = AcousticTagger::new(STATION, size, 1000);
        station.set_key(AUV, &key);
        let mut auv = AcousticTagger::new(AUV, size, 5);
        auv.set_key(STATION, &key);
        (station, auv)
    }

    #[test]
    fn frames_cost_the_documented_bytes() {
        for size in [TagSize::Bits32, TagSize::Bits64] {
            let (mut station, _) = pair(size);
            let sealed = station.seal(AUV, &[0u8; 20]).unwrap();
            assert_eq!(sealed.len(), 20 + size.overhead());
        }
        assert_eq!(OVERHEAD_32, TagSize::Bits32.overhead());
        assert_eq!(OVERHEAD_64, TagSize::Bits64.overhead());
    }

    #[test]
    fn both_directions_work_and_replays_are_refused() {
        let (mut station, mut auv) = pair(TagSize::Bits64);
        let down = station.seal(AUV, b"task").unwrap();
        assert_eq!(auv.open(STATION, AUV, &down).unwrap(), b"task");
        assert!(matches!(
            auv.open(STATION, AUV, &down),
            Err(Rejection::Replayed(_))
        ));
        let up = auv.seal(STATION, b"state").unwrap();
        assert_eq!(station.open(AUV, STATION, &up).unwrap(), b"state");
    }

    #[test]
    fn hop_tags_and_end_to_end_tags_never_stand_in_for_each_other() {
        let key = AcousticKey::generate().unwrap();
        let hop = |local, peer| {
            let mut t = AcousticTagger::for_relay_hops(local, TagSize::Bits64, 1);
            t.set_key(peer, &key);
            t
        };
        let (mut station, mut auv) = pair(TagSize::Bits64);
        // The same key on both kinds of tagger (a USV's link key is also its own).
        station.set_key(AUV, &key);
        let (mut auv_hop, mut station_hop) = (hop(AUV, STATION), hop(STATION, AUV));
        let by_hop = auv_hop.seal(STATION, b"envelope").unwrap();
        assert!(matches!(
            station.open(AUV, STATION, &by_hop),
            Err(Rejection::BadTag)
        ));
        assert_eq!(
            station_hop.open(AUV, STATION, &by_hop).unwrap(),
            b"envelope"
        );
        auv.set_key(STATION, &key);
        let end_to_end = auv.seal(STATION, b"envelope").unwrap();
        assert!(matches!(
            station_hop.open(AUV, STATION, &end_to_end),
            Err(Rejection::BadTag)
        ));
    }

    #[test]
    fn addresses_are_authenticated() {
        let (mut station, mut auv) = pair(TagSize::Bits64);
        let down = station.seal(AUV, b"task").unwrap();
        // Same bytes presented as addressed to another vehicle, or from another source.
        assert_eq!(auv.open(STATION, 8, &down), Err(Rejection::BadTag));
        let mut other = AcousticTagger::new(AUV, TagSize::Bits64, 0);
        other.set_key(2, &AcousticKey::generate().unwrap());
        assert_eq!(other.open(2, AUV, &down), Err(Rejection::BadTag));
    }

    #[test]
    fn unknown_sources_short_frames_and_keyless_broadcasts_are_refused() {
        let (mut station, _) = pair(TagSize::Bits32);
        assert_eq!(
            station.open(9, STATION, &[0; 20]),
            Err(Rejection::NoKey { address: 9 })
        );
        assert!(matches!(
            station.open(AUV, STATION, &[0; 7]),
            Err(Rejection::FrameTooShort { len: 7, min: 8 })
        ));
        assert_eq!(
            station.seal(BROADCAST, b"x"),
            Err(SealError::NoKey(BROADCAST))
        );
    }

    #[test]
    fn broadcasts_use_the_fleet_key() {
        let fleet = AcousticKey::generate().unwrap();
        let (mut station, mut auv) = pair(TagSize::Bits64);
        station.set_key(BROADCAST, &fleet);
        auv.set_key(BROADCAST, &fleet);
        let all = station.seal(BROADCAST, b"abort").unwrap();
        assert_eq!(auv.open(STATION, BROADCAST, &all).unwrap(), b"abort");
    }

    #[test]
    fn a_rejected_forgery_does_not_move_the_window() {
        let (mut station, mut auv) = pair(TagSize::Bits32);
        let good = station.seal(AUV, b"one").unwrap();
        // A forgery with a far-ahead counter must not push the window past `good`.
        let mut forged = b"one".to_vec();
        forged.extend_from_slice(&u32::MAX.to_be_bytes());
        forged.extend_from_slice(&[0; 4]);
        assert_eq!(auv.open(STATION, AUV, &forged), Err(Rejection::BadTag));
        assert_eq!(auv.open(STATION, AUV, &good).unwrap(), b"one");
    }

    #[test]
    fn counters_exhaust_instead_of_wrapping() {
        let (_, mut auv) = {
            let key = AcousticKey::generate().unwrap();
            let mut s = AcousticTagger::new(STATION, TagSize::Bits64, 0);
            s.set_key(AUV, &key);
            let mut a = AcousticTagger::new(AUV, TagSize::Bits64, u32::MAX);
            a.set_key(STATION, &key);
            (s, a)
        };
        auv.seal(STATION, b"last").unwrap();
        assert_eq!(auv.seal(STATION, b"x"), Err(SealError::CounterExhausted));
    }

    #[test]
    fn clock_counters_grow_with_time_and_saturate() {
        assert_eq!(counter_start_from_clock(0), 0);
        let a = counter_start_from_clock(COUNTER_EPOCH_MS + 10_000);
        assert_eq!(a, 40);
        assert_eq!(counter_start_from_clock(i64::MAX), u32::MAX);
    }

    #[test]
    fn keys_never_print_and_round_trip_through_pem_files() {
        let key = AcousticKey::from_bytes([7; 32]);
        assert!(!format!("{key:?}").contains("0707"));
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.key");
        files::write_secret(&p, key.to_pem().as_bytes()).unwrap();
        let back = AcousticKey::load(&p).unwrap();
        assert_eq!(back.fingerprint(), key.fingerprint());
        files::write_secret(
            &p,
            pem::encode(&pem::Pem::new(KEY_PEM_LABEL, vec![1; 16])).as_bytes(),
        )
        .unwrap();
        let err = AcousticKey::load(&p).unwrap_err();
        assert!(err.to_string().contains("32 bytes"), "{err}");
    }

    proptest! {
        /// Sealing then opening returns the frame; flipping any one bit of the sealed frame
        /// is refused.
        #[test]
        fn round_trip_and_every_bit_flip_is_caught(
            frame in prop::collection::vec(any::<u8>(), 0..64),
            bits64 in any::<bool>(),
            flip in any::<prop::sample::Index>(),
        ) {
            let size = if bits64 { TagSize::Bits64 } else { TagSize::Bits32 };
            let (mut station, mut auv) = pair(size);
            let sealed = station.seal(AUV, &frame).unwrap();
            let mut bad = sealed.clone();
            let bit = flip.index(bad.len() * 8);
            bad[bit / 8] ^= 1 << (bit % 8);
            prop_assert!(auv.open(STATION, AUV, &bad).is_err());
            prop_assert_eq!(auv.open(STATION, AUV, &sealed).unwrap(), &frame[..]);
        }
    }
}
