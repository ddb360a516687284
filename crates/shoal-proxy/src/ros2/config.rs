//! The ROS 2 proxy's configuration: the `--proxy-config` file of `shoal vehicle --proxy
//! ros2`, with the vehicle's topics, the goal frame and, for a vehicle on rmw_zenoh, how to
//! reach its Zenoh network.

use serde::{Deserialize, Serialize};
use shoal_model::{Validate, VehicleKind, now_ms};

use super::{Ros2Error, announcement_of};

/// A geodetic datum in a configuration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Datum {
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
}

/// How to reach a ROS 2 vehicle; the `[proxy.ros2]` section a CLI would read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Config {
    /// Shoal vehicle id the proxy announces.
    pub vehicle_id: String,
    /// Human-readable name.
    pub name: String,
    /// Kind of vehicle.
    pub kind: VehicleKind,
    /// Vendor or integrator.
    pub vendor: String,
    /// Maximum speed, m/s.
    pub max_speed_mps: f64,
    /// The ROS 2 namespace of the vehicle's topics (e.g. `bluerov`; empty for none).
    pub namespace: String,
    /// `sensor_msgs/NavSatFix` topic, relative to the namespace.
    pub fix_topic: String,
    /// `nav_msgs/Odometry` topic.
    pub odom_topic: String,
    /// `sensor_msgs/BatteryState` topic.
    pub battery_topic: String,
    /// `geometry_msgs/PoseStamped` goal topic.
    pub goal_topic: String,
    /// Turn the namespace's `/rosout` warnings and errors into events.
    pub rosout: bool,
    /// `frame_id` of the goals: a local ENU frame with its origin at `datum`.
    pub goal_frame_id: String,
    /// Origin of the goal frame; `None` takes the first fix.
    pub datum: Option<Datum>,
    /// Silence after which the link is reported lost, ms.
    pub lost_after_ms: u64,
    /// Distance at which a goal counts as reached, m.
    pub arrival_radius_m: f64,
    /// Depth error within which a goal's depth counts as reached, m.
    pub depth_tolerance_m: f64,
    /// The ROS 2 middleware the vehicle runs: DDS (the default) or rmw_zenoh.
    pub rmw: Rmw,
    /// How to reach the vehicle's Zenoh network when `rmw` is `zenoh`.
    pub zenoh: ZenohSettings,
}

impl Default for Ros2Config {
    fn default() -> Self {
        Self {
            vehicle_id: "ros2-1".into(),
            name: "ROS 2 vehicle".into(),
            kind: VehicleKind::Auv,
            vendor: "ROS 2".into(),
            max_speed_mps: 2.0,
            namespace: String::new(),
            fix_topic: "fix".into(),
            odom_topic: "odom".into(),
            battery_topic: "battery".into(),
            goal_topic: "goal_pose".into(),
            rosout: true,
            goal_frame_id: "map".into(),
            datum: None,
            lost_after_ms: 3000,
            arrival_radius_m: 2.0,
            depth_tolerance_m: 0.5,
            rmw: Rmw::Dds,
            zenoh: ZenohSettings::default(),
        }
    }
}

impl Ros2Config {
    /// The DDS name of a ROS 2 topic of this vehicle: `rt/<namespace>/<name>`.
    pub fn dds_topic(&self, name: &str) -> String {
        let ns = self.namespace.trim_matches('/');
        let name = name.trim_matches('/');
        if ns.is_empty() {
            format!("rt/{name}")
        } else {
            format!("rt/{ns}/{name}")
        }
    }
}

/// The ROS 2 middleware (RMW) of the vehicle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rmw {
    /// DDS (rmw_cyclonedds, rmw_fastrtps): topics `rt/<ns>/<name>` on Shoal's participant.
    #[default]
    Dds,
    /// rmw_zenoh: a Zenoh session of the proxy's own ([`ZenohSettings`]).
    Zenoh,
}

/// Zenoh session mode.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ZenohMode {
    /// A peer, as rmw_zenoh's nodes are: connects to a router or to other peers.
    #[default]
    Peer,
    /// A client: everything through the one router it connects to.
    Client,
}

