//! The Vehicle Register's live state: every known vehicle, its latest state, contact and
//! availability. This is the one place they are kept; the semantic model mirrors them.

use std::collections::BTreeMap;

use serde::Serialize;
use shoal_model::{Availability, LinkKind, LinkStatus, StateVector, VehicleAnnouncement};

use crate::ingest::preprocess::Suspects;

/// Whether a vehicle is being heard from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Contact {
    /// A state vector arrived recently.
    Alive,
    /// Nothing for longer than `stale_after_s`.
    Stale,
    /// Nothing for longer than `lost_after_s`.
    Lost,
    /// Announced but no state vector yet.
    Silent,
}

/// One vehicle as the station knows it.
#[derive(Debug, Clone, Serialize)]
pub struct VehicleView {
    /// Registration data.
    pub announcement: VehicleAnnouncement,
    /// Latest accepted state vector.
    pub latest: Option<StateVector>,
    /// Station clock when the latest state vector arrived, ms since the Unix epoch.
    pub last_contact_ms: Option<i64>,
    /// Link the vehicle is heard on: `ip` unless a CDT reports it acoustic.
    pub link: LinkKind,
    /// The latest link status a CDT reported (acoustic address, RSSI, integrity, relay).
    pub link_status: Option<LinkStatus>,
    /// Contact status now.
    pub contact: Contact,
    /// What it can be asked to do now.
    pub availability: Availability,
    /// State vectors accepted from this vehicle since the station started.
    pub states_accepted: u64,
    /// State vectors rejected from this vehicle since the station started.
    pub states_rejected: u64,
}

#[derive(Debug)]
pub(crate) struct Entry {
    pub(crate) announcement: VehicleAnnouncement,
    pub(crate) latest: Option<StateVector>,
    pub(crate) last_contact_ms: Option<i64>,
    pub(crate) link: LinkKind,
    pub(crate) link_status: Option<LinkStatus>,
    pub(crate) states_accepted: u64,
    pub(crate) states_rejected: u64,
    pub(crate) contact: Contact,
    /// Rejected state vectors in a row that may yet re-anchor the vehicle.
    pub(crate) suspects: Suspects,
    /// The battery rose between the last two accepted states.
    pub(crate) battery_rising: bool,
    /// Station time of the vehicle's latest fault event.
    pub(crate) last_fault_ms: Option<i64>,
    /// DDS participant its announcements come from (its own, or a CDT's for an
    /// acoustic vehicle).
    pub(crate) participant: Option<String>,
    /// Station time that participant left DDS; contact is lost until a newer state.
    pub(crate) left_ms: Option<i64>,
    /// The participant of the CDT that last reported hearing it acoustically: a vehicle
    /// that fails over between IP and acoustic still has that path when its own IP
    /// participant leaves (it dived), so that leaving does not make it lost at once.
    pub(crate) acoustic_via: Option<String>,
    /// What it can be asked to do, as last decided by [`Entry::refresh_availability`].
    pub(crate) availability: Availability,
    /// A task is under way, as the Mission & Task Register last said.
    pub(crate) busy: bool,
}

/// All vehicles by id.
#[derive(Debug, Default)]
pub(crate) struct Fleet {
    pub(crate) vehicles: BTreeMap<String, Entry>,
    /// Vehicles known by their announcement only (no state vector yet): what a flood of
    /// announcements with made-up ids would grow, so it is capped.
    pub(crate) unheard: usize,
}

impl Fleet {
    /// Registers or updates a vehicle; re-registration after a restart keeps its state.
    /// Returns true when the vehicle is new.
    pub(crate) fn register(&mut self, a: VehicleAnnouncement) -> bool {
        match self.vehicles.get_mut(&a.vehicle_id) {
            Some(e) => {
                e.announcement = a;
                false
            }
            None => {
                self.unheard += 1;
                self.vehicles.insert(
                    a.vehicle_id.clone(),
                    Entry {
                        announcement: a,
                        latest: None,
                        last_contact_ms: None,
                        link: LinkKind::Ip,
                        link_status: None,
                        states_accepted: 0,
                        states_rejected: 0,
                        contact: Contact::Silent,
                        suspects: Suspects::default(),
                        battery_rising: false,
                        last_fault_ms: None,
                        participant: None,
                        left_ms: None,
                        acoustic_via: None,
                        availability: Availability::Idle,
                        busy: false,
                    },
                );
                true
            }
        }
    }

