//! Tests of the simulated vehicle, one group per behaviour; all deterministic (fixed steps,
//! seeded detections).

use super::*;
use shoal_model::{EnvironmentObservation, Validate};

const T0: i64 = 1_700_000_000_000;

fn p(lat: f64, lon: f64) -> GeoPoint {
    GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    }
}

fn spec(kind: VehicleKind, battery_pct: f64) -> SimSpec {
    SimSpec {
        id: format!("{kind}-1"),
        kind,
        latitude_deg: 43.0,
        longitude_deg: 5.9,
        rate_hz: 1.0,
        battery_pct,
    }
}

/// No environment samples and no detections, so outputs are only what a test looks at.
fn quiet() -> SimSettings {
    SimSettings {
        environment_hz: 0.0,
        detection_per_s: 0.0,
        ..SimSettings::default()
    }
}

fn vehicle(kind: VehicleKind, battery_pct: f64) -> SimVehicle {
    SimVehicle::with_settings(&spec(kind, battery_pct), &quiet(), T0)
}

fn auv() -> SimVehicle {
    vehicle(VehicleKind::Auv, 100.0)
}

fn order(id: &str, issued_ms: i64, task: Task) -> TaskOrder {
    TaskOrder {
        task_id: id.into(),
        mission_id: String::new(),
        issued_ms,
        task,
    }
}

fn goto(target: GeoPoint, depth_m: f64, speed_mps: f64) -> Task {
    Task::GotoWaypoint {
        target,
        depth_m: Some(depth_m),
        altitude_m: None,
        speed_mps,
    }
}

fn survey(polygon: Vec<GeoPoint>, spacing: f64, depth_m: f64) -> Task {
    Task::SurveyArea {
        polygon,
        line_spacing_m: spacing,
        depth_m: Some(depth_m),
        altitude_m: None,
        speed_mps: 1.5,
    }
}

/// A north-aligned rectangle `east_m` by `north_m` with its south-west corner at `sw`.
fn rectangle(sw: GeoPoint, east_m: f64, north_m: f64) -> Vec<GeoPoint> {
    let frame = shoal_model::geo::LocalFrame::new(sw);
    vec![
        sw,
        frame.to_geo(east_m, 0.0),
        frame.to_geo(east_m, north_m),
        frame.to_geo(0.0, north_m),
    ]
}

/// Steps 0.1 s at a time until task `id` ends or `max_s` pass: when it ended, and every
/// output (including those queued before the call).
fn run_until_final(v: &mut SimVehicle, id: &str, max_s: f64) -> (Option<f64>, Vec<VehicleOutput>) {
    let mut out = v.drain_outputs();
    let steps = (max_s * 10.0).round() as usize;
    for i in 1..=steps {
        v.step(0.1);
        let new = v.drain_outputs();
        let ended = new
            .iter()
            .any(|o| matches!(o, VehicleOutput::Task(u) if u.task_id == id && u.state.is_final()));
        out.extend(new);
        if ended {
            return (Some(i as f64 / 10.0), out);
        }
    }
    (None, out)
}

fn run_for(v: &mut SimVehicle, seconds: f64) -> Vec<VehicleOutput> {
    run_until_final(v, "\u{0}none", seconds).1
}

fn updates<'a>(out: &'a [VehicleOutput], id: &str) -> Vec<&'a TaskUpdate> {
    out.iter()
        .filter_map(|o| match o {
            VehicleOutput::Task(u) if u.task_id == id => Some(u),
            _ => None,
        })
        .collect()
}

fn final_update<'a>(out: &'a [VehicleOutput], id: &str) -> &'a TaskUpdate {
    updates(out, id)
        .into_iter()
        .find(|u| u.state.is_final())
        .unwrap_or_else(|| panic!("{id} never ended: {out:?}"))
}

fn events(out: &[VehicleOutput], kind: EventKind) -> Vec<&VehicleEvent> {
    out.iter()
        .filter_map(|o| match o {
            VehicleOutput::Event(e) if e.kind == kind => Some(e),
            _ => None,
        })
        .collect()
}

// --- Motion -------------------------------------------------------------------------------

