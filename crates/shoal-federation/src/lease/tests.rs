use super::*;

const T: i64 = 1_800_000_000_000;

fn sites(names: &[&str]) -> Vec<String> {
    names.iter().map(|s| (*s).to_string()).collect()
}

/// Ship (home, standby `backup`), backup, and shore.
fn three() -> (LeaseTable, LeaseTable, LeaseTable) {
    (
        LeaseTable::new("ship", "backup", &sites(&["backup", "shore"]), 100),
        LeaseTable::new("backup", "", &sites(&["ship", "shore"]), 100),
        LeaseTable::new("shore", "", &sites(&["ship", "backup"]), 100),
    )
}

fn holder(t: &LeaseTable, v: &str) -> (String, u64) {
    let r = t.lease(v).expect("a lease");
    (r.holder.clone(), r.term)
}

#[test]
fn the_home_claims_a_vehicle_once_at_term_one_and_other_sites_take_the_claim() {
    let (mut ship, mut backup, _) = three();
    let claim = ship.claim("auv-1", T).expect("first claim");
    assert_eq!((claim.term, claim.holder.as_str()), (1, "ship"));
    assert_eq!(claim.standby, "backup");
    assert!(ship.holds("auv-1"));
    assert_eq!(
        ship.claim("auv-1", T + 1),
        None,
        "a vehicle is claimed once"
    );

    assert_eq!(backup.apply("ship", claim.clone()), Ok(Applied::Changed));
    assert!(!backup.holds("auv-1"));
    assert_eq!(holder(&backup, "auv-1"), ("ship".into(), 1));
    assert_eq!(backup.apply("ship", claim), Ok(Applied::Stale));
    assert_eq!(backup.counters().stale, 1);
}

#[test]
fn a_claim_for_another_site_or_a_second_claim_is_refused() {
    let (mut ship, mut backup, mut shore) = three();
    let mut forged = ship.claim("auv-1", T).unwrap();
    // shore publishes a claim naming ship as home: not shore's to make.
    let refused = shore.apply("backup", forged.clone());
    assert!(matches!(refused, Err(LeaseRefusal::NoAuthority { .. })));
    // A home that forgot its claim claims again with a higher term: refused where the
    // first is known.
    backup.apply("ship", forged.clone()).unwrap();
    forged.term = 5;
    let again = backup.apply("ship", forged);
    assert_eq!(again.unwrap_err().reason(), "lease_authority");
    assert_eq!(holder(&backup, "auv-1"), ("ship".into(), 1));
}

#[test]
fn only_the_holder_hands_over_and_every_site_follows() {
    let (mut ship, mut backup, mut shore) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    backup.apply("ship", claim.clone()).unwrap();
    shore.apply("ship", claim).unwrap();

    let refused = shore.hand_over("auv-1", "shore", T);
    assert!(
        matches!(refused, Err(HandoverError::NotHolder { ref holder, .. }) if holder == "ship")
    );
    assert!(matches!(
        ship.hand_over("auv-1", "nowhere", T),
        Err(HandoverError::UnknownSite(_))
    ));
    assert!(matches!(
        ship.hand_over("auv-9", "shore", T),
        Err(HandoverError::Unknown(_))
    ));

    let handover = ship.hand_over("auv-1", "shore", T + 10).unwrap();
    assert_eq!((handover.term, handover.reason), (2, LeaseReason::Handover));
    assert!(!ship.holds("auv-1"));
    shore.apply("ship", handover.clone()).unwrap();
    backup.apply("ship", handover).unwrap();
    assert!(shore.holds("auv-1"));
    assert_eq!(holder(&backup, "auv-1"), ("shore".into(), 2));

    // backup, not the holder, tries to hand it to itself.
    let mut grab = shore.lease("auv-1").unwrap().clone();
    grab.term = 3;
    grab.holder = "backup".into();
    grab.reason = LeaseReason::Handover;
    let refused = ship.apply("backup", grab);
    assert_eq!(refused.unwrap_err().reason(), "lease_authority");
    assert_eq!(holder(&ship, "auv-1"), ("shore".into(), 2));
}

