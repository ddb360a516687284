//! A generated corpus of attacks on the acoustic receive path, interleaved with legitimate
//! traffic from the same senders, both ways and with both tag sizes. (IP links run OMG DDS
//! Security; their attack corpus is `tests/security/` at the top of the repository.)
//!
//! Every attack must be refused (and, where the attack determines it, for the expected
//! reason); every legitimate frame must be accepted. Refusals are counted per reason and
//! every reason must occur. The generator is seeded, so every run makes the same attacks;
//! the keys come from a fresh key store each run.

use std::collections::{BTreeMap, VecDeque};

use shoal_security::acoustic::{AcousticKey, AcousticTagger, TagSize};
use shoal_security::reject::{Rejection, RejectionCounts, RejectionReason};
use shoal_security::revocation::RevokeReason;
use shoal_security::store::{KeyStore, StoreError, StoreOptions};

/// The store's clock.
const T0: i64 = 1_790_000_000_000;
/// Corpus steps; two of three are attacks.
const STEPS: usize = 16_500;
const STATION_ADDR: u8 = 1;
const VEHICLES: [&str; 4] = ["auv-1", "auv-2", "auv-3", "asv-1"];
/// The acoustic address of a vehicle whose certificate and keys were revoked.
const REVOKED_ADDR: u8 = 20;
/// The corpus seed.
const SEED: u64 = 0x5eed_0005_4a0a_0001;

/// A seeded generator (the Rand project's SplitMix64, as the simulator uses), so the
/// corpus is the same on every run.
struct Rng(rand_xoshiro::SplitMix64);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(rand::SeedableRng::seed_from_u64(seed))
    }
    fn next(&mut self) -> u64 {
        rand::Rng::next_u64(&mut self.0)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn bytes(&mut self, n: usize) -> Vec<u8> {
        (0..n).map(|_| self.next() as u8).collect()
    }
    /// Flips `n` distinct bits of `buf` (the same bit twice would undo the tampering).
    fn flip_distinct_bits(&mut self, buf: &mut [u8], n: usize) {
        let mut bits = std::collections::BTreeSet::new();
        while bits.len() < n.min(buf.len() * 8) {
            bits.insert(self.below(buf.len() * 8));
        }
        for bit in bits {
            buf[bit / 8] ^= 1 << (bit % 8);
        }
    }
    /// An acoustic frame's content: 1 to 50 random bytes.
    fn frame(&mut self) -> Vec<u8> {
        let n = 1 + self.below(50);
        self.bytes(n)
    }
}

/// One side of the acoustic corpus: the station's tagger and each vehicle's, for one tag size.
struct AcousticSide {
    station: AcousticTagger,
    vehicles: Vec<(u8, AcousticTagger)>,
    /// The revoked vehicle, still holding its key.
    revoked: AcousticTagger,
    accepted: VecDeque<(u8, Vec<u8>)>,
}

impl AcousticSide {
    fn new(size: TagSize, keys: &[(u8, AcousticKey)], revoked_key: &AcousticKey) -> Self {
        let mut station = AcousticTagger::new(STATION_ADDR, size, 1_000);
        let mut vehicles = Vec::new();
        for (addr, key) in keys {
            station.set_key(*addr, key);
            let mut t = AcousticTagger::new(*addr, size, 10);
            t.set_key(STATION_ADDR, key);
            vehicles.push((*addr, t));
        }
        // The station knew it before the revocation; the CDT drops the key with it.
        station.set_key(REVOKED_ADDR, revoked_key);
        station.remove_key(REVOKED_ADDR);
        let mut revoked = AcousticTagger::new(REVOKED_ADDR, size, 10);
        revoked.set_key(STATION_ADDR, revoked_key);
        Self {
            station,
            vehicles,
            revoked,
            accepted: VecDeque::new(),
        }
    }
}

/// The outcome of the corpus.
#[derive(Default)]
struct Tally {
    attacks: usize,
    attack_counts: RejectionCounts,
    by_class: BTreeMap<&'static str, usize>,
    legit: usize,
    failures: Vec<String>,
}

