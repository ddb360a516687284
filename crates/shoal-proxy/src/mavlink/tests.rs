//! The MAVLink adapter against a scripted vehicle: a UDP socket on loopback sending and
//! checking MAVLink 2 frames made with the `mavlink` crate.

// The proxy asks for streams with REQUEST_DATA_STREAM (deprecated; see request_streams).
#![allow(deprecated)]

use std::time::Duration;

use mavlink::Message;
use mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, COMMAND_ACK_DATA, GLOBAL_POSITION_INT_DATA, MISSION_ACK_DATA,
    MISSION_CURRENT_DATA, MISSION_ITEM_REACHED_DATA, MISSION_REQUEST_INT_DATA, MavSeverity,
    STATUSTEXT_DATA, SYS_STATUS_DATA, VFR_HUD_DATA,
};
use shoal_model::{GeoPoint, Task, TaskState};
use tokio::net::UdpSocket;

use super::*;
use crate::adapter::{TaskUpdate, VehicleEvent};

struct FakeVehicle {
    socket: UdpSocket,
    proxy: SocketAddr,
    seq: u8,
}

impl FakeVehicle {
    async fn new(proxy: SocketAddr) -> Self {
        Self {
            socket: UdpSocket::bind("127.0.0.1:0").await.unwrap(),
            proxy,
            seq: 0,
        }
    }

    fn frame(&mut self, msg: &MavMessage) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1);
        frame::encode(
            MavHeader {
                system_id: 1,
                component_id: 1,
                sequence: self.seq,
            },
            msg,
        )
        .unwrap()
    }

    async fn send(&mut self, msg: MavMessage) {
        let bytes = self.frame(&msg);
        self.socket.send_to(&bytes, self.proxy).await.unwrap();
    }

    async fn send_raw(&self, bytes: &[u8]) {
        self.socket.send_to(bytes, self.proxy).await.unwrap();
    }

    /// Every message from the proxy in the next `ms` milliseconds.
    async fn drain(&self, ms: u64) -> Vec<MavMessage> {
        let mut out = Vec::new();
        let mut buf = vec![0u8; 4096];
        let end = Instant::now() + Duration::from_millis(ms);
        while let Ok(Ok((n, _))) =
            tokio::time::timeout_at(end, self.socket.recv_from(&mut buf)).await
        {
            if let (Frame::Message { message, .. }, _) = frame::next(&buf[..n]) {
                out.push(*message);
            }
        }
        out
    }

    /// The next message from the proxy that is not a GCS heartbeat or a stream request.
    async fn expect(&self) -> MavMessage {
        let mut buf = vec![0u8; 4096];
        loop {
            let (n, _) =
                tokio::time::timeout(Duration::from_secs(5), self.socket.recv_from(&mut buf))
                    .await
                    .expect("a frame from the proxy")
                    .unwrap();
            let (f, _) = frame::next(&buf[..n]);
            let Frame::Message {
                message, header, ..
            } = f
            else {
                panic!("the proxy sent a bad frame: {f:?}");
            };
            assert_eq!(
                (header.system_id, header.component_id),
                (255, GCS_COMPONENT)
            );
            if !matches!(
                *message,
                MavMessage::HEARTBEAT(_) | MavMessage::REQUEST_DATA_STREAM(_)
            ) {
                return *message;
            }
        }
    }

    async fn heartbeat(&mut self, mode: u32, armed: bool) {
        let base_mode = if armed {
            MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED | MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        } else {
            MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        };
        self.send(MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: mode,
            mavtype: MavType::MAV_TYPE_SUBMARINE,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode,
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }))
        .await;
    }

    async fn position(&mut self, lat: f64, lon: f64, depth: f64) {
        self.send(MavMessage::GLOBAL_POSITION_INT(GLOBAL_POSITION_INT_DATA {
            lat: mapping::e7_from_deg(lat),
            lon: mapping::e7_from_deg(lon),
            relative_alt: (-depth * 1000.0).round() as i32,
            vx: 30,
            vy: -40,
            hdg: 9000,
            ..GLOBAL_POSITION_INT_DATA::default()
        }))
        .await;
    }

    async fn battery(&mut self, pct: i8) {
        self.send(MavMessage::SYS_STATUS(SYS_STATUS_DATA {
            battery_remaining: pct,
            ..SYS_STATUS_DATA::default()
        }))
        .await;
    }

    async fn ack(&mut self, command: MavCmd, result: MavResult) {
        self.send(MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
            command,
            result,
        }))
        .await;
    }
}