#[test]
fn the_standby_fails_over_after_the_timeout_and_a_third_site_cannot() {
    let (mut ship, mut backup, mut shore) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    backup.apply("ship", claim.clone()).unwrap();
    shore.apply("ship", claim).unwrap();

    let ship_lost_at = T + 1_000;
    let offline = |s: &str| (s == "ship").then_some(ship_lost_at);
    assert!(
        backup
            .fail_over(offline, 30_000, ship_lost_at + 29_999)
            .is_empty()
    );
    // shore is neither home nor standby: it never takes over.
    assert!(
        shore
            .fail_over(offline, 30_000, ship_lost_at + 60_000)
            .is_empty()
    );
    let taken = backup.fail_over(offline, 30_000, ship_lost_at + 30_000);
    assert_eq!(taken.len(), 1);
    assert_eq!(
        (taken[0].term, taken[0].holder.as_str(), taken[0].reason),
        (2, "backup", LeaseReason::Failover)
    );
    assert!(backup.holds("auv-1"));
    assert_eq!(backup.counters().failovers, 1);
    assert!(
        backup
            .fail_over(offline, 30_000, ship_lost_at + 90_000)
            .is_empty(),
        "a lease is taken once"
    );
    assert_eq!(
        shore.apply("backup", taken[0].clone()),
        Ok(Applied::Changed)
    );

    // shore claims a failover for itself: refused everywhere.
    let mut grab = taken[0].clone();
    grab.term = 3;
    grab.holder = "shore".into();
    assert_eq!(
        backup.apply("shore", grab.clone()).unwrap_err().reason(),
        "lease_authority"
    );
    assert_eq!(
        ship.apply("shore", grab).unwrap_err().reason(),
        "lease_authority"
    );
}

#[test]
fn after_a_partition_heals_every_site_agrees_on_the_holder() {
    let (mut ship, mut backup, mut shore) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    backup.apply("ship", claim.clone()).unwrap();
    shore.apply("ship", claim).unwrap();

    // Partition: {ship} | {backup, shore}. backup takes over; ship still holds term 1.
    let failover = backup
        .fail_over(|s| (s == "ship").then_some(T), 30_000, T + 30_000)
        .remove(0);
    shore.apply("backup", failover).unwrap();
    assert!(ship.holds("auv-1") && backup.holds("auv-1"));

    // Heal: ship answers with its records (term 1, stale everywhere), backup with its own.
    for record in ship.granted_here().cloned().collect::<Vec<_>>() {
        assert_eq!(backup.apply("ship", record.clone()), Ok(Applied::Stale));
        assert_eq!(shore.apply("ship", record), Ok(Applied::Stale));
    }
    for record in backup.granted_here().cloned().collect::<Vec<_>>() {
        assert_eq!(ship.apply("backup", record), Ok(Applied::Changed));
    }
    for t in [&ship, &backup, &shore] {
        assert_eq!(holder(t, "auv-1"), ("backup".into(), 2));
    }
    assert!(!ship.holds("auv-1"));
}

#[test]
fn two_changes_to_one_term_in_a_partition_resolve_to_the_same_holder_in_any_order() {
    // ship hands to shore while backup, cut off from ship, fails over: both are term 2.
    let (mut ship, mut backup, _) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    backup.apply("ship", claim.clone()).unwrap();
    let to_shore = ship.hand_over("auv-1", "shore", T + 5).unwrap();
    let failover = backup
        .fail_over(|s| (s == "ship").then_some(T), 30_000, T + 30_000)
        .remove(0);
    assert_eq!(to_shore.term, failover.term);

    let records = [("ship", to_shore), ("backup", failover)];
    for order in [[0, 1], [1, 0]] {
        let (_, _, mut observer) = three();
        observer.apply("ship", claim.clone()).unwrap();
        for i in order {
            let (grantor, record) = records[i].clone();
            observer.apply(grantor, record).unwrap();
        }
        // "backup" sorts before "shore": the same winner whichever came first.
        assert_eq!(
            holder(&observer, "auv-1"),
            ("backup".into(), 2),
            "order {order:?}"
        );
    }
}

