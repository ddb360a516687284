//! Security on the Publish/Subscribe Manager over real RTPS on loopback: a station and
//! vehicles with certificates from one key store exchange signed samples; unsigned,
//! impersonating, unauthorised and revoked senders are refused, counted by reason, and
//! never delivered. Domains 44–46; run inside the test network namespace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::time::Duration;

use futures::StreamExt;
use shoal_dds::{Priority, PubSub, ReadError, Security, WriterOptions};
use shoal_model::{StateVector, Task, TaskAssignment};
use shoal_security::{Gate, KeyStore, Policy, RejectionReason, RevokeReason, VerifierConfig};

mod common;
use common::{Foreign, config};

fn state(id: &str) -> StateVector {
    common::state_at(id, shoal_model::now_ms())
}

fn station_security(store: &KeyStore) -> Security {
    let gate = Gate::new(
        store.verifier(VerifierConfig::default()).unwrap(),
        Policy::builtin(),
    );
    Security::new(store.station_identity().unwrap(), gate)
}

fn vehicle_security(store: &KeyStore, id: &str) -> Security {
    let gate = Gate::new(
        store.verifier(VerifierConfig::default()).unwrap(),
        Policy::builtin(),
    );
    Security::new(store.vehicle_identity(id).unwrap(), gate)
}

/// Writes `sample` every 100 ms until `stream` yields an item or 15 s pass.
async fn send_until<T, S>(w: &shoal_dds::Writer<T>, sample: T, stream: &mut S) -> S::Item
where
    T: shoal_dds::TopicType,
    S: futures::Stream + Unpin,
{
    for _ in 0..150 {
        w.write(sample.clone()).await.unwrap();
        if let Ok(Some(item)) =
            tokio::time::timeout(Duration::from_millis(100), stream.next()).await
        {
            return item;
        }
    }
    panic!("nothing arrived on {} within 15 s", T::TOPIC);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn signed_samples_flow_both_ways_and_unsigned_or_forged_ones_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut store = KeyStore::init(&dir.path().join("keys"), "ccs").unwrap();
    for id in ["auv-1", "auv-2"] {
        store.issue_vehicle(id).unwrap();
    }
    let station = PubSub::new_secure(&config(44), station_security(&store)).unwrap();
    let mut states = station.subscribe::<StateVector>().unwrap();

    // A vehicle with a certificate: its own state arrives, verified.
    let auv1 = PubSub::new_secure(&config(44), vehicle_security(&store, "auv-1")).unwrap();
    let w1 = auv1
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let (got, _) = send_until(&w1, state("auv-1"), &mut states).await.unwrap();
    assert_eq!(got.vehicle_id, "auv-1");

    // The station's task reaches the vehicle, verified against the station certificate.
    let mut tasks = auv1.subscribe::<TaskAssignment>().unwrap();
    let tw = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let task = TaskAssignment::new("t1", "m1", "auv-1", shoal_model::now_ms(), &Task::Surface);
    let (got, _) = send_until(&tw, task.clone(), &mut tasks).await.unwrap();
    assert_eq!(*got, task);

    // Drain what the retries above left behind.
    while let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(300), states.next()).await {}

    // auv-1 speaking for auv-2: a valid signature, refused by the policy.
    let err = send_until(&w1, state("auv-2"), &mut states)
        .await
        .unwrap_err();
    assert!(
        matches!(
            err,
            ReadError::Refused {
                reason: "wrong_instance",
                ..
            }
        ),
        "{err}"
    );

    // A vehicle assigning a task: refused (only the station assigns tasks).
    let mut station_tasks = station.subscribe::<TaskAssignment>().unwrap();
    let vt = auv1
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let forged = TaskAssignment::new("t2", "m1", "auv-1", shoal_model::now_ms(), &Task::Surface);
    let mut refused = None;
    for _ in 0..100 {
        // The station's own task t1 may come back first (it reads its own topic).
        match send_until(&vt, forged.clone(), &mut station_tasks).await {
            Ok((t, _)) => assert_eq!(t.task_id, "t1", "a vehicle's task was delivered"),
            Err(e) => {
                refused = Some(e);
                break;
            }
        }
    }
    let err = refused.expect("the vehicle's task was never refused");
    assert!(
        matches!(
            err,
            ReadError::Refused {
                reason: "topic_not_allowed",
                ..
            }
        ),
        "{err}"
    );

    // A participant without security: unsigned, counted and dropped.
    let plain = PubSub::new(&config(44)).unwrap();
    let pw = plain
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let mut refused = None;
    for _ in 0..100 {
        match send_until(&pw, state("auv-2"), &mut states).await {
            Ok((s, _)) => panic!("an unsigned state vector was delivered: {s:?}"),
            Err(ReadError::Unsigned { topic }) => {
                refused = Some(topic);
                break;
            }
            // Left over from the impersonation attempt above.
            Err(ReadError::Refused {
                reason: "wrong_instance",
                ..
            }) => {}
            Err(other) => panic!("unexpected {other}"),
        }
    }
    let err = refused.expect("no unsigned sample was counted");
    assert_eq!(err, "shoal/state_vector");

    let counts = station.security_counts().unwrap();
    assert!(counts.refused.get(RejectionReason::WrongInstance) >= 1);
    assert!(counts.refused.get(RejectionReason::TopicNotAllowed) >= 1);
    assert!(counts.unsigned["shoal/state_vector"] >= 1);
    // The vehicle's own forged task came back to its task reader, and was refused there
    // too; nothing else was.
    let at_vehicle = auv1.security_counts().unwrap();
    assert_eq!(
        at_vehicle.total(),
        at_vehicle.refused.get(RejectionReason::TopicNotAllowed),
        "{at_vehicle:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_revoked_vehicle_is_refused_once_the_station_has_the_new_revocation_list() {
    let dir = tempfile::tempdir().unwrap();
    let mut store = KeyStore::init(&dir.path().join("keys"), "ccs").unwrap();
    store.issue_vehicle("auv-3").unwrap();
    let vehicle = vehicle_security(&store, "auv-3");
    let station = PubSub::new_secure(&config(45), station_security(&store)).unwrap();
    let mut states = station.subscribe::<StateVector>().unwrap();
    let auv = PubSub::new_secure(&config(45), vehicle).unwrap();
    let w = auv
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    send_until(&w, state("auv-3"), &mut states).await.unwrap();

    store.revoke("auv-3", RevokeReason::KeyCompromise).unwrap();
    station
        .security()
        .unwrap()
        .set_revocations(store.revocations().clone());
    // Samples sent before the new list took effect may still be in flight.
    let mut refused = None;
    for _ in 0..100 {
        if let Err(e) = send_until(&w, state("auv-3"), &mut states).await {
            refused = Some(e);
            break;
        }
    }
    let err = refused.expect("a revoked vehicle kept being delivered");
    assert!(
        matches!(
            err,
            ReadError::Refused {
                reason: "revoked",
                ..
            }
        ),
        "{err}"
    );
    assert!(
        station
            .security_counts()
            .unwrap()
            .refused
            .get(RejectionReason::Revoked)
            >= 1
    );
}

