//! The link goes down while both sites keep working, then comes back: each side catches
//! up on exactly what it missed, once.
//!
//! The two sites are clients of a router (as a ship and a shore linked through a
//! `zenohd`); closing the router's session cuts the link, and a new router on the same
//! port restores it. The sites' own sessions stay up throughout and reconnect by
//! themselves.

use shoal_federation::keys::Stream;
use shoal_federation::{Federation, keys, wire};
use shoal_model::TaskState;

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_an_outage_each_side_catches_up_on_exactly_what_it_missed() {
    logs();
    let port = free_port();
    let link = router(port).await;
    let ship = Federation::start(client("ship", port, &["shore"]))
        .await
        .unwrap();
    let shore = Federation::start(client("shore", port, &["ship"]))
        .await
        .unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    // Before the outage.
    ship.push_alarm(&alarm("a1")).unwrap();
    ship.push_transition(&transition("t1", TaskState::Running))
        .unwrap();
    shore.push_alarm(&alarm("s1")).unwrap();
    eventually("the first items", || {
        alarm_ids(&shore, "ship") == ["a1"]
            && transitions(&shore, "ship").len() == 1
            && alarm_ids(&ship, "shore") == ["s1"]
    })
    .await;

    // The link goes down: each site sees the other's session go.
    link.close().await.unwrap();
    eventually("the sites to see the link is down", || {
        lost(&shore, "ship") && lost(&ship, "shore")
    })
    .await;

    // Both keep working alone.
    for id in ["a2", "a3", "a4"] {
        ship.push_alarm(&alarm(id)).unwrap();
    }
    ship.push_transition(&transition("t1", TaskState::Done))
        .unwrap();
    ship.push_transition(&transition("t2", TaskState::Running))
        .unwrap();
    shore.push_alarm(&alarm("s2")).unwrap();
    assert_eq!(
        alarm_ids(&shore, "ship"),
        ["a1"],
        "nothing crosses a cut link"
    );

    // The link comes back.
    let link = router(port).await;
    eventually("each side to catch up", || {
        alarm_ids(&shore, "ship").len() >= 4
            && transitions(&shore, "ship").len() >= 3
            && alarm_ids(&ship, "shore").len() >= 2
    })
    .await;
    // A last item on each side after the catch-up, so that anything arriving twice would
    // have arrived by the time it does.
    ship.push_alarm(&alarm("a5")).unwrap();
    shore.push_alarm(&alarm("s3")).unwrap();
    eventually("the items after the outage", || {
        alarm_ids(&shore, "ship").len() >= 5 && alarm_ids(&ship, "shore").len() >= 3
    })
    .await;

    assert_eq!(alarm_ids(&shore, "ship"), ["a1", "a2", "a3", "a4", "a5"]);
    assert_eq!(alarm_seqs(&shore, "ship"), [1, 2, 3, 4, 5]);
    assert_eq!(
        transitions(&shore, "ship"),
        [
            ("t1".to_string(), TaskState::Running),
            ("t1".to_string(), TaskState::Done),
            ("t2".to_string(), TaskState::Running),
        ]
    );
    assert_eq!(alarm_ids(&ship, "shore"), ["s1", "s2", "s3"]);
    for fed in [&ship, &shore] {
        let c = fed.counters().inbound;
        assert_eq!(c.lost, 0, "{}: nothing given up", fed.site());
        assert!(c.refused.is_empty(), "{}: {:?}", fed.site(), c.refused);
        assert!(
            c.catchup_queries >= 2,
            "{}: asked after reconnecting",
            fed.site()
        );
    }

    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
    link.close().await.unwrap();
}

/// What was missed comes in parts of `limits.catchup_batch` frames, each query asking for
/// the next part as soon as the last was full, so a long catch-up never has to cross a
/// slow link in one answer (the WAN bench's loop: one answer too big for the timeout,
/// asked again and again).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_long_catch_up_comes_in_parts_of_the_batch_size() {
    logs();
    let port = free_port();
    let link = router(port).await;
    let ship = Federation::start(client("ship", port, &["shore"]))
        .await
        .unwrap();
    let mut config = client("shore", port, &["ship"]);
    config.limits.catchup_batch = 10;
    let shore = Federation::start(config).await.unwrap();
    eventually("the sites to see each other", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;
    ship.push_alarm(&alarm("a0")).unwrap();
    eventually("the first alarm", || alarm_ids(&shore, "ship") == ["a0"]).await;
    let queries_before = shore.counters().inbound.catchup_queries;

    link.close().await.unwrap();
    eventually("the link to be down", || lost(&shore, "ship")).await;
    for i in 1..=35 {
        ship.push_alarm(&alarm(&format!("a{i}"))).unwrap();
    }
    let link = router(port).await;
    eventually("the whole catch-up", || {
        alarm_ids(&shore, "ship").len() >= 36
    })
    .await;

    let seqs = alarm_seqs(&shore, "ship");
    assert_eq!(seqs, (1..=36).collect::<Vec<u64>>());
    let c = shore.counters().inbound;
    assert_eq!(c.lost, 0);
    // 35 alarms in parts of 10: four parts (10, 10, 10, 5), and the tasks stream's one.
    let asked = c.catchup_queries - queries_before;
    assert!(asked >= 5, "{asked} catch-up queries");
    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
    link.close().await.unwrap();
}

