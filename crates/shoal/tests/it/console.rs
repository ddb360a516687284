//! The console locked down, through the `shoal` binary: logins are on by default, the first
//! admin's password and token appear once on the terminal and never in a log line, and
//! `shoal query` reaches the API with `--token` or `SHOAL_TOKEN`.

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::free_port;

fn shoal() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_shoal"));
    // What the test's own environment says about the console must not leak in.
    c.env_remove("SHOAL_TOKEN")
        .env_remove("SHOAL_CONSOLE__AUTH__ENABLED")
        .env_remove("SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD")
        .env_remove("SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_TOKEN");
    c
}

struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// One request over a plain socket; the status code and the body.
fn http(port: u16, request: &str) -> Option<(u16, String)> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    s.write_all(request.as_bytes()).ok()?;
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    let code = out.split(' ').nth(1)?.parse().ok()?;
    Some((code, out.split_once("\r\n\r\n")?.1.to_owned()))
}

fn get(port: u16, path: &str, token: Option<&str>) -> Option<(u16, String)> {
    let auth = token.map_or(String::new(), |t| format!("Authorization: Bearer {t}\r\n"));
    http(
        port,
        &format!(
            "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{auth}Connection: close\r\n\r\n"
        ),
    )
}

/// The value after `label` on the line of the first-start notice that has it.
fn notice_value(stderr: &str, label: &str) -> String {
    stderr
        .lines()
        .find_map(|l| l.trim_start().strip_prefix(label))
        .unwrap_or_else(|| panic!("no {label:?} line in:\n{stderr}"))
        .trim()
        .to_owned()
}

#[test]
fn a_station_requires_logins_by_default_and_shows_the_first_admin_only_on_the_terminal() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let err_path = dir.path().join("station.stderr");
    let station = KillOnDrop(
        shoal()
            .args(["station", "--db", ":memory:"])
            .args(["--listen", &format!("127.0.0.1:{port}")])
            .current_dir(dir.path())
            .env("SHOAL_DDS__DOMAIN_ID", "71")
            // This test is about the console, not DDS security.
            .env("SHOAL_SECURITY__ENABLED", "false")
            .env("RUST_LOG", "info,cyclonedds=warn")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err_path).unwrap())
            .spawn()
            .unwrap(),
    );
    let start = Instant::now();
    while get(port, "/api/health", None).is_none_or(|(c, _)| c != 200) {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "no console within 30 s: {}",
            std::fs::read_to_string(&err_path).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    // Logins are on without any configuration.
    let (code, body) = get(port, "/api/fleet", None).unwrap();
    assert_eq!(code, 401, "{body}");

    let stderr = std::fs::read_to_string(&err_path).unwrap();
    let password = notice_value(&stderr, "password:");
    let token = notice_value(&stderr, "API token:");
    assert!(
        token.starts_with("shoal_") && password.len() >= 10,
        "{stderr}"
    );
    // Each appears once, on the notice's own line: no log line carries it.
    for secret in [&password, &token] {
        let lines: Vec<&str> = stderr
            .lines()
            .filter(|l| l.contains(secret.as_str()))
            .collect();
        assert_eq!(lines.len(), 1, "{lines:?}");
        assert!(
            !lines[0].contains("WARN") && !lines[0].contains("INFO"),
            "{lines:?}"
        );
    }
    assert!(stderr.contains("printed on the terminal"), "{stderr}");
    // Only hashes are stored.
    let users = std::fs::read_to_string(dir.path().join("shoal-data/console-users.json")).unwrap();
    assert!(!users.contains(&password) && !users.contains(&token));

    // The token opens the API; the password logs in (and gets a CSRF token).
    let (code, _) = get(port, "/api/fleet", Some(&token)).unwrap();
    assert_eq!(code, 200);
    let login = format!(r#"{{"user":"admin","password":"{password}"}}"#);
    let (code, body) = http(
        port,
        &format!(
            "POST /api/auth/login HTTP/1.1\r\nHost: localhost:{port}\r\nOrigin: http://localhost:{port}\r\n\
             Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{login}",
            login.len()
        ),
    )
    .unwrap();
    assert_eq!(code, 200, "{body}");
    assert!(body.contains("\"csrf_token\""), "{body}");
    // Another name for this host is refused (DNS rebinding).
    let (code, _) = http(
        port,
        "GET /api/health HTTP/1.1\r\nHost: rebind.example\r\nConnection: close\r\n\r\n",
    )
    .unwrap();
    assert_eq!(code, 421);

    // `shoal query`: refused without a token, with a hint; works with --token or SHOAL_TOKEN.
    let station_arg = format!("127.0.0.1:{port}");
    let query = |extra: &[&str], env_token: Option<&str>| {
        let mut c = shoal();
        c.args(["query", "ASK {}", "--station", &station_arg])
            .args(extra)
            .current_dir(dir.path());
        if let Some(t) = env_token {
            c.env("SHOAL_TOKEN", t);
        }
        c.output().unwrap()
    };
    let out = query(&[], None);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("401") && err.contains("SHOAL_TOKEN"), "{err}");
    for out in [query(&["--token", &token], None), query(&[], Some(&token))] {
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert!(String::from_utf8_lossy(&out.stdout).contains("true"));
    }
    let out = query(&["--token", "shoal_not_a_token"], None);
    assert!(!out.status.success());
    drop(station);
}

