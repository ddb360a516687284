//! The Mission & Task Register and dispatch: pre-dispatch checks, single tasks, missions
//! (plan, start, abort, abort all), sending each task on the link its vehicle is heard on,
//! retries over the acoustic link and expiry of unacknowledged tasks.
//!
//! The register's bookkeeping ([`register`]) is pure; this module adds the I/O: the
//! outbox, the history, the semantic model, the reporters.

mod preview;
mod register;
mod views;

use shoal_history::Record;
use shoal_model::{EventKind, LinkKind, Severity, Task, TaskAssignment, TaskKind, TaskState};
use tracing::{debug, info, warn};

use crate::config::ms;

/// How often, at most, ended tasks past their retention are looked for (a walk over the
/// register, which retention keeps small).
const PRUNE_EVERY_MS: i64 = 1_000;
use crate::core::{StationHandle, blocking, lock};
use crate::error::DispatchError;
use crate::federation::{LeaseDenial, LeaseGrant, RelayRefused};
use crate::register::Contact;
use crate::reporters::LiveUpdate;
pub use preview::{MissionPreview, VehiclePreview};
pub(crate) use register::TaskRegister;
pub use views::{MissionSpec, MissionState, MissionTaskSpec, MissionView, TaskView};

/// A mission's task as planned, and the site it goes through when its vehicle is another
/// site's.
type Planned = (TaskAssignment, Option<String>);

impl StationHandle {
    /// A surface vehicle (USV, ASV) told to go somewhere with neither a depth nor an
    /// altitude goes at the surface: the only depth it has.
    fn surface_by_default(&self, mut task: TaskAssignment) -> TaskAssignment {
        let moves = matches!(task.kind, TaskKind::GotoWaypoint | TaskKind::SurveyArea);
        if moves && task.depth_m == shoal_model::UNKNOWN && task.altitude_m == shoal_model::UNKNOWN
        {
            let surface = lock(&self.core.fleet)
                .vehicles
                .get(&task.vehicle_id)
                .is_some_and(|v| {
                    matches!(
                        v.announcement.kind,
                        shoal_model::VehicleKind::Usv | shoal_model::VehicleKind::Asv
                    )
                });
            if surface {
                task.depth_m = 0.0;
            }
        }
        task
    }

    /// Checks a task can go to its vehicle now: well-formed, the vehicle registered and
    /// in contact, able to do it (its announced capabilities, the register's part of the
    /// information model) and with battery enough for anything but going home or up.
    fn check_task(&self, task: &TaskAssignment) -> Result<LeaseGrant, DispatchError> {
        let moves = matches!(task.kind, TaskKind::GotoWaypoint | TaskKind::SurveyArea);
        if moves && task.depth_m == shoal_model::UNKNOWN && task.altitude_m == shoal_model::UNKNOWN
        {
            // `surface_by_default` left it so: not a surface vehicle. Say what to send
            // rather than the wire form's "exactly one of" (whose -1 a mission never sees).
            return Err(DispatchError::Invalid(
                shoal_model::ValidationError::Inconsistent {
                    field: "depth_m",
                    rule: "neither depth_m nor altitude_m is set, which only a surface vehicle \
                           (USV, ASV) may leave out; give depth_m (0 for the surface) or altitude_m",
                },
            ));
        }
        shoal_model::Validate::validate(task).map_err(DispatchError::Invalid)?;
        task.task().map_err(DispatchError::Invalid)?;
        // The lease a task carries: the one it was last sent under, or, for a task another
        // site sent here for this site's vehicle, that site's.
        let carried = (task.lease_term > 0).then(|| LeaseGrant {
            term: task.lease_term,
            holder: task.lease_holder.clone(),
        });
        self.dispatch_lease(&task.vehicle_id, task.kind, carried.as_ref())
    }

    /// Whether a task of `kind` would go to `vehicle_id` now, as far as the vehicle is
    /// concerned (registered, in contact, announcing the capability, battery enough): the
    /// same check dispatching makes, so that a console can say beforehand what the station
    /// would refuse.
    pub fn check_dispatch(&self, vehicle_id: &str, kind: TaskKind) -> Result<(), DispatchError> {
        self.dispatch_lease(vehicle_id, kind, None).map(|_| ())
    }

