//! Helpers shared by the integration tests.

use std::path::PathBuf;
use std::time::Duration;

use shoal_federation::TaskTransition;
use shoal_federation::config::Mode;
use shoal_federation::{Federation, FederationConfig, LeasePolicy, VehiclePosition};
use shoal_model::{Event, EventKind, Severity, TaskState, VehicleKind};

/// How long any wait may take before the test fails: a bound on a hang, not a measure.
pub const PATIENCE: Duration = Duration::from_secs(30);

/// A TCP port free on loopback now.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A loopback endpoint.
pub fn endpoint(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}

/// A peer site listening on `listen` (if any), connecting to `connect`, accepting
/// `remotes`. Without site identity (`insecure_open`): these tests are of the transport
/// and the cores (and one has a site the shore was not told of reach it); identity is
/// tested in `tls` and through the binary (`crates/shoal/tests/it/federation.rs`).
pub fn site(
    name: &str,
    listen: Option<u16>,
    connect: &[u16],
    remotes: &[&str],
) -> FederationConfig {
    FederationConfig {
        site: name.into(),
        mode: Mode::Peer,
        listen: listen.map(endpoint).into_iter().collect(),
        connect: connect.iter().copied().map(endpoint).collect(),
        remote_sites: remotes.iter().map(|s| s.to_string()).collect(),
        insecure_open: true,
        ..unkept()
    }
}

/// The defaults, except that the command leases are not kept in a file: the tests run in
/// the crate's directory.
pub fn unkept() -> FederationConfig {
    FederationConfig {
        lease: LeasePolicy {
            state_file: PathBuf::new(),
            ..LeasePolicy::default()
        },
        ..FederationConfig::default()
    }
}

/// Waits until `check` holds, polling; panics naming `what` after [`PATIENCE`].
pub async fn eventually(what: &str, mut check: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while !check() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

/// Logs to the test's output as `RUST_LOG` says (e.g. `shoal_federation=debug`).
pub fn logs() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_test_writer()
        .try_init();
}

/// Whether `fed` sees `remote`'s session up.
pub fn sees(fed: &Federation, remote: &str) -> bool {
    fed.picture(|p| p.sites().any(|(s, st)| s == remote && st.online))
}

/// Whether `fed` sees `remote`'s session down (after having seen it).
pub fn lost(fed: &Federation, remote: &str) -> bool {
    fed.picture(|p| p.sites().any(|(s, st)| s == remote && !st.online))
}

/// The sequence numbers of the alarms `fed` received from `site`, in arrival order.
pub fn alarm_seqs(fed: &Federation, site: &str) -> Vec<u64> {
    fed.picture(|p| {
        p.alarms_after(0)
            .filter(|a| a.site == site)
            .map(|a| a.seq)
            .collect()
    })
}

/// The ids of the alarms `fed` received from `site`, in arrival order.
pub fn alarm_ids(fed: &Federation, site: &str) -> Vec<String> {
    fed.picture(|p| {
        p.alarms_after(0)
            .filter(|a| a.site == site)
            .map(|a| a.alarm.event_id.clone())
            .collect()
    })
}

/// The (task, state) pairs `fed` received from `site`, in arrival order.
pub fn transitions(fed: &Federation, site: &str) -> Vec<(String, TaskState)> {
    fed.picture(|p| {
        p.transitions_after(0)
            .filter(|t| t.site == site)
            .map(|t| (t.transition.task_id.clone(), t.transition.state))
            .collect()
    })
}

/// A critical alarm with this id.
pub fn alarm(id: &str) -> Event {
    Event {
        event_id: id.into(),
        timestamp_ms: shoal_model::now_ms(),
        severity: Severity::Critical,
        kind: EventKind::Fault,
        vehicle_id: "auv-1".into(),
        task_id: String::new(),
        text: format!("alarm {id}"),
    }
}

/// A transition of `task` into `state`.
pub fn transition(task: &str, state: TaskState) -> TaskTransition {
    TaskTransition {
        task_id: task.into(),
        mission_id: "m-1".into(),
        vehicle_id: "auv-1".into(),
        state,
        timestamp_ms: shoal_model::now_ms(),
    }
}

/// A position of `vehicle` fixed now, at latitude `lat`.
pub fn position(vehicle: &str, lat: f64) -> VehiclePosition {
    VehiclePosition {
        vehicle_id: vehicle.into(),
        kind: VehicleKind::Auv,
        timestamp_ms: shoal_model::now_ms(),
        latitude_deg: lat,
        longitude_deg: 5.9,
        depth_m: 20.0,
        heading_deg: 90.0,
        speed_mps: 1.2,
        battery_pct: 75.0,
    }
}

/// A client site of the router on `port`, accepting `remotes`.
pub fn client(name: &str, port: u16, remotes: &[&str]) -> FederationConfig {
    FederationConfig {
        mode: Mode::Client,
        ..site(name, None, &[port], remotes)
    }
}

/// A bare Zenoh router on loopback (no scouting): the link between two sites, closed to
/// cut it.
pub async fn router(port: u16) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""router""#.to_string()),
        ("listen/endpoints", format!(r#"["{}"]"#, endpoint(port))),
        ("connect/endpoints", "[]".into()),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
    ] {
        c.insert_json5(k, &v).unwrap();
    }
    zenoh::open(c).await.unwrap()
}

/// A bare Zenoh peer connected to `port`, to send what no site would.
pub async fn raw_peer(port: u16) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""peer""#.to_string()),
        ("listen/endpoints", "[]".into()),
        ("connect/endpoints", format!(r#"["{}"]"#, endpoint(port))),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
    ] {
        c.insert_json5(k, &v).unwrap();
    }
    zenoh::open(c).await.unwrap()
}

/// Who holds `vehicle`'s command lease at `fed`, and at what term.
pub fn holder(fed: &Federation, vehicle: &str) -> Option<(String, u64)> {
    fed.leases()
        .into_iter()
        .find(|r| r.vehicle_id == vehicle)
        .map(|r| (r.holder, r.term))
}