#[test]
fn announcement_and_every_state_are_valid() {
    let mut v = auv();
    assert_eq!(v.announcement.validate(), Ok(()));
    v.submit(&order("t", T0, goto(p(43.001, 5.901), 20.0, 1.5)))
        .unwrap();
    for _ in 0..2000 {
        v.step(0.1);
        assert_eq!(v.state(v.clock_ms()).validate(), Ok(()));
    }
    assert!(v.state(v.clock_ms()).pitch_deg.abs() <= 30.0);
}

#[test]
fn goto_reaches_the_waypoint_at_the_expected_time() {
    let mut v = auv();
    let target = p(43.002, 5.9); // 222.4 m due north, the way the vehicle faces
    let d = distance(v.position(), target);
    let accepted = v.submit(&order("t1", T0, goto(target, 10.0, 2.0))).unwrap();
    assert_eq!(accepted.message, "");
    let (ended, out) = run_until_final(&mut v, "t1", 600.0);
    let ended = ended.unwrap();
    // At 2 m/s to within the arrival radius, plus about one 2 s time constant to speed up.
    let expected = (d - ARRIVAL_RADIUS_M) / 2.0 + 2.0;
    assert!(
        (ended - expected).abs() < 3.0,
        "done after {ended} s, expected {expected}"
    );
    let done = final_update(&out, "t1");
    assert_eq!((done.state, done.progress_pct), (TaskState::Done, 100.0));
    assert!(distance(v.position(), target) <= ARRIVAL_RADIUS_M + 0.5);
    assert!((v.depth_m() - 10.0).abs() <= DEPTH_TOLERANCE_M);
}

#[test]
fn goto_behind_the_vehicle_turns_and_arrives_no_sooner_than_its_speed_allows() {
    let mut v = auv();
    let target = p(42.999, 5.9015); // south-east: a turn of about 130° first
    let d = distance(v.position(), target);
    v.submit(&order("t", T0, goto(target, 5.0, 1.5))).unwrap();
    let (ended, _) = run_until_final(&mut v, "t", 600.0);
    let ended = ended.unwrap();
    let straight = (d - ARRIVAL_RADIUS_M) / 1.5;
    assert!(
        ended > straight && ended < straight + 40.0,
        "{ended} s vs {straight} s"
    );
}

#[test]
fn dives_and_surfaces_at_the_vertical_rate() {
    let mut v = auv();
    let here = v.position();
    v.submit(&order("dive", T0, goto(here, 30.0, 1.0))).unwrap();
    let mut last = v.depth_m();
    let mut t = 0.0_f64;
    while v.current_task() == Some("dive") {
        v.step(0.1);
        t += 0.1;
        assert!(
            v.depth_m() - last <= 0.5 * 0.1 + 1e-9,
            "faster than 0.5 m/s"
        );
        last = v.depth_m();
        assert!(t < 120.0, "never reached 30 m");
    }
    // 29.5 m (the depth tolerance) at 0.5 m/s.
    assert!((t - 59.0).abs() < 1.5, "dive took {t} s");
    v.drain_outputs();
    v.submit(&order("up", T0, Task::Surface)).unwrap();
    let (ended, out) = run_until_final(&mut v, "up", 200.0);
    assert!((ended.unwrap() - 60.0).abs() < 2.0, "{ended:?}");
    assert_eq!(v.depth_m(), 0.0);
    assert_eq!(final_update(&out, "up").message, "at the surface");
}

#[test]
fn altitude_is_kept_above_the_seabed() {
    let mut v = auv();
    let here = v.position();
    let task = Task::GotoWaypoint {
        target: here,
        depth_m: None,
        altitude_m: Some(10.0),
        speed_mps: 1.0,
    };
    v.submit(&order("t", T0, task)).unwrap();
    run_until_final(&mut v, "t", 400.0).0.unwrap();
    let s = v.state(v.clock_ms());
    assert!((s.altitude_m - 10.0).abs() <= DEPTH_TOLERANCE_M, "{s:?}");
}

