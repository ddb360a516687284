//! End to end: state vectors of three vehicles published on a private DDS domain reach
//! an independent Foxglove client (Foxglove's own `@foxglove/ws-protocol` client, IDL
//! parser, CDR reader and protobufjs, in Node: tests/foxglove/client.js) through the
//! bridge and its gateway, decoded from the schemas the bridge advertises.
//!
//! Needs Node and `npm ci --prefix tests/foxglove`; without them the test is skipped
//! with the reason printed, unless `SHOAL_INTEROP_REQUIRED=1`, when it fails.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::collections::{BTreeMap, BTreeSet};
use std::path::PathBuf;
use std::process::Stdio;
use std::sync::Arc;
use std::time::Duration;

use shoal_dds::{Priority, WriterOptions};
use shoal_foxglove::{Bridge, BridgeConfig, RateLimits};
use shoal_model::StateVector;
use tokio::io::AsyncReadExt;
use tokio_util::sync::CancellationToken;

const DOMAIN: u16 = 175;
const VEHICLES: [&str; 3] = ["auv-1", "usv-2", "glider-3"];
/// Messages the client waits for: both channels, several rounds.
const COUNT: usize = 24;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Why the Node client cannot run here, if it cannot.
fn missing() -> Option<String> {
    let node = std::process::Command::new("node").arg("--version").output();
    match node {
        Err(e) => return Some(format!("node not found: {e}")),
        Ok(o) if !o.status.success() => return Some("node --version failed".into()),
        Ok(_) => {}
    }
    let pkg = repo().join("tests/foxglove/node_modules/@foxglove/ws-protocol/package.json");
    (!pkg.exists()).then(|| {
        format!(
            "{} missing: run npm ci --prefix tests/foxglove",
            pkg.display()
        )
    })
}

fn skip_or_fail(why: &str) {
    assert!(
        std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
        "the Foxglove client is required (SHOAL_INTEROP_REQUIRED=1) but cannot run: {why}"
    );
    println!("SKIPPED: the Foxglove client cannot run: {why}");
}

