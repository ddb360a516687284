//! rmw_zenoh's wire conventions, as its design document (ros2/rmw_zenoh, `docs/design.md`,
//! rolling/Kilted) specifies them: no I/O here, so every rule is unit-tested.
//!
//! - Topic key expressions: `<domain_id>/<fully qualified name without its leading
//!   slash>/<DDS type name>/<RIHS01 type hash>` ("Topic and Service name mapping to Zenoh
//!   key expressions").
//! - Liveliness tokens ("Graph Cache"): a node is
//!   `@ros2_lv/<domain_id>/<session_id>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node>`,
//!   a publisher (`MP`) or subscription (`MS`) is
//!   `@ros2_lv/<domain_id>/<session_id>/<node_id>/<entity_id>/<kind>/<enclave>/<namespace>/<node>/<topic>/<type>/<hash>/<qos>`,
//!   with every `/` of a name replaced by `%` (an empty name is `%`), and the QoS in
//!   rmw_zenoh's compact form (`qos_to_keyexpr`: each policy left empty where it equals
//!   rmw_zenoh's default).
//! - The attachment of every sample ("Publishers"): the sequence number (i64) and the
//!   source timestamp (ns since the Unix epoch, i64), little endian, then the length of the
//!   publisher's GID in one byte (16) and the GID: 33 bytes.

/// The prefix of every ROS 2 liveliness token (a Zenoh hermetic namespace).
pub const ADMIN_SPACE: &str = "@ros2_lv";

/// Length of a publisher GID.
pub const GID_LEN: usize = 16;

/// Length of a sample's attachment.
pub const ATTACHMENT_LEN: usize = 8 + 8 + 1 + GID_LEN;

/// Why an attachment was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum AttachmentError {
    /// The sample carried none.
    #[error("no attachment")]
    Missing,
    /// Not the 33 bytes rmw_zenoh sends.
    #[error("{0} bytes, not {ATTACHMENT_LEN}")]
    Length(usize),
    /// The GID length byte is not 16.
    #[error("GID length {0}, not {GID_LEN}")]
    GidLength(u8),
    /// A negative sequence number or timestamp.
    #[error("negative {0}")]
    Negative(&'static str),
}

/// What rmw_zenoh attaches to each sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// The publisher's sequence number (from 1).
    pub sequence: i64,
    /// When the sample was published, ns since the Unix epoch.
    pub timestamp_ns: i64,
    /// The publisher's GID.
    pub gid: [u8; GID_LEN],
}

impl Attachment {
    /// The 33 bytes on the wire.
    pub fn encode(&self) -> [u8; ATTACHMENT_LEN] {
        let mut out = [0u8; ATTACHMENT_LEN];
        out[..8].copy_from_slice(&self.sequence.to_le_bytes());
        out[8..16].copy_from_slice(&self.timestamp_ns.to_le_bytes());
        // The design document's "1 byte for the length": rmw_zenoh writes the GID as a
        // Zenoh-serialised sequence, whose length is a LEB128 varint, one byte for 16.
        out[16] = GID_LEN as u8;
        out[17..].copy_from_slice(&self.gid);
        out
    }

    /// Decodes and checks an attachment from a remote publisher.
    pub fn decode(bytes: &[u8]) -> Result<Self, AttachmentError> {
        let b: &[u8; ATTACHMENT_LEN] = bytes
            .try_into()
            .map_err(|_| AttachmentError::Length(bytes.len()))?;
        let word = |i: usize| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&b[i..i + 8]);
            i64::from_le_bytes(w)
        };
        if usize::from(b[16]) != GID_LEN {
            return Err(AttachmentError::GidLength(b[16]));
        }
        let a = Self {
            sequence: word(0),
            timestamp_ns: word(8),
            gid: {
                let mut g = [0u8; GID_LEN];
                g.copy_from_slice(&b[17..]);
                g
            },
        };
        if a.sequence < 0 {
            return Err(AttachmentError::Negative("sequence number"));
        }
        if a.timestamp_ns < 0 {
            return Err(AttachmentError::Negative("timestamp"));
        }
        Ok(a)
    }
}

