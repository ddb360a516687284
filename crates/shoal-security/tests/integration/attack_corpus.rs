//! A generated corpus of attacks on the IP and acoustic receive paths, interleaved with
//! legitimate traffic from the same senders.
//!
//! Every attack must be refused (and, where the attack determines it, for the expected
//! reason); every legitimate message must be accepted. Refusals are counted per reason and
//! every reason must occur. The generator is seeded, so every run makes the same attacks;
//! keys are fresh each run, so which check catches a tampered certificate may vary.

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;

use shoal_model::{StateVector, Task, TaskAssignment};
use shoal_security::acoustic::{AcousticKey, AcousticTagger, TagSize};
use shoal_security::envelope::{Envelope, SigningIdentity};
use shoal_security::policy::{Policy, VehicleOwned};
use shoal_security::reject::{Rejection, RejectionCounts, RejectionReason};
use shoal_security::revocation::RevokeReason;
use shoal_security::store::{KeyStore, StoreOptions};
use shoal_security::verify::{Gate, VerifierConfig};

const DAY: i64 = 86_400_000;
/// The corpus's "now" at its start.
const T0: i64 = 1_790_000_000_000;
/// When the store (and its CA) was created: 400 days earlier, so a certificate issued then
/// has expired by T0.
const T_INIT: i64 = T0 - 400 * DAY;
/// Milliseconds between two corpus steps.
const STEP_MS: i64 = 20;
/// Corpus steps; two of three are attacks.
const STEPS: usize = 16_500;
const STATION_ADDR: u8 = 1;
const VEHICLES: [&str; 4] = ["auv-1", "auv-2", "auv-3", "asv-1"];
const SV_TOPIC: &str = "shoal/state_vector";
const TASK_TOPIC: &str = "shoal/task_assignment";
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

fn state_vector(vehicle: &str, now: i64) -> Vec<u8> {
    let sv = StateVector {
        vehicle_id: vehicle.to_owned(),
        timestamp_ms: now,
        latitude_deg: 43.36,
        longitude_deg: -8.41,
        depth_m: 12.5,
        altitude_m: 4.0,
        speed_mps: 1.2,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 87.0,
    };
    serde_json::to_vec(&sv).unwrap()
}

fn task(vehicle: &str, n: usize, now: i64) -> Vec<u8> {
    let t = TaskAssignment::new(format!("t-{n}"), "m-1", vehicle, now, &Task::Abort);
    serde_json::to_vec(&t).unwrap()
}

/// The instance key of a payload: what the DDS layer computes from the decoded sample.
fn instance_key(topic: &str, payload: &[u8]) -> Result<String, String> {
    match topic {
        SV_TOPIC => serde_json::from_slice::<StateVector>(payload)
            .map(|s| s.owner_vehicle().to_owned())
            .map_err(|e| e.to_string()),
        TASK_TOPIC => serde_json::from_slice::<TaskAssignment>(payload)
            .map(|t| t.owner_vehicle().to_owned())
            .map_err(|e| e.to_string()),
        other => Err(format!("no decoder for {other}")),
    }
}

/// An envelope's wire form with another certificate embedded (the documented layout),
/// signature and everything else unchanged: what an attacker can build from captures.
fn with_embedded_cert(env: &Envelope, cert: &[u8]) -> Vec<u8> {
    let mut out = vec![1, 0];
    out.extend_from_slice(&(cert.len() as u16).to_be_bytes());
    out.extend_from_slice(cert);
    out.push(env.topic().len() as u8);
    out.extend_from_slice(env.topic().as_bytes());
    out.extend_from_slice(&env.timestamp_ms().to_be_bytes());
    out.extend_from_slice(&env.counter().to_be_bytes());
    out.extend_from_slice(&(env.payload().len() as u32).to_be_bytes());
    out.extend_from_slice(env.payload());
    out.extend_from_slice(env.signature());
    out
}

struct Sender {
    signer: SigningIdentity,
    counter: u64,
}

impl Sender {
    fn new(signer: SigningIdentity) -> Self {
        Self { signer, counter: 1 }
    }
    fn sign(&mut self, topic: &str, payload: &[u8], ts: i64, compact: bool) -> Envelope {
        self.counter += 1;
        if compact {
            self.signer.sign_compact(topic, payload, ts, self.counter)
        } else {
            self.signer.sign(topic, payload, ts, self.counter)
        }
        .unwrap()
    }
}

/// One side of the acoustic corpus: the station's tagger and each vehicle's, for one tag size.
struct AcousticSide {
    station: AcousticTagger,
    vehicles: Vec<(u8, AcousticTagger)>,
    accepted: VecDeque<(u8, Vec<u8>)>,
}

