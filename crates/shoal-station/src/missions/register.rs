//! The Mission & Task Register's bookkeeping: every task the station issued with its state machine, and
//! missions as ordered task lists per vehicle.
//!
//! Pure bookkeeping, no I/O: the station asks it what to dispatch and feeds it the
//! vehicles' reports, so the rules below are tested without DDS.
//!
//! - A task moves forward only: pending → sent → accepted → running (progress) → done |
//!   failed | aborted | expired. A report that would move it backwards, or touch a final
//!   task, is ignored (late or duplicated delivery, e.g. over the acoustic link).
//! - A mission runs each vehicle's tasks one at a time, in order: the next is dispatched
//!   when the previous is done. When a task fails, expires or is aborted, the vehicle's
//!   remaining tasks in that mission are aborted ("skipped"); the mission ends `done` when
//!   every task is done, otherwise `failed` (or `aborted` by an operator).
//! - Each send stamps the task with the next issue sequence (never repeated, also across
//!   restarts: it continues from the history's highest) and a start-by expiry. A task on
//!   the bus is retired (disposed) once it has ended, so the bus holds live tasks only.

use std::collections::{BTreeMap, HashMap, HashSet};

use shoal_model::{LinkKind, TaskAssignment, TaskState, TaskStatus};

use crate::federation::LeaseGrant;

use super::views::{MissionState, MissionView, TaskView};

#[derive(Debug, Clone)]
struct Mission {
    mission_id: String,
    name: String,
    state: MissionState,
    created_ms: i64,
    started_ms: Option<i64>,
    ended_ms: Option<i64>,
    task_ids: Vec<String>,
}

/// Every task and mission.
#[derive(Debug, Default)]
pub(crate) struct TaskRegister {
    tasks: BTreeMap<String, TaskView>,
    missions: BTreeMap<String, Mission>,
    mission_of: HashMap<String, String>,
    /// State changes the station itself made (sent, skipped, aborted, expired), to be
    /// written to the history as task status reports so it holds every transition.
    transitions: Vec<TaskStatus>,
    /// The last issue sequence given to a task.
    last_seq: u64,
    /// Tasks published and not yet retired from the bus.
    on_bus: HashSet<String>,
    /// When retention last ran (station time).
    pub(crate) pruned_ms: i64,
}

/// Rank in the state machine; a report may only keep or raise it.
fn rank(s: TaskState) -> u8 {
    match s {
        TaskState::Pending => 0,
        TaskState::Sent => 1,
        TaskState::Accepted => 2,
        TaskState::Running => 3,
        _ => 4,
    }
}

/// Sent to its vehicle and not final: the vehicle is busy with it.
fn under_way(s: TaskState) -> bool {
    !s.is_final() && s != TaskState::Pending
}

/// True when a task in `from` may move to `to`.
pub(crate) fn may_move(from: TaskState, to: TaskState) -> bool {
    !from.is_final() && rank(to) >= rank(from) && to != TaskState::Pending
}

impl TaskRegister {
    pub(crate) fn contains_task(&self, task_id: &str) -> bool {
        self.tasks.contains_key(task_id)
    }

    pub(crate) fn contains_mission(&self, mission_id: &str) -> bool {
        self.missions.contains_key(mission_id)
    }

    pub(crate) fn task(&self, task_id: &str) -> Option<&TaskView> {
        self.tasks.get(task_id)
    }

    pub(crate) fn tasks(&self) -> Vec<TaskView> {
        self.tasks.values().cloned().collect()
    }

    /// Tasks under way (sent, accepted or running) of one vehicle.
    pub(crate) fn active_tasks_of(&self, vehicle_id: &str) -> Vec<&TaskView> {
        self.tasks
            .values()
            .filter(|t| t.assignment.vehicle_id == vehicle_id && under_way(t.state))
            .collect()
    }

    /// Vehicles with a task under way.
    pub(crate) fn busy_vehicles(&self) -> HashSet<&str> {
        self.tasks
            .values()
            .filter(|t| under_way(t.state))
            .map(|t| t.assignment.vehicle_id.as_str())
            .collect()
    }