/// A ROS name in a liveliness token: each `/` becomes `%`, and an empty name `%` (Zenoh key
/// expressions have no empty chunks).
pub fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

/// The inverse of [`mangle`].
pub fn demangle(name: &str) -> String {
    name.replace('%', "/")
}

/// A ROS namespace in its absolute form: `/` for none, else `/a/b`.
pub fn absolute_namespace(namespace: &str) -> String {
    let ns = namespace.trim_matches('/');
    if ns.is_empty() {
        "/".into()
    } else {
        format!("/{ns}")
    }
}

/// The fully qualified name of `name` in `namespace`: `/ns/name`; a name starting with `/`
/// is absolute already (`/rosout`).
pub fn fully_qualified(namespace: &str, name: &str) -> String {
    if name.starts_with('/') {
        return format!("/{}", name.trim_matches('/'));
    }
    let ns = namespace.trim_matches('/');
    let name = name.trim_matches('/');
    if ns.is_empty() {
        format!("/{name}")
    } else {
        format!("/{ns}/{name}")
    }
}

/// The key expression samples of a topic travel on.
pub fn topic_key(domain_id: u32, fq_name: &str, dds_type: &str, type_hash: &str) -> String {
    format!(
        "{domain_id}/{}/{dds_type}/{type_hash}",
        fq_name.trim_matches('/')
    )
}

/// The QoS Shoal's endpoints declare, in the policies rmw_zenoh's tokens carry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Reliable (else best effort).
    pub reliable: bool,
    /// Transient local (else volatile).
    pub transient_local: bool,
    /// Keep-last depth.
    pub depth: u32,
}

impl Qos {
    /// ROS 2's default for topics: reliable, volatile, keep last 10.
    pub const ROS_DEFAULT: Self = Self {
        reliable: true,
        transient_local: false,
        depth: 10,
    };

    /// rmw_zenoh's `qos_to_keyexpr`: `reliability:durability:history,depth:deadline
    /// s,ns:lifespan s,ns:liveliness,lease s,lease ns`, each left empty where it equals
    /// rmw_zenoh's default (reliable, volatile, keep last 42, infinite durations,
    /// automatic liveliness). rmw enum values: best effort 2, transient local 1.
    pub fn to_keyexpr(self) -> String {
        const DEFAULT_DEPTH: u32 = 42;
        let reliability = if self.reliable { "" } else { "2" };
        let durability = if self.transient_local { "1" } else { "" };
        let depth = if self.depth == DEFAULT_DEPTH {
            String::new()
        } else {
            self.depth.to_string()
        };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// The kind of a graph entity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// A node (`NN`).
    Node,
    /// A message publisher (`MP`).
    Publisher,
    /// A message subscription (`MS`).
    Subscription,
    /// A service server (`SS`).
    Service,
    /// A service client (`SC`).
    Client,
}

impl EntityKind {
    /// The token's two letters.
    pub fn code(self) -> &'static str {
        match self {
            Self::Node => "NN",
            Self::Publisher => "MP",
            Self::Subscription => "MS",
            Self::Service => "SS",
            Self::Client => "SC",
        }
    }

    fn from_code(code: &str) -> Option<Self> {
        Some(match code {
            "NN" => Self::Node,
            "MP" => Self::Publisher,
            "MS" => Self::Subscription,
            "SS" => Self::Service,
            "SC" => Self::Client,
            _ => return None,
        })
    }
}

/// The topic part of a publisher's or subscription's token.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicInfo {
    /// Fully qualified topic name (`/ns/fix`).
    pub name: String,
    /// DDS type name (`sensor_msgs::msg::dds_::NavSatFix_`).
    pub dds_type: String,
    /// RIHS01 type hash.
    pub type_hash: String,
    /// QoS, as the token writes it.
    pub qos: String,
}

