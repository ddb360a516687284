//! The Zenoh configuration of a site, built from `FederationConfig` alone.
//!
//! Every key this crate depends on is set explicitly, so Zenoh's own defaults (which
//! listen on every interface and scout by UDP multicast) never apply.

use zenoh::Config;

use crate::config::FederationConfig;
use crate::error::StartError;

/// Zenoh's configuration for a (validated) federation configuration.
pub fn zenoh_config(c: &FederationConfig) -> Result<Config, StartError> {
    let mut z = Config::default();
    let json = |v: serde_json::Value| v.to_string();
    let settings = [
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
    for (key, value) in settings {
        z.insert_json5(key, &value)
            .map_err(|source| StartError::Zenoh {
                what: "configure",
                source,
            })?;
    }
    Ok(z)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Mode;

    #[test]
    fn the_zenoh_config_of_the_default_does_not_scout_and_listens_on_loopback() {
        let z = zenoh_config(&FederationConfig::default()).unwrap();
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
        let z = zenoh_config(&c).unwrap();
        assert_eq!(z.get_json("mode").unwrap(), r#""client""#);
        assert_eq!(z.get_json("listen/endpoints").unwrap(), "[]");
    }
}
