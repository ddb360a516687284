//! The receiving core: refusals by reason, duplicates, gaps and catch-up.

use shoal_model::TaskState;

use super::*;
use crate::keys;
use crate::types::tests::position;
use crate::wire::tests::{alarm, transition};

fn shore() -> Inbound {
    let config = FederationConfig {
        site: "shore".into(),
        remote_sites: vec!["ship".into()],
        ..FederationConfig::default()
    };
    Inbound::new(&config)
}

/// A catch-up request to the site "ship".
fn ship_request(stream: Stream, epoch: Option<u64>, after: u64, limit: usize) -> CatchupRequest {
    CatchupRequest {
        site: "ship".into(),
        stream,
        epoch,
        after,
        limit,
    }
}

fn alarm_frame(site: &str, epoch: u64, seq: u64) -> Vec<u8> {
    wire::encode_alarm(site, epoch, seq, &alarm(&format!("e{seq}"))).unwrap()
}

fn end_frame(site: &str, epoch: u64, oldest: u64, highest: u64) -> Vec<u8> {
    wire::encode_catchup_end(&wire::CatchupEnd {
        site: site.into(),
        epoch,
        oldest,
        highest,
    })
    .unwrap()
}

fn seqs(inb: &Inbound) -> Vec<u64> {
    inb.picture().alarms_after(0).map(|a| a.seq).collect()
}

#[test]
fn a_window_delivers_each_number_once_and_reports_gaps() {
    let mut lost = 0;
    let mut w = SeqWindow::new(1);
    assert_eq!(w.admit(1, 1, 8, &mut lost), Admit::New { gap: false });
    assert_eq!(w.admit(1, 3, 8, &mut lost), Admit::New { gap: true });
    assert_eq!(w.admit(1, 3, 8, &mut lost), Admit::Duplicate);
    assert_eq!(w.admit(1, 2, 8, &mut lost), Admit::New { gap: false });
    assert_eq!(w.position(), (1, 3));
    assert_eq!(w.admit(1, 1, 8, &mut lost), Admit::Duplicate);
    // A restarted sender numbers from 1 under a new epoch; the old one is then stale.
    assert_eq!(w.admit(2, 1, 8, &mut lost), Admit::New { gap: false });
    assert_eq!(w.admit(1, 4, 8, &mut lost), Admit::Stale);
    assert_eq!(lost, 0);
}

#[test]
fn a_sender_whose_clock_went_back_across_a_restart_is_heard() {
    let mut lost = 0;
    let mut w = SeqWindow::new(1_000);
    w.admit(1_000, 1, 8, &mut lost);
    // Its new epoch is lower than the old one, but it was never heard: a new run.
    assert_eq!(w.admit(900, 1, 8, &mut lost), Admit::New { gap: false });
    assert_eq!(w.admit(1_000, 2, 8, &mut lost), Admit::Stale);
    // Only a few earlier epochs are remembered.
    for epoch in 1..=5 {
        w.admit(epoch, 1, 8, &mut lost);
    }
    assert_eq!(w.admit(5, 1, 8, &mut lost), Admit::Duplicate);
    assert_eq!(w.admit(4, 1, 8, &mut lost), Admit::Stale);
    assert_eq!(w.admit(900, 1, 8, &mut lost), Admit::New { gap: false });
}

#[test]
fn a_window_past_its_capacity_gives_up_the_oldest_gap() {
    let mut lost = 0;
    let mut w = SeqWindow::new(1);
    for seq in [3, 4, 5] {
        w.admit(1, seq, 2, &mut lost);
    }
    // 1 and 2 were given up to keep at most 2 numbers above the gap.
    assert_eq!(lost, 2);
    assert_eq!(w.position(), (1, 5));
}

#[test]
fn settling_gives_up_only_what_is_missing() {
    let mut lost = 0;
    let mut w = SeqWindow::new(1);
    w.admit(1, 1, 8, &mut lost);
    w.admit(1, 4, 8, &mut lost);
    w.admit(1, 7, 8, &mut lost);
    assert_eq!(w.settle(5), 3); // 2, 3, 5
    assert_eq!(w.position(), (1, 5));
    assert_eq!(w.admit(1, 6, 8, &mut lost), Admit::New { gap: false });
    assert_eq!(w.position(), (1, 7));
}