#[test]
fn survey_flies_every_line_and_covers_the_polygon() {
    let mut v = auv();
    let poly = rectangle(p(43.0005, 5.9), 200.0, 100.0);
    let spacing = 25.0;
    let lines = lawnmower(&poly, spacing).unwrap();
    let path = path_length(v.position(), &lines);
    v.submit(&order("s", T0, survey(poly.clone(), spacing, 5.0)))
        .unwrap();
    let mut track = vec![v.position()];
    let mut out = v.drain_outputs();
    let mut t = 0.0;
    while v.current_task() == Some("s") {
        v.step(0.1);
        t += 0.1;
        track.push(v.position());
        out.extend(v.drain_outputs());
        assert!(t < 3000.0, "survey never finished");
    }
    // No faster than the path at 1.5 m/s, less the corners cut at each waypoint.
    let shortest = (path - ARRIVAL_RADIUS_M * lines.len() as f64) / 1.5;
    assert!(t > shortest, "{t} s for {path} m at 1.5 m/s");
    assert_eq!(final_update(&out, "s").message, "survey complete");
    // Progress rises through the deciles to done.
    let progress: Vec<f64> = updates(&out, "s").iter().map(|u| u.progress_pct).collect();
    assert!(progress.windows(2).all(|w| w[0] <= w[1]), "{progress:?}");
    assert!(progress.len() >= 10, "{progress:?}");
    // Every point of the polygon passed within half a line spacing (plus the arrival
    // radius, where the vehicle turns early at the line ends).
    let frame = shoal_model::geo::LocalFrame::new(poly[0]);
    let track: Vec<(f64, f64)> = track.iter().map(|q| frame.to_xy(*q)).collect();
    for i in 0..=20 {
        for j in 0..=10 {
            let (x, y) = (f64::from(i) * 10.0, f64::from(j) * 10.0);
            let near = track
                .iter()
                .map(|(tx, ty)| (tx - x).hypot(ty - y))
                .fold(f64::MAX, f64::min);
            assert!(
                near <= spacing / 2.0 + ARRIVAL_RADIUS_M + 1.0,
                "({x}, {y}) missed by {near:.1} m"
            );
        }
    }
}

#[test]
fn hold_lasts_its_duration_in_place() {
    let mut v = auv();
    let start = v.position();
    v.submit(&order("h", T0, Task::Hold { duration_s: 60.0 }))
        .unwrap();
    let (ended, out) = run_until_final(&mut v, "h", 120.0);
    assert!((ended.unwrap() - 60.0).abs() <= 0.15, "{ended:?}");
    assert_eq!(final_update(&out, "h").state, TaskState::Done);
    assert!(distance(start, v.position()) < 0.01);
    let halfway: Vec<f64> = updates(&out, "h").iter().map(|u| u.progress_pct).collect();
    assert!(
        halfway.iter().any(|p| (50.0..51.0).contains(p)),
        "{halfway:?}"
    );
}

#[test]
fn open_ended_hold_lasts_until_the_next_task() {
    let mut v = auv();
    v.submit(&order("h", T0, Task::Hold { duration_s: 0.0 }))
        .unwrap();
    let out = run_for(&mut v, 3600.0);
    assert!(updates(&out, "h").iter().all(|u| !u.state.is_final()));
    let acc = v.submit(&order("next", T0 + 1, Task::Surface)).unwrap();
    assert_eq!(acc.message, "", "the hold gives way, nothing is queued");
    let out = v.drain_outputs();
    assert_eq!(final_update(&out, "h").message, "held until next started");
    assert_eq!(v.current_task(), Some("next"));
}

#[test]
fn return_home_comes_back_to_the_start_at_the_surface() {
    let mut v = auv();
    let home = v.position();
    v.submit(&order("out", T0, goto(p(43.0, 5.904), 15.0, 2.0)))
        .unwrap();
    v.submit(&order("home", T0 + 1, Task::ReturnHome)).unwrap();
    let (ended, out) = run_until_final(&mut v, "home", 1200.0);
    assert!(ended.is_some());
    assert_eq!(final_update(&out, "out").state, TaskState::Done);
    assert_eq!(final_update(&out, "home").message, "home");
    assert!(distance(v.position(), home) <= ARRIVAL_RADIUS_M + 0.5);
    assert_eq!(v.depth_m(), 0.0);
}

#[test]
fn surface_craft_stay_at_the_surface() {
    let mut v = vehicle(VehicleKind::Usv, 50.0);
    v.submit(&order("t", T0, goto(p(43.001, 5.9), 30.0, 1.0)))
        .unwrap();
    run_for(&mut v, 30.0);
    assert_eq!(v.depth_m(), 0.0);
    assert_eq!(v.state(T0).altitude_m, UNKNOWN);
    let refused = v.submit(&order("s", T0, Task::Surface)).unwrap_err();
    assert!(
        refused.reason.contains("no surface capability"),
        "{refused}"
    );
}