    /// Registers a task in `pending`.
    pub(crate) fn add_task(&mut self, assignment: TaskAssignment, now_ms: i64) {
        let id = assignment.task_id.clone();
        self.tasks.insert(
            id,
            TaskView {
                assignment,
                state: TaskState::Pending,
                progress_pct: 0.0,
                message: String::new(),
                updated_ms: now_ms,
                dispatched_ms: None,
                started_ms: None,
                ended_ms: None,
                link: None,
                status: None,
                retries: 0,
                via_site: None,
            },
        );
    }

    /// Marks a registered task as sent through `site` (another site's vehicle).
    pub(crate) fn set_via_site(&mut self, task_id: &str, site: &str) {
        if let Some(t) = self.tasks.get_mut(task_id) {
            t.via_site = Some(site.to_owned());
        }
    }

    /// Registers a mission whose tasks were checked and added with [`Self::add_task`].
    pub(crate) fn add_mission(
        &mut self,
        mission_id: &str,
        name: &str,
        task_ids: Vec<String>,
        now_ms: i64,
    ) {
        for t in &task_ids {
            self.mission_of.insert(t.clone(), mission_id.to_owned());
        }
        self.missions.insert(
            mission_id.to_owned(),
            Mission {
                mission_id: mission_id.to_owned(),
                name: name.to_owned(),
                state: MissionState::Planned,
                created_ms: now_ms,
                started_ms: None,
                ended_ms: None,
                task_ids,
            },
        );
    }

    /// Continues the issue sequence after `seq` (the highest the history holds).
    pub(crate) fn continue_sequence_after(&mut self, seq: u64) {
        self.last_seq = self.last_seq.max(seq);
    }

    /// Stamps a task about to be published: its issue sequence (the next one, unless it
    /// has one from an earlier send), an expiry `start_window_ms` from now and the command
    /// lease it goes under. Returns the assignment to publish, or `None` for an unknown
    /// task.
    pub(crate) fn stamp(
        &mut self,
        task_id: &str,
        now_ms: i64,
        start_window_ms: i64,
        lease: &LeaseGrant,
    ) -> Option<TaskAssignment> {
        let t = self.tasks.get_mut(task_id)?;
        t.assignment.lease_term = lease.term;
        t.assignment.lease_holder.clone_from(&lease.holder);
        if t.assignment.issue_seq == 0 {
            self.last_seq += 1;
            t.assignment.issue_seq = self.last_seq;
        }
        t.assignment.expires_ms = now_ms
            .saturating_add(start_window_ms)
            .max(t.assignment.issued_ms);
        Some(t.assignment.clone())
    }

    /// Marks a task handed to a link.
    pub(crate) fn sent(&mut self, task_id: &str, link: LinkKind, now_ms: i64) {
        let Some(t) = self.tasks.get_mut(task_id) else {
            return;
        };
        // One sent through another site was never on this station's bus.
        if t.via_site.is_none() {
            self.on_bus.insert(task_id.to_owned());
        }
        // The dispatch time is this send, the station's own step between planning and the
        // vehicle (a mission's task waits `pending`, possibly long, for its turn). It is noted
        // even when the state does not move: the vehicle's acceptance can be applied before
        // this call (the write races it), and the task was sent all the same, no later than
        // what the vehicle then reported. A retry's send keeps the first one.
        let at = t
            .started_ms
            .or(t.ended_ms)
            .map_or(now_ms, |s| s.min(now_ms));
        note_time(t, TaskState::Sent, at);
        if may_move(t.state, TaskState::Sent) {
            t.state = TaskState::Sent;
            t.link = Some(link);
            t.updated_ms = now_ms;
            t.message = match &t.via_site {
                Some(site) => format!("sent through site {site}"),
                None => format!("sent over {}", link_name(link)),
            };
            let record = transition(t, now_ms);
            self.transitions.push(record);
        }
    }