#[test]
fn an_alarm_crosses_once() {
    let mut inb = shore();
    let key = keys::alarms("ship");
    assert_eq!(inb.receive(&key, &alarm_frame("ship", 1, 1), 0), Ok(None));
    assert_eq!(
        inb.receive(&key, &alarm_frame("ship", 1, 1), 0),
        Err(Refusal::Duplicate)
    );
    assert_eq!(seqs(&inb), vec![1]);
    assert_eq!(inb.counters().duplicates, 1);
}

#[test]
fn bad_input_is_refused_and_counted_by_reason() {
    let mut inb = shore();
    let cases: Vec<(String, Vec<u8>, &str)> = vec![
        (
            keys::alarms("pirate"),
            alarm_frame("pirate", 1, 1),
            "unknown_site",
        ),
        (
            keys::alarms("shore"),
            alarm_frame("shore", 1, 1),
            "own_site",
        ),
        (
            keys::alarms("ship"),
            alarm_frame("ship2", 1, 1),
            "site_mismatch",
        ),
        (keys::alarms("ship"), vec![1, 2, 3], "malformed:truncated"),
        (keys::alarms("ship"), vec![], "malformed:truncated"),
        (keys::alarms("ship"), vec![9; 40], "malformed:version"),
        ("shoal/ship/elsewhere".into(), vec![], "bad_key"),
        (
            keys::position("ship", "auv-1"),
            alarm_frame("ship", 1, 1),
            "malformed:kind",
        ),
    ];
    for (key, payload, reason) in &cases {
        let refusal = inb.receive(key, payload, 0).unwrap_err();
        assert_eq!(refusal.reason(), *reason, "{key}");
    }
    let c = inb.counters();
    assert_eq!(c.refused("unknown_site"), 1);
    assert_eq!(c.refused("malformed:truncated"), 2);
    assert_eq!(c.alarms, 0);
    assert_eq!(inb.picture().alarms_after(0).count(), 0);
}

#[test]
fn positions_fill_the_picture_and_stale_ones_are_refused() {
    let mut inb = shore();
    let key = keys::position("ship", "auv-1");
    let p = position("auv-1");
    inb.receive(&key, &wire::encode_position(&p).unwrap(), 5)
        .unwrap();
    let mut older = p;
    older.timestamp_ms -= 1000;
    let refusal = inb
        .receive(&key, &wire::encode_position(&older).unwrap(), 6)
        .unwrap_err();
    assert_eq!(refusal, Refusal::StalePosition);
    let v = inb.picture().vehicle("ship", "auv-1").unwrap();
    assert_eq!((v.site.as_str(), v.received_ms), ("ship", 5));
}

#[test]
fn a_gap_asks_for_catch_up_which_fills_it_without_duplicates() {
    let mut inb = shore();
    let key = keys::alarms("ship");
    inb.receive(&key, &alarm_frame("ship", 1, 1), 0).unwrap();
    let request = inb
        .receive(&key, &alarm_frame("ship", 1, 4), 0)
        .unwrap()
        .expect("a gap asks for catch-up");
    assert_eq!((request.epoch, request.after), (Some(1), 1));
    // A second gap while the query is under way asks for nothing more.
    assert_eq!(inb.receive(&key, &alarm_frame("ship", 1, 6), 0), Ok(None));
    // The sender answers with everything after 1 it still has: 3..=6 (2 is gone).
    let reply_key = keys::catchup("ship", Stream::Alarms);
    for seq in 3..=6 {
        let r = inb.receive_catchup(&request, &reply_key, &alarm_frame("ship", 1, seq), 0);
        assert_eq!(r.is_ok(), seq == 3 || seq == 5, "{seq}");
    }
    inb.receive_catchup(&request, &reply_key, &end_frame("ship", 1, 3, 6), 0)
        .unwrap();
    assert_eq!(inb.finish_catchup(&request), CatchupOutcome::Done);
    assert_eq!(seqs(&inb), vec![1, 4, 6, 3, 5]);
    assert_eq!(inb.counters().duplicates, 2);
    assert_eq!(inb.counters().lost, 1);
    // Settled: 7 follows without a gap.
    assert_eq!(inb.receive(&key, &alarm_frame("ship", 1, 7), 0), Ok(None));
}

#[test]
fn a_site_coming_up_is_asked_for_what_was_missed_on_each_stream() {
    let mut inb = shore();
    inb.receive(&keys::alarms("ship"), &alarm_frame("ship", 3, 1), 0)
        .unwrap();
    let requests = inb.site_alive(&keys::alive("ship"), true, 10);
    assert_eq!(requests.len(), 2);
    assert_eq!(requests[0], ship_request(Stream::Alarms, Some(3), 1, 100));
    assert_eq!((requests[1].epoch, requests[1].after), (None, 0));
    // Under way: not asked twice.
    assert!(inb.site_alive(&keys::alive("ship"), true, 11).is_empty());
    assert!(inb.site_alive(&keys::alive("pirate"), true, 11).is_empty());
    assert_eq!(inb.counters().refused("unknown_site"), 1);
    let (_, status) = inb.picture().sites().next().unwrap();
    assert!(status.online);
}

