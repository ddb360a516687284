//! The station's side of the federation (`[federation]`): its live feed goes out over
//! Zenoh (positions, alarms, task transitions, as the section's policies say), and the
//! remote sites' picture comes back for `GET /api/federation`. Tasks cross too, under the
//! command lease: one for another site's vehicle goes to that site, one another site sends
//! for a vehicle here is dispatched, and the task transitions of the former come back.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::Arc;

use anyhow::{Context, Result};
use shoal_federation::{
    CommandDenied, Federation, FederationConfig, HandoverError, LeaseReason, LeaseRecord,
    TaskTransition, VehiclePosition,
};
use shoal_model::{EnvironmentObservation, TaskAssignment, TaskStatus};
use shoal_station::{
    FederationSnapshot, FederationView, HandoverRefused, LeaseDenial, LeaseGrant, LeaseView,
    LiveUpdate, RelayRefused, RemoteAlarmView, RemoteEnvironmentView, RemoteTransitionView,
    RemoteVehicleView, SiteView, StationHandle,
};
use tokio::sync::broadcast::error::RecvError;
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

/// Alarm ids remembered so that an acknowledgement (the same event again on the live
/// feed) is not sent a second time.
const ALARMS_REMEMBERED: usize = 10_000;
/// Tasks whose last state is remembered, so that progress reports are not transitions.
const TASKS_REMEMBERED: usize = 100_000;

/// A running federation, as the station reads it.
struct View(Arc<Federation>);

fn lease_view(r: &LeaseRecord, site: &str) -> LeaseView {
    LeaseView {
        vehicle_id: r.vehicle_id.clone(),
        holder: r.holder.clone(),
        home: r.home.clone(),
        standby: r.standby.clone(),
        term: r.term,
        reason: r.reason.as_str(),
        granted_ms: r.granted_ms,
        held_here: r.holder == site,
    }
}

impl FederationView for View {
    fn may_command(&self, vehicle: &str) -> Result<LeaseGrant, LeaseDenial> {
        let term = self.0.may_command(vehicle).map_err(|e| match e {
            CommandDenied::HeldElsewhere {
                vehicle,
                holder,
                term,
            } => LeaseDenial::HeldElsewhere {
                vehicle,
                holder,
                term,
            },
            CommandDenied::NotSettled {
                vehicle,
                waited_ms,
                settle_ms,
            } => LeaseDenial::NotSettled {
                vehicle,
                waited_ms,
                settle_ms,
            },
            other => LeaseDenial::Unavailable {
                vehicle: vehicle.to_owned(),
                why: other.to_string(),
            },
        })?;
        Ok(if term == 0 {
            LeaseGrant::NONE
        } else {
            LeaseGrant {
                term,
                holder: self.0.site().to_owned(),
            }
        })
    }

    fn hand_over(&self, vehicle: &str, to: &str) -> Result<LeaseView, HandoverRefused> {
        if !self.0.lease_enabled() {
            return Err(HandoverRefused::NotInForce);
        }
        match self.0.hand_over(vehicle, to) {
            Ok(r) => Ok(lease_view(&r, self.0.site())),
            Err(HandoverError::Unknown(v)) => Err(HandoverRefused::UnknownLease(v)),
            Err(HandoverError::UnknownSite(s)) => Err(HandoverRefused::UnknownSite(s)),
            Err(HandoverError::NotHolder {
                vehicle,
                holder,
                term,
            }) => Err(HandoverRefused::NotHolder {
                vehicle,
                holder,
                term,
            }),
            Err(other) => Err(HandoverRefused::UnknownLease(other.to_string())),
        }
    }

    fn home_of(&self, vehicle: &str) -> Option<String> {
        let fed = &self.0;
        // The lease names the vehicle's home; without one, the site whose picture has it.
        let home = fed
            .leases()
            .into_iter()
            .find(|r| r.vehicle_id == vehicle)
            .map(|r| r.home)
            .or_else(|| {
                fed.picture(|p| {
                    p.vehicles()
                        .find(|v| v.position.vehicle_id == vehicle)
                        .map(|v| v.site.clone())
                })
            });
        home.filter(|h| h != fed.site())
    }

    fn relay(&self, task: &TaskAssignment) -> Result<(), RelayRefused> {
        self.0.relay_order(task).map_err(|e| RelayRefused::Refused {
            vehicle: task.vehicle_id.clone(),
            site: self.home_of(&task.vehicle_id).unwrap_or_default(),
            why: e.to_string(),
        })
    }

    fn observe(&self, observation: &EnvironmentObservation) {
        if let Err(e) = self.0.push_observation(observation) {
            // Validated by the station already: this is a bug, not bad input.
            warn!(error = %e, "environment observation not aggregated for the federation");
        }
    }

