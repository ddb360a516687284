//! Orders, with no network: a task that the site holding a vehicle's command lease sends to
//! the vehicle's home site, whose station publishes it to the vehicle unchanged, under the
//! holder's lease. The holder has the lease (after a handover or a failover) but no DDS
//! path to the vehicle; the home has the path but not the lease.
//!
//! - [`check_relay`]: what the sending site checks before it sends ([`OrderError`]).
//! - [`check_received`]: what the home checks against the lease as it knows it
//!   ([`OrderRefusal`]); [`OrderLedger`] drops what was already delivered.
//! - [`RelayedOrder`]: what the home's station gets.
//!
//! The key `shoal/<sender>/orders/<vehicle>` names the sender, which site identity
//! authenticates (a site publishes only under its own `shoal/<site>/**`), so an order
//! reaches every site subscribed; only the vehicle's home takes it. Orders are not caught
//! up after an outage: an order that did not arrive is not delivered late (a stale command
//! is worse than none); the sending station sees no task transition and sends it again or
//! gives up.

use std::collections::{HashMap, HashSet, VecDeque};

use shoal_model::{TaskAssignment, ValidationError};

use crate::inbound::{Admit, SeqWindow};
use crate::lease::LeaseRecord;
use crate::wire::DecodeError;

/// A task the vehicle's lease holder sent to this site, the vehicle's home, to publish to
/// the vehicle as it is (its lease is the holder's).
#[derive(Debug, Clone, PartialEq)]
pub struct RelayedOrder {
    /// The sending site: it holds the vehicle's lease (`task.lease_holder`).
    pub from_site: String,
    /// The task: `lease_term` and `lease_holder` are the sender's lease; `issue_seq` and
    /// `expires_ms` are 0, for the home station to stamp.
    pub task: TaskAssignment,
}

/// Why this site did not send an order.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum OrderError {
    /// The command lease is off here: an order goes only under a lease.
    #[error("the command lease is off (lease.enabled = false): orders go only under a lease")]
    LeaseOff,
    /// No site holds the vehicle's lease as this site knows it.
    #[error("no command lease is known for {0}")]
    NoLease(String),
    /// Another site holds the vehicle's lease.
    #[error("{vehicle} is commanded by site {holder} (lease term {term}), not by this site")]
    NotHolder {
        /// The vehicle.
        vehicle: String,
        /// Who holds it.
        holder: String,
        /// Its term.
        term: u64,
    },
    /// The vehicle's home is this site: its station commands it directly, not by order.
    #[error("{0} is this site's own vehicle: command it directly")]
    OwnVehicle(String),
    /// The task does not carry the lease this site holds.
    #[error(
        "the task carries lease term {task_term} of {task_holder:?}; this site holds {vehicle}'s lease at term {term}"
    )]
    WrongLease {
        /// The vehicle.
        vehicle: String,
        /// The term this site holds.
        term: u64,
        /// The term in the task.
        task_term: u64,
        /// The holder in the task.
        task_holder: String,
    },
    /// The task breaks the model's rules.
    #[error("not sent: {0}")]
    Invalid(#[from] ValidationError),
    /// The publishing queue is full; nothing was sent (try again).
    #[error("the federation's publishing queue is full: the order was not sent")]
    QueueFull,
    /// The federation is stopping.
    #[error("the federation is stopping: the order was not sent")]
    Stopped,
}

/// Checks that this site (`site`) may send `task` to the vehicle's home, given the
/// vehicle's lease as this site knows it; returns the term it holds. (Not
/// `Federation::may_command`: that claims a vehicle nobody holds, which is for the home.)
pub fn check_relay(
    site: &str,
    lease_enabled: bool,
    lease: Option<&LeaseRecord>,
    task: &TaskAssignment,
) -> Result<u64, OrderError> {
    if !lease_enabled {
        return Err(OrderError::LeaseOff);
    }
    let vehicle = &task.vehicle_id;
    let lease = lease.ok_or_else(|| OrderError::NoLease(vehicle.clone()))?;
    if lease.holder != site {
        return Err(OrderError::NotHolder {
            vehicle: vehicle.clone(),
            holder: lease.holder.clone(),
            term: lease.term,
        });
    }
    if lease.home == site {
        return Err(OrderError::OwnVehicle(vehicle.clone()));
    }
    if task.lease_term != lease.term || task.lease_holder != site {
        return Err(OrderError::WrongLease {
            vehicle: vehicle.clone(),
            term: lease.term,
            task_term: task.lease_term,
            task_holder: task.lease_holder.clone(),
        });
    }
    Ok(lease.term)
}

