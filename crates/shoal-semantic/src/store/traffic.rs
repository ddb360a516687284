//! Vessel traffic in the model: each vessel known from AIS is a `shoal:TrafficTarget`,
//! and each surface vehicle's encounter with one is a `shoal:Encounter` carrying the
//! closest point of approach, which the built-in collision-risk rule watches. The rule
//! engine's edge tracking raises one alarm per encounter until its condition clears.

use std::collections::HashSet;

use oxrdf::Triple;
use shoal_model::{Event, EventKind, Severity, ValidationError, is_identifier};

use super::{SemanticStore, text};
use crate::config::StoreConfig;
use crate::error::StoreError;
use crate::rules::{Condition, RuleSpec, builtin};
use crate::vocab::{
    self, EntityKind, GEO, date_time, double, encounter_iri, shoal, traffic_iri, vehicle_iri,
};

/// Most vessels the model holds; the traffic picture bounds its own table below this.
const MAX_TARGETS: usize = 10_000;
/// Most encounters the model holds at once.
const MAX_ENCOUNTERS: usize = 10_000;

/// A vessel known from AIS, as the model keeps it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrafficTarget<'a> {
    /// Its Maritime Mobile Service Identity.
    pub mmsi: u32,
    /// Its name, empty when not yet received.
    pub name: &'a str,
    /// Latitude, degrees WGS84.
    pub latitude_deg: f64,
    /// Longitude, degrees WGS84.
    pub longitude_deg: f64,
    /// Course over ground, degrees, when known.
    pub course_deg: Option<f64>,
    /// Speed over ground, m/s, when known.
    pub speed_mps: Option<f64>,
    /// When it was last heard, ms since the Unix epoch.
    pub seen_ms: i64,
}

/// A surface vehicle's encounter with a vessel: where and when they come closest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Encounter<'a> {
    /// The vehicle.
    pub vehicle_id: &'a str,
    /// The vessel's MMSI.
    pub mmsi: u32,
    /// Closest point of approach, metres.
    pub cpa_m: f64,
    /// Time to the closest point of approach, seconds (negative: already past).
    pub tcpa_s: f64,
    /// When this was computed, ms since the Unix epoch.
    pub at_ms: i64,
}

/// Which vessels and encounters the model holds.
#[derive(Debug, Default)]
pub(super) struct TrafficEntries {
    targets: HashSet<u32>,
    encounters: HashSet<(String, u32)>,
}

/// The built-in collision-risk rule for `config`'s thresholds.
pub(super) fn collision_rule(config: &StoreConfig) -> RuleSpec {
    RuleSpec {
        id: builtin::COLLISION_RISK.into(),
        description: format!(
            "A vessel will pass within {} m of a surface vehicle in the next {} s",
            config.collision_cpa_m, config.collision_tcpa_s
        ),
        severity: Severity::Alarm,
        kind: EventKind::Detection,
        condition: Condition::Sparql {
            query: format!(
                "ASK {{ ?this a shoal:Encounter ; shoal:cpaMetres ?cpa ; shoal:tcpaSeconds ?t . \
                 FILTER(?cpa < {:?} && ?t >= 0 && ?t <= {:?}) }}",
                config.collision_cpa_m, config.collision_tcpa_s
            ),
            watches: vec!["shoal:cpaMetres".into(), "shoal:tcpaSeconds".into()],
        },
    }
}

fn finite(field: &'static str, v: f64, min: f64, max: f64) -> Result<(), ValidationError> {
    if !v.is_finite() {
        return Err(ValidationError::NotFinite { field });
    }
    if !(min..=max).contains(&v) {
        return Err(ValidationError::OutOfRange {
            field,
            value: v,
            min,
            max,
        });
    }
    Ok(())
}

fn check_target(t: &TrafficTarget<'_>) -> Result<(), ValidationError> {
    finite("latitude_deg", t.latitude_deg, -90.0, 90.0)?;
    finite("longitude_deg", t.longitude_deg, -180.0, 180.0)?;
    if let Some(c) = t.course_deg {
        finite("course_deg", c, 0.0, 360.0)?;
    }
    if let Some(s) = t.speed_mps {
        finite("speed_mps", s, 0.0, 100.0)?;
    }
    if t.name.len() > 64 {
        return Err(ValidationError::BadText {
            field: "name",
            rule: "at most 64 bytes",
        });
    }
    Ok(())
}

fn check_encounter(e: &Encounter<'_>) -> Result<(), ValidationError> {
    if !is_identifier(e.vehicle_id, 32) {
        return Err(ValidationError::BadText {
            field: "vehicle_id",
            rule: "1..=32 of [A-Za-z0-9_.-]",
        });
    }
    finite("cpa_m", e.cpa_m, 0.0, f64::MAX)?;
    finite("tcpa_s", e.tcpa_s, f64::MIN, f64::MAX)?;
    Ok(())
}