    /// Tasks on the bus that have ended since the last call, now forgotten as on the bus:
    /// the ones to retire. Costs the number of tasks on the bus, which is bounded by the
    /// live ones.
    pub(crate) fn take_ended_on_bus(&mut self) -> Vec<TaskAssignment> {
        let tasks = &self.tasks;
        let mut ended = Vec::new();
        self.on_bus.retain(|id| match tasks.get(id) {
            Some(t) if t.state.is_final() => {
                ended.push(t.assignment.clone());
                false
            }
            Some(_) => true,
            None => false,
        });
        ended
    }

    /// Forgets what ended before `before_ms`: tasks outside missions, and missions with all
    /// their tasks once the mission has ended. Returns the task ids forgotten. Nothing
    /// that is live, or belongs to a live mission, is touched.
    /// Beyond `max_ended` ended tasks, the oldest go too (an ended mission goes whole), so
    /// a fleet that finishes tasks fast cannot grow the register within the time.
    pub(crate) fn prune(&mut self, before_ms: i64, max_ended: usize) -> Vec<String> {
        // What may go, oldest first: ended missions (with their tasks) and ended tasks
        // outside missions, each with when it ended.
        let mut units: Vec<(i64, Option<String>, Vec<String>)> = self
            .missions
            .values()
            .filter_map(|m| {
                m.ended_ms
                    .map(|t| (t, Some(m.mission_id.clone()), m.task_ids.clone()))
            })
            .collect();
        units.extend(
            self.tasks
                .values()
                .filter(|t| {
                    t.state.is_final() && !self.mission_of.contains_key(&t.assignment.task_id)
                })
                .map(|t| (t.updated_ms, None, vec![t.assignment.task_id.clone()])),
        );
        units.sort_unstable_by_key(|(t, ..)| *t);
        let mut ended: usize = units.iter().map(|(_, _, ids)| ids.len()).sum();
        let mut gone: Vec<String> = Vec::new();
        for (t, mission, ids) in units {
            if t >= before_ms && ended <= max_ended {
                break;
            }
            ended -= ids.len();
            if let Some(m) = mission {
                self.missions.remove(&m);
            }
            gone.extend(ids);
        }
        for id in &gone {
            self.tasks.remove(id);
            self.mission_of.remove(id);
            self.on_bus.remove(id);
        }
        gone
    }

    /// How many tasks and missions it holds.
    pub(crate) fn sizes(&self) -> (usize, usize) {
        (self.tasks.len(), self.missions.len())
    }

    /// Tasks under way (sent, accepted or running): what a restarted station publishes
    /// again, so a vehicle that restarts too can resume its task.
    pub(crate) fn under_way(&self) -> Vec<TaskAssignment> {
        self.tasks
            .values()
            .filter(|t| under_way(t.state))
            .map(|t| t.assignment.clone())
            .collect()
    }

    /// Marks a task published again after a restart, without changing its state.
    pub(crate) fn republished(&mut self, task_id: &str) {
        self.on_bus.insert(task_id.to_owned());
    }

    /// The station's own state changes since the last call, oldest first.
    pub(crate) fn take_transitions(&mut self) -> Vec<TaskStatus> {
        std::mem::take(&mut self.transitions)
    }

