//! The recorder's target (docs/recorder.md, "Targets"): recording 10,000 state vectors/s
//! costs at most 10 % of one core and 40 bytes per state vector on disk.
//!
//! A fleet of 100 vehicles reporting at 100 Hz each (10,000 state vectors/s) for 60 s of
//! data (600,000 state vectors), recorded through [`RecordWriter`] with the default
//! configuration, and measured:
//!
//! - **bytes on disk per state vector**: the size of the file once it is closed (header,
//!   schemas, chunks, summary, footer) over the state vectors in it;
//! - **CPU**: this thread's CPU time (user and system, as the scheduler accounts it in
//!   `/proc/thread-self/schedstat`, in ns) spent on the recorder's write path, i.e. the CDR
//!   encoding of each sample (the subscription tasks' part), the MCAP writer, zstd and the
//!   file writes, over the 60 s the data covers: percent of one core at 10,000 state
//!   vectors/s. The wall time of the same single-threaded loop is printed beside it (an
//!   upper bound: it also counts time other processes had the core). Not counted: DDS
//!   reception and decoding, and the queue between the subscriptions and the writer.
//!
//! The chunk is written out whenever a second of data has gone by since the last one
//! (what [`RecordWriter::tick`] does in real time), or when it is full.
//!
//! Then, on the first 10 s of the same data, what the levers give: zstd levels and chunk
//! sizes (configuration keys), MCAP-level variants the recorder does not use (written with
//! the mcap crate directly), the CDR payloads alone compressed without any MCAP around
//! them (a floor for any MCAP file of these payloads), and the same fleet with values
//! quantised at the source. Finally criterion times recording one second of the fleet
//! into a new file (wall time, opening and closing the file included).
//!
//! `CARGO_TARGET_DIR=... cargo bench -p shoal-recorder --bench record`

#![allow(clippy::panic)]

use std::collections::BTreeMap;
use std::hint::black_box;
use std::io::Cursor;
use std::path::Path;
use std::time::{Duration, Instant};

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use shoal_model::StateVector;
use shoal_recorder::{RecordWriter, RecorderConfig, Topic};

const VEHICLES: u32 = 100;
const RATE_HZ: u32 = 100;
const SECONDS: u32 = 60;
/// The data the levers are measured on, seconds.
const LEVER_SECONDS: u32 = 10;
/// State vectors per second of data.
const PER_SECOND: u32 = VEHICLES * RATE_HZ;

const TARGET_CPU_PCT: f64 = 10.0;
const TARGET_BYTES: f64 = 40.0;

/// One state vector as the recorder receives it.
struct Received {
    /// When the recorder received it, ns since the Unix epoch.
    log_ns: u64,
    /// The writer's DDS source timestamp (ms resolution), ns.
    publish_ns: u64,
    state: StateVector,
}

/// SplitMix64: repeatable noise without a dependency.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// Roughly normal, zero mean, unit variance (sum of three uniforms).
    fn noise(&mut self) -> f64 {
        (self.unit() + self.unit() + self.unit()) * 2.0 - 3.0
    }
}

/// One simulated vehicle's navigation state.
struct Vehicle {
    id: String,
    lat: f64,
    lon: f64,
    heading_deg: f64,
    turn_dps: f64,
    speed: f64,
    depth: f64,
    target_depth: f64,
    seabed: f64,
    battery: f64,
    phase: f64,
    clock_offset_ms: i64,
}

