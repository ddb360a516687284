//! Link metadata: how the station tells that a vehicle's data came acoustically.
//! (Written by the CDT in `shoal-converter`, read by the station.)
//!
//! The data itself must look exactly like an IP vehicle's (same topics, same types), so
//! the metadata travels beside it, without new IDL types:
//!
//! 1. **A per-vehicle link table on the standard `shoal/event` topic.** For every vehicle
//!    it hears, the CDT publishes an [`Event`] with the stable id `link.<vehicle_id>`,
//!    severity `info`, kind `other`, and a machine-readable `key=value` text (see
//!    [`LinkStatus`]): link kind, the CDT's modem address, the vehicle's acoustic address,
//!    the last RSSI and integrity the modem reported, when the vehicle was last heard, and
//!    the CDT's DDS participant. Because the event id is stable, the DDS instance, the
//!    transient-local history a late-joining station receives, and the history store's
//!    `event` row (primary key `event_id`) all hold exactly the latest status per vehicle:
//!    a link table. It is republished at most every `link_status_interval_s`. Later keys
//!    (the CDT modem's position or carrier, a frame counter, the interval) are optional:
//!    a reader skips keys it does not know and an old text lacks them.
//! 2. **Per-datum provenance.** Every sample the CDT republishes is written by the CDT's
//!    own DDS participant, so its `shoal_dds::SampleMeta::writer` GUID starts with the
//!    participant prefix named in the link status; [`LinkStatus::wrote`] checks it. A
//!    station that wants per-sample link kind keeps the link table and tests each sample.
//!
//! A dedicated `shoal/link_status` topic with its own type would be cleaner, but it needs a
//! new type in `shoal-model` and the IDL; until then this module is the one place that
//! writes and reads the convention.

use std::fmt::Write as _;

use serde::Serialize;

use crate::{Event, EventKind, LinkKind, Severity};

/// Prefix of the event ids that carry link status.
pub const EVENT_ID_PREFIX: &str = "link.";

/// One vehicle's acoustic link status, as carried in a link-status [`Event`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LinkStatus {
    /// Vehicle the status is about.
    pub vehicle_id: String,
    /// Link the vehicle's data arrives on (always `acoustic` from a CDT).
    pub link: LinkKind,
    /// Acoustic address of the CDT's modem.
    pub cdt_address: u8,
    /// Acoustic address of the vehicle.
    pub vehicle_address: u8,
    /// Received signal strength of the last frame, dB, when the modem reports it.
    pub rssi_db: Option<i32>,
    /// Signal integrity of the last frame, when the modem reports it.
    pub integrity: Option<u32>,
    /// When the last frame from the vehicle arrived, ms since the Unix epoch.
    pub heard_ms: i64,
    /// GUID prefix (hex) of the CDT's DDS participant, which writes the vehicle's data.
    pub participant: String,
    /// Latitude of the CDT's modem, degrees, when the CDT knows where it is.
    pub cdt_latitude_deg: Option<f64>,
    /// Longitude of the CDT's modem, degrees, when the CDT knows where it is.
    pub cdt_longitude_deg: Option<f64>,
    /// The vehicle carrying the CDT's modem (a USV), whose live position is the modem's.
    pub cdt_vehicle: Option<String>,
    /// Frames heard from the vehicle since the CDT started.
    pub frames: Option<u64>,
    /// The CDT's `link_status_interval_s`: how stale a status may get while the link lives.
    pub interval_s: Option<f64>,
}

impl LinkStatus {
    /// The event id that carries a vehicle's link status.
    pub fn event_id(vehicle_id: &str) -> String {
        format!("{EVENT_ID_PREFIX}{vehicle_id}")
    }

