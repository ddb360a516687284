//! A synthetic fleet for the store: deterministic data of the kind the station writes.
//!
//! [`populate_fleet`] fills a [`SemanticStore`] with vehicles, states, tasks in assorted
//! states, environment observations and events; [`synthetic_state`] and
//! [`synthetic_observation`] make more of the same traffic. The same seed gives the same
//! data, so the unit tests, the rdflib cross-check (`tests/crosscheck.rs`) and `shoal bench
//! semantic` all see the same kind of fleet.

use shoal_model::{
    Availability, EnvironmentObservation, Event, EventKind, GeoPoint, LinkKind, Severity,
    StateVector, Task, TaskAssignment, TaskState, TaskStatus, VehicleAnnouncement, VehicleKind,
};

use crate::{SemanticStore, StoreError};

/// First timestamp of the synthetic fleet: 2023-11-14T22:13:20Z.
pub const T0_MS: i64 = 1_700_000_000_000;

/// A small deterministic generator (xorshift64*), so data needs no `rand` dependency.
#[derive(Debug, Clone)]
pub struct Lcg(u64);

impl Lcg {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (x >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `0..n`.
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_f64() * n as f64) as usize).min(n.saturating_sub(1))
    }
}

const KINDS: [VehicleKind; 5] = [
    VehicleKind::Auv,
    VehicleKind::Usv,
    VehicleKind::Asv,
    VehicleKind::Rov,
    VehicleKind::Glider,
];
const SENSORS: [&str; 8] = [
    "ctd",
    "sidescan_sonar",
    "sas",
    "multibeam",
    "camera",
    "gps",
    "dvl",
    "unknown_probe",
];
const CAPS: [&str; 5] = ["goto", "hold", "survey", "sidescan_survey", "custom_skill"];
/// The environment properties the fleet observes: (property, UCUM unit, base value).
pub const PROPERTIES: [(&str, &str, f64); 2] = [
    ("sea_water_temperature", "Cel", 14.0),
    ("sea_water_salinity", "[ppth]", 38.0),
];
const EVENT_KINDS: [(EventKind, Severity, &str); 4] = [
    (EventKind::Detection, Severity::Info, "contact on sonar"),
    (EventKind::Fault, Severity::Warning, "thruster current high"),
    (EventKind::LowBattery, Severity::Warning, "battery low"),
    (EventKind::Task, Severity::Info, "waypoint reached"),
];
/// Events per vehicle in the fixture: 1000 vehicles fill the default `max_events`.
const EVENTS_PER_VEHICLE: usize = 10;
const STATES: [TaskState; 6] = [
    TaskState::Pending,
    TaskState::Sent,
    TaskState::Accepted,
    TaskState::Running,
    TaskState::Done,
    TaskState::Failed,
];

/// A state vector for vehicle `i` of the synthetic fleet at time `t_ms`.
pub fn synthetic_state(rng: &mut Lcg, vehicle_id: &str, t_ms: i64) -> StateVector {
    StateVector {
        vehicle_id: vehicle_id.to_owned(),
        timestamp_ms: t_ms,
        latitude_deg: 42.9 + rng.next_f64() * 0.4,
        longitude_deg: 5.7 + rng.next_f64() * 0.4,
        depth_m: rng.next_f64() * 100.0,
        altitude_m: if rng.next_f64() < 0.2 {
            shoal_model::UNKNOWN
        } else {
            rng.next_f64() * 50.0
        },
        speed_mps: rng.next_f64() * 3.0,
        yaw_deg: rng.next_f64() * 359.0,
        pitch_deg: rng.next_f64() * 10.0 - 5.0,
        roll_deg: rng.next_f64() * 10.0 - 5.0,
        // Rounded to 0.1 % so that the cross-check compares exact decimal values.
        battery_pct: (rng.next_f64() * 1000.0).round() / 10.0,
    }
}

/// An observation by `vehicle_id` of the `k`-th of [`PROPERTIES`] (wrapping) at `t_ms`.
pub fn synthetic_observation(
    rng: &mut Lcg,
    vehicle_id: &str,
    k: usize,
    t_ms: i64,
) -> EnvironmentObservation {
    let (property, unit, base) = PROPERTIES[k % PROPERTIES.len()];
    EnvironmentObservation {
        vehicle_id: vehicle_id.to_owned(),
        property: property.to_owned(),
        timestamp_ms: t_ms,
        value: base + rng.next_f64(),
        unit: unit.to_owned(),
        latitude_deg: 42.9 + rng.next_f64() * 0.4,
        longitude_deg: 5.7 + rng.next_f64() * 0.4,
        depth_m: rng.next_f64() * 100.0,
    }
}