    /// [`Self::check_dispatch`], returning the command lease the task would go under: this
    /// station's, or `carried` when that is the lease another site holds now (a task that
    /// site sent here for this site's vehicle).
    fn dispatch_lease(
        &self,
        vehicle_id: &str,
        kind: TaskKind,
        carried: Option<&LeaseGrant>,
    ) -> Result<LeaseGrant, DispatchError> {
        use shoal_model::TaskKind as K;
        let fleet = lock(&self.core.fleet);
        let Some(v) = fleet.vehicles.get(vehicle_id) else {
            return Err(DispatchError::UnknownVehicle(vehicle_id.to_owned()));
        };
        // Exactly one site commands a vehicle, aborts included: a federated site that does
        // not hold the lease asks the holder to hand it over (or takes it over when the
        // holder is lost).
        let lease = match self.may_command(vehicle_id) {
            Ok(lease) => match carried {
                Some(c) if c.holder != lease.holder => {
                    return Err(LeaseDenial::Superseded {
                        vehicle: vehicle_id.to_owned(),
                        sent_holder: c.holder.clone(),
                        sent_term: c.term,
                        holder: lease.holder,
                        term: lease.term,
                    }
                    .into());
                }
                _ => lease,
            },
            Err(LeaseDenial::HeldElsewhere { holder, term, .. })
                if carried.is_some_and(|c| c.holder == holder && c.term == term) =>
            {
                LeaseGrant { term, holder }
            }
            Err(e) => return Err(e.into()),
        };
        if kind == K::Abort {
            // An emergency order always goes out, whatever the vehicle says it can do.
            return Ok(lease);
        }
        if v.contact == Contact::Lost {
            return Err(DispatchError::VehicleLost(vehicle_id.to_owned()));
        }
        let capability = kind.capability();
        if !v.announcement.capabilities.iter().any(|c| c == capability) {
            return Err(DispatchError::Incapable {
                vehicle: vehicle_id.to_owned(),
                capability,
            });
        }
        let needs_energy = !matches!(
            kind,
            K::Surface | K::ReturnHome | K::RequestState | K::SetReportingRate
        );
        let min = self.core.config.min_dispatch_battery_pct;
        if let Some(s) = &v.latest
            && needs_energy
            && s.battery_pct != shoal_model::UNKNOWN
            && s.battery_pct < min
        {
            return Err(DispatchError::LowBattery {
                vehicle: vehicle_id.to_owned(),
                battery_pct: s.battery_pct,
                min_pct: min,
            });
        }
        Ok(lease)
    }

    /// Validates a single task, registers it and sends it at once. Aborts go out on the
    /// emergency priority class.
    pub async fn dispatch(&self, task: TaskAssignment) -> Result<(), DispatchError> {
        self.dispatch_now(task)
    }

    /// [`Self::dispatch`] for code that is not async. A task for another site's vehicle
    /// whose command lease this station holds goes to that site.
    pub fn dispatch_now(&self, mut task: TaskAssignment) -> Result<(), DispatchError> {
        // This station's own lease is stamped at the send; only a task another site sent
        // here may carry another's, and an operator cannot claim one.
        task.lease_term = 0;
        task.lease_holder.clear();
        if let Some(site) = self.site_of_remote(&task.vehicle_id) {
            return self.dispatch_through(task, &site);
        }
        let task = self.surface_by_default(task);
        self.check_task(&task)?;
        {
            let mut reg = lock(&self.core.tasks);
            if reg.contains_task(&task.task_id) {
                return Err(DispatchError::DuplicateTask(task.task_id));
            }
            reg.add_task(task.clone(), self.now());
        }
        self.register_task(&task);
        // The outcome of the write itself: reading the register afterwards would race the
        // vehicle, whose acceptance may already have moved the task past `sent`.
        blocking(|| self.send_registered(&task.task_id))
    }

