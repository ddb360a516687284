//! The Zenoh configuration of a site, built from `FederationConfig` alone.
//!
//! Every key this crate depends on is set explicitly, so Zenoh's own defaults (which
//! listen on every interface and scout by UDP multicast) never apply.
//!
//! With an [`Identity`], the site authenticates with Zenoh's user-password scheme
//! (`transport/auth/usrpwd`: username = site name) and, when it listens, polices what
//! the sites connecting to it send with Zenoh's access control (`access_control`).

use serde_json::json;
use zenoh::Config;

use crate::config::{FederationConfig, Identity};
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
    ];
    if let Some(id) = identity {
        // Only a listening site has links Zenoh identifies (those it accepts); a site
        // that connects trusts the endpoints it was given (see `identity_topology`).
        if !c.listen.is_empty() {
            settings.push(("access_control", json(access_control(c))));
        }
        let usrpwd = json!({
            "user": id.user,
            "password": id.password.expose(),
            "dictionary_file": id.credentials_file,
        });
        // Zenoh's error could quote the value, which holds the password: withheld.
        z.insert_json5("transport/auth/usrpwd", &json(usrpwd))
            .map_err(|_| StartError::Zenoh {
                what: "configure user-password authentication",
                source: "refused (details withheld: the value holds the password)".into(),
            })?;
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

/// Zenoh's access control of a listening site: each remote site (Zenoh username = its
/// name, authenticated by the dictionary) may send data, replies, queryables and
/// liveliness tokens only under `shoal/<its site>/**`, and declare its interest in any
/// `shoal/**` key; this site sends it anything under `shoal/**`. Everything else, and
/// everything from a peer that matches no remote site, is denied both ways.
pub fn access_control(c: &FederationConfig) -> serde_json::Value {
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
        subjects.push(json!({ "id": format!("site-{site}"), "usernames": [site] }));
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
    use crate::config::Mode;

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
            user: "shore".into(),
            password: crate::config::Secret::new("pw-shore"),
            credentials_file: "/etc/shoal/sites.txt".into(),
            users: vec!["ship".into(), "ship2".into()],
        }
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
        assert_eq!(access_control(&c), expected);
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
        id.user = "ship".into();
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
}