impl AcousticSide {
    fn new(size: TagSize, keys: &[(u8, AcousticKey)]) -> Self {
        let mut station = AcousticTagger::new(STATION_ADDR, size, 1_000);
        let mut vehicles = Vec::new();
        for (addr, key) in keys {
            station.set_key(*addr, key);
            let mut t = AcousticTagger::new(*addr, size, 10);
            t.set_key(STATION_ADDR, key);
            vehicles.push((*addr, t));
        }
        Self {
            station,
            vehicles,
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

fn open_store(dir: &Path, now: i64) -> KeyStore {
    KeyStore::open_at(dir, now).unwrap()
}

#[test]
fn every_attack_is_refused_and_all_legitimate_traffic_accepted() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("station");
    KeyStore::init_with(&dir, "ccs", &StoreOptions::default(), Some(T_INIT)).unwrap();
    // Issued 400 days ago with a 365-day certificate: expired now.
    open_store(&dir, T_INIT).issue_vehicle("old-1").unwrap();
    // Issued 30 days from now: not valid yet.
    open_store(&dir, T0 + 30 * DAY)
        .issue_vehicle("future-1")
        .unwrap();
    let mut store = open_store(&dir, T0);
    // The station certificate issued with the store has expired too: renew it.
    store.renew_station().unwrap();
    for v in VEHICLES {
        store.issue_vehicle(v).unwrap();
    }
    store.issue_vehicle("stolen-1").unwrap();
    let mut old = Sender::new(store.vehicle_identity("old-1").unwrap());
    let mut future = Sender::new(store.vehicle_identity("future-1").unwrap());
    let mut stolen = Sender::new(store.vehicle_identity("stolen-1").unwrap());
    store
        .revoke("stolen-1", RevokeReason::KeyCompromise)
        .unwrap();
    let ca_not_after = store.trust_anchor().certificate().not_after_ms();

    // A rogue CA with the same station name and a vehicle of the same id.
    let rogue_dir = tmp.path().join("rogue");
    let mut rogue_store =
        KeyStore::init_with(&rogue_dir, "ccs", &StoreOptions::default(), Some(T0)).unwrap();
    rogue_store.issue_vehicle("auv-1").unwrap();
    let mut rogue = Sender::new(rogue_store.vehicle_identity("auv-1").unwrap());

    let mut station = Sender::new(store.station_identity().unwrap());
    let mut vehicles: Vec<Sender> = VEHICLES
        .iter()
        .map(|v| Sender::new(store.vehicle_identity(v).unwrap()))
        .collect();
    let vehicle_certs: Vec<Vec<u8>> = vehicles
        .iter()
        .map(|s| s.signer.certificate().der().to_vec())
        .collect();

    let mut gate = Gate::new(
        store.verifier(VerifierConfig::default()).unwrap(),
        Policy::builtin(),
    );

    let keys: Vec<(u8, AcousticKey)> = VEHICLES
        .iter()
        .enumerate()
        .map(|(i, v)| (10 + i as u8, store.acoustic_key(v).unwrap()))
        .collect();
    let mut sides = [
        AcousticSide::new(TagSize::Bits32, &keys),
        AcousticSide::new(TagSize::Bits64, &keys),
    ];

    let mut rng = Rng::new(SEED);
    let mut tally = Tally::default();
    let mut accepted: VecDeque<Vec<u8>> = VecDeque::new();
    let mut old_accepted: Vec<(i64, Vec<u8>)> = Vec::new();

    for step in 0..STEPS {
        let now = T0 + step as i64 * STEP_MS;
        if step % 3 == 0 {
            // Legitimate traffic: a state vector, a task, or an acoustic frame each way.
            match rng.below(4) {
                0 | 1 => {
                    let k = rng.below(vehicles.len());
                    let id = VEHICLES[k];
                    let compact = rng.below(2) == 0;
                    let env = vehicles[k].sign(SV_TOPIC, &state_vector(id, now), now, compact);
                    let wire = env.encode();
                    tally.legit("state vector", admit(&mut gate, &wire, now + 40));
                    accepted.push_back(wire.clone());
                    if old_accepted.len() < 20 && step % 300 == 0 {
                        old_accepted.push((now, wire));
                    }
                }
                2 => {
                    let k = rng.below(VEHICLES.len());
                    let env = station.sign(TASK_TOPIC, &task(VEHICLES[k], step, now), now, false);
                    let wire = env.encode();
                    tally.legit("task", admit(&mut gate, &wire, now + 15));
                    accepted.push_back(wire);
                }
                _ => {
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
                }
            }
            while accepted.len() > 50 {
                accepted.pop_front();
            }
            for side in &mut sides {
                while side.accepted.len() > 30 {
                    side.accepted.pop_front();
                }
            }
            continue;
        }

        // An attack.
        let k = rng.below(vehicles.len());
        let id = VEHICLES[k];
        let sv = state_vector(id, now);
        match rng.below(24) {
            0 => {
                // Forged signature: random bytes where the signature goes.
                let mut wire = vehicles[k].sign(SV_TOPIC, &sv, now, false).encode();
                let n = wire.len();
                wire[n - 64..].copy_from_slice(&rng.bytes(64));
                tally.attack(
                    "forged signature",
                    Some(R::BadSignature),
                    admit(&mut gate, &wire, now),
                );
            }
            1 | 2 => {
                // One flipped bit in the payload.
                let env = vehicles[k].sign(SV_TOPIC, &sv, now, rng.below(2) == 0);
                let mut wire = env.encode();
                let start = wire.len() - 64 - env.payload().len();
                let bit = rng.below(env.payload().len() * 8);
                wire[start + bit / 8] ^= 1 << (bit % 8);
                tally.attack(
                    "payload bit flip",
                    Some(R::BadSignature),
                    admit(&mut gate, &wire, now),
                );
            }
            3 | 4 => {
                // One flipped bit in the header (version, credential, topic, time, counter).
                let env = vehicles[k].sign(SV_TOPIC, &sv, now, rng.below(2) == 0);
                let mut wire = env.encode();
                let header = wire.len() - 64 - env.payload().len();
                let bit = rng.below(header * 8);
                wire[bit / 8] ^= 1 << (bit % 8);
                tally.attack("header bit flip", None, admit(&mut gate, &wire, now));
            }
            5 => {
                // One flipped bit in the signature.
                let mut wire = vehicles[k].sign(SV_TOPIC, &sv, now, false).encode();
                let n = wire.len();
                let bit = rng.below(64 * 8);
                wire[n - 64 + bit / 8] ^= 1 << (bit % 8);
                tally.attack(
                    "signature bit flip",
                    Some(R::BadSignature),
                    admit(&mut gate, &wire, now),
                );
            }
            6 => {
                // Several flipped bits anywhere.
                let mut wire = vehicles[k].sign(SV_TOPIC, &sv, now, false).encode();
                let n = 1 + rng.below(8);
                rng.flip_distinct_bits(&mut wire, n);
                tally.attack("multi-bit tamper", None, admit(&mut gate, &wire, now));
            }
            7 | 8 => {
                // Replay of a recently accepted envelope.
                if let Some(wire) = accepted.get(rng.below(accepted.len().max(1))).cloned() {
                    tally.attack("replay", Some(R::Replayed), admit(&mut gate, &wire, now));
                } else {
                    let wire = vehicles[k]
                        .sign(SV_TOPIC, &sv, now - 60_000, false)
                        .encode();
                    tally.attack(
                        "stale timestamp",
                        Some(R::Stale),
                        admit(&mut gate, &wire, now),
                    );
                }
            }
            9 => {
                // Replay of an envelope captured long ago.
                let wire = match old_accepted.iter().find(|(ts, _)| now - ts > 31_000) {
                    Some((_, w)) => w.clone(),
                    None => vehicles[k]
                        .sign(SV_TOPIC, &sv, now - 31_000, false)
                        .encode(),
                };
                tally.attack(
                    "old capture replayed",
                    Some(R::Stale),
                    admit(&mut gate, &wire, now),
                );
            }
            10 => {
                // Signed with another vehicle's key, presented under this vehicle's certificate.
                let other = (k + 1) % vehicles.len();
                // A counter far ahead, so only the signature can give it away.
                let counter = u64::MAX - rng.next() % 1_000_000;
                let env = vehicles[other]
                    .signer
                    .sign(SV_TOPIC, &sv, now, counter)
                    .unwrap();
                let wire = with_embedded_cert(&env, &vehicle_certs[k]);
                tally.attack(
                    "wrong key",
                    Some(R::BadSignature),
                    admit(&mut gate, &wire, now),
                );
            }
            11 => {
                let wire = old
                    .sign(SV_TOPIC, &state_vector("old-1", now), now, false)
                    .encode();
                tally.attack(
                    "expired certificate",
                    Some(R::CertificateExpired),
                    admit(&mut gate, &wire, now),
                );
            }
            12 => {
                let wire = future
                    .sign(SV_TOPIC, &state_vector("future-1", now), now, false)
                    .encode();
                tally.attack(
                    "certificate not yet valid",
                    Some(R::CertificateNotYetValid),
                    admit(&mut gate, &wire, now),
                );
            }
            13 => {
                let wire = stolen
                    .sign(
                        SV_TOPIC,
                        &state_vector("stolen-1", now),
                        now,
                        rng.below(2) == 0,
                    )
                    .encode();
                tally.attack(
                    "revoked certificate",
                    Some(R::Revoked),
                    admit(&mut gate, &wire, now),
                );
            }
            14 => {
                let wire = rogue
                    .sign(SV_TOPIC, &state_vector("auv-1", now), now, false)
                    .encode();
                tally.attack(
                    "rogue CA",
                    Some(R::UntrustedCertificate),
                    admit(&mut gate, &wire, now),
                );
            }
            15 => {
                let wire = rogue
                    .sign(SV_TOPIC, &state_vector("auv-1", now), now, true)
                    .encode();
                tally.attack(
                    "unknown certificate id",
                    Some(R::UnknownCertificate),
                    admit(&mut gate, &wire, now),
                );
            }
            16 => {
                // A corrupted certificate: cut short, so it no longer parses.
                let env = vehicles[k].sign(SV_TOPIC, &sv, now, false);
                let cert = &vehicle_certs[k];
                let wire = with_embedded_cert(&env, &cert[..1 + rng.below(cert.len() - 1)]);
                tally.attack(
                    "corrupt certificate",
                    Some(R::BadCertificate),
                    admit(&mut gate, &wire, now),
                );
            }
            17 => {
                let late = now + 6_000 + rng.below(600_000) as i64;
                let wire = vehicles[k].sign(SV_TOPIC, &sv, late, false).encode();
                tally.attack(
                    "timestamp from the future",
                    Some(R::FromFuture),
                    admit(&mut gate, &wire, now),
                );
            }
            18 => {
                // A vehicle with a valid certificate reporting another vehicle's position.
                let victim = VEHICLES[(k + 1 + rng.below(VEHICLES.len() - 1)) % VEHICLES.len()];
                let wire = vehicles[k]
                    .sign(SV_TOPIC, &state_vector(victim, now), now, rng.below(2) == 0)
                    .encode();
                tally.attack(
                    "impersonation",
                    Some(R::WrongInstance),
                    admit(&mut gate, &wire, now),
                );
            }
            19 => {
                // A vehicle assigning a task (only the station may).
                let wire = vehicles[k]
                    .sign(TASK_TOPIC, &task(id, step, now), now, false)
                    .encode();
                tally.attack(
                    "task from a vehicle",
                    Some(R::TopicNotAllowed),
                    admit(&mut gate, &wire, now),
                );
            }
            20 => {
                let wire = vehicles[k]
                    .sign(SV_TOPIC, &rng.bytes(40), now, false)
                    .encode();
                tally.attack(
                    "undecodable payload",
                    Some(R::MalformedPayload),
                    admit(&mut gate, &wire, now),
                );
            }
            21 => {
                // Garbage, or a legitimate envelope cut short.
                let wire = if rng.below(2) == 0 {
                    {
                        let n = rng.below(300);
                        rng.bytes(n)
                    }
                } else {
                    let w = vehicles[k].sign(SV_TOPIC, &sv, now, false).encode();
                    w[..rng.below(w.len())].to_vec()
                };
                tally.attack(
                    "malformed bytes",
                    Some(R::Malformed),
                    admit(&mut gate, &wire, now),
                );
            }
            22 => {
                // Traffic after the CA expired: nothing verifies any more.
                let late = ca_not_after + DAY + rng.below(1000) as i64;
                let wire = vehicles[k].sign(SV_TOPIC, &sv, late, false).encode();
                tally.attack(
                    "after CA expiry",
                    Some(R::CaExpired),
                    admit(&mut gate, &wire, late),
                );
            }
            _ => acoustic_attack(&mut rng, &mut sides, &mut tally),
        }
        // The acoustic path gets its own share of attacks beyond the one slot above.
        if rng.below(2) == 0 {
            acoustic_attack(&mut rng, &mut sides, &mut tally);
        }
    }

    let gate_counts = gate.counts().clone();
    println!("attack classes:");
    for (class, n) in &tally.by_class {
        println!("  {class:<28} {n:>6}");
    }
    println!("attacks refused by reason:\n{}", tally.attack_counts);
    println!("legitimate messages accepted: {}", tally.legit);

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
    // The gate counted exactly the IP attacks: legitimate traffic added no rejection.
    let acoustic_attacks: usize = tally
        .by_class
        .iter()
        .filter(|(class, _)| class.starts_with("acoustic"))
        .map(|(_, n)| *n)
        .sum();
    assert_eq!(
        gate_counts.total(),
        (tally.attacks - acoustic_attacks) as u64
    );
    assert!(
        tally.legit > 5_000,
        "only {} legitimate messages",
        tally.legit
    );
}

use RejectionReason as R;

fn admit(gate: &mut Gate, wire: &[u8], now: i64) -> Result<(), Rejection> {
    gate.admit(wire, now, instance_key).map(|_| ())
}

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
    match rng.below(8) {
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
