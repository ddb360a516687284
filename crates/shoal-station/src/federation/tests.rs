//! The command lease at the station, with a federation that is only a lease table: tasks
//! carry the lease they go under, another site's vehicle is commanded through its site,
//! and a task another site sends here is taken only under the lease in force.

#![allow(clippy::unwrap_used)]

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use shoal_model::{TaskAssignment, TaskState, TaskStatus, now_ms};

use super::*;
use crate::error::DispatchError;
use crate::missions::MissionState;
use crate::testing::{Fixture, assignment, goto, spec};

/// A federation of which this site is `site`: who holds each vehicle's lease, whose
/// vehicle each is, and what was sent to other sites.
struct Leases {
    site: String,
    /// Vehicle → (holder, term).
    held: Mutex<HashMap<String, (String, u64)>>,
    /// Vehicle → its site, for other sites' vehicles.
    homes: HashMap<String, String>,
    relayed: Mutex<Vec<TaskAssignment>>,
    /// Environment observations handed over, by vehicle.
    observed: Mutex<Vec<String>>,
}

impl Leases {
    fn new(site: &str, held: &[(&str, &str, u64)], homes: &[(&str, &str)]) -> Arc<Self> {
        Arc::new(Self {
            site: site.into(),
            held: Mutex::new(
                held.iter()
                    .map(|(v, h, t)| ((*v).to_owned(), ((*h).to_owned(), *t)))
                    .collect(),
            ),
            homes: homes
                .iter()
                .map(|(v, s)| ((*v).to_owned(), (*s).to_owned()))
                .collect(),
            relayed: Mutex::new(Vec::new()),
            observed: Mutex::new(Vec::new()),
        })
    }

    fn set(&self, vehicle: &str, holder: &str, term: u64) {
        self.held
            .lock()
            .unwrap()
            .insert(vehicle.into(), (holder.into(), term));
    }
}

impl FederationView for Leases {
    fn snapshot(&self, _now_ms: i64) -> FederationSnapshot {
        FederationSnapshot::default()
    }

    fn may_command(&self, vehicle: &str) -> Result<LeaseGrant, LeaseDenial> {
        match self.held.lock().unwrap().get(vehicle) {
            Some((holder, term)) if *holder == self.site => Ok(LeaseGrant {
                term: *term,
                holder: holder.clone(),
            }),
            Some((holder, term)) => Err(LeaseDenial::HeldElsewhere {
                vehicle: vehicle.into(),
                holder: holder.clone(),
                term: *term,
            }),
            None => Err(LeaseDenial::Unavailable {
                vehicle: vehicle.into(),
                why: "none".into(),
            }),
        }
    }

    fn hand_over(&self, _vehicle: &str, _to: &str) -> Result<LeaseView, HandoverRefused> {
        Err(HandoverRefused::NotInForce)
    }

    fn home_of(&self, vehicle: &str) -> Option<String> {
        self.homes.get(vehicle).cloned()
    }

    fn relay(&self, task: &TaskAssignment) -> Result<(), RelayRefused> {
        self.relayed.lock().unwrap().push(task.clone());
        Ok(())
    }

    fn observe(&self, observation: &EnvironmentObservation) {
        self.observed
            .lock()
            .unwrap()
            .push(observation.vehicle_id.clone());
    }
}

fn federated(leases: &Arc<Leases>) -> Fixture {
    let f = Fixture::new();
    let view: Arc<dyn FederationView> = leases.clone();
    assert!(f.h.attach_federation(view).is_ok());
    f
}

fn state_of(f: &Fixture, task: &str) -> TaskState {
    f.h.task(task).unwrap().state
}

