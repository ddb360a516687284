#![allow(clippy::unwrap_used)]
use shoal_model::{EventKind, Task};

use super::*;

const T0: i64 = 1_800_000_000_000;

fn state(id: &str, s: f64, lat: f64, depth: f64, battery: f64, speed: f64) -> StateVector {
    StateVector {
        vehicle_id: id.into(),
        #[allow(clippy::cast_possible_truncation)]
        timestamp_ms: T0 + (s * 1000.0) as i64,
        latitude_deg: lat,
        longitude_deg: 10.0,
        depth_m: depth,
        altitude_m: -1.0,
        speed_mps: speed,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: battery,
    }
}

fn status(task: &str, s: i64, state: TaskState) -> TaskStatus {
    TaskStatus {
        task_id: task.into(),
        vehicle_id: "auv-1".into(),
        timestamp_ms: T0 + s * 1000,
        state,
        progress_pct: 0.0,
        message: String::new(),
    }
}

fn record() -> RunRecord {
    // 0.001° of latitude is 111.2 m: two legs of it.
    let track = vec![
        state("auv-1", 0.0, 63.0, 0.0, 100.0, 0.0),
        state("auv-1", 60.0, 63.001, 5.0, 98.0, 1.5),
        state("auv-1", 120.0, 63.002, 2.5, 97.0, 1.5),
    ];
    let goto = TaskAssignment::new(
        "survey-1-1",
        "survey-1",
        "auv-1",
        T0,
        &Task::Hold { duration_s: 30.0 },
    );
    let lost = TaskAssignment::new("survey-1-2", "survey-1", "auv-1", T0, &Task::Surface);
    RunRecord {
        scenario: "box <survey>".into(),
        description: "a & b".into(),
        seed: 7,
        speed: 60.0,
        start_ms: T0,
        end_ms: T0 + 180_000,
        wall_s: 3.04,
        vehicles: vec![
            VehicleRecord {
                id: "auv-1".into(),
                kind: "auv".into(),
                track,
            },
            VehicleRecord {
                id: "usv-1".into(),
                kind: "usv".into(),
                track: vec![],
            },
        ],
        tasks: vec![
            TaskRecord {
                assignment: goto,
                statuses: vec![
                    status("survey-1-1", 1, TaskState::Sent),
                    status("survey-1-1", 2, TaskState::Accepted),
                    status("survey-1-1", 3, TaskState::Running),
                    status("survey-1-1", 33, TaskState::Done),
                ],
            },
            TaskRecord {
                assignment: lost,
                statuses: vec![status("survey-1-2", 34, TaskState::Failed)],
            },
        ],
        events: vec![
            Event {
                event_id: "e1".into(),
                timestamp_ms: T0 + 90_000,
                severity: Severity::Alarm,
                kind: EventKind::Fault,
                vehicle_id: "auv-1".into(),
                task_id: String::new(),
                text: "battery <low> & falling".into(),
            },
            rule_event("builtin.low_battery", 95, "auv-1"),
            rule_event("deep-dive", 100, "usv-1"),
            rule_event("builtin.low_battery", 110, "auv-1"),
            // The station's own event has a rule firing's shape; no rule is called so.
            rule_event("station", 120, "auv-1"),
        ],
        station: StationFigures {
            states_accepted: 3,
            rejected: 1,
            history_committed: 9,
            rule_firings: 3,
        },
        faults: vec![FaultRecord {
            at_s: 100.0,
            what: "auv-1 fails <for good>".into(),
        }],
        rule_ids: vec![
            "builtin.low_battery".into(),
            "deep-dive".into(),
            "never-fires".into(),
        ],
        links: vec![
            LinkFigures {
                from: "auv-1".into(),
                to: "relay".into(),
                frames: 8,
                delivered: 6,
                lost: 1,
                outage: 1,
                ..LinkFigures::default()
            },
            LinkFigures {
                from: "relay".into(),
                to: "auv-<1>".into(),
                ..LinkFigures::default()
            },
        ],
        acoustic_latency_ms: [("auv-1".to_owned(), vec![3_000, 1_000, 30_000, 2_000, 4_000])]
            .into(),
        link_quality: [(
            "auv-1".to_owned(),
            vec![
                LinkSample {
                    at_ms: T0 + 30_000,
                    rssi_db: Some(-58),
                    integrity: Some(255),
                },
                LinkSample {
                    at_ms: T0 + 60_000,
                    rssi_db: Some(-70),
                    integrity: Some(120),
                },
            ],
        )]
        .into(),
        airtime_s: [("relay".to_owned(), 9.0), ("auv-1".to_owned(), 9.04)].into(),
        environment: Vec::new(),
    }
}