#[test]
fn a_catch_up_query_answered_with_too_much_is_cut_at_the_limit() {
    let mut inb = shore();
    inb.limits.catchup_replies = 2;
    let request = inb.site_alive(&keys::alive("ship"), true, 0).remove(0);
    let key = keys::catchup("ship", Stream::Alarms);
    let results: Vec<bool> = (1..=4)
        .map(|seq| {
            inb.receive_catchup(&request, &key, &alarm_frame("ship", 1, seq), 0)
                .is_ok()
        })
        .collect();
    assert_eq!(results, vec![true, true, false, false]);
    assert_eq!(inb.counters().refused("catchup_overflow"), 2);
    // Only what was read is settled; the rest comes with the next part.
    inb.receive_catchup(&request, &key, &end_frame("ship", 1, 1, 4), 0)
        .unwrap();
    let CatchupOutcome::More(next) = inb.finish_catchup(&request) else {
        panic!("the sender has more");
    };
    assert_eq!(next.after, 2);
}

#[test]
fn a_catch_up_reply_for_another_stream_is_refused() {
    let mut inb = shore();
    let request = inb.site_alive(&keys::alive("ship"), true, 0).remove(0);
    let t = wire::encode_task("ship", 1, 1, &transition("t", TaskState::Done)).unwrap();
    let r = inb.receive_catchup(&request, &keys::catchup("ship", Stream::Tasks), &t, 0);
    assert_eq!(r, Err(Refusal::CatchupKey));
}

#[test]
fn a_restarted_sender_is_heard_again_from_one() {
    let mut inb = shore();
    let key = keys::alarms("ship");
    inb.receive(&key, &alarm_frame("ship", 1, 1), 0).unwrap();
    inb.receive(&key, &alarm_frame("ship", 1, 2), 0).unwrap();
    assert_eq!(inb.receive(&key, &alarm_frame("ship", 2, 1), 0), Ok(None));
    assert_eq!(
        inb.receive(&key, &alarm_frame("ship", 1, 3), 0),
        Err(Refusal::StaleEpoch)
    );
}

/// The ship, home of `auv-1`, which it handed over to the shore (term 2).
fn ship_handed_over() -> Inbound {
    let config = FederationConfig {
        site: "ship".into(),
        remote_sites: vec!["shore".into(), "ship-2".into()],
        ..FederationConfig::default()
    };
    let mut inb = Inbound::new(&config);
    let t = 1_700_000_000_000;
    inb.leases_mut().claim("auv-1", t).unwrap();
    inb.leases_mut().hand_over("auv-1", "shore", t).unwrap();
    inb
}

fn order_frame(site: &str, seq: u64, term: u64) -> Vec<u8> {
    let mut t = wire::tests::order_task(term);
    t.lease_holder = site.into();
    wire::encode_order(site, 1, seq, &t).unwrap()
}

#[test]
fn an_order_from_the_holder_is_delivered_once() {
    let mut inb = ship_handed_over();
    let key = keys::order("shore", "ship", "auv-1");
    let mut got = Vec::new();
    let frame = order_frame("shore", 1, 2);
    inb.receive_order(&key, &frame, 0, |o| {
        got.push(o);
        Ok(())
    })
    .unwrap();
    assert_eq!(got.len(), 1);
    assert_eq!(got[0].from_site, "shore");
    assert_eq!(
        (got[0].task.lease_term, got[0].task.lease_holder.as_str()),
        (2, "shore")
    );
    assert_eq!(got[0].task.vehicle_id, "auv-1");
    // The same frame again, and the same task under a new number: dropped and counted.
    for (seq, frame) in [(1, frame), (2, order_frame("shore", 2, 2))] {
        let r = inb.receive_order(&key, &frame, 0, |_| panic!("delivered twice"));
        assert_eq!(r, Err(Refusal::Order(OrderRefusal::Duplicate)), "{seq}");
    }
    let c = inb.counters();
    assert_eq!(
        (c.orders_received, c.orders_accepted, c.order_duplicates),
        (3, 1, 2)
    );
    assert!(c.refused.is_empty(), "{:?}", c.refused);
}

