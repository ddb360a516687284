//! `shoal ledger`: a vehicle's task ledger (`[vehicle] state_dir/<id>.tasks.json`), shown,
//! and its obeyed command lease forgotten when the vehicle leaves a federation.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context as _, Result, bail};
use shoal_proxy::ledger::{Progress, TaskLedger};

use crate::config::VehicleConfig;

/// `shoal ledger ...`.
#[derive(Debug, clap::Args)]
pub struct LedgerArgs {
    /// The ledgers' directory (default: vehicle.state_dir).
    #[arg(long, value_name = "DIR", global = true)]
    dir: Option<PathBuf>,
    #[command(subcommand)]
    command: LedgerCommand,
}

/// What to do with a vehicle's ledger.
#[derive(Debug, clap::Subcommand)]
enum LedgerCommand {
    /// What a vehicle's ledger holds: its tasks by how they ended, and the command lease
    /// it obeys.
    Show {
        /// The vehicle's id.
        vehicle: String,
    },
    /// Forget the command lease a vehicle has obeyed. Once a federated station has
    /// commanded it, the vehicle refuses tasks under an older lease or none; after it
    /// leaves that federation (or the stations' lease tables were reset), this lets a
    /// station outside it command the vehicle again. Tasks that ran still never run
    /// again. Stop the vehicle's process first: a running one writes its own copy back.
    ForgetLease {
        /// The vehicle's id.
        vehicle: String,
    },
}

/// Runs `shoal ledger`.
pub fn run(args: LedgerArgs, vehicle: &VehicleConfig) -> Result<()> {
    let dir = args.dir.unwrap_or_else(|| vehicle.state_dir.clone());
    match args.command {
        LedgerCommand::Show { vehicle } => {
            let Some(ledger) = open(&dir, &vehicle)? else {
                println!(
                    "vehicle {vehicle}: no ledger in {} (it has taken no task there)",
                    dir.display()
                );
                return Ok(());
            };
            print!("{}", describe(&vehicle, &ledger));
        }
        LedgerCommand::ForgetLease { vehicle } => {
            let Some(mut ledger) = open(&dir, &vehicle)? else {
                println!(
                    "vehicle {vehicle}: no ledger in {}, no lease to forget",
                    dir.display()
                );
                return Ok(());
            };
            match ledger
                .forget_lease(shoal_model::now_ms())
                .with_context(|| format!("cannot write the ledger of {vehicle}"))?
            {
                Some(lease) => {
                    tracing::warn!(
                        vehicle,
                        holder = %lease.holder,
                        term = lease.term,
                        "command lease forgotten: the vehicle takes tasks under any lease again"
                    );
                    println!(
                        "vehicle {vehicle}: forgot the command lease of site {} (term {}); \
                         it takes tasks under no lease, or any lease, again",
                        lease.holder, lease.term
                    );
                }
                None => println!("vehicle {vehicle}: it obeys no command lease"),
            }
        }
    }
    Ok(())
}

/// The ledger of `vehicle` in `dir`, if it has one (never creating it).
fn open(dir: &Path, vehicle: &str) -> Result<Option<TaskLedger>> {
    if !shoal_model::is_identifier(vehicle, shoal_model::MAX_VEHICLE_ID_LEN) {
        bail!(
            "{vehicle:?} is not a vehicle id (1 to {} characters of A-Z a-z 0-9 _ . -)",
            shoal_model::MAX_VEHICLE_ID_LEN
        );
    }
    if !dir.join(format!("{vehicle}.tasks.json")).exists() {
        return Ok(None);
    }
    let ledger = TaskLedger::open(dir, vehicle, None)
        .with_context(|| format!("cannot read the ledger of {vehicle}"))?;
    Ok(Some(ledger))
}

/// A few lines on what `ledger` holds.
fn describe(vehicle: &str, ledger: &TaskLedger) -> String {
    let mut by_state: BTreeMap<String, usize> = BTreeMap::new();
    for (_, progress) in ledger.entries() {
        let state = match progress {
            Progress::Started => "started, not ended".to_owned(),
            Progress::Ended(s) => format!("{s:?}").to_lowercase(),
        };
        *by_state.entry(state).or_default() += 1;
    }
    let mut out = format!("vehicle {vehicle}: {} tasks remembered\n", ledger.len());
    for (state, n) in by_state {
        out.push_str(&format!("  {state}: {n}\n"));
    }
    match ledger.lease() {
        Some(l) => out.push_str(&format!(
            "  obeys the command lease of site {} (term {}): a task under an older one, or \
             none, is refused\n",
            l.holder, l.term
        )),
        None => out.push_str("  obeys no command lease\n"),
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::{Task, TaskAssignment};

    #[test]
    fn a_ledger_is_described_and_its_lease_forgotten_without_creating_one() {
        let dir = tempfile::tempdir().unwrap();
        let args = |command| LedgerArgs {
            dir: Some(dir.path().to_owned()),
            command,
        };
        let vehicle = VehicleConfig::default();
        // No ledger: nothing is created.
        run(
            args(LedgerCommand::ForgetLease {
                vehicle: "auv-1".into(),
            }),
            &vehicle,
        )
        .unwrap();
        assert!(!dir.path().join("auv-1.tasks.json").exists());
        assert!(open(dir.path(), "../etc").is_err());

        let now = shoal_model::now_ms();
        let mut l = TaskLedger::open(dir.path(), "auv-1", None).unwrap();
        let mut a = TaskAssignment::new("t-1", "", "auv-1", now, &Task::Surface);
        a.lease_term = 2;
        a.lease_holder = "shore".into();
        l.admit(&a, now).unwrap();
        l.end("t-1", shoal_model::TaskState::Done, now).unwrap();
        drop(l);
        let text = describe("auv-1", &open(dir.path(), "auv-1").unwrap().unwrap());
        assert!(text.contains("1 tasks remembered"), "{text}");
        assert!(text.contains("done: 1"), "{text}");
        assert!(text.contains("site shore (term 2)"), "{text}");

        run(
            args(LedgerCommand::ForgetLease {
                vehicle: "auv-1".into(),
            }),
            &vehicle,
        )
        .unwrap();
        let l = open(dir.path(), "auv-1").unwrap().unwrap();
        assert_eq!(l.lease(), None);
        assert_eq!(l.len(), 1, "the tasks that ran are still remembered");
    }
}
