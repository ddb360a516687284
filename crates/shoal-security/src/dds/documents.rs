//! The governance and permissions documents of OMG DDS Security 1.1 (§9.4.1.2, §9.4.1.3),
//! written for Shoal's topics and partitions.
//!
//! - Governance: one domain rule for every domain id; unauthenticated participants are
//!   not admitted, joining needs permissions, and each topic gets the protection the
//!   keystore's [`Protection`] choice gives it (every topic encrypted by default).
//! - Permissions: the station may publish and subscribe everything; a vehicle may publish
//!   only its own topics ([`VEHICLE_TOPICS`]) and only in its own partition
//!   (`shoal.vehicle.<id>`), may never publish task assignments, and may subscribe to
//!   everything. Anything not allowed is denied.
//!
//! Dates are written `YYYY-MM-DDTHH:MM:SS` (UTC, no zone suffix): the form both the
//! Cyclone DDS and Fast DDS parsers read.

use serde::{Deserialize, Serialize};
use time::OffsetDateTime;
use time::macros::format_description;

use super::pki::{lowest_organisation, subject_text};

/// Topics a vehicle publishes about itself.
pub const VEHICLE_TOPICS: [&str; 5] = [
    "shoal/state_vector",
    "shoal/vehicle_announcement",
    "shoal/task_status",
    "shoal/event",
    "shoal/environment",
];

/// The partition a vehicle's writers use: its permissions allow it no other, so what
/// arrives from this partition comes from that vehicle (or the station).
pub fn vehicle_partition(vehicle_id: &str) -> String {
    format!("{VEHICLE_PARTITION_PREFIX}{vehicle_id}")
}

/// The highest domain id the documents cover: Cyclone DDS's governance and permissions
/// parsers refuse ids above 230 (RTPS ports allow 232), so secured swarms use 0–230.
pub const MAX_SECURE_DOMAIN: u16 = 230;

/// The prefix of [`vehicle_partition`].
pub const VEHICLE_PARTITION_PREFIX: &str = "shoal.vehicle.";

/// How the governance document protects a topic's samples and their metadata.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Protection {
    /// Encrypted and authenticated (AES-GCM): nobody without keys reads positions.
    #[default]
    Encrypt,
    /// Authenticated only (AES-GMAC): readable on the wire, but not forgeable.
    Sign,
    /// In the clear; access control still decides who may publish.
    None,
}

impl Protection {
    fn kind(self) -> &'static str {
        match self {
            Self::Encrypt => "ENCRYPT",
            Self::Sign => "SIGN",
            Self::None => "NONE",
        }
    }

    /// The name used in `[security.governance]`: `encrypt`, `sign` or `none`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Encrypt => "encrypt",
            Self::Sign => "sign",
            Self::None => "none",
        }
    }
}

impl GovernanceOptions {
    /// The protection the governance gives `topic`: the first listed expression that
    /// matches it (the order the document lists them in), else the default.
    pub fn protection_of(&self, topic: &str) -> Protection {
        self.topics
            .iter()
            .find(|(expression, _)| glob::Pattern::new(expression).is_ok_and(|p| p.matches(topic)))
            .map_or(self.default, |(_, p)| *p)
    }
}

impl std::fmt::Display for GovernanceOptions {
    /// One line: the default protection, then each topic's own.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} by default", self.default.as_str())?;
        for (topic, p) in &self.topics {
            write!(f, ", {topic} {}", p.as_str())?;
        }
        Ok(())
    }
}

/// Per-topic protection in the governance document.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GovernanceOptions {
    /// Protection of discovery and liveliness traffic and of every topic not listed in
    /// `topics`.
    pub default: Protection,
    /// Protection by topic name (e.g. `"shoal/environment" = "sign"`).
    pub topics: std::collections::BTreeMap<String, Protection>,
}

impl Default for GovernanceOptions {
    fn default() -> Self {
        Self {
            default: Protection::Encrypt,
            topics: std::collections::BTreeMap::new(),
        }
    }
}

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