/// Position of vehicle `v` in round `k`: distinct per vehicle and per round.
fn position(v: usize, k: i64) -> (f64, f64, f64) {
    let v = v as f64;
    let k = k as f64;
    (
        43.0 + v * 0.5 + k * 1e-4,
        5.0 + v * 0.25 - k * 1e-4,
        2.0 + v * 10.0 + k,
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_independent_foxglove_client_decodes_the_fleet_from_the_bridge() {
    if let Some(why) = missing() {
        skip_or_fail(&why);
        return;
    }
    let station = Arc::new(common::pubsub(DOMAIN));
    let vehicle = common::pubsub(DOMAIN);
    let cancel = CancellationToken::new();
    let config = BridgeConfig {
        enabled: true,
        rates: RateLimits::unlimited(),
        ..BridgeConfig::default()
    };
    let bridge = Bridge::start(Arc::clone(&station), config, cancel.clone())
        .await
        .unwrap();
    let addr = common::front(bridge.clone()).await;
    let writer = vehicle
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    common::wait_matched(&writer).await;

    let mut child = tokio::process::Command::new("node")
        .arg(repo().join("tests/foxglove/client.js"))
        .args(["--url", &format!("ws://{addr}/api/foxglove")])
        .args(["--topics", "shoal/state_vector,shoal/location_fix"])
        .args(["--count", &COUNT.to_string()])
        .args(["--timeout-ms", "30000"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();

    // Publish rounds until the client has what it waits for (it subscribes a moment
    // after it connects, and the bridge keeps no history).
    let t0 = 1_767_225_600_000_i64;
    let mut published: BTreeMap<(String, i64), StateVector> = BTreeMap::new();
    let mut k = 0;
    let status = loop {
        for (v, id) in VEHICLES.iter().enumerate() {
            let (lat, lon, depth) = position(v, k);
            let s = common::state(id, t0 + k * 1000, lat, lon, depth);
            published.insert((id.to_string(), s.timestamp_ms), s.clone());
            writer.write(s).await.unwrap();
        }
        k += 1;
        assert!(k < 300, "the client got too little in 60 s");
        if let Ok(Ok(Some(status))) =
            tokio::time::timeout(Duration::from_millis(200), async { child.try_wait() }).await
        {
            break status;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    let mut out = String::new();
    child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut out)
        .await
        .unwrap();
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .await
        .unwrap();
    assert!(status.success(), "client failed ({status}): {err}\n{out}");

    let lines: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    // What the client saw advertised: every Shoal topic with its IDL schema, and the
    // LocationFix channel.
    let advertised: BTreeMap<String, serde_json::Value> = lines
        .iter()
        .filter_map(|l| l["advertised"].as_array())
        .flatten()
        .map(|c| (c["topic"].as_str().unwrap().to_owned(), c.clone()))
        .collect();
    for (topic, type_name) in shoal_dds::ALL_TOPICS {
        let c = advertised
            .get(topic)
            .unwrap_or_else(|| panic!("{topic} not advertised"));
        assert_eq!(c["encoding"], "cdr", "{topic}");
        assert_eq!(c["schemaEncoding"], "omgidl", "{topic}");
        assert_eq!(c["schemaName"], type_name, "{topic}");
    }
    let fix = &advertised["shoal/location_fix"];
    assert_eq!(fix["encoding"], "protobuf");
    assert_eq!(fix["schemaName"], "foxglove.LocationFix");

    let messages: Vec<&serde_json::Value> =
        lines.iter().filter(|l| l.get("topic").is_some()).collect();
    assert_eq!(messages.len(), COUNT);
    let mut states = BTreeSet::new();
    let mut fixes = BTreeSet::new();
    for m in &messages {
        let msg = &m["message"];
        match m["topic"].as_str().unwrap() {
            "shoal/state_vector" => {
                assert_eq!(m["schemaName"], "shoal::StateVector");
                let id = msg["vehicle_id"].as_str().unwrap().to_owned();
                let ts: i64 = msg["timestamp_ms"].as_str().unwrap().parse().unwrap();
                let sent = published
                    .get(&(id.clone(), ts))
                    .unwrap_or_else(|| panic!("never published: {msg}"));
                assert_eq!(msg["latitude_deg"], sent.latitude_deg);
                assert_eq!(msg["longitude_deg"], sent.longitude_deg);
                assert_eq!(msg["depth_m"], sent.depth_m);
                assert_eq!(msg["yaw_deg"], sent.yaw_deg);
                assert_eq!(msg["battery_pct"], sent.battery_pct);
                // The message's log time is the sample's own time.
                assert_eq!(m["logTimeNs"], (ts * 1_000_000).to_string());
                states.insert(id);
            }
            "shoal/location_fix" => {
                // protobufjs names fields in camelCase.
                let id = msg["frameId"]
                    .as_str()
                    .unwrap_or_else(|| panic!("no frameId: {msg}"))
                    .to_owned();
                let ts = &msg["timestamp"];
                // google.protobuf.Timestamp; protobufjs gives int64 as text.
                let int = |v: &serde_json::Value| {
                    v.as_i64()
                        .or_else(|| v.as_str().and_then(|s| s.parse().ok()))
                        .unwrap_or_else(|| panic!("not an integer: {msg}"))
                };
                let sec = int(&ts["seconds"]);
                let nsec = int(&ts["nanos"]);
                let sent = published
                    .get(&(id.clone(), sec * 1000 + nsec / 1_000_000))
                    .unwrap_or_else(|| panic!("never published: {msg}"));
                assert_eq!(msg["latitude"], sent.latitude_deg);
                assert_eq!(msg["longitude"], sent.longitude_deg);
                assert_eq!(msg["altitude"], -sent.depth_m);
                assert_eq!(msg["positionCovarianceType"], "UNKNOWN");
                fixes.insert(id);
            }
            other => panic!("not subscribed: {other}"),
        }
    }
    let all: BTreeSet<String> = VEHICLES.iter().map(|v| v.to_string()).collect();
    assert_eq!(states, all, "state vectors of every vehicle");
    assert_eq!(fixes, all, "location fixes of every vehicle");
    assert!(
        bridge
            .stats()
            .logged
            .load(std::sync::atomic::Ordering::Relaxed)
            >= COUNT as u64
    );
    cancel.cancel();
}
