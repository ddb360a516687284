//! The ROS 2 proxy over rmw_zenoh: the vehicle's topics and goals on a Zenoh session of the
//! proxy's own, following rmw_zenoh's design document ([`super::zenoh_wire`]).
//!
//! [`open`] joins the vehicle's ROS graph as a node (`zenoh.node_name`, in the vehicle's
//! namespace) with a liveliness token for the node, one for each subscription (fix,
//! odometry, battery, `/rosout`) and one for the goal publisher, so that `ros2 node list`
//! and `ros2 topic info` on the vehicle show the proxy. It watches the graph's tokens too:
//! the vehicle's subscriptions to the goal topic (with the goal's type and type hash) are
//! what "a subscriber took the goal" means here, as DDS's matched readers do over DDS.
//!
//! Each subscriber listens on `<domain>/<topic>/*/*` rather than the exact key, so that a
//! sample of another type or type hash (a vehicle built against other message
//! definitions) is seen and counted (`wrong_type`) instead of silently missing. Samples
//! cross from Zenoh's callback threads to the link task through a bounded queue; a flood
//! that overruns it is counted (`flooded`) and dropped there, and payloads above
//! [`MAX_PAYLOAD`] are refused before they are copied.

use std::collections::HashSet;
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use sha2::{Digest, Sha256};
use shoal_dds::TopicType;
use shoal_model::{Validate, Validated};
use tokio::sync::mpsc;
use tracing::{debug, info, warn};
use zenoh::Session;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::sample::{Locality, Sample as ZSample, SampleKind};

use super::config::{Ros2Config, ZenohMode, ZenohSettings};
use super::msgs::{BatteryState, Log, NavSatFix, Odometry, PoseStamped};
use super::transport::{GoalError, Received, Rejection, Sample, Topic};
use super::type_hash::type_hash;
use super::zenoh_wire::{
    Attachment, Entity, EntityKind, GID_LEN, Qos, TopicInfo, absolute_namespace, fully_qualified,
    topic_key,
};
use super::{Counters, Ros2Error};
use crate::link::bump;

/// Samples waiting for the link task; beyond this a flood is dropped and counted.
const INBOX: usize = 256;
/// Largest payload accepted, bytes: far above any real fix, odometry, battery or log
/// sample (strings are capped at [`super::msgs::MAX_STRING`]).
pub const MAX_PAYLOAD: usize = 64 * 1024;

/// A ROS type as rmw_zenoh names it on the wire.
#[derive(Debug, Clone)]
struct RosType {
    /// `sensor_msgs::msg::dds_::NavSatFix_`.
    dds: &'static str,
    /// RIHS01 hash.
    hash: String,
}

impl RosType {
    fn of<T: TopicType>() -> Result<Self, Ros2Error> {
        let dds = T::TYPE_NAME;
        // `pkg::msg::dds_::Name_` is `pkg/msg/Name` (the ROS 2 DDS type-name mangling).
        let ros = dds
            .strip_suffix('_')
            .map(|s| s.replace("::msg::dds_::", "/msg/"))
            .ok_or_else(|| Ros2Error::Config(format!("{dds} is not a ROS 2 DDS type name")))?;
        let hash = type_hash(&ros).map_err(|e| Ros2Error::Config(e.to_string()))?;
        Ok(Self { dds, hash })
    }
}

/// A sample as Zenoh delivered it, before any check.
#[derive(Debug)]
struct Raw {
    topic: Topic,
    key: String,
    /// The payload, or its length when it was too large to take.
    payload: Result<Vec<u8>, usize>,
    attachment: Option<Vec<u8>>,
}

/// The vehicle's topics as Zenoh subscribers.
pub(crate) struct ZenohInbox {
    rx: mpsc::Receiver<Raw>,
    types: Vec<(Topic, RosType)>,
    // Kept: dropping them undeclares the subscriptions and their tokens, and dropping the
    // last handle of the session closes it (its entities hold it only weakly).
    _subscribers: Vec<Subscriber<()>>,
    _tokens: Vec<LivelinessToken>,
    _session: Session,
}

impl ZenohInbox {
    pub(crate) async fn next(&mut self) -> Option<Received> {
        let raw = self.rx.recv().await?;
        let topic = raw.topic;
        Some((topic, self.check(raw)))
    }

