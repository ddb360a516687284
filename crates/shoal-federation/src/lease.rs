//! The command lease, with no network: which site commands each vehicle, so that exactly
//! one does at a time.
//!
//! Every vehicle has a *home* (the site it is registered at, which claims its lease first,
//! at term 1) and may have a *standby* (a site the home names to take over when it is
//! lost). A lease record says: from term `term` on, `holder` commands the vehicle. Each
//! change makes a new record with a higher term, published by the site that made it (the
//! *grantor*) under its own key, so the transport's site identity authenticates it:
//!
//! - **claim**: the home takes a vehicle no site has a lease for (term 1);
//! - **handover**: the holder gives the lease to another site (an operator's decision);
//! - **failover**: the home or the standby takes the lease for itself when the holder's
//!   site has been offline for `failover_timeout_ms`.
//!
//! A record is taken only from a grantor with the authority for its kind of change (the
//! holder for a handover; the home or standby for a failover; the home for a claim of an
//! unknown vehicle), otherwise it is refused and counted (and kept aside, one per vehicle
//! and grantor, in case a record this site missed arrives later and gives it that
//! authority). Records are ordered by term, then by holder name (the smaller first), so two
//! sites that claimed the same term in a partition agree on one winner once they hear each
//! other: every site converges to the same holder for every vehicle.
//!
//! What this cannot give on its own: during a partition the old holder and the site that
//! failed over both believe they hold the lease. The vehicle settles it: tasks carry the
//! lease, and a vehicle refuses one older than the newest lease it has seen.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use shoal_model::{MAX_TIMESTAMP_MS, MAX_VEHICLE_ID_LEN, MIN_TIMESTAMP_MS, is_identifier};

use crate::types::is_site_name;

/// Why a site made a lease record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LeaseReason {
    /// The vehicle's home took a vehicle no site held.
    Claim,
    /// The holder gave the lease to another site.
    Handover,
    /// The home or the standby took the lease from a holder that was lost.
    Failover,
}

impl LeaseReason {
    /// The reason's code on the wire.
    pub fn code(self) -> u8 {
        match self {
            Self::Claim => 1,
            Self::Handover => 2,
            Self::Failover => 3,
        }
    }

    /// The reason of a wire code.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            1 => Some(Self::Claim),
            2 => Some(Self::Handover),
            3 => Some(Self::Failover),
            _ => None,
        }
    }

    /// Its name in logs and the API.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Claim => "claim",
            Self::Handover => "handover",
            Self::Failover => "failover",
        }
    }
}

/// One change of a vehicle's lease.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LeaseRecord {
    /// The vehicle.
    pub vehicle_id: String,
    /// Increases with every change; from 1.
    pub term: u64,
    /// The site that commands the vehicle from this term on.
    pub holder: String,
    /// The vehicle's home site.
    pub home: String,
    /// The site the home named to take over when the holder is lost; empty for none.
    pub standby: String,
    /// Why the record was made.
    pub reason: LeaseReason,
    /// When, ms since the Unix epoch (the grantor's clock; informative only).
    pub granted_ms: i64,
}

impl LeaseRecord {
    /// Whether this record is newer than `other`: a higher term, or the same term for a
    /// holder whose name sorts first (how sites that claimed one term in a partition
    /// agree).
    pub fn supersedes(&self, other: &Self) -> bool {
        shoal_model::lease_supersedes(self.term, &self.holder, other.term, &other.holder)
    }

    /// Checks identifiers, the term and the time (the codec calls this on every frame);
    /// the error names the first field that fails.
    pub fn check(&self) -> Result<(), &'static str> {
        if !(MIN_TIMESTAMP_MS..=MAX_TIMESTAMP_MS).contains(&self.granted_ms) {
            return Err("granted_ms");
        }
        if !is_identifier(&self.vehicle_id, MAX_VEHICLE_ID_LEN) {
            return Err("vehicle_id");
        }
        if self.term == 0 {
            return Err("term");
        }
        if !is_site_name(&self.holder) {
            return Err("holder");
        }
        if !is_site_name(&self.home) {
            return Err("home");
        }
        if !self.standby.is_empty() && !is_site_name(&self.standby) {
            return Err("standby");
        }
        Ok(())
    }
}

