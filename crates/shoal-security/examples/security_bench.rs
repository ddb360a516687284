//! Measures what security costs: signatures and verifications per second on IP links, HMAC
//! tags per second on the acoustic link, the latency each adds per message, and the bytes
//! each adds per envelope and per acoustic frame.
//!
//! Run with `cargo run --release -p shoal-security --example security_bench`; debug builds
//! are several times slower and say so in the output.

use std::hint::black_box;
use std::time::{Duration, Instant};

use shoal_security::acoustic::{self, AcousticKey, AcousticTagger, TagSize};
use shoal_security::envelope::{self, Envelope};
use shoal_security::policy::Policy;
use shoal_security::store::KeyStore;
use shoal_security::verify::{Gate, VerifierConfig};

/// Wall time spent on each measurement.
const BUDGET: Duration = Duration::from_millis(1500);
/// A CDR-encoded state vector is about this long (string id, ten doubles, a timestamp).
const PAYLOAD_LEN: usize = 100;
/// A DCCL state vector is 20 bytes (docs/acoustic.md#dccl-comparison).
const DCCL_STATE_VECTOR: usize = 20;
/// The EvoLogics instant-message limit.
const IM_BYTES: usize = 64;
/// The instant-message bit rate.
const IM_BITRATE: f64 = 976.0;
const TOPIC: &str = "shoal/state_vector";

/// Runs `f` over pre-built inputs until the budget is spent; returns operations per second.
fn rate<T>(inputs: &[T], mut f: impl FnMut(&T)) -> f64 {
    let start = Instant::now();
    let mut n = 0usize;
    while start.elapsed() < BUDGET {
        for x in inputs {
            f(x);
        }
        n += inputs.len();
    }
    n as f64 / start.elapsed().as_secs_f64()
}