/// Why a received order was not delivered.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum OrderRefusal {
    /// The payload does not decode as an order.
    #[error("malformed order: {0}")]
    Malformed(#[from] DecodeError),
    /// The envelope names another site than the key (the key's site is authenticated).
    #[error("order from site {frame} under the key of site {key}")]
    SiteMismatch {
        /// The site named by the key.
        key: String,
        /// The site named in the frame.
        frame: String,
    },
    /// The command lease is off here: nothing to check an order against.
    #[error("the command lease is off here")]
    LeaseOff,
    /// No lease is known here for the vehicle.
    #[error("no lease is known here for the vehicle")]
    NoLease,
    /// The vehicle's home is another site (with three sites or more, every order reaches
    /// every site; only the home takes it).
    #[error("the vehicle's home is {home}, not this site")]
    NotOurs {
        /// The vehicle's home.
        home: String,
    },
    /// The sender does not hold the vehicle's lease as this site knows it.
    #[error("the vehicle's lease is held by {holder} (term {term}), not by the sender")]
    NotHolder {
        /// The holder this site knows.
        holder: String,
        /// Its term.
        term: u64,
    },
    /// The sender holds the lease, but the task carries another term.
    #[error("the order carries lease term {carried}; the lease known here is term {known}")]
    Term {
        /// The term this site knows.
        known: u64,
        /// The term in the order.
        carried: u64,
    },
    /// From an earlier run of the sending site than one heard since.
    #[error("from an earlier epoch of its site")]
    StaleEpoch,
    /// Already delivered (the same frame, or the same task sent again).
    #[error("already delivered")]
    Duplicate,
    /// The station has not taken the orders waiting (or never took the receiver).
    #[error("the order queue is full")]
    QueueFull,
    /// The station dropped the receiver of orders.
    #[error("the order receiver is closed")]
    ReceiverClosed,
}

impl OrderRefusal {
    /// A stable short code for counters, e.g. `order_not_holder`,
    /// `order_malformed:truncated`.
    pub fn reason(&self) -> String {
        match self {
            Self::Malformed(e) => format!("order_malformed:{}", e.reason()),
            Self::SiteMismatch { .. } => "order_site_mismatch".into(),
            Self::LeaseOff => "order_lease_off".into(),
            Self::NoLease => "order_no_lease".into(),
            Self::NotOurs { .. } => "order_not_ours".into(),
            Self::NotHolder { .. } => "order_not_holder".into(),
            Self::Term { .. } => "order_term".into(),
            Self::StaleEpoch => "order_stale_epoch".into(),
            Self::Duplicate => "order_duplicate".into(),
            Self::QueueFull => "order_queue_full".into(),
            Self::ReceiverClosed => "order_receiver_closed".into(),
        }
    }

    /// Whether it is routine, not worth a warning: with three sites or more every order
    /// reaches sites that are not the vehicle's home; duplicates are expected.
    pub fn routine(&self) -> bool {
        matches!(self, Self::NotOurs { .. } | Self::NoLease | Self::Duplicate)
    }
}

/// Checks an order from `from` against the vehicle's lease as this site (`site`) knows it:
/// the vehicle's home must be this site, and its holder the sender at the order's term.
pub fn check_received(
    site: &str,
    lease_enabled: bool,
    lease: Option<&LeaseRecord>,
    from: &str,
    task: &TaskAssignment,
) -> Result<(), OrderRefusal> {
    if !lease_enabled {
        return Err(OrderRefusal::LeaseOff);
    }
    let lease = lease.ok_or(OrderRefusal::NoLease)?;
    if lease.home != site {
        return Err(OrderRefusal::NotOurs {
            home: lease.home.clone(),
        });
    }
    if lease.holder != from {
        return Err(OrderRefusal::NotHolder {
            holder: lease.holder.clone(),
            term: lease.term,
        });
    }
    if lease.term != task.lease_term {
        return Err(OrderRefusal::Term {
            known: lease.term,
            carried: task.lease_term,
        });
    }
    Ok(())
}