async fn setup(tweak: impl FnOnce(&mut MavlinkConfig)) -> (MavlinkAdapter, FakeVehicle) {
    let mut config = MavlinkConfig {
        vehicle_id: "rov-3".into(),
        address: "udpin:127.0.0.1:0".into(),
        heartbeat_interval_ms: 100,
        lost_after_ms: 2000,
        command_timeout_ms: 300,
        ..MavlinkConfig::default()
    };
    tweak(&mut config);
    let adapter = MavlinkAdapter::connect(config).await.unwrap();
    let vehicle = FakeVehicle::new(adapter.local_addr()).await;
    (adapter, vehicle)
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

async fn next(adapter: &mut MavlinkAdapter) -> VehicleOutput {
    tokio::time::timeout(Duration::from_secs(5), adapter.next_output())
        .await
        .expect("an output")
        .unwrap()
}

async fn next_task(adapter: &mut MavlinkAdapter) -> TaskUpdate {
    loop {
        if let VehicleOutput::Task(u) = next(adapter).await {
            return u;
        }
    }
}

async fn next_event(adapter: &mut MavlinkAdapter, kind: EventKind) -> VehicleEvent {
    loop {
        if let VehicleOutput::Event(e) = next(adapter).await
            && e.kind == kind
        {
            return e;
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

const LAT: f64 = 47.397_742;
const LON: f64 = 8.545_594;

/// A vehicle heard, armed in MANUAL, with a position and a battery.
async fn online(adapter: &mut MavlinkAdapter, v: &mut FakeVehicle) {
    v.heartbeat(sub_mode::MANUAL, true).await;
    v.position(LAT, LON, 3.0).await;
    v.battery(80).await;
    eventually("a state vector", || adapter.state()).await;
}

fn goto_task(depth: f64, speed: f64) -> Task {
    Task::GotoWaypoint {
        target: GeoPoint {
            latitude_deg: LAT + 0.0002,
            longitude_deg: LON,
        },
        depth_m: Some(depth),
        altitude_m: None,
        speed_mps: speed,
    }
}

#[tokio::test]
async fn telemetry_becomes_a_valid_state_vector() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    assert!(adapter.state().is_none());
    v.heartbeat(sub_mode::MANUAL, true).await;
    v.position(LAT, LON, 12.345).await;
    v.battery(73).await;
    let s = eventually("a state vector", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    assert_eq!(s.vehicle_id, "rov-3");
    assert!((s.latitude_deg - LAT).abs() < 1e-7 && (s.longitude_deg - LON).abs() < 1e-7);
    assert!((s.depth_m - 12.345).abs() < 1e-9);
    assert_eq!(s.speed_mps, 0.5, "from vx, vy in cm/s without VFR_HUD");
    assert_eq!(s.yaw_deg, 90.0, "from hdg without ATTITUDE");
    assert_eq!(s.battery_pct, 73.0);
    v.send(MavMessage::ATTITUDE(ATTITUDE_DATA {
        roll: 0.1,
        pitch: -0.2,
        yaw: -1.0,
        ..ATTITUDE_DATA::default()
    }))
    .await;
    v.send(MavMessage::VFR_HUD(VFR_HUD_DATA {
        groundspeed: 0.75,
        ..VFR_HUD_DATA::default()
    }))
    .await;
    let s = eventually("the attitude", || {
        adapter.state().filter(|s| s.speed_mps == 0.75)
    })
    .await;
    assert!((s.roll_deg - 5.729_578).abs() < 1e-4);
    assert!((s.pitch_deg + 11.459_156).abs() < 1e-4);
    assert!((s.yaw_deg - 302.704_22).abs() < 1e-3, "{}", s.yaw_deg);
    assert_eq!(s.validate(), Ok(()));
    assert_eq!(adapter.mode(), Some((sub_mode::MANUAL, true)));
    // The proxy heartbeats as a GCS and asks for the telemetry streams.
    let sent = v.drain(300).await;
    assert!(
        sent.iter()
            .any(|m| matches!(m, MavMessage::HEARTBEAT(h) if h.mavtype == MavType::MAV_TYPE_GCS))
    );
    assert!(sent.iter().any(|m| matches!(m, MavMessage::REQUEST_DATA_STREAM(r) if r.target_system == 1 && r.start_stop == 1)));
}

#[tokio::test]
async fn bad_frames_are_counted_and_dropped() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    v.send_raw(b"NMEA,not,mavlink").await;
    let mut bad = v.frame(&MavMessage::SYS_STATUS(SYS_STATUS_DATA {
        battery_remaining: 5,
        ..SYS_STATUS_DATA::default()
    }));
    let n = bad.len();
    bad[n - 1] ^= 0xFF;
    v.send_raw(&bad).await;
    let mut unknown = v.frame(&MavMessage::SYS_STATUS(SYS_STATUS_DATA::default()));
    unknown[7] = 0x33;
    unknown[8] = 0xEA;
    v.send_raw(&unknown).await;
    v.position(95.0, LON, 1.0).await;
    v.battery(120).await;
    let c = eventually("the counters", || {
        let c = adapter.counters();
        (c.out_of_range >= 2).then_some(c)
    })
    .await;
    assert!(c.garbage_bytes >= 16, "{c:?}");
    assert_eq!(
        (c.bad_crc, c.unknown_message, c.out_of_range),
        (1, 1, 2),
        "{c:?}"
    );
    let s = adapter.state().unwrap();
    assert!((s.latitude_deg - LAT).abs() < 1e-7 && s.battery_pct == 80.0);
    // A MAVLink 1 frame is still understood.
    let mut v1 = Vec::new();
    mavlink::write_v1_msg(
        &mut v1,
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        },
        &MavMessage::SYS_STATUS(SYS_STATUS_DATA {
            battery_remaining: 61,
            ..SYS_STATUS_DATA::default()
        }),
    )
    .unwrap();
    v.send_raw(&v1).await;
    eventually("the v1 battery", || {
        adapter.state().filter(|s| s.battery_pct == 61.0)
    })
    .await;
    assert_eq!(adapter.counters().v1_frames, 1);
}

#[tokio::test]
async fn other_systems_and_gcs_heartbeats_are_ignored() {
    let (adapter, mut v) = setup(|_| {}).await;
    v.send(MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        mavtype: MavType::MAV_TYPE_GCS,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        ..HEARTBEAT_DATA::default()
    }))
    .await;
    v.position(LAT, LON, 1.0).await;
    eventually("two foreign frames", || {
        (adapter.counters().foreign == 2).then_some(())
    })
    .await;
    assert!(!adapter.is_connected());
}