/// The fleet's state vectors of `seconds`, in the order the recorder receives them.
///
/// Each vehicle goes at 0.5 to 2.5 m/s on a slowly wandering heading (1 to 2.5 cm per
/// report), changes depth slowly, pitches and rolls a little; every value is a full
/// precision double with the small noise of a navigation filter, as vehicles report
/// them. `timestamp_ms` is the vehicle's clock (each vehicle on its own millisecond
/// phase); the DDS source timestamp is 0 or 1 ms later; the recorder receives each
/// sample 2 to 10 ms after its timestamp, so the vehicles' samples interleave
/// differently from one report to the next.
fn fleet(seconds: u32) -> Vec<Received> {
    let mut rng = Rng(0x5EED_0F5E_A5EA);
    let mut vehicles: Vec<Vehicle> = (0..VEHICLES)
        .map(|v| Vehicle {
            id: format!("auv-{v:03}"),
            lat: 63.40 + 0.1 * rng.unit(),
            lon: 10.30 + 0.2 * rng.unit(),
            heading_deg: 360.0 * rng.unit(),
            turn_dps: 0.0,
            speed: 1.2 + 0.6 * rng.unit(),
            depth: 5.0 + 50.0 * rng.unit(),
            target_depth: 5.0 + 50.0 * rng.unit(),
            seabed: 80.0 + 40.0 * rng.unit(),
            battery: 60.0 + 40.0 * rng.unit(),
            phase: std::f64::consts::TAU * rng.unit(),
            clock_offset_ms: i64::try_from(rng.next() % 10).unwrap_or(0),
        })
        .collect();
    let dt = 1.0 / f64::from(RATE_HZ);
    let period_ms = i64::from(1000 / RATE_HZ);
    let t0_ms: i64 = 1_780_000_000_000;
    let mut out = Vec::with_capacity(usize::try_from(PER_SECOND * seconds).unwrap_or(0));
    for k in 0..i64::from(RATE_HZ * seconds) {
        for v in &mut vehicles {
            v.turn_dps = (v.turn_dps + 0.05 * rng.noise()).clamp(-3.0, 3.0);
            v.heading_deg = (v.heading_deg + v.turn_dps * dt).rem_euclid(360.0);
            v.speed = (v.speed + 0.002 * rng.noise()).clamp(0.5, 2.5);
            let heading = v.heading_deg.to_radians();
            let north_m = v.speed * dt * heading.cos();
            let east_m = v.speed * dt * heading.sin();
            v.lat += north_m / 111_320.0 + 2e-8 * rng.noise();
            v.lon += east_m / (111_320.0 * v.lat.to_radians().cos()) + 4e-8 * rng.noise();
            v.depth += (v.target_depth - v.depth) * 0.05 * dt + 0.003 * rng.noise();
            v.seabed += 0.001 * rng.noise();
            // 20 % in 8 hours.
            v.battery -= 20.0 / (8.0 * 3600.0) * dt;
            v.phase += 0.7 * dt;
            let t_ms = t0_ms + k * period_ms + v.clock_offset_ms;
            let state = StateVector {
                vehicle_id: v.id.clone(),
                timestamp_ms: t_ms,
                latitude_deg: v.lat,
                longitude_deg: v.lon,
                depth_m: v.depth.max(0.0),
                altitude_m: (v.seabed - v.depth + 0.02 * rng.noise()).max(0.0),
                speed_mps: v.speed + 0.01 * rng.noise(),
                yaw_deg: (v.heading_deg + 0.05 * rng.noise()).rem_euclid(360.0),
                pitch_deg: 2.0 * v.phase.sin() + 0.05 * rng.noise(),
                roll_deg: 0.5 * (1.3 * v.phase).cos() + 0.05 * rng.noise(),
                battery_pct: v.battery,
            };
            let t_ns = u64::try_from(t_ms).unwrap_or(0) * 1_000_000;
            out.push(Received {
                log_ns: t_ns + 2_000_000 + rng.next() % 8_000_000,
                publish_ns: t_ns + (rng.next() % 2) * 1_000_000,
                state,
            });
        }
    }
    out.sort_by_key(|r| r.log_ns);
    out
}

/// The same state with its values rounded to binary fractions, as if vehicles published
/// them quantised: latitude and longitude to 2^-27 degrees (under a millimetre), depth,
/// altitude and speed to 2^-10 (about a millimetre, mm/s), angles and battery to 2^-8
/// (0.004). Such doubles end in zero bits, which compress.
fn quantised(s: &StateVector) -> StateVector {
    let q = |x: f64, bits: i32| (x * 2f64.powi(bits)).round() / 2f64.powi(bits);
    StateVector {
        latitude_deg: q(s.latitude_deg, 27),
        longitude_deg: q(s.longitude_deg, 27),
        depth_m: q(s.depth_m, 10),
        altitude_m: q(s.altitude_m, 10),
        speed_mps: q(s.speed_mps, 10),
        yaw_deg: q(s.yaw_deg, 8).rem_euclid(360.0),
        pitch_deg: q(s.pitch_deg, 8),
        roll_deg: q(s.roll_deg, 8),
        battery_pct: q(s.battery_pct, 8),
        ..s.clone()
    }
}

