//! A shore and two ships, and what no configured site would send.

use shoal_federation::{Federation, wire};
use shoal_model::TaskState;

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shore_sees_two_ships_and_refuses_an_unknown_site() {
    let port = free_port();
    let shore = Federation::start(site("shore", Some(port), &[], &["ship1", "ship2"]))
        .await
        .unwrap();
    let ship1 = Federation::start(site("ship1", None, &[port], &["shore"]))
        .await
        .unwrap();
    let ship2 = Federation::start(site("ship2", None, &[port], &["shore"]))
        .await
        .unwrap();
    // A site the shore was not told of, properly configured on its own side.
    let pirate = Federation::start(site("pirate", None, &[port], &["shore"]))
        .await
        .unwrap();
    eventually("the shore to see both ships", || {
        sees(&shore, "ship1") && sees(&shore, "ship2")
    })
    .await;

    ship1.push_position(position("auv-1", 43.1)).unwrap();
    ship2.push_position(position("auv-1", 44.2)).unwrap();
    ship2
        .push_transition(&transition("t9", TaskState::Accepted))
        .unwrap();
    pirate.push_position(position("auv-666", 45.0)).unwrap();
    pirate.push_alarm(&alarm("boo")).unwrap();
    eventually("both ships' data and the pirate's refusals", || {
        let c = shore.counters().inbound;
        c.positions == 2 && c.transitions == 1 && c.refused("unknown_site") >= 2
    })
    .await;

    // The same vehicle id at two sites is two vehicles, each with its site.
    let vehicles = shore.picture(|p| {
        p.vehicles()
            .map(|v| (v.site.clone(), v.position.vehicle_id.clone()))
            .collect::<Vec<_>>()
    });
    assert_eq!(
        vehicles,
        [
            ("ship1".to_string(), "auv-1".to_string()),
            ("ship2".to_string(), "auv-1".to_string())
        ]
    );
    let lat2 = shore.picture(|p| p.vehicle("ship2", "auv-1").unwrap().position.latitude_deg);
    assert!((lat2 - 44.2).abs() < 1e-6);
    assert!(alarm_ids(&shore, "pirate").is_empty());
    assert!(shore.picture(|p| p.sites().all(|(s, _)| s != "pirate")));

    for fed in [pirate, ship2, ship1, shore] {
        fed.shutdown().await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_forged_site_and_malformed_payloads_are_refused_and_counted() {
    let port = free_port();
    let shore = Federation::start(site("shore", Some(port), &[], &["ship1", "ship2"]))
        .await
        .unwrap();
    let raw = raw_peer(port).await;
    // Subscriptions reach the raw peer asynchronously; resend until counted.
    let alarm_from_ship2 = wire::encode_alarm("ship2", 1, 1, &alarm("x")).unwrap();
    let sends: [(&str, Vec<u8>, &str); 4] = [
        // ship1's key, ship2's frame: someone speaks for another site.
        ("shoal/ship1/alarms", alarm_from_ship2, "site_mismatch"),
        ("shoal/ship1/alarms", vec![1, 2], "malformed:truncated"),
        ("shoal/ship1/tasks/t1", vec![7; 30], "malformed:version"),
        (
            "shoal/ship1/vehicles/auv-1/position",
            vec![
                1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
            ],
            "malformed:range:timestamp_ms",
        ),
    ];
    eventually("every bad sample refused under its reason", || {
        let c = shore.counters().inbound;
        if sends.iter().all(|(_, _, reason)| c.refused(reason) >= 1) {
            return true;
        }
        for (key, payload, _) in &sends {
            zenoh::Wait::wait(raw.put(*key, payload.clone())).unwrap();
        }
        false
    })
    .await;
    let c = shore.counters().inbound;
    assert_eq!((c.alarms, c.transitions, c.positions), (0, 0, 0));
    assert!(alarm_ids(&shore, "ship1").is_empty());

    raw.close().await.unwrap();
    shore.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_shore_router_relays_between_two_ship_clients() {
    let port = free_port();
    let mut shore = site("shore", Some(port), &[], &["ship1", "ship2"]);
    shore.mode = shoal_federation::config::Mode::Router;
    let shore = Federation::start(shore).await.unwrap();
    let ship1 = Federation::start(client("ship1", port, &["shore", "ship2"]))
        .await
        .unwrap();
    let ship2 = Federation::start(client("ship2", port, &["shore", "ship1"]))
        .await
        .unwrap();
    eventually("the ships to see each other through the shore", || {
        sees(&ship1, "ship2") && sees(&ship2, "ship1") && sees(&shore, "ship1")
    })
    .await;

    ship1.push_alarm(&alarm("from-ship1")).unwrap();
    shore
        .push_transition(&transition("t-shore", TaskState::Sent))
        .unwrap();
    eventually(
        "ship1's alarm at ship2 and the shore, the shore's task at both ships",
        || {
            alarm_ids(&ship2, "ship1") == ["from-ship1"]
                && alarm_ids(&shore, "ship1") == ["from-ship1"]
                && transitions(&ship1, "shore").len() == 1
                && transitions(&ship2, "shore").len() == 1
        },
    )
    .await;

    for fed in [ship2, ship1, shore] {
        fed.shutdown().await.unwrap();
    }
}
