//! The simulated fleet of `bench endurance`, in a process of its own
//! (`bench endurance-fleet`): one DDS participant, a real task ledger per vehicle. Its
//! ledgers grow by design (each remembers a task until an hour after its expiry); in the
//! station's process that growth would hide whether the station's own state stays bounded.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_dds::{Priority, PubSub, Writer, WriterOptions};
use shoal_model::{
    StateVector, TaskAssignment, TaskState, TaskStatus, VehicleAnnouncement, VehicleKind, now_ms,
};
use shoal_proxy::ledger::{Admission, TaskLedger};
use shoal_proxy::sim::{SimSpec, SimVehicle};

use super::lines::{LineChild, READY, field, stdin_lines, tell_parent};
use super::{Plan, vehicle_id};
use crate::bench::helpers::dds;
use crate::config::ShoalConfig;

/// What the benchmark asks the fleet process, one line on its stdin; each is answered with
/// `<word> <completed> <twice>` (see [`FleetProgress`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum FleetCommand {
    /// Only the progress.
    Count,
    /// A tenth of the vehicles restart (ledgers reopened) and the task reader is replaced
    /// (a late joiner), before the answer.
    Restart,
    /// Answer, then end.
    Stop,
}

/// Every word the fleet process answers with.
const WORDS: &[&str] = &[READY, "count", "restart", "stop"];

impl FleetCommand {
    pub(super) fn word(self) -> &'static str {
        match self {
            Self::Count => "count",
            Self::Restart => "restart",
            Self::Stop => "stop",
        }
    }

    fn parse(line: &str) -> Option<Self> {
        [Self::Count, Self::Restart, Self::Stop]
            .into_iter()
            .find(|c| c.word() == line.trim())
    }
}

/// What the fleet process reports: tasks it ran to the end, and tasks it was handed to run
/// a second time (counted by the vehicles, from what their ledgers admitted).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct FleetProgress {
    pub(super) completed: u64,
    pub(super) twice: u64,
}

impl FleetProgress {
    fn line(self, word: &str) -> String {
        format!("{word} {} {}", self.completed, self.twice)
    }

    fn from_fields(fields: &[String]) -> Result<Self> {
        Ok(Self {
            completed: field(fields, 0, "completed tasks")?,
            twice: field(fields, 1, "count of tasks run twice")?,
        })
    }
}

/// The fleet process, as the benchmark drives it.
pub(super) struct FleetProcess(LineChild);

impl FleetProcess {
    pub(super) async fn start(cfg: &ShoalConfig, plan: &Plan, dir: &Path) -> Result<Self> {
        let args = [
            "endurance-fleet".to_string(),
            "--domain".into(),
            plan.domain.to_string(),
            "--vehicles".into(),
            plan.vehicles.to_string(),
            "--dir".into(),
            dir.display().to_string(),
        ];
        let (child, _) = LineChild::start(cfg, "fleet process", WORDS, &args).await?;
        Ok(Self(child))
    }

    pub(super) fn pid(&self) -> &str {
        &self.0.pid
    }

    pub(super) async fn ask(&mut self, command: FleetCommand) -> Result<FleetProgress> {
        FleetProgress::from_fields(&self.0.ask(command.word()).await?)
    }

    pub(super) fn rss_mb(&self) -> f64 {
        self.0.rss_mb()
    }

    /// Tells the fleet to stop, and its last progress.
    pub(super) async fn stop(self) -> Result<FleetProgress> {
        FleetProgress::from_fields(&self.0.stop(FleetCommand::Stop.word()).await?)
    }
}

/// The simulated fleet: one participant, a real ledger per vehicle; it lives in the
/// `endurance-fleet` process.
struct Fleet {
    ids: Vec<String>,
    specs: HashMap<String, SimVehicle>,
    ledgers: HashMap<String, TaskLedger>,
    dir: PathBuf,
    /// Times each task was executed (handed to the vehicle), recent tasks only.
    executions: HashMap<String, u32>,
    order: VecDeque<String>,
    twice: u64,
    completed: u64,
    status: Writer<TaskStatus>,
    state: Writer<StateVector>,
    announcement: Writer<VehicleAnnouncement>,
}