    /// Rebuilds the register from the history after a restart: each task with the state
    /// its reports reached, missions grouped by id in issue order. A mission with a task
    /// past `pending` is running; one whose tasks are all final has ended.
    pub(crate) fn restore(&mut self, history: Vec<shoal_history::TaskHistory>, now_ms: i64) {
        let mut missions: Vec<(String, Vec<String>)> = Vec::new();
        for h in history {
            let Some(a) = h.assignment else { continue };
            let id = a.task_id.clone();
            let mission = a.mission_id.clone();
            self.add_task(a, now_ms);
            if let Some(t) = self.tasks.get_mut(&id) {
                for s in h.statuses {
                    if may_move(t.state, s.state) {
                        t.state = s.state;
                        t.progress_pct = s.progress_pct;
                        t.message.clone_from(&s.message);
                        t.updated_ms = s.timestamp_ms;
                        note_time(t, s.state, s.timestamp_ms);
                        if s.message.contains("acoustic link") {
                            t.link = Some(LinkKind::Acoustic);
                        }
                        t.status = Some(s);
                    }
                }
                if t.state == TaskState::Sent && t.link.is_none() {
                    t.link = Some(LinkKind::Ip);
                }
            }
            if mission.is_empty() {
                continue;
            }
            match missions.iter_mut().find(|(m, _)| *m == mission) {
                Some((_, ids)) => ids.push(id),
                None => missions.push((mission, vec![id])),
            }
        }
        for (mission, ids) in missions {
            let states: Vec<TaskState> = ids
                .iter()
                .filter_map(|i| self.tasks.get(i).map(|t| t.state))
                .collect();
            self.add_mission(&mission, "", ids, now_ms);
            if let Some(m) = self.missions.get_mut(&mission)
                && states.iter().any(|s| *s != TaskState::Pending)
            {
                m.state = MissionState::Running;
                m.started_ms = Some(now_ms);
            }
            self.settle(&mission, now_ms);
        }
    }

    /// Running missions' tasks that are due (after a restart: re-sent, which is harmless,
    /// since vehicles ignore a task id they already have).
    pub(crate) fn due_tasks(&self) -> Vec<String> {
        self.missions
            .values()
            .filter(|m| m.state == MissionState::Running)
            .flat_map(|m| self.next_tasks(&m.mission_id))
            .collect()
    }

    /// Re-issues a task the acoustic link gave up on, if it has retries left: back to
    /// `pending` with a new issue time (so relays forward it again). Returns the new
    /// assignment.
    pub(crate) fn retry(
        &mut self,
        task_id: &str,
        max_retries: u32,
        now_ms: i64,
    ) -> Option<TaskAssignment> {
        let t = self.tasks.get_mut(task_id)?;
        let retryable = t.link == Some(LinkKind::Acoustic)
            && matches!(t.state, TaskState::Sent | TaskState::Pending)
            && t.retries < max_retries;
        if !retryable {
            return None;
        }
        t.retries += 1;
        t.state = TaskState::Pending;
        t.assignment.issued_ms = now_ms;
        t.updated_ms = now_ms;
        t.message = format!("retry {}/{max_retries} over the acoustic link", t.retries);
        Some(t.assignment.clone())
    }

    /// Moves a task to a final state decided at the station (expired, aborted, not sent).
    pub(crate) fn finish(&mut self, task_id: &str, state: TaskState, message: &str, now_ms: i64) {
        if let Some(t) = self.tasks.get_mut(task_id)
            && may_move(t.state, state)
        {
            t.state = state;
            t.message = message.to_owned();
            t.updated_ms = now_ms;
            note_time(t, state, now_ms);
            let record = transition(t, now_ms);
            self.transitions.push(record);
        }
    }

    /// Applies a vehicle's report. Returns false when the task is unknown (never issued by
    /// this station) and the report must be ignored; a report that would move the task
    /// backwards is kept as the latest status but does not change the state.
    pub(crate) fn on_status(&mut self, s: &TaskStatus, now_ms: i64) -> Option<bool> {
        let t = self.tasks.get_mut(&s.task_id)?;
        if t.assignment.vehicle_id != s.vehicle_id {
            return None;
        }
        t.status = Some(s.clone());
        if !may_move(t.state, s.state) {
            return Some(false);
        }
        t.state = s.state;
        t.progress_pct = if s.state == TaskState::Done {
            100.0
        } else {
            s.progress_pct
        };
        t.message.clone_from(&s.message);
        t.updated_ms = now_ms;
        // Station time, like `updated_ms`: vehicles' clocks may be off, and one timeline
        // compares them all.
        note_time(t, s.state, now_ms);
        Some(true)
    }