#[test]
fn bad_time_steps_change_nothing() {
    let mut v = auv();
    let before = v.state(T0);
    for dt in [f64::NAN, -1.0, 0.0, f64::NEG_INFINITY, f64::INFINITY] {
        v.step(dt);
    }
    assert_eq!(v.state(T0), before);
    assert_eq!(v.clock_ms(), T0);
}

// --- Tasks ------------------------------------------------------------------------------

#[test]
fn tasks_queue_in_issue_order() {
    let mut v = auv();
    let here = v.position();
    v.submit(&order("x", 10, goto(here, 2.0, 1.0))).unwrap();
    let a = v
        .submit(&order("a", 30, Task::Hold { duration_s: 5.0 }))
        .unwrap();
    assert_eq!(a.message, "queued behind 1 task(s)");
    // Issued before `a` though it arrived after: it runs before `a`.
    let b = v
        .submit(&order("b", 20, Task::Hold { duration_s: 5.0 }))
        .unwrap();
    assert_eq!(b.message, "queued behind 1 task(s)");
    assert_eq!(v.queued_tasks().collect::<Vec<_>>(), ["b", "a"]);
    let (ended, out) = run_until_final(&mut v, "a", 200.0);
    assert!(ended.is_some());
    let started: Vec<&str> = out
        .iter()
        .filter_map(|o| match o {
            VehicleOutput::Task(u) if u.state == TaskState::Running && u.progress_pct == 0.0 => {
                Some(u.task_id.as_str())
            }
            _ => None,
        })
        .collect();
    assert_eq!(started, ["x", "b", "a"]);
}

#[test]
fn speeds_above_the_maximum_are_limited_and_said_so() {
    let mut v = auv();
    let acc = v
        .submit(&order("t", T0, goto(p(43.01, 5.9), 5.0, 9.0)))
        .unwrap();
    assert_eq!(acc.message, "speed limited to 2.5 m/s");
    run_for(&mut v, 30.0);
    assert!(v.state(T0).speed_mps <= 2.5);
}

#[test]
fn tasks_the_vehicle_cannot_do_are_refused_with_the_reason() {
    let mut rov = vehicle(VehicleKind::Rov, 100.0);
    let poly = rectangle(p(43.0, 5.9), 100.0, 100.0);
    let r = rov
        .submit(&order("s", T0, survey(poly, 10.0, 5.0)))
        .unwrap_err();
    assert_eq!(r.reason, "a simulated rov has no survey capability");

    let mut v = auv();
    let r = v
        .submit(&order("deep", T0, goto(p(43.001, 5.9), 100.0, 1.0)))
        .unwrap_err();
    assert!(r.reason.contains("below the seabed"), "{r}");
    let big = rectangle(p(43.0, 5.9), 100.0, 5000.0);
    let r = v
        .submit(&order("big", T0, survey(big, 1.0, 5.0)))
        .unwrap_err();
    assert!(r.reason.contains("more than the 1000 allowed"), "{r}");
    let r = v.submit(&order("rs", T0, Task::RequestState)).unwrap_err();
    assert!(r.reason.contains("served by the DDS proxy"), "{r}");
    assert_eq!(v.current_task(), None);
    assert!(
        v.drain_outputs().is_empty(),
        "a refusal reports nothing by itself"
    );
}

#[test]
fn abort_aborts_the_running_and_queued_tasks_and_surfaces() {
    let mut v = auv();
    v.depth = 20.0;
    v.submit(&order("g", T0, goto(p(43.01, 5.9), 20.0, 1.5)))
        .unwrap();
    let poly = rectangle(p(43.0, 5.9), 100.0, 100.0);
    v.submit(&order("s", T0 + 1, survey(poly, 20.0, 5.0)))
        .unwrap();
    v.submit(&order("h", T0 + 2, Task::Hold { duration_s: 10.0 }))
        .unwrap();
    run_for(&mut v, 10.0);
    let acc = v.submit(&order("abort-1", T0 + 3, Task::Abort)).unwrap();
    assert_eq!(acc.message, "emergency surface; 3 task(s) aborted");
    assert_eq!(v.queued_tasks().count(), 0);
    assert_eq!(v.current_task(), Some("abort-1"));
    let (ended, out) = run_until_final(&mut v, "abort-1", 200.0);
    for id in ["g", "s", "h"] {
        let u = final_update(&out, id);
        assert_eq!(u.state, TaskState::Aborted);
        assert_eq!(u.message, "aborted by abort-1 (emergency surface)");
    }
    assert!(ended.unwrap() <= 20.0 / 0.5 + 1.0);
    assert_eq!(final_update(&out, "abort-1").state, TaskState::Done);
    assert_eq!(v.depth_m(), 0.0);
}

