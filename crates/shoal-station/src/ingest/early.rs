//! State vectors that arrive before their vehicle's announcement.
//!
//! A vehicle that has just started publishes its announcement (reliable, transient-local)
//! and its first state vectors at once. DDS delivers a best-effort sample as soon as the
//! writers match, and the reliable announcement one repair round trip later, so the first
//! state vector often reaches the station first. Refusing it as `unknown_vehicle` would
//! lose good data and raise a warning per vehicle at every start. The Data Access Manager
//! holds such samples for a short grace instead: the announcement releases them into the
//! normal path; at the end of the grace they are refused as before.
//!
//! A sender controls what it holds, so everything here is bounded: samples per vehicle,
//! vehicles, and the grace itself.

use std::collections::{HashMap, VecDeque};

use shoal_model::{StateVector, Validated};

/// Samples held for one vehicle id; beyond, the oldest is refused.
pub(crate) const MAX_PER_VEHICLE: usize = 16;
/// Vehicle ids with held samples; a sample naming another id is refused at once.
pub(crate) const MAX_VEHICLES: usize = 256;

/// State vectors of vehicles not announced yet, each with when it was held.
#[derive(Debug, Default)]
pub(crate) struct EarlyStates {
    by_vehicle: HashMap<String, VecDeque<(i64, Validated<StateVector>)>>,
}

impl EarlyStates {
    /// Holds `s`, received at `now`. What cannot be held comes back, to be refused now:
    /// `s` itself when too many vehicles are waiting, or the vehicle's oldest sample when
    /// its queue is full.
    pub(crate) fn hold(
        &mut self,
        s: Validated<StateVector>,
        now: i64,
    ) -> Option<Validated<StateVector>> {
        let id = &s.as_ref().vehicle_id;
        if !self.by_vehicle.contains_key(id) && self.by_vehicle.len() >= MAX_VEHICLES {
            return Some(s);
        }
        let queue = self.by_vehicle.entry(id.clone()).or_default();
        let evicted = (queue.len() >= MAX_PER_VEHICLE)
            .then(|| queue.pop_front().map(|(_, s)| s))
            .flatten();
        queue.push_back((now, s));
        evicted
    }

    /// The samples held for `vehicle_id`, oldest first; none are held for it afterwards.
    pub(crate) fn release(&mut self, vehicle_id: &str) -> Vec<Validated<StateVector>> {
        self.by_vehicle
            .remove(vehicle_id)
            .map(|q| q.into_iter().map(|(_, s)| s).collect())
            .unwrap_or_default()
    }

    /// The samples held since before `now - grace_ms`, oldest first per vehicle; the
    /// rest stay held.
    pub(crate) fn expire(&mut self, now: i64, grace_ms: i64) -> Vec<Validated<StateVector>> {
        let mut out = Vec::new();
        self.by_vehicle.retain(|_, q| {
            while q.front().is_some_and(|(at, _)| now - at >= grace_ms) {
                out.extend(q.pop_front().map(|(_, s)| s));
            }
            !q.is_empty()
        });
        out
    }

    /// Samples held now, all vehicles together.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.by_vehicle.values().map(VecDeque::len).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Timestamps are small numbers in these tests; the sample carries them as an
    /// offset from a valid epoch time.
    const T0: i64 = 1_800_000_000_000;

    fn sv(id: &str, t: i64) -> Validated<StateVector> {
        Validated::new(crate::testing::state(id, T0 + t, 50.0)).unwrap()
    }

    #[test]
    fn held_samples_are_released_oldest_first_when_the_vehicle_announces() {
        let mut e = EarlyStates::default();
        assert!(e.hold(sv("auv-1", 10), 100).is_none());
        assert!(e.hold(sv("auv-1", 20), 150).is_none());
        assert!(e.hold(sv("auv-2", 30), 150).is_none());
        let got: Vec<i64> = e
            .release("auv-1")
            .iter()
            .map(|s| s.as_ref().timestamp_ms - T0)
            .collect();
        assert_eq!(got, [10, 20]);
        assert!(e.release("auv-1").is_empty());
        assert_eq!(e.len(), 1);
    }

    #[test]
    fn samples_older_than_the_grace_expire_and_younger_ones_stay() {
        let mut e = EarlyStates::default();
        e.hold(sv("auv-1", 1), 1_000);
        e.hold(sv("auv-1", 2), 5_000);
        e.hold(sv("auv-2", 3), 2_500);
        let gone: Vec<i64> = e
            .expire(6_000, 4_000)
            .iter()
            .map(|s| s.as_ref().timestamp_ms - T0)
            .collect();
        assert_eq!(gone, [1]);
        assert_eq!(e.len(), 2);
        let mut gone: Vec<i64> = e
            .expire(9_000, 4_000)
            .iter()
            .map(|s| s.as_ref().timestamp_ms - T0)
            .collect();
        gone.sort_unstable();
        assert_eq!(gone, [2, 3]);
        assert_eq!(e.len(), 0);
        assert!(e.by_vehicle.is_empty(), "emptied vehicles are forgotten");
    }

    #[test]
    fn a_full_queue_gives_back_its_oldest_and_too_many_vehicles_give_back_the_new_one() {
        let mut e = EarlyStates::default();
        for t in 0..MAX_PER_VEHICLE as i64 {
            assert!(e.hold(sv("auv-1", t), 0).is_none());
        }
        let evicted = e.hold(sv("auv-1", 99), 0).unwrap();
        assert_eq!(evicted.as_ref().timestamp_ms, T0);
        assert_eq!(e.len(), MAX_PER_VEHICLE);

        for v in 1..MAX_VEHICLES {
            assert!(e.hold(sv(&format!("v-{v}"), 1), 0).is_none());
        }
        let refused = e.hold(sv("one-too-many", 7), 0).unwrap();
        assert_eq!(refused.as_ref().vehicle_id, "one-too-many");
        // A vehicle already waiting still gets its samples held.
        assert!(e.hold(sv("v-1", 2), 0).is_none());
        assert_eq!(e.len(), MAX_PER_VEHICLE + MAX_VEHICLES);
    }
}