fn topic_rule(expression: &str, p: Protection) -> String {
    let k = p.kind();
    format!(
        "        <topic_rule>\n\
         \x20         <topic_expression>{}</topic_expression>\n\
         \x20         <enable_discovery_protection>true</enable_discovery_protection>\n\
         \x20         <enable_liveliness_protection>true</enable_liveliness_protection>\n\
         \x20         <enable_read_access_control>true</enable_read_access_control>\n\
         \x20         <enable_write_access_control>true</enable_write_access_control>\n\
         \x20         <metadata_protection_kind>{k}</metadata_protection_kind>\n\
         \x20         <data_protection_kind>{k}</data_protection_kind>\n\
         \x20       </topic_rule>\n",
        xml_escape(expression)
    )
}

/// The governance document.
pub fn governance(options: &GovernanceOptions) -> String {
    let mut rules = String::new();
    // First match wins: listed topics before the catch-all.
    for (topic, p) in &options.topics {
        rules.push_str(&topic_rule(topic, *p));
    }
    rules.push_str(&topic_rule("*", options.default));
    let k = options.default.kind();
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
         <dds xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" xsi:noNamespaceSchemaLocation=\"http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd\">\n\
         \x20 <domain_access_rules>\n\
         \x20   <domain_rule>\n\
         \x20     <domains><id_range><min>0</min><max>{MAX_SECURE_DOMAIN}</max></id_range></domains>\n\
         \x20     <allow_unauthenticated_participants>false</allow_unauthenticated_participants>\n\
         \x20     <enable_join_access_control>true</enable_join_access_control>\n\
         \x20     <discovery_protection_kind>{k}</discovery_protection_kind>\n\
         \x20     <liveliness_protection_kind>{k}</liveliness_protection_kind>\n\
         \x20     <rtps_protection_kind>NONE</rtps_protection_kind>\n\
         \x20     <topic_access_rules>\n{rules}\x20     </topic_access_rules>\n\
         \x20   </domain_rule>\n\
         \x20 </domain_access_rules>\n\
         </dds>\n"
    )
}

/// What a participant may do on the bus.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Grant {
    /// The station: everything, in every partition.
    Station,
    /// A vehicle: its own topics in its own partition.
    Vehicle(String),
}

impl Grant {
    /// The enclave (SROS2 style) and certificate common name of this participant.
    pub fn enclave_name(&self) -> String {
        match self {
            Self::Station => "/shoal/station".into(),
            Self::Vehicle(id) => format!("/shoal/vehicle/{id}"),
        }
    }

    /// The organisation (`O=`) of this participant's certificate subject. Vehicles: `Shoal`.
    /// The station: `Shoal <nonce>`, the nonce chosen so that SHA-256 of the DER subject
    /// starts with 16 zero bits. The standard's PKI-DH plugins make the participant with
    /// the lower adjusted GUID (its first 47 bits are that hash) send the handshake
    /// request, so the station always initiates. This matters with Fast DDS 2.9 vehicles:
    /// as initiator, Fast DDS 2.9 offers only DH+MODP-2048, whose public key Cyclone DDS
    /// 0.10 cannot decode; as responder it accepts the ECDH that Cyclone offers.
    pub fn organisation(&self) -> String {
        static STATION: std::sync::OnceLock<String> = std::sync::OnceLock::new();
        match self {
            Self::Station => STATION
                .get_or_init(|| lowest_organisation(&self.enclave_name(), super::ORGANISATION))
                .clone(),
            Self::Vehicle(_) => super::ORGANISATION.to_string(),
        }
    }

    /// The certificate subject as the permissions document writes it (RFC 2253:
    /// `O=<organisation>,CN=<enclave name>`).
    pub fn subject_name(&self) -> String {
        subject_text(&self.enclave_name(), &self.organisation())
    }

    /// The vehicle this grant is for, if any.
    pub fn vehicle_id(&self) -> Option<&str> {
        match self {
            Self::Station => None,
            Self::Vehicle(id) => Some(id),
        }
    }
}

fn date(t: OffsetDateTime) -> String {
    let f = format_description!("[year]-[month]-[day]T[hour]:[minute]:[second]");
    t.format(&f)
        .unwrap_or_else(|_| "1970-01-01T00:00:00".into())
}