/// A graph entity as its liveliness token describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entity {
    /// ROS domain id.
    pub domain_id: u32,
    /// Zenoh session id.
    pub session_id: String,
    /// Node id within the session.
    pub node_id: u32,
    /// Entity id within the node (the node id for a node).
    pub entity_id: u32,
    /// Kind.
    pub kind: EntityKind,
    /// SROS enclave (empty: none).
    pub enclave: String,
    /// Absolute namespace (`/` for none).
    pub namespace: String,
    /// Node name.
    pub node_name: String,
    /// The topic, for a publisher or subscription.
    pub topic: Option<TopicInfo>,
}

impl Entity {
    /// The entity's liveliness token key expression.
    pub fn token(&self) -> String {
        let mut key = format!(
            "{ADMIN_SPACE}/{}/{}/{}/{}/{}/{}/{}/{}",
            self.domain_id,
            self.session_id,
            self.node_id,
            self.entity_id,
            self.kind.code(),
            mangle(&self.enclave),
            mangle(&self.namespace),
            mangle(&self.node_name),
        );
        if let Some(t) = &self.topic {
            key.push_str(&format!(
                "/{}/{}/{}/{}",
                mangle(&t.name),
                mangle(&t.dds_type),
                mangle(&t.type_hash),
                t.qos
            ));
        }
        key
    }