#[test]
fn abort_stops_a_surface_craft() {
    let mut v = vehicle(VehicleKind::Usv, 100.0);
    v.submit(&order("g", T0, goto(p(43.01, 5.9), 0.0, 3.0)))
        .unwrap();
    run_for(&mut v, 30.0);
    assert!(v.state(T0).speed_mps > 2.0);
    v.submit(&order("stop", T0, Task::Abort)).unwrap();
    let (ended, out) = run_until_final(&mut v, "stop", 60.0);
    assert!(ended.is_some());
    assert_eq!(final_update(&out, "g").state, TaskState::Aborted);
    assert_eq!(final_update(&out, "stop").message, "stopped");
    assert!(v.state(T0).speed_mps < 0.05);
}

// --- Battery ----------------------------------------------------------------------------

#[test]
fn battery_drains_faster_at_speed() {
    let mut resting = auv();
    run_for(&mut resting, 600.0);
    let mut moving = auv();
    moving
        .submit(&order("t", T0, goto(p(43.1, 5.9), 5.0, 2.5)))
        .unwrap();
    run_for(&mut moving, 600.0);
    // Hotel only: 2 %/h for 10 min.
    assert!((resting.battery_pct() - (100.0 - 2.0 / 6.0)).abs() < 1e-6);
    assert!(moving.battery_pct() < resting.battery_pct() - 3.0);
}

#[test]
fn refuses_a_task_it_cannot_finish_above_the_reserve() {
    let mut v = vehicle(VehicleKind::Auv, 15.0);
    let far = goto(p(43.09, 5.9), 5.0, 2.5); // 10 km at full speed: about 24 %
    let r = v.submit(&order("far", T0, far)).unwrap_err();
    assert!(
        r.reason.starts_with(
            "needs about 26.9 % of battery, but only 5.0 % is left above the 10 % reserve"
        ),
        "{r}"
    );
    // 3 km at cruise speed needs about 3.9 %: one leg fits above the reserve, two do not.
    let one = goto(p(43.027, 5.9), 5.0, 0.0);
    v.submit(&order("one", T0, one)).unwrap();
    let two = goto(p(43.054, 5.9), 5.0, 0.0);
    let r = v.submit(&order("two", T0 + 1, two)).unwrap_err();
    assert!(r.reason.contains("after the 1 task(s) ahead of it"), "{r}");
    // Coming home may use the reserve; that is what it is for.
    assert!(v.submit(&order("home", T0 + 2, Task::ReturnHome)).is_ok());
}

#[test]
fn running_tasks_fail_when_the_battery_reaches_the_reserve() {
    let mut v = vehicle(VehicleKind::Auv, 60.0);
    v.depth = 20.0;
    let poly = rectangle(p(43.0, 5.9), 500.0, 500.0);
    v.submit(&order("s", T0, survey(poly, 25.0, 20.0))).unwrap();
    v.submit(&order("g", T0 + 1, goto(p(43.001, 5.9), 5.0, 1.0)))
        .unwrap();
    v.submit(&order("up", T0 + 2, Task::Surface)).unwrap();
    run_for(&mut v, 10.0);
    // A failing cell: the battery drops to just above the reserve.
    v.battery = 10.01;
    let (ended, out) = run_until_final(&mut v, "s", 60.0);
    assert!(ended.is_some());
    let failed = final_update(&out, "s");
    assert_eq!(failed.state, TaskState::Failed);
    assert_eq!(failed.message, "battery at its 10 % reserve");
    assert_eq!(final_update(&out, "g").state, TaskState::Failed);
    let alarm = events(&out, EventKind::LowBattery)
        .into_iter()
        .find(|e| e.severity == Severity::Alarm)
        .expect("an alarm at the reserve");
    assert_eq!(
        alarm.text,
        "battery at its 10 % reserve: 2 task(s) failed, surfacing"
    );
    // Surfacing is a safety task: it stays and runs.
    let (ended, out) = run_until_final(&mut v, "up", 120.0);
    assert!(ended.is_some());
    assert_eq!(final_update(&out, "up").state, TaskState::Done);
    assert_eq!(v.depth_m(), 0.0);
    let r = v
        .submit(&order("more", T0 + 3, goto(p(43.001, 5.9), 5.0, 1.0)))
        .unwrap_err();
    assert!(r.reason.starts_with("battery at its 10 % reserve"), "{r}");
}