impl Fleet {
    fn new(dds: &PubSub, n: usize, dir: &Path) -> Result<Self> {
        let mut ids = Vec::new();
        let mut specs = HashMap::new();
        let mut ledgers = HashMap::new();
        let dir = dir.join("vehicles");
        for i in 0..n {
            let id = vehicle_id(i);
            let spec = SimSpec {
                id: id.clone(),
                kind: VehicleKind::Auv,
                latitude_deg: 63.4 + f64::from(u32::try_from(i % 100).unwrap_or(0)) * 1e-3,
                longitude_deg: 10.4,
                rate_hz: 1.0,
                battery_pct: 100.0,
            };
            specs.insert(id.clone(), SimVehicle::new(&spec, now_ms()));
            let ledger = TaskLedger::open(&dir, &id, Some(900_000))
                .with_context(|| format!("cannot open the ledger of {id} in {}", dir.display()))?;
            ledgers.insert(id.clone(), ledger);
            ids.push(id);
        }
        Ok(Self {
            ids,
            specs,
            ledgers,
            dir,
            executions: HashMap::new(),
            order: VecDeque::new(),
            twice: 0,
            completed: 0,
            status: dds.writer(WriterOptions::new(Priority::Control))?,
            state: dds.writer(WriterOptions::new(Priority::Telemetry))?,
            announcement: dds.writer(WriterOptions::new(Priority::Control))?,
        })
    }