#[test]
fn an_order_the_queue_had_no_room_for_is_taken_when_it_comes_again() {
    let mut inb = ship_handed_over();
    let key = keys::order("shore", "ship", "auv-1");
    let frame = order_frame("shore", 1, 2);
    let r = inb.receive_order(&key, &frame, 0, |_| Err(OrderRefusal::QueueFull));
    assert_eq!(r.unwrap_err().reason(), "order_queue_full");
    assert_eq!(inb.receive_order(&key, &frame, 1, |_| Ok(())), Ok(()));
    assert_eq!(inb.counters().refused("order_queue_full"), 1);
    assert_eq!(inb.counters().orders_accepted, 1);
}

#[test]
fn orders_not_from_the_holder_or_not_for_this_site_are_refused_by_reason() {
    let mut inb = ship_handed_over();
    let forged = order_frame("ship-2", 1, 2);
    let cases: Vec<(String, Vec<u8>, &str)> = vec![
        // ship-2 is configured but does not hold the lease.
        (
            keys::order("ship-2", "ship", "auv-1"),
            forged.clone(),
            "order_not_holder",
        ),
        // The holder, at an older term.
        (
            keys::order("shore", "ship", "auv-1"),
            order_frame("shore", 1, 1),
            "order_term",
        ),
        // The envelope claims the shore, under ship-2's key.
        (
            keys::order("ship-2", "ship", "auv-1"),
            order_frame("shore", 2, 2),
            "order_site_mismatch",
        ),
        // A vehicle whose lease is not known here.
        (
            keys::order("shore", "ship", "auv-9"),
            order_frame("shore", 3, 2),
            "order_no_lease",
        ),
        (
            keys::order("pirate", "ship", "auv-1"),
            order_frame("pirate", 1, 2),
            "unknown_site",
        ),
        (
            keys::order("ship", "ship", "auv-1"),
            order_frame("ship", 1, 2),
            "own_site",
        ),
        (
            keys::order("shore", "ship", "auv-1"),
            vec![1, 5, 1],
            "order_malformed:truncated",
        ),
        (
            keys::order("shore", "ship", "auv-1"),
            alarm_frame("shore", 1, 1),
            "order_malformed:kind",
        ),
        (keys::alarms("shore"), order_frame("shore", 4, 2), "bad_key"),
    ];
    for (key, payload, reason) in &cases {
        let r = inb.receive_order(key, payload, 0, |_| panic!("{key} delivered"));
        assert_eq!(r.unwrap_err().reason(), *reason, "{key}");
        assert_eq!(inb.counters().refused(reason), 1, "{key}");
    }
    // Sent again and again: counted each time (a refused order is not remembered).
    for _ in 0..3 {
        let r = inb.receive_order(&keys::order("ship-2", "ship", "auv-1"), &forged, 0, |_| {
            Ok(())
        });
        assert!(r.is_err());
    }
    assert_eq!(inb.counters().refused("order_not_holder"), 4);
    assert_eq!(inb.counters().orders_accepted, 0);
    // An order key is not picture data: `receive` refuses it, as it does a catch-up reply.
    assert_eq!(
        inb.receive(
            &keys::order("shore", "ship", "auv-1"),
            &order_frame("shore", 5, 2),
            0
        ),
        Err(Refusal::BadKey)
    );
}

#[test]
fn an_order_for_another_sites_vehicle_or_with_the_lease_off_is_refused() {
    // ship-2 learnt the lease but is not auv-1's home.
    let config = FederationConfig {
        site: "ship-2".into(),
        remote_sites: vec!["shore".into(), "ship".into()],
        ..FederationConfig::default()
    };
    let mut third = Inbound::new(&config);
    let mut ship = ship_handed_over();
    for r in ship.leases().leases().cloned().collect::<Vec<_>>() {
        third.leases_mut().apply("ship", r).ok();
    }
    let key = keys::order("shore", "ship", "auv-1");
    // Addressed to the ship, it is not for ship-2 (which does not subscribe to it anyway).
    let r = third.receive_order(&key, &order_frame("shore", 1, 2), 0, |_| Ok(()));
    assert_eq!(r.unwrap_err(), Refusal::BadKey);
    // Addressed to ship-2, which is not the vehicle's home.
    let to_third = keys::order("shore", "ship-2", "auv-1");
    let r = third.receive_order(&to_third, &order_frame("shore", 1, 2), 0, |_| Ok(()));
    assert_eq!(r.unwrap_err().reason(), "order_not_ours");
    // The lease off at the home: nothing to check an order against.
    ship.lease_enabled = false;
    let r = ship.receive_order(&key, &order_frame("shore", 1, 2), 0, |_| Ok(()));
    assert_eq!(r.unwrap_err().reason(), "order_lease_off");
}

