//! `shoal scenario run`: a scenario headless, faster than real time, and its report
//! directory, through the binary. Domains 113 and 114 (the acoustic vehicles of a run take
//! private domains down from 232).

use std::process::Command;
use std::time::Instant;

/// Two vehicles, three tasks and four faults; ten simulated minutes.
const SCENARIO: &str = r#"
[scenario]
name = "two-boats"
description = "An AUV goes out and holds; a USV crosses."
duration_s = 600.0

[[vehicles]]
id = "auv-7"
kind = "auv"
latitude_deg = 63.465
longitude_deg = 10.36

[[vehicles]]
id = "usv-7"
kind = "usv"
latitude_deg = 63.466
longitude_deg = 10.362

[[missions]]
id = "out"
name = "out and hold"
at_s = 5.0

[[missions.tasks]]
vehicle = "auv-7"
kind = "goto"
latitude_deg = 63.467
longitude_deg = 10.36
depth_m = 4.0
speed_mps = 1.5

[[missions.tasks]]
vehicle = "auv-7"
kind = "hold"
duration_s = 60.0

[[missions]]
id = "cross"
name = "crossing"
at_s = 30.0

[[missions.tasks]]
vehicle = "usv-7"
kind = "goto"
latitude_deg = 63.466
longitude_deg = 10.372
speed_mps = 2.0

# auv-7's computer stops during its goto and starts again 30 s later.
[[faults]]
at_s = 20.0
kind = "vehicle_failure"
vehicle = "auv-7"
duration_s = 30.0

[[faults]]
at_s = 100.0
kind = "rogue_sample"
vehicle = "usv-7"

[[faults]]
at_s = 200.0
kind = "battery_drop"
vehicle = "usv-7"
battery_pct = 15.0

[[faults]]
at_s = 300.0
kind = "station_restart"
duration_s = 10.0

# Cold water without eddies, and a warm lens where auv-7 holds.
[environment]
surface_temperature_c = 8.0
eddy_temperature_c = 0.0

[[environment.plumes]]
latitude_deg = 63.467
longitude_deg = 10.36
radius_m = 100.0
depth_m = 4.0
thickness_m = 5.0
temperature_c = 5.0
"#;

fn shoal(dir: &std::path::Path) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_shoal"));
    c.current_dir(dir);
    c
}

