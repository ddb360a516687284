//! Site identity over mutual TLS, in one process: a shore `Federation` listening on
//! `tls/127.0.0.1`, the genuine ship's `Federation` connecting with its certificate, and
//! raw Zenoh sessions presenting what no genuine site would: an expired certificate, and
//! a valid certificate whose common name is not one of the shore's `remote_sites`.
//! Certificates come from a station key store's CA, as `shoal keys site-cert` issues them.

use std::path::{Path, PathBuf};
use std::time::Duration;

use shoal_federation::{
    Federation, FederationConfig, LeaseReason, LeaseRecord, TlsConfig, keys, signed, wire,
};
use shoal_security::{KeyStore, SiteName, StoreOptions};

use crate::common::*;

const DAY_MS: i64 = 86_400_000;

/// One CA, and the site certificates the test needs from it: `ship-expired` (issued 30
/// days ago for 1 day), and valid ones for `shore`, `ship` and `ship7`.
struct Pki {
    _dir: tempfile::TempDir,
    ca: PathBuf,
    out: PathBuf,
    expired: PathBuf,
}

impl Pki {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let store_dir = dir.path().join("store");
        let names = [SiteName::parse("127.0.0.1").unwrap()];
        let past = shoal_model::now_ms() - 30 * DAY_MS;
        let options = StoreOptions {
            cert_validity_days: 1,
            ..StoreOptions::default()
        };
        let old = KeyStore::init_with(&store_dir, "ccs", &options, Some(past)).unwrap();
        let expired = dir.path().join("expired");
        old.issue_site("ship", &names, &expired).unwrap();
        let store = KeyStore::open_at(&store_dir, shoal_model::now_ms()).unwrap();
        let out = dir.path().join("sites");
        for site in ["shore", "ship", "ship7"] {
            store.issue_site(site, &names, &out).unwrap();
        }
        Self {
            ca: out.join("shore-ca.crt"),
            out,
            expired,
            _dir: dir,
        }
    }

    fn tls(&self, site: &str) -> TlsConfig {
        TlsConfig {
            enabled: true,
            certificate: self.out.join(format!("{site}.crt")),
            private_key: self.out.join(format!("{site}.key")),
            trusted_cas: self.ca.clone(),
            verify_name: true,
        }
    }
}

