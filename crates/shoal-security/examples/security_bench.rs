//! Measures what acoustic-link security costs: HMAC tags sealed and opened per second, the
//! latency each adds per frame, and the bytes each adds per frame. (The cost of DDS Security
//! on IP links is measured by `shoal bench security`, beside the insecure bus.)
//!
//! Run with `cargo run --release -p shoal-security --example security_bench`; debug builds
//! are several times slower and say so in the output.

use std::hint::black_box;
use std::time::{Duration, Instant};

use shoal_security::acoustic::{self, AcousticKey, AcousticTagger, TagSize};

/// Wall time spent on each measurement.
const BUDGET: Duration = Duration::from_millis(1500);
/// A DCCL state vector is 20 bytes (docs/acoustic.md#dccl-comparison).
const DCCL_STATE_VECTOR: usize = 20;
/// The EvoLogics instant-message limit.
const IM_BYTES: usize = 64;
/// The instant-message bit rate.
const IM_BITRATE: f64 = 976.0;

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
