//! `GET /api/acoustic`: the acoustic network as the console's map draws it (as Neptus
//! does): the range rings of the channel model around the relay's modem, and for every
//! vehicle heard acoustically the link its CDT reports — addresses, RSSI, integrity, when
//! it was last heard, frames heard, and where the relay's modem is.
//!
//! The rings are the distances at which a full link-layer frame
//! ([`shoal_acoustic::pdu::MAX_FRAME`] bytes, the link's default `max_frame`) sent as an
//! instant message at the emulator's default bit rate, at full source level, is lost with
//! a packet error rate of 10 %, 50 % and 90 % under [`ChannelModel::default`]: the channel
//! the emulated relay runs and docs/acoustic.md#packet-error-rate describes.

use std::sync::LazyLock;

use axum::Json;
use axum::extract::State;
use serde::Serialize;
use shoal_acoustic::channel::ChannelModel;
use shoal_acoustic::emulator::EmulatorConfig;
use shoal_model::{GeoPoint, LinkKind, LinkStatus};
use shoal_station::{StationHandle, VehicleView};

/// Packet error rates the range rings are drawn at.
const RING_PERS: [f64; 3] = [0.1, 0.5, 0.9];

/// Farthest distance searched for a ring, m: beyond it any modem is deaf.
const MAX_RANGE_M: f64 = 100_000.0;

/// What `GET /api/acoustic` answers.
#[derive(Debug, Serialize)]
pub(crate) struct AcousticDoc {
    /// The station's clock, ms since the Unix epoch: link ages are against it.
    now_ms: i64,
    /// Frame size the rings are computed for, bytes.
    frame_bytes: usize,
    /// Bit rate the rings are computed for, bit/s.
    bit_rate_bps: f64,
    /// Range rings of the relay's modem, nearest first.
    rings: &'static [Ring],
    /// One per vehicle heard acoustically, by vehicle id.
    links: Vec<LinkView>,
}

/// A range ring: where a frame's packet error rate reaches `per`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub(crate) struct Ring {
    /// Packet error rate, 0..1.
    per: f64,
    /// Distance from the modem, m.
    range_m: f64,
}

/// One vehicle's acoustic link.
#[derive(Debug, Serialize)]
struct LinkView {
    /// The link status as the CDT last reported it.
    #[serde(flatten)]
    status: LinkStatus,
    /// Station time since the vehicle was last heard, ms.
    age_ms: i64,
    /// Where the vehicle last reported itself (its modem is there).
    position: Option<GeoPoint>,
    /// Where the relay's modem is: on its carrier's last reported position if it rides on
    /// one the station knows, else the position its CDT reports.
    relay_position: Option<RelayPosition>,
}

/// Where the relay's modem is, and how that is known.
#[derive(Debug, Serialize)]
struct RelayPosition {
    latitude_deg: f64,
    longitude_deg: f64,
    /// `carrier` (its vehicle's last state) or `fixed` (the CDT's configured position).
    from: &'static str,
}

static RINGS: LazyLock<Vec<Ring>> = LazyLock::new(|| {
    let model = ChannelModel::default();
    RING_PERS
        .iter()
        .filter_map(|&per| {
            range_for_per(&model, frame_bits(), bit_rate(), per).map(|range_m| Ring {
                per,
                range_m: range_m.round(),
            })
        })
        .collect()
});

fn frame_bits() -> usize {
    shoal_acoustic::pdu::MAX_FRAME * 8
}

fn bit_rate() -> f64 {
    EmulatorConfig::default().im_bit_rate
}