fn encounter_key(vehicle_id: &str, mmsi: u32) -> String {
    format!("{vehicle_id}/{mmsi}")
}

impl SemanticStore {
    /// Adds or updates a vessel known from AIS. Past the model's bound of vessels a new
    /// one is refused (the traffic picture keeps fewer).
    pub fn upsert_traffic_target(&mut self, t: &TrafficTarget<'_>) -> Result<(), StoreError> {
        check_target(t).map_err(StoreError::invalid("traffic target"))?;
        if !self.traffic.targets.contains(&t.mmsi) && self.traffic.targets.len() >= MAX_TARGETS {
            return Err(StoreError::Invalid {
                what: "traffic target",
                source: ValidationError::Inconsistent {
                    field: "mmsi",
                    rule: "the model holds 10000 vessels already",
                },
            });
        }
        let s = traffic_iri(t.mmsi);
        let mut triples = vec![
            Triple::new(s.clone(), vocab::rdf_type(), shoal("TrafficTarget")),
            Triple::new(s.clone(), shoal("mmsi"), text(&t.mmsi.to_string())),
            Triple::new(s.clone(), vocab::ns(GEO, "lat"), double(t.latitude_deg)),
            Triple::new(s.clone(), vocab::ns(GEO, "long"), double(t.longitude_deg)),
            Triple::new(s.clone(), shoal("lastSeen"), date_time(t.seen_ms)),
        ];
        if !t.name.is_empty() {
            triples.push(Triple::new(s.clone(), shoal("vesselName"), text(t.name)));
        }
        if let Some(c) = t.course_deg {
            triples.push(Triple::new(s.clone(), shoal("courseOverGround"), double(c)));
        }
        if let Some(v) = t.speed_mps {
            triples.push(Triple::new(s, shoal("speedOverGround"), double(v)));
        }
        self.write_entity(EntityKind::TrafficTarget, &t.mmsi.to_string(), triples)?;
        self.traffic.targets.insert(t.mmsi);
        Ok(())
    }

    /// Removes a vessel (its AIS reports stopped) and every encounter with it.
    pub fn forget_traffic_target(&mut self, mmsi: u32) -> Result<bool, StoreError> {
        let ended: Vec<String> = self
            .traffic
            .encounters
            .iter()
            .filter(|(_, m)| *m == mmsi)
            .map(|(v, _)| v.clone())
            .collect();
        for vehicle_id in ended {
            self.end_encounter(&vehicle_id, mmsi)?;
        }
        if !self.traffic.targets.remove(&mmsi) {
            return Ok(false);
        }
        self.drop_entity(EntityKind::TrafficTarget, &mmsi.to_string())?;
        Ok(true)
    }

    /// Records where a vehicle and a vessel come closest and runs the rules watching it
    /// (the built-in collision-risk rule among them); returns the events they raise.
    pub fn update_encounter(&mut self, e: &Encounter<'_>) -> Result<Vec<Event>, StoreError> {
        check_encounter(e).map_err(StoreError::invalid("encounter"))?;
        let key = (e.vehicle_id.to_owned(), e.mmsi);
        if !self.traffic.encounters.contains(&key)
            && self.traffic.encounters.len() >= MAX_ENCOUNTERS
        {
            return Err(StoreError::Invalid {
                what: "encounter",
                source: ValidationError::Inconsistent {
                    field: "vehicle_id",
                    rule: "the model holds 10000 encounters already",
                },
            });
        }
        let s = encounter_iri(e.vehicle_id, e.mmsi);
        let triples = vec![
            Triple::new(s.clone(), vocab::rdf_type(), shoal("Encounter")),
            Triple::new(
                s.clone(),
                shoal("encounterVehicle"),
                vehicle_iri(e.vehicle_id),
            ),
            Triple::new(s.clone(), shoal("encounterTarget"), traffic_iri(e.mmsi)),
            Triple::new(s.clone(), shoal("cpaMetres"), double(e.cpa_m)),
            Triple::new(s.clone(), shoal("tcpaSeconds"), double(e.tcpa_s)),
            Triple::new(s.clone(), shoal("computedAt"), date_time(e.at_ms)),
        ];
        let changed = self.write_entity(
            EntityKind::Encounter,
            &encounter_key(e.vehicle_id, e.mmsi),
            triples,
        )?;
        self.traffic.encounters.insert(key);
        self.run_sparql_rules(&s, e.vehicle_id, "", e.at_ms, &changed)
    }

    /// Removes an encounter (the vessel or vehicle is gone, or they drew apart); the
    /// rules forget it, so a later encounter of the same pair alarms afresh.
    pub fn end_encounter(&mut self, vehicle_id: &str, mmsi: u32) -> Result<bool, StoreError> {
        if !self
            .traffic
            .encounters
            .remove(&(vehicle_id.to_owned(), mmsi))
        {
            return Ok(false);
        }
        self.drop_entity(EntityKind::Encounter, &encounter_key(vehicle_id, mmsi))?;
        self.rules.forget(encounter_iri(vehicle_id, mmsi).as_str());
        Ok(true)
    }

