//! Interop with PyPI `pyais`: tests/traffic/ais_encode.py encodes AIS messages of types 1,
//! 2, 3, 5 (two sentences), 18, 19, 24A and 24B with known fields; they go to a running
//! `TrafficPicture` over a real UDP socket and over a TCP server it connects to (and
//! reconnects to), mixed with corrupted lines; each target must read back as encoded.
//!
//! Without the repository's `.venv` or pyais the test is skipped with the reason printed,
//! unless `SHOAL_INTEROP_REQUIRED=1`, when it fails.

// A test: a failed step is a failed test, so it panics with the reason.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use serde_json::Value;
use shoal_traffic::{Class, TargetView, TrafficConfig, TrafficPicture};
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpListener, UdpSocket};
use tokio_util::sync::CancellationToken;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The encoder's JSON output, or why it cannot run here.
fn encode() -> Result<Value, String> {
    let python = repo().join(".venv/bin/python");
    if !python.exists() {
        return Err(format!(
            "{} not found: run scripts/install-test-deps.sh",
            python.display()
        ));
    }
    let probe = Command::new(&python)
        .args(["-c", "import pyais"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !probe.success() {
        return Err("Python module pyais is not installed in .venv".into());
    }
    let out = Command::new(&python)
        .arg(repo().join("tests/traffic/ais_encode.py"))
        .output()
        .expect("run ais_encode.py");
    assert!(
        out.status.success(),
        "ais_encode.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Ok(serde_json::from_slice(&out.stdout).expect("ais_encode.py prints JSON"))
}

/// `line` with its checksum recomputed after an edit.
fn resum(line: &str) -> String {
    let body = &line[1..line.rfind('*').unwrap()];
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("{}{body}*{sum:02X}", &line[..1])
}

fn lines(m: &Value) -> Vec<String> {
    m["lines"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| l.as_str().unwrap().to_string())
        .collect()
}

fn approx(got: Option<f64>, want: &Value, tol: f64, what: &str, mmsi: u64) {
    let want = want.as_f64().unwrap();
    let got = got.unwrap_or_else(|| panic!("{mmsi}: {what} missing"));
    assert!(
        (got - want).abs() <= tol,
        "{mmsi}: {what} is {got}, pyais encoded {want}"
    );
}

/// Asserts that `t` holds every field in `expect`.
fn check(t: &TargetView, expect: &Value) {
    let mmsi = expect["mmsi"].as_u64().unwrap();
    let e = expect.as_object().unwrap();
    for (key, want) in e {
        match key.as_str() {
            "mmsi" => assert_eq!(u64::from(t.mmsi), mmsi),
            // AIS resolution: 1/10000 minute of arc, 0.1 kn, 0.1°, 1° heading.
            "lat" => approx(t.lat, want, 1.0 / 600_000.0 + 1e-9, key, mmsi),
            "lon" => approx(t.lon, want, 1.0 / 600_000.0 + 1e-9, key, mmsi),
            "sog_kn" => approx(t.sog_kn, want, 0.1 + 1e-9, key, mmsi),
            "cog_deg" => approx(t.cog_deg, want, 0.1 + 1e-9, key, mmsi),
            "heading_deg" if want.is_null() => assert_eq!(t.heading_deg, None, "{mmsi}"),
            "heading_deg" => approx(t.heading_deg, want, 0.0, key, mmsi),
            "nav_status" => assert_eq!(
                t.nav_status.map(u64::from),
                want.as_u64(),
                "{mmsi}: nav_status"
            ),
            "klass" => {
                let want = if want == "A" { Class::A } else { Class::B };
                assert_eq!(t.class, Some(want), "{mmsi}: class");
            }
            "name" => assert_eq!(t.name.as_deref(), want.as_str(), "{mmsi}: name"),
            "call_sign" => assert_eq!(t.call_sign.as_deref(), want.as_str(), "{mmsi}: call sign"),
            "imo" => assert_eq!(t.imo.map(u64::from), want.as_u64(), "{mmsi}: IMO"),
            "ship_type" => assert_eq!(
                t.ship_type.map(u64::from),
                want.as_u64(),
                "{mmsi}: ship type"
            ),
            "dimensions" => {
                let d = t
                    .dimensions
                    .unwrap_or_else(|| panic!("{mmsi}: no dimensions"));
                let got = serde_json::to_value(d).unwrap();
                assert_eq!(&got, want, "{mmsi}: dimensions");
            }
            other => panic!("ais_encode.py gave an unknown field {other}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pyais_messages_over_udp_and_tcp() {
    let encoded = match encode() {
        Ok(v) => v,
        Err(reason) => {
            assert!(
                std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
                "pyais interop is required (SHOAL_INTEROP_REQUIRED=1) but cannot run: {reason}"
            );
            eprintln!("SKIPPED: pyais interop cannot run: {reason}");
            return;
        }
    };
    let messages = encoded["messages"].as_array().unwrap().clone();
    assert_eq!(messages.len(), 8, "types 1, 2, 3, 18, 19, 5, 24A, 24B");

    let server = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let tcp_port = server.local_addr().unwrap().port();
    let config: TrafficConfig = serde_json::from_value(serde_json::json!({
        "inputs": ["udp://127.0.0.1:0", format!("tcp://127.0.0.1:{tcp_port}")],
        "reconnect_min_ms": 100,
        "reconnect_max_ms": 400,
    }))
    .unwrap();
    let cancel = CancellationToken::new();
    let handle = TrafficPicture::spawn(config, cancel.clone()).unwrap();
    let udp_to = handle.udp_addrs()[0];
    let udp = UdpSocket::bind("127.0.0.1:0").await.unwrap();

    // Types 1, 3, 19 and 24A (and the second half of the split below) over UDP; 2, 18, 5
    // over the first TCP connection; 24B over a second one after the server hung up.
    let by_type = |t: &str| {
        messages
            .iter()
            .find(|m| m["type"].to_string().trim_matches('"') == t)
            .unwrap_or_else(|| panic!("no type {t}"))
    };
    for t in ["1", "3", "19", "24A"] {
        let datagram = lines(by_type(t)).join("\r\n") + "\r\n";
        udp.send_to(datagram.as_bytes(), udp_to).await.unwrap();
    }
    // Corrupted over UDP: a flipped payload character (bad checksum), garbage, an
    // over-long line; then a good line in the same datagram must still land.
    let good1 = lines(by_type("1")).remove(0);
    let flipped = good1.replacen("13KF5P", "13KF5Q", 1);
    let long = format!("{good1}{}", "0".repeat(600));
    let mixed = format!("{flipped}\r\nnot nmea at all\r\n{long}\r\n{good1}\r\n");
    udp.send_to(mixed.as_bytes(), udp_to).await.unwrap();

    let (mut conn, _) = tokio::time::timeout(Duration::from_secs(10), server.accept())
        .await
        .expect("the picture connects")
        .unwrap();
    let mut stream = String::new();
    for t in ["2", "18", "5"] {
        for l in lines(by_type(t)) {
            stream.push_str(&l);
            stream.push_str("\r\n");
        }
    }
    // A fragment whose first part never came, and a truncated sentence.
    let t5 = lines(by_type("5"));
    stream.push_str(&resum(&t5[1].replace(",3,B,", ",7,B,")));
    stream.push_str("\r\n");
    stream.push_str(&good1[..good1.len() - 5]);
    stream.push_str("\r\n");
    // In small pieces, so that lines are split across reads.
    for chunk in stream.as_bytes().chunks(7) {
        conn.write_all(chunk).await.unwrap();
        conn.flush().await.unwrap();
    }
    wait_for(&handle, 230_000_005, |t| t.name.is_some()).await;
    drop(conn);

    let (mut conn, _) = tokio::time::timeout(Duration::from_secs(10), server.accept())
        .await
        .expect("the picture reconnects")
        .unwrap();
    for l in lines(by_type("24B")) {
        conn.write_all(format!("{l}\r\n").as_bytes()).await.unwrap();
    }
    wait_for(&handle, 230_000_024, |t| t.call_sign.is_some()).await;

    for m in &messages {
        let mmsi = u32::try_from(m["expect"]["mmsi"].as_u64().unwrap()).unwrap();
        let t = handle
            .target(mmsi)
            .unwrap_or_else(|| panic!("no target {mmsi}"));
        check(&t, &m["expect"]);
    }
    assert_eq!(handle.targets().len(), 7, "24A and 24B are one vessel");

    let s = handle.stats();
    eprintln!("{}", serde_json::to_string(&s).unwrap());
    assert_eq!(s.bad_checksum, 1, "{s:?}");
    assert_eq!(s.garbage, 1, "{s:?}");
    assert_eq!(s.too_long, 1, "{s:?}");
    assert_eq!(s.fragment_out_of_order, 1, "{s:?}");
    assert_eq!(s.no_checksum, 1, "truncated line: {s:?}");
    assert_eq!(
        s.ais_messages, 9,
        "8 messages and the repeated type 1: {s:?}"
    );
    assert_eq!(s.udp_datagrams, 5);
    assert_eq!(s.tcp_connects, 2);
    assert!(s.tcp_failures >= 1);

    cancel.cancel();
    tokio::time::timeout(Duration::from_secs(5), handle.join())
        .await
        .expect("inputs stop on cancel");
}

async fn wait_for(
    handle: &shoal_traffic::TrafficHandle,
    mmsi: u32,
    ready: impl Fn(&TargetView) -> bool,
) {
    for _ in 0..200 {
        if handle.target(mmsi).is_some_and(|t| ready(&t)) {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!(
        "target {mmsi} not complete after 10 s; stats {:?}",
        handle.stats()
    );
}