#[tokio::test]
async fn a_goto_is_guided_mode_then_a_position_target_and_ends_on_arrival() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    adapter
        .submit(order("g1", goto_task(6.0, 0.8)))
        .await
        .unwrap();
    let MavMessage::COMMAND_LONG(c) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    assert_eq!(c.command, MavCmd::MAV_CMD_DO_SET_MODE);
    assert_eq!((c.param1, c.param2), (1.0, 4.0), "custom mode GUIDED");
    assert_eq!((c.target_system, c.target_component), (1, 1));
    v.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED)
        .await;
    let MavMessage::COMMAND_LONG(c) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    assert_eq!(c.command, MavCmd::MAV_CMD_DO_CHANGE_SPEED);
    assert_eq!(c.param2, 0.8);
    v.ack(
        MavCmd::MAV_CMD_DO_CHANGE_SPEED,
        MavResult::MAV_RESULT_UNSUPPORTED,
    )
    .await;
    let MavMessage::SET_POSITION_TARGET_GLOBAL_INT(t) = v.expect().await else {
        panic!("expected SET_POSITION_TARGET_GLOBAL_INT");
    };
    assert_eq!(t.lat_int, mapping::e7_from_deg(LAT + 0.0002));
    assert_eq!(t.lon_int, mapping::e7_from_deg(LON));
    assert_eq!(t.alt, -6.0, "6 m below the surface");
    assert_eq!(t.coordinate_frame, MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT);
    assert_eq!(t.type_mask.bits(), 0x0DF8);
    let u = next_task(&mut adapter).await;
    assert_eq!((u.task_id.as_str(), u.state), ("g1", TaskState::Running));
    v.heartbeat(sub_mode::GUIDED, true).await;
    v.position(LAT + 0.0001, LON, 5.0).await;
    let u = next_task(&mut adapter).await;
    assert_eq!(u.state, TaskState::Running);
    assert!((40.0..60.0).contains(&u.progress_pct), "{u:?}");
    v.position(LAT + 0.0002, LON, 6.2).await;
    let u = next_task(&mut adapter).await;
    assert_eq!((u.state, u.message.as_str()), (TaskState::Done, "arrived"));
}

