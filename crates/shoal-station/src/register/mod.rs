//! The Vehicle & Service Register: which vehicles exist, what they can do, whether they
//! are heard (contact) and what they can be asked to do now (availability).
//!
//! It is the one owner of a vehicle's live state: the semantic model receives each
//! availability change from here and never decides contact or availability itself.

mod fleet;

use shoal_history::Record;
use shoal_model::{Availability, EventKind, LinkKind, LinkStatus, Severity, VehicleAnnouncement};
use tracing::{debug, info, warn};

use crate::config::ms;
use crate::core::{StationHandle, lock};
use crate::error::Rejection;
use crate::reporters::LiveUpdate;
pub(crate) use fleet::Fleet;
pub use fleet::{Contact, VehicleView};

/// INFO lines a second for registrations and contact changes together; beyond, a debug
/// line each, the next INFO line says how many were left out, and the fleet summary
/// counts vehicles by contact (ten thousand vehicles coming alive make ten thousand
/// changes, which help nobody one by one).
pub(crate) const FLEET_LOG_LINES_PER_S: u32 = 10;

impl StationHandle {
    /// Registers (or re-registers) a vehicle as if it had announced itself, e.g. from the
    /// operator's tool; the announcement is validated first.
    pub fn register_vehicle(
        &self,
        a: VehicleAnnouncement,
    ) -> Result<(), shoal_model::ValidationError> {
        let a = shoal_model::Validated::new(a).map_err(|(e, _)| e)?;
        self.register(a.into_inner(), "operator", None);
        Ok(())
    }

    /// A vehicle announced itself on the bus, through `participant` (its own, or the
    /// CDT's that relays it); re-announcing is idempotent.
    pub fn ingest_announcement(
        &self,
        a: shoal_model::Validated<VehicleAnnouncement>,
        writer: &str,
        participant: &str,
    ) {
        self.register(a.into_inner(), writer, Some(participant));
    }

    fn register(&self, a: VehicleAnnouncement, source: &str, participant: Option<&str>) {
        let id = a.vehicle_id.clone();
        let new = {
            let mut fleet = lock(&self.core.fleet);
            let max = self.core.config.max_unheard_vehicles;
            if fleet.unheard >= max && !fleet.vehicles.contains_key(&id) {
                drop(fleet);
                let why = Rejection::TooManyUnheard { max };
                self.count_rejection(&why.reason());
                self.alert_rejection("vehicle announcement", "", &why.reason(), &why.to_string());
                return;
            }
            let new = fleet.register(a.clone());
            if let (Some(p), Some(e)) = (participant, fleet.vehicles.get_mut(&id)) {
                e.participant = Some(p.to_owned());
            }
            new
        };
        lock(&self.core.stats).announcements += 1;
        let fired = lock(&self.core.semantic).upsert_vehicle(&a);
        self.emit_fired(fired);
        // After the fleet knows the vehicle: what waited for this announcement goes in now.
        self.release_early_states(&id);
        if new {
            match self.fleet_line() {
                Some(0) => {
                    info!(vehicle = %id, kind = %a.kind, vendor = %a.vendor, source, "vehicle registered");
                }
                Some(left_out) => info!(
                    vehicle = %id,
                    kind = %a.kind,
                    vendor = %a.vendor,
                    source,
                    left_out,
                    "vehicle registered (and {left_out} more registrations or contact changes not logged one by one; the fleet summary counts them)"
                ),
                None => debug!(vehicle = %id, kind = %a.kind, source, "vehicle registered"),
            }
            self.mirror_availability(&id);
        } else {
            debug!(vehicle = %id, "vehicle re-announced");
        }
        self.store(Record::Vehicle(a));
    }

    /// DDS discovery says a participant left: the vehicles heard through it are lost now.
    pub fn participant_left(&self, participant: &str, reason: &str) {
        let gone = lock(&self.core.fleet).participant_left(participant, self.now());
        for id in gone {
            info!(vehicle = %id, %participant, reason, "the vehicle's DDS participant left");
        }
    }

    /// A CDT reports the link it hears a vehicle on.
    pub(crate) fn link_reported(&self, status: LinkStatus) {
        let mut fleet = lock(&self.core.fleet);
        if let Some(v) = fleet.vehicles.get_mut(&status.vehicle_id) {
            if v.link != status.link {
                info!(vehicle = %status.vehicle_id, link = ?status.link, "vehicle heard on a new link");
            }
            v.link = status.link;
            if status.link == LinkKind::Acoustic {
                v.acoustic_via = Some(status.participant.clone());
            }
            v.link_status = Some(status);
        }
    }

