//! The `shoal` binary: configuration errors and `shoal up`.

use std::io::Read;

use crate::common::http_get;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn shoal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_shoal"))
}

#[test]
fn an_invalid_config_file_gives_one_line_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, "[dds]\ndomain_id = \"zero\"\n").unwrap();
    let out = shoal()
        .arg("--config")
        .arg(&path)
        .arg("config")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<_> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].contains("dds.domain_id"), "{err}");
}

/// `shoal vehicle --proxy`: bad flags and a bad settings file are named before anything
/// starts, and the process exits with an error instead of panicking.
#[test]
fn proxy_flags_and_settings_errors_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = shoal().arg("vehicle").args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = run(&[
        "--proxy",
        "imc",
        "--id",
        "v1",
        "--address",
        "not-an-address",
    ]);
    assert!(
        err.contains("--address") && err.contains("HOST:PORT"),
        "{err}"
    );
    let err = run(&["--proxy", "mavlink", "--id", "bad id!"]);
    assert!(err.contains("--id"), "{err}");
    let missing = dir.path().join("missing.toml");
    let err = run(&[
        "--proxy",
        "ros2",
        "--id",
        "v1",
        "--proxy-config",
        missing.to_str().unwrap(),
    ]);
    assert!(err.contains("missing.toml"), "{err}");
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "lost_after_ms = \"soon\"\n").unwrap();
    let err = run(&[
        "--proxy",
        "mavlink",
        "--id",
        "v1",
        "--proxy-config",
        bad.to_str().unwrap(),
    ]);
    assert!(
        err.contains("bad.toml") && err.contains("lost_after_ms"),
        "{err}"
    );
    let err = run(&["--sim", "auv", "--proxy", "imc", "--id", "v1"]);
    assert!(err.contains("cannot be used with"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn an_environment_override_with_a_bad_value_is_named() {
    let out = shoal()
        .arg("config")
        .env("SHOAL_STATION__LOST_AFTER_S", "soon")
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("station.lost_after_s"));
}

#[test]
fn config_prints_the_effective_configuration() {
    let out = shoal()
        .arg("config")
        .env("SHOAL_DDS__DOMAIN_ID", "9")
        .output()
        .unwrap();
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stdout).contains("domain_id = 9"));
}

/// Credentials given in the configuration are shown as set, never printed.
#[test]
fn config_never_prints_a_credential() {
    let token = "an-initial-admin-token-of-at-least-32-characters";
    let out = shoal()
        .arg("config")
        .env("SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_TOKEN", token)
        .env(
            "SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD",
            "a long admin password",
        )
        .env("SHOAL_FEDERATION__PASSWORD", "a federation password")
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    for secret in [token, "a long admin password", "a federation password"] {
        assert!(!text.contains(secret), "{secret:?} printed");
    }
    assert!(
        text.contains("initial_admin_token = \"<redacted>\""),
        "{text}"
    );
}

/// `shoal up` on its own domain and port: the IP vehicles and the acoustic one appear on
/// the API (the latter with an acoustic link), SIGTERM stops all without DDS errors.
#[test]
fn up_starts_the_station_and_fleet_and_stops_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let mut child = shoal()
        .arg("up")
        .current_dir(dir.path())
        .env("SHOAL_DDS__DOMAIN_ID", "63")
        .env("SHOAL_CONSOLE__LISTEN", format!("127.0.0.1:{port}"))
        // Logins are on by default; this test reads the API without credentials.
        .env("SHOAL_CONSOLE__AUTH__ENABLED", "false")
        .env("SHOAL_STATION__SUMMARY_INTERVAL_S", "1")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(40);
    let mut fleet = String::new();
    while Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(500));
        if let Ok(body) = http_get(port, "/api/fleet")
            && body.matches("\"contact\":\"alive\"").count() == 5
            && body.contains("\"link\":\"acoustic\"")
        {
            fleet = body;
            break;
        }
    }
    let pid = child.id().to_string();
    let _ = Command::new("kill").args(["-TERM", &pid]).status();
    let mut status = None;
    for _ in 0..150 {
        if let Some(s) = child.try_wait().unwrap() {
            status = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let mut log = String::new();
    if status.is_none() {
        let _ = child.kill();
    }
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut log)
        .unwrap();
    assert!(
        !fleet.is_empty(),
        "the five vehicles never showed as alive; log:\n{log}"
    );
    // Four vehicles on IP and the submerged one heard through the acoustic relay.
    for id in ["auv-1", "auv-2", "usv-1", "rov-1", "auv-ac1"] {
        assert!(fleet.contains(id), "{id} missing from {fleet}");
    }
    assert!(
        status.is_some_and(|s| s.success()),
        "shoal up did not stop cleanly; log:\n{log}"
    );
    assert!(log.contains("station stopped"), "{log}");
    // An error the DDS library logs (at shutdown or before) is a fault of Shoal's use of it.
    assert!(
        !log.lines()
            .any(|l| l.contains("ERROR") && l.contains("cyclonedds")),
        "{log}"
    );
    assert!(dir.path().join("shoal-data/history.db").exists());
}