/// Why a lease record from a remote site was not taken.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LeaseRefusal {
    /// The grantor has no authority for this change as this site knows the lease.
    #[error("{grantor} may not {reason} the lease of {vehicle} (held by {holder}, term {term})")]
    NoAuthority {
        /// The site that published the record.
        grantor: String,
        /// What it tried.
        reason: &'static str,
        /// The vehicle.
        vehicle: String,
        /// The holder this site knows.
        holder: String,
        /// The term this site knows.
        term: u64,
    },
    /// The record names another home than the one this site knows for the vehicle.
    #[error("the record says {vehicle}'s home is {claimed}, not {known}")]
    WrongHome {
        /// The vehicle.
        vehicle: String,
        /// The home this site knows.
        known: String,
        /// The home the record names.
        claimed: String,
    },
    /// A new vehicle beyond the table's limit.
    #[error("too many leased vehicles")]
    Full,
}

impl LeaseRefusal {
    /// A stable short code for counters.
    pub fn reason(&self) -> &'static str {
        match self {
            Self::NoAuthority { .. } => "lease_authority",
            Self::WrongHome { .. } => "lease_home",
            Self::Full => "lease_full",
        }
    }
}

/// What taking a record did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Applied {
    /// The vehicle's lease changed (records kept aside may have been taken after it).
    Changed,
    /// This site already had this record, or a newer one.
    Stale,
}

/// Why this site could not hand a lease over.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HandoverError {
    /// No site holds a lease for the vehicle here.
    #[error("no lease is known for {0}")]
    Unknown(String),
    /// Another site holds it: only the holder can hand it over.
    #[error("{vehicle} is commanded by {holder} (term {term}); only {holder} can hand it over")]
    NotHolder {
        /// The vehicle.
        vehicle: String,
        /// Who holds it.
        holder: String,
        /// The term.
        term: u64,
    },
    /// The receiving site is not a configured site.
    #[error("{0} is not a configured site")]
    UnknownSite(String),
}

/// The lease counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LeaseCounters {
    /// Records taken from remote sites.
    pub taken: u64,
    /// Records received that this site already had (or had a newer one).
    pub stale: u64,
    /// Records this site made (claims, handovers, failovers).
    pub granted: u64,
    /// Failovers this site made.
    pub failovers: u64,
    /// Records kept aside were taken later.
    pub taken_later: u64,
}

/// A vehicle's current lease and the site that published it (as kept across restarts).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Current {
    /// The record.
    pub record: LeaseRecord,
    /// The site that made it.
    pub grantor: String,
}

/// Every vehicle's lease as this site knows it.
#[derive(Debug, Clone)]
pub struct LeaseTable {
    site: String,
    /// This site's standby for the vehicles it is home to.
    standby: String,
    /// Every site this one knows (itself and its remote sites).
    sites: Vec<String>,
    max_vehicles: usize,
    leases: BTreeMap<String, Current>,
    /// Refused for authority, kept in case a record this site missed arrives: one per
    /// (vehicle, grantor).
    aside: BTreeMap<(String, String), LeaseRecord>,
    counters: LeaseCounters,
}

impl LeaseTable {
    /// An empty table for `site`, which names `standby` (empty: none) to take over its
    /// vehicles, knows `remote_sites`, and holds at most `max_vehicles` leases.
    pub fn new(site: &str, standby: &str, remote_sites: &[String], max_vehicles: usize) -> Self {
        let mut sites = remote_sites.to_vec();
        sites.push(site.to_string());
        Self {
            site: site.to_string(),
            standby: standby.to_string(),
            sites,
            max_vehicles,
            leases: BTreeMap::new(),
            aside: BTreeMap::new(),
            counters: LeaseCounters::default(),
        }
    }

    /// The current lease of a vehicle.
    pub fn lease(&self, vehicle: &str) -> Option<&LeaseRecord> {
        self.leases.get(vehicle).map(|c| &c.record)
    }

    /// Every lease known, by vehicle.
    pub fn leases(&self) -> impl Iterator<Item = &LeaseRecord> {
        self.leases.values().map(|c| &c.record)
    }

    /// Whether this site holds the vehicle's lease.
    pub fn holds(&self, vehicle: &str) -> bool {
        self.lease(vehicle).is_some_and(|r| r.holder == self.site)
    }

    /// The counters so far.
    pub fn counters(&self) -> &LeaseCounters {
        &self.counters
    }

