//! The IMC adapter against a scripted vehicle: a plain UDP socket on loopback that sends
//! and checks IMC packets.

use std::time::Duration;

use shoal_model::{GeoPoint, Task, TaskState, UNKNOWN, Validate};
use tokio::net::UdpSocket;

use super::codec::{
    self, EstimatedState, FuelLevel, Header, Message, Packet, PlanControl, PlanControlState,
    VehicleState, plan_control, plan_state,
};
use super::*;
use crate::adapter::TaskUpdate;

const VEHICLE: u16 = 0x0017;

struct FakeVehicle {
    socket: UdpSocket,
    proxy: SocketAddr,
}

impl FakeVehicle {
    async fn send(&self, message: Message) {
        self.send_from(VEHICLE, message).await;
    }

    async fn send_from(&self, src: u16, message: Message) {
        let bytes = codec::encode(&Packet {
            header: Header {
                timestamp: 1.7e9,
                src,
                src_ent: 1,
                dst: ANY_SYSTEM,
                dst_ent: ANY_ENTITY,
            },
            message,
        })
        .unwrap();
        self.socket.send_to(&bytes, self.proxy).await.unwrap();
    }

    async fn send_raw(&self, bytes: &[u8]) {
        self.socket.send_to(bytes, self.proxy).await.unwrap();
    }

    /// The next packet from the proxy that is not a heartbeat or announce.
    async fn expect(&self) -> Packet {
        let mut buf = vec![0u8; 65_536];
        loop {
            let (n, _) =
                tokio::time::timeout(Duration::from_secs(5), self.socket.recv_from(&mut buf))
                    .await
                    .expect("a packet from the proxy")
                    .unwrap();
            let (p, _, _) = codec::decode(&buf[..n]).unwrap();
            if !matches!(p.message, Message::Heartbeat | Message::Announce(_)) {
                return p;
            }
        }
    }
}

async fn setup(tweak: impl FnOnce(&mut ImcConfig)) -> (ImcAdapter, FakeVehicle) {
    let socket = UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let mut config = ImcConfig {
        vehicle_id: "auv-7".into(),
        bind: "127.0.0.1:0".parse().unwrap(),
        vehicle: socket.local_addr().unwrap(),
        heartbeat_interval_ms: 100,
        lost_after_ms: 2000,
        reply_timeout_ms: 300,
        ..ImcConfig::default()
    };
    tweak(&mut config);
    let adapter = ImcAdapter::bind(config).await.unwrap();
    let proxy = adapter.local_addr();
    (adapter, FakeVehicle { socket, proxy })
}

fn estimated_state() -> EstimatedState {
    EstimatedState {
        lat: 41.185_f64.to_radians(),
        lon: (-8.706_f64).to_radians(),
        x: 120.0,
        y: -40.0,
        depth: 7.5,
        alt: 12.0,
        psi: 1.0,
        theta: 0.05,
        phi: -0.02,
        vx: 1.0,
        vy: 0.2,
        ..EstimatedState::default()
    }
}