#[test]
fn a_scenario_with_faults_runs_at_60x_and_leaves_a_report_with_its_figures() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("two-boats.toml"), SCENARIO).unwrap();
    let started = Instant::now();
    let out = shoal(dir.path())
        .args([
            "scenario",
            "run",
            "two-boats.toml",
            "--speed",
            "60",
            "--seed",
            "3",
        ])
        .args(["--domain", "113", "--out", "run"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    // Ten simulated minutes at 60x: about ten real seconds, plus start and report.
    let took = started.elapsed().as_secs_f64();
    assert!(took < 60.0, "{took} s");
    assert!(stderr.contains("simulated ("), "progress lines: {stderr}");

    let run = dir.path().join("run");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["format"], 1);
    assert_eq!(summary["scenario"], "two-boats");
    assert_eq!(summary["seed"], 3);
    assert_eq!(summary["simulated_s"], 600.0);
    // Both vehicles reported through the run (1 Hz simulated: hundreds of states, fewer
    // when a loaded machine skips ticks) and moved.
    for id in ["auv-7", "usv-7"] {
        let v = &summary["vehicles"][id];
        assert!(v["states"].as_u64().unwrap() > 200, "{id}: {v}");
        assert!(v["distance_m"].as_f64().unwrap() > 150.0, "{id}: {v}");
    }
    assert!(
        summary["vehicles"]["auv-7"]["max_depth_m"]
            .as_f64()
            .unwrap()
            > 3.0
    );
    assert_eq!(summary["vehicles"]["usv-7"]["max_depth_m"], 0.0);
    // The missions started on the timeline, in simulated time: the USV not before 30 s.
    let usv_moved = summary["vehicles"]["usv-7"]["first_motion_s"]
        .as_f64()
        .unwrap();
    assert!((30.0..90.0).contains(&usv_moved), "{usv_moved}");
    // Every fault happened, on time; a restart comes its delay after the failure.
    let faults = summary["faults"].as_array().unwrap();
    let when: Vec<f64> = faults.iter().map(|f| f["at_s"].as_f64().unwrap()).collect();
    assert_eq!(faults.len(), 6, "{faults:?}");
    for (got, want) in when.iter().zip([20.0, 50.0, 100.0, 200.0, 300.0, 310.0]) {
        assert!((want..want + 30.0).contains(got), "{when:?}");
    }
    // The report gives times to 0.1 s, and 50.3 - 20.3 is 29.999... in floating point.
    assert!(
        when[1] - when[0] >= 29.9,
        "restarted 30 s after failing: {when:?}"
    );
    // The rogue sample was refused and counted; the battery drop is in the track.
    assert!(
        summary["station"]["rejected"].as_u64().unwrap() >= 1,
        "{summary}"
    );
    assert!(
        summary["vehicles"]["usv-7"]["battery_end_pct"]
            .as_f64()
            .unwrap()
            < 15.1
    );
    assert!(
        summary["events"]["warning"].as_u64().unwrap() >= 2,
        "{summary}"
    );
    // The drop below the low-battery level fired the built-in rule, about that vehicle.
    let low = &summary["rule_firings"]["builtin.low_battery"];
    assert!(low["count"].as_u64().unwrap() >= 1, "{summary}");
    assert!(
        low["vehicles"]
            .as_array()
            .unwrap()
            .iter()
            .any(|v| v == "usv-7"),
        "{summary}"
    );
    assert!(summary["station"]["rule_firings"].as_u64().unwrap() >= 1);
    // Every task ran to done, once, across the vehicle's failure and the station's
    // restart; each is keyed by its mission and place, whatever the run.
    assert_eq!(summary["tasks"]["total"], 3, "{summary}");
    assert_eq!(summary["tasks"]["done"], 3, "{summary}");
    for key in ["out/1", "out/2", "cross/1"] {
        assert_eq!(summary["task_outcomes"][key]["state"], "done", "{key}");
    }
    let hold = summary["task_outcomes"]["out/2"]["duration_s"]
        .as_f64()
        .unwrap();
    assert!(
        (55.0..75.0).contains(&hold),
        "the 60 s hold took {hold} simulated s"
    );

    // The scenario's ocean is what the vehicles measured: the warm lens at the hold, the
    // cold water elsewhere.
    let t = &summary["environment"]["sea_water_temperature"];
    assert!(t["observations"].as_u64().unwrap() >= 20, "{t}");
    let (min, max) = (t["min"].as_f64().unwrap(), t["max"].as_f64().unwrap());
    assert!(min < 8.5 && max > 11.0, "{t}");
    let at = &t["max_at"];
    assert!((at[0].as_f64().unwrap() - 63.467).abs() < 0.001, "{t}");
    assert!((at[1].as_f64().unwrap() - 10.36).abs() < 0.002, "{t}");

    let html = std::fs::read_to_string(run.join("report.html")).unwrap();
    assert!(html.contains("auv-7") && html.contains("usv-7") && html.contains("<svg"));
    assert!(
        html.contains("<h2>Environment</h2>"),
        "the environment table"
    );
    assert!(html.contains("Faults injected") && html.contains("class=\"fault\""));
    assert!(
        html.contains("<td>builtin.low_battery</td>"),
        "the rule firings table"
    );
    assert!(run.join("history.sqlite").exists());
    let mcap: Vec<_> = std::fs::read_dir(run.join("recording"))
        .unwrap()
        .filter_map(Result::ok)
        .filter(|e| e.path().extension().is_some_and(|x| x == "mcap"))
        .collect();
    assert_eq!(mcap.len(), 1);
    assert!(mcap[0].metadata().unwrap().len() > 10_000);

    // The same directory again is refused: runs never mix their histories.
    let again = shoal(dir.path())
        .args([
            "scenario",
            "run",
            "two-boats.toml",
            "--domain",
            "113",
            "--out",
            "run",
        ])
        .output()
        .unwrap();
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("not empty"));
}

