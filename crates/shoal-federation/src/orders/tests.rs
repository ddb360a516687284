//! The checks on both sides, duplicate suppression and the warning gate.

use super::*;
use crate::lease::LeaseReason;
use crate::wire::tests::order_task;

/// The ship's `auv-1`, handed over to the shore at term 2.
fn handed_over() -> LeaseRecord {
    LeaseRecord {
        vehicle_id: "auv-1".into(),
        term: 2,
        holder: "shore".into(),
        home: "ship".into(),
        standby: String::new(),
        reason: LeaseReason::Handover,
        granted_ms: 1_700_000_000_000,
    }
}

#[test]
fn only_the_holder_of_another_sites_vehicle_sends_an_order_under_its_lease() {
    let lease = handed_over();
    let task = order_task(2);
    assert_eq!(check_relay("shore", true, Some(&lease), &task), Ok(2));
    assert_eq!(
        check_relay("shore", false, Some(&lease), &task),
        Err(OrderError::LeaseOff)
    );
    assert_eq!(
        check_relay("shore", true, None, &task),
        Err(OrderError::NoLease("auv-1".into()))
    );
    // The ship, which gave the lease away, may not.
    assert!(matches!(
        check_relay("ship", true, Some(&lease), &task),
        Err(OrderError::NotHolder { ref holder, term: 2, .. }) if holder == "shore"
    ));
    // The ship holding its own vehicle commands it over DDS, not by order.
    let own = LeaseRecord {
        holder: "ship".into(),
        term: 1,
        ..lease.clone()
    };
    let mut t = order_task(1);
    t.lease_holder = "ship".into();
    assert_eq!(
        check_relay("ship", true, Some(&own), &t),
        Err(OrderError::OwnVehicle("auv-1".into()))
    );
    // A task under an older term, or another holder, is not the lease held.
    for (term, holder) in [(1, "shore"), (3, "shore"), (2, "ship")] {
        let mut t = order_task(term);
        t.lease_holder = holder.into();
        assert!(
            matches!(
                check_relay("shore", true, Some(&lease), &t),
                Err(OrderError::WrongLease { term: 2, .. })
            ),
            "{term} {holder}"
        );
    }
}

#[test]
fn the_home_takes_an_order_only_from_the_holder_at_its_term() {
    let lease = handed_over();
    let task = order_task(2);
    fn check(
        site: &str,
        enabled: bool,
        lease: Option<&LeaseRecord>,
        from: &str,
        task: &TaskAssignment,
    ) -> Result<(), String> {
        check_received(site, enabled, lease, from, task).map_err(|r| r.reason())
    }
    assert_eq!(check("ship", true, Some(&lease), "shore", &task), Ok(()));
    assert_eq!(
        check("ship", false, Some(&lease), "shore", &task),
        Err("order_lease_off".into())
    );
    assert_eq!(
        check("ship", true, None, "shore", &task),
        Err("order_no_lease".into())
    );
    // A third site: the vehicle is not its own.
    assert_eq!(
        check("ship-2", true, Some(&lease), "shore", &task),
        Err("order_not_ours".into())
    );
    assert_eq!(
        check("ship", true, Some(&lease), "ship-2", &task),
        Err("order_not_holder".into())
    );
    // The holder at an older (or a newer) term than the lease known here.
    for term in [1, 3] {
        let task = order_task(term);
        assert_eq!(
            check("ship", true, Some(&lease), "shore", &task),
            Err("order_term".into())
        );
    }
}

#[test]
fn an_order_is_delivered_once_even_when_it_is_sent_again() {
    let mut ledger = OrderLedger::default();
    let task = order_task(2);
    let admitted = ledger.admit("shore", 7, 1, &task, 8).unwrap();
    // Not recorded until delivered: a queue that was full takes it when it comes again.
    assert!(ledger.admit("shore", 7, 1, &task, 8).is_ok());
    ledger.delivered(admitted);
    assert_eq!(
        ledger.admit("shore", 7, 1, &task, 8).unwrap_err(),
        OrderRefusal::Duplicate
    );
    // The same task sent again under a new number.
    assert_eq!(
        ledger.admit("shore", 7, 2, &task, 8).unwrap_err(),
        OrderRefusal::Duplicate
    );
    // Another task, or the same one under a new lease, is new.
    let mut other = order_task(2);
    other.task_id = "t-10".into();
    let a = ledger.admit("shore", 7, 2, &other, 8).unwrap();
    ledger.delivered(a);
    assert!(ledger.admit("shore", 7, 3, &order_task(3), 8).is_ok());
    // A frame of a restarted sender's earlier run.
    let a = ledger.admit("shore", 8, 1, &order_task(3), 8).unwrap();
    ledger.delivered(a);
    let mut late = order_task(2);
    late.task_id = "t-11".into();
    assert_eq!(
        ledger.admit("shore", 7, 9, &late, 8).unwrap_err(),
        OrderRefusal::StaleEpoch
    );
}

#[test]
fn the_tasks_remembered_are_bounded() {
    let mut ledger = OrderLedger::default();
    for seq in 1..=(TASKS_REMEMBERED as u64 + 10) {
        let mut t = order_task(2);
        t.task_id = format!("t-{seq}");
        let a = ledger.admit("shore", 1, seq, &t, 8).unwrap();
        ledger.delivered(a);
    }
    assert_eq!(ledger.tasks.len(), TASKS_REMEMBERED);
    assert_eq!(ledger.order.len(), TASKS_REMEMBERED);
}

#[test]
fn a_burst_of_one_reason_is_warned_once_then_counted() {
    let mut gate = WarnGate::default();
    assert_eq!(gate.admit("order_term", 0), Some(0));
    assert_eq!(gate.admit("order_term", 10), None);
    assert_eq!(gate.admit("order_term", WARN_QUIET_MS - 1), None);
    // Another reason has its own burst.
    assert_eq!(gate.admit("order_not_holder", 20), Some(0));
    assert_eq!(gate.admit("order_term", WARN_QUIET_MS), Some(2));
    assert_eq!(gate.admit("order_term", WARN_QUIET_MS + 1), None);
}