    /// Starts a planned mission: returns the first task of each vehicle to dispatch.
    pub(crate) fn start(&mut self, mission_id: &str, now_ms: i64) -> Option<Vec<String>> {
        let m = self.missions.get_mut(mission_id)?;
        if m.state != MissionState::Planned {
            return Some(Vec::new());
        }
        m.state = MissionState::Running;
        m.started_ms = Some(now_ms);
        Some(self.next_tasks(mission_id))
    }

    /// For each vehicle of a running mission with nothing active, its next pending task.
    fn next_tasks(&self, mission_id: &str) -> Vec<String> {
        let Some(m) = self.missions.get(mission_id) else {
            return Vec::new();
        };
        if m.state != MissionState::Running {
            return Vec::new();
        }
        let mut busy: Vec<&str> = Vec::new();
        let mut next = Vec::new();
        for id in &m.task_ids {
            let Some(t) = self.tasks.get(id) else {
                continue;
            };
            let v = t.assignment.vehicle_id.as_str();
            if busy.contains(&v) {
                continue;
            }
            match t.state {
                TaskState::Pending => {
                    next.push(id.clone());
                    busy.push(v);
                }
                s if !s.is_final() => busy.push(v),
                _ => {}
            }
        }
        next
    }

    /// After a task changed: skips the rest of its vehicle's tasks in the mission when it
    /// did not succeed, settles the mission, and returns the tasks to dispatch next.
    pub(crate) fn advance(&mut self, task_id: &str, now_ms: i64) -> Vec<String> {
        let Some(mission_id) = self.mission_of.get(task_id).cloned() else {
            return Vec::new();
        };
        let Some(t) = self.tasks.get(task_id) else {
            return Vec::new();
        };
        if matches!(
            t.state,
            TaskState::Failed | TaskState::Aborted | TaskState::Expired
        ) {
            let vehicle = t.assignment.vehicle_id.clone();
            let why = format!("skipped: {task_id} ended {:?}", t.state).to_lowercase();
            let ids = self.missions[&mission_id].task_ids.clone();
            for id in ids {
                if let Some(o) = self.tasks.get_mut(&id)
                    && o.assignment.vehicle_id == vehicle
                    && o.state == TaskState::Pending
                {
                    o.state = TaskState::Aborted;
                    o.message.clone_from(&why);
                    o.updated_ms = now_ms;
                    note_time(o, TaskState::Aborted, now_ms);
                    let record = transition(o, now_ms);
                    self.transitions.push(record);
                }
            }
        }
        self.settle(&mission_id, now_ms);
        self.next_tasks(&mission_id)
    }

    /// Ends a mission whose tasks are all final.
    fn settle(&mut self, mission_id: &str, now_ms: i64) {
        let Some(m) = self.missions.get(mission_id) else {
            return;
        };
        if !matches!(m.state, MissionState::Running | MissionState::Aborted) || m.ended_ms.is_some()
        {
            return;
        }
        let states: Vec<TaskState> = m
            .task_ids
            .iter()
            .filter_map(|id| self.tasks.get(id).map(|t| t.state))
            .collect();
        if !states.iter().all(|s| s.is_final()) {
            return;
        }
        let Some(m) = self.missions.get_mut(mission_id) else {
            return;
        };
        m.ended_ms = Some(now_ms);
        if m.state == MissionState::Running {
            m.state = if states.iter().all(|s| *s == TaskState::Done) {
                MissionState::Done
            } else {
                MissionState::Failed
            };
        }
    }

    /// Aborts a mission: its pending tasks end `aborted` at once; returns the vehicles
    /// with a task under way, which must be told to abort.
    pub(crate) fn abort_mission(&mut self, mission_id: &str, now_ms: i64) -> Option<Vec<String>> {
        let m = self.missions.get_mut(mission_id)?;
        if matches!(
            m.state,
            MissionState::Done | MissionState::Failed | MissionState::Aborted
        ) {
            return Some(Vec::new());
        }
        m.state = MissionState::Aborted;
        let ids = m.task_ids.clone();
        let mut vehicles = Vec::new();
        for id in ids {
            if let Some(t) = self.tasks.get_mut(&id) {
                if t.state == TaskState::Pending {
                    t.state = TaskState::Aborted;
                    t.message = "mission aborted by the operator".into();
                    t.updated_ms = now_ms;
                    note_time(t, TaskState::Aborted, now_ms);
                    let record = transition(t, now_ms);
                    self.transitions.push(record);
                } else if !t.state.is_final() && !vehicles.contains(&t.assignment.vehicle_id) {
                    vehicles.push(t.assignment.vehicle_id.clone());
                }
            }
        }
        self.settle(mission_id, now_ms);
        Some(vehicles)
    }