/// This thread's CPU time so far (user and system), ns: the first field of
/// `/proc/thread-self/schedstat` (Linux). None where there is no such file.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// What one recording cost.
struct Run {
    /// Bytes on disk once closed.
    bytes: u64,
    state_vectors: usize,
    cpu: Option<Duration>,
    wall: Duration,
}

impl Run {
    fn bytes_per_sv(&self) -> f64 {
        self.bytes as f64 / self.state_vectors as f64
    }
    /// Percent of one core, for data covering `seconds`.
    fn cpu_pct(&self, seconds: u32) -> Option<f64> {
        self.cpu
            .map(|c| c.as_secs_f64() / f64::from(seconds) * 100.0)
    }
    fn wall_pct(&self, seconds: u32) -> f64 {
        self.wall.as_secs_f64() / f64::from(seconds) * 100.0
    }
}

/// Records `states` into a new file in `dir` as the recorder's writer thread would, and
/// measures it. `quantise` records [`quantised`] states instead (the rounding is not
/// timed).
fn record(dir: &Path, config: &RecorderConfig, states: &[Received], quantise: bool) -> Run {
    let config = RecorderConfig {
        directory: dir.to_path_buf(),
        ..config.clone()
    };
    let quantised: Vec<StateVector> = if quantise {
        states.iter().map(|r| quantised(&r.state)).collect()
    } else {
        Vec::new()
    };
    let flush_ns = u64::try_from(shoal_recorder::FLUSH_INTERVAL.as_nanos()).unwrap_or(u64::MAX);
    let mut w = RecordWriter::new(&config).unwrap_or_else(|e| panic!("{e}"));
    let cpu0 = thread_cpu_ns();
    let wall0 = Instant::now();
    let mut last_flush_ns = states.first().map_or(0, |r| r.log_ns);
    let mut on_disk = w.stats().bytes;
    let mut unflushed = false;
    for (i, r) in states.iter().enumerate() {
        // tick(): the chunk goes to disk once a second has gone by since the last one.
        if unflushed && r.log_ns.saturating_sub(last_flush_ns) >= flush_ns {
            w.flush().unwrap_or_else(|e| panic!("{e}"));
            last_flush_ns = r.log_ns;
        }
        let state = if quantise { &quantised[i] } else { &r.state };
        let data = shoal_dds::to_cdr_le(state).unwrap_or_else(|e| panic!("{e}"));
        w.write(Topic::StateVector, r.log_ns, r.publish_ns, &data)
            .unwrap_or_else(|e| panic!("{e}"));
        unflushed = true;
        // A full chunk was written out by write() itself.
        let now = w.stats().bytes;
        if now != on_disk {
            on_disk = now;
            last_flush_ns = r.log_ns;
            unflushed = false;
        }
    }
    w.close().unwrap_or_else(|e| panic!("{e}"));
    let wall = wall0.elapsed();
    let cpu = thread_cpu_ns()
        .zip(cpu0)
        .map(|(end, start)| Duration::from_nanos(end.saturating_sub(start)));
    let bytes = w
        .files()
        .iter()
        .map(|p| std::fs::metadata(p).map_or(0, |m| m.len()))
        .sum();
    Run {
        bytes,
        state_vectors: states.len(),
        cpu,
        wall,
    }
}

/// MCAP-level variants the recorder does not use, written with the mcap crate directly
/// with the recorder's options (one channel, zstd, no message indexes, a chunk per
/// second of data).
#[derive(Clone, Copy, Default)]
struct Variant {
    /// Sequence 0 ("not set") instead of a counter per channel.
    sequence_zero: bool,
    /// `publish_time` set to `log_time` instead of the DDS source timestamp.
    publish_is_log: bool,
    /// Each chunk's messages grouped by vehicle (so out of `log_time` order).
    by_vehicle: bool,
}

