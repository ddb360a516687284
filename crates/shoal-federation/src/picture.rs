//! `FederatedPicture`: what this site knows of the remote sites — their vehicles with the
//! age of their data, the alarms and task transitions received from them, the latest
//! environment summary of each of their vehicles' properties, and whether each site's
//! session is up. Everything in it is bounded by `[federation.limits]`.

use std::collections::{BTreeMap, VecDeque};

use shoal_model::Event;

use crate::environment::{EnvironmentAggregates, PropertyAggregate};
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

/// The latest environment summary of one property of a remote site's vehicle: over the
/// window `[window_start_ms, window_end_ms)` of the sending site's clock.
#[derive(Debug, Clone, PartialEq)]
pub struct RemoteEnvironment {
    /// The site the vehicle belongs to.
    pub site: String,
    /// The vehicle.
    pub vehicle_id: String,
    /// Start of the window, ms since the Unix epoch.
    pub window_start_ms: i64,
    /// End of the window, ms since the Unix epoch.
    pub window_end_ms: i64,
    /// The property's summary over the window, as the frame carried it (positions to its
    /// wire steps: 1e-7 degree, 0.2 m).
    pub summary: PropertyAggregate,
    /// When the summary arrived here, ms since the Unix epoch.
    pub received_ms: i64,
}

/// (site, vehicle, property): one environment summary held per key.
type EnvironmentKey = (String, String, String);
/// A summary held, with the (epoch, seq) of the frame that brought it.
type HeldEnvironment = (RemoteEnvironment, (u64, u64));

/// What became of the summaries of one environment frame.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct EnvironmentTaken {
    /// Taken into the picture.
    pub taken: u64,
    /// Refused: the picture holds a later window of the same property.
    pub stale: u64,
    /// The same frame again (same sender run and number).
    pub duplicate: u64,
    /// Refused: a new (site, vehicle, property) beyond `limits.remote_environment`.
    pub full: u64,
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
    environment: BTreeMap<EnvironmentKey, HeldEnvironment>,
    sites: BTreeMap<String, SiteStatus>,
    last_index: u64,
    max_vehicles: usize,
    max_alarms: usize,
    max_transitions: usize,
    max_environment: usize,
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
    /// An empty picture with these bounds (those of `[federation.limits]`).
    pub fn new(
        max_vehicles: usize,
        max_alarms: usize,
        max_transitions: usize,
        max_environment: usize,
    ) -> Self {
        Self {
            max_vehicles,
            max_alarms,
            max_transitions,
            max_environment,
            ..Self::default()
        }
    }

    /// Takes each summary of a frame from `site`, sent as `(epoch, seq)`, on its own: a
    /// summary replaces the one held for its (site, vehicle, property) unless that one is
    /// of a later window, or the same frame.
    pub(crate) fn environment_frame(
        &mut self,
        site: &str,
        sent: (u64, u64),
        frame: EnvironmentAggregates,
        now_ms: i64,
    ) -> EnvironmentTaken {
        let mut out = EnvironmentTaken::default();
        let EnvironmentAggregates {
            vehicle_id,
            window_start_ms,
            window_end_ms,
            properties,
        } = frame;
        for p in properties {
            let key = (site.to_string(), vehicle_id.clone(), p.property.clone());
            let full = self.environment.len() >= self.max_environment;
            let held = self.environment.get(&key);
            match held {
                Some((h, _)) if h.window_end_ms > window_end_ms => {
                    out.stale += 1;
                    continue;
                }
                Some((h, from)) if h.window_end_ms == window_end_ms && *from == sent => {
                    out.duplicate += 1;
                    continue;
                }
                None if full => {
                    out.full += 1;
                    continue;
                }
                _ => {}
            }
            let remote = RemoteEnvironment {
                site: site.to_string(),
                vehicle_id: vehicle_id.clone(),
                window_start_ms,
                window_end_ms,
                summary: p,
                received_ms: now_ms,
            };
            self.environment.insert(key, (remote, sent));
            out.taken += 1;
        }
        out
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

    /// The latest environment summary of every property of every remote vehicle, by site,
    /// vehicle, then property. A rolling picture: each window's summary replaces the
    /// previous one, and a lost one is replaced by the next window's (none is caught up).
    pub fn environment(&self) -> impl Iterator<Item = &RemoteEnvironment> {
        self.environment.values().map(|(e, _)| e)
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
        let mut pic = FederatedPicture::new(2, 10, 10, 10);
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
        let mut pic = FederatedPicture::new(1, 2, 2, 2);
        for seq in 1..=3 {
            pic.alarm("ship", seq, alarm(&format!("e{seq}")), 0);
        }
        let kept: Vec<u64> = pic.alarms_after(0).map(|a| a.seq).collect();
        assert_eq!(kept, vec![2, 3]);
        assert_eq!(pic.alarms_after(2).count(), 1);
    }

    #[test]
    fn environment_keeps_the_latest_window_per_property_within_its_bound() {
        use crate::environment::tests::aggregates;
        let mut pic = FederatedPicture::new(1, 1, 1, 3);
        let frame = aggregates("auv-1", &["s", "t"]);
        let taken = pic.environment_frame("ship", (1, 1), frame.clone(), 5);
        assert_eq!(taken.taken, 2);
        // The same frame again: a duplicate.
        let again = pic.environment_frame("ship", (1, 1), frame.clone(), 6);
        assert_eq!((again.taken, again.duplicate), (0, 2));
        // An earlier window: stale; a later one replaces, and a third property fits.
        let mut earlier = frame;
        earlier.window_start_ms -= 60_000;
        earlier.window_end_ms -= 60_000;
        assert_eq!(pic.environment_frame("ship", (1, 2), earlier, 7).stale, 2);
        let mut later = aggregates("auv-1", &["o", "t"]);
        later.window_start_ms += 60_000;
        later.window_end_ms += 60_000;
        later.properties[1].count = 9;
        assert_eq!(pic.environment_frame("ship", (1, 3), later, 8).taken, 2);
        // The bound: a fourth (site, vehicle, property) is refused, a known one is not.
        let other = aggregates("auv-2", &["t"]);
        assert_eq!(pic.environment_frame("ship", (1, 4), other, 9).full, 1);
        let got: Vec<(&str, u32, i64)> = pic
            .environment()
            .map(|e| (e.summary.property.as_str(), e.summary.count, e.received_ms))
            .collect();
        assert_eq!(got, [("o", 3, 8), ("s", 3, 5), ("t", 9, 8)]);
        let t = pic.environment().last().unwrap();
        assert_eq!((t.site.as_str(), t.vehicle_id.as_str()), ("ship", "auv-1"));
    }
}