    fn snapshot(&self, now_ms: i64) -> FederationSnapshot {
        let fed = &self.0;
        // Read before the picture: `picture` holds the inbound core, and the lease state is
        // locked before it, never inside it.
        let lease_enabled = fed.lease_enabled();
        let mut snap = fed.picture(|p| FederationSnapshot {
            site: fed.site().to_owned(),
            sites: p
                .sites()
                .map(|(site, st)| SiteView {
                    site: site.to_owned(),
                    online: st.online,
                    since_ms: st.since_ms,
                })
                .collect(),
            vehicles: p
                .vehicles()
                .map(|v| RemoteVehicleView {
                    site: v.site.clone(),
                    vehicle_id: v.position.vehicle_id.clone(),
                    kind: v.position.kind,
                    timestamp_ms: v.position.timestamp_ms,
                    latitude_deg: v.position.latitude_deg,
                    longitude_deg: v.position.longitude_deg,
                    depth_m: v.position.depth_m,
                    heading_deg: v.position.heading_deg,
                    speed_mps: v.position.speed_mps,
                    battery_pct: v.position.battery_pct,
                    age_ms: v.age_ms(now_ms),
                })
                .collect(),
            alarms: p
                .alarms_after(0)
                .map(|a| RemoteAlarmView {
                    site: a.site.clone(),
                    alarm: a.alarm.clone(),
                })
                .collect(),
            transitions: p
                .transitions_after(0)
                .map(|t| RemoteTransitionView {
                    site: t.site.clone(),
                    task_id: t.transition.task_id.clone(),
                    mission_id: t.transition.mission_id.clone(),
                    vehicle_id: t.transition.vehicle_id.clone(),
                    state: t.transition.state,
                    timestamp_ms: t.transition.timestamp_ms,
                })
                .collect(),
            environment: p
                .environment()
                .map(|e| {
                    let s = &e.summary;
                    RemoteEnvironmentView {
                        site: e.site.clone(),
                        vehicle_id: e.vehicle_id.clone(),
                        property: s.property.clone(),
                        unit: s.unit.clone(),
                        window_start_ms: e.window_start_ms,
                        window_end_ms: e.window_end_ms,
                        count: u64::from(s.count),
                        min: s.min,
                        max: s.max,
                        mean: s.mean,
                        last_value: s.last_value,
                        last_ms: s.last_ms,
                        latitude_deg: s.latitude_deg,
                        longitude_deg: s.longitude_deg,
                        depth_m: s.depth_m,
                    }
                })
                .collect(),
            lease_enabled,
            leases: Vec::new(),
            counters: Default::default(),
        });
        snap.leases = fed
            .leases()
            .iter()
            .map(|r| lease_view(r, fed.site()))
            .collect();
        let c = fed.counters();
        let (i, o) = (&c.inbound, &c.outbound);
        for (k, v) in [
            ("received_positions", i.positions),
            ("received_alarms", i.alarms),
            ("received_transitions", i.transitions),
            ("duplicates", i.duplicates),
            ("lost", i.lost),
            ("catchup_queries", i.catchup_queries),
            ("catchup_replies", i.catchup_replies),
            ("received_leases", i.leases),
            ("received_orders", i.orders_received),
            ("accepted_orders", i.orders_accepted),
            ("duplicate_orders", i.order_duplicates),
            ("held_for_identity", i.held_for_identity),
            ("remote_identities", i.identities),
            ("sent_orders", o.orders_sent),
            ("received_environment", i.environment),
            ("environment_observations", o.environment_observations),
            ("environment_not_listed", o.environment_not_listed),
            ("environment_dropped", o.environment_dropped),
            ("sent_environment_aggregates", o.environment_aggregates_sent),
            ("sent_environment_frames", o.environment_frames_sent),
            ("sent_positions", o.positions_sent),
            ("coalesced_positions", o.positions_coalesced),
            ("sent_alarms", o.alarms_sent),
            ("alarms_below_severity", o.alarms_below_severity),
            ("sent_transitions", o.transitions_sent),
            ("catchup_served", o.catchup_served),
            ("catchup_cut", o.catchup_cut),
            ("catchup_dropped", o.catchup_dropped),
            ("queue_full", o.queue_full),
        ] {
            snap.counters.insert(k.to_owned(), v);
        }
        let l = fed.lease_counters();
        for (k, v) in [
            ("leases_stale", l.stale),
            ("leases_granted", l.granted),
            ("leases_failed_over", l.failovers),
            ("leases_taken_later", l.taken_later),
        ] {
            snap.counters.insert(k.to_owned(), v);
        }
        for (reason, n) in &i.refused {
            snap.counters.insert(format!("refused_{reason}"), *n);
        }
        snap
    }
}