    fn check(&self, raw: Raw) -> Result<Sample, Rejection> {
        let expected = self
            .types
            .iter()
            .find(|(t, _)| *t == raw.topic)
            .map(|(_, ty)| ty)
            .ok_or_else(|| Rejection::WrongType("no such topic".into()))?;
        // The subscription is `<domain>/<topic>/*/*`: the last two chunks are the type and
        // the hash (rmw_zenoh puts them last, and neither contains a `/`).
        let mut chunks = raw.key.rsplitn(3, '/');
        let (hash, dds) = (chunks.next(), chunks.next());
        if hash != Some(expected.hash.as_str()) || dds != Some(expected.dds) {
            return Err(Rejection::WrongType(format!(
                "{} / {} where {} / {} is expected",
                dds.unwrap_or("?"),
                hash.unwrap_or("?"),
                expected.dds,
                expected.hash
            )));
        }
        let payload = raw
            .payload
            .map_err(|len| Rejection::Malformed(format!("{len} bytes, more than {MAX_PAYLOAD}")))?;
        let attachment = raw
            .attachment
            .as_deref()
            .ok_or(super::zenoh_wire::AttachmentError::Missing)
            .and_then(Attachment::decode)
            .map_err(|e| Rejection::BadAttachment(e.to_string()))?;
        debug!(
            key = %raw.key,
            sequence = attachment.sequence,
            gid = %hex::encode(attachment.gid),
            "rmw_zenoh sample"
        );
        Ok(match raw.topic {
            Topic::Fix => Sample::Fix(decode::<NavSatFix>(&payload)?),
            Topic::Odom => Sample::Odom(Box::new(decode::<Odometry>(&payload)?)),
            Topic::Battery => Sample::Battery(decode::<BatteryState>(&payload)?),
            Topic::Rosout => Sample::Log(decode::<Log>(&payload)?),
        })
    }
}

/// CDR with its encapsulation header, as over DDS (design.md, "Serialization").
fn decode<T: serde::de::DeserializeOwned + Validate>(
    bytes: &[u8],
) -> Result<Validated<T>, Rejection> {
    let v: T = shoal_dds::from_cdr(bytes).map_err(|e| Rejection::Malformed(e.to_string()))?;
    Validated::new(v).map_err(|(e, _)| Rejection::Invalid(e.to_string()))
}

/// What the graph's liveliness tokens say about the goal topic.
#[derive(Debug, Default)]
struct Graph {
    /// Tokens of the vehicle's subscriptions to the goal topic, of the goal's type.
    goal_readers: HashSet<String>,
}

/// The goal topic's Zenoh publisher.
#[derive(Debug)]
pub(crate) struct ZenohGoals {
    publisher: Publisher<'static>,
    gid: [u8; GID_LEN],
    sequence: AtomicI64,
    graph: Arc<Mutex<Graph>>,
    // Kept: the publisher's token and the graph watch live as long as the goals, and so
    // does the session.
    _token: LivelinessToken,
    _graph_watch: Subscriber<()>,
    _session: Session,
}

impl ZenohGoals {
    pub(crate) fn subscribers(&self) -> usize {
        self.graph
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .goal_readers
            .len()
    }

    pub(crate) async fn publish(&self, goal: &PoseStamped) -> Result<(), GoalError> {
        goal.validate()?;
        let payload = shoal_dds::to_cdr_le(goal)?;
        let attachment = Attachment {
            sequence: self.sequence.fetch_add(1, Ordering::Relaxed),
            timestamp_ns: now_ns(),
            gid: self.gid,
        };
        self.publisher
            .put(payload)
            .attachment(attachment.encode().to_vec())
            .await
            .map_err(|source| GoalError::Zenoh { source })
    }
}

/// Now, ns since the Unix epoch: the attachment's source timestamp.
fn now_ns() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_nanos()).unwrap_or(i64::MAX))
}

fn zenoh_config(z: &ZenohSettings) -> Result<zenoh::Config, Ros2Error> {
    let mode = match z.mode {
        ZenohMode::Peer => "peer",
        ZenohMode::Client => "client",
    };
    let json = |v: &Vec<String>| serde_json::to_string(v).unwrap_or_else(|_| "[]".into());
    let mut c = zenoh::Config::default();
    for (key, value) in [
        ("mode", format!("\"{mode}\"")),
        ("connect/endpoints", json(&z.connect)),
        // Set even when empty: a peer's default is every interface.
        ("listen/endpoints", json(&z.listen)),
        // rmw_zenoh's session defaults: no multicast scouting; gossip through the router
        // so that peers find each other's (loopback) endpoints.
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "true".into()),
    ] {
        c.insert_json5(key, &value)
            .map_err(|source| Ros2Error::Zenoh {
                what: "configure the session",
                source,
            })?;
    }
    Ok(c)
}