impl Tally {
    fn attack(
        &mut self,
        class: &'static str,
        expected: Option<RejectionReason>,
        outcome: Result<(), Rejection>,
    ) {
        self.attacks += 1;
        *self.by_class.entry(class).or_default() += 1;
        match outcome {
            Ok(()) => self.failures.push(format!("attack {class} was accepted")),
            Err(r) => {
                self.attack_counts.record(&r);
                if let Some(want) = expected
                    && r.reason() != want
                {
                    self.failures.push(format!(
                        "attack {class}: expected {want}, got {} ({r})",
                        r.reason()
                    ));
                }
            }
        }
    }

    fn legit(&mut self, what: &str, outcome: Result<(), Rejection>) {
        self.legit += 1;
        if let Err(r) = outcome {
            self.failures
                .push(format!("legitimate {what} refused: {r}"));
        }
    }
}

#[test]
fn every_attack_is_refused_and_all_legitimate_traffic_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = KeyStore::init_with(
        &tmp.path().join("station"),
        "ccs",
        &StoreOptions::default(),
        Some(T0),
    )
    .unwrap();
    for v in VEHICLES {
        store.issue_vehicle(v).unwrap();
    }
    // A vehicle captured and revoked: its key leaves the store, and the station's tagger.
    store.issue_vehicle("stolen-1").unwrap();
    let stolen_key = store.acoustic_key("stolen-1").unwrap();
    store
        .revoke("stolen-1", RevokeReason::KeyCompromise)
        .unwrap();
    assert!(matches!(
        store.acoustic_key("stolen-1"),
        Err(StoreError::UnknownVehicle { .. })
    ));

    let keys: Vec<(u8, AcousticKey)> = VEHICLES
        .iter()
        .enumerate()
        .map(|(i, v)| (10 + i as u8, store.acoustic_key(v).unwrap()))
        .collect();
    let mut sides = [
        AcousticSide::new(TagSize::Bits32, &keys, &stolen_key),
        AcousticSide::new(TagSize::Bits64, &keys, &stolen_key),
    ];

    let mut rng = Rng::new(SEED);
    let mut tally = Tally::default();

    for step in 0..STEPS {
        if step % 3 != 0 {
            acoustic_attack(&mut rng, &mut sides, &mut tally);
            continue;
        }
        // Legitimate traffic: a frame up from a vehicle and one back down to it.
        let side = &mut sides[rng.below(2)];
        let v = rng.below(side.vehicles.len());
        let frame = rng.frame();
        let (addr, tagger) = &mut side.vehicles[v];
        let up = tagger.seal(STATION_ADDR, &frame).unwrap();
        let got = side
            .station
            .open(*addr, STATION_ADDR, &up)
            .map(<[u8]>::to_vec);
        tally.legit("acoustic uplink", got.clone().map(|_| ()));
        assert_eq!(got.ok().as_deref(), Some(&frame[..]));
        side.accepted.push_back((*addr, up));
        let down = side.station.seal(*addr, &frame).unwrap();
        tally.legit(
            "acoustic downlink",
            tagger.open(STATION_ADDR, *addr, &down).map(|_| ()),
        );
        while side.accepted.len() > 30 {
            side.accepted.pop_front();
        }
    }

    println!("attack classes:");
    for (class, n) in &tally.by_class {
        println!("  {class:<28} {n:>6}");
    }
    println!("attacks refused by reason:\n{}", tally.attack_counts);
    println!("legitimate frames accepted: {}", tally.legit);

    assert!(
        tally.failures.is_empty(),
        "{} failures, first: {:#?}",
        tally.failures.len(),
        &tally.failures[..tally.failures.len().min(10)]
    );
    assert!(tally.attacks >= 10_000, "only {} attacks", tally.attacks);
    assert_eq!(
        tally.attack_counts.total(),
        tally.attacks as u64,
        "100 % refused"
    );
    for reason in RejectionReason::ALL {
        assert!(
            tally.attack_counts.get(reason) > 0,
            "no attack was refused as {reason}"
        );
    }
    assert!(
        tally.legit > 5_000,
        "only {} legitimate frames",
        tally.legit
    );
}

