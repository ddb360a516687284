//! Vehicle announcements: registration data a vehicle publishes when it joins.

use serde::{Deserialize, Serialize};

use crate::validate::{finite_in, identifier, text, timestamp};
use crate::{MAX_NAME_LEN, MAX_VEHICLE_ID_LEN, Validate, ValidationError};

/// What a vehicle can be asked to do now, as the station's Vehicle and Service Register
/// decides it (the semantic model mirrors it as `shoal:availability`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Availability {
    /// In contact, no task under way.
    Idle,
    /// A task sent, accepted or running.
    Busy,
    /// At rest at the surface with its battery rising.
    Charging,
    /// Reported a fault recently.
    Fault,
    /// Not heard from for the lost-contact time, or its DDS participant left.
    Lost,
}

impl Availability {
    /// The lowercase name, as JSON and the ontology's individuals spell it.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Idle => "idle",
            Self::Busy => "busy",
            Self::Charging => "charging",
            Self::Fault => "fault",
            Self::Lost => "lost",
        }
    }
}

/// The kind of platform; the IDL enum `shoal::VehicleKind` in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VehicleKind {
    /// Autonomous underwater vehicle.
    Auv,
    /// Unmanned surface vehicle.
    Usv,
    /// Autonomous surface vehicle.
    Asv,
    /// Remotely operated (tethered) vehicle.
    Rov,
    /// Underwater glider.
    Glider,
}

impl VehicleKind {
    /// True for platforms that dive and may only be reachable acoustically.
    pub fn is_underwater(self) -> bool {
        matches!(self, Self::Auv | Self::Rov | Self::Glider)
    }

    /// Lower-case name as used in JSON and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Auv => "auv",
            Self::Usv => "usv",
            Self::Asv => "asv",
            Self::Rov => "rov",
            Self::Glider => "glider",
        }
    }
}

impl std::fmt::Display for VehicleKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A communication link a vehicle has; the IDL enum `shoal::LinkKind` in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LinkKind {
    /// IP over Wi-Fi, radio or Ethernet.
    Ip,
    /// Underwater acoustic modem.
    Acoustic,
    /// Long-range radio without IP.
    Radio,
    /// Satellite (e.g. Iridium).
    Satellite,
    /// Tether (ROV umbilical).
    Tether,
}

/// Who a vehicle is and what it can do; DDS key `vehicle_id`, published transient-local.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VehicleAnnouncement {
    /// Vehicle identifier: 1..=32 of `[A-Za-z0-9_.-]`.
    pub vehicle_id: String,
    /// Human-readable name, at most 64 bytes.
    pub name: String,
    /// Platform kind.
    pub kind: VehicleKind,
    /// Manufacturer or integrator, at most 64 bytes.
    pub vendor: String,
    /// Capabilities (e.g. `survey`, `goto`, `hold`), at most 32 identifiers.
    pub capabilities: Vec<String>,
    /// Sensors carried (e.g. `ctd`, `sidescan_sonar`), at most 32 identifiers.
    pub sensors: Vec<String>,
    /// Links the vehicle can be reached on, at most 8.
    pub links: Vec<LinkKind>,
    /// Maximum speed through water in m/s, (0, 30]; used for plausibility checks.
    pub max_speed_mps: f64,
    /// Time of the announcement, ms since the Unix epoch.
    pub timestamp_ms: i64,
}

impl VehicleAnnouncement {
    /// Most capabilities or sensors one announcement may list.
    pub const MAX_LIST: usize = 32;
    /// Most links one announcement may list.
    pub const MAX_LINKS: usize = 8;
}

impl Validate for VehicleAnnouncement {
    fn validate(&self) -> Result<(), ValidationError> {
        identifier("vehicle_id", &self.vehicle_id, MAX_VEHICLE_ID_LEN)?;
        text("name", &self.name, MAX_NAME_LEN)?;
        text("vendor", &self.vendor, MAX_NAME_LEN)?;
        for (field, list) in [
            ("capabilities", &self.capabilities),
            ("sensors", &self.sensors),
        ] {
            if list.len() > Self::MAX_LIST {
                return Err(ValidationError::BadText {
                    field,
                    rule: "at most 32 entries",
                });
            }
            for item in list {
                identifier(field, item, MAX_NAME_LEN)?;
            }
        }
        if self.links.len() > Self::MAX_LINKS {
            return Err(ValidationError::BadText {
                field: "links",
                rule: "at most 8 entries",
            });
        }
        finite_in("max_speed_mps", self.max_speed_mps, 0.0, 30.0)?;
        if self.max_speed_mps == 0.0 {
            return Err(ValidationError::Inconsistent {
                field: "max_speed_mps",
                rule: "must be greater than zero",
            });
        }
        timestamp("timestamp_ms", self.timestamp_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> VehicleAnnouncement {
        VehicleAnnouncement {
            vehicle_id: "usv-1".into(),
            name: "Surface relay".into(),
            kind: VehicleKind::Usv,
            vendor: "Shoal sim".into(),
            capabilities: vec!["goto".into(), "hold".into()],
            sensors: vec!["gps".into()],
            links: vec![LinkKind::Ip, LinkKind::Acoustic],
            max_speed_mps: 3.0,
            timestamp_ms: 1_700_000_000_000,
        }
    }

    #[test]
    fn valid_announcement_passes() {
        assert_eq!(sample().validate(), Ok(()));
    }

    #[test]
    fn too_many_capabilities_are_rejected() {
        let mut a = sample();
        a.capabilities = (0..33).map(|i| format!("c{i}")).collect();
        assert_eq!(a.validate().unwrap_err().reason().field, "capabilities");
    }

    #[test]
    fn zero_max_speed_is_rejected() {
        let mut a = sample();
        a.max_speed_mps = 0.0;
        assert!(a.validate().is_err());
    }

    #[test]
    fn kinds_serialise_lowercase_in_json() {
        assert_eq!(
            serde_json::to_string(&VehicleKind::Glider).unwrap(),
            "\"glider\""
        );
    }
}