async fn eventually<T>(what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    for _ in 0..200 {
        if let Some(v) = f() {
            return v;
        }
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    panic!("timed out waiting for {what}");
}

async fn next(adapter: &mut ImcAdapter) -> VehicleOutput {
    tokio::time::timeout(Duration::from_secs(5), adapter.next_output())
        .await
        .expect("an output")
        .unwrap()
}

async fn next_task(adapter: &mut ImcAdapter) -> TaskUpdate {
    loop {
        if let VehicleOutput::Task(u) = next(adapter).await {
            return u;
        }
    }
}

fn order(id: &str, task: Task) -> TaskOrder {
    TaskOrder {
        task_id: id.into(),
        mission_id: String::new(),
        issued_ms: now_ms(),
        task,
    }
}

fn goto_task() -> Task {
    Task::GotoWaypoint {
        target: GeoPoint {
            latitude_deg: 41.19,
            longitude_deg: -8.70,
        },
        depth_m: Some(5.0),
        altitude_m: None,
        speed_mps: 1.6,
    }
}

async fn with_fix(adapter: &mut ImcAdapter, vehicle: &FakeVehicle) {
    vehicle
        .send(Message::EstimatedState(estimated_state()))
        .await;
    vehicle
        .send(Message::FuelLevel(FuelLevel {
            value: 64.0,
            confidence: 100.0,
            opmodes: String::new(),
        }))
        .await;
    eventually("a state", || adapter.state()).await;
}

#[tokio::test]
async fn telemetry_becomes_a_valid_state_vector() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    assert!(adapter.state().is_none());
    with_fix(&mut adapter, &vehicle).await;
    let s = adapter.state().unwrap();
    assert_eq!(s.validate(), Ok(()));
    assert_eq!(s.vehicle_id, "auv-7");
    let (lat, lon) = mapping::displace(
        41.185_f64.to_radians(),
        (-8.706_f64).to_radians(),
        120.0,
        -40.0,
    );
    assert!((s.latitude_deg - lat).abs() < 1e-9 && (s.longitude_deg - lon).abs() < 1e-9);
    // 120 m north is about 0.001 08° of latitude; 40 m west 0.000 48° of longitude.
    assert!(
        (s.latitude_deg - 41.185 - 0.001_08).abs() < 1e-5,
        "{}",
        s.latitude_deg
    );
    assert!(
        (s.longitude_deg + 8.706 + 0.000_48).abs() < 1e-5,
        "{}",
        s.longitude_deg
    );
    assert_eq!(s.depth_m, 7.5);
    assert_eq!(s.altitude_m, 12.0);
    assert!((s.yaw_deg - 57.295_78).abs() < 1e-3);
    assert!((s.speed_mps - 1.0198).abs() < 1e-3);
    assert_eq!(s.battery_pct, 64.0);
    assert!(adapter.is_connected());
}

#[tokio::test]
async fn bad_packets_are_counted_and_dropped() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    with_fix(&mut adapter, &vehicle).await;
    let before = adapter.state().unwrap();
    // Garbage, a bad CRC, an unknown id, an impossible latitude and a bad battery.
    vehicle.send_raw(b"hello, not IMC").await;
    let mut bad_crc = codec::encode(&Packet {
        header: Header {
            timestamp: 0.0,
            src: VEHICLE,
            src_ent: 0,
            dst: ANY_SYSTEM,
            dst_ent: 0,
        },
        message: Message::EstimatedState(EstimatedState {
            depth: 99.0,
            ..estimated_state()
        }),
    })
    .unwrap();
    let n = bad_crc.len();
    bad_crc[n - 1] ^= 0xFF;
    vehicle.send_raw(&bad_crc).await;
    let mut unknown = codec::encode(&Packet {
        header: Header {
            timestamp: 0.0,
            src: VEHICLE,
            src_ent: 0,
            dst: ANY_SYSTEM,
            dst_ent: 0,
        },
        message: Message::Heartbeat,
    })
    .unwrap();
    unknown[2] = 0xE8; // id 1000: outside LSTS's range
    unknown[3] = 0x03;
    let n = unknown.len();
    let crc = codec::crc16(&unknown[..n - 2]).to_le_bytes();
    unknown[n - 2..].copy_from_slice(&crc);
    vehicle.send_raw(&unknown).await;
    vehicle
        .send(Message::EstimatedState(EstimatedState {
            lat: 3.0, // radians: beyond the pole
            ..estimated_state()
        }))
        .await;
    vehicle
        .send(Message::FuelLevel(FuelLevel {
            value: 250.0,
            ..FuelLevel::default()
        }))
        .await;
    let c = eventually("the counters", || {
        let c = adapter.counters();
        (c.out_of_range >= 2).then_some(c)
    })
    .await;
    assert!(c.garbage_bytes >= 14, "{c:?}");
    assert_eq!(c.bad_crc, 1, "{c:?}");
    assert_eq!(c.unknown_message, 1, "{c:?}");
    assert_eq!(c.out_of_range, 2, "{c:?}");
    assert_eq!(adapter.state().unwrap().latitude_deg, before.latitude_deg);
    assert_eq!(adapter.state().unwrap().battery_pct, 64.0);
}