use RejectionReason as R;

fn acoustic_attack(rng: &mut Rng, sides: &mut [AcousticSide; 2], tally: &mut Tally) {
    let side = &mut sides[rng.below(2)];
    let v = rng.below(side.vehicles.len());
    let frame = rng.frame();
    let overhead = side.station.overhead();
    let (addr, tagger) = &mut side.vehicles[v];
    let addr = *addr;
    let open = |station: &mut AcousticTagger, src: u8, dst: u8, bytes: &[u8]| {
        station.open(src, dst, bytes).map(|_| ())
    };
    match rng.below(9) {
        0 | 1 => {
            let mut sealed = tagger.seal(STATION_ADDR, &frame).unwrap();
            let n = 1 + rng.below(3);
            rng.flip_distinct_bits(&mut sealed, n);
            tally.attack(
                "acoustic bit flip",
                None,
                open(&mut side.station, addr, STATION_ADDR, &sealed),
            );
        }
        2 => {
            // Sealed with a key that is not the vehicle's.
            let mut thief = AcousticTagger::new(addr, side.station.tag_size(), 1 << 30);
            thief.set_key(STATION_ADDR, &AcousticKey::generate().unwrap());
            let sealed = thief.seal(STATION_ADDR, &frame).unwrap();
            tally.attack(
                "acoustic wrong key",
                Some(R::BadTag),
                open(&mut side.station, addr, STATION_ADDR, &sealed),
            );
        }
        3 => {
            if let Some((src, sealed)) = side
                .accepted
                .get(rng.below(side.accepted.len().max(1)))
                .cloned()
            {
                tally.attack(
                    "acoustic replay",
                    Some(R::Replayed),
                    open(&mut side.station, src, STATION_ADDR, &sealed),
                );
            } else {
                let sealed = rng.bytes(overhead - 1);
                tally.attack(
                    "acoustic truncated",
                    Some(R::FrameTooShort),
                    open(&mut side.station, addr, STATION_ADDR, &sealed),
                );
            }
        }
        4 => {
            // A fresh counter with a made-up tag.
            let mut sealed = frame.clone();
            sealed.extend_from_slice(&(u32::MAX - rng.below(1 << 20) as u32).to_be_bytes());
            sealed.extend_from_slice(&rng.bytes(overhead - 4));
            tally.attack(
                "acoustic forged tag",
                Some(R::BadTag),
                open(&mut side.station, addr, STATION_ADDR, &sealed),
            );
        }
        5 => {
            // A genuine frame re-presented as coming from another vehicle: a bad tag, or a
            // replay when that vehicle already used the counter (refused before the tag).
            let sealed = tagger.seal(STATION_ADDR, &frame).unwrap();
            let other = side.vehicles[(v + 1) % side.vehicles.len()].0;
            tally.attack(
                "acoustic spoofed source",
                None,
                open(&mut side.station, other, STATION_ADDR, &sealed),
            );
        }
        6 => {
            let sealed = tagger.seal(STATION_ADDR, &frame).unwrap();
            tally.attack(
                "acoustic unknown source",
                Some(R::NoKey),
                open(&mut side.station, 200, STATION_ADDR, &sealed),
            );
        }
        7 => {
            // The revoked vehicle, sealing correctly with the key it still holds.
            let sealed = side.revoked.seal(STATION_ADDR, &frame).unwrap();
            tally.attack(
                "acoustic revoked vehicle",
                Some(R::NoKey),
                open(&mut side.station, REVOKED_ADDR, STATION_ADDR, &sealed),
            );
        }
        _ => {
            let sealed = tagger.seal(STATION_ADDR, &frame).unwrap();
            let cut = rng.below(overhead);
            tally.attack(
                "acoustic truncated",
                Some(R::FrameTooShort),
                open(&mut side.station, addr, STATION_ADDR, &sealed[..cut]),
            );
        }
    }
}
