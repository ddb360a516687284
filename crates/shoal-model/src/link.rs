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
//!    a link table. It is republished at most every `link_status_interval_s`.
//! 2. **Per-datum provenance.** Every sample the CDT republishes is written by the CDT's
//!    own DDS participant, so its `shoal_dds::SampleMeta::writer` GUID starts with the
//!    participant prefix named in the link status; [`LinkStatus::wrote`] checks it. A
//!    station that wants per-sample link kind keeps the link table and tests each sample.
//!
//! A dedicated `shoal/link_status` topic with its own type would be cleaner, but it needs a
//! new type in `shoal-model` and the IDL; until then this module is the one place that
//! writes and reads the convention.

use serde::Serialize;

use crate::{Event, EventKind, LinkKind, Severity};

/// Prefix of the event ids that carry link status.
pub const EVENT_ID_PREFIX: &str = "link.";

/// One vehicle's acoustic link status, as carried in a link-status [`Event`].
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
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
}

impl LinkStatus {
    /// The event id that carries a vehicle's link status.
    pub fn event_id(vehicle_id: &str) -> String {
        format!("{EVENT_ID_PREFIX}{vehicle_id}")
    }

    /// The link-status event.
    pub fn to_event(&self) -> Event {
        let opt = |v: Option<String>| v.unwrap_or_else(|| "-".into());
        Event {
            event_id: Self::event_id(&self.vehicle_id),
            timestamp_ms: self.heard_ms,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: self.vehicle_id.clone(),
            task_id: String::new(),
            text: format!(
                "link={} cdt_address={} vehicle_address={} rssi_db={} integrity={} participant={}",
                link_name(self.link),
                self.cdt_address,
                self.vehicle_address,
                opt(self.rssi_db.map(|v| v.to_string())),
                opt(self.integrity.map(|v| v.to_string())),
                self.participant,
            ),
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
        };
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
        }
    }

    #[test]
    fn link_status_round_trips_through_a_valid_event() {
        let e = sample().to_event();
        assert_eq!(e.validate(), Ok(()));
        assert_eq!(LinkStatus::from_event(&e), Some(sample()));
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