fn us(per_s: f64) -> f64 {
    1e6 / per_s
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let tmp = tempfile::tempdir()?;
    let now = shoal_model::now_ms();
    let mut store = KeyStore::init_with(
        &tmp.path().join("keys"),
        "ccs",
        &Default::default(),
        Some(now),
    )?;
    store.issue_vehicle("auv-1")?;
    let signer = store.vehicle_identity("auv-1")?;
    let payload = vec![0x5a_u8; PAYLOAD_LEN];

    println!(
        "shoal-security benchmark ({} build, {} CPUs)",
        if cfg!(debug_assertions) {
            "DEBUG"
        } else {
            "release"
        },
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!();
    println!("IP links: Ed25519-signed envelopes, {PAYLOAD_LEN}-byte payload on {TOPIC:?}");

    let counters: Vec<u64> = (1..=2_000).collect();
    let sign_rate = rate(&counters, |c| {
        black_box(signer.sign(TOPIC, &payload, now, *c).ok());
    });

    // Fresh envelopes for verification: each counter once per verifier.
    let full: Vec<Envelope> = (1..=20_000u64)
        .map(|c| signer.sign(TOPIC, &payload, now, c))
        .collect::<Result<_, _>>()?;
    let compact: Vec<Envelope> = full.iter().map(Envelope::to_compact).collect();
    let mut verify_full = 0.0;
    let mut verify_compact = 0.0;
    for (list, out) in [(&full, &mut verify_full), (&compact, &mut verify_compact)] {
        let mut v = store.verifier(VerifierConfig::default())?;
        let start = Instant::now();
        let mut n = 0usize;
        for env in list.iter() {
            v.verify(env, now).map_err(|e| e.to_string())?;
            n += 1;
            if start.elapsed() > BUDGET {
                break;
            }
        }
        *out = n as f64 / start.elapsed().as_secs_f64();
    }

    // The whole receive path: decode, verify, policy, counters.
    let wires: Vec<Vec<u8>> = compact.iter().map(Envelope::encode).collect();
    let mut gate = Gate::new(
        store.verifier(VerifierConfig::default())?,
        Policy::builtin(),
    );
    let start = Instant::now();
    let mut n = 0usize;
    for w in &wires {
        gate.admit(w, now, |_, _| Ok("auv-1".to_owned()))
            .map_err(|e| e.to_string())?;
        n += 1;
        if start.elapsed() > BUDGET {
            break;
        }
    }
    let gate_rate = n as f64 / start.elapsed().as_secs_f64();

    let full_overhead = full[0].encoded_len() - PAYLOAD_LEN;
    let compact_overhead = compact[0].encoded_len() - PAYLOAD_LEN;
    println!(
        "  signatures/s                  {sign_rate:>12.0}   ({:.1} µs each)",
        us(sign_rate)
    );
    println!(
        "  verifications/s (full cert)   {verify_full:>12.0}   ({:.1} µs each)",
        us(verify_full)
    );
    println!(
        "  verifications/s (compact)     {verify_compact:>12.0}   ({:.1} µs each)",
        us(verify_compact)
    );
    println!(
        "  gate admissions/s             {gate_rate:>12.0}   ({:.1} µs each: decode + verify + policy)",
        us(gate_rate)
    );
    println!(
        "  added latency per message     {:>12.1} µs (sign + admit)",
        us(sign_rate) + us(gate_rate)
    );
    println!(
        "  added bytes per message       {full_overhead:>12} (certificate embedded), {compact_overhead} (certificate id)"
    );
    println!(
        "    of which fixed              {:>12} (version, kind, lengths, time, counter, 64-byte signature) + topic",
        envelope::FIXED_OVERHEAD
    );

    println!();
    println!(
        "Acoustic link: truncated HMAC-SHA256, {DCCL_STATE_VECTOR}-byte frame (one DCCL state vector)"
    );
    let key = AcousticKey::generate()?;
    for size in [TagSize::Bits32, TagSize::Bits64] {
        let mut vehicle = AcousticTagger::new(7, size, 0);
        vehicle.set_key(1, &key);
        let frame = vec![0x33_u8; DCCL_STATE_VECTOR];
        let seal_rate = rate(&[()], |_| {
            black_box(vehicle.seal(1, &frame).ok());
        });
        let mut sender = AcousticTagger::new(7, size, 0);
        sender.set_key(1, &key);
        let sealed: Vec<Vec<u8>> = (0..200_000)
            .map(|_| sender.seal(1, &frame))
            .collect::<Result<_, _>>()?;
        let mut station = AcousticTagger::new(1, size, 0);
        station.set_key(7, &key);
        let start = Instant::now();
        let mut n = 0usize;
        for s in &sealed {
            station.open(7, 1, s).map_err(|e| e.to_string())?;
            n += 1;
            if start.elapsed() > BUDGET {
                break;
            }
        }
        let open_rate = n as f64 / start.elapsed().as_secs_f64();
        let overhead = size.overhead();
        let bits = size.tag_len() * 8;
        let airtime_ms = overhead as f64 * 8.0 / IM_BITRATE * 1000.0;
        println!("  {bits}-bit tag:");
        println!(
            "    tags/s                      {seal_rate:>12.0}   ({:.2} µs each)",
            us(seal_rate)
        );
        println!(
            "    tag verifications/s         {open_rate:>12.0}   ({:.2} µs each)",
            us(open_rate)
        );
        println!(
            "    added bytes per frame       {overhead:>12} (4-byte counter + {}-byte tag)",
            size.tag_len()
        );
        println!(
            "    added latency per frame     {:>12.2} µs CPU + {airtime_ms:.1} ms on air at {IM_BITRATE} bit/s",
            us(seal_rate) + us(open_rate)
        );
        println!(
            "    64-byte IM payload left     {:>12} bytes ({} DCCL state vectors instead of {})",
            IM_BYTES - overhead,
            (IM_BYTES - overhead) / DCCL_STATE_VECTOR,
            IM_BYTES / DCCL_STATE_VECTOR
        );
        println!(
            "    forgery: per attempt {:.1e}; in a day at 1 frame/s {:.1e}; in a year {:.1e}",
            size.forgery_probability(),
            size.forgery_probability() * 86_400.0,
            size.forgery_probability() * 31_557_600.0
        );
    }
    println!();
    println!(
        "constants: acoustic::OVERHEAD_32 = {}, acoustic::OVERHEAD_64 = {}",
        acoustic::OVERHEAD_32,
        acoustic::OVERHEAD_64
    );
    Ok(())
}