fn environment_frame(site: &str, seq: u64, vehicle: &str, properties: &[&str]) -> Vec<u8> {
    let a = crate::environment::tests::aggregates(vehicle, properties);
    wire::encode_environment(site, 1, seq, &a).unwrap()
}

#[test]
fn environment_summaries_fill_the_picture_and_bad_frames_are_refused_by_reason() {
    let mut inb = shore();
    let key = keys::environment("ship", "auv-1");
    let frame = environment_frame("ship", 1, "auv-1", &["s", "t"]);
    assert_eq!(inb.receive(&key, &frame, 10), Ok(None));
    assert_eq!(inb.counters().environment, 2);
    let got: Vec<(String, String, String)> = inb
        .picture()
        .environment()
        .map(|e| {
            (
                e.site.clone(),
                e.vehicle_id.clone(),
                e.summary.property.clone(),
            )
        })
        .collect();
    assert_eq!(
        got,
        [
            ("ship".into(), "auv-1".into(), "s".into()),
            ("ship".into(), "auv-1".into(), "t".into())
        ]
    );
    // The same frame again: each summary a duplicate, nothing refused.
    assert_eq!(inb.receive(&key, &frame, 11), Ok(None));
    assert_eq!(inb.counters().duplicates, 2);
    assert!(inb.counters().refused.is_empty());

    let cases: Vec<(String, Vec<u8>, &str)> = vec![
        (
            keys::environment("pirate", "auv-1"),
            environment_frame("pirate", 1, "auv-1", &["t"]),
            "unknown_site",
        ),
        (
            keys::environment("shore", "auv-1"),
            environment_frame("shore", 1, "auv-1", &["t"]),
            "own_site",
        ),
        (
            keys::environment("ship", "auv-1"),
            environment_frame("ship2", 1, "auv-1", &["t"]),
            "site_mismatch",
        ),
        (
            key.clone(),
            frame[..frame.len() - 1].to_vec(),
            "malformed:truncated",
        ),
        (key.clone(), alarm_frame("ship", 1, 1), "malformed:kind"),
    ];
    for (key, payload, reason) in &cases {
        let refusal = inb.receive(key, payload, 0).unwrap_err();
        assert_eq!(refusal.reason(), *reason, "{key}");
        assert_eq!(inb.counters().refused(reason), 1, "{reason}");
    }
    // Never in a catch-up reply.
    let request = ship_request(Stream::Alarms, None, 0, 10);
    assert_eq!(
        inb.receive_catchup(&request, &key, &frame, 0),
        Err(Refusal::CatchupKey)
    );
    assert_eq!(inb.counters().environment, 2);
}

#[test]
fn environment_summaries_past_the_limit_or_stale_are_refused_each() {
    let config = FederationConfig {
        site: "shore".into(),
        remote_sites: vec!["ship".into()],
        limits: Limits {
            remote_environment: 2,
            ..Limits::default()
        },
        ..FederationConfig::default()
    };
    let mut inb = Inbound::new(&config);
    let key = keys::environment("ship", "auv-1");
    inb.receive(
        &key,
        &environment_frame("ship", 1, "auv-1", &["a", "b", "c"]),
        0,
    )
    .unwrap();
    assert_eq!(inb.counters().environment, 2);
    assert_eq!(inb.counters().refused("too_many_environment"), 1);
    // A later window of a held property replaces it even when the picture is full.
    let mut later = crate::environment::tests::aggregates("auv-1", &["a"]);
    later.window_start_ms += 60_000;
    later.window_end_ms += 60_000;
    let later = wire::encode_environment("ship", 1, 2, &later).unwrap();
    inb.receive(&key, &later, 1).unwrap();
    assert_eq!(inb.counters().environment, 3);
    // The earlier window of `a`, arriving late: stale.
    inb.receive(&key, &environment_frame("ship", 3, "auv-1", &["a"]), 2)
        .unwrap();
    assert_eq!(inb.counters().refused("stale_environment"), 1);
    assert_eq!(inb.picture().environment().count(), 2);
}

/// End-to-end signatures, with certificates issued as `shoal keys site-cert` issues them.
#[cfg(feature = "transport")]
mod signatures {
    use super::*;
    use crate::config::TlsConfig;
    use crate::lease::LeaseRecord;
    use crate::site_keys::{SiteCertificates, SiteSigner};
    use crate::tls::tests::site_files;