/// Bytes per state vector of `states` written as `variant` at zstd `level`.
fn mcap_variant(states: &[Received], variant: Variant, level: u32) -> f64 {
    let mut file = Vec::new();
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(level)
        .compression_threads(0)
        .chunk_size(None)
        .disable_seeking(true)
        .emit_message_indexes(false)
        .create(Cursor::new(&mut file))
        .unwrap_or_else(|e| panic!("{e}"));
    let schema = w
        .add_schema(
            "shoal::StateVector",
            shoal_recorder::SCHEMA_ENCODING,
            shoal_recorder::SHOAL_IDL.as_bytes(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
    let channel = w
        .add_channel(
            schema,
            Topic::StateVector.name(),
            shoal_recorder::MESSAGE_ENCODING,
            &BTreeMap::new(),
        )
        .unwrap_or_else(|e| panic!("{e}"));
    let mut sequence = 0u32;
    for second in states.chunks(usize::try_from(PER_SECOND).unwrap_or(1)) {
        let mut order: Vec<&Received> = second.iter().collect();
        if variant.by_vehicle {
            order.sort_by(|a, b| a.state.vehicle_id.cmp(&b.state.vehicle_id));
        }
        for r in order {
            sequence += 1;
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: if variant.sequence_zero { 0 } else { sequence },
                log_time: r.log_ns,
                publish_time: if variant.publish_is_log {
                    r.log_ns
                } else {
                    r.publish_ns
                },
            };
            let data = shoal_dds::to_cdr_le(&r.state).unwrap_or_else(|e| panic!("{e}"));
            w.write_to_known_channel(&header, &data)
                .unwrap_or_else(|e| panic!("{e}"));
        }
        w.flush().unwrap_or_else(|e| panic!("{e}"));
    }
    w.finish().unwrap_or_else(|e| panic!("{e}"));
    drop(w);
    file.len() as f64 / states.len() as f64
}

/// The CDR payloads alone, each second's compressed as one zstd frame at `level`: no
/// MCAP records, no file around them. No MCAP file of these payloads at this level
/// comes out smaller.
fn payload_floor(states: &[Received], level: i32) -> f64 {
    let mut total = 0;
    for second in states.chunks(usize::try_from(PER_SECOND).unwrap_or(1)) {
        let mut block = Vec::new();
        for r in second {
            let data = shoal_dds::to_cdr_le(&r.state).unwrap_or_else(|e| panic!("{e}"));
            block.extend_from_slice(&data);
        }
        total += zstd::bulk::compress(&block, level)
            .unwrap_or_else(|e| panic!("{e}"))
            .len();
    }
    total as f64 / states.len() as f64
}

fn met(ok: bool) -> &'static str {
    if ok { "met" } else { "NOT MET" }
}

fn pct(p: Option<f64>) -> String {
    p.map_or_else(|| "n/a".into(), |p| format!("{p:.1} %"))
}

