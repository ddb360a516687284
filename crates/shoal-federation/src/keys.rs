//! The key expressions the federation publishes under, and their parsing on receipt.
//!
//! Every key starts with `shoal/<site>/`, so a subscriber can take one site
//! (`shoal/ship-1/**`) or one kind of data from every site (`shoal/*/alarms`):
//!
//! | key | what |
//! |-----|------|
//! | `shoal/<site>/vehicles/<vehicle>/position` | a vehicle's position (rate limited) |
//! | `shoal/<site>/alarms` | alarms, sequenced |
//! | `shoal/<site>/tasks/<task>` | task transitions, sequenced |
//! | `shoal/<site>/catchup/alarms` | queryable: the site's recent alarms |
//! | `shoal/<site>/catchup/tasks` | queryable: the site's recent task transitions |
//! | `shoal/<site>/alive` | liveliness token while the site's session is up |
//! | `shoal/<site>/leases/<vehicle>` | a command-lease record the site made; also its queryable |
//! | `shoal/<site>/orders/<home>/<vehicle>` | a task the site, holding the vehicle's lease, sends to the vehicle's home site |
//! | `shoal/<site>/environment/<vehicle>` | a vehicle's environment summaries of one window |
//! | `shoal/<site>/identity` | queryable: the site's certificate chain, to check its signatures |

use shoal_model::{MAX_ID_LEN, is_identifier};

use crate::types::{MAX_VEHICLE_ID, is_site_name};

/// The first chunk of every federation key.
pub const ROOT: &str = "shoal";

/// A sequenced stream: each has its own sequence numbers and catch-up buffer per site.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stream {
    /// Alarms (`shoal_model::Event`).
    Alarms,
    /// Task transitions.
    Tasks,
}

impl Stream {
    /// Both streams, in a fixed order.
    pub const ALL: [Self; 2] = [Self::Alarms, Self::Tasks];

    /// The stream's name in catch-up keys and counters.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Alarms => "alarms",
            Self::Tasks => "tasks",
        }
    }
}

/// Key of a vehicle's position.
pub fn position(site: &str, vehicle: &str) -> String {
    format!("{ROOT}/{site}/vehicles/{vehicle}/position")
}

/// Key of a site's alarms.
pub fn alarms(site: &str) -> String {
    format!("{ROOT}/{site}/alarms")
}

/// Key of one task's transitions.
pub fn task(site: &str, task_id: &str) -> String {
    format!("{ROOT}/{site}/tasks/{task_id}")
}

/// Key of a site's catch-up queryable for one stream.
pub fn catchup(site: &str, stream: Stream) -> String {
    format!("{ROOT}/{site}/catchup/{}", stream.as_str())
}

/// Key of a command-lease record `site` made for `vehicle`.
pub fn lease(site: &str, vehicle: &str) -> String {
    format!("{ROOT}/{site}/leases/{vehicle}")
}

/// Selector of every lease record a site made (its queryable answers it).
pub fn leases(site: &str) -> String {
    format!("{ROOT}/{site}/leases/*")
}

/// Key of an order: a task `site` (the sender, holding `vehicle`'s command lease) sends
/// to `home`, the vehicle's home site, to publish to it. It opens with the sender because
/// a site may publish only under its own `shoal/<site>/**` (what authenticates it), and
/// names the home so that only the home subscribes: other sites never receive the order.
pub fn order(site: &str, home: &str, vehicle: &str) -> String {
    format!("{ROOT}/{site}/orders/{home}/{vehicle}")
}

/// Selector of every order sent to `home`, by any site.
pub fn orders_to(home: &str) -> String {
    format!("{ROOT}/*/orders/{home}/*")
}

/// Key of a vehicle's environment summaries.
pub fn environment(site: &str, vehicle: &str) -> String {
    format!("{ROOT}/{site}/environment/{vehicle}")
}

/// Key of a site's identity queryable (its certificate chain, [`crate::signed`]).
pub fn identity(site: &str) -> String {
    format!("{ROOT}/{site}/identity")
}

/// Key of a site's liveliness token.
pub fn alive(site: &str) -> String {
    format!("{ROOT}/{site}/alive")
}

/// What a received key expression addresses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Key<'a> {
    /// `shoal/<site>/vehicles/<vehicle>/position`
    Position {
        /// The publishing site.
        site: &'a str,
        /// The vehicle.
        vehicle: &'a str,
    },
    /// `shoal/<site>/alarms` or, in a catch-up reply, `shoal/<site>/catchup/alarms`.
    Alarms {
        /// The publishing site.
        site: &'a str,
    },
    /// `shoal/<site>/tasks/<task>` or, in a catch-up reply, `shoal/<site>/catchup/tasks`.
    Task {
        /// The publishing site.
        site: &'a str,
    },
    /// `shoal/<site>/leases/<vehicle>`
    Lease {
        /// The site that made the record.
        site: &'a str,
        /// The vehicle.
        vehicle: &'a str,
    },
    /// `shoal/<site>/orders/<home>/<vehicle>`
    Order {
        /// The sending site (the lease holder).
        site: &'a str,
        /// The site the order is for (the vehicle's home).
        home: &'a str,
        /// The vehicle the task is for.
        vehicle: &'a str,
    },
    /// `shoal/<site>/environment/<vehicle>`
    Environment {
        /// The publishing site.
        site: &'a str,
        /// The vehicle whose summaries they are.
        vehicle: &'a str,
    },
    /// `shoal/<site>/alive`
    Alive {
        /// The site whose session is up.
        site: &'a str,
    },
    /// `shoal/<site>/identity`
    Identity {
        /// The site whose certificate chain it is.
        site: &'a str,
    },
}