/// The `[zenoh]` table: where the vehicle's rmw_zenoh network is.
///
/// rmw_zenoh's nodes run as peers connected to a router on their host
/// (`tcp/127.0.0.1:7447`, `ros2 run rmw_zenoh_cpp rmw_zenohd`), which is the default here;
/// point `connect` at the vehicle computer's router when the proxy runs elsewhere, or
/// connect peer to peer (one side listens, the other connects). Multicast scouting is
/// always off, as in rmw_zenoh's default configuration: Zenoh reaches only the endpoints
/// named here (and, through gossip, the peers those know).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ZenohSettings {
    /// The vehicle's `ROS_DOMAIN_ID`.
    pub domain_id: u32,
    /// Peer (rmw_zenoh's own mode) or client.
    pub mode: ZenohMode,
    /// Endpoints to connect to (`tcp/<host>:<port>`).
    pub connect: Vec<String>,
    /// Endpoints to listen on, for peers that connect to the proxy.
    pub listen: Vec<String>,
    /// The name of the proxy's node in the vehicle's ROS graph (in the vehicle's namespace).
    pub node_name: String,
}

impl Default for ZenohSettings {
    fn default() -> Self {
        Self {
            domain_id: 0,
            mode: ZenohMode::Peer,
            connect: vec!["tcp/127.0.0.1:7447".into()],
            listen: vec!["tcp/127.0.0.1:0".into()],
            node_name: "shoal_proxy".into(),
        }
    }
}

impl ZenohSettings {
    fn check(&self) -> Result<(), Ros2Error> {
        let node_ok = self
            .node_name
            .chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
            && self
                .node_name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_');
        if !node_ok {
            return Err(Ros2Error::Config(format!(
                "zenoh.node_name {:?} is not a ROS 2 node name",
                self.node_name
            )));
        }
        if self.connect.is_empty() && self.listen.is_empty() {
            return Err(Ros2Error::Config(
                "zenoh: no endpoint to connect to or listen on (multicast scouting is off)".into(),
            ));
        }
        if self.mode == ZenohMode::Client && self.connect.is_empty() {
            return Err(Ros2Error::Config(
                "zenoh: a client needs a router to connect to".into(),
            ));
        }
        for e in self.connect.iter().chain(&self.listen) {
            // Zenoh's own parser where it is built in; the shape of an endpoint otherwise.
            #[cfg(feature = "rmw-zenoh")]
            let ok = e.parse::<zenoh::config::EndPoint>().is_ok();
            #[cfg(not(feature = "rmw-zenoh"))]
            let ok = e
                .split_once('/')
                .is_some_and(|(p, a)| !p.is_empty() && !a.is_empty());
            if !ok {
                return Err(Ros2Error::Config(format!(
                    "zenoh endpoint {e:?} is not <protocol>/<address> (e.g. tcp/127.0.0.1:7447)"
                )));
            }
        }
        if !cfg!(feature = "rmw-zenoh") {
            return Err(Ros2Error::Config(
                "rmw = \"zenoh\" needs shoal-proxy's rmw-zenoh feature, left out of this build"
                    .into(),
            ));
        }
        Ok(())
    }
}