/// Joins the vehicle's rmw_zenoh graph: declares the proxy's node, its subscriptions and
/// goal publisher with their tokens, and starts watching the graph.
pub(crate) async fn open(
    config: &Ros2Config,
    counters: &Arc<Counters>,
) -> Result<(ZenohInbox, ZenohGoals), Ros2Error> {
    let z = &config.zenoh;
    let zerr = |what| move |source| Ros2Error::Zenoh { what, source };
    let session = zenoh::open(zenoh_config(z)?)
        .await
        .map_err(zerr("open a session"))?;
    let zid = session.zid().to_string();
    let namespace = absolute_namespace(&config.namespace);
    let node = Entity {
        domain_id: z.domain_id,
        session_id: zid.clone(),
        node_id: 0,
        entity_id: 0,
        kind: EntityKind::Node,
        enclave: String::new(),
        namespace,
        node_name: z.node_name.clone(),
        topic: None,
    };
    let mut tokens = vec![declare_token(&session, &node.token()).await?];

    let mut inbound = vec![
        (
            Topic::Fix,
            config.fix_topic.as_str(),
            RosType::of::<NavSatFix>()?,
        ),
        (
            Topic::Odom,
            config.odom_topic.as_str(),
            RosType::of::<Odometry>()?,
        ),
        (
            Topic::Battery,
            config.battery_topic.as_str(),
            RosType::of::<BatteryState>()?,
        ),
    ];
    if config.rosout {
        inbound.push((Topic::Rosout, "/rosout", RosType::of::<Log>()?));
    }
    let (tx, rx) = mpsc::channel(INBOX);
    let mut subscribers = Vec::new();
    let mut types = Vec::new();
    for (id, (topic, name, ty)) in (1u32..).zip(inbound) {
        let fq = fully_qualified(&config.namespace, name);
        let pattern = format!("{}/{}/*/*", z.domain_id, fq.trim_matches('/'));
        let tx = tx.clone();
        let counters = Arc::clone(counters);
        let subscriber = session
            .declare_subscriber(pattern)
            .allowed_origin(Locality::Remote)
            .callback(move |s| enqueue(&tx, &counters, topic, &s))
            .await
            .map_err(zerr("declare a subscriber"))?;
        subscribers.push(subscriber);
        let token = Entity {
            entity_id: id,
            kind: EntityKind::Subscription,
            topic: Some(topic_info(&fq, &ty)),
            ..node.clone()
        };
        tokens.push(declare_token(&session, &token.token()).await?);
        types.push((topic, ty));
    }

    let goal_type = RosType::of::<PoseStamped>()?;
    let goal_fq = fully_qualified(&config.namespace, &config.goal_topic);
    let key = topic_key(z.domain_id, &goal_fq, goal_type.dds, &goal_type.hash);
    let publisher = session
        .declare_publisher(key.clone())
        .await
        .map_err(zerr("declare the goal publisher"))?;
    let goal_entity = Entity {
        entity_id: u32::try_from(types.len() + 1).unwrap_or(u32::MAX),
        kind: EntityKind::Publisher,
        topic: Some(topic_info(&goal_fq, &goal_type)),
        ..node.clone()
    };
    let goal_token = goal_entity.token();
    // rmw_zenoh derives an entity's GID from its token (an XXH3-128 hash); the design
    // document leaves the derivation open, so Shoal takes SHA-256's first 16 bytes of the
    // same text: stable for the publisher, distinct between publishers.
    let mut gid = [0u8; GID_LEN];
    gid.copy_from_slice(&Sha256::digest(goal_token.as_bytes())[..GID_LEN]);
    let token = declare_token(&session, &goal_token).await?;

    let graph = Arc::new(Mutex::new(Graph::default()));
    let watch = GraphWatch {
        own_session: zid.clone(),
        goal_topic: goal_fq,
        goal_type,
        inbound: types
            .iter()
            .map(|(t, ty)| {
                let name = match t {
                    Topic::Fix => &config.fix_topic,
                    Topic::Odom => &config.odom_topic,
                    Topic::Battery => &config.battery_topic,
                    Topic::Rosout => "/rosout",
                };
                (fully_qualified(&config.namespace, name), ty.clone())
            })
            .collect(),
        graph: Arc::clone(&graph),
    };
    let graph_watch = session
        .liveliness()
        .declare_subscriber(format!(
            "{}/{}/**",
            super::zenoh_wire::ADMIN_SPACE,
            z.domain_id
        ))
        .history(true)
        .callback(move |s| watch.on_token(&s))
        .await
        .map_err(zerr("watch the ROS graph"))?;
    info!(
        zid = %zid,
        domain = z.domain_id,
        goal_key = %key,
        "rmw_zenoh session open"
    );
    Ok((
        ZenohInbox {
            rx,
            types,
            _subscribers: subscribers,
            _tokens: tokens,
            _session: session.clone(),
        },
        ZenohGoals {
            publisher,
            gid,
            // rmw_zenoh's sequence numbers start at 1.
            sequence: AtomicI64::new(1),
            graph,
            _token: token,
            _graph_watch: graph_watch,
            _session: session,
        },
    ))
}