    /// Makes a vehicle whose command lease this station has just taken (handed over to it,
    /// or taken over) obey that lease at once: a `request_state` task under it, which the
    /// vehicle answers with a state vector, moves the lease its task ledger obeys, so that
    /// an old holder cut off from the federation is refused from then on, not only after
    /// this station's first task. The task's id, `lease-<vehicle>-<term>`.
    pub fn announce_lease(&self, vehicle_id: &str, term: u64) -> Result<String, DispatchError> {
        let id = format!("lease-{vehicle_id}-{term}");
        let task =
            TaskAssignment::new(id.as_str(), "", vehicle_id, self.now(), &Task::RequestState);
        self.dispatch_now(task).map(|()| id)
    }

    /// The site whose vehicle `vehicle` is, when it is not one of this station's own but
    /// another federated site's: its tasks go through that site.
    fn site_of_remote(&self, vehicle: &str) -> Option<String> {
        let local = lock(&self.core.fleet).vehicles.contains_key(vehicle);
        if local { None } else { self.home_of(vehicle) }
    }

    /// Checks a task for `site`'s vehicle as this station can: well formed, and under a
    /// command lease this station holds. The vehicle's own site checks the rest (contact,
    /// capability, battery) when it takes the task, and a refusal comes back as a failed
    /// transition.
    fn check_through(&self, task: &TaskAssignment, site: &str) -> Result<(), DispatchError> {
        shoal_model::Validate::validate(task).map_err(DispatchError::Invalid)?;
        task.task().map_err(DispatchError::Invalid)?;
        let lease = self.may_command(&task.vehicle_id)?;
        if lease.term == 0 {
            return Err(RelayRefused::Refused {
                vehicle: task.vehicle_id.clone(),
                site: site.to_owned(),
                why: "the command lease is off ([federation.lease] enabled = false), so no \
                      site commands another's vehicles"
                    .into(),
            }
            .into());
        }
        Ok(())
    }

    /// Sends a task for `site`'s vehicle to that site, under this station's lease of it:
    /// registered here, its state follows that site's task transitions.
    fn dispatch_through(&self, task: TaskAssignment, site: &str) -> Result<(), DispatchError> {
        self.check_through(&task, site)?;
        {
            let mut reg = lock(&self.core.tasks);
            if reg.contains_task(&task.task_id) {
                return Err(DispatchError::DuplicateTask(task.task_id));
            }
            reg.add_task(task.clone(), self.now());
            reg.set_via_site(&task.task_id, site);
        }
        self.register_task(&task);
        blocking(|| self.send_registered(&task.task_id))
    }

    /// Takes a task that `from_site`, holding the command lease of this site's vehicle,
    /// sent here: checked as any task (the lease it carries must be the one in force), then
    /// given to the vehicle with that lease. A task refused here ends failed, so that the
    /// sender learns it through this site's task transitions.
    pub fn dispatch_for(
        &self,
        from_site: &str,
        mut task: TaskAssignment,
    ) -> Result<(), DispatchError> {
        if task.lease_term == 0 || task.lease_holder != from_site {
            return Err(DispatchError::BadField {
                field: "lease_holder",
                rule: "a task sent by another site carries that site's command lease",
            });
        }
        // This station numbers and times what it sends.
        task.issue_seq = 0;
        task.expires_ms = 0;
        let task = self.surface_by_default(task);
        let checked = self.check_task(&task);
        let mut reg = lock(&self.core.tasks);
        if reg.contains_task(&task.task_id) {
            return Err(DispatchError::DuplicateTask(task.task_id));
        }
        reg.add_task(task.clone(), self.now());
        drop(reg);
        self.register_task(&task);
        if let Err(e) = checked {
            warn!(task = %task.task_id, from = from_site, error = %e, "task from another site not sent");
            self.task_ended(&task.task_id, TaskState::Failed, &format!("not sent: {e}"));
            return Err(e);
        }
        info!(task = %task.task_id, vehicle = %task.vehicle_id, from = from_site, term = task.lease_term, "task from the lease holder");
        blocking(|| self.send_registered(&task.task_id))
    }

    /// Enters a task in the semantic model and the history.
    fn register_task(&self, task: &TaskAssignment) {
        let fired = lock(&self.core.semantic).upsert_task(task);
        self.emit_fired(fired);
        self.store(Record::Task(task.clone()));
    }