#[test]
fn acoustic_latency_channel_use_and_link_quality_are_reported() {
    let r = record();
    let s = summarise(&r);
    let l = s.acoustic_latency["auv-1"];
    assert_eq!((l.samples, l.p50_s, l.p95_s, l.max_s), (5, 3.0, 30.0, 30.0));
    assert_eq!(LatencyFigures::of(&[]), None);
    assert_eq!(LatencyFigures::of(&[1_234]).unwrap().p50_s, 1.23);
    // 18.04 s on air over 180 s.
    assert_eq!(s.acoustic_channel_use_pct, Some(10.0));
    assert_eq!(s.acoustic_airtime_s["auv-1"], 9.0);
    let html = render_html(&r, &s);
    assert!(
        html.contains("carried a transmission 10 % of the run"),
        "{html}"
    );
    assert!(html.contains("<td class=\"n\">3 s</td>"), "{html}");
    assert!(html.contains("aria-label=\"Acoustic link quality (RSSI at the relay)\""));
    let none = RunRecord {
        airtime_s: BTreeMap::new(),
        ..RunRecord::default()
    };
    assert_eq!(summarise(&none).acoustic_channel_use_pct, None);
}

#[test]
fn acoustic_links_are_in_the_summary_and_the_page() {
    let r = record();
    let s = summarise(&r);
    let up = &s.acoustic_links["auv-1>relay"];
    assert_eq!((up.figures.delivered, up.delivery_pct), (6, Some(75.0)));
    assert_eq!(s.acoustic_links["relay>auv-<1>"].delivery_pct, None);
    let json = serde_json::to_value(&s).unwrap();
    assert_eq!(json["acoustic_links"]["auv-1>relay"]["outage"], 1);
    let html = render_html(&r, &s);
    assert!(html.contains("<h2>Acoustic network</h2>"));
    assert!(html.contains("auv-1 → relay"));
    assert!(html.contains("6 (75 %)"), "{html}");
    assert!(html.contains("relay → auv-&lt;1&gt;"));
    let none = RunRecord {
        links: Vec::new(),
        airtime_s: BTreeMap::new(),
        ..record()
    };
    assert!(!render_html(&none, &summarise(&none)).contains("Acoustic network"));
}

/// An event as rule `rule` raises it, `at_s` into the run.
fn rule_event(rule: &str, at_s: i64, vehicle: &str) -> Event {
    let ts = T0 + at_s * 1000;
    Event {
        event_id: format!("{rule}-{ts}-{at_s}"),
        timestamp_ms: ts,
        severity: Severity::Warning,
        kind: EventKind::Rule,
        vehicle_id: vehicle.into(),
        task_id: String::new(),
        text: format!("{rule} fired"),
    }
}

#[test]
fn rule_firings_are_counted_by_rule_from_their_event_ids() {
    let s = summarise(&record());
    assert_eq!(s.rule_firings.len(), 2, "{:?}", s.rule_firings);
    let low = &s.rule_firings["builtin.low_battery"];
    assert_eq!((low.count, low.first_s), (2, 95.0));
    assert_eq!(low.vehicles, ["auv-1"]);
    assert_eq!(s.rule_firings["deep-dive"].count, 1);
    let ids = record().rule_ids;
    assert_eq!(
        rule_of("deep-dive-1800000000000-4", &ids),
        Some("deep-dive")
    );
    assert_eq!(rule_of("deep-dive-x-4", &ids), None);
    assert_eq!(rule_of("station-1-2", &ids), None);
    assert_eq!(rule_of("nothing", &ids), None);
    let r = record();
    let html = render_html(&r, &s);
    assert!(html.contains("<h2>Rule firings</h2>"));
    assert!(
        html.contains("<td>builtin.low_battery</td><td class=\"n\">2</td>"),
        "{html}"
    );
}

#[test]
fn the_summary_has_each_vehicles_figures_and_each_tasks_outcome() {
    let s = summarise(&record());
    let auv = &s.vehicles["auv-1"];
    assert_eq!(auv.states, 3);
    assert!((auv.distance_m - 222.0).abs() <= 1.0, "{}", auv.distance_m);
    assert_eq!(auv.max_depth_m, 5.0);
    assert_eq!(
        (
            auv.battery_start_pct,
            auv.battery_end_pct,
            auv.battery_min_pct
        ),
        (100.0, 97.0, 97.0)
    );
    assert_eq!(auv.first_motion_s, Some(60.0));
    assert_eq!(round_dp(20.400_000_000_000_002, 1).to_string(), "20.4");
    let usv = &s.vehicles["usv-1"];
    assert_eq!(
        (usv.states, usv.distance_m, usv.first_motion_s),
        (0, 0.0, None)
    );
    assert_eq!(s.tasks["total"], 2);
    assert_eq!(s.tasks["done"], 1);
    assert_eq!(s.tasks["failed"], 1);
    let hold = &s.task_outcomes["survey/1"];
    assert_eq!(
        (hold.kind.as_str(), hold.state.as_str(), hold.duration_s),
        ("hold", "done", Some(30.0))
    );
    assert_eq!(s.task_outcomes["survey/2"].duration_s, None);
    assert_eq!(s.task_outcomes["survey/2"].task_id, "survey-1-2");
    assert_eq!(s.events["alarm"], 1);
    assert_eq!(s.events["warning"], 4);
    assert_eq!(s.simulated_s, 180.0);
    assert_eq!(s.wall_s, 3.0);
    assert_eq!(s.faults.len(), 1);
}