#[tokio::test]
async fn a_rejected_mode_change_fails_the_task() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    adapter
        .submit(order("g2", goto_task(2.0, 0.0)))
        .await
        .unwrap();
    let MavMessage::COMMAND_LONG(_) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    v.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_DENIED)
        .await;
    let u = next_task(&mut adapter).await;
    assert_eq!(u.state, TaskState::Failed);
    assert_eq!(u.message, "the vehicle rejected DO_SET_MODE: DENIED");
}

#[tokio::test]
async fn an_unacknowledged_command_is_resent_then_fails() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    adapter
        .submit(order("g3", goto_task(2.0, 0.0)))
        .await
        .unwrap();
    for _ in 0..3 {
        let MavMessage::COMMAND_LONG(c) = v.expect().await else {
            panic!("expected COMMAND_LONG");
        };
        assert_eq!(c.command, MavCmd::MAV_CMD_DO_SET_MODE);
        // Keep the link alive, without answering.
        v.heartbeat(sub_mode::MANUAL, true).await;
    }
    let u = next_task(&mut adapter).await;
    assert_eq!(u.state, TaskState::Failed);
    assert_eq!(
        u.message,
        "no answer from the vehicle to COMMAND_ACK for DO_SET_MODE (3 attempts)"
    );
}

#[tokio::test]
async fn a_survey_is_uploaded_as_a_mission_and_run_in_auto() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    let p = |lat: f64, lon: f64| GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    let task = Task::SurveyArea {
        polygon: vec![
            p(LAT, LON),
            p(LAT, LON + 0.0005),
            p(LAT + 0.0003, LON + 0.0005),
            p(LAT + 0.0003, LON),
        ],
        line_spacing_m: 15.0,
        depth_m: Some(4.0),
        altitude_m: None,
        speed_mps: 0.5,
    };
    adapter.submit(order("s1", task)).await.unwrap();
    let MavMessage::MISSION_COUNT(count) = v.expect().await else {
        panic!("expected MISSION_COUNT");
    };
    // 33 m north-south at 15 m: 3 lines of 2 points, after home and the speed change.
    assert_eq!(count.count, 8);
    let mut items = Vec::new();
    for seq in 0..count.count {
        v.send(MavMessage::MISSION_REQUEST_INT(MISSION_REQUEST_INT_DATA {
            seq,
            target_system: 255,
            target_component: GCS_COMPONENT,
        }))
        .await;
        let MavMessage::MISSION_ITEM_INT(item) = v.expect().await else {
            panic!("expected MISSION_ITEM_INT");
        };
        assert_eq!(item.seq, seq);
        items.push(item);
    }
    assert_eq!(items[1].command, MavCmd::MAV_CMD_DO_CHANGE_SPEED);
    assert_eq!(items[1].param2, 0.5);
    for it in &items[2..] {
        assert_eq!(it.command, MavCmd::MAV_CMD_NAV_WAYPOINT);
        assert_eq!(it.frame, MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT);
        assert_eq!(it.z, -4.0);
    }
    assert!(
        (items[2].x - mapping::e7_from_deg(LAT + 0.0003 / 6.0)).abs() <= 1,
        "{}",
        items[2].x
    );
    v.send(MavMessage::MISSION_ACK(MISSION_ACK_DATA {
        target_system: 255,
        target_component: GCS_COMPONENT,
        mavtype: MavMissionResult::MAV_MISSION_ACCEPTED,
    }))
    .await;
    let MavMessage::COMMAND_LONG(c) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    assert_eq!(
        (c.command, c.param2),
        (MavCmd::MAV_CMD_DO_SET_MODE, 3.0),
        "AUTO"
    );
    v.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED)
        .await;
    assert_eq!(next_task(&mut adapter).await.state, TaskState::Running);
    v.send(MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA { seq: 5 }))
        .await;
    let u = next_task(&mut adapter).await;
    assert_eq!(
        (u.state, u.progress_pct),
        (TaskState::Running, 50.0),
        "3 of 6 waypoints"
    );
    v.send(MavMessage::MISSION_ITEM_REACHED(
        MISSION_ITEM_REACHED_DATA { seq: 7 },
    ))
    .await;
    let u = next_task(&mut adapter).await;
    assert_eq!(
        (u.state, u.message.as_str()),
        (TaskState::Done, "mission complete")
    );
}