    const T: i64 = 1_700_000_000_000;

    fn chain(tls: &TlsConfig) -> Vec<u8> {
        let pem = std::fs::read(&tls.certificate).unwrap();
        SiteSigner::load(tls).unwrap();
        let ders: Vec<Vec<u8>> = {
            use rustls::pki_types::CertificateDer;
            use rustls::pki_types::pem::PemObject;
            CertificateDer::pem_slice_iter(&pem)
                .map(|c| c.unwrap().to_vec())
                .collect()
        };
        signed::encode_identity(&ders)
    }

    /// The ship's claim of `vehicle`, encoded and (with `signer`) signed.
    fn claim(vehicle: &str, signer: Option<&SiteSigner>) -> (String, Vec<u8>) {
        let record = LeaseRecord {
            vehicle_id: vehicle.into(),
            term: 1,
            holder: "ship".into(),
            home: "ship".into(),
            standby: String::new(),
            reason: crate::lease::LeaseReason::Claim,
            granted_ms: T,
        };
        let key = keys::lease("ship", vehicle);
        let mut frame = wire::encode_lease(&record).unwrap();
        if let Some(s) = signer {
            s.seal(&key, &mut frame).unwrap();
        }
        (key, frame)
    }

    fn holder(inb: &Inbound, vehicle: &str) -> Option<String> {
        inb.leases().lease(vehicle).map(|r| r.holder.clone())
    }

    #[test]
    fn a_signed_record_waits_for_its_signers_certificate_and_a_forged_one_is_refused() {
        let (_dir, ship_tls) = site_files("ship");
        let (_other, impostor_tls) = site_files("ship");
        let ship = SiteSigner::load(&ship_tls).unwrap();
        let impostor = SiteSigner::load(&impostor_tls).unwrap();
        let mut inb = shore();
        inb.require_signatures(Box::new(SiteCertificates::load(&ship_tls).unwrap()));
        let now = shoal_model::now_ms();

        let (key, unsigned) = claim("auv-1", None);
        assert_eq!(
            inb.receive(&key, &unsigned, now),
            Err(Refusal::Signature(SignatureError::Unsigned))
        );
        // Signed, the ship's certificate not known yet: held, and asked for once.
        let (k1, f1) = claim("auv-1", Some(&ship));
        let (k2, f2) = claim("auv-2", Some(&ship));
        assert!(matches!(
            inb.receive(&k1, &f1, now),
            Err(Refusal::AwaitingIdentity { ask: true, .. })
        ));
        assert!(matches!(
            inb.receive(&k2, &f2, now),
            Err(Refusal::AwaitingIdentity { ask: false, .. })
        ));
        assert_eq!((inb.awaiting_identity(), holder(&inb, "auv-1")), (2, None));

        // An identity from another CA under the ship's name is refused; the samples wait.
        let r = inb.identity("ship", &chain(&impostor_tls), now);
        assert_eq!(r.unwrap_err().reason(), "signature:identity");
        assert_eq!(inb.awaiting_identity(), 2);
        assert!(inb.identity("ship", b"junk", now).is_err());

        // The genuine one: the held samples come back, in order, and are taken.
        let held = inb.identity("ship", &chain(&ship_tls), now).unwrap();
        assert_eq!(held, vec![(k1, f1), (k2, f2)]);
        for (k, f) in held {
            assert_eq!(inb.receive(&k, &f, now), Ok(None));
        }
        assert_eq!(holder(&inb, "auv-2").as_deref(), Some("ship"));

        // Signed with another key of the same name, or moved to another vehicle's key.
        let (k3, forged) = claim("auv-3", Some(&impostor));
        assert_eq!(
            inb.receive(&k3, &forged, now),
            Err(Refusal::Signature(SignatureError::Bad))
        );
        let (_, genuine) = claim("auv-4", Some(&ship));
        assert_eq!(
            inb.receive(&keys::lease("ship", "auv-5"), &genuine, now),
            Err(Refusal::Signature(SignatureError::Bad))
        );
        assert_eq!((holder(&inb, "auv-3"), holder(&inb, "auv-5")), (None, None));

        let c = inb.counters();
        assert_eq!(c.held_for_identity, 2);
        assert_eq!(c.identities, 1);
        assert_eq!(c.refused("signature:unsigned"), 1);
        assert_eq!(c.refused("signature:bad"), 2);
        assert_eq!(c.refused("signature:identity"), 1);
        assert_eq!(c.refused("malformed:version"), 1);

        // The site's session came up again: its certificate is asked for anew.
        inb.site_alive(&keys::alive("ship"), true, now);
        let (k6, f6) = claim("auv-6", Some(&ship));
        assert!(matches!(
            inb.receive(&k6, &f6, now),
            Err(Refusal::AwaitingIdentity { ask: false, .. })
        ));
    }

