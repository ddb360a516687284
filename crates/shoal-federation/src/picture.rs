//! `FederatedPicture`: what this site knows of the remote sites — their vehicles with the
//! age of their data, the alarms and task transitions received from them, and whether
//! each site's session is up. Everything in it is bounded by `[federation.limits]`.

use std::collections::{BTreeMap, VecDeque};

use shoal_model::Event;

use crate::types::{TaskTransition, VehiclePosition};

/// A remote site's vehicle, as last heard.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteVehicle {
    /// The site it belongs to.
    pub site: String,
    /// Its latest position.
    pub position: VehiclePosition,
    /// When that position arrived here, ms since the Unix epoch.
    pub received_ms: i64,
}

impl RemoteVehicle {
    /// Age of the data at `now_ms`: time since the fix was taken (never negative).
    pub fn age_ms(&self, now_ms: i64) -> i64 {
        (now_ms - self.position.timestamp_ms).max(0)
    }
}

/// An alarm received from a remote site.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteAlarm {
    /// Local arrival order, from 1: a reader asks for those after the last it saw.
    pub index: u64,
    /// The site that raised it.
    pub site: String,
    /// Its sequence number in that site's alarm stream.
    pub seq: u64,
    /// The alarm.
    pub alarm: Event,
    /// Arrival time here, ms since the Unix epoch.
    pub received_ms: i64,
}

/// A task transition received from a remote site.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteTransition {
    /// Local arrival order, from 1.
    pub index: u64,
    /// The site whose task it is.
    pub site: String,
    /// Its sequence number in that site's task stream.
    pub seq: u64,
    /// The transition.
    pub transition: TaskTransition,
    /// Arrival time here, ms since the Unix epoch.
    pub received_ms: i64,
}

/// Whether a remote site's session is up, as its liveliness token says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SiteStatus {
    /// Its token is present.
    pub online: bool,
    /// Since when, ms since the Unix epoch.
    pub since_ms: i64,
}

/// The remote part of the fleet picture.
#[derive(Debug, Default)]
pub struct FederatedPicture {
    vehicles: BTreeMap<(String, String), RemoteVehicle>,
    alarms: VecDeque<RemoteAlarm>,
    transitions: VecDeque<RemoteTransition>,
    sites: BTreeMap<String, SiteStatus>,
    last_index: u64,
    max_vehicles: usize,
    max_alarms: usize,
    max_transitions: usize,
}

/// Why the picture did not take a position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PositionRefusal {
    /// Older than the one held for that vehicle.
    Stale,
    /// A new vehicle beyond `limits.remote_vehicles`.
    Full,
}

impl FederatedPicture {
    /// An empty picture with these bounds.
    pub fn new(max_vehicles: usize, max_alarms: usize, max_transitions: usize) -> Self {
        Self {
            max_vehicles,
            max_alarms,
            max_transitions,
            ..Self::default()
        }
    }

    pub(crate) fn position(
        &mut self,
        site: &str,
        position: VehiclePosition,
        now_ms: i64,
    ) -> Result<(), PositionRefusal> {
        let key = (site.to_string(), position.vehicle_id.clone());
        let full = self.vehicles.len() >= self.max_vehicles;
        match self.vehicles.get_mut(&key) {
            Some(held) if held.position.timestamp_ms > position.timestamp_ms => {
                Err(PositionRefusal::Stale)
            }
            Some(held) => {
                held.position = position;
                held.received_ms = now_ms;
                Ok(())
            }
            None if full => Err(PositionRefusal::Full),
            None => {
                self.vehicles.insert(
                    key,
                    RemoteVehicle {
                        site: site.to_string(),
                        position,
                        received_ms: now_ms,
                    },
                );
                Ok(())
            }
        }
    }

    pub(crate) fn alarm(&mut self, site: &str, seq: u64, alarm: Event, now_ms: i64) {
        self.last_index += 1;
        if self.alarms.len() == self.max_alarms {
            self.alarms.pop_front();
        }
        self.alarms.push_back(RemoteAlarm {
            index: self.last_index,
            site: site.to_string(),
            seq,
            alarm,
            received_ms: now_ms,
        });
    }

    pub(crate) fn transition(
        &mut self,
        site: &str,
        seq: u64,
        transition: TaskTransition,
        now_ms: i64,
    ) {
        self.last_index += 1;
        if self.transitions.len() == self.max_transitions {
            self.transitions.pop_front();
        }
        self.transitions.push_back(RemoteTransition {
            index: self.last_index,
            site: site.to_string(),
            seq,
            transition,
            received_ms: now_ms,
        });
    }

    pub(crate) fn site(&mut self, site: &str, online: bool, now_ms: i64) {
        let status = self.sites.entry(site.to_string()).or_insert(SiteStatus {
            online,
            since_ms: now_ms,
        });
        if status.online != online {
            *status = SiteStatus {
                online,
                since_ms: now_ms,
            };
        }
    }

    /// Every remote vehicle, by site then vehicle id.
    pub fn vehicles(&self) -> impl Iterator<Item = &RemoteVehicle> {
        self.vehicles.values()
    }

    /// One remote vehicle.
    pub fn vehicle(&self, site: &str, vehicle_id: &str) -> Option<&RemoteVehicle> {
        self.vehicles
            .get(&(site.to_string(), vehicle_id.to_string()))
    }

    /// The kept alarms that arrived after the one with `index` (0 for all), oldest first.
    pub fn alarms_after(&self, index: u64) -> impl Iterator<Item = &RemoteAlarm> {
        self.alarms.iter().filter(move |a| a.index > index)
    }

    /// The kept transitions that arrived after the one with `index` (0 for all).
    pub fn transitions_after(&self, index: u64) -> impl Iterator<Item = &RemoteTransition> {
        self.transitions.iter().filter(move |t| t.index > index)
    }

    /// The remote sites heard of, with whether each is up.
    pub fn sites(&self) -> impl Iterator<Item = (&str, SiteStatus)> {
        self.sites.iter().map(|(s, st)| (s.as_str(), *st))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::types::tests::position;
    use crate::wire::tests::alarm;

    #[test]
    fn the_picture_keeps_the_newest_position_and_refuses_vehicles_past_its_bound() {
        let mut pic = FederatedPicture::new(2, 10, 10);
        let mut p = position("a");
        pic.position("ship", p.clone(), 0).unwrap();
        p.timestamp_ms -= 1;
        assert_eq!(pic.position("ship", p, 0), Err(PositionRefusal::Stale));
        pic.position("ship", position("b"), 0).unwrap();
        assert_eq!(
            pic.position("ship", position("c"), 0),
            Err(PositionRefusal::Full)
        );
        // The same vehicle id at another site is another vehicle.
        assert_eq!(
            pic.position("ship2", position("a"), 0),
            Err(PositionRefusal::Full)
        );
        let a = pic.vehicle("ship", "a").unwrap();
        assert_eq!(a.age_ms(a.position.timestamp_ms + 1500), 1500);
    }

    #[test]
    fn alarms_are_bounded_and_read_after_an_index() {
        let mut pic = FederatedPicture::new(1, 2, 2);
        for seq in 1..=3 {
            pic.alarm("ship", seq, alarm(&format!("e{seq}")), 0);
        }
        let kept: Vec<u64> = pic.alarms_after(0).map(|a| a.seq).collect();
        assert_eq!(kept, vec![2, 3]);
        assert_eq!(pic.alarms_after(2).count(), 1);
    }
}