    /// Counts the vehicles known by announcement only again (after a restart's reload).
    pub(crate) fn recount_unheard(&mut self) {
        self.unheard = self
            .vehicles
            .values()
            .filter(|e| e.latest.is_none())
            .count();
    }

    /// Re-evaluates contact status at `now_ms`; returns the vehicles whose status changed.
    pub(crate) fn refresh_contact(
        &mut self,
        now_ms: i64,
        stale_ms: i64,
        lost_ms: i64,
    ) -> Vec<(String, Contact, Contact)> {
        let mut changed = Vec::new();
        for (id, e) in &mut self.vehicles {
            let new = match e.last_contact_ms {
                // Its DDS participant left after its last state: lost at once, without
                // waiting for `lost_after_s`.
                Some(t) if e.left_ms.is_some_and(|l| l >= t) => Contact::Lost,
                None => Contact::Silent,
                Some(t) if now_ms - t >= lost_ms => Contact::Lost,
                Some(t) if now_ms - t >= stale_ms => Contact::Stale,
                Some(_) => Contact::Alive,
            };
            if new != e.contact {
                changed.push((id.clone(), e.contact, new));
                e.contact = new;
            }
        }
        changed
    }

    /// `id` was heard at `now_ms` by something other than a state vector; the change of
    /// its contact to alive, if it was not.
    pub(crate) fn heard(&mut self, id: &str, now_ms: i64) -> Option<(Contact, Contact)> {
        let e = self.vehicles.get_mut(id)?;
        e.last_contact_ms = Some(e.last_contact_ms.map_or(now_ms, |t| t.max(now_ms)));
        let from = e.contact;
        if from == Contact::Alive || from == Contact::Silent {
            // Silent: never sent a state; hearing a report does not make up a position.
            return None;
        }
        e.contact = Contact::Alive;
        Some((from, Contact::Alive))
    }

    /// Marks the vehicles heard through `participant` as gone; returns their ids.
    pub(crate) fn participant_left(&mut self, participant: &str, now_ms: i64) -> Vec<String> {
        let mut gone = Vec::new();
        for (id, e) in &mut self.vehicles {
            let other_path = e
                .acoustic_via
                .as_deref()
                .is_some_and(|via| via != participant);
            if e.participant.as_deref() == Some(participant) && !other_path {
                e.left_ms = Some(now_ms);
                gone.push(id.clone());
            }
        }
        gone
    }

    pub(crate) fn view(&self) -> Vec<VehicleView> {
        self.vehicles.values().map(Entry::view).collect()
    }
}

impl Entry {
    /// Decides availability again; returns the new value when it changed.
    pub(crate) fn refresh_availability(&mut self, now_ms: i64) -> Option<Availability> {
        let now = self.decide_availability(self.busy, now_ms);
        (now != self.availability).then(|| {
            self.availability = now;
            now
        })
    }

    /// Availability from contact, faults, tasks and charging, in that order of precedence.
    fn decide_availability(&self, busy: bool, now_ms: i64) -> Availability {
        const FAULT_MEMORY_MS: i64 = 600_000;
        if self.contact == Contact::Lost {
            Availability::Lost
        } else if self
            .last_fault_ms
            .is_some_and(|t| now_ms - t < FAULT_MEMORY_MS)
        {
            Availability::Fault
        } else if busy {
            Availability::Busy
        } else if self.battery_rising
            && self
                .latest
                .as_ref()
                .is_some_and(|s| s.depth_m <= 1.0 && s.speed_mps <= 0.2)
        {
            Availability::Charging
        } else {
            Availability::Idle
        }
    }