#[tokio::test]
async fn other_systems_are_ignored() {
    let (mut adapter, vehicle) = setup(|c| c.vehicle_imc_id = Some(VEHICLE)).await;
    vehicle
        .send_from(0x0099, Message::EstimatedState(estimated_state()))
        .await;
    eventually("the foreign packet", || {
        (adapter.counters().foreign == 1).then_some(())
    })
    .await;
    assert!(adapter.state().is_none());
    assert!(!adapter.is_connected());
}

#[tokio::test]
async fn a_goto_becomes_a_plan_and_its_progress_task_updates() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    with_fix(&mut adapter, &vehicle).await;
    let accepted = adapter.submit(order("t1", goto_task())).await.unwrap();
    assert_eq!(accepted.message, "IMC plan of 1 maneuvers sent");
    let p = vehicle.expect().await;
    let Message::PlanControl(pc) = p.message else {
        panic!("expected PlanControl, got {:?}", p.message);
    };
    assert_eq!(
        (pc.kind, pc.op, pc.plan_id.as_str()),
        (plan_control::REQUEST, plan_control::START, "t1")
    );
    let Some(Message::PlanSpecification(spec)) = pc.arg.as_deref() else {
        panic!("no plan inline");
    };
    assert_eq!(spec.maneuvers.len(), 1);
    let Some(Message::Goto(g)) = spec.maneuvers[0].data.as_deref() else {
        panic!("no Goto");
    };
    assert!((g.lat.to_degrees() - 41.19).abs() < 1e-9);
    assert!((g.lon.to_degrees() + 8.70).abs() < 1e-9);
    assert_eq!((g.z, g.z_units, g.speed), (5.0, 1, 1.6));
    vehicle
        .send(Message::PlanControl(PlanControl {
            kind: plan_control::SUCCESS,
            op: plan_control::START,
            request_id: pc.request_id,
            plan_id: "t1".into(),
            ..PlanControl::default()
        }))
        .await;
    let u = next_task(&mut adapter).await;
    assert_eq!((u.task_id.as_str(), u.state), ("t1", TaskState::Running));
    let pcs = |state, progress, outcome| {
        Message::PlanControlState(PlanControlState {
            state,
            plan_id: "t1".into(),
            plan_progress: progress,
            last_outcome: outcome,
            ..PlanControlState::default()
        })
    };
    vehicle.send(pcs(plan_state::EXECUTING, 42.0, 0)).await;
    let u = next_task(&mut adapter).await;
    assert_eq!((u.state, u.progress_pct), (TaskState::Running, 42.0));
    vehicle
        .send(pcs(plan_state::READY, 100.0, plan_state::OUTCOME_SUCCESS))
        .await;
    let u = next_task(&mut adapter).await;
    assert_eq!((u.state, u.progress_pct), (TaskState::Done, 100.0));
}

#[tokio::test]
async fn a_refused_plan_fails_with_the_vehicles_reason() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    with_fix(&mut adapter, &vehicle).await;
    adapter.submit(order("t2", goto_task())).await.unwrap();
    let Message::PlanControl(pc) = vehicle.expect().await.message else {
        panic!("expected PlanControl");
    };
    vehicle
        .send(Message::PlanControl(PlanControl {
            kind: plan_control::FAILURE,
            op: plan_control::START,
            request_id: pc.request_id,
            plan_id: "t2".into(),
            info: "vehicle is in calibration".into(),
            ..PlanControl::default()
        }))
        .await;
    let u = next_task(&mut adapter).await;
    assert_eq!(u.state, TaskState::Failed);
    assert_eq!(
        u.message,
        "the vehicle refused the plan: vehicle is in calibration"
    );
}