    /// A vehicle reported a fault: unavailable for a while.
    pub(crate) fn fault_reported(&self, vehicle_id: &str) {
        let now = self.now();
        if let Some(v) = lock(&self.core.fleet).vehicles.get_mut(vehicle_id) {
            v.last_fault_ms = Some(now);
        }
        self.refresh_heard_availability(vehicle_id, now);
    }

    /// Decides a vehicle's availability again after its tasks changed (and maybe its
    /// contact, faults or charging), asking the Mission & Task Register whether it is
    /// busy, and mirrors a change into the semantic model.
    pub(crate) fn refresh_availability(&self, vehicle_id: &str, now: i64) {
        let busy = !lock(&self.core.tasks)
            .active_tasks_of(vehicle_id)
            .is_empty();
        self.decide_availability(vehicle_id, now, Some(busy));
    }

    /// [`Self::refresh_availability`] when the vehicle's tasks did not change (a state
    /// vector, a fault, contact): the busy flag the register holds stands, so only the
    /// fleet's lock is taken. Ingest calls this for every state vector; asking the task
    /// register would scan every task each time.
    pub(crate) fn refresh_heard_availability(&self, vehicle_id: &str, now: i64) {
        self.decide_availability(vehicle_id, now, None);
    }

    fn decide_availability(&self, vehicle_id: &str, now: i64, busy: Option<bool>) {
        let changed = lock(&self.core.fleet)
            .vehicles
            .get_mut(vehicle_id)
            .and_then(|e| {
                if let Some(busy) = busy {
                    e.busy = busy;
                }
                e.refresh_availability(now)
            });
        if let Some(a) = changed {
            self.set_semantic_availability(vehicle_id, a);
        }
    }

    /// [`Self::refresh_availability`] for every vehicle (faults age out with time).
    pub(crate) fn refresh_availability_all(&self, now: i64) {
        let busy: std::collections::HashSet<String> = lock(&self.core.tasks)
            .busy_vehicles()
            .into_iter()
            .map(str::to_owned)
            .collect();
        let changed: Vec<(String, Availability)> = lock(&self.core.fleet)
            .vehicles
            .iter_mut()
            .filter_map(|(id, e)| {
                e.busy = busy.contains(id);
                e.refresh_availability(now).map(|a| (id.clone(), a))
            })
            .collect();
        for (id, a) in changed {
            self.set_semantic_availability(&id, a);
        }
    }

    /// Writes a vehicle's current availability to the semantic model as it stands.
    fn mirror_availability(&self, vehicle_id: &str) {
        let a = lock(&self.core.fleet)
            .vehicles
            .get(vehicle_id)
            .map(|e| e.availability);
        if let Some(a) = a {
            self.set_semantic_availability(vehicle_id, a);
        }
    }

    fn set_semantic_availability(&self, vehicle_id: &str, a: Availability) {
        debug!(
            vehicle = vehicle_id,
            availability = a.as_str(),
            "availability"
        );
        if let Err(e) = lock(&self.core.semantic).set_availability(vehicle_id, a) {
            warn!(vehicle = vehicle_id, error = %e, "availability not in the semantic model");
        }
    }

    /// Re-evaluates contact at `now`: stale and lost vehicles, lost at once when their
    /// participant left; a CommLost alarm on loss, an event when contact comes back.
    pub(crate) fn refresh_contact(&self, now: i64) {
        let cfg = &self.core.config;
        let (stale, lost) = (ms(cfg.stale_after_s), ms(cfg.lost_after_s));
        let changed = lock(&self.core.fleet).refresh_contact(now, stale, lost);
        for (id, from, to) in changed {
            self.contact_changed(&id, from, to, now);
        }
    }

    /// A vehicle's own report on its task (accepted, running, done) reached the station:
    /// it is heard, whatever its state vectors do. Over a slow acoustic link the report of
    /// a finished task can be the first thing through after an outage, and the mission's
    /// next task must not be refused because the vehicle still counts as lost.
    pub(crate) fn heard_from(&self, vehicle_id: &str, now: i64) {
        let changed = lock(&self.core.fleet).heard(vehicle_id, now);
        if let Some((from, to)) = changed {
            self.contact_changed(vehicle_id, from, to, now);
        }
    }