#[tokio::test]
async fn the_pilot_taking_over_aborts_the_task() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    adapter
        .submit(order("h1", Task::Hold { duration_s: 0.0 }))
        .await
        .unwrap();
    let MavMessage::COMMAND_LONG(c) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    assert_eq!(c.param2, 16.0, "POSHOLD");
    v.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED)
        .await;
    assert_eq!(next_task(&mut adapter).await.state, TaskState::Running);
    v.heartbeat(sub_mode::POSHOLD, true).await;
    v.heartbeat(sub_mode::MANUAL, true).await;
    let u = next_task(&mut adapter).await;
    assert_eq!(
        (u.state, u.message.as_str()),
        (TaskState::Aborted, "the vehicle left POSHOLD for MANUAL")
    );
}

#[tokio::test]
async fn abort_surfaces_and_aborts_the_running_task() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    adapter
        .submit(order("g", goto_task(6.0, 0.0)))
        .await
        .unwrap();
    let _ = v.expect().await;
    v.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED)
        .await;
    let _ = v.expect().await;
    assert_eq!(next_task(&mut adapter).await.state, TaskState::Running);
    adapter.submit(order("stop", Task::Abort)).await.unwrap();
    let u = next_task(&mut adapter).await;
    assert_eq!(
        (u.task_id.as_str(), u.state, u.message.as_str()),
        ("g", TaskState::Aborted, "aborted by task stop")
    );
    let MavMessage::COMMAND_LONG(c) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    assert_eq!(c.param2, 9.0, "SURFACE");
    v.ack(MavCmd::MAV_CMD_DO_SET_MODE, MavResult::MAV_RESULT_ACCEPTED)
        .await;
    assert_eq!(next_task(&mut adapter).await.state, TaskState::Running);
    v.position(LAT, LON, 0.1).await;
    let u = next_task(&mut adapter).await;
    assert_eq!(
        (u.task_id.as_str(), u.state, u.message.as_str()),
        ("stop", TaskState::Done, "at the surface")
    );
}

#[tokio::test]
async fn refusals_say_why() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    let r = adapter
        .submit(order("a", goto_task(1.0, 0.0)))
        .await
        .unwrap_err();
    assert_eq!(r.reason, "no contact with the vehicle over MAVLink");
    v.heartbeat(sub_mode::MANUAL, false).await;
    v.position(LAT, LON, 1.0).await;
    eventually("contact", || adapter.is_connected().then_some(())).await;
    eventually("the position", || {
        lock(&adapter.shared).position.map(|_| ())
    })
    .await;
    let r = adapter
        .submit(order("b", goto_task(1.0, 0.0)))
        .await
        .unwrap_err();
    assert_eq!(r.reason, "the vehicle is disarmed and auto_arm is off");
    let r = adapter
        .submit(order("c", Task::ReturnHome))
        .await
        .unwrap_err();
    assert_eq!(r.reason, "ArduSub has no return-to-launch mode");
    // Surfacing needs no arming.
    assert!(adapter.submit(order("d", Task::Surface)).await.is_ok());
}