    #[test]
    fn orders_are_signed_by_the_holder_or_refused() {
        let (_dir, shore_tls) = site_files("shore");
        let shore = SiteSigner::load(&shore_tls).unwrap();
        let mut inb = ship_handed_over();
        inb.require_signatures(Box::new(SiteCertificates::load(&shore_tls).unwrap()));
        let now = shoal_model::now_ms();
        inb.identity("shore", &chain(&shore_tls), now).unwrap();
        let key = keys::order("shore", "ship", "auv-1");
        let r = inb.receive_order(&key, &order_frame("shore", 1, 2), now, |_| {
            panic!("an unsigned order was delivered")
        });
        assert_eq!(r.unwrap_err().reason(), "signature:unsigned");
        let mut frame = order_frame("shore", 1, 2);
        shore.seal(&key, &mut frame).unwrap();
        let mut got = Vec::new();
        inb.receive_order(&key, &frame, now, |o| {
            got.push(o);
            Ok(())
        })
        .unwrap();
        assert_eq!(got.len(), 1);
        // A tampered byte (the task's depth).
        let mut tampered = order_frame("shore", 2, 2);
        shore.seal(&key, &mut tampered).unwrap();
        tampered[40] ^= 0x10;
        let r = inb.receive_order(&key, &tampered, now, |_| panic!("delivered"));
        assert_eq!(r.unwrap_err().reason(), "signature:bad");
    }

    #[test]
    fn without_tls_a_signed_frame_is_read_as_unsigned() {
        let (_dir, ship_tls) = site_files("ship");
        let ship = SiteSigner::load(&ship_tls).unwrap();
        let mut inb = shore();
        let (key, frame) = claim("auv-1", Some(&ship));
        assert_eq!(inb.receive(&key, &frame, 0), Ok(None));
        assert_eq!(holder(&inb, "auv-1").as_deref(), Some("ship"));
    }
}

#[test]
fn an_answer_without_its_end_gives_nothing_up_and_is_asked_again() {
    let mut inb = shore();
    let key = keys::alarms("ship");
    inb.site_alive(&keys::alive("ship"), true, 0);
    // The queries asked at reconnection were not heard by any queryable.
    for stream in Stream::ALL {
        let request = ship_request(stream, None, 0, 100);
        assert_eq!(inb.finish_catchup(&request), CatchupOutcome::Retry);
    }
    inb.receive(&key, &alarm_frame("ship", 1, 1), 0).unwrap();
    let request = inb
        .receive(&key, &alarm_frame("ship", 1, 5), 0)
        .unwrap()
        .expect("a gap asks");
    // The wait ran out after 2 and 4 came: 3 may still come, nothing is given up.
    let reply = keys::catchup("ship", Stream::Alarms);
    for seq in [2, 4] {
        inb.receive_catchup(&request, &reply, &alarm_frame("ship", 1, seq), 0)
            .unwrap();
    }
    assert_eq!(inb.finish_catchup(&request), CatchupOutcome::Retry);
    assert_eq!(inb.counters().lost, 0);
    let again = inb.retry_catchup("ship", Stream::Alarms).expect("online");
    assert_eq!(again.after, 2);
    // Once the site is gone, it is asked again when it comes back, not before.
    inb.abandon_catchup(&again);
    inb.site_alive(&keys::alive("ship"), false, 1);
    assert_eq!(inb.retry_catchup("ship", Stream::Alarms), None);
}

