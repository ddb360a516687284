//! Fuzzes the federation's WAN decoders and its receiving core: arbitrary bytes under any
//! federation key must never panic, whatever decodes must re-encode to the same bytes,
//! signature blocks and identity frames must open or be refused without panicking, and
//! the receiving core must refuse or take every sample without panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_federation::config::FederationConfig;
use shoal_federation::inbound::{CatchupRequest, Inbound};
use shoal_federation::keys::{self, Stream};
use shoal_federation::{signed, wire};

fuzz_target!(|data: &[u8]| {
    if let Ok(p) = wire::decode_position("auv-1", data) {
        let again = wire::encode_position(&p).expect("a decoded position re-encodes");
        assert_eq!(again, data, "position re-encoding differs");
    }
    if let Ok(a) = wire::decode_alarm(data) {
        let again = wire::encode_alarm(&a.site, a.epoch, a.seq, &a.item).expect("re-encodes");
        assert_eq!(again, data, "alarm re-encoding differs");
    }
    if let Ok(t) = wire::decode_task(data) {
        let again = wire::encode_task(&t.site, t.epoch, t.seq, &t.item).expect("re-encodes");
        assert_eq!(again, data, "task re-encoding differs");
    }
    if let Ok(r) = wire::decode_lease("auv-1", data) {
        let again = wire::encode_lease(&r).expect("a decoded lease re-encodes");
        assert_eq!(again, data, "lease re-encoding differs");
    }
    if let Ok(o) = wire::decode_order("auv-1", data) {
        assert_eq!(
            o.item.lease_holder, o.site,
            "the holder is the envelope's site"
        );
        let again = wire::encode_order(&o.site, o.epoch, o.seq, &o.item).expect("re-encodes");
        assert_eq!(again, data, "order re-encoding differs");
    }
    if let Ok(e) = wire::decode_environment("auv-1", data) {
        let again =
            wire::encode_environment(&e.site, e.epoch, e.seq, &e.item).expect("re-encodes");
        assert_eq!(again, data, "environment re-encoding differs");
    }
    if let Ok(end) = wire::decode_catchup_end(data) {
        let again = wire::encode_catchup_end(&end).expect("a decoded end re-encodes");
        assert_eq!(again, data, "catch-up end re-encoding differs");
    }
    // End-to-end signature blocks and identity frames (the certificates themselves are
    // parsed by WebPKI, fuzzed upstream).
    if let Ok(Some(o)) = signed::open("shoal/ship/leases/auv-1", data) {
        assert_eq!(o.frame.len() + o.signature.len() + 4, data.len());
        assert_eq!(o.frame[1] & signed::SIGNED, 0, "the opened frame reads as unsigned");
    }
    if let Ok(chain) = signed::decode_identity(data) {
        assert!((1..=signed::MAX_CHAIN).contains(&chain.len()));
    }

    // The first byte picks the key, the rest is the payload; the same bytes also arrive
    // as a catch-up reply.
    let Some((&pick, payload)) = data.split_first() else {
        return;
    };
    let site = if pick & 0x80 == 0 { "ship" } else { "pirate" };
    let key = match pick % 9 {
        0 => keys::position(site, "auv-1"),
        1 => keys::alarms(site),
        2 => keys::task(site, "t-1"),
        3 => keys::catchup(site, Stream::Alarms),
        4 => keys::alive(site),
        5 => keys::lease(site, "auv-1"),
        6 => keys::order(site, "shore", "auv-1"),
        7 => keys::environment(site, "auv-1"),
        _ => String::from_utf8_lossy(payload).into_owned(),
    };
    let config = FederationConfig {
        site: "shore".into(),
        remote_sites: vec!["ship".into()],
        ..FederationConfig::default()
    };
    let mut inbound = Inbound::new(&config);
    let _ = inbound.receive(&key, payload, 0);
    let _ = inbound.receive(&key, payload, 1);
    let request = CatchupRequest {
        site: "ship".into(),
        stream: Stream::Alarms,
        epoch: None,
        after: 0,
        limit: 100,
    };
    let _ = inbound.site_alive(&keys::alive("ship"), true, 2);
    let _ = inbound.receive_catchup(&request, &key, payload, 3);
    let _ = inbound.finish_catchup(&request);
    assert!(inbound.counters().alarms <= 2);
    // One frame carries 32 summaries at most; the second time they are duplicates.
    assert!(inbound.counters().environment <= 32);

    // Orders, at the home of `auv-1` whose lease it handed to `ship` (term 2): one may be
    // delivered, never twice (the same bytes come again as a resend).
    let mut home = Inbound::new(&config);
    let t = 1_800_000_000_000;
    let _ = home.leases_mut().claim("auv-1", t);
    let _ = home.leases_mut().hand_over("auv-1", "ship", t);
    for now in [4, 5] {
        let _ = home.receive_order(&key, payload, now, |o| {
            assert_eq!(o.from_site, "ship", "only the holder's order is delivered");
            assert_eq!(
                (o.task.lease_term, o.task.vehicle_id.as_str()),
                (2, "auv-1")
            );
            Ok(())
        });
    }
    assert!(home.counters().orders_accepted <= 1);
});
