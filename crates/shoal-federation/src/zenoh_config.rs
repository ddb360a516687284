//! The Zenoh configuration of a site, built from `FederationConfig` alone.
//!
//! Every key this crate depends on is set explicitly, so Zenoh's own defaults (which
//! listen on every interface and scout by UDP multicast) never apply.
//!
//! With an [`Identity`], the site authenticates with Zenoh's TLS link and client
//! certificates (`transport/link/tls`: mTLS, the certificate's common name = site name),
//! with Zenoh's user-password scheme (`transport/auth/usrpwd`: username = site name), or
//! both; and polices what remote sites send with Zenoh's access control
//! (`access_control`): on every link with TLS (both ends are identified), on the links it
//! accepts with user-password alone (only the connecting end is identified).

use serde_json::json;
use zenoh::Config;

use crate::config::{FederationConfig, Identity, Mode};
use crate::error::StartError;
use crate::keys::ROOT;

/// What a remote site may send only under its own `shoal/<site>/**`: data, catch-up
/// replies, the catch-up queryable it answers from, its liveliness token.
const WRITES: [&str; 5] = [
    "put",
    "delete",
    "reply",
    "declare_queryable",
    "liveliness_token",
];
/// What a remote site may send under any site's keys: its interest in their data.
const READS: [&str; 4] = [
    "declare_subscriber",
    "query",
    "declare_liveliness_subscriber",
    "liveliness_query",
];

/// Zenoh's queues of the priorities that carry reliable data (`block`): alarms, task
/// transitions, lease records, orders, catch-up.
const RELIABLE_QUEUES: [&str; 5] = [
    "transport/link/tx/queue/size/control",
    "transport/link/tx/queue/size/real_time",
    "transport/link/tx/queue/size/interactive_high",
    "transport/link/tx/queue/size/interactive_low",
    "transport/link/tx/queue/size/data_high",
];
/// Zenoh's queues of the priorities that carry what a newer value replaces (`drop`):
/// positions (`data`) and environment summaries (`background`).
const LATEST_VALUE_QUEUES: [&str; 3] = [
    "transport/link/tx/queue/size/data",
    "transport/link/tx/queue/size/data_low",
    "transport/link/tx/queue/size/background",
];
/// Batches of a latest-value queue: Zenoh's least. A full one drops the newest position
/// rather than keep seconds of stale ones ahead of it (16 of 8 KiB are 16 s of a
/// 64 kbit/s link).
const LATEST_VALUE_BATCHES: u8 = 2;