    /// Publishes a registered pending task on the link its vehicle is reachable on now.
    ///
    /// Both links start at the same topic: a vehicle on IP takes it directly, and the CDT
    /// that hears a submerged vehicle forwards it acoustically (retransmitting until its
    /// TTL). The station records which link it expects to carry the task, which sets how
    /// long it waits for an acknowledgement before the task expires.
    pub(crate) fn send_registered(&self, task_id: &str) -> Result<(), DispatchError> {
        let Some((task, via_site)) = lock(&self.core.tasks)
            .task(task_id)
            .map(|t| (t.assignment.clone(), t.via_site.clone()))
        else {
            return Err(DispatchError::UnknownTask(task_id.to_owned()));
        };
        if let Some(site) = via_site {
            return self.send_through(&task, &site);
        }
        // Checked again when a mission's next task comes due: things change (the lease
        // too, so the task carries the one in force now).
        let lease = match self.check_task(&task) {
            Ok(lease) => lease,
            Err(e) => {
                warn!(task = task_id, error = %e, "task not sent");
                self.task_ended(task_id, TaskState::Failed, &format!("not sent: {e}"));
                return Err(e);
            }
        };
        let link = lock(&self.core.fleet)
            .vehicles
            .get(&task.vehicle_id)
            .map_or(LinkKind::Ip, |v| v.link);
        let Some(task) =
            lock(&self.core.tasks).stamp(task_id, self.now(), self.start_window_ms(link), &lease)
        else {
            return Err(DispatchError::UnknownTask(task_id.to_owned()));
        };
        // The history keeps the sequence and expiry the vehicle sees.
        self.store(Record::Task(task.clone()));
        let (kind, vehicle) = (task.kind, task.vehicle_id.clone());
        match self.core.outbox.publish_task(task) {
            Ok(()) => {
                info!(task = task_id, vehicle = %vehicle, ?kind, ?link, "task dispatched");
                lock(&self.core.stats).tasks_dispatched += 1;
                lock(&self.core.tasks).sent(task_id, link, self.now());
                self.record_transitions();
                self.refresh_availability(&vehicle, self.now());
                self.push_task(task_id);
                Ok(())
            }
            Err(e) => {
                warn!(task = task_id, error = %e, "task not published");
                lock(&self.core.tasks).finish(
                    task_id,
                    TaskState::Failed,
                    &format!("could not be published: {e}"),
                    self.now(),
                );
                self.record_transitions();
                Err(DispatchError::Publish(e))
            }
        }
    }

    /// [`Self::send_registered`] for a task sent through another site: under this station's
    /// lease, checked again now.
    fn send_through(&self, task: &TaskAssignment, site: &str) -> Result<(), DispatchError> {
        let task_id = task.task_id.as_str();
        let lease = match self.may_command(&task.vehicle_id) {
            Ok(lease) if lease.term > 0 => Ok(lease),
            Ok(_) => Err(DispatchError::Relay(RelayRefused::Refused {
                vehicle: task.vehicle_id.clone(),
                site: site.to_owned(),
                why: "the command lease is off".into(),
            })),
            Err(e) => Err(e.into()),
        };
        let lease = match lease {
            Ok(lease) => lease,
            Err(e) => {
                warn!(task = task_id, error = %e, "task not sent");
                self.task_ended(task_id, TaskState::Failed, &format!("not sent: {e}"));
                return Err(e);
            }
        };
        let window = self.start_window_ms(LinkKind::Acoustic);
        let Some(task) = lock(&self.core.tasks).stamp(task_id, self.now(), window, &lease) else {
            return Err(DispatchError::UnknownTask(task_id.to_owned()));
        };
        self.store(Record::Task(task.clone()));
        match self.relay(&task, site) {
            Ok(()) => {
                info!(task = %task.task_id, vehicle = %task.vehicle_id, site, term = lease.term, "task sent through the vehicle's site");
                lock(&self.core.stats).tasks_dispatched += 1;
                lock(&self.core.tasks).sent(&task.task_id, LinkKind::Ip, self.now());
                self.record_transitions();
                self.push_task(&task.task_id);
                Ok(())
            }
            Err(e) => {
                warn!(task = %task.task_id, error = %e, "task not sent through its vehicle's site");
                self.task_ended(&task.task_id, TaskState::Failed, &format!("not sent: {e}"));
                Err(e.into())
            }
        }
    }