/// A catch-up query that runs out of time is asked again: over a congested link its
/// answer may miss the timeout, and nothing else would ask for a gap that no later frame
/// reveals (the WAN bench's missing task transitions). The "ship" is a bare Zenoh peer
/// that holds the first query unanswered and answers the next.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_catch_up_that_runs_out_of_time_is_asked_again() {
    logs();
    let port = free_port();
    let mut config = site("shore", Some(port), &[], &["ship"]);
    config.limits.catchup_timeout_ms = 500;
    let shore = Federation::start(config).await.unwrap();
    let ship = raw_peer(port).await;
    let queryable = ship
        .declare_queryable(keys::catchup("ship", Stream::Alarms))
        .await
        .unwrap();
    let answering = tokio::spawn(async move {
        let mut held = Vec::new();
        let mut asked = 0u32;
        while let Ok(query) = queryable.recv_async().await {
            asked += 1;
            if asked == 1 {
                // Never answered in time: kept (not dropped, which would end it at once).
                held.push(query);
                continue;
            }
            for seq in 1..=3 {
                let frame = wire::encode_alarm("ship", 7, seq, &alarm(&format!("a{seq}"))).unwrap();
                query.reply(query.key_expr().clone(), frame).await.unwrap();
            }
            let end = wire::CatchupEnd {
                site: "ship".into(),
                epoch: 7,
                oldest: 1,
                highest: 3,
            };
            let end = wire::encode_catchup_end(&end).unwrap();
            query.reply(query.key_expr().clone(), end).await.unwrap();
            return asked;
        }
        asked
    });
    let _alive = ship
        .liveliness()
        .declare_token(keys::alive("ship"))
        .await
        .unwrap();
    eventually("the alarms, on the second query", || {
        alarm_ids(&shore, "ship") == ["a1", "a2", "a3"]
    })
    .await;
    assert_eq!(answering.await.unwrap(), 2);
    assert_eq!(shore.counters().inbound.lost, 0);
    shore.shutdown().await.unwrap();
}

/// A sender pacing its answers on a slow link cuts each one where its next frame would
/// leave after half its asker's wait, and ends it with how far its stream goes: the asker
/// asks for the rest, part by part, and gets every alarm once, none given up. Before,
/// a paced answer shared with other askers outlived the wait and was thrown away whole,
/// over and over (the WAN bench's lost transitions).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_paced_answer_is_cut_to_its_askers_wait_and_the_rest_follows() {
    logs();
    let port = free_port();
    let mut config = site("ship", Some(port), &[], &["shore"]);
    // 8 kbit/s: answers leave at 250 B/s, two alarms a second.
    config.link_rate_kbps = 8;
    let ship = Federation::start(config).await.unwrap();
    for i in 1..=16 {
        ship.push_alarm(&alarm(&format!("a{i}"))).unwrap();
    }
    let mut config = site("shore", None, &[port], &["ship"]);
    // Half of it, one second, for each answer to leave in.
    config.limits.catchup_timeout_ms = 2000;
    let shore = Federation::start(config).await.unwrap();
    eventually("the whole catch-up", || {
        alarm_ids(&shore, "ship").len() >= 16
    })
    .await;
    assert_eq!(alarm_seqs(&shore, "ship"), (1..=16).collect::<Vec<u64>>());
    let (sent, got) = (ship.counters().outbound, shore.counters().inbound);
    assert!(sent.catchup_cut >= 2, "answers cut: {}", sent.catchup_cut);
    assert_eq!(sent.catchup_served, 16, "each alarm sent once");
    assert_eq!((got.lost, got.duplicates), (0, 0));
    assert!(got.catchup_queries >= 3, "{} queries", got.catchup_queries);
    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
}