    pub(crate) fn view(&self) -> VehicleView {
        VehicleView {
            availability: self.availability,
            announcement: self.announcement.clone(),
            latest: self.latest.clone(),
            last_contact_ms: self.last_contact_ms,
            link: self.link,
            link_status: self.link_status.clone(),
            contact: self.contact,
            states_accepted: self.states_accepted,
            states_rejected: self.states_rejected,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::VehicleKind;

    fn ann(id: &str) -> VehicleAnnouncement {
        VehicleAnnouncement {
            vehicle_id: id.into(),
            name: id.into(),
            kind: VehicleKind::Auv,
            vendor: "test".into(),
            capabilities: vec![],
            sensors: vec![],
            links: vec![LinkKind::Ip],
            max_speed_mps: 2.0,
            timestamp_ms: 1_700_000_000_000,
        }
    }

    #[test]
    fn re_registration_is_idempotent_and_keeps_counters() {
        let mut f = Fleet::default();
        assert!(f.register(ann("a")));
        if let Some(e) = f.vehicles.get_mut("a") {
            e.states_accepted = 5;
        }
        assert!(!f.register(ann("a")));
        assert_eq!(f.vehicles.len(), 1);
        assert_eq!(f.vehicles["a"].states_accepted, 5);
    }

    #[test]
    fn contact_goes_stale_then_lost() {
        let mut f = Fleet::default();
        f.register(ann("a"));
        if let Some(e) = f.vehicles.get_mut("a") {
            e.last_contact_ms = Some(0);
        }
        assert_eq!(
            f.refresh_contact(1000, 5000, 30_000),
            vec![("a".into(), Contact::Silent, Contact::Alive)]
        );
        assert_eq!(f.refresh_contact(6000, 5000, 30_000)[0].2, Contact::Stale);
        assert_eq!(f.refresh_contact(31_000, 5000, 30_000)[0].2, Contact::Lost);
        assert!(f.refresh_contact(32_000, 5000, 30_000).is_empty());
    }

    #[test]
    fn a_vehicle_whose_participant_left_is_lost_until_it_reports_again() {
        let mut f = Fleet::default();
        f.register(ann("a"));
        if let Some(e) = f.vehicles.get_mut("a") {
            e.last_contact_ms = Some(1000);
            e.participant = Some("p1".into());
        }
        f.refresh_contact(1500, 5000, 30_000);
        assert_eq!(f.participant_left("p2", 2000), Vec::<String>::new());
        assert_eq!(f.participant_left("p1", 2000), vec!["a".to_string()]);
        assert_eq!(f.refresh_contact(2100, 5000, 30_000)[0].2, Contact::Lost);
        // A newer state (e.g. through another relay) brings it back.
        if let Some(e) = f.vehicles.get_mut("a") {
            e.last_contact_ms = Some(3000);
        }
        assert_eq!(f.refresh_contact(3100, 5000, 30_000)[0].2, Contact::Alive);
    }

    #[test]
    fn a_vehicle_a_cdt_also_hears_is_not_lost_when_its_ip_participant_leaves() {
        let mut f = Fleet::default();
        f.register(ann("a"));
        if let Some(e) = f.vehicles.get_mut("a") {
            e.last_contact_ms = Some(1000);
            // It surfaced: its announcements now come over its own IP participant, and
            // a CDT heard it acoustically before.
            e.participant = Some("ip".into());
            e.acoustic_via = Some("cdt".into());
        }
        f.refresh_contact(1500, 5000, 30_000);
        // It dives: its IP participant leaves; contact ages as usual over acoustic.
        assert!(f.participant_left("ip", 2000).is_empty());
        assert!(f.refresh_contact(2100, 5000, 30_000).is_empty());
        assert_eq!(f.refresh_contact(31_000, 5000, 30_000)[0].2, Contact::Lost);
        // The CDT's own participant leaving takes its acoustic vehicles' path away.
        if let Some(e) = f.vehicles.get_mut("a") {
            e.last_contact_ms = Some(40_000);
            e.participant = Some("cdt".into());
        }
        f.refresh_contact(40_100, 5000, 30_000);
        assert_eq!(f.participant_left("cdt", 41_000), vec!["a".to_string()]);
        assert_eq!(f.refresh_contact(41_100, 5000, 30_000)[0].2, Contact::Lost);
    }
}