/// Tasks remembered as delivered, to drop one sent again.
const TASKS_REMEMBERED: usize = 1024;

/// What was delivered: each sender's order numbers (as a [`SeqWindow`], which also tells
/// a stale epoch) and the last [`TASKS_REMEMBERED`] tasks by (sender, task id, lease
/// term), so that a task sent again under a new number is still dropped.
#[derive(Debug, Default)]
pub struct OrderLedger {
    windows: HashMap<String, SeqWindow>,
    tasks: HashSet<(String, String, u64)>,
    order: VecDeque<(String, String, u64)>,
}

/// A new order's place in its sender's numbers, to record once it is delivered.
#[derive(Debug)]
pub struct Admitted {
    site: String,
    window: SeqWindow,
    task: (String, String, u64),
}

impl OrderLedger {
    /// Whether an order is new; nothing is recorded until [`Self::delivered`], so an
    /// order that could not be delivered (a full queue) is taken when it comes again.
    /// `capacity` bounds the numbers held above a gap (orders are not caught up, so a gap
    /// stays until it is given up). The caller passes configured sites only, which bounds
    /// the windows.
    pub fn admit(
        &self,
        site: &str,
        epoch: u64,
        seq: u64,
        task: &TaskAssignment,
        capacity: usize,
    ) -> Result<Admitted, OrderRefusal> {
        let key = (site.to_string(), task.task_id.clone(), task.lease_term);
        if self.tasks.contains(&key) {
            return Err(OrderRefusal::Duplicate);
        }
        let mut window = self
            .windows
            .get(site)
            .cloned()
            .unwrap_or_else(|| SeqWindow::new(epoch));
        // A gap given up is not counted as lost: orders are not caught up anyway.
        let mut given_up = 0;
        match window.admit(epoch, seq, capacity, &mut given_up) {
            Admit::New { .. } => Ok(Admitted {
                site: site.to_string(),
                window,
                task: key,
            }),
            Admit::Duplicate => Err(OrderRefusal::Duplicate),
            Admit::Stale => Err(OrderRefusal::StaleEpoch),
        }
    }

    /// Records an order as delivered.
    pub fn delivered(&mut self, admitted: Admitted) {
        self.windows.insert(admitted.site, admitted.window);
        if self.order.len() >= TASKS_REMEMBERED
            && let Some(old) = self.order.pop_front()
        {
            self.tasks.remove(&old);
        }
        self.tasks.insert(admitted.task.clone());
        self.order.push_back(admitted.task);
    }
}

/// How long the warnings of one refusal reason stay quiet after one was logged, ms.
pub const WARN_QUIET_MS: i64 = 60_000;

/// Warns once per burst of one reason: the first refusal of a reason is logged, the next
/// ones only counted until [`WARN_QUIET_MS`] has passed since, and the next warning says
/// how many were not logged. A forged or misrouted stream thus cannot flood the log.
#[derive(Debug, Default)]
pub struct WarnGate {
    /// By reason (a closed set of codes): when the last warning was logged, and how many
    /// refusals were not logged since.
    reasons: HashMap<String, (i64, u64)>,
}

impl WarnGate {
    /// Whether to log a refusal of `reason` at `now_ms`: `Some(n)` with the number not
    /// logged since the last warning, `None` to stay quiet.
    pub fn admit(&mut self, reason: &str, now_ms: i64) -> Option<u64> {
        match self.reasons.get_mut(reason) {
            Some((last, quiet)) if now_ms.saturating_sub(*last) < WARN_QUIET_MS => {
                *quiet += 1;
                None
            }
            Some((last, quiet)) => {
                *last = now_ms;
                Some(std::mem::take(quiet))
            }
            None => {
                self.reasons.insert(reason.to_string(), (now_ms, 0));
                Some(0)
            }
        }
    }
}

#[cfg(test)]
mod tests;
