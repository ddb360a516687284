//! Vessel traffic at the station: the traffic picture's AIS targets mirrored into the
//! semantic model once a second, and each surface vehicle's encounter with each of them
//! (closest point of approach), which the built-in collision-risk rule watches, so that a
//! collision alarm is an event of the rules engine like any other.

use std::collections::{HashMap, HashSet};
use std::sync::Mutex;

use shoal_model::VehicleKind;
use shoal_semantic::{Encounter, TrafficTarget};
use shoal_traffic::{ApproachWindow, Motion, OwnVehicle, TrafficHandle};
use tracing::info;

use crate::core::{StationHandle, lock};
use crate::reporters::LiveUpdate;

/// Metres per second in one knot.
const MS_PER_KNOT: f64 = shoal_traffic::MS_PER_KNOT;
/// An encounter is kept in the model while its CPA is under this many times the
/// collision-risk threshold, so that an operator's own rule can use a wider one.
const WATCH_FACTOR: f64 = 4.0;
/// ... and while its closest point is at most this far in the past, seconds.
const WATCH_PAST_S: f64 = 60.0;
/// A vehicle state older than this is not extrapolated, seconds.
const MAX_EXTRAPOLATION_S: f64 = 120.0;

/// The traffic picture as the station holds it, with what it last wrote to the model.
pub(crate) struct TrafficLink {
    handle: TrafficHandle,
    mirror: Mutex<Mirror>,
}

/// What the semantic model holds of the picture: targets by MMSI with the message count
/// last written, and the encounters.
#[derive(Default)]
struct Mirror {
    targets: HashMap<u32, u64>,
    encounters: HashSet<(String, u32)>,
}

impl StationHandle {
    /// Attaches a running traffic picture: from now on its targets are mirrored into the
    /// semantic model and checked against the surface vehicles once a second. A second
    /// picture is refused (returned).
    pub fn attach_traffic(&self, handle: TrafficHandle) -> Result<(), TrafficHandle> {
        self.core
            .traffic
            .set(TrafficLink {
                handle,
                mirror: Mutex::new(Mirror::default()),
            })
            .map_err(|link| link.handle)
    }

    /// The traffic picture, when one is attached (`[traffic]` has inputs).
    pub fn traffic(&self) -> Option<&TrafficHandle> {
        self.core.traffic.get().map(|t| &t.handle)
    }

