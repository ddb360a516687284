//! The command lease between real sites: claimed by the home, handed over by the holder,
//! taken over by the standby when the holder's site is lost, and given up by the old
//! holder when the partition heals; a record without authority is refused and counted.
//!
//! Sites are clients of a router (closed to cut the link, opened again on the same port to
//! heal it), as in `outage`.

use std::time::{Duration, Instant};

use shoal_federation::{
    CommandDenied, Federation, FederationConfig, LeaseReason, LeaseRecord, keys, wire,
};

use crate::common::*;

/// A short failover timeout (the least accepted), so the test runs in seconds.
const FAILOVER_MS: u64 = 1_000;

fn leased(mut c: FederationConfig, standby: &str, home: bool) -> FederationConfig {
    c.lease.standby = standby.into();
    c.lease.home = home;
    c.lease.failover_timeout_ms = FAILOVER_MS;
    c.lease.settle_ms = 2_000;
    c
}

fn refused(fed: &Federation, reason: &str) -> u64 {
    fed.counters().inbound.refused(reason)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_home_claims_the_holder_hands_over_and_others_are_refused() {
    logs();
    let port = free_port();
    let _link = router(port).await;
    let ship = Federation::start(leased(client("ship", port, &["shore", "bk"]), "", true))
        .await
        .unwrap();
    let shore = Federation::start(leased(client("shore", port, &["ship", "bk"]), "", true))
        .await
        .unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    // The ship's vehicle: claimed by the ship once settled, learnt by the shore.
    ship.push_position(position("auv-1", 43.1)).unwrap();
    eventually("the shore to learn the ship's lease", || {
        holder(&shore, "auv-1") == Some(("ship".into(), 1))
    })
    .await;
    assert_eq!(ship.may_command("auv-1"), Ok(1));
    assert!(matches!(
        shore.may_command("auv-1"),
        Err(CommandDenied::HeldElsewhere { ref holder, term: 1, .. }) if holder == "ship"
    ));
    // The shore cannot give away what it does not hold.
    assert!(shore.hand_over("auv-1", "shore").is_err());

    let record = ship.hand_over("auv-1", "shore").unwrap();
    assert_eq!((record.term, record.reason), (2, LeaseReason::Handover));
    eventually("the shore to hold the lease", || {
        shore.may_command("auv-1") == Ok(2)
    })
    .await;
    assert!(matches!(
        ship.may_command("auv-1"),
        Err(CommandDenied::HeldElsewhere { ref holder, term: 2, .. }) if holder == "shore"
    ));

    // bk is a configured site, but neither the vehicle's home, its standby nor its holder:
    // its failover claim is refused and counted at both sites, which keep the lease as is.
    let bk = raw_peer(port).await;
    let grab = LeaseRecord {
        vehicle_id: "auv-1".into(),
        term: 9,
        holder: "bk".into(),
        home: "ship".into(),
        standby: String::new(),
        reason: LeaseReason::Failover,
        granted_ms: shoal_model::now_ms(),
    };
    let frame = wire::encode_lease(&grab).unwrap();
    eventually("the forged claim to be refused at both sites", || {
        // Published until both have heard it (the raw peer's routes take a moment).
        let bk = bk.clone();
        let frame = frame.clone();
        tokio::spawn(async move { bk.put(keys::lease("bk", "auv-1"), frame).await });
        refused(&ship, "lease_authority") > 0 && refused(&shore, "lease_authority") > 0
    })
    .await;
    assert_eq!(holder(&ship, "auv-1"), Some(("shore".into(), 2)));
    assert_eq!(holder(&shore, "auv-1"), Some(("shore".into(), 2)));
    // A malformed lease payload is refused and counted too.
    bk.put(keys::lease("bk", "auv-1"), vec![1u8, 4, 9])
        .await
        .unwrap();
    eventually("the malformed record to be refused", || {
        refused(&shore, "malformed:truncated") > 0 || refused(&shore, "malformed:code:reason") > 0
    })
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_standby_takes_over_a_lost_holder_and_the_old_holder_gives_way_when_it_heals() {
    logs();
    let port = free_port();
    let link = router(port).await;
    let ship = Federation::start(leased(client("ship", port, &["backup"]), "backup", true))
        .await
        .unwrap();
    // The standby reaches the ship's vehicles but is not their home: it never claims them.
    let backup = Federation::start(leased(client("backup", port, &["ship"]), "", false))
        .await
        .unwrap();
    eventually("the sites to see each other", || {
        sees(&backup, "ship") && sees(&ship, "backup")
    })
    .await;
    ship.push_position(position("auv-1", 43.1)).unwrap();
    backup.push_position(position("auv-1", 43.1)).unwrap();
    eventually("the backup to learn the ship's lease", || {
        holder(&backup, "auv-1") == Some(("ship".into(), 1))
    })
    .await;
    assert!(matches!(
        backup.may_command("auv-1"),
        Err(CommandDenied::HeldElsewhere { .. })
    ));

    // Partition: each side loses the other.
    link.close().await.unwrap();
    eventually("the backup to see the ship is lost", || {
        lost(&backup, "ship")
    })
    .await;
    let lost_at = Instant::now();
    eventually("the backup to take the lease over", || {
        backup.may_command("auv-1") == Ok(2)
    })
    .await;
    let took = lost_at.elapsed();
    // Never before the timeout (the site might only be slow); the upper bound is measured by
    // `shoal bench federation`, not here.
    assert!(
        took >= Duration::from_millis(FAILOVER_MS - 100),
        "taken over after {took:?}, before lease.failover_timeout_ms"
    );
    // The ship, cut off, still believes it holds the lease: the vehicle settles that.
    assert_eq!(ship.may_command("auv-1"), Ok(1));

    // Heal: a router on the same port; the ship learns the newer lease and gives way.
    let _link = router(port).await;
    eventually("the ship to learn the backup's lease", || {
        holder(&ship, "auv-1") == Some(("backup".into(), 2))
    })
    .await;
    assert!(matches!(
        ship.may_command("auv-1"),
        Err(CommandDenied::HeldElsewhere { ref holder, term: 2, .. }) if holder == "backup"
    ));
    assert_eq!(backup.may_command("auv-1"), Ok(2));
    assert_eq!(backup.lease_counters().failovers, 1);
    assert_eq!(
        ship.lease_counters().failovers,
        0,
        "the ship did not fight back"
    );
}

/// A site that comes up learns every lease a remote site holds, through its lease query,
/// in parts (a fleet's records in one answer would not cross a slow link in time); and
/// reading the picture while the lease state is busy never deadlocks.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_site_that_comes_up_learns_a_whole_fleets_leases_in_parts() {
    logs();
    let port = free_port();
    let _link = router(port).await;
    let ship = Federation::start(leased(client("ship", port, &["shore"]), "", true))
        .await
        .unwrap();
    let fleet: Vec<String> = (0..250).map(|i| format!("auv-{i:03}")).collect();
    for v in &fleet {
        ship.push_position(position(v, 43.1)).unwrap();
    }
    eventually("the ship to claim its fleet", || {
        ship.leases().len() == fleet.len()
    })
    .await;

    // The claims were published before the shore existed: only its query brings them.
    let shore = std::sync::Arc::new(
        Federation::start(leased(client("shore", port, &["ship"]), "", false))
            .await
            .unwrap(),
    );
    // Meanwhile, readers of the picture that ask about leases from inside it, and callers
    // of the lease state, as the station's console and dispatcher do at once.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let (done_tx, done_rx) = std::sync::mpsc::channel();
    let mut threads = Vec::new();
    for reader in [true, false] {
        let (shore, stop, done) = (shore.clone(), stop.clone(), done_tx.clone());
        threads.push(std::thread::spawn(move || {
            let mut n = 0u64;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                if reader {
                    shore.picture(|_| shore.lease_enabled());
                } else {
                    let _ = shore.may_command("auv-007");
                }
                n += 1;
            }
            done.send(n).unwrap();
        }));
    }
    // While the shore's lease query is answered and taken in.
    tokio::time::sleep(Duration::from_secs(2)).await;
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    for _ in 0..2 {
        // Checked before anything else takes a lock: a deadlocked pair would hang it.
        let n = done_rx
            .recv_timeout(Duration::from_secs(10))
            .expect("a reader or a lease caller is stuck: a lock-order deadlock");
        assert!(n > 0);
    }
    for t in threads {
        t.join().unwrap();
    }
    eventually("the shore to learn every lease", || {
        shore.leases().len() == fleet.len()
    })
    .await;
    assert!(
        shore
            .leases()
            .iter()
            .all(|r| r.holder == "ship" && r.term == 1)
    );
}