/// The commands this project added take bad input with one clear line and an error exit,
/// before anything joins DDS or touches a key store: `shoal keys` (no store, a bad vehicle
/// id, an unknown vehicle, a store twice), `shoal swarm` (out-of-range flags), and
/// `shoal up` asked for unsigned swarm vehicles with security on.
#[test]
fn keys_swarm_and_up_refuse_bad_input_with_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let out = shoal()
            .args(args)
            .current_dir(dir.path())
            .env("SHOAL_DDS__DOMAIN_ID", "54")
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let refused = |args: &[&str], needle: &str| {
        let (ok, err) = run(args);
        assert!(!ok, "shoal {args:?} succeeded");
        let last = err.lines().last().unwrap_or_default();
        assert!(last.starts_with("shoal: error: "), "{err}");
        assert!(last.contains(needle), "{needle:?} not in {last}");
        assert!(!err.contains("panicked"), "{err}");
    };
    refused(&["keys", "list"], "shoal-data/keys: missing");
    refused(
        &["keys", "--dir", "/nonexistent/keys", "issue", "auv-1"],
        "/nonexistent/keys",
    );
    let (ok, err) = run(&["keys", "init"]);
    assert!(ok, "{err}");
    refused(&["keys", "init"], "already holds a key store");
    refused(&["keys", "issue", "bad id"], "not an identifier");
    refused(&["keys", "revoke", "auv-404"], "auv-404");
    refused(&["keys", "export", "auv-404", "out"], "auv-404");
    let (ok, err) = run(&["keys", "issue", "auv-1"]);
    assert!(ok, "{err}");
    refused(
        &["keys", "issue", "auv-1"],
        "already has an active certificate",
    );

    refused(&["swarm", "--count", "0"], "--count 0");
    refused(&["swarm", "--rate", "50"], "--rate 50");
    refused(&["swarm", "--prefix", "no spaces"], "--prefix");
    refused(&["swarm", "--lat", "95"], "--lat 95");
    refused(
        &["up", "--secure", "--sim-vehicles", "10"],
        "--sim-vehicles",
    );

    // `shoal keys governance` signs the configured governance again and copies it into
    // every enclave (here: every topic only signed, state vectors left in the clear).
    let out = shoal()
        .args(["keys", "governance"])
        .current_dir(dir.path())
        .env("SHOAL_SECURITY__GOVERNANCE__DEFAULT", "sign")
        .env(
            "SHOAL_SECURITY__GOVERNANCE__TOPICS",
            "{ \"shoal/state_vector\" = \"none\" }",
        )
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        said.contains("sign by default, shoal/state_vector none"),
        "{said}"
    );
    let keys = dir.path().join("shoal-data/keys/dds");
    let signed = std::fs::read(keys.join("enclaves/governance.p7s")).unwrap();
    for enclave in ["enclaves/shoal/station", "enclaves/shoal/vehicle/auv-1"] {
        assert_eq!(
            std::fs::read(keys.join(enclave).join("governance.p7s")).unwrap(),
            signed,
            "{enclave} holds another governance"
        );
    }
    let text = std::fs::read_to_string(keys.join("enclaves/governance.xml")).unwrap();
    assert!(
        text.contains("<data_protection_kind>SIGN</data_protection_kind>")
            && text.contains("<data_protection_kind>NONE</data_protection_kind>")
            && !text.contains("ENCRYPT"),
        "{text}"
    );

    // A station whose credentials do not fit stops at once; `up` says so without waiting
    // out its 30 s for the API, and the station's own line names the file and the fix.
    let enclaves = dir.path().join("shoal-data/keys/dds/enclaves/shoal");
    std::fs::copy(
        enclaves.join("vehicle/auv-1/permissions.p7s"),
        enclaves.join("station/permissions.p7s"),
    )
    .unwrap();
    let started = Instant::now();
    let (ok, err) = run(&["up", "--no-fleet"]);
    assert!(!ok, "{err}");
    assert!(
        started.elapsed() < Duration::from_secs(20),
        "shoal up took {:?} to notice",
        started.elapsed()
    );
    assert!(
        err.contains("station/permissions.p7s: grants nothing")
            && err.contains("shoal keys renew-station"),
        "{err}"
    );
    let last = err.lines().last().unwrap_or_default();
    assert!(last.contains("the station stopped"), "{last}");
}

/// The short version of `shoal bench endurance` (the long one is run by hand and saved
/// under bench/runs/): it fails if a task ran twice or the clock step changed contact.
/// Domain 92.
#[test]
fn the_endurance_benchmark_runs_short_with_no_task_twice_and_no_contact_change() {
    let out = shoal()
        .args(["bench", "endurance", "--vehicles", "10", "--tasks", "600"])
        .args(["--report-every", "200", "--domain", "92"])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("tasks executed twice, counted by the vehicles: 0"),
        "{stdout}"
    );
    assert!(
        stdout.contains("contact changes caused by the clock step: 0"),
        "{stdout}"
    );
}

/// `shoal scenario check`: a valid file gives one summary line and exit 0; an invalid
/// one a single error line naming the line and the key, and exit 2.
#[test]
fn scenario_check_summarises_or_names_the_line_and_key() {
    let dir = tempfile::tempdir().unwrap();
    let shipped = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenarios/sea-trial.toml"
    );
    let out = shoal()
        .args(["scenario", "check", shipped])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(0), "{out:?}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(stdout.lines().count(), 1, "{stdout}");
    assert!(stdout.contains("5 vehicles (1 acoustic)"), "{stdout}");

    let bad = dir.path().join("bad.toml");
    std::fs::write(
        &bad,
        "[scenario]\nname = \"x\"\n\n[[vehicles]]\nid = \"auv-1\"\nkind = \"auv\"\nlatitude_deg = 63.0\nlongitude_deg = 10.0\n\n[[missions]]\nname = \"m\"\nat_s = 1\n[[missions.tasks]]\nvehicle = \"auv-7\"\nkind = \"surface\"\n",
    )
    .unwrap();
    let out = shoal()
        .args(["scenario", "check"])
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    let lines: Vec<_> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(
        lines[0].contains("line 14") && lines[0].contains("missions[0].tasks[0].vehicle"),
        "{err}"
    );
}