/// A foreign writer on a signed twin: a sample that is not a `SignedSample` at all, and
/// one whose envelope is garbage. Both are reported (malformed CDR; refused as
/// `malformed` and counted), and a good signed sample behind them still arrives.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_on_a_signed_topic_is_refused_and_counted_and_good_samples_still_arrive() {
    use rustdds::Keyed;
    #[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
    struct Wire {
        key: String,
        envelope: Vec<u8>,
    }
    impl Keyed for Wire {
        type K = String;
        fn key(&self) -> String {
            self.key.clone()
        }
    }
    #[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
    struct Short {
        key: String,
    }
    impl Keyed for Short {
        type K = String;
        fn key(&self) -> String {
            self.key.clone()
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let mut store = KeyStore::init(&dir.path().join("keys"), "ccs").unwrap();
    store.issue_vehicle("auv-1").unwrap();
    let station = PubSub::new_secure(&config(46), station_security(&store)).unwrap();
    let mut states = station.subscribe::<StateVector>().unwrap();

    let foreign = Foreign::new(46, "shoal/state_vector/signed", "shoal::SignedSample");
    let garbage = foreign
        .publisher
        .create_datawriter_cdr::<Wire>(&foreign.topic, None)
        .unwrap();
    let short = foreign
        .publisher
        .create_datawriter_cdr::<Short>(&foreign.topic, None)
        .unwrap();

    // The good vehicle first, so every participant has discovered every other.
    let auv1 = PubSub::new_secure(&config(46), vehicle_security(&store, "auv-1")).unwrap();
    let w1 = auv1
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let (got, _) = send_until(&w1, state("auv-1"), &mut states).await.unwrap();
    assert_eq!(got.vehicle_id, "auv-1");
    tokio::time::sleep(Duration::from_millis(500)).await;

    let (mut refused, mut malformed, mut good_after) = (0, 0, false);
    for round in 0..100 {
        garbage
            .write(
                Wire {
                    key: "auv-9".into(),
                    envelope: vec![0xff; 40 + round],
                },
                None,
            )
            .unwrap();
        short.write(Short { key: "x".into() }, None).unwrap();
        w1.write(state("auv-1")).await.unwrap();
        while let Ok(Some(item)) =
            tokio::time::timeout(Duration::from_millis(100), states.next()).await
        {
            match item {
                Ok((s, _)) => {
                    assert_eq!(s.vehicle_id, "auv-1");
                    good_after = refused > 0;
                }
                Err(ReadError::Refused {
                    reason: "malformed",
                    ..
                }) => refused += 1,
                Err(ReadError::Malformed { .. }) => malformed += 1,
                Err(other) => panic!("unexpected {other}"),
            }
        }
        if refused > 0 && malformed > 0 && good_after {
            break;
        }
    }
    assert!(refused > 0, "the garbage envelope was never refused");
    assert!(malformed > 0, "the short sample was never reported");
    assert!(good_after, "no good sample arrived after the garbage");
    let counts = station.security_counts().unwrap();
    assert!(
        counts.refused.get(RejectionReason::Malformed) >= 1,
        "{counts:?}"
    );
}