/// Zenoh's configuration for a (validated) federation configuration and this site's
/// identity (`None` with `insecure_open`).
pub fn zenoh_config(
    c: &FederationConfig,
    identity: Option<&Identity>,
) -> Result<Config, StartError> {
    let mut z = Config::default();
    let json = |v: serde_json::Value| v.to_string();
    let mut settings = vec![
        ("mode", json(c.mode.as_str().into())),
        // Set even when empty: Zenoh's default listens on tcp/[::] (every interface).
        ("listen/endpoints", json(c.listen.clone().into())),
        ("connect/endpoints", json(c.connect.clone().into())),
        (
            "scouting/multicast/enabled",
            json(c.multicast_scouting.into()),
        ),
        ("scouting/gossip/enabled", json(c.gossip.into())),
        // A site works alone while its remotes are unreachable: a peer or router never
        // fails to start for want of a connection and keeps retrying in the background
        // (1 s doubling to 4 s), also after a link is lost. (0 would mean "try once".)
        // A client is different in Zenoh: it waits at start until its router answers.
        ("connect/timeout_ms", json((-1).into())),
        ("connect/exit_on_failure", json(false.into())),
        // Listening on a configured endpoint must work, or the site is misconfigured.
        ("listen/exit_on_failure", json(true.into())),
        // How long a silent link lives: a remote site is seen lost (its liveliness token
        // gone, the command lease's failover clock started) this long after it fell
        // silent. Zenoh sends a keep-alive every quarter of it.
        ("transport/link/tx/lease", json(c.link_lease_ms.into())),
    ];
    if let Some(shaping) = c.link_shaping() {
        // Zenoh's priorities order what waits in its own queues; once written to the
        // socket, data leaves in order. A small send buffer keeps the queue where the
        // priorities act, and small batches bound what an alarm waits behind.
        let send = json(shaping.send_buffer_bytes.into());
        settings.push(("transport/link/tcp/so_sndbuf", send.clone()));
        settings.push(("transport/link/tls/so_sndbuf", send));
        settings.push((
            "transport/link/tx/batch_size",
            json(shaping.batch_bytes.into()),
        ));
        for key in RELIABLE_QUEUES {
            settings.push((key, json(shaping.queue_batches.into())));
        }
        for key in LATEST_VALUE_QUEUES {
            settings.push((key, json(LATEST_VALUE_BATCHES.into())));
        }
    }
    if let Some(id) = identity {
        if polices(c, id) {
            settings.push(("access_control", json(access_control(c, id))));
        }
        if let Some(t) = &id.tls {
            // One certificate for both roles: a site presents it when it listens and when
            // it connects, and checks the other side's against the same trusted CAs.
            // `enable_mtls` makes a listener require and verify the client's certificate
            // (rustls WebPkiClientVerifier over `root_ca_certificate`) and a connecting
            // side present its own; Zenoh then runs TLS 1.3 only. The connecting side
            // verifies the listener's chain against the same CAs (Zenoh 1.10 adds the
            // Mozilla web roots there too: see docs/federation.md) and, with
            // `verify_name_on_connect`, that it names the endpoint's host.
            for (key, value) in [
                ("root_ca_certificate", json(t.trusted_cas.clone().into())),
                ("listen_certificate", json(t.certificate.clone().into())),
                ("listen_private_key", json(t.private_key.clone().into())),
                ("connect_certificate", json(t.certificate.clone().into())),
                ("connect_private_key", json(t.private_key.clone().into())),
                ("enable_mtls", json(true.into())),
                ("verify_name_on_connect", json(t.verify_name.into())),
                // A link ends when a certificate of the peer's chain expires, rather than
                // living on with it.
                ("close_link_on_expiration", json(true.into())),
            ] {
                z.insert_json5(&format!("transport/link/tls/{key}"), &value)
                    .map_err(|source| StartError::Zenoh {
                        what: "configure TLS",
                        source,
                    })?;
            }
        }
        if let Some(up) = &id.usrpwd {
            let usrpwd = json!({
                "user": up.user,
                "password": up.password.expose(),
                "dictionary_file": up.credentials_file,
            });
            // Zenoh's error could quote the value, which holds the password: withheld.
            z.insert_json5("transport/auth/usrpwd", &json(usrpwd))
                .map_err(|_| StartError::Zenoh {
                    what: "configure user-password authentication",
                    source: "refused (details withheld: the value holds the password)".into(),
                })?;
        }
    }
    for (key, value) in settings {
        z.insert_json5(key, &value)
            .map_err(|source| StartError::Zenoh {
                what: "configure",
                source,
            })?;
    }
    Ok(z)
}

/// Whether this site runs Zenoh's access control on its links.
///
/// - With TLS, Zenoh knows the common name of the certificate at the far end of every
///   link, accepted or opened (zenoh-link-tls records it on both sides): every site
///   polices, except a client, whose one link is to a router that relays every site's
///   data under their keys (a client trusts the router it verified by certificate).
/// - With user-password alone, Zenoh knows the username only on the links a site
///   accepts: a site polices only if it listens (and then does not connect, see
///   `FederationConfig::validate`).
pub fn polices(c: &FederationConfig, id: &Identity) -> bool {
    if id.tls.is_some() {
        c.mode != Mode::Client
    } else {
        !c.listen.is_empty()
    }
}