    /// Changes whenever the table does (to know when to write it out).
    pub fn generation(&self) -> u64 {
        self.counters.taken + self.counters.granted + self.counters.taken_later
    }

    /// The records this site made that are still current: what it answers a remote site
    /// that asks (after its link came up).
    pub fn granted_here(&self) -> impl Iterator<Item = &LeaseRecord> {
        self.leases
            .values()
            .filter(|c| c.grantor == self.site)
            .map(|c| &c.record)
    }

    /// Every current lease with its grantor, to keep across a restart ([`Self::restore`]).
    pub fn snapshot(&self) -> Vec<Current> {
        self.leases.values().cloned().collect()
    }

    /// Takes back what [`Self::snapshot`] saved before a restart, so that this site never
    /// believes an older lease than it had learnt (its own records first claims included).
    /// Records that do not check, or beyond the limit, are skipped; returns how many were
    /// taken.
    pub fn restore(&mut self, saved: Vec<Current>) -> usize {
        let mut taken = 0;
        for c in saved {
            if c.record.check().is_err()
                || !is_site_name(&c.grantor)
                || self.leases.len() >= self.max_vehicles
            {
                continue;
            }
            let newer = self
                .leases
                .get(&c.record.vehicle_id)
                .is_none_or(|known| c.record.supersedes(&known.record));
            if newer {
                self.leases.insert(c.record.vehicle_id.clone(), c);
                taken += 1;
            }
        }
        taken
    }

    /// Claims, as its home, a vehicle no site has a lease for; the record to publish, or
    /// `None` when the vehicle already has a lease (or the table is full).
    pub fn claim(&mut self, vehicle: &str, now_ms: i64) -> Option<LeaseRecord> {
        if self.leases.contains_key(vehicle) || self.leases.len() >= self.max_vehicles {
            return None;
        }
        let record = LeaseRecord {
            vehicle_id: vehicle.to_string(),
            term: 1,
            holder: self.site.clone(),
            home: self.site.clone(),
            standby: self.standby.clone(),
            reason: LeaseReason::Claim,
            granted_ms: now_ms,
        };
        self.grant(record.clone());
        Some(record)
    }

    /// Hands a lease this site holds to `to`; the record to publish.
    pub fn hand_over(
        &mut self,
        vehicle: &str,
        to: &str,
        now_ms: i64,
    ) -> Result<LeaseRecord, HandoverError> {
        if !self.sites.iter().any(|s| s == to) {
            return Err(HandoverError::UnknownSite(to.to_string()));
        }
        let current = self
            .lease(vehicle)
            .ok_or_else(|| HandoverError::Unknown(vehicle.to_string()))?;
        if current.holder != self.site {
            return Err(HandoverError::NotHolder {
                vehicle: vehicle.to_string(),
                holder: current.holder.clone(),
                term: current.term,
            });
        }
        let record = LeaseRecord {
            term: current.term + 1,
            holder: to.to_string(),
            reason: LeaseReason::Handover,
            granted_ms: now_ms,
            ..current.clone()
        };
        self.grant(record.clone());
        Ok(record)
    }

    /// Takes over, as home or standby, every lease whose holder's site has been offline
    /// for `timeout_ms` (`offline_since` says since when a site is offline, `None` while
    /// it is online); the records to publish.
    pub fn fail_over(
        &mut self,
        offline_since: impl Fn(&str) -> Option<i64>,
        timeout_ms: i64,
        now_ms: i64,
    ) -> Vec<LeaseRecord> {
        let lost: Vec<LeaseRecord> = self
            .leases
            .values()
            .map(|c| &c.record)
            .filter(|r| r.holder != self.site)
            .filter(|r| r.home == self.site || r.standby == self.site)
            .filter(|r| offline_since(&r.holder).is_some_and(|t| now_ms - t >= timeout_ms))
            .cloned()
            .collect();
        let mut made = Vec::with_capacity(lost.len());
        for current in lost {
            let record = LeaseRecord {
                term: current.term + 1,
                holder: self.site.clone(),
                reason: LeaseReason::Failover,
                granted_ms: now_ms,
                ..current
            };
            self.counters.failovers += 1;
            self.grant(record.clone());
            made.push(record);
        }
        made
    }