impl<'a> Key<'a> {
    /// Parses a key this crate publishes; `None` for anything else.
    pub fn parse(key: &'a str) -> Option<Self> {
        let mut chunks = key.split('/');
        if chunks.next() != Some(ROOT) {
            return None;
        }
        let site = chunks.next().filter(|s| is_site_name(s))?;
        let rest: Vec<&str> = chunks.collect();
        let parsed = match rest.as_slice() {
            ["vehicles", vehicle, "position"] if is_identifier(vehicle, MAX_VEHICLE_ID) => {
                Self::Position { site, vehicle }
            }
            ["alarms"] | ["catchup", "alarms"] => Self::Alarms { site },
            ["tasks", task] if is_identifier(task, MAX_ID_LEN) => Self::Task { site },
            ["catchup", "tasks"] => Self::Task { site },
            ["leases", vehicle] if is_identifier(vehicle, MAX_VEHICLE_ID) => {
                Self::Lease { site, vehicle }
            }
            ["orders", home, vehicle]
                if is_site_name(home) && is_identifier(vehicle, MAX_VEHICLE_ID) =>
            {
                Self::Order {
                    site,
                    home,
                    vehicle,
                }
            }
            ["environment", vehicle] if is_identifier(vehicle, MAX_VEHICLE_ID) => {
                Self::Environment { site, vehicle }
            }
            ["alive"] => Self::Alive { site },
            ["identity"] => Self::Identity { site },
            _ => return None,
        };
        Some(parsed)
    }

    /// The site named in the key.
    pub fn site(&self) -> &'a str {
        match *self {
            Self::Position { site, .. }
            | Self::Lease { site, .. }
            | Self::Order { site, .. }
            | Self::Environment { site, .. }
            | Self::Alarms { site }
            | Self::Task { site }
            | Self::Alive { site }
            | Self::Identity { site } => site,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_keys_parse_back() {
        assert_eq!(
            Key::parse(&position("ship-1", "auv-7")),
            Some(Key::Position {
                site: "ship-1",
                vehicle: "auv-7"
            })
        );
        assert_eq!(
            Key::parse(&alarms("shore")),
            Some(Key::Alarms { site: "shore" })
        );
        assert_eq!(
            Key::parse(&catchup("shore", Stream::Alarms)),
            Some(Key::Alarms { site: "shore" })
        );
        assert_eq!(Key::parse(&task("s", "t-1")), Some(Key::Task { site: "s" }));
        assert_eq!(
            Key::parse(&catchup("s", Stream::Tasks)),
            Some(Key::Task { site: "s" })
        );
        assert_eq!(Key::parse(&alive("s")), Some(Key::Alive { site: "s" }));
        assert_eq!(
            Key::parse(&lease("ship", "auv-1")),
            Some(Key::Lease {
                site: "ship",
                vehicle: "auv-1"
            })
        );
        assert_eq!(
            Key::parse(&order("shore", "ship", "auv-1")),
            Some(Key::Order {
                site: "shore",
                home: "ship",
                vehicle: "auv-1"
            })
        );
        assert_eq!(
            Key::parse(&order("shore", "ship", "auv-1")).unwrap().site(),
            "shore"
        );
        assert_eq!(
            Key::parse(&environment("ship", "auv-1")),
            Some(Key::Environment {
                site: "ship",
                vehicle: "auv-1"
            })
        );
        assert_eq!(environment("ship", "auv-1"), "shoal/ship/environment/auv-1");
        assert_eq!(
            Key::parse(&environment("ship", "auv-1")).unwrap().site(),
            "ship"
        );
    }

    #[test]
    fn foreign_keys_are_not_ours() {
        for k in [
            "",
            "shoal",
            "other/s/alarms",
            "shoal/s",
            "shoal/s/alarms/x",
            "shoal/s/vehicles/a b/position",
            "shoal/s/vehicles/v",
            "shoal/s/tasks",
            "shoal/s/leases",
            "shoal/s/leases/*",
            "shoal/s/orders",
            "shoal/s/orders/*",
            "shoal/s/orders/auv-1",
            "shoal/s/orders/h/a b",
            "shoal/s/orders/a b/auv-1",
            "shoal/s/orders/h/auv-1/x",
            "shoal/*/orders/h/auv-1",
            "shoal/s/orders/*/auv-1",
            "shoal/../alarms",
            "shoal/s/environment",
            "shoal/s/environment/*",
            "shoal/s/environment/a b",
            "shoal/s/environment/auv-1/x",
            "shoal/*/environment/auv-1",
        ] {
            assert_eq!(Key::parse(k), None, "{k}");
        }
    }
}
