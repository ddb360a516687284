//! Round trip of RustDDS alone, without the Publish/Subscribe Manager: how much of
//! `shoal bench bus`'s round trip is the DDS library and how much is Shoal's layer (reader
//! threads, the channel to async code, validation).
//!
//! Two participants in one process on loopback, each with its own thread: one writes a
//! sample of about the State Vector's size and waits (mio readiness, as Shoal's reader
//! threads do) for the echo the other sends back. Reliable, keep-last, volatile, as
//! Shoal's state vectors.
//!
//! `cargo run --release -p shoal-dds --example rustdds_round_trip -- [seconds] [domain]`,
//! inside a network namespace (`scripts/netns-run.sh`): discovery multicasts.

// A measurement program: any failure to set up is fatal and says where.
#![allow(clippy::expect_used, clippy::panic)]

use std::time::{Duration, Instant};

use rustdds::mio1::{Events, Interest, Poll, Token};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::with_key::{DataReader, DataWriter, Sample as DdsSample};
use rustdds::{
    CDRDeserializerAdapter, CDRSerializerAdapter, DomainParticipant, DomainParticipantBuilder,
    Keyed, QosPolicies, QosPolicyBuilder, ReadCondition, TopicKind,
};
use serde::{Deserialize, Serialize};

/// About a State Vector on the wire: a vehicle id and ten numbers.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Sample {
    id: String,
    seq: u64,
    values: [f64; 9],
}

impl Keyed for Sample {
    type K = String;
    fn key(&self) -> String {
        self.id.clone()
    }
}

type Reader = DataReader<Sample, CDRDeserializerAdapter<Sample>>;
type Writer = DataWriter<Sample, CDRSerializerAdapter<Sample>>;

fn qos() -> QosPolicies {
    QosPolicyBuilder::new()
        .reliability(Reliability::Reliable {
            max_blocking_time: rustdds::Duration::from_millis(200),
        })
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 64 })
        .build()
}

fn endpoints(dp: &DomainParticipant, out: &str, input: &str) -> (Writer, Reader) {
    let q = qos();
    let t_out = dp
        .create_topic(out.into(), "bench::Sample".into(), &q, TopicKind::WithKey)
        .expect("topic");
    let t_in = dp
        .create_topic(input.into(), "bench::Sample".into(), &q, TopicKind::WithKey)
        .expect("topic");
    let w = dp
        .create_publisher(&q)
        .expect("publisher")
        .create_datawriter_cdr::<Sample>(&t_out, None)
        .expect("writer");
    let r = dp
        .create_subscriber(&q)
        .expect("subscriber")
        .create_datareader_cdr::<Sample>(&t_in, None)
        .expect("reader");
    (w, r)
}

/// Waits until `reader` has a sample (or `timeout`), then takes what is there.
fn take_wait(poll: &mut Poll, reader: &mut Reader, timeout: Duration) -> Vec<Sample> {
    let mut events = Events::with_capacity(4);
    let deadline = Instant::now() + timeout;
    loop {
        let got: Vec<Sample> = reader
            .take(64, ReadCondition::not_read())
            .unwrap_or_default()
            .into_iter()
            .filter_map(|s| match s.into_value() {
                DdsSample::Value(v) => Some(v),
                DdsSample::Dispose(_) => None,
            })
            .collect();
        if !got.is_empty() {
            return got;
        }
        let now = Instant::now();
        if now >= deadline {
            return got;
        }
        let _ = poll.poll(&mut events, Some(deadline - now));
    }
}

fn participant(domain: u16) -> DomainParticipant {
    DomainParticipantBuilder::new(domain)
        .with_only_networks([std::net::Ipv4Addr::LOCALHOST])
        .build()
        .expect("participant")
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, name: &str, default: u64, (min, max): (u64, u64)| -> u64 {
        let Some(text) = args.get(i) else {
            return default;
        };
        match text.parse::<u64>() {
            Ok(v) if (min..=max).contains(&v) => v,
            _ => {
                eprintln!(
                    "rustdds_round_trip: {name} must be a whole number from {min} to {max}, not {text:?}"
                );
                eprintln!("usage: rustdds_round_trip [seconds] [domain]");
                std::process::exit(2);
            }
        }
    };
    let seconds = arg(0, "seconds", 5, (1, 3600));
    // RTPS ports overflow above domain 232.
    let domain = u16::try_from(arg(1, "domain", 27, (0, 232))).unwrap_or(27);

    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let pong_stop = stop.clone();
    let pong = std::thread::spawn(move || {
        let dp = participant(domain);
        let (w, mut r) = endpoints(&dp, "bench/pong", "bench/ping");
        let mut poll = Poll::new().expect("poll");
        poll.registry()
            .register(&mut r, Token(0), Interest::READABLE)
            .expect("register");
        while !pong_stop.load(std::sync::atomic::Ordering::Relaxed) {
            for s in take_wait(&mut poll, &mut r, Duration::from_millis(200)) {
                let _ = w.write(s, None);
            }
        }
    });

    let dp = participant(domain);
    let (w, mut r) = endpoints(&dp, "bench/ping", "bench/pong");
    let mut poll = Poll::new().expect("poll");
    poll.registry()
        .register(&mut r, Token(0), Interest::READABLE)
        .expect("register");
    let sample = |seq| Sample {
        id: "ping".into(),
        seq,
        values: [1.0; 9],
    };
    // Discovery: ping until an echo comes back.
    let mut seq = 0;
    let start = Instant::now();
    loop {
        seq += 1;
        let _ = w.write(sample(seq), None);
        if !take_wait(&mut poll, &mut r, Duration::from_millis(200)).is_empty() {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(30), "no echo in 30 s");
    }
    while !take_wait(&mut poll, &mut r, Duration::from_millis(300)).is_empty() {}

    let mut rtts = Vec::new();
    let end = Instant::now() + Duration::from_secs(seconds);
    while Instant::now() < end {
        seq += 1;
        let t0 = Instant::now();
        let _ = w.write(sample(seq), None);
        'wait: loop {
            let got = take_wait(&mut poll, &mut r, Duration::from_secs(2));
            if got.is_empty() {
                break; // lost: counted by its absence
            }
            if got.iter().any(|s| s.seq == seq) {
                rtts.push(t0.elapsed().as_secs_f64() * 1e6);
                break 'wait;
            }
        }
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let _ = pong.join();
    rtts.sort_by(f64::total_cmp);
    let pick = |p: f64| {
        rtts.get(((rtts.len() as f64 - 1.0) * p / 100.0).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    println!(
        "RustDDS alone, two participants in one process: {} round trips in {seconds} s, p50 {:.0} µs, p99 {:.0} µs",
        rtts.len(),
        pick(50.0),
        pick(99.0)
    );
}