    /// The once-a-second traffic work at `now`: targets into the model, gone ones out,
    /// encounters updated (the collision-risk rule fires inside).
    pub(crate) fn traffic_tick(&self, now: i64) {
        let Some(link) = self.core.traffic.get() else {
            return;
        };
        let targets = link.handle.targets();
        // Surface vehicles with a position, carried forward to now.
        let vehicles: Vec<OwnVehicle> = {
            let fleet = lock(&self.core.fleet);
            fleet
                .vehicles
                .values()
                .filter(|e| matches!(e.announcement.kind, VehicleKind::Usv | VehicleKind::Asv))
                .filter_map(|e| {
                    let s = e.latest.as_ref()?;
                    #[allow(clippy::cast_precision_loss)]
                    let age_s = (now - s.timestamp_ms) as f64 / 1000.0;
                    if !(0.0..=MAX_EXTRAPOLATION_S).contains(&age_s) {
                        return None;
                    }
                    let m = Motion {
                        lat: s.latitude_deg,
                        lon: s.longitude_deg,
                        // The state vector has heading, not course: without current or
                        // drift data the two are taken as the same.
                        cog_deg: s.yaw_deg.rem_euclid(360.0),
                        sog_kn: s.speed_mps.max(0.0) / MS_PER_KNOT,
                    };
                    Some(OwnVehicle {
                        id: s.vehicle_id.clone(),
                        motion: m.advanced(age_s),
                    })
                })
                .collect()
        };
        let cfg = &self.core.config.semantic;
        let window = ApproachWindow {
            within_m: cfg.collision_cpa_m * WATCH_FACTOR,
            past_s: WATCH_PAST_S,
            ahead_s: cfg.collision_tcpa_s * 2.0,
        };
        let approaches = link.handle.approaches(&vehicles, window);
        let mut mirror = lock(&link.mirror);
        let mut semantic = lock(&self.core.semantic);
        let mut fired = Vec::new();
        let mut present = HashSet::with_capacity(targets.len());
        let mut moved = Vec::new();
        // Copies for live clients only while some are connected (as vehicle states).
        let live_clients = self.has_live_clients();
        for t in &targets {
            let (Some(lat), Some(lon)) = (t.lat, t.lon) else {
                continue;
            };
            present.insert(t.mmsi);
            if mirror.targets.get(&t.mmsi) == Some(&t.messages) {
                continue;
            }
            let written = semantic.upsert_traffic_target(&TrafficTarget {
                mmsi: t.mmsi,
                name: t.name.as_deref().unwrap_or(""),
                latitude_deg: lat,
                longitude_deg: lon,
                course_deg: t.cog_deg,
                speed_mps: t.sog_kn.map(|kn| kn * MS_PER_KNOT),
                #[allow(clippy::cast_possible_truncation)]
                seen_ms: now - (t.age_s * 1000.0) as i64,
            });
            // A new report, whether or not the model took it: the map shows it at once.
            if live_clients {
                moved.push(t.clone());
            }
            match written {
                Ok(()) => {
                    mirror.targets.insert(t.mmsi, t.messages);
                }
                Err(e) => {
                    tracing::debug!(mmsi = t.mmsi, error = %e, "AIS target not in the model");
                }
            }
        }
        let mut close = HashSet::with_capacity(approaches.len());
        for a in &approaches {
            let e = Encounter {
                vehicle_id: &a.vehicle_id,
                mmsi: a.mmsi,
                cpa_m: a.cpa_m,
                tcpa_s: a.tcpa_s,
                at_ms: now,
            };
            match semantic.update_encounter(&e) {
                Ok(events) => {
                    close.insert((a.vehicle_id.clone(), a.mmsi));
                    fired.extend(events);
                }
                Err(err) => {
                    tracing::debug!(vehicle = %a.vehicle_id, mmsi = a.mmsi, error = %err, "encounter not in the model");
                }
            }
        }
        // Encounters that opened out, and targets whose reports stopped.
        for (vehicle_id, mmsi) in mirror.encounters.difference(&close) {
            let _ = semantic.end_encounter(vehicle_id, *mmsi);
        }
        mirror.encounters = close;
        let gone: Vec<u32> = mirror
            .targets
            .keys()
            .filter(|m| !present.contains(m))
            .copied()
            .collect();
        for &mmsi in &gone {
            mirror.targets.remove(&mmsi);
            let _ = semantic.forget_traffic_target(mmsi);
        }
        drop(semantic);
        drop(mirror);
        // Live clients get what changed this second; the locks are released first.
        for t in moved {
            self.publish_live(LiveUpdate::Vessel(Box::new(t)));
        }
        for mmsi in gone {
            self.publish_live(LiveUpdate::VesselGone { mmsi });
        }
        if !fired.is_empty() {
            info!(alarms = fired.len(), "collision risk with AIS traffic");
        }
        self.emit_fired(Ok(fired));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{Fixture, announcement, state, valid};
    use shoal_model::{EventKind, Severity};
    use shoal_traffic::{TrafficConfig, TrafficPicture};
    use tokio_util::sync::CancellationToken;

    // Encoded by pyais 3.3.1 (an independent AIS encoder): MMSI 257000001 at 63.4567 N
    // 10.40 E steering 180 at 10 kn, then its static data (name NORNE, ETA 1 June 12:00,
    // in two sentences); MMSI 257000002 at
    // 63.30 N 10.10 E steering 270 at 12 kn.
    const HEAD_ON: &str = "!AIVDM,1,1,,A,13m62@@P1TPgVp0TCna725`1P000,0*40";
    const STATIC_1: &str =
        "!AIVDM,2,1,0,A,53m62@@00000hpu8000pu8pD000000000000001600000000000000000000,0*21";
    const STATIC_2: &str = "!AIVDM,2,2,0,A,00000000000,2*24";
    const FAR_AWAY: &str = "!AIVDM,1,1,,A,13m62@PP1pPf>w0T>7H:S8L1P000,0*5A";

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_vessel_heading_for_a_usv_raises_one_collision_alarm_through_the_rules() {
        let f = Fixture::new();
        let cancel = CancellationToken::new();
        let picture = TrafficPicture::spawn(TrafficConfig::default(), cancel.clone()).unwrap();
        // The first part of the two-sentence message changes nothing yet.
        assert!(!picture.ingest_line(STATIC_1));
        for line in [HEAD_ON, STATIC_2, FAR_AWAY] {
            assert!(picture.ingest_line(line), "{line} refused");
        }
        assert!(f.h.attach_traffic(picture.clone()).is_ok());
        assert!(
            f.h.attach_traffic(picture).is_err(),
            "a second picture is refused"
        );
        // A USV a nautical mile south of the vessel, heading north at 2 m/s, and an AUV
        // at the same place (not a surface vehicle: never checked).
        let mut usv = announcement("usv-1");
        usv.kind = VehicleKind::Usv;
        f.h.ingest_announcement(valid(usv), "w", "p");
        f.announce("auv-1");
        let now = f.h.now();
        for id in ["usv-1", "auv-1"] {
            let mut s = state(id, now, 80.0);
            (s.latitude_deg, s.longitude_deg, s.speed_mps, s.yaw_deg) = (63.44, 10.40, 2.0, 0.0);
            f.h.ingest_state(s).unwrap();
        }
        let mut live = f.h.live();
        f.h.traffic_tick(now);
        // Each vessel with a position goes to live clients once, with its new report.
        let vessels = |live: &mut tokio::sync::broadcast::Receiver<LiveUpdate>| {
            let mut mmsis = Vec::new();
            while let Ok(u) = live.try_recv() {
                if let LiveUpdate::Vessel(t) = u {
                    mmsis.push(t.mmsi);
                }
            }
            mmsis.sort_unstable();
            mmsis
        };
        assert_eq!(vessels(&mut live), [257_000_001, 257_000_002]);
        let alarms: Vec<_> = f
            .out
            .events()
            .into_iter()
            .filter(|e| e.kind == EventKind::Detection)
            .collect();
        assert_eq!(alarms.len(), 1, "{alarms:?}");
        assert_eq!(alarms[0].vehicle_id, "usv-1");
        assert_eq!(alarms[0].severity, Severity::Alarm);
        assert!(alarms[0].text.contains("257000001"), "{}", alarms[0].text);
        // Both vessels are in the model, the far one with no encounter.
        let (targets, encounters) = lock(&f.h.core.semantic).traffic_counts();
        assert_eq!((targets, encounters), (2, 1));
        let named = f
            .h
            .sparql(
                "ASK { ?t a shoal:TrafficTarget ; shoal:vesselName \"NORNE\" ; shoal:mmsi \"257000001\" }",
                &shoal_semantic::QueryLimits::default(),
            )
            .unwrap();
        assert!(matches!(named, shoal_semantic::QueryResult::Boolean(true)));
        // The next second: still the same encounter, no second alarm, and no vessel sent
        // again without a new report.
        f.h.traffic_tick(now + 1000);
        assert!(vessels(&mut live).is_empty());
        let n = f
            .out
            .events()
            .iter()
            .filter(|e| e.kind == EventKind::Detection)
            .count();
        assert_eq!(n, 1);
        cancel.cancel();
    }
}