#[test]
fn a_bad_scenario_is_one_line_and_nothing_starts() {
    let dir = tempfile::tempdir().unwrap();
    let bad = SCENARIO.replace("vehicle = \"usv-7\"", "vehicle = \"usv-9\"");
    std::fs::write(dir.path().join("bad.toml"), bad).unwrap();
    let out = shoal(dir.path())
        .args([
            "scenario", "run", "bad.toml", "--domain", "113", "--out", "run",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    let errors: Vec<&str> = stderr.lines().filter(|l| l.contains("error")).collect();
    assert_eq!(errors.len(), 1, "{stderr}");
    assert!(
        errors[0].contains("usv-9") && errors[0].contains("line"),
        "{stderr}"
    );
    assert!(!dir.path().join("run").exists(), "nothing was created");
}

/// The shipped acoustic scenario: an AUV heard only through the emulated acoustic relay,
/// its link cut for two minutes, its computer failed and restarted, and the relay's modem
/// failed for one minute, all at 60x; with `[recorder] acoustic` on, the relay's frames
/// recorded beside the DDS samples.
#[test]
fn an_acoustic_vehicle_runs_its_tasks_through_the_relay_across_outages() {
    let dir = tempfile::tempdir().unwrap();
    let out = shoal(dir.path())
        .env("SHOAL_RECORDER__ACOUSTIC", "true")
        .args([
            "scenario",
            "run",
            "acoustic-relay",
            "--speed",
            "60",
            "--duration",
            "1200",
        ])
        .args(["--domain", "114", "--out", "run"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let run = dir.path().join("run");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap();
    // The station heard the AUV only through the relay, and it moved.
    let auv = &summary["vehicles"]["auv-ac1"];
    assert!(auv["states"].as_u64().unwrap() > 100, "{summary}");
    assert!(auv["distance_m"].as_f64().unwrap() > 200.0, "{summary}");
    // Its first two waypoints went over the acoustic link and were done, the second
    // one sent after the first ended, across the link outage.
    for key in ["acoustic-transect/1", "acoustic-transect/2"] {
        assert_eq!(summary["task_outcomes"][key]["state"], "done", "{summary}");
    }
    // Both faults happened, and the sea counted what the outage cost.
    let faults = summary["faults"].as_array().unwrap();
    let said: Vec<&str> = faults.iter().map(|f| f["what"].as_str().unwrap()).collect();
    assert!(
        said.iter()
            .any(|w| w.contains("auv-ac1's acoustic link is cut")),
        "{said:?}"
    );
    assert!(
        said.iter().any(|w| w.contains("the relay's modem fails")),
        "{said:?}"
    );
    // Its computer failed and started again behind the same modem: nothing failed.
    assert!(
        said.iter().any(|w| w.contains("auv-ac1 starts again")),
        "{said:?}"
    );
    assert!(summary["tasks"].get("failed").is_none(), "{summary}");
    let up = &summary["acoustic_links"]["auv-ac1>relay"];
    assert!(up["delivered"].as_u64().unwrap() > 100, "{summary}");
    assert!(up["outage"].as_u64().unwrap() > 10, "{summary}");
    let pct = up["delivery_pct"].as_f64().unwrap();
    assert!((50.0..100.0).contains(&pct), "{summary}");
    assert!(
        summary["acoustic_links"]["relay>auv-ac1"]["delivered"]
            .as_u64()
            .unwrap()
            >= 2,
        "the tasks went down the link: {summary}"
    );
    // The relayed states' age on arrival: the VDT sends the freshest every 2 s, so about
    // a second or two, never near the station's 30 s contact timeout.
    let age = &summary["acoustic_latency"]["auv-ac1"];
    assert!(age["samples"].as_u64().unwrap() > 100, "{summary}");
    let p50 = age["p50_s"].as_f64().unwrap();
    assert!((0.1..10.0).contains(&p50), "{summary}");
    let used = summary["acoustic_channel_use_pct"].as_f64().unwrap();
    assert!((0.5..60.0).contains(&used), "{summary}");
    assert!(summary["acoustic_airtime_s"]["relay"].as_f64().unwrap() > 0.0);
    let html = std::fs::read_to_string(run.join("report.html")).unwrap();
    assert!(html.contains("<h2>Acoustic network</h2>") && html.contains("auv-ac1 → relay"));
    assert!(html.contains("State vector age on reaching the station"));
    assert!(html.contains("aria-label=\"Acoustic link quality (RSSI at the relay)\""));

    // The DDS recording and, under their own prefix, the relay's frames and link events.
    let mut dds_files = 0;
    let mut acoustic = Vec::new();
    for entry in std::fs::read_dir(run.join("recording")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        if name.starts_with("shoal-acoustic-") {
            acoustic.push(path);
        } else if name.starts_with("shoal-") {
            dds_files += 1;
        }
    }
    assert_eq!(dds_files, 1);
    assert!(!acoustic.is_empty(), "no acoustic recording");
    if let Some(python) = crate::recorder::python_with_mcap() {
        let found = crate::recorder::check_acoustic_mcap(&python, &acoustic);
        // Hundreds of the AUV's frames at the relay, the tasks down, their fates.
        assert!(
            found["directions"]["received"].as_u64().unwrap() > 100,
            "{found}"
        );
        assert!(
            found["pdu_types"]["identified_task"].as_u64().unwrap() >= 2,
            "{found}"
        );
        assert!(
            found["events"]["delivered"].as_u64().unwrap() >= 2,
            "{found}"
        );
        assert_eq!(found["invalid"], serde_json::json!([]), "{found}");
    }
}