    /// Tells of a contact change: an alarm on loss, an event on regaining, a log line, the
    /// availability it implies and the live feed.
    fn contact_changed(&self, id: &str, from: Contact, to: Contact, now: i64) {
        let cfg = &self.core.config;
        let id = id.to_owned();
        match to {
            Contact::Lost => {
                let left = lock(&self.core.fleet).vehicles.get(&id).is_some_and(|e| {
                    e.left_ms
                        .is_some_and(|l| e.last_contact_ms.is_some_and(|t| l >= t))
                });
                let text = if left {
                    format!("lost contact with {id}: its DDS participant left")
                } else {
                    format!("no state vector from {id} for {:.0} s", cfg.lost_after_s)
                };
                self.raise(Severity::Alarm, EventKind::CommLost, &id, "", &text);
            }
            Contact::Alive if from == Contact::Lost => {
                self.raise(
                    Severity::Info,
                    EventKind::Other,
                    &id,
                    "",
                    &format!("contact with {id} regained"),
                );
            }
            _ => {}
        }
        match self.fleet_line() {
            Some(0) => info!(vehicle = %id, from = ?from, to = ?to, "contact changed"),
            Some(left_out) => info!(
                vehicle = %id,
                from = ?from,
                to = ?to,
                left_out,
                "contact changed (and {left_out} more registrations or contact changes not logged one by one; the fleet summary counts them)"
            ),
            None => debug!(vehicle = %id, from = ?from, to = ?to, "contact changed"),
        }
        self.refresh_heard_availability(&id, now);
        // Stale and lost happen exactly when the vehicle sends nothing, so no state
        // carries the change to live clients: push the vehicle's view now.
        if let Some(v) = self.vehicle(&id) {
            self.publish_live(LiveUpdate::Vehicle(Box::new(v)));
        }
    }

    /// Every known vehicle, sorted by id.
    pub fn fleet(&self) -> Vec<VehicleView> {
        lock(&self.core.fleet).view()
    }

    /// One vehicle.
    pub fn vehicle(&self, id: &str) -> Option<VehicleView> {
        lock(&self.core.fleet)
            .vehicles
            .get(id)
            .map(fleet::Entry::view)
    }

    /// Whether a registration or contact change gets its own INFO line: `Some(n)` yes,
    /// with `n` left out before it; `None`: over the budget, a debug line only.
    fn fleet_line(&self) -> Option<u64> {
        lock(&self.core.fleet_log).take(std::time::Instant::now())
    }

    /// Registration and contact-change lines left out of the log so far.
    pub fn fleet_lines_not_logged(&self) -> u64 {
        lock(&self.core.fleet_log).left_out_total()
    }

    /// Logs the fleet: a line per vehicle for a small fleet, counts by contact for a large
    /// one (ten thousand lines every few seconds help nobody). The lines are formatted
    /// after the fleet's lock is released, since ingest takes it for every state vector.
    pub(crate) fn log_summary(&self) {
        const VEHICLE_LINES_UP_TO: usize = 20;
        let now = self.now();
        let (mut lines, mut counts) = (Vec::new(), None);
        let fleet = lock(&self.core.fleet);
        let total = fleet.vehicles.len();
        if total <= VEHICLE_LINES_UP_TO {
            lines = fleet.view();
        } else {
            let count = |c| fleet.vehicles.values().filter(|e| e.contact == c).count();
            counts = Some(
                [
                    Contact::Alive,
                    Contact::Stale,
                    Contact::Lost,
                    Contact::Silent,
                ]
                .map(count),
            );
        }
        drop(fleet);
        if total == 0 {
            info!("no vehicles yet");
        }
        if let Some([alive, stale, lost, silent]) = counts {
            let changes_not_logged = self.fleet_lines_not_logged();
            info!(
                vehicles = total,
                alive, stale, lost, silent, changes_not_logged, "fleet"
            );
        }
        for v in lines {
            let (id, kind) = (&v.announcement.vehicle_id, v.announcement.kind.as_str());
            #[allow(clippy::cast_precision_loss)]
            let ago = v.last_contact_ms.map_or_else(
                || "never".to_string(),
                |t| format!("{:.1}s ago", (now - t) as f64 / 1000.0),
            );
            let n = v.states_accepted;
            match &v.latest {
                Some(s) => info!(
                    "{id:<10} {kind:<6} {contact:<6} lat {lat:>9.5} lon {lon:>10.5} depth {depth:>6.1} m speed {speed:>4.1} m/s heading {yaw:>5.1} battery {batt:>5.1}% last {ago} states {n}",
                    contact = format!("{:?}", v.contact).to_lowercase(),
                    lat = s.latitude_deg,
                    lon = s.longitude_deg,
                    depth = s.depth_m,
                    speed = s.speed_mps,
                    yaw = s.yaw_deg,
                    batt = s.battery_pct,
                ),
                None => info!("{id:<10} {kind:<6} announced, no state yet"),
            }
        }
        let stats = self.stats();
        info!(
            accepted = stats.states_accepted,
            rejected = stats.total_rejected(),
            history_committed = self.history_committed(),
            "ingest"
        );
    }
}

#[cfg(test)]
mod tests;