#[test]
fn a_task_goes_out_under_the_lease_held_here_whatever_the_operator_wrote() {
    let leases = Leases::new("ship", &[("auv-1", "ship", 3)], &[]);
    let f = federated(&leases);
    f.alive("auv-1");
    let mut forged = assignment("t-1", "auv-1");
    forged.lease_term = 9;
    forged.lease_holder = "shore".into();
    f.h.dispatch_now(forged).unwrap();
    let sent = f.out.tasks();
    assert_eq!(
        (sent[0].lease_term, sent[0].lease_holder.as_str()),
        (3, "ship")
    );
    // Handed over: the station no longer commands auv-1.
    leases.set("auv-1", "shore", 4);
    assert!(matches!(
        f.h.dispatch_now(assignment("t-2", "auv-1")),
        Err(DispatchError::Lease(LeaseDenial::HeldElsewhere { .. }))
    ));
    assert_eq!(f.out.tasks().len(), 1);
}

#[test]
fn another_sites_vehicle_is_commanded_through_its_site_and_follows_its_transitions() {
    let leases = Leases::new("shore", &[("auv-9", "shore", 2)], &[("auv-9", "ship")]);
    let f = federated(&leases);
    f.h.dispatch_now(assignment("h-1", "auv-9")).unwrap();
    assert!(
        f.out.tasks().is_empty(),
        "nothing on this station's own bus"
    );
    let relayed = leases.relayed.lock().unwrap().clone();
    assert_eq!(relayed.len(), 1);
    assert_eq!(
        (relayed[0].lease_term, relayed[0].lease_holder.as_str()),
        (2, "shore")
    );
    let view = f.h.task("h-1").unwrap();
    assert_eq!(
        (view.state, view.via_site.as_deref(), view.message.as_str()),
        (TaskState::Sent, Some("ship"), "sent through site ship")
    );
    let moved = |state| TaskStatus {
        task_id: "h-1".into(),
        vehicle_id: "auv-9".into(),
        timestamp_ms: now_ms(),
        state,
        progress_pct: 0.0,
        message: String::new(),
    };
    // Only the site it went through speaks for it.
    assert!(!f.h.remote_task_moved("other", &moved(TaskState::Failed)));
    assert!(f.h.remote_task_moved("ship", &moved(TaskState::Running)));
    assert_eq!(state_of(&f, "h-1"), TaskState::Running);
    assert!(f.h.remote_task_moved("ship", &moved(TaskState::Done)));
    assert_eq!(state_of(&f, "h-1"), TaskState::Done);
    assert!(
        f.out.retired().is_empty(),
        "never on the bus, never retired"
    );

    // Without the lease, nothing goes.
    leases.set("auv-9", "ship", 3);
    assert!(matches!(
        f.h.dispatch_now(assignment("h-2", "auv-9")),
        Err(DispatchError::Lease(_))
    ));
    assert_eq!(leases.relayed.lock().unwrap().len(), 1);
}