/// Registers `vehicles` vehicles with one state each, about two tasks per vehicle in
/// assorted states, two environment observations and ten events per vehicle; flushes so
/// the RDF model is complete. Deterministic for a seed.
pub fn populate_fleet(
    store: &mut SemanticStore,
    vehicles: usize,
    seed: u64,
) -> Result<(), StoreError> {
    let mut rng = Lcg::new(seed);
    for i in 0..vehicles {
        let id = format!("v{i:04}");
        let kind = KINDS[i % KINDS.len()];
        let mut sensors: Vec<String> = vec!["gps".into()];
        for s in SENSORS {
            if rng.next_f64() < 0.25 && !sensors.iter().any(|x| x == s) {
                sensors.push(s.into());
            }
        }
        let caps: Vec<String> = CAPS
            .iter()
            .filter(|_| rng.next_f64() < 0.3)
            .map(|c| (*c).to_owned())
            .collect();
        let links = if kind.is_underwater() {
            vec![LinkKind::Acoustic, LinkKind::Ip]
        } else {
            vec![LinkKind::Ip, LinkKind::Radio]
        };
        store.upsert_vehicle(&VehicleAnnouncement {
            vehicle_id: id.clone(),
            name: format!("Vehicle {i}"),
            kind,
            vendor: "Shoal sim".into(),
            capabilities: caps,
            sensors,
            links,
            max_speed_mps: 3.0,
            timestamp_ms: T0_MS,
        })?;
        // Availability is the station register's to decide; a synthetic fleet decides it
        // as the register would: busy while a task is under way.
        store.set_availability(&id, Availability::Idle)?;
        store.update_state(&synthetic_state(&mut rng, &id, T0_MS + 1000))?;
        let mut busy = false;
        for k in 0..(1 + rng.below(3)) {
            let task_id = format!("t{i:04}-{k}");
            let task = if rng.next_f64() < 0.5 {
                Task::GotoWaypoint {
                    target: GeoPoint {
                        latitude_deg: 43.0 + rng.next_f64() * 0.1,
                        longitude_deg: 5.9,
                    },
                    depth_m: Some(10.0),
                    altitude_m: None,
                    speed_mps: 1.5,
                }
            } else {
                Task::SurveyArea {
                    polygon: vec![
                        GeoPoint {
                            latitude_deg: 43.0,
                            longitude_deg: 5.9,
                        },
                        GeoPoint {
                            latitude_deg: 43.0,
                            longitude_deg: 5.95,
                        },
                        GeoPoint {
                            latitude_deg: 43.05,
                            longitude_deg: 5.95,
                        },
                    ],
                    line_spacing_m: 20.0,
                    depth_m: None,
                    altitude_m: Some(5.0),
                    speed_mps: 1.0,
                }
            };
            store.upsert_task(&TaskAssignment::new(
                &task_id,
                format!("m{}", i % 7),
                &id,
                T0_MS,
                &task,
            ))?;
            let state = STATES[rng.below(STATES.len())];
            busy |= is_under_way(state);
            if state != TaskState::Pending {
                store.task_status(&TaskStatus {
                    task_id,
                    vehicle_id: id.clone(),
                    timestamp_ms: T0_MS + 2000,
                    state,
                    progress_pct: 50.0,
                    message: String::new(),
                })?;
            }
        }
        if busy {
            store.set_availability(&id, Availability::Busy)?;
        }
    }
    for i in 0..vehicles {
        let id = format!("v{i:04}");
        for k in 0..PROPERTIES.len() {
            store.add_observation(&synthetic_observation(&mut rng, &id, k, T0_MS + 3000))?;
        }
        for k in 0..EVENTS_PER_VEHICLE {
            let (kind, severity, text) = EVENT_KINDS[rng.below(EVENT_KINDS.len())];
            store.add_event(&Event {
                event_id: format!("e{i:04}-{k}"),
                timestamp_ms: T0_MS + 4000 + k as i64,
                severity,
                kind,
                vehicle_id: id.clone(),
                task_id: if kind == EventKind::Task {
                    format!("t{i:04}-0")
                } else {
                    String::new()
                },
                text: text.to_owned(),
            })?;
        }
    }
    store.flush_dirty(T0_MS + 10_000)?;
    Ok(())
}

/// A task sent to its vehicle and not finished: the vehicle is busy with it.
pub fn is_under_way(state: TaskState) -> bool {
    matches!(
        state,
        TaskState::Sent | TaskState::Accepted | TaskState::Running
    )
}
