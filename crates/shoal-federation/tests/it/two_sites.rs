//! Two sites on one link: what crosses and how often.

use std::time::{Duration, Instant};

use crate::common::*;
use shoal_federation::{Federation, wire};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn positions_cross_at_the_configured_rate_and_the_latest_value_wins() {
    let port = free_port();
    let mut ship = site("ship", None, &[port], &["shore"]);
    ship.positions.max_rate_hz = 2.0; // one per 500 ms per vehicle
    let shore = Federation::start(site("shore", Some(port), &[], &["ship"]))
        .await
        .unwrap();
    let ship = Federation::start(ship).await.unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    // 40 fixes of one vehicle in about 2 s: far more than 2 Hz lets through.
    let start = Instant::now();
    let pushes = 40;
    for i in 0..pushes {
        ship.push_position(position("auv-1", 43.0 + f64::from(i) * 1e-4))
            .unwrap();
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let last = 43.0 + f64::from(pushes - 1) * 1e-4;
    eventually("the last fix to reach the shore", || {
        shore.picture(|p| {
            p.vehicle("ship", "auv-1")
                .is_some_and(|v| (v.position.latitude_deg - last).abs() < 1e-6)
        })
    })
    .await;
    let elapsed_ms = start.elapsed().as_millis() as u64;

    let sent = ship.counters().outbound;
    let received = shore.counters().inbound;
    // Every fix was either sent or replaced by a newer one before it was sent.
    assert_eq!(
        sent.positions_sent + sent.positions_coalesced,
        pushes as u64
    );
    assert!(sent.positions_coalesced > 0);
    // Never more than one per period (plus the first), whatever the scheduling.
    assert!(
        sent.positions_sent <= elapsed_ms / 500 + 1,
        "{} sent in {elapsed_ms} ms",
        sent.positions_sent
    );
    assert_eq!(received.positions, sent.positions_sent);
    let vehicle = shore
        .picture(|p| p.vehicle("ship", "auv-1").cloned())
        .unwrap();
    assert_eq!(vehicle.site, "ship");
    assert!(vehicle.age_ms(shoal_model::now_ms()) >= 0);

    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_alarm_crosses_once_even_when_replayed() {
    let port = free_port();
    let shore = Federation::start(site("shore", Some(port), &[], &["ship"]))
        .await
        .unwrap();
    let ship = Federation::start(site("ship", None, &[port], &["shore"]))
        .await
        .unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    let a1 = alarm("a1");
    ship.push_alarm(&a1).unwrap();
    eventually("the alarm", || alarm_ids(&shore, "ship").len() == 1).await;

    // Someone on the link replays the very bytes the ship sent.
    let replayer = raw_peer(port).await;
    let replay = wire::encode_alarm("ship", ship.epoch(), 1, &a1).unwrap();
    let before = shore.counters().inbound.duplicates;
    eventually("the replay to be seen", || {
        if shore.counters().inbound.duplicates > before {
            return true;
        }
        zenoh::Wait::wait(replayer.put("shoal/ship/alarms", replay.clone())).unwrap();
        false
    })
    .await;

    // A second alarm after it: once it is there, anything the first could bring twice
    // (the live sample, a catch-up reply, the replay) has arrived too.
    ship.push_alarm(&alarm("a2")).unwrap();
    eventually("the second alarm", || alarm_ids(&shore, "ship").len() >= 2).await;
    assert_eq!(alarm_ids(&shore, "ship"), vec!["a1", "a2"]);
    assert_eq!(alarm_seqs(&shore, "ship"), vec![1, 2]);
    // Nothing crossed back to the ship, and nothing was refused.
    assert!(alarm_ids(&ship, "shore").is_empty());
    assert!(shore.counters().inbound.refused.is_empty());

    replayer.close().await.unwrap();
    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
}