fn topic_info(fq: &str, ty: &RosType) -> TopicInfo {
    TopicInfo {
        name: fq.to_string(),
        dds_type: ty.dds.to_string(),
        type_hash: ty.hash.clone(),
        qos: Qos::ROS_DEFAULT.to_keyexpr(),
    }
}

async fn declare_token(session: &Session, key: &str) -> Result<LivelinessToken, Ros2Error> {
    session
        .liveliness()
        .declare_token(key.to_string())
        .await
        .map_err(|source| Ros2Error::Zenoh {
            what: "declare a liveliness token",
            source,
        })
}

/// Zenoh's callback: copy what the link needs and queue it, never blocking Zenoh.
fn enqueue(tx: &mpsc::Sender<Raw>, counters: &Counters, topic: Topic, s: &ZSample) {
    let len = s.payload().len();
    let raw = Raw {
        topic,
        key: s.key_expr().as_str().to_string(),
        payload: if len > MAX_PAYLOAD {
            Err(len)
        } else {
            Ok(s.payload().to_bytes().into_owned())
        },
        attachment: s.attachment().map(|a| a.to_bytes().into_owned()),
    };
    if tx.try_send(raw).is_err() {
        bump(&counters.flooded);
    }
}

/// Follows the graph's liveliness tokens.
struct GraphWatch {
    own_session: String,
    goal_topic: String,
    goal_type: RosType,
    inbound: Vec<(String, RosType)>,
    graph: Arc<Mutex<Graph>>,
}

impl GraphWatch {
    fn on_token(&self, s: &ZSample) {
        let key = s.key_expr().as_str();
        let Some(e) = Entity::parse(key) else {
            return;
        };
        let Some(topic) = e
            .topic
            .as_ref()
            .filter(|_| e.session_id != self.own_session)
        else {
            return;
        };
        let alive = s.kind() == SampleKind::Put;
        let same = |ty: &RosType| topic.dds_type == ty.dds && topic.type_hash == ty.hash;
        match e.kind {
            EntityKind::Subscription if topic.name == self.goal_topic => {
                if !same(&self.goal_type) {
                    warn!(
                        node = %e.node_name,
                        dds_type = %topic.dds_type,
                        type_hash = %topic.type_hash,
                        "a subscription to the goal topic of another type: it cannot receive goals"
                    );
                    return;
                }
                let mut g = self.graph.lock().unwrap_or_else(PoisonError::into_inner);
                if alive {
                    g.goal_readers.insert(key.to_string());
                } else {
                    g.goal_readers.remove(key);
                }
                debug!(node = %e.node_name, alive, readers = g.goal_readers.len(), "goal subscription");
            }
            EntityKind::Publisher => {
                let Some((_, ty)) = self.inbound.iter().find(|(n, _)| *n == topic.name) else {
                    return;
                };
                if !alive {
                    debug!(node = %e.node_name, topic = %topic.name, "vehicle publisher gone");
                } else if same(ty) {
                    info!(node = %e.node_name, topic = %topic.name, "vehicle publisher seen");
                } else {
                    warn!(
                        node = %e.node_name,
                        topic = %topic.name,
                        type_hash = %topic.type_hash,
                        "a vehicle publisher of another type: its samples will be dropped"
                    );
                }
            }
            _ => {}
        }
    }
}