    /// Vessels and encounters the model holds.
    pub fn traffic_counts(&self) -> (usize, usize) {
        (self.traffic.targets.len(), self.traffic.encounters.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn store() -> SemanticStore {
        SemanticStore::new(StoreConfig::default()).unwrap()
    }

    fn target(mmsi: u32) -> TrafficTarget<'static> {
        TrafficTarget {
            mmsi,
            name: "NORNE",
            latitude_deg: 63.44,
            longitude_deg: 10.40,
            course_deg: Some(270.0),
            speed_mps: Some(6.0),
            seen_ms: 1_800_000_000_000,
        }
    }

    fn encounter(cpa_m: f64, tcpa_s: f64) -> Encounter<'static> {
        Encounter {
            vehicle_id: "usv-1",
            mmsi: 257_000_001,
            cpa_m,
            tcpa_s,
            at_ms: 1_800_000_000_000,
        }
    }

    fn ask(s: &SemanticStore, q: &str) -> bool {
        match s.query(q, &crate::QueryLimits::default()).unwrap() {
            crate::QueryResult::Boolean(b) => b,
            other => panic!("not an ASK result: {other:?}"),
        }
    }

    #[test]
    fn a_close_encounter_raises_one_alarm_until_it_clears() {
        let mut s = store();
        s.upsert_traffic_target(&target(257_000_001)).unwrap();
        // Far: nothing.
        assert!(
            s.update_encounter(&encounter(2_000.0, 120.0))
                .unwrap()
                .is_empty()
        );
        // Close and ahead: one alarm, naming the vehicle.
        let ev = s.update_encounter(&encounter(150.0, 120.0)).unwrap();
        assert_eq!(ev.len(), 1, "{ev:?}");
        assert_eq!(ev[0].vehicle_id, "usv-1");
        assert_eq!(ev[0].severity, Severity::Alarm);
        assert!(
            ev[0].text.contains("encounter/usv-1/257000001"),
            "{}",
            ev[0].text
        );
        // Still close: no second alarm.
        assert!(
            s.update_encounter(&encounter(120.0, 90.0))
                .unwrap()
                .is_empty()
        );
        // Passed (TCPA negative): cleared; closing again raises anew.
        assert!(
            s.update_encounter(&encounter(120.0, -10.0))
                .unwrap()
                .is_empty()
        );
        assert_eq!(
            s.update_encounter(&encounter(100.0, 60.0)).unwrap().len(),
            1
        );
        // Too far ahead in time: no alarm.
        s.end_encounter("usv-1", 257_000_001).unwrap();
        assert!(
            s.update_encounter(&encounter(100.0, 5_000.0))
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn vessels_and_encounters_are_queryable_and_forgotten() {
        let mut s = store();
        s.upsert_traffic_target(&target(257_000_001)).unwrap();
        s.update_encounter(&encounter(150.0, 120.0)).unwrap();
        assert_eq!(s.traffic_counts(), (1, 1));
        assert!(ask(
            &s,
            "ASK { ?e a shoal:Encounter ; shoal:encounterTarget ?t . ?t shoal:vesselName \"NORNE\" ; shoal:mmsi \"257000001\" }"
        ));
        assert!(s.forget_traffic_target(257_000_001).unwrap());
        assert_eq!(s.traffic_counts(), (0, 0));
        assert!(!ask(&s, "ASK { ?t a shoal:TrafficTarget }"));
        assert!(!ask(&s, "ASK { ?e a shoal:Encounter }"));
        assert!(!s.forget_traffic_target(257_000_001).unwrap());
    }

    #[test]
    fn bad_values_are_refused_and_change_nothing() {
        let mut s = store();
        let mut t = target(1);
        t.latitude_deg = 91.0;
        assert!(s.upsert_traffic_target(&t).is_err());
        t.latitude_deg = f64::NAN;
        assert!(s.upsert_traffic_target(&t).is_err());
        let mut e = encounter(f64::INFINITY, 1.0);
        assert!(s.update_encounter(&e).is_err());
        e.cpa_m = 1.0;
        e.vehicle_id = "not an id";
        assert!(s.update_encounter(&e).is_err());
        assert_eq!(s.traffic_counts(), (0, 0));
    }

    #[test]
    fn the_thresholds_follow_the_configuration() {
        let mut s = SemanticStore::new(StoreConfig {
            collision_cpa_m: 50.0,
            ..StoreConfig::default()
        })
        .unwrap();
        assert!(
            s.update_encounter(&encounter(150.0, 120.0))
                .unwrap()
                .is_empty()
        );
        assert_eq!(
            s.update_encounter(&encounter(40.0, 120.0)).unwrap().len(),
            1
        );
    }
}