    /// How long after a send the vehicle may still start the task: three quarters of the
    /// acknowledgement timeout on its link, so that its acceptance reaches the station
    /// before the station gives up on the task and expires it.
    fn start_window_ms(&self, link: LinkKind) -> i64 {
        let cfg = &self.core.config;
        let timeout = if link == LinkKind::Acoustic {
            ms(cfg.acoustic_task_ack_timeout_s)
        } else {
            ms(cfg.task_ack_timeout_s)
        };
        timeout / 4 * 3
    }

    /// Retires from the bus the published tasks that have ended, so a vehicle that
    /// restarts, or joins later, is never handed them again.
    pub(crate) fn retire_ended_tasks(&self) {
        let ended = lock(&self.core.tasks).take_ended_on_bus();
        for task in ended {
            match self.core.outbox.retire_task(&task) {
                Ok(()) => {
                    lock(&self.core.stats).tasks_retired += 1;
                    debug!(task = %task.task_id, "ended task retired from the bus");
                }
                Err(e) => {
                    lock(&self.core.stats).tasks_not_retired += 1;
                    warn!(task = %task.task_id, error = %e, "ended task not retired from the bus");
                }
            }
        }
    }

    /// Ends a task in `state` on the station's own account and moves its mission on.
    fn task_ended(&self, task_id: &str, state: TaskState, message: &str) {
        lock(&self.core.tasks).finish(task_id, state, message, self.now());
        self.task_changed(task_id, state, message);
    }

    /// Sends the tasks that became due; a refused one has ended the task already.
    pub(crate) fn send_all(&self, task_ids: Vec<String>) {
        blocking(|| {
            for id in task_ids {
                let _ = self.send_registered(&id);
            }
        });
    }

    /// A mission's tasks as they would go out, every one checked (ids unique, vehicles
    /// able), with the time they are issued at; beside each, the site it goes through when
    /// its vehicle is another site's.
    fn mission_assignments(
        &self,
        spec: &MissionSpec,
    ) -> Result<(i64, Vec<Planned>), DispatchError> {
        if !shoal_model::is_identifier(&spec.mission_id, shoal_model::MAX_ID_LEN) {
            return Err(DispatchError::BadField {
                field: "mission_id",
                rule: "1..=64 of [A-Za-z0-9_.-]",
            });
        }
        if spec.tasks.is_empty() {
            return Err(DispatchError::BadField {
                field: "tasks",
                rule: "a mission needs at least one task",
            });
        }
        if lock(&self.core.tasks).contains_mission(&spec.mission_id) {
            return Err(DispatchError::DuplicateMission(spec.mission_id.clone()));
        }
        let now = self.now();
        let mut assignments: Vec<TaskAssignment> = Vec::with_capacity(spec.tasks.len());
        let mut through: Vec<Option<String>> = Vec::with_capacity(spec.tasks.len());
        for (n, t) in spec.tasks.iter().enumerate() {
            let id = t
                .task_id
                .clone()
                .unwrap_or_else(|| format!("{}-{}", spec.mission_id, n + 1));
            // One millisecond apart, so that the history keeps the mission's order.
            let issued = now + i64::try_from(n).unwrap_or(0);
            let a = self.surface_by_default(TaskAssignment::new(
                id,
                &spec.mission_id,
                &t.vehicle_id,
                issued,
                &t.task,
            ));
            let in_mission = |error| DispatchError::InMission {
                index: n,
                error: Box::new(error),
            };
            let site = self.site_of_remote(&a.vehicle_id);
            match &site {
                Some(site) => self.check_through(&a, site),
                None => self.check_task(&a).map(|_| ()),
            }
            .map_err(in_mission)?;
            if assignments.iter().any(|b| b.task_id == a.task_id)
                || lock(&self.core.tasks).contains_task(&a.task_id)
            {
                return Err(in_mission(DispatchError::DuplicateTask(a.task_id)));
            }
            assignments.push(a);
            through.push(site);
        }
        // A vehicle's next task in a mission goes out when its task before has ended: a
        // hold until the next task never would, and both would wait for ever.
        for (n, a) in assignments.iter().enumerate() {
            let open_hold = a.kind == TaskKind::Hold && a.duration_s == 0.0;
            if open_hold
                && assignments[n + 1..]
                    .iter()
                    .any(|b| b.vehicle_id == a.vehicle_id)
            {
                return Err(DispatchError::InMission {
                    index: n,
                    error: Box::new(DispatchError::BadField {
                        field: "duration_s",
                        rule: "a hold of 0 s (until the next task) must be its vehicle's last \
                               task in the mission: the next one is sent only when it ends; \
                               give it a duration",
                    }),
                });
            }
        }
        Ok((now, assignments.into_iter().zip(through).collect()))
    }