#[test]
fn a_record_refused_for_want_of_an_earlier_one_is_taken_when_that_arrives() {
    // backup misses ship's handover to shore, then hears shore's handover to backup.
    let (mut ship, mut backup, mut shore) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    backup.apply("ship", claim.clone()).unwrap();
    shore.apply("ship", claim).unwrap();
    let to_shore = ship.hand_over("auv-1", "shore", T + 1).unwrap();
    shore.apply("ship", to_shore.clone()).unwrap();
    let to_backup = shore.hand_over("auv-1", "backup", T + 2).unwrap();

    assert_eq!(
        backup.apply("shore", to_backup).unwrap_err().reason(),
        "lease_authority"
    );
    assert_eq!(holder(&backup, "auv-1"), ("ship".into(), 1));
    assert_eq!(backup.apply("ship", to_shore), Ok(Applied::Changed));
    assert_eq!(holder(&backup, "auv-1"), ("backup".into(), 3));
    assert!(backup.holds("auv-1"));
    assert_eq!(backup.counters().taken_later, 1);
}

#[test]
fn a_record_naming_another_home_is_refused_and_the_table_is_bounded() {
    let (mut ship, mut backup, _) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    backup.apply("ship", claim.clone()).unwrap();
    let mut rehomed = ship.hand_over("auv-1", "shore", T).unwrap();
    rehomed.home = "shore".into();
    assert_eq!(
        backup.apply("ship", rehomed).unwrap_err().reason(),
        "lease_home"
    );

    let mut small = LeaseTable::new("shore", "", &sites(&["ship"]), 1);
    small.apply("ship", claim.clone()).unwrap();
    let mut other = claim;
    other.vehicle_id = "auv-2".into();
    assert_eq!(small.apply("ship", other).unwrap_err(), LeaseRefusal::Full);
    assert_eq!(small.claim("auv-3", T), None, "full for own claims too");
}

#[test]
fn a_restarted_site_remembers_the_leases_it_had_learnt() {
    let (mut ship, _, mut shore) = three();
    let claim = ship.claim("auv-1", T).unwrap();
    shore.apply("ship", claim).unwrap();
    let to_shore = ship.hand_over("auv-1", "shore", T + 1).unwrap();
    shore.apply("ship", to_shore).unwrap();
    let saved = serde_json::to_string(&ship.snapshot()).unwrap();

    // ship restarts: without its records it would claim term 1 again and never accept
    // shore's next handover (shore would not be the holder it knows).
    let (mut restarted, _, _) = three();
    assert_eq!(restarted.restore(serde_json::from_str(&saved).unwrap()), 1);
    assert_eq!(restarted.claim("auv-1", T + 2), None);
    let to_ship = shore.hand_over("auv-1", "ship", T + 3).unwrap();
    assert_eq!(restarted.apply("shore", to_ship), Ok(Applied::Changed));
    assert!(restarted.holds("auv-1"));

    // A saved record that does not check is skipped.
    let mut bad = restarted.snapshot();
    bad[0].record.term = 0;
    let (mut again, _, _) = three();
    assert_eq!(again.restore(bad), 0);
}

#[test]
fn refused_records_for_unknown_vehicles_are_not_kept() {
    let (_, _, mut shore) = three();
    for n in 0..1000 {
        let forged = LeaseRecord {
            vehicle_id: format!("ghost-{n}"),
            term: 1,
            holder: "ship".into(),
            home: "ship".into(),
            standby: String::new(),
            reason: LeaseReason::Claim,
            granted_ms: T,
        };
        // backup claims ship's vehicles: no authority, and nothing is remembered of it.
        assert_eq!(
            shore.apply("backup", forged).unwrap_err().reason(),
            "lease_authority"
        );
    }
    assert!(shore.aside.is_empty());
    assert_eq!(shore.leases().count(), 0);
}