    /// Reads a token's key expression; `None` when it is not one of rmw_zenoh's.
    pub fn parse(key: &str) -> Option<Self> {
        let parts: Vec<&str> = key.split('/').collect();
        if parts.first() != Some(&ADMIN_SPACE) || !(parts.len() == 9 || parts.len() == 13) {
            return None;
        }
        let kind = EntityKind::from_code(parts[5])?;
        let topic = match (kind, parts.len()) {
            (EntityKind::Node, 9) => None,
            (EntityKind::Node, _) | (_, 9) => return None,
            _ => Some(TopicInfo {
                name: demangle(parts[9]),
                dds_type: demangle(parts[10]),
                type_hash: demangle(parts[11]),
                qos: parts[12].to_string(),
            }),
        };
        let enclave = demangle(parts[6]);
        Some(Self {
            domain_id: parts[1].parse().ok()?,
            session_id: parts[2].to_string(),
            node_id: parts[3].parse().ok()?,
            entity_id: parts[4].parse().ok()?,
            kind,
            enclave: if enclave == "/" {
                String::new()
            } else {
                enclave
            },
            namespace: demangle(parts[7]),
            node_name: demangle(parts[8]),
            topic,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const STRING_HASH: &str =
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";

    #[test]
    fn topic_keys_are_the_design_documents() {
        // design.md: the `chatter` topic, without and with the `/robot1` namespace.
        let fq = fully_qualified("", "chatter");
        assert_eq!(
            topic_key(0, &fq, "std_msgs::msg::dds_::String_", STRING_HASH),
            format!("0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
        );
        let fq = fully_qualified("/robot1/", "chatter");
        assert_eq!(fq, "/robot1/chatter");
        assert_eq!(
            topic_key(0, &fq, "std_msgs::msg::dds_::String_", STRING_HASH),
            format!("0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}")
        );
        assert_eq!(fully_qualified("robot1", "/rosout"), "/rosout");
    }

    #[test]
    fn tokens_are_the_design_documents() {
        // design.md's `listener` node and its subscription, and `talker`'s publisher
        // (depth 7), byte for byte.
        let node = Entity {
            domain_id: 2,
            session_id: "aac3178e146ba6f1fc6e6a4085e77f21".into(),
            node_id: 0,
            entity_id: 0,
            kind: EntityKind::Node,
            enclave: String::new(),
            namespace: absolute_namespace(""),
            node_name: "listener".into(),
            topic: None,
        };
        assert_eq!(
            node.token(),
            "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
        );
        let topic = |qos: Qos| TopicInfo {
            name: "/chatter".into(),
            dds_type: "std_msgs::msg::dds_::String_".into(),
            type_hash: STRING_HASH.into(),
            qos: qos.to_keyexpr(),
        };
        let sub = Entity {
            entity_id: 10,
            kind: EntityKind::Subscription,
            topic: Some(topic(Qos::ROS_DEFAULT)),
            ..node.clone()
        };
        assert_eq!(
            sub.token(),
            format!(
                "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/\
                 std_msgs::msg::dds_::String_/{STRING_HASH}/::,10:,:,:,,"
            )
        );
        let publisher = Entity {
            session_id: "8b20917502ee955ac4476e0266340d5c".into(),
            entity_id: 10,
            kind: EntityKind::Publisher,
            node_name: "talker".into(),
            topic: Some(topic(Qos {
                depth: 7,
                ..Qos::ROS_DEFAULT
            })),
            ..node.clone()
        };
        assert_eq!(
            publisher.token(),
            format!(
                "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/\
                 std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,"
            )
        );
        for e in [&node, &sub, &publisher] {
            assert_eq!(Entity::parse(&e.token()).as_ref(), Some(e));
        }
    }

    #[test]
    fn qos_leaves_rmw_zenohs_defaults_empty() {
        assert_eq!(
            Qos {
                reliable: false,
                transient_local: true,
                depth: 42
            }
            .to_keyexpr(),
            "2:1:,:,:,:,,"
        );
    }

    #[test]
    fn namespaces_mangle_with_percent_signs() {
        assert_eq!(mangle(&absolute_namespace("/bluerov")), "%bluerov");
        assert_eq!(mangle("/a/b/fix"), "%a%b%fix");
        assert_eq!(mangle(""), "%");
        assert_eq!(demangle("%a%b"), "/a/b");
    }

    #[test]
    fn foreign_keys_are_not_tokens() {
        for key in [
            "0/chatter/std_msgs::msg::dds_::String_/RIHS01_00",
            "@ros2_lv/0/z/0/0/NN/%/%",
            "@ros2_lv/x/z/0/0/NN/%/%/n",
            "@ros2_lv/0/z/0/0/XX/%/%/n",
            "@ros2_lv/0/z/0/0/NN/%/%/n/%t/T/H/::,:,:,:,,",
            "@ros2_lv/0/z/0/1/MP/%/%/n",
        ] {
            assert_eq!(Entity::parse(key), None, "{key}");
        }
    }

    #[test]
    fn attachments_round_trip_in_33_bytes() {
        let a = Attachment {
            sequence: 7,
            timestamp_ns: 1_700_000_000_123_456_789,
            gid: [0xab; GID_LEN],
        };
        let b = a.encode();
        assert_eq!(hex::encode(&b[..17]), "070000000000000015cd853dfe9c971710");
        assert_eq!(Attachment::decode(&b), Ok(a));
    }

    #[test]
    fn malformed_attachments_are_refused() {
        let good = Attachment {
            sequence: 1,
            timestamp_ns: 1,
            gid: [1; GID_LEN],
        }
        .encode();
        assert_eq!(
            Attachment::decode(&good[..32]),
            Err(AttachmentError::Length(32))
        );
        assert_eq!(Attachment::decode(&[]), Err(AttachmentError::Length(0)));
        let mut bad = good;
        bad[16] = 8;
        assert_eq!(Attachment::decode(&bad), Err(AttachmentError::GidLength(8)));
        let mut bad = good;
        bad[7] = 0x80;
        assert!(matches!(
            Attachment::decode(&bad),
            Err(AttachmentError::Negative(_))
        ));
    }

    proptest::proptest! {
        #[test]
        fn any_bytes_decode_or_are_refused_without_panicking(
            bytes in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..64)
        ) {
            let _ = Attachment::decode(&bytes);
            let _ = Entity::parse(&String::from_utf8_lossy(&bytes));
        }

        #[test]
        fn attachments_round_trip(seq in 0i64.., ts in 0i64.., gid in proptest::prelude::any::<[u8; 16]>()) {
            let a = Attachment { sequence: seq, timestamp_ns: ts, gid };
            proptest::prop_assert_eq!(Attachment::decode(&a.encode()), Ok(a));
        }
    }
}