    /// Registers a mission after checking every task (ids unique, vehicles able); it
    /// starts with [`Self::start_mission`].
    pub fn plan_mission(&self, spec: MissionSpec) -> Result<MissionView, DispatchError> {
        let (now, assignments) = self.mission_assignments(&spec)?;
        {
            let mut reg = lock(&self.core.tasks);
            let ids = assignments.iter().map(|(a, _)| a.task_id.clone()).collect();
            for (a, site) in &assignments {
                reg.add_task(a.clone(), now);
                if let Some(site) = site {
                    reg.set_via_site(&a.task_id, site);
                }
            }
            reg.add_mission(&spec.mission_id, &spec.name, ids, now);
        }
        for (a, _) in &assignments {
            self.register_task(a);
        }
        info!(mission = %spec.mission_id, tasks = assignments.len(), "mission planned");
        let view = self
            .mission(&spec.mission_id)
            .ok_or(DispatchError::UnknownMission(spec.mission_id))?;
        self.publish_live(LiveUpdate::Mission(Box::new(view.clone())));
        Ok(view)
    }

    /// Starts a planned mission: each vehicle's first task goes out.
    pub fn start_mission(&self, mission_id: &str) -> Result<MissionView, DispatchError> {
        let first = lock(&self.core.tasks)
            .start(mission_id, self.now())
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))?;
        info!(mission = mission_id, "mission started");
        self.send_all(first);
        self.mission(mission_id)
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))
    }

    /// Aborts a mission: pending tasks end, vehicles with a task under way get an abort
    /// (emergency surface) on the emergency class.
    pub fn abort_mission(&self, mission_id: &str) -> Result<MissionView, DispatchError> {
        let busy = lock(&self.core.tasks)
            .abort_mission(mission_id, self.now())
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))?;
        self.record_transitions();
        warn!(mission = mission_id, vehicles = ?busy, "mission aborted");
        self.raise(
            Severity::Warning,
            EventKind::Task,
            "",
            "",
            &format!("mission {mission_id} aborted by the operator"),
        );
        blocking(|| {
            for v in busy {
                self.send_abort(&v, mission_id);
            }
        });
        self.mission(mission_id)
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))
    }

    /// Aborts every open mission and sends an abort to every vehicle in contact.
    pub fn abort_all(&self) -> Vec<String> {
        let missions = lock(&self.core.tasks).open_missions();
        let mut busy = Vec::new();
        for m in &missions {
            busy.extend(
                lock(&self.core.tasks)
                    .abort_mission(m, self.now())
                    .unwrap_or_default(),
            );
        }
        self.record_transitions();
        let mut vehicles: Vec<String> = lock(&self.core.fleet)
            .vehicles
            .iter()
            .filter(|(_, v)| v.contact != Contact::Lost)
            .map(|(id, _)| id.clone())
            .collect();
        // Other sites' vehicles busy with this station's missions: aborted through their
        // sites (under the lease this station holds).
        for v in busy {
            if !vehicles.contains(&v) && self.site_of_remote(&v).is_some() {
                vehicles.push(v);
            }
        }
        self.raise(
            Severity::Alarm,
            EventKind::Task,
            "",
            "",
            &format!(
                "ABORT ALL by the operator: {} vehicles, {} missions",
                vehicles.len(),
                missions.len()
            ),
        );
        blocking(|| {
            for v in &vehicles {
                self.send_abort(v, "all");
            }
        });
        vehicles
    }

    fn send_abort(&self, vehicle_id: &str, scope: &str) {
        let seq = self.next_seq();
        let id: String = format!("abort-{scope}-{vehicle_id}-{seq}")
            .chars()
            .take(shoal_model::MAX_ID_LEN)
            .collect();
        let a = TaskAssignment::new(&id, "", vehicle_id, self.now(), &Task::Abort);
        // Another site's vehicle on a mission of this station's: through its site. Asked
        // before the register is locked, so that the fleet's lock is not taken inside it.
        let through = self.site_of_remote(vehicle_id);
        {
            let mut reg = lock(&self.core.tasks);
            reg.add_task(a.clone(), self.now());
            if let Some(site) = through {
                reg.set_via_site(&id, &site);
            }
        }
        self.register_task(&a);
        if let Err(e) = self.send_registered(&id) {
            warn!(vehicle = vehicle_id, error = %e, "abort not sent");
        }
    }

    /// Expires sent tasks their vehicle never acknowledged in time (at `now`).
    pub(crate) fn expire_tasks(&self, now: i64) {
        let cfg = &self.core.config;
        let (ip, acoustic) = (
            ms(cfg.task_ack_timeout_s),
            ms(cfg.acoustic_task_ack_timeout_s),
        );
        let overdue = lock(&self.core.tasks).overdue(now, ip, acoustic);
        for id in overdue {
            let msg = "not acknowledged by the vehicle in time";
            lock(&self.core.tasks).finish(&id, TaskState::Expired, msg, now);
            self.task_changed(&id, TaskState::Expired, msg);
        }
    }

    /// Forgets tasks and missions that ended longer than `task_retention_s` ago, and the
    /// oldest ended ones beyond `max_ended_tasks`, in the register and the semantic model
    /// (the history keeps them). Runs at most once a second: it walks every task.
    pub(crate) fn prune_tasks(&self, now: i64) {
        let gone = {
            let mut reg = lock(&self.core.tasks);
            if now - reg.pruned_ms < PRUNE_EVERY_MS {
                return;
            }
            reg.pruned_ms = now;
            reg.prune(
                now - ms(self.core.config.task_retention_s),
                self.core.config.max_ended_tasks,
            )
        };
        if gone.is_empty() {
            return;
        }
        let mut semantic = lock(&self.core.semantic);
        for id in &gone {
            if let Err(e) = semantic.forget_task(id) {
                warn!(task = %id, error = %e, "ended task not removed from the semantic model");
            }
        }
        drop(semantic);
        lock(&self.core.stats).tasks_forgotten += gone.len() as u64;
        info!(
            tasks = gone.len(),
            "ended tasks past their retention forgotten (the history keeps them)"
        );
    }

    /// The tasks restored missions are waiting for (after a restart); sent at once.
    /// Tasks that were under way are published again first, unchanged, so a vehicle that
    /// restarts can resume the one it was doing (one that already has it ignores it).
    pub(crate) fn resume_missions(&self) {
        let under_way = lock(&self.core.tasks).under_way();
        for task in under_way {
            let id = task.task_id.clone();
            match self.core.outbox.publish_task(task) {
                Ok(()) => lock(&self.core.tasks).republished(&id),
                Err(e) => warn!(task = %id, error = %e, "task under way not published again"),
            }
        }
        let due = lock(&self.core.tasks).due_tasks();
        if !due.is_empty() {
            info!(
                tasks = due.len(),
                "sending the tasks restored missions are waiting for"
            );
            self.send_all(due);
        }
    }

    /// Tasks issued since the station started, by id.
    pub fn tasks(&self) -> Vec<TaskView> {
        lock(&self.core.tasks).tasks()
    }

    /// One task.
    pub fn task(&self, task_id: &str) -> Option<TaskView> {
        lock(&self.core.tasks).task(task_id).cloned()
    }

    /// Every mission, by id.
    pub fn missions(&self) -> Vec<MissionView> {
        lock(&self.core.tasks).missions()
    }

    /// One mission.
    pub fn mission(&self, mission_id: &str) -> Option<MissionView> {
        lock(&self.core.tasks).mission(mission_id)
    }

    /// Remote readers matched by the station's (control-class) task writer now.
    pub fn task_readers(&self) -> i32 {
        self.core.outbox.task_readers()
    }
}

#[cfg(test)]
mod tests;
