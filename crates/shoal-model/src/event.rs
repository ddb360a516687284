//! Events: alarms, detections, task events and rule firings.

use serde::{Deserialize, Serialize};

use crate::validate::{identifier, optional_identifier, text, timestamp};
use crate::{MAX_ID_LEN, MAX_TEXT_LEN, MAX_VEHICLE_ID_LEN, Validate, ValidationError};

/// How urgent an event is; the IDL enum `shoal::Severity` in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// For the record.
    Info,
    /// Needs attention soon.
    Warning,
    /// Needs attention now.
    Alarm,
    /// Safety of a vehicle is at stake; sent on the emergency priority class.
    Critical,
}

/// What an event is about; the IDL enum `shoal::EventKind` in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    /// Battery below its threshold.
    LowBattery,
    /// Vehicle outside its operating area.
    OutOfArea,
    /// No data from a vehicle for too long.
    CommLost,
    /// A vehicle reports a fault.
    Fault,
    /// Something a sensor detected.
    Detection,
    /// A task changed state.
    Task,
    /// A user rule fired.
    Rule,
    /// The station rejected data.
    DataRejected,
    /// Anything else.
    Other,
}

/// An event; DDS key `event_id`, published reliable and transient-local (bounded).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Event {
    /// Unique event identifier: 1..=64 of `[A-Za-z0-9_.-]`.
    pub event_id: String,
    /// When it happened, ms since the Unix epoch.
    pub timestamp_ms: i64,
    /// How urgent.
    pub severity: Severity,
    /// What about.
    pub kind: EventKind,
    /// Vehicle concerned, or empty.
    pub vehicle_id: String,
    /// Task concerned, or empty.
    pub task_id: String,
    /// Human-readable text, at most 512 bytes.
    pub text: String,
}

impl Validate for Event {
    fn validate(&self) -> Result<(), ValidationError> {
        identifier("event_id", &self.event_id, MAX_ID_LEN)?;
        timestamp("timestamp_ms", self.timestamp_ms)?;
        optional_identifier("vehicle_id", &self.vehicle_id, MAX_VEHICLE_ID_LEN)?;
        optional_identifier("task_id", &self.task_id, MAX_ID_LEN)?;
        text("text", &self.text, MAX_TEXT_LEN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn severity_orders_by_urgency() {
        assert!(Severity::Critical > Severity::Alarm && Severity::Alarm > Severity::Info);
    }

    #[test]
    fn control_characters_in_text_are_rejected() {
        let e = Event {
            event_id: "e1".into(),
            timestamp_ms: 1_700_000_000_000,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: String::new(),
            task_id: String::new(),
            text: "line\u{1b}[31m".into(),
        };
        assert_eq!(e.validate().unwrap_err().reason().field, "text");
    }
}