    fn grant(&mut self, record: LeaseRecord) {
        self.counters.granted += 1;
        self.leases.insert(
            record.vehicle_id.clone(),
            Current {
                record,
                grantor: self.site.clone(),
            },
        );
    }

    /// Takes a record published by the remote site `grantor` (a configured site; the
    /// caller checks). Refused when `grantor` lacks the authority for it.
    pub fn apply(&mut self, grantor: &str, record: LeaseRecord) -> Result<Applied, LeaseRefusal> {
        let vehicle = record.vehicle_id.clone();
        let result = self.take(grantor, record.clone());
        match &result {
            Ok(Applied::Changed) => {
                self.counters.taken += 1;
                self.aside.remove(&(vehicle.clone(), grantor.to_string()));
                self.retry_aside(&vehicle);
            }
            Ok(Applied::Stale) => self.counters.stale += 1,
            Err(LeaseRefusal::NoAuthority { .. }) => {
                // Only for a vehicle the table holds, one per configured grantor: bounded
                // by the table's limit × the sites. A refused record for a vehicle not
                // known here is forgotten (else a site could fill this with made-up ids).
                if self.leases.contains_key(&vehicle) {
                    self.aside.insert((vehicle, grantor.to_string()), record);
                }
            }
            Err(_) => {}
        }
        result
    }

    /// Takes records kept aside for `vehicle` that a change gave authority to.
    fn retry_aside(&mut self, vehicle: &str) {
        loop {
            let keys: Vec<(String, String)> = self
                .aside
                .keys()
                .filter(|(v, _)| v == vehicle)
                .cloned()
                .collect();
            let mut progressed = false;
            for key in keys {
                let Some(record) = self.aside.remove(&key) else {
                    continue;
                };
                match self.take(&key.1, record.clone()) {
                    Ok(Applied::Changed) => {
                        self.counters.taken_later += 1;
                        progressed = true;
                    }
                    Ok(Applied::Stale) => {}
                    Err(_) => {
                        self.aside.insert(key, record);
                    }
                }
            }
            if !progressed {
                return;
            }
        }
    }

    fn take(&mut self, grantor: &str, record: LeaseRecord) -> Result<Applied, LeaseRefusal> {
        let refuse = |current: &LeaseRecord, reason: LeaseReason| LeaseRefusal::NoAuthority {
            grantor: grantor.to_string(),
            reason: reason.as_str(),
            vehicle: current.vehicle_id.clone(),
            holder: current.holder.clone(),
            term: current.term,
        };
        match self.leases.get(&record.vehicle_id) {
            None => {
                // Nothing known to judge by but the record itself: a claim must come from
                // the home, a failover from the site taking it; a handover is believed.
                let allowed = match record.reason {
                    LeaseReason::Claim => record.home == grantor && record.holder == grantor,
                    LeaseReason::Failover => record.holder == grantor,
                    LeaseReason::Handover => true,
                };
                if !allowed {
                    return Err(LeaseRefusal::NoAuthority {
                        grantor: grantor.to_string(),
                        reason: record.reason.as_str(),
                        vehicle: record.vehicle_id.clone(),
                        holder: record.holder.clone(),
                        term: 0,
                    });
                }
                if self.leases.len() >= self.max_vehicles {
                    return Err(LeaseRefusal::Full);
                }
            }
            Some(current) => {
                let current = &current.record;
                if !record.supersedes(current) {
                    return Ok(Applied::Stale);
                }
                if record.home != current.home {
                    return Err(LeaseRefusal::WrongHome {
                        vehicle: record.vehicle_id.clone(),
                        known: current.home.clone(),
                        claimed: record.home.clone(),
                    });
                }
                let allowed = match record.reason {
                    // A second claim of a vehicle with a lease is a home that forgot it.
                    LeaseReason::Claim => false,
                    LeaseReason::Handover => current.holder == grantor,
                    LeaseReason::Failover => {
                        record.holder == grantor
                            && (current.home == grantor || current.standby == grantor)
                    }
                };
                if !allowed {
                    return Err(refuse(current, record.reason));
                }
            }
        }
        self.leases.insert(
            record.vehicle_id.clone(),
            Current {
                record,
                grantor: grantor.to_string(),
            },
        );
        Ok(Applied::Changed)
    }
}

#[cfg(test)]
mod tests;