#[test]
fn a_part_cut_short_is_followed_at_once_and_an_empty_one_after_a_while() {
    let mut inb = shore();
    let request = inb.site_alive(&keys::alive("ship"), true, 0).remove(0);
    let reply = keys::catchup("ship", Stream::Alarms);
    // The sender had 10 but time for 3 only.
    for seq in 1..=3 {
        inb.receive_catchup(&request, &reply, &alarm_frame("ship", 7, seq), 0)
            .unwrap();
    }
    inb.receive_catchup(&request, &reply, &end_frame("ship", 7, 1, 10), 0)
        .unwrap();
    let CatchupOutcome::More(next) = inb.finish_catchup(&request) else {
        panic!("7 more to ask for");
    };
    assert_eq!((next.epoch, next.after), (Some(7), 3));
    // No time for any: asked again after a while, not at once.
    inb.receive_catchup(&next, &reply, &end_frame("ship", 7, 1, 10), 0)
        .unwrap();
    assert_eq!(inb.finish_catchup(&next), CatchupOutcome::Retry);
    let last = inb.retry_catchup("ship", Stream::Alarms).unwrap();
    for seq in 4..=10 {
        inb.receive_catchup(&last, &reply, &alarm_frame("ship", 7, seq), 0)
            .unwrap();
    }
    inb.receive_catchup(&last, &reply, &end_frame("ship", 7, 1, 10), 0)
        .unwrap();
    assert_eq!(inb.finish_catchup(&last), CatchupOutcome::Done);
    assert_eq!(seqs(&inb), (1..=10).collect::<Vec<_>>());
    assert_eq!(inb.counters().lost, 0);
}

#[test]
fn what_the_sender_no_longer_keeps_is_given_up_and_counted_once() {
    let mut inb = shore();
    let key = keys::alarms("ship");
    inb.receive(&key, &alarm_frame("ship", 1, 1), 0).unwrap();
    inb.site_alive(&keys::alive("ship"), true, 0);
    let request = inb.retry_catchup("ship", Stream::Alarms);
    assert_eq!(request, None, "one under way already");
    let request = ship_request(Stream::Alarms, Some(1), 1, 100);
    // The sender keeps 6..=8 only.
    let reply = keys::catchup("ship", Stream::Alarms);
    for seq in 6..=8 {
        inb.receive_catchup(&request, &reply, &alarm_frame("ship", 1, seq), 0)
            .unwrap();
    }
    inb.receive_catchup(&request, &reply, &end_frame("ship", 1, 6, 8), 0)
        .unwrap();
    assert_eq!(inb.finish_catchup(&request), CatchupOutcome::Done);
    assert_eq!(inb.counters().lost, 4);
    // A stream the sender keeps nothing of (alarms not `reliable`) is done at once.
    let tasks = CatchupRequest {
        stream: Stream::Tasks,
        ..request
    };
    inb.receive_catchup(
        &tasks,
        &keys::catchup("ship", Stream::Tasks),
        &end_frame("ship", 1, 31, 30),
        0,
    )
    .unwrap();
    assert_eq!(inb.finish_catchup(&tasks), CatchupOutcome::Done);
}

#[test]
fn every_online_site_is_polled_on_each_stream_unless_a_query_is_under_way() {
    let mut inb = shore();
    assert!(inb.poll_catchup().is_empty(), "no site online yet");
    let asked = inb.site_alive(&keys::alive("ship"), true, 0);
    assert!(inb.poll_catchup().is_empty(), "both under way");
    for request in &asked {
        inb.receive_catchup(
            request,
            &keys::catchup("ship", request.stream),
            &end_frame("ship", 1, 1, 0),
            0,
        )
        .unwrap();
        assert_eq!(inb.finish_catchup(request), CatchupOutcome::Done);
    }
    let polled = inb.poll_catchup();
    assert_eq!(
        polled.iter().map(|r| r.stream).collect::<Vec<_>>(),
        Stream::ALL.to_vec()
    );
    for request in &polled {
        inb.abandon_catchup(request);
    }
    inb.site_alive(&keys::alive("ship"), false, 1);
    assert!(inb.poll_catchup().is_empty(), "the site is offline");
}

#[test]
fn an_end_frame_for_another_site_or_stream_or_malformed_is_refused() {
    let mut inb = shore();
    let request = inb.site_alive(&keys::alive("ship"), true, 0).remove(0);
    let alarms = keys::catchup("ship", Stream::Alarms);
    let cases = [
        (
            keys::catchup("ship", Stream::Tasks),
            end_frame("ship", 1, 1, 5),
            "catchup_key",
        ),
        (alarms.clone(), end_frame("other", 1, 1, 5), "site_mismatch"),
        (
            alarms,
            end_frame("ship", 1, 1, 5)[..20].to_vec(),
            "malformed:truncated",
        ),
    ];
    for (key, frame, reason) in cases {
        assert!(inb.receive_catchup(&request, &key, &frame, 0).is_err());
        assert_eq!(inb.counters().refused(reason), 1, "{reason}");
    }
    // None of them ended the answer.
    assert_eq!(inb.finish_catchup(&request), CatchupOutcome::Retry);
}
