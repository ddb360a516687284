//! A mission's log for other tools: the tracks of its vehicles over the mission's time
//! window (from the history store), as CSV (one state vector per row) or GeoJSON (a line
//! per vehicle, a point per waypoint, a polygon per survey area).

use std::fmt::Write as _;

use serde_json::{Value, json};
use shoal_model::datetime::format_utc;
use shoal_model::{StateVector, TaskKind};
use shoal_station::MissionView;

/// One mission and its vehicles' tracks, oldest point first.
#[derive(Debug, Clone)]
pub struct MissionLog {
    /// The mission as the register has it.
    pub mission: MissionView,
    /// Start of the window, ms since the Unix epoch.
    pub from_ms: i64,
    /// End of the window.
    pub to_ms: i64,
    /// (vehicle id, its states in the window).
    pub tracks: Vec<(String, Vec<StateVector>)>,
    /// True when a vehicle had more states than one export holds (its latest were left out).
    pub truncated: bool,
}

impl MissionLog {
    /// The vehicles of a mission, in the order they first appear in its tasks.
    pub fn vehicles(mission: &MissionView) -> Vec<String> {
        let mut out: Vec<String> = Vec::new();
        for t in &mission.tasks {
            if !out.contains(&t.assignment.vehicle_id) {
                out.push(t.assignment.vehicle_id.clone());
            }
        }
        out
    }

    /// The window a mission's log covers: from its start (or creation, if it never
    /// started) to its end, or to `now_ms` while it runs.
    pub fn window(mission: &MissionView, now_ms: i64) -> (i64, i64) {
        let from = mission.started_ms.unwrap_or(mission.created_ms);
        let to = mission.ended_ms.unwrap_or(now_ms).max(from);
        (from, to)
    }
}

/// Quotes a CSV field when it holds a separator, quote or line break (RFC 4180).
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_owned()
    }
}

/// Column names of the CSV export.
pub const CSV_HEADER: &str = "mission_id,vehicle_id,timestamp_ms,time_utc,latitude_deg,longitude_deg,depth_m,altitude_m,speed_mps,yaw_deg,pitch_deg,roll_deg,battery_pct";

/// The CSV export: a header, then every state vector of every vehicle, by vehicle then time.
pub fn to_csv(log: &MissionLog) -> String {
    let mut out =
        String::with_capacity(64 + 128 * log.tracks.iter().map(|t| t.1.len()).sum::<usize>());
    out.push_str(CSV_HEADER);
    out.push_str("\r\n");
    let mission = field(&log.mission.mission_id);
    for (vehicle, states) in &log.tracks {
        let vehicle = field(vehicle);
        for s in states {
            let _ = write!(
                out,
                "{mission},{vehicle},{},{},{},{},{},{},{},{},{},{},{}\r\n",
                s.timestamp_ms,
                format_utc(s.timestamp_ms),
                s.latitude_deg,
                s.longitude_deg,
                s.depth_m,
                s.altitude_m,
                s.speed_mps,
                s.yaw_deg,
                s.pitch_deg,
                s.roll_deg,
                s.battery_pct
            );
        }
    }
    out
}