    /// The link-status event.
    pub fn to_event(&self) -> Event {
        let opt = |v: Option<String>| v.unwrap_or_else(|| "-".into());
        let mut text = format!(
            "link={} cdt_address={} vehicle_address={} rssi_db={} integrity={} participant={}",
            link_name(self.link),
            self.cdt_address,
            self.vehicle_address,
            opt(self.rssi_db.map(|v| v.to_string())),
            opt(self.integrity.map(|v| v.to_string())),
            self.participant,
        );
        // Optional keys are left out rather than written as "-": readers that predate them
        // would otherwise have to know to skip a placeholder.
        let mut key = |k: &str, v: Option<String>| {
            if let Some(v) = v {
                // Writing to a String cannot fail.
                let _ = write!(text, " {k}={v}");
            }
        };
        // 1e-7 degrees is about 1 cm.
        key(
            "cdt_latitude_deg",
            self.cdt_latitude_deg.map(|v| format!("{v:.7}")),
        );
        key(
            "cdt_longitude_deg",
            self.cdt_longitude_deg.map(|v| format!("{v:.7}")),
        );
        // A vehicle id has no spaces nor `=`; anything else would break the pairs.
        key(
            "cdt_vehicle",
            self.cdt_vehicle
                .clone()
                .filter(|v| !v.is_empty() && !v.contains(|c: char| c.is_whitespace() || c == '=')),
        );
        key("frames", self.frames.map(|v| v.to_string()));
        key("interval_s", self.interval_s.map(|v| v.to_string()));
        Event {
            event_id: Self::event_id(&self.vehicle_id),
            timestamp_ms: self.heard_ms,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: self.vehicle_id.clone(),
            task_id: String::new(),
            text,
        }
    }

    /// Parses a link-status event; `None` for any other event.
    pub fn from_event(e: &Event) -> Option<Self> {
        let vehicle_id = e.event_id.strip_prefix(EVENT_ID_PREFIX)?;
        if vehicle_id != e.vehicle_id || e.kind != EventKind::Other {
            return None;
        }
        let mut s = Self {
            vehicle_id: vehicle_id.to_owned(),
            link: LinkKind::Acoustic,
            cdt_address: 0,
            vehicle_address: 0,
            rssi_db: None,
            integrity: None,
            heard_ms: e.timestamp_ms,
            participant: String::new(),
            cdt_latitude_deg: None,
            cdt_longitude_deg: None,
            cdt_vehicle: None,
            frames: None,
            interval_s: None,
        };
        let finite = |v: &str| v.parse::<f64>().ok().filter(|x| x.is_finite());
        let mut has_link = false;
        for pair in e.text.split_whitespace() {
            let (k, v) = pair.split_once('=')?;
            match k {
                "link" => {
                    s.link = parse_link(v)?;
                    has_link = true;
                }
                "cdt_address" => s.cdt_address = v.parse().ok()?,
                "vehicle_address" => s.vehicle_address = v.parse().ok()?,
                "rssi_db" => s.rssi_db = v.parse().ok(),
                "integrity" => s.integrity = v.parse().ok(),
                "participant" => s.participant = v.to_owned(),
                "cdt_latitude_deg" => {
                    s.cdt_latitude_deg = finite(v).filter(|x| x.abs() <= 90.0);
                }
                "cdt_longitude_deg" => {
                    s.cdt_longitude_deg = finite(v).filter(|x| x.abs() <= 180.0);
                }
                "cdt_vehicle" => s.cdt_vehicle = Some(v.to_owned()).filter(|v| !v.is_empty()),
                "frames" => s.frames = v.parse().ok(),
                "interval_s" => s.interval_s = finite(v).filter(|x| *x > 0.0),
                // Unknown keys are future additions: skip them.
                _ => {}
            }
        }
        has_link.then_some(s)
    }

    /// Whether a sample whose `shoal_dds::SampleMeta::writer` is `writer` was written
    /// by this CDT (and so came over the acoustic link).
    pub fn wrote(&self, writer: &str) -> bool {
        !self.participant.is_empty() && writer.contains(&self.participant)
    }
}

fn link_name(l: LinkKind) -> &'static str {
    match l {
        LinkKind::Ip => "ip",
        LinkKind::Acoustic => "acoustic",
        LinkKind::Radio => "radio",
        LinkKind::Satellite => "satellite",
        LinkKind::Tether => "tether",
    }
}