    async fn announce(&self) -> Result<()> {
        for id in &self.ids {
            let mut a = self.specs[id].announcement.clone();
            a.timestamp_ms = now_ms();
            self.announcement
                .write(a)
                .await
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        Ok(())
    }

    async fn report_states(&self) {
        let now = now_ms();
        for id in &self.ids {
            // A full history or a slow reader is the measurement's business, not an error.
            let _ = self.state.write(self.specs[id].state(now)).await;
        }
    }

    async fn status(&self, task: &TaskAssignment, state: TaskState, message: &str) {
        let s = TaskStatus {
            task_id: task.task_id.clone(),
            vehicle_id: task.vehicle_id.clone(),
            timestamp_ms: now_ms(),
            state,
            progress_pct: if state == TaskState::Done { 100.0 } else { 0.0 },
            message: message.to_owned(),
        };
        let _ = self.status.write(s).await;
    }

    /// A vehicle restarts: what it remembers is only what its ledger file says.
    fn restart(&mut self, id: &str) -> Result<()> {
        self.ledgers.remove(id);
        let ledger = TaskLedger::open(&self.dir, id, Some(900_000))
            .with_context(|| format!("cannot reopen the ledger of {id}"))?;
        self.ledgers.insert(id.to_owned(), ledger);
        Ok(())
    }

    fn progress(&self) -> FleetProgress {
        FleetProgress {
            completed: self.completed,
            twice: self.twice,
        }
    }

    async fn on_task(&mut self, a: &TaskAssignment) -> Result<()> {
        let Some(ledger) = self.ledgers.get_mut(&a.vehicle_id) else {
            return Ok(());
        };
        let admission = ledger
            .admit(a, now_ms())
            .with_context(|| format!("ledger of {}", a.vehicle_id))?;
        match admission {
            Admission::Start => {
                let n = self.executions.entry(a.task_id.clone()).or_insert(0);
                *n += 1;
                if *n > 1 {
                    self.twice += 1;
                } else {
                    self.order.push_back(a.task_id.clone());
                    while self.order.len() > 20_000 {
                        if let Some(old) = self.order.pop_front() {
                            self.executions.remove(&old);
                        }
                    }
                }
                // Time compressed: accepted, running and done at once.
                ledger
                    .end(&a.task_id, TaskState::Done, now_ms())
                    .with_context(|| format!("ledger of {}", a.vehicle_id))?;
                self.status(a, TaskState::Accepted, "").await;
                self.status(a, TaskState::Running, "").await;
                self.status(a, TaskState::Done, "").await;
                self.completed += 1;
            }
            Admission::Ended(state) => {
                self.status(a, state, "already ended before; not run again")
                    .await;
            }
            Admission::Expired => self.status(a, TaskState::Expired, "expired").await,
            // One station commands this fleet: a refusal would be a fault of the bench.
            Admission::Fenced(obeyed) => {
                let msg = format!(
                    "refused: obeys site {} (term {})",
                    obeyed.holder, obeyed.term
                );
                self.status(a, TaskState::Failed, &msg).await;
            }
            // Tasks here end as they start: nothing is ever left under way to resume.
            Admission::Resume | Admission::Duplicate => {}
        }
        Ok(())
    }
}

/// `shoal bench endurance-fleet`: the fleet of `bench endurance` in a process of its own,
/// its ledgers under `dir`, driven by [`FleetCommand`]s on stdin; it ends when stdin closes.
pub(in crate::bench) async fn fleet(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    dir: &Path,
) -> Result<()> {
    let mut commands = stdin_lines()?;
    let p = dds(cfg, domain)?;
    let mut fleet = Fleet::new(&p, vehicles, dir)?;
    fleet.announce().await?;
    let mut sub = p.subscribe::<TaskAssignment>()?;
    tell_parent(&fleet.progress().line(READY))?;
    // State at 1 Hz, tasks as they come, and the parent's commands, in one loop: a command
    // is answered between two tasks, so its counts are exact at that instant.
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    loop {
        tokio::select! {
            line = commands.recv() => {
                // No more commands: the benchmark process has ended.
                let Some(line) = line else { return Ok(()) };
                let command = FleetCommand::parse(&line)
                    .with_context(|| format!("unknown command from the benchmark: {line:?}"))?;
                if command == FleetCommand::Restart {
                    for id in fleet.ids.clone().iter().step_by(10) {
                        fleet.restart(id)?;
                    }
                    sub = p.subscribe::<TaskAssignment>()?;
                }
                tell_parent(&fleet.progress().line(command.word()))?;
                if command == FleetCommand::Stop {
                    return Ok(());
                }
            }
            _ = tick.tick() => fleet.report_states().await,
            item = sub.next() => match item {
                Some(Ok((a, _))) => fleet.on_task(&a).await?,
                Some(Err(_)) => {}
                None => bail!("the task reader ended"),
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fleet_commands_are_one_word_each_and_read_back() {
        for c in [
            FleetCommand::Count,
            FleetCommand::Restart,
            FleetCommand::Stop,
        ] {
            assert_eq!(FleetCommand::parse(c.word()), Some(c));
            assert!(WORDS.contains(&c.word()));
        }
        assert_eq!(
            FleetCommand::parse("restart\r"),
            Some(FleetCommand::Restart)
        );
        assert_eq!(FleetCommand::parse(""), None);
        assert_eq!(FleetCommand::parse("restart all"), None);
        assert_eq!(FleetCommand::parse("COUNT"), None);
    }

    #[test]
    fn fleet_progress_reads_back_from_its_line() {
        let p = FleetProgress {
            completed: 100_002,
            twice: 3,
        };
        let line = p.line("restart");
        assert_eq!(line, "restart 100002 3");
        let (word, fields) = super::super::lines::split_answer(&line, WORDS).unwrap();
        assert_eq!(word, "restart");
        assert_eq!(FleetProgress::from_fields(&fields).unwrap(), p);
        for junk in [
            &[][..],
            &["12".to_string()][..],
            &["-1".to_string(), "0".to_string()][..],
        ] {
            assert!(FleetProgress::from_fields(junk).is_err(), "{junk:?}");
        }
    }
}