fn list(tag: &str, inner: &str, items: &[&str]) -> String {
    let body: String = items
        .iter()
        .map(|i| format!("<{inner}>{}</{inner}>", xml_escape(i)))
        .collect();
    format!("<{tag}>{body}</{tag}>")
}

/// The permissions document of one participant, valid from `not_before_s` to
/// `not_after_s` (Unix seconds).
pub fn permissions(grant: &Grant, not_before_s: i64, not_after_s: i64) -> String {
    let subject = xml_escape(&grant.subject_name());
    let from = date(
        OffsetDateTime::from_unix_timestamp(not_before_s).unwrap_or(OffsetDateTime::UNIX_EPOCH),
    );
    let until = date(
        OffsetDateTime::from_unix_timestamp(not_after_s).unwrap_or(OffsetDateTime::UNIX_EPOCH),
    );
    // A reader of vehicles' data listens in the default partition (the station's writers
    // and unmodified third-party vehicles in insecure labs) and every vehicle partition.
    let read_partitions = list("partitions", "partition", &["", "shoal.vehicle.*"]);
    let rules = match grant {
        Grant::Station => format!(
            "<publish>{}{}</publish><subscribe>{}{}</subscribe>",
            list("topics", "topic", &["*"]),
            list("partitions", "partition", &["*"]),
            list("topics", "topic", &["*"]),
            list("partitions", "partition", &["*"]),
        ),
        Grant::Vehicle(id) => format!(
            "<publish>{}{}</publish><subscribe>{}{}</subscribe>",
            list("topics", "topic", &VEHICLE_TOPICS),
            list("partitions", "partition", &[&vehicle_partition(id)]),
            list("topics", "topic", &["*"]),
            read_partitions,
        ),
    };
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n\
         <dds xmlns:xsi=\"http://www.w3.org/2001/XMLSchema-instance\" xsi:noNamespaceSchemaLocation=\"http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_permissions.xsd\">\n\
         \x20 <permissions>\n\
         \x20   <grant name=\"{name}\">\n\
         \x20     <subject_name>{subject}</subject_name>\n\
         \x20     <validity><not_before>{from}</not_before><not_after>{until}</not_after></validity>\n\
         \x20     <allow_rule>\n\
         \x20       <domains><id_range><min>0</min><max>{MAX_SECURE_DOMAIN}</max></id_range></domains>\n\
         \x20       {rules}\n\
         \x20     </allow_rule>\n\
         \x20     <default>DENY</default>\n\
         \x20   </grant>\n\
         \x20 </permissions>\n\
         </dds>\n",
        name = xml_escape(&grant.enclave_name()),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vehicle_permissions_allow_only_its_partition_and_no_tasks() {
        let doc = permissions(&Grant::Vehicle("auv-1".into()), 0, 86_400);
        assert!(doc.contains("<subject_name>O=Shoal,CN=/shoal/vehicle/auv-1</subject_name>"));
        assert!(doc.contains("<partition>shoal.vehicle.auv-1</partition>"));
        assert!(!doc.contains("shoal/task_assignment"));
        assert!(doc.contains("<not_before>1970-01-01T00:00:00</not_before>"));
        assert!(doc.contains("<not_after>1970-01-02T00:00:00</not_after>"));
        assert!(doc.contains("<default>DENY</default>"));
    }

    #[test]
    fn governance_lists_overrides_before_the_catch_all() {
        let mut o = GovernanceOptions::default();
        o.topics
            .insert("shoal/environment".into(), Protection::Sign);
        let doc = governance(&o);
        let env = doc.find("shoal/environment").unwrap();
        let all = doc.find("<topic_expression>*</topic_expression>").unwrap();
        assert!(env < all);
        assert!(doc.contains("<data_protection_kind>SIGN</data_protection_kind>"));
        assert_eq!(o.protection_of("shoal/environment"), Protection::Sign);
        assert_eq!(o.protection_of("shoal/event"), Protection::Encrypt);
        assert!(doc.contains("<allow_unauthenticated_participants>false"));
    }

    #[test]
    fn names_are_escaped() {
        let doc = permissions(&Grant::Vehicle("a<b".into()), 0, 1);
        assert!(doc.contains("a&lt;b"));
    }
}
