//! The WAN encoding measured against the candidate it was chosen over, on a realistic
//! fleet: 500 vehicles in five operating areas, as one 5-second tick at 0.2 Hz sends
//! them. The figures printed here are those in `docs/federation.md`.
//!
//! Candidates, none carrying the vehicle id (the key expression does, in all of them):
//! - plain CDR (XCDR1, as Shoal's DDS topics go on the wire, 4-byte encapsulation
//!   header), one message per position, and zstd over a whole tick's batch;
//! - this crate's packed fixed-point frame, one per position, and zstd over a batch.

use rand::{RngExt as _, SeedableRng as _};
use rand_xoshiro::SplitMix64;
use serde::Serialize;
use shoal_federation::{VehiclePosition, wire};
use shoal_model::VehicleKind;

/// A position as a DDS topic would carry it: the same fields, doubles and an enum.
#[derive(Serialize)]
struct CdrPosition {
    kind: u32,
    timestamp_ms: i64,
    latitude_deg: f64,
    longitude_deg: f64,
    depth_m: f64,
    heading_deg: f64,
    speed_mps: f64,
    battery_pct: f64,
}

fn cdr(p: &VehiclePosition) -> Vec<u8> {
    let c = CdrPosition {
        kind: p.kind as u32,
        timestamp_ms: p.timestamp_ms,
        latitude_deg: p.latitude_deg,
        longitude_deg: p.longitude_deg,
        depth_m: p.depth_m,
        heading_deg: p.heading_deg,
        speed_mps: p.speed_mps,
        battery_pct: p.battery_pct,
    };
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    out.extend(cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&c).unwrap());
    out
}

/// 500 vehicles in five areas a few tens of km across, fixes within one 5 s tick.
fn fleet() -> Vec<VehiclePosition> {
    let mut rng = SplitMix64::seed_from_u64(22);
    let areas = [
        (43.05, 5.85),
        (42.3, 3.2),
        (47.6, -3.4),
        (36.7, -6.4),
        (54.1, 7.9),
    ];
    let kinds = [VehicleKind::Auv, VehicleKind::Usv, VehicleKind::Glider];
    (0..500)
        .map(|i| {
            let (lat0, lon0) = areas[i % areas.len()];
            let kind = kinds[i % kinds.len()];
            let depth = if kind == VehicleKind::Usv {
                0.0
            } else {
                rng.random::<f64>() * 300.0
            };
            VehiclePosition {
                vehicle_id: format!("v-{i:03}"),
                kind,
                timestamp_ms: 1_790_000_000_000 + (rng.random::<f64>() * 5000.0) as i64,
                latitude_deg: lat0 + (rng.random::<f64>() - 0.5) * 0.3,
                longitude_deg: lon0 + (rng.random::<f64>() - 0.5) * 0.4,
                depth_m: depth,
                heading_deg: rng.random::<f64>() * 360.0,
                speed_mps: 0.5 + rng.random::<f64>() * 2.0,
                battery_pct: 20.0 + rng.random::<f64>() * 80.0,
            }
        })
        .collect()
}

#[test]
fn the_packed_layout_is_smaller_than_cdr_with_or_without_zstd() {
    let fleet = fleet();
    let n = fleet.len();
    let cdr_frames: Vec<Vec<u8>> = fleet.iter().map(cdr).collect();
    let packed_frames: Vec<Vec<u8>> = fleet
        .iter()
        .map(|p| wire::encode_position(p).unwrap())
        .collect();
    let total = |frames: &[Vec<u8>]| frames.iter().map(Vec::len).sum::<usize>();
    let zstd_batch = |frames: &[Vec<u8>]| zstd::bulk::compress(&frames.concat(), 19).unwrap().len();
    let zstd_each = |frames: &[Vec<u8>]| {
        frames
            .iter()
            .map(|f| zstd::bulk::compress(f, 19).unwrap().len())
            .sum::<usize>()
    };

    let rows = [
        ("CDR, one message each", total(&cdr_frames)),
        ("CDR + zstd -19, each", zstd_each(&cdr_frames)),
        ("CDR + zstd -19, one batch", zstd_batch(&cdr_frames)),
        ("packed v1, one message each", total(&packed_frames)),
        (
            "packed v1 + zstd -19, one batch",
            zstd_batch(&packed_frames),
        ),
    ];
    println!("{n} positions (one 5 s tick at 0.2 Hz):");
    for (name, bytes) in rows {
        println!(
            "  {name:<34} {bytes:>6} B  {:>6.1} B/position",
            bytes as f64 / n as f64
        );
    }

    let packed = total(&packed_frames);
    assert_eq!(packed, n * wire::POSITION_LEN);
    assert!(packed * 2 < total(&cdr_frames));
    // Even compressed as one batch (which per-vehicle keys do not allow), CDR is larger.
    assert!(packed < zstd_batch(&cdr_frames));
}