#[test]
fn an_open_ended_hold_fails_at_the_reserve_and_the_vehicle_surfaces() {
    let mut v = vehicle(VehicleKind::Auv, 10.02);
    v.depth = 20.0;
    v.submit(&order("h", T0, Task::Hold { duration_s: 0.0 }))
        .unwrap();
    // 0.02 % at 2 %/h of hotel load: 36 s.
    let (ended, _) = run_until_final(&mut v, "h", 100.0);
    assert!((ended.unwrap() - 36.0).abs() < 0.5, "{ended:?}");
    run_for(&mut v, 60.0);
    assert_eq!(v.depth_m(), 0.0, "idle at the reserve means surfacing");
}

#[test]
fn low_battery_warning_fires_once_with_hysteresis() {
    let mut alarm = FallingAlarm::new(20.0, 5.0);
    let fired: Vec<bool> = [25.0, 21.0, 20.0, 19.9, 20.1, 24.0, 19.0, 25.1, 22.0, 19.5]
        .iter()
        .map(|b| alarm.update(*b))
        .collect();
    assert_eq!(
        fired,
        [
            false, false, true, false, false, false, false, false, false, true
        ]
    );

    let mut v = vehicle(VehicleKind::Auv, 20.05);
    v.submit(&order("h", T0, Task::Hold { duration_s: 0.0 }))
        .unwrap();
    let out = run_for(&mut v, 1200.0);
    let warnings = events(&out, EventKind::LowBattery);
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert_eq!(warnings[0].severity, Severity::Warning);
    assert_eq!(
        warnings[0].text,
        "battery at 20.0 %, below the 20 % threshold"
    );
    assert_eq!(warnings[0].task_id, "h");
    // 0.05 % at 2 %/h: 90 s after the start.
    assert!((warnings[0].timestamp_ms - T0 - 90_000).abs() <= 100);
}

// --- Events and environment -------------------------------------------------------------

fn detections(seed: u64, per_s: f64, seconds: f64) -> Vec<VehicleEvent> {
    let settings = SimSettings {
        seed: Some(seed),
        detection_per_s: per_s,
        environment_hz: 0.0,
        ..SimSettings::default()
    };
    let poly = rectangle(p(43.0, 5.9), 1000.0, 500.0);
    let mut v = SimVehicle::with_settings(&spec(VehicleKind::Auv, 100.0), &settings, T0);
    v.submit(&order("s", T0, survey(poly, 25.0, 10.0))).unwrap();
    let out = run_for(&mut v, seconds);
    assert_eq!(v.current_task(), Some("s"), "still surveying");
    events(&out, EventKind::Detection)
        .into_iter()
        .cloned()
        .collect()
}

#[test]
fn detections_come_at_the_configured_rate_and_repeat_for_a_seed() {
    let a = detections(7, 0.05, 2000.0);
    // Poisson with mean 0.05 × ~2000 s on the lines = ~100, σ = 10.
    assert!((70..=130).contains(&a.len()), "{} detections", a.len());
    assert!(
        a.iter()
            .all(|e| e.severity == Severity::Info && e.task_id == "s")
    );
    assert!(
        a[0].text.starts_with("sidescan_sonar contact at 43.0"),
        "{}",
        a[0].text
    );
    assert_eq!(detections(7, 0.05, 2000.0), a, "same seed, same detections");
    assert_ne!(
        detections(8, 0.05, 2000.0),
        a,
        "another seed, other detections"
    );
    assert!(detections(7, 0.0, 500.0).is_empty());
}

#[test]
fn no_detections_outside_a_survey() {
    let settings = SimSettings {
        detection_per_s: 1.0,
        ..quiet()
    };
    let mut v = SimVehicle::with_settings(&spec(VehicleKind::Auv, 100.0), &settings, T0);
    v.submit(&order("g", T0, goto(p(43.01, 5.9), 5.0, 1.5)))
        .unwrap();
    let out = run_for(&mut v, 300.0);
    assert!(events(&out, EventKind::Detection).is_empty());
}