/// Dispatches a task that the vehicle's lease holder sent here; a refusal ends the task
/// failed here (the sender sees it in this site's transitions) and is logged.
fn take_order(station: &StationHandle, order: shoal_federation::RelayedOrder) {
    let (task_id, from) = (order.task.task_id.clone(), order.from_site.clone());
    if let Err(e) = station.dispatch_for(&order.from_site, order.task) {
        warn!(task = %task_id, from = %from, error = %e, "task from another site refused");
    }
}

/// Announces to their vehicles the leases this site took since `before` (the leases it
/// held then, vehicle → term; `None` at the first check, which announces nothing): a
/// handover to it or a takeover, not its own claims. Returns the leases held now.
fn announce_new_leases(
    fed: &Federation,
    station: &StationHandle,
    before: Option<&HashMap<String, u64>>,
) -> HashMap<String, u64> {
    let mine: Vec<LeaseRecord> = fed
        .leases()
        .into_iter()
        .filter(|r| r.holder == fed.site())
        .collect();
    if let Some(before) = before {
        for r in &mine {
            let new = before.get(&r.vehicle_id).is_none_or(|term| *term < r.term);
            if new && r.reason != LeaseReason::Claim {
                match station.announce_lease(&r.vehicle_id, r.term) {
                    Ok(task) => {
                        info!(vehicle = %r.vehicle_id, term = r.term, task = %task, "command lease announced to the vehicle");
                    }
                    // Unreached (another site's vehicle whose home is lost, a vehicle out
                    // of contact): its first task under the lease will do it.
                    Err(e) => {
                        info!(vehicle = %r.vehicle_id, term = r.term, error = %e, "command lease not announced to the vehicle");
                    }
                }
            }
        }
    }
    mine.into_iter().map(|r| (r.vehicle_id, r.term)).collect()
}

/// Applies the task transitions that arrived after `after` (a local arrival index) to the
/// tasks this station sent through their sites; the index of the last one seen.
fn follow_sent_tasks(fed: &Federation, station: &StationHandle, after: u64) -> u64 {
    let new: Vec<(u64, String, TaskStatus)> = fed.picture(|p| {
        p.transitions_after(after)
            .map(|t| {
                let status = TaskStatus {
                    task_id: t.transition.task_id.clone(),
                    vehicle_id: t.transition.vehicle_id.clone(),
                    timestamp_ms: t.transition.timestamp_ms,
                    state: t.transition.state,
                    progress_pct: 0.0,
                    message: String::new(),
                };
                (t.index, t.site.clone(), status)
            })
            .collect()
    });
    let mut last = after;
    for (index, site, status) in new {
        station.remote_task_moved(&site, &status);
        last = last.max(index);
    }
    last
}

/// What the bridge has already sent, so the live feed's repeats are not sent again.
#[derive(Default)]
struct Sent {
    alarms: HashSet<String>,
    alarm_order: VecDeque<String>,
    task_states: HashMap<String, shoal_model::TaskState>,
}

impl Sent {
    fn new_alarm(&mut self, id: &str) -> bool {
        if self.alarms.contains(id) {
            return false;
        }
        if self.alarm_order.len() >= ALARMS_REMEMBERED
            && let Some(old) = self.alarm_order.pop_front()
        {
            self.alarms.remove(&old);
        }
        self.alarms.insert(id.to_owned());
        self.alarm_order.push_back(id.to_owned());
        true
    }

    fn new_state(&mut self, task: &str, state: shoal_model::TaskState) -> bool {
        if self.task_states.get(task) == Some(&state) {
            return false;
        }
        if state.is_final() {
            self.task_states.remove(task);
        } else {
            if self.task_states.len() >= TASKS_REMEMBERED {
                self.task_states.clear();
            }
            self.task_states.insert(task.to_owned(), state);
        }
        true
    }
}

/// Where the command leases are kept: `lease.state_file` as given, except `auto`, which
/// is `leases-<site>.json` beside a SQLite history file (so two stations run from one
/// directory keep theirs apart, as their databases).
pub fn lease_file(
    fed: &FederationConfig,
    history: &shoal_history::HistoryConfig,
) -> std::path::PathBuf {
    let auto = fed.lease.state_file == std::path::Path::new(shoal_federation::config::AUTO);
    let sqlite_file =
        history.backend == shoal_history::Backend::Sqlite && history.path.as_os_str() != ":memory:";
    match history.path.parent() {
        Some(dir) if auto && sqlite_file => dir.join(format!("leases-{}.json", fed.site)),
        _ => fed.lease.state_path(&fed.site).unwrap_or_default(),
    }
}