/// The distance at which a `bits`-bit frame at `bit_rate` has packet error rate `target`,
/// m, by bisection (PER grows with distance); `None` if it is not reached within
/// [`MAX_RANGE_M`].
pub(crate) fn range_for_per(
    model: &ChannelModel,
    bits: usize,
    bit_rate: f64,
    target: f64,
) -> Option<f64> {
    let per = |d: f64| model.per(d, bits, bit_rate, 0.0);
    let (mut lo, mut hi) = (1.0, MAX_RANGE_M);
    if per(hi) < target {
        return None;
    }
    if per(lo) >= target {
        return Some(lo);
    }
    // 40 halvings of 100 km: well under a millimetre.
    for _ in 0..40 {
        let mid = f64::midpoint(lo, hi);
        if per(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Some(f64::midpoint(lo, hi))
}

fn link_view(
    v: VehicleView,
    carrier_at: impl Fn(&str) -> Option<GeoPoint>,
    now: i64,
) -> Option<LinkView> {
    let status = v.link_status.filter(|s| s.link == LinkKind::Acoustic)?;
    let carried = status
        .cdt_vehicle
        .as_deref()
        .and_then(&carrier_at)
        .map(|p| RelayPosition {
            latitude_deg: p.latitude_deg,
            longitude_deg: p.longitude_deg,
            from: "carrier",
        });
    let fixed = status.cdt_latitude_deg.zip(status.cdt_longitude_deg).map(
        |(latitude_deg, longitude_deg)| RelayPosition {
            latitude_deg,
            longitude_deg,
            from: "fixed",
        },
    );
    Some(LinkView {
        age_ms: now.saturating_sub(status.heard_ms).max(0),
        position: v.latest.map(|s| GeoPoint {
            latitude_deg: s.latitude_deg,
            longitude_deg: s.longitude_deg,
        }),
        relay_position: carried.or(fixed),
        status,
    })
}

/// The document for a fleet as the station sees it at `now`.
fn doc(fleet: Vec<VehicleView>, now: i64) -> AcousticDoc {
    let positions: std::collections::HashMap<String, GeoPoint> = fleet
        .iter()
        .filter_map(|v| {
            let s = v.latest.as_ref()?;
            Some((
                v.announcement.vehicle_id.clone(),
                GeoPoint {
                    latitude_deg: s.latitude_deg,
                    longitude_deg: s.longitude_deg,
                },
            ))
        })
        .collect();
    let mut links: Vec<LinkView> = fleet
        .into_iter()
        .filter_map(|v| link_view(v, |id| positions.get(id).copied(), now))
        .collect();
    links.sort_by(|a, b| a.status.vehicle_id.cmp(&b.status.vehicle_id));
    AcousticDoc {
        now_ms: now,
        frame_bytes: shoal_acoustic::pdu::MAX_FRAME,
        bit_rate_bps: bit_rate(),
        rings: RINGS.as_slice(),
        links,
    }
}

pub(crate) async fn acoustic(State(s): State<StationHandle>) -> Json<AcousticDoc> {
    // The station's clock, not the host's: link status is stamped with it (a scenario run's
    // simulated clock included).
    Json(doc(s.fleet(), s.now()))
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    #[test]
    fn the_rings_are_where_the_frames_per_crosses_each_level() {
        let model = ChannelModel::default();
        let rings = RINGS.as_slice();
        assert_eq!(rings.len(), 3, "{rings:?}");
        for pair in rings.windows(2) {
            assert!(pair[0].range_m < pair[1].range_m, "{rings:?}");
        }
        for r in rings {
            let p = model.per(r.range_m, frame_bits(), bit_rate(), 0.0);
            assert!((p - r.per).abs() < 0.005, "{r:?}: PER {p}");
        }
        // docs/acoustic.md#packet-error-rate: a 20-byte frame at 976 bit/s is lost 1 time
        // in 100 at 3.5 km; a 64-byte frame, longer, reaches 10 % about there too.
        assert!((2500.0..5000.0).contains(&rings[0].range_m), "{rings:?}");
    }

    #[test]
    fn a_level_never_reached_has_no_ring() {
        let model = ChannelModel::default();
        assert_eq!(range_for_per(&model, 512, 976.0, 1.5), None);
        assert_eq!(range_for_per(&model, 512, 976.0, 0.0), Some(1.0));
    }
}
