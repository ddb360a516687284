//! Orders: the shore, holding the lease of the ship's vehicle after a handover, sends a
//! task to the ship (the vehicle's home), which delivers it to its station with the
//! shore's lease; an order without the lease, for a site's own vehicle, under a stale
//! term or with a forged envelope is refused and counted, and never delivered; a queue
//! the station does not read holds a bounded number.
//!
//! Sites are clients of a router, as in `lease`.

use shoal_federation::{Federation, FederationConfig, OrderError, keys, wire};
use shoal_model::{GeoPoint, Task, TaskAssignment};
use tokio::sync::mpsc::error::TryRecvError;

use crate::common::*;

fn leased(mut c: FederationConfig) -> FederationConfig {
    c.lease.settle_ms = 2_000;
    c
}

/// A goto for `vehicle` under the lease (`term`, `holder`).
fn goto(task: &str, vehicle: &str, term: u64, holder: &str) -> TaskAssignment {
    let mut t = TaskAssignment::new(
        task,
        "m-1",
        vehicle,
        shoal_model::now_ms(),
        &Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: 43.123_456_789,
                longitude_deg: 5.987_654_321,
            },
            depth_m: Some(15.0),
            altitude_m: None,
            speed_mps: 1.2,
        },
    );
    t.lease_term = term;
    t.lease_holder = holder.into();
    t
}

fn refused(fed: &Federation, reason: &str) -> u64 {
    fed.counters().inbound.refused(reason)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_holder_commands_another_sites_vehicle_through_its_home_and_forgeries_are_refused() {
    logs();
    let port = free_port();
    let _link = router(port).await;
    let ship = Federation::start(leased(client("ship", port, &["shore"])))
        .await
        .unwrap();
    let shore = Federation::start(leased(client("shore", port, &["ship"])))
        .await
        .unwrap();
    let mut orders = ship
        .take_orders()
        .expect("the first call gets the receiver");
    assert!(ship.take_orders().is_none());
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    // The ship's vehicle, claimed by the ship.
    ship.push_position(position("auv-1", 43.1)).unwrap();
    eventually("the shore to learn the ship's lease", || {
        shore
            .leases()
            .iter()
            .any(|r| r.vehicle_id == "auv-1" && r.holder == "ship")
    })
    .await;
    assert_eq!(ship.may_command("auv-1"), Ok(1));

    // Not the shore's to command yet; and the ship commands its own vehicle directly.
    assert!(matches!(
        shore.relay_order(&goto("t-0", "auv-1", 1, "shore")),
        Err(OrderError::NotHolder { ref holder, term: 1, .. }) if holder == "ship"
    ));
    assert_eq!(
        ship.relay_order(&goto("t-0", "auv-1", 1, "ship")),
        Err(OrderError::OwnVehicle("auv-1".into()))
    );

    ship.hand_over("auv-1", "shore").unwrap();
    eventually("the shore to hold the lease", || {
        shore.may_command("auv-1") == Ok(2)
    })
    .await;
    // A vehicle whose lease the shore does not know, and a task under an older term.
    assert_eq!(
        shore.relay_order(&goto("t-0", "auv-9", 2, "shore")),
        Err(OrderError::NoLease("auv-9".into()))
    );
    assert!(matches!(
        shore.relay_order(&goto("t-0", "auv-1", 1, "shore")),
        Err(OrderError::WrongLease {
            term: 2,
            task_term: 1,
            ..
        })
    ));
    assert_eq!(shore.counters().outbound.orders_sent, 0);

    let task = goto("t-1", "auv-1", 2, "shore");
    shore.relay_order(&task).unwrap();
    let order = tokio::time::timeout(PATIENCE, orders.recv())
        .await
        .expect("the order within the patience")
        .expect("an order");
    assert_eq!(order.from_site, "shore");
    // The task as sent, lease intact, exact to the bit.
    assert_eq!(order.task, task);
    assert_eq!(shore.counters().outbound.orders_sent, 1);
    assert_eq!(ship.counters().inbound.orders_accepted, 1);

    // Sent again: dropped at the ship.
    shore.relay_order(&task).unwrap();
    eventually("the resend to be dropped", || {
        ship.counters().inbound.order_duplicates == 1
    })
    .await;

    // A raw peer publishes under the shore's key what the shore would not: an order under
    // the lease's older term, and one whose envelope claims another site.
    let peer = raw_peer(port).await;
    let stale = wire::encode_order("shore", 1, 1, &goto("t-2", "auv-1", 1, "shore")).unwrap();
    let claimed = wire::encode_order("bk", 1, 1, &goto("t-3", "auv-1", 2, "bk")).unwrap();
    eventually("the forged orders to be refused at the ship", || {
        // Published until heard (the raw peer's routes take a moment).
        for frame in [stale.clone(), claimed.clone()] {
            let peer = peer.clone();
            tokio::spawn(
                async move { peer.put(keys::order("shore", "ship", "auv-1"), frame).await },
            );
        }
        refused(&ship, "order_term") > 0 && refused(&ship, "order_site_mismatch") > 0
    })
    .await;
    assert_eq!(orders.try_recv().unwrap_err(), TryRecvError::Empty);
    let c = ship.counters().inbound;
    assert_eq!((c.orders_accepted, c.order_duplicates), (1, 1));
    assert!(c.orders_received >= 4, "{c:?}");

    // A station that does not read its orders (or never took the receiver) holds at most
    // 256: the rest are refused and counted.
    for i in 0..260 {
        shore
            .relay_order(&goto(&format!("t-q{i}"), "auv-1", 2, "shore"))
            .unwrap();
    }
    eventually("the ship to refuse what its queue has no room for", || {
        refused(&ship, "order_queue_full") == 4
    })
    .await;
    assert_eq!(ship.counters().inbound.orders_accepted, 1 + 256);
    assert_eq!(shore.counters().outbound.orders_sent, 2 + 260);
    let mut queued = 0;
    while orders.try_recv().is_ok() {
        queued += 1;
    }
    assert_eq!(queued, 256);
}