#[test]
fn the_page_is_self_contained_escaped_and_plots_every_vehicle() {
    let r = record();
    let html = render_html(&r, &summarise(&r));
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(html.ends_with("</html>"));
    // Nothing is fetched: the page opens offline.
    for outside in ["http://", "https://", "src=", "<script", "@import", "url("] {
        assert!(!html.contains(outside), "{outside}");
    }
    assert!(html.contains("box &lt;survey&gt;"));
    assert!(html.contains("battery &lt;low&gt; &amp; falling"));
    assert!(!html.contains("<low>"));
    // Tracks, depth, battery, speed: one line each for the vehicle with data; and the
    // acoustic link's quality.
    assert_eq!(html.matches("<polyline").count(), 5);
    assert!(html.contains("aria-label=\"Task timeline\""));
    assert!(html.contains("auv-1 fails &lt;for good&gt;"));
    assert!(html.contains("class=\"fault\""));
    assert!(html.matches("<rect x=").count() >= 2);
}

#[test]
fn an_empty_run_still_renders() {
    let r = RunRecord {
        scenario: "empty".into(),
        start_ms: T0,
        end_ms: T0,
        ..RunRecord::default()
    };
    let html = render_html(&r, &summarise(&r));
    assert!(html.contains("No positions were stored."));
    assert!(html.contains("No task was issued."));
    assert!(html.contains("No rule fired."));
}

#[test]
fn ticks_are_round_numbers() {
    assert_eq!(html_tick(3600.0), 500.0);
    assert_eq!(html_tick(7.3), 1.0);
}

#[test]
fn time_ticks_are_whole_minutes_and_hours() {
    assert_eq!(html::time_step_for_tests(900.0), 300.0);
    assert_eq!(html::time_step_for_tests(3600.0), 600.0);
    assert_eq!(html::time_step_for_tests(7.0 * 86_400.0), 86_400.0 * 2.0);
}

fn html_tick(span: f64) -> f64 {
    html::tick_step_for_tests(span)
}

fn observation(
    vehicle: &str,
    property: &str,
    value: f64,
    lat: f64,
    depth: f64,
) -> EnvironmentObservation {
    EnvironmentObservation {
        vehicle_id: vehicle.into(),
        property: property.into(),
        timestamp_ms: T0,
        value,
        unit: "Cel".into(),
        latitude_deg: lat,
        longitude_deg: 10.0,
        depth_m: depth,
    }
}

#[test]
fn the_environment_figures_give_each_propertys_range_and_where_its_extremes_were() {
    let t = "sea_water_temperature";
    let r = RunRecord {
        environment: vec![
            observation("auv-2", t, 8.0, 63.0, 5.0),
            observation("auv-1", t, 11.456, 63.0012, 2.0),
            observation("auv-1", t, 7.5, 63.0003, 30.04),
            observation("auv-1", "sea_water_salinity", 31.0, 63.0, 5.0),
        ],
        ..record()
    };
    let s = summarise(&r);
    let e = &s.environment[t];
    assert_eq!(e.observations, 3);
    assert_eq!(e.vehicles, ["auv-1", "auv-2"]);
    assert_eq!((e.min, e.max), (7.5, 11.46));
    assert_eq!(e.mean, 8.99);
    assert_eq!(e.max_at, [63.0012, 10.0, 2.0]);
    assert_eq!(e.min_at, [63.0003, 10.0, 30.0]);
    assert_eq!(s.environment["sea_water_salinity"].observations, 1);
    let html = render_html(&r, &s);
    assert!(html.contains("<h2>Environment</h2>"), "{html}");
    assert!(html.contains("11.46 (63.00120, 10.00000, 2.0 m)"), "{html}");
    // Without observations, no section.
    let none = summarise(&record());
    assert!(none.environment.is_empty());
    assert!(!render_html(&record(), &none).contains("<h2>Environment</h2>"));
}
