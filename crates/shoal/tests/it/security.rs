//! Security end to end with the `shoal` binary: `shoal up` is secured by default (OMG DDS
//! Security; the key store made on first run, every vehicle with its own identity, the
//! acoustic AUV relayed by the CDT as the station), an intruder without credentials on the
//! same domain is never heard, `shoal keys revoke` takes effect in the running station, and
//! credentials that are missing or wrong stop a process with one clear line. Domain 59.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::http_get;

fn shoal() -> Command {
    Command::new(env!("CARGO_BIN_EXE_shoal"))
}

/// The count of `reason` in the station's rejection statistics.
fn rejected(port: u16, reason: &str) -> u64 {
    let Ok(body) = http_get(port, "/api/stats") else {
        return 0;
    };
    let Ok(v) = serde_json::from_str::<serde_json::Value>(&body) else {
        return 0;
    };
    v["ingest"]["rejected"][reason].as_u64().unwrap_or(0)
}

/// Polls `check` every 500 ms for at most `secs` seconds.
fn wait_for(secs: u64, mut check: impl FnMut() -> bool) -> bool {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while Instant::now() < deadline {
        if check() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    false
}

struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        for _ in 0..100 {
            if matches!(self.0.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = self.0.kill();
    }
}

#[test]
fn a_secure_fleet_works_and_outsiders_or_revoked_vehicles_are_not_heard() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let env = [
        ("SHOAL_DDS__DOMAIN_ID", "59".to_string()),
        ("SHOAL_CONSOLE__LISTEN", format!("127.0.0.1:{port}")),
        ("SHOAL_CONSOLE__AUTH__ENABLED", "false".to_string()),
        ("SHOAL_SECURITY__CRL_CHECK_S", "1".to_string()),
    ];
    let log_path = dir.path().join("up.log");
    let up = KillOnDrop(
        shoal()
            .args(["up"])
            .current_dir(dir.path())
            .envs(env.iter().cloned())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log_path).unwrap())
            .spawn()
            .unwrap(),
    );
    let all_alive = wait_for(60, || {
        http_get(port, "/api/fleet").is_ok_and(|b| {
            b.matches("\"contact\":\"alive\"").count() == 5 && b.contains("\"link\":\"acoustic\"")
        })
    });
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    assert!(
        all_alive,
        "the secured fleet never showed as alive: {:?}\n{}",
        http_get(port, "/api/fleet"),
        log()
    );
    let keys = dir.path().join("shoal-data/keys/dds");
    assert!(keys.join("private/identity_ca.key.pem").exists());
    assert!(keys.join("enclaves/shoal/station/permissions.p7s").exists());
    assert!(
        dir.path()
            .join("shoal-data/bundles/auv-1/dds/key.pem")
            .exists()
    );
    assert!(log().contains("identity=/shoal/vehicle/auv-1"), "{}", log());

    // A vehicle with security off on the same domain: it cannot even join the secured
    // participants, so nothing it says is heard.
    let intruder = KillOnDrop(
        shoal()
            .args(["--insecure", "vehicle", "--sim", "auv", "--id", "intruder"])
            .current_dir(dir.path())
            .envs(env.iter().cloned())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    std::thread::sleep(Duration::from_secs(8));
    drop(intruder);
    let fleet = http_get(port, "/api/fleet").unwrap();
    assert!(!fleet.contains("intruder"), "{fleet}");

    // A revocation list damaged on disk is logged and ignored: nobody is refused.
    let revoked = keys.join("revoked.toml");
    let good = std::fs::read(&revoked).unwrap();
    std::fs::write(&revoked, b"revoked = 3\n").unwrap();
    assert!(
        wait_for(15, || log().contains("new revocation list ignored")),
        "the damaged list was not reported: {}",
        log()
    );
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(rejected(port, "security:revoked"), 0);
    std::fs::write(&revoked, good).unwrap();

    // Revoking a vehicle takes effect in the running station.
    let out = shoal()
        .args(["keys", "revoke", "auv-2", "--reason", "key-compromise"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    assert!(
        wait_for(30, || rejected(port, "security:revoked") > 0),
        "auv-2's samples were not refused after revocation"
    );
    let refused_before = rejected(port, "security:revoked");
    assert!(
        wait_for(15, || rejected(port, "security:revoked") > refused_before),
        "auv-2 kept being refused"
    );
    let fleet = http_get(port, "/api/fleet").unwrap();
    assert!(
        fleet.matches("\"contact\":\"alive\"").count() >= 4,
        "{fleet}"
    );
    drop(up);
}

/// Runs `shoal <args>` in `dir` with `env`; it must fail. Its stderr.
fn refused(dir: &std::path::Path, args: &[&str], env: &[(&str, &str)]) -> String {
    let out = shoal()
        .args(args)
        .current_dir(dir)
        .env("SHOAL_DDS__DOMAIN_ID", "59")
        .envs(env.iter().copied())
        .output()
        .unwrap();
    assert!(!out.status.success(), "shoal {args:?} started");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn missing_or_wrong_credentials_stop_a_process_with_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    // A vehicle with no bundle and no key store here: says how to get credentials.
    let err = refused(
        dir.path(),
        &["vehicle", "--sim", "auv", "--id", "auv-9"],
        &[],
    );
    assert!(err.contains("shoal keys export auv-9"), "{err}");
    assert!(err.contains("--insecure"), "{err}");

    let init = shoal()
        .args(["keys", "init"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(init.status.success(), "{init:?}");
    let issue = shoal()
        .args(["keys", "issue", "auv-1"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(issue.status.success(), "{issue:?}");
    let export = shoal()
        .args(["keys", "export", "auv-1", "bundle-1"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(export.status.success(), "{export:?}");

    // Another vehicle's bundle.
    let err = refused(
        dir.path(),
        &["vehicle", "--sim", "auv", "--id", "auv-2"],
        &[("SHOAL_SECURITY__BUNDLE", "bundle-1")],
    );
    assert!(
        err.contains("/shoal/vehicle/auv-1") && err.contains("auv-2"),
        "{err}"
    );

    // A tampered permissions document: named, and nothing starts half-secured.
    let perms = dir.path().join("bundle-1/dds/permissions.p7s");
    let text = std::fs::read_to_string(&perms).unwrap();
    std::fs::write(
        &perms,
        text.replace("shoal.vehicle.auv-1", "shoal.vehicle.auv-X"),
    )
    .unwrap();
    let err = refused(
        dir.path(),
        &["vehicle", "--sim", "auv", "--id", "auv-1"],
        &[("SHOAL_SECURITY__BUNDLE", "bundle-1")],
    );
    assert!(err.contains("permissions.p7s"), "{err}");
    assert!(err.contains("permissions CA"), "{err}");

    // Insecure on a real interface: refused unless configured explicitly.
    std::fs::write(
        dir.path().join("lan.toml"),
        "[dds]\ninterfaces = [\"192.0.2.1\"]\n",
    )
    .unwrap();
    let err = refused(
        dir.path(),
        &[
            "--insecure",
            "--config",
            "lan.toml",
            "station",
            "--db",
            ":memory:",
            "--listen",
            "127.0.0.1:0",
        ],
        &[],
    );
    assert!(err.contains("allow_insecure_network"), "{err}");
}