pub(crate) fn check(c: &Ros2Config) -> Result<(), Ros2Error> {
    let mut a = announcement_of(c);
    a.timestamp_ms = now_ms();
    a.validate()
        .map_err(|e| Ros2Error::Config(format!("the vehicle cannot be announced: {e}")))?;
    let name_ok = |s: &str| {
        s.trim_matches('/')
            .chars()
            .all(|ch| ch.is_ascii_alphanumeric() || ch == '_' || ch == '/')
    };
    for (what, s) in [
        ("namespace", &c.namespace),
        ("fix_topic", &c.fix_topic),
        ("odom_topic", &c.odom_topic),
        ("battery_topic", &c.battery_topic),
        ("goal_topic", &c.goal_topic),
    ] {
        if !name_ok(s) || (what != "namespace" && s.trim_matches('/').is_empty()) {
            return Err(Ros2Error::Config(format!(
                "{what} {s:?} is not a ROS 2 name (letters, digits, _ and /)"
            )));
        }
    }
    if c.lost_after_ms == 0 {
        return Err(Ros2Error::Config("lost_after_ms must be positive".into()));
    }
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if !positive(c.arrival_radius_m) || !positive(c.depth_tolerance_m) {
        return Err(Ros2Error::Config(
            "arrival_radius_m and depth_tolerance_m must be positive".into(),
        ));
    }
    if let Some(d) = c.datum
        && !((-90.0..=90.0).contains(&d.latitude_deg)
            && (-180.0..=180.0).contains(&d.longitude_deg))
    {
        return Err(Ros2Error::Config("datum is not a WGS84 position".into()));
    }
    if c.rmw == Rmw::Zenoh {
        c.zenoh.check()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_names_follow_ros_2() {
        let c = Ros2Config {
            namespace: "/bluerov/".into(),
            ..Ros2Config::default()
        };
        assert_eq!(c.dds_topic("fix"), "rt/bluerov/fix");
        assert_eq!(c.dds_topic("/goal_pose"), "rt/bluerov/goal_pose");
        assert_eq!(Ros2Config::default().dds_topic("odom"), "rt/odom");
    }

    #[test]
    fn the_config_has_defaults_and_rejects_unknown_fields() {
        let c: Ros2Config = serde_json::from_str(
            r#"{"namespace": "auv1", "datum": {"latitude_deg": 59.9, "longitude_deg": 10.7}}"#,
        )
        .unwrap();
        assert_eq!(c.namespace, "auv1");
        assert_eq!(c.goal_topic, "goal_pose");
        assert!(check(&c).is_ok());
        assert!(serde_json::from_str::<Ros2Config>(r#"{"name_space": "x"}"#).is_err());
        let bad = Ros2Config {
            namespace: "bad ns".into(),
            ..Ros2Config::default()
        };
        assert!(matches!(check(&bad), Err(Ros2Error::Config(_))));
        let bad = Ros2Config {
            datum: Some(Datum {
                latitude_deg: 100.0,
                longitude_deg: 0.0,
            }),
            ..Ros2Config::default()
        };
        assert!(check(&bad).is_err());
    }

    #[test]
    fn rmw_zenoh_is_chosen_in_the_file_with_its_endpoints() {
        let c: Ros2Config = toml::from_str(
            r#"
            namespace = "auv1"
            rmw = "zenoh"
            [zenoh]
            domain_id = 7
            connect = ["tcp/192.168.1.20:7447"]
            "#,
        )
        .unwrap();
        assert_eq!(c.rmw, Rmw::Zenoh);
        assert_eq!(c.zenoh.domain_id, 7);
        assert_eq!(c.zenoh.connect, ["tcp/192.168.1.20:7447"]);
        assert_eq!(c.zenoh.listen, ["tcp/127.0.0.1:0"], "defaults for the rest");
        // Without the feature (`cargo test -p shoal-proxy` alone) it is refused, and says so.
        assert_eq!(check(&c).is_ok(), cfg!(feature = "rmw-zenoh"));
        assert_eq!(Ros2Config::default().rmw, Rmw::Dds);
        assert!(toml::from_str::<Ros2Config>("rmw = \"fastdds\"").is_err());
        assert!(toml::from_str::<Ros2Config>("[zenoh]\nrouter = \"x\"").is_err());
    }

    #[test]
    fn bad_zenoh_settings_are_refused() {
        let with = |z: ZenohSettings| Ros2Config {
            rmw: Rmw::Zenoh,
            zenoh: z,
            ..Ros2Config::default()
        };
        for z in [
            ZenohSettings {
                node_name: "shoal-proxy".into(),
                ..ZenohSettings::default()
            },
            ZenohSettings {
                connect: vec![],
                listen: vec![],
                ..ZenohSettings::default()
            },
            ZenohSettings {
                mode: ZenohMode::Client,
                connect: vec![],
                ..ZenohSettings::default()
            },
            ZenohSettings {
                connect: vec!["127.0.0.1:7447".into()],
                ..ZenohSettings::default()
            },
        ] {
            assert!(
                matches!(check(&with(z.clone())), Err(Ros2Error::Config(_))),
                "{z:?}"
            );
            // The DDS proxy does not look at the table.
            assert!(
                check(&Ros2Config {
                    rmw: Rmw::Dds,
                    ..with(z)
                })
                .is_ok()
            );
        }
    }
}