fn parse_link(s: &str) -> Option<LinkKind> {
    Some(match s {
        "ip" => LinkKind::Ip,
        "acoustic" => LinkKind::Acoustic,
        "radio" => LinkKind::Radio,
        "satellite" => LinkKind::Satellite,
        "tether" => LinkKind::Tether,
        _ => return None,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::Validate;

    fn sample() -> LinkStatus {
        LinkStatus {
            vehicle_id: "auv-1".into(),
            link: LinkKind::Acoustic,
            cdt_address: 1,
            vehicle_address: 2,
            rssi_db: Some(-61),
            integrity: None,
            heard_ms: 1_700_000_000_000,
            participant: "010f6a2b".into(),
            cdt_latitude_deg: Some(63.464),
            cdt_longitude_deg: Some(-10.38),
            cdt_vehicle: Some("usv-1".into()),
            frames: Some(42),
            interval_s: Some(5.0),
        }
    }

    #[test]
    fn link_status_round_trips_through_a_valid_event() {
        let e = sample().to_event();
        assert_eq!(e.validate(), Ok(()));
        assert_eq!(LinkStatus::from_event(&e), Some(sample()));
    }

    #[test]
    fn a_text_without_the_later_keys_still_parses() {
        let mut e = sample().to_event();
        e.text = "link=acoustic cdt_address=1 vehicle_address=2 rssi_db=-61 integrity=- \
                  participant=010f6a2b"
            .into();
        let old = LinkStatus {
            cdt_latitude_deg: None,
            cdt_longitude_deg: None,
            cdt_vehicle: None,
            frames: None,
            interval_s: None,
            ..sample()
        };
        assert_eq!(LinkStatus::from_event(&e), Some(old.clone()));
        // And a status without them writes none of them.
        assert_eq!(old.to_event().text, e.text);
    }

    #[test]
    fn bad_values_of_the_later_keys_are_dropped_not_believed() {
        let mut e = sample().to_event();
        e.text = "link=acoustic cdt_address=1 vehicle_address=2 rssi_db=-61 integrity=- \
                  participant=010f6a2b cdt_latitude_deg=999 cdt_longitude_deg=NaN \
                  cdt_vehicle= frames=-3 interval_s=0"
            .into();
        let s = LinkStatus::from_event(&e).unwrap();
        assert_eq!(
            (
                s.cdt_latitude_deg,
                s.cdt_longitude_deg,
                s.cdt_vehicle,
                s.frames,
                s.interval_s
            ),
            (None, None, None, None, None)
        );
        // What the status is about still holds.
        assert_eq!(
            (s.cdt_address, s.vehicle_address, s.rssi_db),
            (1, 2, Some(-61))
        );
    }

    #[test]
    fn the_longest_link_status_fits_an_event() {
        let longest = LinkStatus {
            vehicle_id: "v".repeat(crate::MAX_VEHICLE_ID_LEN),
            cdt_address: 255,
            vehicle_address: 255,
            rssi_db: Some(i32::MIN),
            integrity: Some(u32::MAX),
            participant: "f".repeat(32),
            cdt_latitude_deg: Some(-89.123_456_7),
            cdt_longitude_deg: Some(-179.123_456_7),
            cdt_vehicle: Some("c".repeat(crate::MAX_VEHICLE_ID_LEN)),
            frames: Some(u64::MAX),
            interval_s: Some(0.123_456_789_012_345_6),
            ..sample()
        };
        let e = longest.to_event();
        assert!(e.text.len() <= crate::MAX_TEXT_LEN, "{}", e.text.len());
        assert_eq!(e.validate(), Ok(()));
        assert_eq!(LinkStatus::from_event(&e), Some(longest));
    }

    #[test]
    fn ordinary_events_are_not_link_status() {
        let mut e = sample().to_event();
        e.event_id = "station-1-2".into();
        assert_eq!(LinkStatus::from_event(&e), None);
    }

    #[test]
    fn provenance_matches_the_writer_guid_format() {
        assert!(sample().wrote("GUID {010f6a2b EntityId {..}}"));
        assert!(!sample().wrote("GUID {99999999 EntityId {..}}"));
    }
}