    /// Missions not yet ended.
    pub(crate) fn open_missions(&self) -> Vec<String> {
        self.missions
            .values()
            .filter(|m| matches!(m.state, MissionState::Planned | MissionState::Running))
            .map(|m| m.mission_id.clone())
            .collect()
    }

    /// Sent tasks not acknowledged within their timeout (by link), to expire.
    pub(crate) fn overdue(&self, now_ms: i64, ip_ms: i64, acoustic_ms: i64) -> Vec<String> {
        self.tasks
            .values()
            .filter(|t| t.state == TaskState::Sent)
            .filter(|t| {
                // A task sent through another site waits as long as an acoustic one: that
                // site may be reaching its vehicle acoustically.
                let limit = if t.link == Some(LinkKind::Acoustic) || t.via_site.is_some() {
                    acoustic_ms
                } else {
                    ip_ms
                };
                now_ms - t.updated_ms > limit
            })
            .map(|t| t.assignment.task_id.clone())
            .collect()
    }

    pub(crate) fn mission(&self, mission_id: &str) -> Option<MissionView> {
        let m = self.missions.get(mission_id)?;
        let tasks: Vec<TaskView> = m
            .task_ids
            .iter()
            .filter_map(|id| self.tasks.get(id).cloned())
            .collect();
        #[allow(clippy::cast_precision_loss)]
        let progress_pct = if tasks.is_empty() {
            0.0
        } else {
            tasks
                .iter()
                .map(|t| match t.state {
                    TaskState::Done => 100.0,
                    TaskState::Running => t.progress_pct,
                    _ => 0.0,
                })
                .sum::<f64>()
                / tasks.len() as f64
        };
        Some(MissionView {
            mission_id: m.mission_id.clone(),
            name: m.name.clone(),
            state: m.state,
            created_ms: m.created_ms,
            started_ms: m.started_ms,
            ended_ms: m.ended_ms,
            progress_pct,
            tasks,
        })
    }

    pub(crate) fn missions(&self) -> Vec<MissionView> {
        self.missions
            .keys()
            .filter_map(|id| self.mission(id))
            .collect()
    }
}

/// Notes when a task first reached the stage of its life `state` belongs to (sent; accepted
/// or running; final), for the console's timeline. Each time is set once: a repeated or late
/// report, or a retry's second send, never moves it.
fn note_time(t: &mut TaskView, state: TaskState, at_ms: i64) {
    let slot = match state {
        TaskState::Sent => &mut t.dispatched_ms,
        TaskState::Accepted | TaskState::Running => &mut t.started_ms,
        s if s.is_final() => &mut t.ended_ms,
        _ => return,
    };
    slot.get_or_insert(at_ms);
}

/// A state change the station made, as a status report for the history.
fn transition(t: &TaskView, now_ms: i64) -> TaskStatus {
    TaskStatus {
        task_id: t.assignment.task_id.clone(),
        vehicle_id: t.assignment.vehicle_id.clone(),
        timestamp_ms: now_ms,
        state: t.state,
        progress_pct: t.progress_pct,
        message: t.message.chars().take(shoal_model::MAX_TEXT_LEN).collect(),
    }
}

fn link_name(link: LinkKind) -> &'static str {
    match link {
        LinkKind::Ip => "IP",
        LinkKind::Acoustic => "the acoustic link",
        _ => "a link",
    }
}

#[cfg(test)]
#[path = "register_tests.rs"]
mod tests;