#[test]
fn environment_is_sampled_at_the_configured_rate_by_the_sensors_carried() {
    let settings = SimSettings {
        environment_hz: 0.5,
        ..quiet()
    };
    let mut auv = SimVehicle::with_settings(&spec(VehicleKind::Auv, 100.0), &settings, T0);
    auv.submit(&order("d", T0, goto(auv.position(), 40.0, 1.0)))
        .unwrap();
    let out = run_for(&mut auv, 60.0);
    let obs: Vec<&EnvironmentObservation> = out
        .iter()
        .filter_map(|o| match o {
            VehicleOutput::Observation(o) => Some(o),
            _ => None,
        })
        .collect();
    // Every 2 s for 60 s, four properties each (CTD and DVL).
    assert_eq!(obs.len(), 30 * 4);
    for o in &obs {
        assert_eq!(o.validate(), Ok(()), "{o:?}");
        assert!(
            UNITS.contains(&(o.property.as_str(), o.unit.as_str())),
            "{o:?}"
        );
    }
    let temps: Vec<f64> = obs
        .iter()
        .filter(|o| o.property == TEMPERATURE)
        .map(|o| o.value)
        .collect();
    assert!(temps.iter().all(|t| (5.0..20.0).contains(t)), "{temps:?}");
    assert!(
        temps.last() < temps.first(),
        "colder as it dives: {temps:?}"
    );

    let mut rov = SimVehicle::with_settings(&spec(VehicleKind::Rov, 100.0), &settings, T0);
    let props: std::collections::BTreeSet<String> = run_for(&mut rov, 10.0)
        .into_iter()
        .filter_map(|o| match o {
            VehicleOutput::Observation(o) => Some(o.property),
            _ => None,
        })
        .collect();
    assert_eq!(
        props.into_iter().collect::<Vec<_>>(),
        [SALINITY, TEMPERATURE],
        "an ROV has a CTD but no current sensor"
    );
}

#[test]
fn a_plume_in_the_configured_ocean_is_what_the_ctd_measures() {
    let start = spec(VehicleKind::Auv, 100.0);
    let here = p(start.latitude_deg, start.longitude_deg);
    let ocean = OceanField {
        surface_temperature_c: Some(8.0),
        plumes: vec![Plume {
            latitude_deg: here.latitude_deg,
            longitude_deg: here.longitude_deg,
            radius_m: 500.0,
            depth_m: 0.0,
            thickness_m: 5.0,
            temperature_c: 6.0,
            salinity_psu: -8.0,
        }],
        ..OceanField::default()
    };
    let settings = SimSettings {
        environment_hz: 1.0,
        ocean: ocean.clone(),
        ..quiet()
    };
    let mut v = SimVehicle::with_settings(&start, &settings, T0);
    let out = run_for(&mut v, 5.0);
    let value = |property: &str| {
        out.iter()
            .find_map(|o| match o {
                VehicleOutput::Observation(o) if o.property == property => Some(o.value),
                _ => None,
            })
            .unwrap()
    };
    let expected = ocean.water_at(here, 0.0);
    assert!((value(TEMPERATURE) - expected.temperature_c).abs() < 0.01);
    assert!((value(SALINITY) - expected.salinity_psu).abs() < 0.01);
    // The plume is in it: warmer and fresher than the same ocean without.
    let plain = OceanField::default().water_at(here, 0.0);
    assert!(value(SALINITY) < plain.salinity_psu - 7.0);
}

#[test]
fn settings_out_of_range_are_made_safe() {
    let s = SimSettings {
        reserve_pct: f64::NAN,
        low_battery_pct: 250.0,
        detection_per_s: -3.0,
        environment_hz: f64::INFINITY,
        ..SimSettings::default()
    }
    .sanitized();
    assert_eq!(
        (
            s.reserve_pct,
            s.low_battery_pct,
            s.detection_per_s,
            s.environment_hz
        ),
        (10.0, 100.0, 0.0, 0.0)
    );
    let mut v = SimVehicle::with_settings(&spec(VehicleKind::Auv, f64::NAN), &s, T0);
    v.step(10.0);
    assert_eq!(v.state(T0).validate(), Ok(()));
}