/// The GeoJSON export (RFC 7946, WGS84 longitude/latitude): a `LineString` per vehicle
/// with its times, depths and batteries as parallel arrays; a `Point` per waypoint task and
/// a `Polygon` per survey task with the task's state. The mission is a foreign member.
pub fn to_geojson(log: &MissionLog) -> Value {
    let m = &log.mission;
    let mut features = Vec::new();
    for (vehicle, states) in &log.tracks {
        let coords: Vec<[f64; 2]> = states
            .iter()
            .map(|s| [s.longitude_deg, s.latitude_deg])
            .collect();
        // A single fix is a point: a LineString needs two positions.
        let geometry = match coords.as_slice() {
            [] => Value::Null,
            [one] => json!({"type": "Point", "coordinates": one}),
            _ => json!({"type": "LineString", "coordinates": coords}),
        };
        features.push(json!({
            "type": "Feature",
            "geometry": geometry,
            "properties": {
                "feature": "track",
                "mission_id": m.mission_id,
                "vehicle_id": vehicle,
                "points": states.len(),
                "timestamps_ms": states.iter().map(|s| s.timestamp_ms).collect::<Vec<_>>(),
                "depth_m": states.iter().map(|s| s.depth_m).collect::<Vec<_>>(),
                "battery_pct": states.iter().map(|s| s.battery_pct).collect::<Vec<_>>(),
            }
        }));
    }
    for t in &m.tasks {
        let a = &t.assignment;
        let ring: Vec<[f64; 2]> = a
            .area
            .iter()
            .map(|p| [p.longitude_deg, p.latitude_deg])
            .collect();
        let geometry = match (a.kind, ring.as_slice()) {
            (TaskKind::GotoWaypoint, [p]) => json!({"type": "Point", "coordinates": p}),
            (TaskKind::SurveyArea, [first, ..]) if ring.len() >= 3 => {
                let mut closed = ring.clone();
                closed.push(*first);
                json!({"type": "Polygon", "coordinates": [closed]})
            }
            _ => Value::Null,
        };
        features.push(json!({
            "type": "Feature",
            "geometry": geometry,
            "properties": {
                "feature": "task",
                "mission_id": m.mission_id,
                "task_id": a.task_id,
                "vehicle_id": a.vehicle_id,
                "kind": a.kind,
                "state": t.state,
                "progress_pct": t.progress_pct,
                "message": t.message,
                "updated_ms": t.updated_ms,
                "depth_m": a.depth_m,
                "altitude_m": a.altitude_m,
                "speed_mps": a.speed_mps,
            }
        }));
    }
    json!({
        "type": "FeatureCollection",
        "mission": {
            "mission_id": m.mission_id,
            "name": m.name,
            "state": m.state,
            "created_ms": m.created_ms,
            "started_ms": m.started_ms,
            "ended_ms": m.ended_ms,
            "progress_pct": m.progress_pct,
            "window_from_ms": log.from_ms,
            "window_to_ms": log.to_ms,
            "truncated": log.truncated,
        },
        "features": features,
    })
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use shoal_model::{GeoPoint, Task, TaskAssignment, TaskState};
    use shoal_station::{MissionState, TaskView};

    fn state(vehicle: &str, t: i64, lat: f64) -> StateVector {
        StateVector {
            vehicle_id: vehicle.into(),
            timestamp_ms: t,
            latitude_deg: lat,
            longitude_deg: 10.37,
            depth_m: 5.5,
            altitude_m: -1.0,
            speed_mps: 1.5,
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: 88.25,
        }
    }

    fn task(id: &str, vehicle: &str, task: &Task, st: TaskState) -> TaskView {
        TaskView {
            assignment: TaskAssignment::new(id, "m-1", vehicle, 1_000, task),
            state: st,
            progress_pct: 100.0,
            message: "ok, \"fine\"".into(),
            updated_ms: 2_000,
            dispatched_ms: None,
            started_ms: None,
            ended_ms: None,
            link: None,
            status: None,
            retries: 0,
            via_site: None,
        }
    }

    fn log() -> MissionLog {
        let p = |lat, lon| GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        };
        let goto = Task::GotoWaypoint {
            target: p(63.47, 10.37),
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        };
        let survey = Task::SurveyArea {
            polygon: vec![p(63.46, 10.36), p(63.46, 10.38), p(63.47, 10.38)],
            line_spacing_m: 20.0,
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        };
        let mission = MissionView {
            mission_id: "m-1".into(),
            name: "harbour, north".into(),
            state: MissionState::Done,
            created_ms: 1_000,
            started_ms: Some(1_500),
            ended_ms: Some(9_000),
            progress_pct: 100.0,
            tasks: vec![
                task("m-1-1", "auv-1", &goto, TaskState::Done),
                task("m-1-2", "auv-2", &survey, TaskState::Done),
                task("m-1-3", "auv-1", &goto, TaskState::Done),
            ],
        };
        MissionLog {
            tracks: vec![
                (
                    "auv-1".into(),
                    vec![state("auv-1", 2_000, 63.46), state("auv-1", 3_000, 63.461)],
                ),
                ("auv-2".into(), vec![state("auv-2", 2_500, 63.465)]),
            ],
            from_ms: 1_500,
            to_ms: 9_000,
            mission,
            truncated: false,
        }
    }

    #[test]
    fn iso_times_are_utc_with_milliseconds() {
        assert_eq!(format_utc(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(format_utc(951_782_400_000), "2000-02-29T00:00:00.000Z");
        assert_eq!(format_utc(1_763_733_787_250), "2025-11-21T14:03:07.250Z");
        assert_eq!(format_utc(-1), "1969-12-31T23:59:59.999Z");
    }

    #[test]
    fn the_window_and_vehicles_come_from_the_mission() {
        let l = log();
        assert_eq!(MissionLog::vehicles(&l.mission), ["auv-1", "auv-2"]);
        assert_eq!(MissionLog::window(&l.mission, 50_000), (1_500, 9_000));
        let mut running = l.mission;
        running.ended_ms = None;
        assert_eq!(MissionLog::window(&running, 50_000), (1_500, 50_000));
        running.started_ms = None;
        assert_eq!(MissionLog::window(&running, 50_000), (1_000, 50_000));
    }

    #[test]
    fn csv_has_one_row_per_state_and_quotes_what_needs_it() {
        let csv = to_csv(&log());
        let lines: Vec<&str> = csv.split("\r\n").filter(|l| !l.is_empty()).collect();
        assert_eq!(lines.len(), 4);
        assert_eq!(lines[0], CSV_HEADER);
        assert_eq!(
            lines[1],
            "m-1,auv-1,2000,1970-01-01T00:00:02.000Z,63.46,10.37,5.5,-1,1.5,90,0,0,88.25"
        );
        assert!(lines[3].starts_with("m-1,auv-2,2500,"));
        let columns = CSV_HEADER.split(',').count();
        assert!(lines.iter().all(|l| l.split(',').count() == columns));
        assert_eq!(field("a,b"), "\"a,b\"");
        assert_eq!(field("say \"hi\""), "\"say \"\"hi\"\"\"");
    }

    #[test]
    fn geojson_has_tracks_waypoints_and_closed_survey_polygons() {
        let g = to_geojson(&log());
        assert_eq!(g["type"], "FeatureCollection");
        assert_eq!(g["mission"]["name"], "harbour, north");
        let f = g["features"].as_array().unwrap();
        assert_eq!(f.len(), 5);
        assert_eq!(f[0]["geometry"]["type"], "LineString");
        assert_eq!(f[0]["geometry"]["coordinates"][1][1], 63.461);
        assert_eq!(f[0]["properties"]["timestamps_ms"][1], 3_000);
        assert_eq!(f[1]["geometry"]["type"], "Point");
        assert_eq!(f[2]["geometry"]["type"], "Point");
        assert_eq!(f[2]["properties"]["task_id"], "m-1-1");
        let ring = f[3]["geometry"]["coordinates"][0].as_array().unwrap();
        assert_eq!(f[3]["geometry"]["type"], "Polygon");
        assert_eq!(ring.len(), 4);
        assert_eq!(ring[0], ring[3]);
        assert_eq!(f[3]["properties"]["state"], "done");
    }
}