/// A raw Zenoh peer connecting over TLS to `port` with `cert` and `key`.
async fn raw_tls_peer(port: u16, ca: &Path, cert: &Path, key: &Path) -> zenoh::Session {
    let quoted = |p: &Path| format!("{:?}", p.display().to_string());
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""peer""#.to_string()),
        ("listen/endpoints", "[]".into()),
        ("connect/endpoints", format!(r#"["tls/127.0.0.1:{port}"]"#)),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
        ("transport/link/tls/root_ca_certificate", quoted(ca)),
        ("transport/link/tls/connect_certificate", quoted(cert)),
        ("transport/link/tls/connect_private_key", quoted(key)),
        ("transport/link/tls/enable_mtls", "true".into()),
    ] {
        c.insert_json5(k, &v).unwrap();
    }
    zenoh::open(c).await.unwrap()
}

fn vehicles(fed: &Federation) -> Vec<String> {
    fed.picture(|p| {
        p.vehicles()
            .map(|v| format!("{}/{}", v.site, v.position.vehicle_id))
            .collect()
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_expired_certificate_and_an_unknown_common_name_never_reach_the_shore() {
    logs();
    let pki = Pki::new();
    let port = free_port();
    let shore = Federation::start(FederationConfig {
        site: "shore".into(),
        listen: vec![format!("tls/127.0.0.1:{port}")],
        remote_sites: vec!["ship".into()],
        tls: pki.tls("shore"),
        ..unkept()
    })
    .await
    .unwrap();
    assert_eq!(shore.identity(), "tls");
    let ship = Federation::start(FederationConfig {
        site: "ship".into(),
        listen: vec![],
        connect: vec![format!("tls/127.0.0.1:{port}")],
        remote_sites: vec!["shore".into()],
        positions: shoal_federation::config::PositionsPolicy {
            max_rate_hz: 10.0,
            ..Default::default()
        },
        tls: pki.tls("ship"),
        ..unkept()
    })
    .await
    .unwrap();
    eventually("the sites to see each other over TLS", || {
        sees(&shore, "ship") && sees(&ship, "shore")
    })
    .await;

    // The expired ship certificate (same CA, same name) and ship7's (valid, same CA,
    // a name the shore does not accept), each publishing as site ship.
    let expired = raw_tls_peer(
        port,
        &pki.ca,
        &pki.expired.join("ship.crt"),
        &pki.expired.join("ship.key"),
    )
    .await;
    let ship7 = raw_tls_peer(
        port,
        &pki.ca,
        &pki.out.join("ship7.crt"),
        &pki.out.join("ship7.key"),
    )
    .await;
    let frame = |v: &str| wire::encode_position(&position(v, 43.0)).unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    let mut n = 0;
    while tokio::time::Instant::now() < deadline || !vehicles(&shore).contains(&"ship/auv-1".into())
    {
        ship.push_position(position("auv-1", 43.0 + f64::from(n) * 1e-4))
            .unwrap();
        n += 1;
        expired
            .put("shoal/ship/vehicles/expired-1/position", frame("expired-1"))
            .await
            .unwrap();
        ship7
            .put("shoal/ship/vehicles/seven-1/position", frame("seven-1"))
            .await
            .unwrap();
        let seen = vehicles(&shore);
        assert!(
            seen.iter().all(|v| v == "ship/auv-1"),
            "a refused peer reached the shore: {seen:?}"
        );
        assert!(n < 300, "the genuine ship never reached the shore");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Zenoh refused or denied them before the federation: nothing to count.
    let refused = shore.counters().inbound.refused;
    assert!(refused.is_empty(), "{refused:?}");
    for s in [expired, ship7] {
        s.close().await.unwrap();
    }
    ship.shutdown().await.unwrap();
    shore.shutdown().await.unwrap();
}

#[tokio::test]
async fn a_bad_tls_file_stops_the_start_naming_its_key() {
    let pki = Pki::new();
    let config = FederationConfig {
        site: "ship".into(),
        listen: vec![],
        connect: vec!["tls/127.0.0.1:1".into()],
        remote_sites: vec!["shore".into()],
        tls: TlsConfig {
            private_key: pki.out.join("shore.key"),
            ..pki.tls("ship")
        },
        ..unkept()
    };
    let e = Federation::start(config).await.unwrap_err().to_string();
    assert!(e.starts_with("federation.tls.private_key:"), "{e}");
    // An expired certificate of this site's own is refused at start too.
    let config = FederationConfig {
        site: "ship".into(),
        listen: vec![],
        connect: vec!["tls/127.0.0.1:1".into()],
        remote_sites: vec!["shore".into()],
        tls: TlsConfig {
            certificate: pki.expired.join("ship.crt"),
            private_key: pki.expired.join("ship.key"),
            ..pki.tls("ship")
        },
        ..unkept()
    };
    let e = Federation::start(config).await.unwrap_err().to_string();
    assert!(
        e.starts_with("federation.tls.certificate:") && e.contains("expired"),
        "{e}"
    );
}

/// A raw Zenoh router listening over TLS on `port` with `site`'s certificate, relaying
/// whatever its clients send and policing nothing: a compromised or careless router.
async fn raw_tls_router(port: u16, pki: &Pki, site: &str) -> zenoh::Session {
    let tls = pki.tls(site);
    let quoted = |p: &Path| format!("{:?}", p.display().to_string());
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""router""#.to_string()),
        ("listen/endpoints", format!(r#"["tls/127.0.0.1:{port}"]"#)),
        ("connect/endpoints", "[]".into()),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
        (
            "transport/link/tls/root_ca_certificate",
            quoted(&tls.trusted_cas),
        ),
        (
            "transport/link/tls/listen_certificate",
            quoted(&tls.certificate),
        ),
        (
            "transport/link/tls/listen_private_key",
            quoted(&tls.private_key),
        ),
        ("transport/link/tls/enable_mtls", "true".into()),
    ] {
        c.insert_json5(k, &v).unwrap();
    }
    zenoh::open(c).await.unwrap()
}

/// A ship: a client of the router on `port`, home of its vehicles, over TLS.
fn tls_ship(pki: &Pki, site: &str, port: u16, other: &str) -> FederationConfig {
    let mut c = FederationConfig {
        site: site.into(),
        mode: shoal_federation::config::Mode::Client,
        listen: vec![],
        connect: vec![format!("tls/127.0.0.1:{port}")],
        remote_sites: vec!["shore".into(), other.into()],
        tls: pki.tls(site),
        ..unkept()
    };
    c.lease.home = true;
    c.lease.settle_ms = 1_000;
    c
}

/// The router between two ships holds a trusted certificate (the shore's), so the ships'
/// links accept it, and a client does not police what its router relays. The lease
/// records cross signed by the ship that made them: the router's forgeries of one ship's
/// records (unsigned, or signed with its own key) are refused and counted by the other,
/// and the genuine records, checked against the maker's certificate fetched through the
/// same router, are taken.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_router_cannot_forge_a_sites_lease_records() {
    logs();
    let pki = Pki::new();
    let port = free_port();
    let router = raw_tls_router(port, &pki, "shore").await;
    let ship = Federation::start(tls_ship(&pki, "ship", port, "ship7"))
        .await
        .unwrap();
    let ship7 = Federation::start(tls_ship(&pki, "ship7", port, "ship"))
        .await
        .unwrap();
    eventually("the ships to see each other through the router", || {
        sees(&ship, "ship7") && sees(&ship7, "ship")
    })
    .await;
    ship.push_position(position("auv-1", 43.0)).unwrap();
    ship7.push_position(position("auv-7", 43.1)).unwrap();
    eventually("each ship to learn the other's signed lease", || {
        holder(&ship7, "auv-1") == Some(("ship".into(), 1))
            && holder(&ship, "auv-7") == Some(("ship7".into(), 1))
    })
    .await;
    assert!(ship7.counters().inbound.identities >= 1);

    // The router forges the ship handing auv-1 over to the shore: the holder's own
    // change, which ship7 would take from the ship.
    let forged = LeaseRecord {
        vehicle_id: "auv-1".into(),
        term: 2,
        holder: "shore".into(),
        home: "ship".into(),
        standby: String::new(),
        reason: LeaseReason::Handover,
        granted_ms: shoal_model::now_ms(),
    };
    let key = keys::lease("ship", "auv-1");
    let unsigned = wire::encode_lease(&forged).unwrap();
    let mut signed_by_router = unsigned.clone();
    let shore_key = {
        use rustls::pki_types::PrivateKeyDer;
        use rustls::pki_types::pem::PemObject;
        let pem = std::fs::read(pki.tls("shore").private_key).unwrap();
        rustls::crypto::ring::sign::any_supported_type(
            &PrivateKeyDer::from_pem_slice(&pem).unwrap(),
        )
        .unwrap()
    };
    signed::seal(&mut signed_by_router, &key, |m| {
        let signer = shore_key
            .choose_scheme(&[rustls::SignatureScheme::ED25519])
            .unwrap();
        Ok::<_, rustls::Error>((u16::from(signer.scheme()), signer.sign(m)?))
    })
    .unwrap();
    let refused = |reason| ship7.counters().inbound.refused(reason);
    let deadline = tokio::time::Instant::now() + PATIENCE;
    while refused("signature:unsigned") == 0 || refused("signature:bad") == 0 {
        assert!(tokio::time::Instant::now() < deadline, "forgeries not seen");
        router.put(&key, unsigned.clone()).await.unwrap();
        router.put(&key, signed_by_router.clone()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert_eq!(holder(&ship7, "auv-1"), Some(("ship".into(), 1)));

    // The genuine handover crosses the same router.
    ship.hand_over("auv-1", "ship7").unwrap();
    eventually("ship7 to take the genuine handover", || {
        ship7.may_command("auv-1") == Ok(2)
    })
    .await;
    router.close().await.unwrap();
    ship.shutdown().await.unwrap();
    ship7.shutdown().await.unwrap();
}