#[test]
fn a_mission_on_another_sites_vehicle_goes_through_its_site_task_by_task() {
    let leases = Leases::new("shore", &[("auv-9", "shore", 2)], &[("auv-9", "ship")]);
    let f = federated(&leases);
    let hold = shoal_model::Task::Hold { duration_s: 30.0 };
    let m = spec("m-9", &[("auv-9", goto()), ("auv-9", hold)]);
    // The plan preview starts from where the federation last saw the vehicle (none yet).
    assert!(matches!(
        f.h.preview_mission(&m),
        Err(DispatchError::UnknownVehicle(_))
    ));
    f.h.plan_mission(m).unwrap();
    f.h.start_mission("m-9").unwrap();
    let relayed = || leases.relayed.lock().unwrap().clone();
    // One task at a time, each under the shore's lease; nothing on the shore's own bus.
    assert_eq!(relayed().len(), 1);
    assert_eq!(
        (
            relayed()[0].task_id.as_str(),
            relayed()[0].mission_id.as_str()
        ),
        ("m-9-1", "m-9")
    );
    assert_eq!(relayed()[0].lease_term, 2);
    assert!(f.out.tasks().is_empty());
    let moved = |task: &str, state| TaskStatus {
        task_id: task.into(),
        vehicle_id: "auv-9".into(),
        timestamp_ms: now_ms(),
        state,
        progress_pct: 0.0,
        message: String::new(),
    };
    assert!(f.h.remote_task_moved("ship", &moved("m-9-1", TaskState::Done)));
    // The first done at the ship: the second goes through it.
    assert_eq!(relayed().len(), 2);
    assert_eq!(relayed()[1].task_id, "m-9-2");
    assert_eq!(f.h.mission("m-9").unwrap().state, MissionState::Running);
    assert!(f.h.remote_task_moved("ship", &moved("m-9-2", TaskState::Running)));

    // Aborted while the hold runs: the abort goes through the ship too.
    f.h.abort_mission("m-9").unwrap();
    let sent = relayed();
    assert_eq!(sent.len(), 3);
    assert_eq!(sent[2].kind, shoal_model::TaskKind::Abort);
    assert_eq!(
        (sent[2].vehicle_id.as_str(), sent[2].lease_term),
        ("auv-9", 2)
    );
    assert_eq!(f.h.mission("m-9").unwrap().state, MissionState::Aborted);

    // Without the lease, such a mission is refused when planned.
    leases.set("auv-9", "ship", 3);
    let again = spec("m-10", &[("auv-9", goto())]);
    assert!(matches!(
        f.h.plan_mission(again),
        Err(DispatchError::InMission { index: 0, .. })
    ));
}

#[test]
fn a_task_from_the_lease_holder_reaches_the_vehicle_with_its_lease_and_no_other() {
    let leases = Leases::new("ship", &[("auv-1", "shore", 2)], &[]);
    let f = federated(&leases);
    f.alive("auv-1");
    let mut order = assignment("h-1", "auv-1");
    order.lease_term = 2;
    order.lease_holder = "shore".into();
    f.h.dispatch_for("shore", order.clone()).unwrap();
    let sent = f.out.tasks();
    assert_eq!(sent.len(), 1);
    assert_eq!(
        (sent[0].lease_term, sent[0].lease_holder.as_str()),
        (2, "shore")
    );
    assert!(sent[0].issue_seq > 0, "numbered by this station");

    // The shore's lease moved on (handed back, term 3): its old order is refused, and the
    // refusal is a failed task, which the shore learns through this site's transitions.
    leases.set("auv-1", "ship", 3);
    let mut stale = order.clone();
    stale.task_id = "h-2".into();
    assert!(matches!(
        f.h.dispatch_for("shore", stale),
        Err(DispatchError::Lease(_))
    ));
    assert_eq!(state_of(&f, "h-2"), TaskState::Failed);
    // A site cannot send under another's lease.
    let mut forged = order;
    forged.task_id = "h-3".into();
    assert!(matches!(
        f.h.dispatch_for("bravo", forged),
        Err(DispatchError::BadField { .. })
    ));
    assert!(f.h.task("h-3").is_none());
    assert_eq!(f.out.tasks().len(), 1);
}

#[test]
fn every_observation_the_station_accepts_goes_to_the_federation() {
    let leases = Leases::new("ship", &[], &[]);
    let f = federated(&leases);
    f.alive("auv-1");
    let o = EnvironmentObservation {
        vehicle_id: "auv-1".into(),
        property: "sea_water_temperature".into(),
        timestamp_ms: now_ms(),
        value: 7.5,
        unit: "Cel".into(),
        latitude_deg: 63.44,
        longitude_deg: 10.38,
        depth_m: 10.0,
    };
    f.h.ingest_observation(crate::testing::valid(o.clone()))
        .unwrap();
    let mut stale = o;
    stale.timestamp_ms -= 86_400_000;
    assert!(
        f.h.ingest_observation(crate::testing::valid(stale))
            .is_err()
    );
    assert_eq!(
        *leases.observed.lock().unwrap(),
        ["auv-1"],
        "only the accepted one"
    );
}
