//! The Event Reporter's acknowledgements, the Environment Reporter's subscriptions, and
//! the live feed the API's WebSocket forwards.

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};
use shoal_model::{EnvironmentObservation, Event, GeoPoint};

use crate::error::SubscriptionError;
use crate::missions::{MissionView, TaskView};
use crate::register::VehicleView;

/// Who acknowledged an event, and when.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ack {
    /// Operator name.
    pub by: String,
    /// Station time, ms since the Unix epoch.
    pub at_ms: i64,
}

/// An event with its acknowledgement, as the API lists it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EventView {
    /// The event.
    #[serde(flatten)]
    pub event: Event,
    /// Set once an operator acknowledged it.
    pub acknowledged: Option<Ack>,
}

/// What an operator asks the Environment Reporter for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EnvSubscriptionSpec {
    /// Property (e.g. `sea_water_temperature`); absent = every property.
    #[serde(default)]
    pub property: Option<String>,
    /// Polygon the observation must lie in; absent = anywhere.
    #[serde(default)]
    pub area: Option<Vec<GeoPoint>>,
    /// Most observations per second delivered per vehicle and property (default 1).
    #[serde(default = "one")]
    pub max_rate_hz: f64,
}

fn one() -> f64 {
    1.0
}

/// Most observations kept per subscription for polling clients.
pub const SUBSCRIPTION_BUFFER: usize = 1000;

/// A subscription and what it has matched.
#[derive(Debug, Clone, Serialize)]
pub struct EnvSubscription {
    /// Identifier given by the station.
    pub id: String,
    /// What it asks for.
    pub spec: EnvSubscriptionSpec,
    /// Observations delivered so far.
    pub delivered: u64,
    #[serde(skip)]
    pub(crate) recent: VecDeque<EnvironmentObservation>,
    #[serde(skip)]
    pub(crate) last_ms: std::collections::HashMap<(String, String), i64>,
}

impl EnvSubscriptionSpec {
    /// Checks the request; the error names the field.
    pub fn check(&self) -> Result<(), SubscriptionError> {
        if !(self.max_rate_hz.is_finite() && self.max_rate_hz > 0.0 && self.max_rate_hz <= 100.0) {
            return Err(SubscriptionError::Rate);
        }
        if let Some(area) = &self.area {
            if area.len() < 3 {
                return Err(SubscriptionError::AreaTooSmall);
            }
            for p in area {
                shoal_model::Validate::validate(p).map_err(SubscriptionError::AreaPoint)?;
            }
        }
        Ok(())
    }
}

impl EnvSubscription {
    /// A new subscription with nothing matched yet.
    pub(crate) fn new(id: String, spec: EnvSubscriptionSpec) -> Self {
        Self {
            id,
            spec,
            delivered: 0,
            recent: VecDeque::new(),
            last_ms: std::collections::HashMap::new(),
        }
    }

    /// Takes the observation if it matches and the rate allows; true when taken.
    pub(crate) fn offer(&mut self, o: &EnvironmentObservation, now_ms: i64) -> bool {
        if self
            .spec
            .property
            .as_deref()
            .is_some_and(|p| p != o.property)
        {
            return false;
        }
        if let Some(area) = &self.spec.area
            && shoal_semantic::outside(area, o.latitude_deg, o.longitude_deg)
        {
            return false;
        }
        #[allow(clippy::cast_possible_truncation)]
        let gap_ms = (1000.0 / self.spec.max_rate_hz) as i64;
        let key = (o.vehicle_id.clone(), o.property.clone());
        if self.last_ms.get(&key).is_some_and(|t| now_ms - t < gap_ms) {
            return false;
        }
        self.last_ms.insert(key, now_ms);
        self.recent.push_back(o.clone());
        while self.recent.len() > SUBSCRIPTION_BUFFER {
            self.recent.pop_front();
        }
        self.delivered += 1;
        true
    }
}

/// One live update for API clients.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "type", content = "data", rename_all = "snake_case")]
pub enum LiveUpdate {
    /// A new or acknowledged event.
    Event(EventView),
    /// A task changed state or progress.
    Task(Box<TaskView>),
    /// A mission changed.
    Mission(Box<MissionView>),
    /// A vehicle's state (at most once a second per vehicle).
    Vehicle(Box<VehicleView>),
    /// An observation matching an environment subscription.
    Observation {
        /// The subscription it matched.
        subscription: String,
        /// The observation.
        observation: EnvironmentObservation,
    },
    /// An AIS target with a position that sent a new report (at most once a second each).
    Vessel(Box<shoal_traffic::TargetView>),
    /// An AIS target no longer in the traffic picture (its reports stopped).
    VesselGone {
        /// Its MMSI.
        mmsi: u32,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    fn obs(property: &str, lat: f64, vehicle: &str) -> EnvironmentObservation {
        EnvironmentObservation {
            vehicle_id: vehicle.into(),
            property: property.into(),
            timestamp_ms: 1_800_000_000_000,
            value: 12.5,
            unit: "Cel".into(),
            latitude_deg: lat,
            longitude_deg: 10.0,
            depth_m: 5.0,
        }
    }

    fn sub(spec: EnvSubscriptionSpec) -> EnvSubscription {
        EnvSubscription {
            id: "s1".into(),
            spec,
            delivered: 0,
            recent: VecDeque::new(),
            last_ms: std::collections::HashMap::new(),
        }
    }

    #[test]
    fn a_subscription_filters_by_property_area_and_rate() {
        let p = |lat: f64, lon: f64| GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        };
        let mut s = sub(EnvSubscriptionSpec {
            property: Some("sea_water_temperature".into()),
            area: Some(vec![
                p(62.0, 9.0),
                p(64.0, 9.0),
                p(64.0, 11.0),
                p(62.0, 11.0),
            ]),
            max_rate_hz: 0.5,
        });
        assert!(s.offer(&obs("sea_water_temperature", 63.0, "a"), 0));
        // Too soon for the same vehicle and property; another vehicle is fine.
        assert!(!s.offer(&obs("sea_water_temperature", 63.0, "a"), 1000));
        assert!(s.offer(&obs("sea_water_temperature", 63.0, "b"), 1000));
        assert!(s.offer(&obs("sea_water_temperature", 63.0, "a"), 2000));
        assert!(!s.offer(&obs("sea_water_salinity", 63.0, "c"), 5000));
        assert!(!s.offer(&obs("sea_water_temperature", 65.0, "d"), 5000));
        assert_eq!(s.delivered, 3);
        assert_eq!(s.recent.len(), 3);
    }

    #[test]
    fn bad_subscriptions_name_the_field() {
        let bad = EnvSubscriptionSpec {
            property: None,
            area: Some(vec![]),
            max_rate_hz: 1.0,
        };
        assert!(bad.check().unwrap_err().to_string().contains("area"));
        let bad = EnvSubscriptionSpec {
            property: None,
            area: None,
            max_rate_hz: 0.0,
        };
        assert!(bad.check().unwrap_err().to_string().contains("max_rate_hz"));
    }
}