#[tokio::test]
async fn an_unanswered_plan_is_resent_then_fails() {
    let (mut adapter, vehicle) = setup(|c| c.lost_after_ms = 60_000).await;
    with_fix(&mut adapter, &vehicle).await;
    adapter.submit(order("t3", goto_task())).await.unwrap();
    let mut ids = Vec::new();
    for _ in 0..3 {
        let Message::PlanControl(pc) = vehicle.expect().await.message else {
            panic!("expected PlanControl");
        };
        ids.push(pc.request_id);
    }
    assert!(
        ids.iter().all(|i| *i == ids[0]),
        "a resend keeps its request id"
    );
    let u = next_task(&mut adapter).await;
    assert_eq!(u.state, TaskState::Failed);
    assert!(u.message.contains("3 attempts"), "{}", u.message);
}

#[tokio::test]
async fn a_survey_is_a_chain_of_gotos() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    with_fix(&mut adapter, &vehicle).await;
    let p = |lat: f64, lon: f64| GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    let task = Task::SurveyArea {
        polygon: vec![
            p(41.19, -8.70),
            p(41.19, -8.699),
            p(41.1905, -8.699),
            p(41.1905, -8.70),
        ],
        line_spacing_m: 20.0,
        depth_m: None,
        altitude_m: Some(3.0),
        speed_mps: 0.0,
    };
    adapter.submit(order("s1", task)).await.unwrap();
    let Message::PlanControl(pc) = vehicle.expect().await.message else {
        panic!("expected PlanControl");
    };
    let Some(Message::PlanSpecification(spec)) = pc.arg.as_deref() else {
        panic!("no plan inline");
    };
    // 55 m north-south at 20 m spacing: 3 lines, 2 points each.
    assert_eq!(spec.maneuvers.len(), 6);
    assert_eq!(spec.transitions.len(), 5);
    assert_eq!(spec.start_man_id, "1");
    assert_eq!(spec.transitions[0].conditions, "ManeuverIsDone");
    for m in &spec.maneuvers {
        let Some(Message::Goto(g)) = m.data.as_deref() else {
            panic!("not a Goto");
        };
        assert_eq!((g.z, g.z_units), (3.0, codec::units::Z_ALTITUDE));
        assert_eq!(g.speed, 1.2, "the default speed");
    }
}

#[tokio::test]
async fn abort_stops_the_running_plan() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    with_fix(&mut adapter, &vehicle).await;
    adapter.submit(order("g", goto_task())).await.unwrap();
    let Message::PlanControl(pc) = vehicle.expect().await.message else {
        panic!("expected PlanControl");
    };
    vehicle
        .send(Message::PlanControl(PlanControl {
            kind: plan_control::SUCCESS,
            op: plan_control::START,
            request_id: pc.request_id,
            plan_id: "g".into(),
            ..PlanControl::default()
        }))
        .await;
    assert_eq!(next_task(&mut adapter).await.state, TaskState::Running);
    adapter.submit(order("stop", Task::Abort)).await.unwrap();
    assert!(matches!(vehicle.expect().await.message, Message::Abort));
    let u = next_task(&mut adapter).await;
    assert_eq!((u.task_id.as_str(), u.state), ("g", TaskState::Aborted));
    assert_eq!(u.message, "aborted by task stop");
    let u = next_task(&mut adapter).await;
    assert_eq!((u.task_id.as_str(), u.state), ("stop", TaskState::Running));
    vehicle
        .send(Message::PlanControlState(PlanControlState {
            state: plan_state::READY,
            plan_id: "g".into(),
            last_outcome: plan_state::OUTCOME_FAILURE,
            ..PlanControlState::default()
        }))
        .await;
    let u = next_task(&mut adapter).await;
    assert_eq!((u.task_id.as_str(), u.state), ("stop", TaskState::Done));
}

