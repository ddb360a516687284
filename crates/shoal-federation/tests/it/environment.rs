//! Environment data aggregated: a ship's observations cross as one summary per vehicle,
//! property and window; with the mode off nothing crosses; a site not configured is refused.

use std::time::Duration;

use crate::common::*;
use shoal_federation::config::MIN_ENVIRONMENT_WINDOW_S;
use shoal_federation::{
    EnvironmentAggregates, EnvironmentMode, Federation, PropertyAggregate, RemoteEnvironment, keys,
    wire,
};
use shoal_model::{EnvironmentObservation, now_ms};

const TEMPERATURE: &str = "sea_water_temperature";
const SALINITY: &str = "sea_water_salinity";

/// An observation of `property` by `vehicle`, fixed `ago_ms` before now.
fn observation(vehicle: &str, property: &str, value: f64, ago_ms: i64) -> EnvironmentObservation {
    EnvironmentObservation {
        vehicle_id: vehicle.into(),
        property: property.into(),
        timestamp_ms: now_ms() - ago_ms,
        value,
        unit: if property == SALINITY {
            "[ppth]"
        } else {
            "Cel"
        }
        .into(),
        latitude_deg: 43.1,
        longitude_deg: 5.9,
        depth_m: 10.0,
    }
}

/// The shore's summaries of `vehicle`, by property.
fn summaries(shore: &Federation, vehicle: &str) -> Vec<RemoteEnvironment> {
    shore.picture(|p| {
        p.environment()
            .filter(|e| e.site == "ship" && e.vehicle_id == vehicle)
            .cloned()
            .collect()
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn observations_cross_as_one_summary_per_property_and_window() {
    let port = free_port();
    let mut ship = site("ship", None, &[port], &["shore"]);
    ship.environment.mode = EnvironmentMode::Aggregated;
    // The shortest window production accepts: the test waits for one window at most.
    ship.environment.window_s = MIN_ENVIRONMENT_WINDOW_S;
    ship.environment.properties = vec![TEMPERATURE.into(), SALINITY.into()];
    let shore = Federation::start(site("shore", Some(port), &[], &["ship"]))
        .await
        .unwrap();
    let ship = Federation::start(ship).await.unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    // Pushed within a millisecond or so; should a window end in between (the summaries
    // then split over two windows), the attempt is made again with another vehicle.
    for attempt in 0..3 {
        let vehicle = format!("auv-{attempt}");
        let before = now_ms();
        for (property, value, ago_ms) in [
            (TEMPERATURE, 14.0, 3000),
            // The latest by its own time, though not the last pushed.
            (TEMPERATURE, 12.0, 1000),
            (TEMPERATURE, 13.0, 2000),
            (SALINITY, 38.0, 2000),
            (SALINITY, 38.5, 1500),
            // Not listed: does not cross.
            ("turbidity", 1.0, 1000),
        ] {
            let mut o = observation(&vehicle, property, value, ago_ms);
            if value == 12.0 {
                o.latitude_deg = 43.2;
                o.depth_m = 20.4;
            }
            ship.push_observation(&o).unwrap();
        }
        let after = now_ms();
        eventually("the summaries to reach the shore", || {
            summaries(&shore, &vehicle).len() == 2
        })
        .await;
        let got = summaries(&shore, &vehicle);
        let window = (got[0].window_start_ms, got[0].window_end_ms);
        if !(window.0 <= before && after < window.1) {
            eprintln!("a window ended while pushing ({window:?}, {before}..{after}): again");
            continue;
        }
        // By property name: salinity, then temperature.
        let (s, t) = (&got[0], &got[1]);
        assert_eq!(
            (s.summary.property.as_str(), t.summary.property.as_str()),
            (SALINITY, TEMPERATURE)
        );
        assert_eq!(window.1 - window.0, 5000);
        assert_eq!((t.window_start_ms, t.window_end_ms), window);
        assert_eq!(
            (
                t.summary.count,
                t.summary.min,
                t.summary.max,
                t.summary.mean
            ),
            (3, 12.0, 14.0, 13.0)
        );
        assert_eq!(t.summary.last_value, 12.0);
        assert_eq!(t.summary.unit, "Cel");
        assert!(
            (t.summary.latitude_deg - 43.2).abs() < 1e-7
                && (t.summary.longitude_deg - 5.9).abs() < 1e-7
        );
        assert!((t.summary.depth_m - 20.4).abs() <= 0.1 + 1e-9);
        assert_eq!(
            (
                s.summary.count,
                s.summary.min,
                s.summary.max,
                s.summary.mean
            ),
            (2, 38.0, 38.5, 38.25)
        );
        assert_eq!(
            (s.summary.last_value, s.summary.unit.as_str()),
            (38.5, "[ppth]")
        );
        assert!(s.summary.last_ms < t.summary.last_ms);
        assert!(
            t.received_ms >= window.1 - 1000,
            "sent before its window ended"
        );

        let sent = ship.counters().outbound;
        let received = shore.counters().inbound;
        assert_eq!(sent.environment_observations, 5 * (attempt + 1));
        assert_eq!(sent.environment_not_listed, attempt + 1);
        assert_eq!(sent.environment_dropped, 0);
        // (An earlier attempt's second window may still be on its way.)
        assert!(received.environment >= 2);
        assert!(received.environment <= sent.environment_aggregates_sent);
        assert!(received.refused.is_empty(), "{:?}", received.refused);
        // Nothing crossed back.
        assert_eq!(ship.picture(|p| p.environment().count()), 0);
        ship.shutdown().await.unwrap();
        shore.shutdown().await.unwrap();
        return;
    }
    panic!("a window ended during every attempt");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn with_the_mode_off_no_observation_crosses() {
    let port = free_port();
    let shore = Federation::start(site("shore", Some(port), &[], &["ship"]))
        .await
        .unwrap();
    // The default: off.
    let ship = Federation::start(site("ship", None, &[port], &["shore"]))
        .await
        .unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;
    for i in 0..10 {
        ship.push_observation(&observation("auv-1", TEMPERATURE, f64::from(i), 0))
            .unwrap();
    }
    // Off, it is not even looked at.
    let mut invalid = observation("auv-1", TEMPERATURE, f64::NAN, 0);
    invalid.vehicle_id = "not an id".into();
    assert_eq!(ship.push_observation(&invalid), Ok(()));
    // With no window at all there is nothing to wait for: an alarm sent after the
    // observations is there once anything sent before it would be.
    ship.push_alarm(&alarm("a1")).unwrap();
    eventually("the alarm", || alarm_ids(&shore, "ship").len() == 1).await;
    tokio::time::sleep(Duration::from_millis(200)).await;
    let sent = ship.counters().outbound;
    assert_eq!(
        (
            sent.environment_observations,
            sent.environment_not_listed,
            sent.environment_dropped,
            sent.environment_aggregates_sent,
            sent.environment_frames_sent
        ),
        (0, 0, 0, 0, 0)
    );
    assert_eq!(shore.picture(|p| p.environment().count()), 0);
    assert_eq!(shore.counters().inbound.environment, 0);

    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_site_not_configured_is_refused_and_counted() {
    let port = free_port();
    let shore = Federation::start(site("shore", Some(port), &[], &["ship"]))
        .await
        .unwrap();
    let pirate = raw_peer(port).await;
    let end = now_ms();
    let frame = wire::encode_environment(
        "pirate",
        1,
        1,
        &EnvironmentAggregates {
            vehicle_id: "auv-1".into(),
            window_start_ms: end - 60_000,
            window_end_ms: end,
            properties: vec![PropertyAggregate {
                property: TEMPERATURE.into(),
                unit: "Cel".into(),
                count: 1,
                min: 13.0,
                max: 13.0,
                mean: 13.0,
                last_value: 13.0,
                last_ms: end - 1,
                latitude_deg: 43.1,
                longitude_deg: 5.9,
                depth_m: 10.0,
            }],
        },
    )
    .unwrap();
    let key = keys::environment("pirate", "auv-1");
    // Sent until the shore has seen one: its subscription takes a moment to reach the peer.
    eventually("the pirate's summary to be refused", || {
        if shore.counters().inbound.refused("unknown_site") > 0 {
            return true;
        }
        zenoh::Wait::wait(pirate.put(&key, frame.clone())).unwrap();
        false
    })
    .await;
    assert_eq!(shore.picture(|p| p.environment().count()), 0);
    assert_eq!(shore.counters().inbound.environment, 0);

    pirate.close().await.unwrap();
    shore.shutdown().await.unwrap();
}