/// The console over HTTPS: `shoal query` trusts the console's own certificate from the
/// configuration, or the one `--ca` names; it refuses plain HTTP to a TLS port and a
/// certificate it was not told to trust.
#[test]
fn shoal_query_reaches_a_console_over_tls() {
    let dir = tempfile::tempdir().unwrap();
    let tls = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shoal-console/tests/tls");
    let (cert, key) = (tls.join("localhost.crt"), tls.join("localhost.key"));
    let port = free_port();
    let token = "shoal_tls_query_token_0123456789";
    let listen = format!("127.0.0.1:{port}");
    let with_console = |c: &mut Command| {
        c.current_dir(dir.path())
            .env("SHOAL_CONSOLE__LISTEN", &listen)
            .env("SHOAL_CONSOLE__TLS__CERT", &cert)
            .env("SHOAL_CONSOLE__TLS__KEY", &key);
    };
    let err_path = dir.path().join("station.stderr");
    let mut station = shoal();
    station
        .args(["station", "--db", ":memory:"])
        .env("SHOAL_DDS__DOMAIN_ID", "72")
        .env("SHOAL_SECURITY__ENABLED", "false")
        .env("SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_TOKEN", token)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&err_path).unwrap());
    with_console(&mut station);
    let _station = KillOnDrop(station.spawn().unwrap());

    let query = |args: &[&str], configured: bool| {
        let mut c = shoal();
        c.args(["query", "ASK {}", "--token", token]).args(args);
        if configured {
            with_console(&mut c);
        } else {
            c.current_dir(dir.path());
        }
        c.output().unwrap()
    };
    // From the station's own configuration: HTTPS to console.listen, trusting its cert.
    let start = Instant::now();
    let out = loop {
        let out = query(&[], true);
        if out.status.success() || start.elapsed() > Duration::from_secs(30) {
            break out;
        }
        std::thread::sleep(Duration::from_millis(300));
    };
    assert!(
        out.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&out.stderr),
        std::fs::read_to_string(&err_path).unwrap_or_default()
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("true"));
    // By name, with --ca.
    let url = format!("https://localhost:{port}");
    let ca = cert.display().to_string();
    let out = query(&["--station", &url, "--ca", &ca], false);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // HTTPS without a certificate to trust, plain HTTP to the TLS port, and a CA that did
    // not sign the console's certificate: each refused with a reason.
    let out = query(&["--station", &url], false);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--ca"), "{err}");
    let out = query(&["--station", &format!("http://localhost:{port}")], false);
    assert!(!out.status.success());
    let stranger = dir.path().join("stranger.pem");
    std::fs::write(&stranger, STRANGER_CERT).unwrap();
    let out = query(
        &["--station", &url, "--ca", &stranger.display().to_string()],
        false,
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("no answer"), "{err}");
}

/// A self-signed certificate for another name, which did not sign the console's.
const STRANGER_CERT: &str = include_str!("console_stranger.crt");