/// Starts the federation, attaches its picture to the station and feeds it the station's
/// live updates until `shutdown`; returns the task that shuts it down at the end.
pub async fn start(
    config: FederationConfig,
    station: StationHandle,
    shutdown: CancellationToken,
) -> Result<tokio::task::JoinHandle<()>> {
    if config.insecure_open {
        // Once per start, on the terminal and in the log, like the other insecure modes.
        let msg = format!(
            "FEDERATION WITHOUT SITE IDENTITY ([federation] insecure_open = true): any Zenoh \
             peer that reaches site {} can claim any site name. Use this only in a lab.",
            config.site
        );
        eprintln!("shoal: WARNING: {msg}");
        warn!("{msg}");
    }
    let insecure_open = config.insecure_open;
    let fed = Arc::new(
        Federation::start(config)
            .await
            .context("cannot start the federation ([federation])")?,
    );
    info!(
        site = fed.site(),
        identity = fed.identity(),
        encrypted = fed.encrypted(),
        "federated over Zenoh ([federation])"
    );
    if !fed.encrypted() && !insecure_open {
        // User-password alone: authenticated, but in clear on the WAN.
        let msg = format!(
            "FEDERATION NOT ENCRYPTED: site {} authenticates with Zenoh's user-password \
             scheme alone ([federation.tls] enabled = false), so positions, alarms and tasks \
             cross in clear and a connecting site cannot check who it reached. Turn on \
             [federation.tls] (docs/federation.md, \"Site identity\").",
            fed.site()
        );
        eprintln!("shoal: WARNING: {msg}");
        warn!("{msg}");
    }
    if station
        .attach_federation(Arc::new(View(Arc::clone(&fed))))
        .is_err()
    {
        warn!("a federation was already attached; this one only sends");
    }
    let mut live = station.live();
    let mut orders = fed.take_orders();
    let mut changed = fed.changed();
    let mut lease_check = tokio::time::interval(std::time::Duration::from_secs(1));
    Ok(tokio::spawn(async move {
        let mut held: Option<HashMap<String, u64>> = None;
        let mut sent = Sent::default();
        let mut lagged = 0u64;
        let mut seen_transition = 0u64;
        loop {
            let update = tokio::select! {
                () = shutdown.cancelled() => break,
                u = live.recv() => u,
                Some(order) = async {
                    match orders.as_mut() {
                        Some(rx) => rx.recv().await,
                        None => std::future::pending().await,
                    }
                } => {
                    take_order(&station, order);
                    continue;
                }
                Ok(()) = changed.changed() => {
                    seen_transition = follow_sent_tasks(&fed, &station, seen_transition);
                    continue;
                }
                _ = lease_check.tick() => {
                    held = Some(announce_new_leases(&fed, &station, held.as_ref()));
                    continue;
                }
            };
            let result = match update {
                Ok(LiveUpdate::Vehicle(v)) => match &v.latest {
                    Some(s) => {
                        fed.push_position(VehiclePosition::from_state(v.announcement.kind, s))
                    }
                    None => Ok(()),
                },
                Ok(LiveUpdate::Event(e)) if sent.new_alarm(&e.event.event_id) => {
                    fed.push_alarm(&e.event)
                }
                Ok(LiveUpdate::Task(t)) if sent.new_state(&t.assignment.task_id, t.state) => fed
                    .push_transition(&TaskTransition {
                        task_id: t.assignment.task_id.clone(),
                        mission_id: t.assignment.mission_id.clone(),
                        vehicle_id: t.assignment.vehicle_id.clone(),
                        state: t.state,
                        timestamp_ms: t.updated_ms,
                    }),
                Ok(_) => Ok(()),
                Err(RecvError::Lagged(n)) => {
                    // Positions come again within a second; a missed alarm or transition
                    // is in the history, and says so here.
                    lagged += n;
                    warn!(
                        missed = n,
                        total = lagged,
                        "federation fell behind the station's live feed"
                    );
                    Ok(())
                }
                Err(RecvError::Closed) => break,
            };
            if let Err(e) = result {
                warn!(error = %e, "not sent over the federation");
            }
        }
        match Arc::try_unwrap(fed) {
            Ok(fed) => {
                if let Err(e) = fed.shutdown().await {
                    warn!(error = %e, "federation did not shut down cleanly");
                }
            }
            // The station's view still holds it: dropping the last handle closes it.
            Err(_) => info!("federation closes with the station"),
        }
    }))
}