fn report(states: &[Received]) {
    let payload = shoal_dds::to_cdr_le(&states[0].state).map_or(0, |d| d.len());
    let default = RecorderConfig::default();
    println!(
        "\nrecorder target: {PER_SECOND} state vectors/s cost <= {TARGET_CPU_PCT} % of one core and <= {TARGET_BYTES} bytes per state vector on disk"
    );
    println!(
        "fleet: {VEHICLES} vehicles x {RATE_HZ} Hz, {SECONDS} s of data = {} state vectors (CDR payload {payload} bytes each)",
        states.len()
    );
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let run = record(dir.path(), &default, states, false);
    drop(dir);
    let cpu = run.cpu_pct(SECONDS);
    println!(
        "default configuration (zstd level {}, chunks of at most {} KiB, written at least every second):",
        default.compression_level,
        default.max_chunk_bytes / 1024
    );
    println!(
        "  on disk: {} bytes = {:.1} bytes per state vector          target <= {TARGET_BYTES}: {}",
        run.bytes,
        run.bytes_per_sv(),
        met(run.bytes_per_sv() <= TARGET_BYTES)
    );
    println!(
        "  CPU (this thread's CPU time, /proc/thread-self/schedstat): {} for {SECONDS} s of data = {} of one core   target <= {TARGET_CPU_PCT} %: {}",
        run.cpu
            .map_or_else(|| "n/a".into(), |c| format!("{:.2} s", c.as_secs_f64())),
        pct(cpu),
        cpu.map_or("not measured", |c| met(c <= TARGET_CPU_PCT))
    );
    println!(
        "  wall time of the same single-threaded loop (an upper bound): {:.2} s = {:.1} % of one core",
        run.wall.as_secs_f64(),
        run.wall_pct(SECONDS)
    );

    let lever_states = &states[..usize::try_from(PER_SECOND * LEVER_SECONDS).unwrap_or(0)];
    println!(
        "levers, on the first {LEVER_SECONDS} s ({} state vectors; each file also holds its schemas and summary, about 64 KiB):",
        lever_states.len()
    );
    println!("  compression_level  max_chunk_bytes  bytes/SV  CPU of one core");
    let mib = 1024 * 1024;
    for (level, chunk) in [
        (1, mib),
        (3, mib),
        (6, mib),
        (9, mib),
        (12, mib),
        (19, mib),
        (9, 4 * mib),
    ] {
        let config = RecorderConfig {
            compression_level: level,
            max_chunk_bytes: chunk,
            ..default.clone()
        };
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let run = record(dir.path(), &config, lever_states, false);
        println!(
            "  {level:>17}  {:>11} MiB  {:>8.1}  {:>8}",
            chunk / mib,
            run.bytes_per_sv(),
            pct(run.cpu_pct(LEVER_SECONDS))
        );
    }
    let level = default.compression_level;
    println!(
        "  MCAP variants the recorder does not use (mcap crate directly, zstd level {level}, a chunk per second):"
    );
    for (name, variant) in [
        ("as the recorder writes", Variant::default()),
        (
            "sequence 0 (MCAP: a recorder numbers what the publisher did not)",
            Variant {
                sequence_zero: true,
                ..Variant::default()
            },
        ),
        (
            "publish_time = log_time (the DDS source timestamp lost)",
            Variant {
                publish_is_log: true,
                ..Variant::default()
            },
        ),
        (
            "messages grouped by vehicle in each chunk (out of log_time order)",
            Variant {
                by_vehicle: true,
                ..Variant::default()
            },
        ),
    ] {
        println!(
            "    {:.1} bytes/SV  {name}",
            mcap_variant(lever_states, variant, level)
        );
    }
    for level in [i32::try_from(level).unwrap_or(9), 19] {
        println!(
            "  the CDR payloads alone, zstd level {level} per second, no MCAP: {:.1} bytes/SV (a floor)",
            payload_floor(lever_states, level)
        );
    }
    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let run = record(dir.path(), &default, lever_states, true);
    println!(
        "  values quantised at the source (latitude, longitude 2^-27 deg; depth, altitude, speed 2^-10; angles, battery 2^-8), default configuration: {:.1} bytes/SV, {} of one core",
        run.bytes_per_sv(),
        pct(run.cpu_pct(LEVER_SECONDS))
    );
    println!();
}

fn bench(c: &mut Criterion) {
    let states = fleet(SECONDS);
    report(&states);

    println!(
        "criterion: one second of the fleet into a new file, its opening and closing (summary, fsync) included, wall time:"
    );
    let one_second = &states[..usize::try_from(PER_SECOND).unwrap_or(0)];
    let mut group = c.benchmark_group("recorder");
    group.throughput(Throughput::Elements(u64::from(PER_SECOND)));
    group.sample_size(20);
    group.bench_function("record_1s_of_100_vehicles_at_100_hz", |b| {
        b.iter(|| {
            let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
            black_box(record(
                dir.path(),
                &RecorderConfig::default(),
                one_second,
                false,
            ))
            .bytes
        });
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