#[tokio::test]
async fn tasks_are_refused_without_contact_or_in_error() {
    let (mut adapter, vehicle) = setup(|_| {}).await;
    let r = adapter.submit(order("a", goto_task())).await.unwrap_err();
    assert_eq!(r.reason, "no contact with the vehicle over IMC");
    with_fix(&mut adapter, &vehicle).await;
    vehicle
        .send(Message::VehicleState(VehicleState {
            op_mode: op_mode::ERROR,
            last_error: "DVL not responding".into(),
            ..VehicleState::default()
        }))
        .await;
    let out = next(&mut adapter).await;
    let VehicleOutput::Event(e) = out else {
        panic!("expected an event, got {out:?}");
    };
    assert_eq!((e.severity, e.kind), (Severity::Alarm, EventKind::Fault));
    assert_eq!(e.text, "vehicle in ERROR mode: DVL not responding");
    let r = adapter.submit(order("b", goto_task())).await.unwrap_err();
    assert_eq!(r.reason, "vehicle in ERROR mode: DVL not responding");
}

#[tokio::test]
async fn silence_is_reported_lost_and_speech_restored() {
    let (mut adapter, vehicle) = setup(|c| c.lost_after_ms = 400).await;
    with_fix(&mut adapter, &vehicle).await;
    let out = next(&mut adapter).await;
    let VehicleOutput::Event(e) = out else {
        panic!("expected an event, got {out:?}");
    };
    assert_eq!((e.severity, e.kind), (Severity::Alarm, EventKind::CommLost));
    assert!(adapter.state().is_none(), "no stale state while lost");
    assert!(!adapter.is_connected());
    vehicle.send(Message::Heartbeat).await;
    let out = next(&mut adapter).await;
    let VehicleOutput::Event(e) = out else {
        panic!("expected an event, got {out:?}");
    };
    assert_eq!((e.severity, e.kind), (Severity::Info, EventKind::CommLost));
    assert!(e.text.starts_with("IMC link restored"), "{}", e.text);
    assert!(adapter.state().is_some());
}

#[tokio::test]
async fn the_proxy_heartbeats_and_announces_itself() {
    let (adapter, vehicle) = setup(|_| {}).await;
    let mut buf = vec![0u8; 2048];
    let mut seen = (false, false);
    while seen != (true, true) {
        let (n, from) =
            tokio::time::timeout(Duration::from_secs(2), vehicle.socket.recv_from(&mut buf))
                .await
                .unwrap()
                .unwrap();
        assert_eq!(from, adapter.local_addr());
        let (p, order, _) = codec::decode(&buf[..n]).unwrap();
        assert_eq!(order, codec::ByteOrder::Little);
        assert_eq!(p.header.src, 0x4100);
        match p.message {
            Message::Heartbeat => seen.0 = true,
            Message::Announce(a) => {
                assert_eq!(a.sys_type, 0);
                assert_eq!(a.services, format!("imc+udp://{}/", adapter.local_addr()));
                seen.1 = true;
            }
            other => panic!("unexpected {other:?}"),
        }
    }
}

#[test]
fn the_config_has_defaults_and_rejects_unknown_fields() {
    let c: ImcConfig = serde_json::from_str(r#"{"vehicle_id": "lauv-xplore-1"}"#).unwrap();
    assert_eq!(c.vehicle_id, "lauv-xplore-1");
    assert_eq!(c.vehicle, ImcConfig::default().vehicle);
    assert!(serde_json::from_str::<ImcConfig>(r#"{"vehicle_idd": "x"}"#).is_err());
    assert!(check(&ImcConfig::default()).is_ok());
    let bad = ImcConfig {
        vehicle_id: "bad id".into(),
        ..ImcConfig::default()
    };
    assert!(matches!(check(&bad), Err(ImcError::Config(_))));
}

#[test]
fn altitude_unknown_maps_to_the_sentinel() {
    let s = mapping::state_from(&estimated_state(), "x", 0);
    assert_eq!(s.altitude_m, 12.0);
    let s = mapping::state_from(
        &EstimatedState {
            alt: -1.0,
            ..estimated_state()
        },
        "x",
        0,
    );
    assert_eq!(s.altitude_m, UNKNOWN);
}