/// Zenoh's access control of a site: each remote site may send data, replies, queryables
/// and liveliness tokens only under `shoal/<its site>/**`, and declare its interest in any
/// `shoal/**` key; this site sends it anything under `shoal/**`. Everything else, and
/// everything from a peer that matches no remote site, is denied both ways.
///
/// A remote site is recognised (its subject) by its certificate's common name with TLS,
/// by its Zenoh username with user-password alone, and by both (the same name twice)
/// when both are on and this site only listens (on links it opens, Zenoh has no
/// username for the far end).
pub fn access_control(c: &FederationConfig, id: &Identity) -> serde_json::Value {
    let every = [WRITES.as_slice(), READS.as_slice()].concat();
    let mut rules = vec![
        json!({
            "id": "shoal-reads",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": READS,
            "key_exprs": [format!("{ROOT}/**")],
        }),
        json!({
            "id": "shoal-sends",
            "permission": "allow",
            "flows": ["egress"],
            "messages": every,
            "key_exprs": [format!("{ROOT}/**")],
        }),
    ];
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    for site in &c.remote_sites {
        rules.push(json!({
            "id": format!("own-{site}"),
            "permission": "allow",
            "flows": ["ingress"],
            "messages": WRITES,
            "key_exprs": [format!("{ROOT}/{site}/**")],
        }));
        let mut subject = json!({ "id": format!("site-{site}") });
        if id.tls.is_some() {
            subject["cert_common_names"] = json!([site]);
        }
        if id.usrpwd.is_some() && (id.tls.is_none() || c.connect.is_empty()) {
            subject["usernames"] = json!([site]);
        }
        subjects.push(subject);
        policies.push(json!({
            "id": format!("site-{site}"),
            "rules": ["shoal-reads", "shoal-sends", format!("own-{site}")],
            "subjects": [format!("site-{site}")],
        }));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Secret, TlsIdentity, UserPassword};

    #[test]
    fn the_zenoh_config_of_the_default_does_not_scout_and_listens_on_loopback() {
        let z = zenoh_config(&FederationConfig::default(), None).unwrap();
        assert_eq!(z.get_json("scouting/multicast/enabled").unwrap(), "false");
        assert_eq!(z.get_json("scouting/gossip/enabled").unwrap(), "false");
        assert_eq!(
            z.get_json("listen/endpoints").unwrap(),
            r#"["tcp/127.0.0.1:7447"]"#
        );
    }

    #[test]
    fn a_slow_link_gets_a_small_send_buffer_and_small_batches_a_fast_one_the_defaults() {
        let fast = zenoh_config(&FederationConfig::default(), None).unwrap();
        assert_eq!(
            fast.get_json("transport/link/tcp/so_sndbuf").unwrap(),
            "null"
        );
        let default_batch = fast.get_json("transport/link/tx/batch_size").unwrap();
        let c = FederationConfig {
            link_rate_kbps: 64,
            ..FederationConfig::default()
        };
        let z = zenoh_config(&c, None).unwrap();
        // 64 kbit/s: 8000 B/s, half a second is under the 4 KiB floor; an eighth, 1000 B,
        // under the 8 KiB one.
        assert_eq!(z.get_json("transport/link/tcp/so_sndbuf").unwrap(), "4096");
        assert_eq!(z.get_json("transport/link/tls/so_sndbuf").unwrap(), "4096");
        assert_eq!(z.get_json("transport/link/tx/batch_size").unwrap(), "8192");
        assert_ne!(default_batch, "8192");
        // 16 batches of 8 KiB for reliable data: 128 KiB, as Zenoh's default two of 64 KiB;
        // the least for positions, which a newer one replaces.
        assert_eq!(parsed(&z, "transport/link/tx/queue/size")["real_time"], 16);
        assert_eq!(parsed(&z, "transport/link/tx/queue/size")["data_high"], 16);
        assert_eq!(parsed(&z, "transport/link/tx/queue/size")["data"], 2);
        assert_eq!(parsed(&z, "transport/link/tx/queue/size")["background"], 2);
        let c = FederationConfig {
            link_rate_kbps: 2_000,
            ..FederationConfig::default()
        };
        let z = zenoh_config(&c, None).unwrap();
        assert_eq!(
            z.get_json("transport/link/tcp/so_sndbuf").unwrap(),
            "125000"
        );
        assert_eq!(z.get_json("transport/link/tx/batch_size").unwrap(), "31250");
        assert_eq!(parsed(&z, "transport/link/tx/queue/size")["real_time"], 4);
    }

    #[test]
    fn a_slow_link_paces_answers_at_a_quarter_and_asks_for_parts_that_fit_the_timeout() {
        use crate::config::{CATCHUP_ITEM_BYTES, LEASE_ITEM_BYTES, LinkShaping};
        let sat = LinkShaping::for_rate(64);
        assert_eq!(sat.bulk_bytes_per_s, 2000);
        // A quarter of 10 s at 2000 B/s: 5000 B, 41 catch-up frames, 50 lease records.
        assert_eq!(sat.part_items(CATCHUP_ITEM_BYTES, 10_000, 100), 41);
        assert_eq!(sat.part_items(LEASE_ITEM_BYTES, 10_000, 100), 50);
        // Never more than configured, never fewer than 10.
        assert_eq!(
            LinkShaping::for_rate(10_000).part_items(100, 10_000, 100),
            100
        );
        assert_eq!(LinkShaping::for_rate(2).part_items(100, 10_000, 100), 10);
        assert_eq!(LinkShaping::for_rate(2).bulk_bytes_per_s, 250);
        // The receiving core asks catch-up in such parts.
        let c = FederationConfig {
            link_rate_kbps: 64,
            remote_sites: vec!["ship".into()],
            ..FederationConfig::default()
        };
        let mut inbound = crate::inbound::Inbound::new(&c);
        let asks = inbound.site_alive(&crate::keys::alive("ship"), true, 0);
        assert!(asks.iter().all(|r| r.limit == 41), "{asks:?}");
    }

    #[test]
    fn a_client_listens_nowhere() {
        let c = FederationConfig {
            mode: Mode::Client,
            listen: vec![],
            connect: vec!["tcp/127.0.0.1:7447".into()],
            ..FederationConfig::default()
        };
        let z = zenoh_config(&c, None).unwrap();
        assert_eq!(z.get_json("mode").unwrap(), r#""client""#);
        assert_eq!(z.get_json("listen/endpoints").unwrap(), "[]");
    }

    fn identity() -> Identity {
        Identity {
            site: "shore".into(),
            usrpwd: Some(UserPassword {
                user: "shore".into(),
                password: Secret::new("pw-shore"),
                credentials_file: "/etc/shoal/sites.txt".into(),
                users: vec!["ship".into(), "ship2".into()],
            }),
            tls: None,
        }
    }

    fn tls_identity(site: &str, usrpwd: bool) -> Identity {
        let mut id = identity();
        id.site = site.into();
        if usrpwd {
            if let Some(up) = id.usrpwd.as_mut() {
                up.user = site.into();
            }
        } else {
            id.usrpwd = None;
        }
        id.tls = Some(TlsIdentity {
            certificate: format!("/etc/shoal/{site}.crt"),
            private_key: format!("/etc/shoal/{site}.key"),
            trusted_cas: "/etc/shoal/trusted-cas.pem".into(),
            verify_name: true,
            not_after_ms: i64::MAX,
        });
        id
    }

    fn parsed(z: &Config, key: &str) -> serde_json::Value {
        serde_json::from_str(&z.get_json(key).unwrap()).unwrap()
    }

    #[test]
    fn a_listening_site_authenticates_and_polices_each_remote_site() {
        let c = FederationConfig {
            site: "shore".into(),
            remote_sites: vec!["ship".into(), "ship2".into()],
            ..FederationConfig::default()
        };
        let z = zenoh_config(&c, Some(&identity())).unwrap();
        assert_eq!(
            parsed(&z, "transport/auth/usrpwd"),
            json!({
                "user": "shore",
                "password": "pw-shore",
                "dictionary_file": "/etc/shoal/sites.txt",
            })
        );
        let writes = json!([
            "put",
            "delete",
            "reply",
            "declare_queryable",
            "liveliness_token"
        ]);
        let reads = json!([
            "declare_subscriber",
            "query",
            "declare_liveliness_subscriber",
            "liveliness_query"
        ]);
        let own = |site: &str| {
            json!({
                "id": format!("own-{site}"),
                "permission": "allow",
                "flows": ["ingress"],
                "messages": writes,
                "key_exprs": [format!("shoal/{site}/**")],
            })
        };
        let policy = |site: &str| {
            json!({
                "id": format!("site-{site}"),
                "rules": ["shoal-reads", "shoal-sends", format!("own-{site}")],
                "subjects": [format!("site-{site}")],
            })
        };
        let expected = json!({
            "enabled": true,
            "default_permission": "deny",
            "rules": [
                {
                    "id": "shoal-reads",
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": reads,
                    "key_exprs": ["shoal/**"],
                },
                {
                    "id": "shoal-sends",
                    "permission": "allow",
                    "flows": ["egress"],
                    "messages": [
                        "put", "delete", "reply", "declare_queryable", "liveliness_token",
                        "declare_subscriber", "query", "declare_liveliness_subscriber",
                        "liveliness_query"
                    ],
                    "key_exprs": ["shoal/**"],
                },
                own("ship"),
                own("ship2"),
            ],
            "subjects": [
                { "id": "site-ship", "usernames": ["ship"] },
                { "id": "site-ship2", "usernames": ["ship2"] },
            ],
            "policies": [policy("ship"), policy("ship2")],
        });
        assert_eq!(access_control(&c, &identity()), expected);
        // Zenoh took it as given (its own defaults fill the keys left out).
        let acl = parsed(&z, "access_control");
        assert_eq!(acl["enabled"], true);
        assert_eq!(acl["default_permission"], "deny");
        for key in ["rules", "subjects"] {
            let got: Vec<_> = acl[key]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v["id"].clone())
                .collect();
            let want: Vec<_> = expected[key]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v["id"].clone())
                .collect();
            assert_eq!(got, want, "{key}");
        }
        assert_eq!(acl["subjects"][1]["usernames"], json!(["ship2"]));
        assert_eq!(acl["rules"][3]["key_exprs"], json!(["shoal/ship2/**"]));
        assert_eq!(acl["policies"], expected["policies"]);
    }

    #[test]
    fn a_connecting_site_authenticates_without_access_control() {
        let c = FederationConfig {
            site: "ship".into(),
            listen: vec![],
            connect: vec!["tcp/127.0.0.1:7447".into()],
            remote_sites: vec!["shore".into()],
            ..FederationConfig::default()
        };
        let mut id = identity();
        if let Some(up) = id.usrpwd.as_mut() {
            up.user = "ship".into();
        }
        let z = zenoh_config(&c, Some(&id)).unwrap();
        assert_eq!(parsed(&z, "transport/auth/usrpwd")["user"], "ship");
        assert_eq!(parsed(&z, "access_control")["enabled"], false);
    }

    #[test]
    fn without_identity_there_is_neither() {
        let z = zenoh_config(&FederationConfig::default(), None).unwrap();
        assert_eq!(
            parsed(&z, "transport/auth/usrpwd"),
            json!({ "user": null, "password": null, "dictionary_file": null })
        );
        assert_eq!(parsed(&z, "access_control")["enabled"], false);
    }

    #[test]
    fn tls_sets_mutual_tls_with_one_certificate_for_both_roles() {
        let c = FederationConfig {
            site: "shore".into(),
            listen: vec!["tls/127.0.0.1:7447".into()],
            remote_sites: vec!["ship".into()],
            ..FederationConfig::default()
        };
        let z = zenoh_config(&c, Some(&tls_identity("shore", false))).unwrap();
        let tls = parsed(&z, "transport/link/tls");
        for (key, want) in [
            ("root_ca_certificate", json!("/etc/shoal/trusted-cas.pem")),
            ("listen_certificate", json!("/etc/shoal/shore.crt")),
            ("listen_private_key", json!("/etc/shoal/shore.key")),
            ("connect_certificate", json!("/etc/shoal/shore.crt")),
            ("connect_private_key", json!("/etc/shoal/shore.key")),
            ("enable_mtls", json!(true)),
            ("verify_name_on_connect", json!(true)),
            ("close_link_on_expiration", json!(true)),
        ] {
            assert_eq!(tls[key], want, "{key}: {tls}");
        }
        // No user-password without its files.
        assert_eq!(parsed(&z, "transport/auth/usrpwd")["user"], json!(null));
        // Remote sites are known by their certificate's common name.
        let acl = parsed(&z, "access_control");
        assert_eq!(acl["enabled"], true);
        assert_eq!(acl["subjects"][0]["cert_common_names"], json!(["ship"]));
        assert_eq!(acl["subjects"][0]["usernames"], json!(null));
    }

    #[test]
    fn with_tls_a_connecting_site_polices_too_but_a_client_trusts_its_router() {
        let peer = FederationConfig {
            site: "ship".into(),
            listen: vec![],
            connect: vec!["tls/127.0.0.1:7447".into()],
            remote_sites: vec!["shore".into()],
            ..FederationConfig::default()
        };
        let id = tls_identity("ship", false);
        assert!(polices(&peer, &id));
        let acl = parsed(&zenoh_config(&peer, Some(&id)).unwrap(), "access_control");
        assert_eq!(acl["enabled"], true);
        assert_eq!(acl["rules"][2]["key_exprs"], json!(["shoal/shore/**"]));
        let client = FederationConfig {
            mode: Mode::Client,
            ..peer.clone()
        };
        assert!(!polices(&client, &id));
        let acl = parsed(&zenoh_config(&client, Some(&id)).unwrap(), "access_control");
        assert_eq!(acl["enabled"], false);
        // User-password alone: only a listening site polices.
        assert!(!polices(&peer, &identity()));
    }

    #[test]
    fn tls_and_usrpwd_together_require_both_names_where_zenoh_knows_both() {
        let listening = FederationConfig {
            site: "shore".into(),
            listen: vec!["tls/127.0.0.1:7447".into()],
            remote_sites: vec!["ship".into()],
            ..FederationConfig::default()
        };
        let id = tls_identity("shore", true);
        let z = zenoh_config(&listening, Some(&id)).unwrap();
        assert_eq!(parsed(&z, "transport/auth/usrpwd")["user"], "shore");
        assert_eq!(
            access_control(&listening, &id)["subjects"],
            json!([{ "id": "site-ship", "cert_common_names": ["ship"], "usernames": ["ship"] }])
        );
        // A site that also connects knows no username on the links it opens.
        let both = FederationConfig {
            connect: vec!["tls/127.0.0.1:7448".into()],
            ..listening
        };
        assert_eq!(
            access_control(&both, &id)["subjects"],
            json!([{ "id": "site-ship", "cert_common_names": ["ship"] }])
        );
    }
}
