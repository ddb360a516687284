//! Security end to end with the `shoal` binary: `shoal up --secure` signs everything (the
//! acoustic AUV's data too, relayed by the CDT as the station), an unsigned intruder on the
//! same domain is counted and never shown, `shoal keys revoke` takes effect in the running
//! station, and a station told to be secure without keys refuses to start. Domain 59.

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
fn a_secure_fleet_works_and_unsigned_or_revoked_senders_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let env = [
        ("SHOAL_DDS__DOMAIN_ID", "59".to_string()),
        ("SHOAL_CONSOLE__LISTEN", format!("127.0.0.1:{port}")),
        ("SHOAL_SECURITY__CRL_CHECK_S", "1".to_string()),
    ];
    let log_path = dir.path().join("up.log");
    let up = KillOnDrop(
        shoal()
            .args(["up", "--secure"])
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
    assert!(
        all_alive,
        "the signed fleet never showed as alive: {:?}",
        http_get(port, "/api/fleet")
    );
    assert!(dir.path().join("shoal-data/keys/ca.key").exists());
    assert!(
        dir.path()
            .join("shoal-data/bundles/auv-1/vehicle.key")
            .exists()
    );

    // A vehicle without security on the same domain: refused, counted, never listed.
    let intruder = KillOnDrop(
        shoal()
            .args(["vehicle", "--sim", "auv", "--id", "intruder"])
            .current_dir(dir.path())
            .envs(env.iter().cloned())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    assert!(
        wait_for(30, || rejected(port, "security:unsigned") > 0),
        "unsigned samples were not counted"
    );
    drop(intruder);
    let fleet = http_get(port, "/api/fleet").unwrap();
    assert!(!fleet.contains("intruder"), "{fleet}");

    // A revocation list damaged on disk is logged and ignored: the list in force stays,
    // and nobody is refused because of it.
    let crl = dir.path().join("shoal-data/keys/revoked.crl");
    let good = std::fs::read(&crl).unwrap();
    std::fs::write(&crl, b"-----BEGIN X509 CRL-----\nnot a list\n").unwrap();
    let log = || std::fs::read_to_string(&log_path).unwrap_or_default();
    assert!(
        wait_for(15, || log().contains("new revocation list ignored")),
        "the damaged list was not reported: {}",
        log()
    );
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(rejected(port, "security:revoked"), 0);
    let fleet = http_get(port, "/api/fleet").unwrap();
    assert_eq!(fleet.matches("\"contact\":\"alive\"").count(), 5, "{fleet}");
    std::fs::write(&crl, good).unwrap();

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
    // The other vehicles are unaffected.
    let fleet = http_get(port, "/api/fleet").unwrap();
    assert!(
        fleet.matches("\"contact\":\"alive\"").count() >= 4,
        "{fleet}"
    );
    drop(up);
}

/// Runs `shoal <args>` in `dir` with security on and `env`; it must fail. Its stderr.
fn refused(dir: &std::path::Path, args: &[&str], env: &[(&str, &str)]) -> String {
    let out = shoal()
        .args(args)
        .current_dir(dir)
        .env("SHOAL_SECURITY__ENABLED", "true")
        .env("SHOAL_DDS__DOMAIN_ID", "59")
        .envs(env.iter().copied())
        .output()
        .unwrap();
    assert!(!out.status.success(), "shoal {args:?} started");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

#[test]
fn a_station_told_to_be_secure_without_keys_refuses_to_start() {
    let dir = tempfile::tempdir().unwrap();
    let station = ["station", "--db", ":memory:", "--listen", "127.0.0.1:0"];
    let err = refused(
        dir.path(),
        &station,
        &[("SHOAL_SECURITY__STORE", "missing-keys")],
    );
    assert!(err.contains("missing-keys"), "{err}");
    assert!(err.contains("shoal keys init"), "{err}");

    // A policy file with an error: named with its line.
    let init = shoal()
        .args(["keys", "init"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(init.status.success(), "{init:?}");
    std::fs::write(
        dir.path().join("policy.toml"),
        "[[allow]]\npublisher = \"robot\"\ntopics = [\"*\"]\ninstances = \"any\"\n",
    )
    .unwrap();
    let err = refused(
        dir.path(),
        &station,
        &[("SHOAL_SECURITY__POLICY", "policy.toml")],
    );
    assert!(err.contains("policy.toml: line 2"), "{err}");

    // A vehicle without its bundle says how to make one.
    let err = refused(
        dir.path(),
        &["vehicle", "--sim", "auv", "--id", "auv-9"],
        &[],
    );
    assert!(err.contains("shoal keys export auv-9"), "{err}");
}