#[tokio::test]
async fn auto_arm_arms_before_moving() {
    let (mut adapter, mut v) = setup(|c| c.auto_arm = true).await;
    v.heartbeat(sub_mode::MANUAL, false).await;
    v.position(LAT, LON, 1.0).await;
    eventually("the position", || {
        lock(&adapter.shared).position.map(|_| ())
    })
    .await;
    adapter
        .submit(order("g", goto_task(1.0, 0.0)))
        .await
        .unwrap();
    let MavMessage::COMMAND_LONG(c) = v.expect().await else {
        panic!("expected COMMAND_LONG");
    };
    assert_eq!(
        (c.command, c.param1),
        (MavCmd::MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
    );
}

#[tokio::test]
async fn statustext_becomes_an_event() {
    let (mut adapter, mut v) = setup(|_| {}).await;
    online(&mut adapter, &mut v).await;
    v.send(MavMessage::STATUSTEXT(STATUSTEXT_DATA {
        severity: MavSeverity::MAV_SEVERITY_CRITICAL,
        text: "Leak Detected".into(),
    }))
    .await;
    let e = next_event(&mut adapter, EventKind::Fault).await;
    assert_eq!(
        (e.severity, e.text.as_str()),
        (Severity::Critical, "Leak Detected")
    );
}

#[tokio::test]
async fn silence_is_lost_and_a_vehicle_on_a_new_port_is_picked_up() {
    // Well above the 400 ms the test listens to the restarted vehicle below, so a loaded
    // machine cannot declare it lost again before the last check.
    let (mut adapter, mut v) = setup(|c| c.lost_after_ms = 1500).await;
    online(&mut adapter, &mut v).await;
    let e = next_event(&mut adapter, EventKind::CommLost).await;
    assert_eq!(e.severity, Severity::Alarm);
    assert!(adapter.state().is_none());
    // The vehicle restarts: a new socket, a new source port.
    let mut v2 = FakeVehicle::new(adapter.local_addr()).await;
    v2.heartbeat(sub_mode::MANUAL, true).await;
    let e = next_event(&mut adapter, EventKind::CommLost).await;
    assert_eq!(e.severity, Severity::Info);
    assert!(e.text.starts_with("MAVLink link restored"));
    let sent = v2.drain(400).await;
    assert!(
        sent.iter()
            .any(|m| matches!(m, MavMessage::REQUEST_DATA_STREAM(_))),
        "the streams are asked for again, at the new address"
    );
    assert!(sent.iter().any(|m| m.message_name() == "HEARTBEAT"));
    assert!(adapter.state().is_some());
}

#[test]
fn addresses_and_config() {
    assert_eq!(
        "udpin:127.0.0.1:14550".parse::<Endpoint>().unwrap(),
        Endpoint::In("127.0.0.1:14550".parse().unwrap())
    );
    assert_eq!(
        "udpout:127.0.0.1:14555".parse::<Endpoint>().unwrap(),
        Endpoint::Out("127.0.0.1:14555".parse().unwrap())
    );
    assert!("tcp:127.0.0.1:5760".parse::<Endpoint>().is_err());
    assert!("udpin:localhost:14550".parse::<Endpoint>().is_err());
    let c: MavlinkConfig =
        serde_json::from_str(r#"{"address": "udpout:127.0.0.1:14551", "vehicle_id": "br2"}"#)
            .unwrap();
    assert_eq!(c.system_id, 255);
    assert!(serde_json::from_str::<MavlinkConfig>(r#"{"adress": "x"}"#).is_err());
    assert!(check(&MavlinkConfig::default()).is_ok());
    assert!(
        check(&MavlinkConfig {
            address: "serial:/dev/ttyACM0".into(),
            ..MavlinkConfig::default()
        })
        .is_err()
    );
}

#[test]
fn mission_items_start_with_home_and_carry_the_depth() {
    let home = GeoPoint {
        latitude_deg: LAT,
        longitude_deg: LON,
    };
    let pts = [home, home];
    let items = mission_items(home, &pts, None, Some(3.0), 0.0, 2.0);
    assert_eq!(items.len(), 3, "no speed item without a speed");
    assert_eq!(items[0].frame, MavFrame::MAV_FRAME_GLOBAL);
    assert_eq!(items[1].frame, MavFrame::MAV_FRAME_GLOBAL_TERRAIN_ALT);
    assert_eq!((items[1].z, items[1].param2), (3.0, 2.0));
    assert_eq!(items.iter().map(|i| i.seq).collect::<Vec<_>>(), [0, 1, 2]);
}
