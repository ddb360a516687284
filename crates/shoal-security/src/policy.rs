//! The publish access policy: which identity may publish which topics, for which instances.
//!
//! The policy is a TOML file of `[[allow]]` rules; anything no rule allows is denied:
//!
//! ```toml
//! [[allow]]
//! publisher = "vehicle"              # a role, or one identity: "vehicle:auv-1", "station:ccs"
//! topics = ["shoal/state_vector"]    # topic names, or "*" for every topic
//! instances = "own"                  # "own": only samples whose vehicle id is the publisher's
//! ```
//!
//! The instance key [`Policy::check`] takes is the vehicle a sample speaks for (the
//! `vehicle_id` field every Shoal topic type carries; [`VehicleOwned`] reads it), so "own"
//! is what stops a vehicle holding a valid certificate from publishing another vehicle's
//! position. [`DEFAULT_POLICY`] is the policy Shoal ships.

use std::fmt;
use std::ops::Range;
use std::path::Path;

use serde::Deserialize;
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement,
};
use toml::Spanned;

use crate::files::{self, FileError};
use crate::identity::{Identity, Role};

/// The policy Shoal ships (`policy.default.toml` in this crate), equal to [`Policy::builtin`].
pub const DEFAULT_POLICY: &str = include_str!("../policy.default.toml");

/// Topics a vehicle publishes about itself, as `shoal-dds` names them.
const VEHICLE_TOPICS: [&str; 5] = [
    "shoal/state_vector",
    "shoal/vehicle_announcement",
    "shoal/task_status",
    "shoal/event",
    "shoal/environment",
];

/// Which instances a rule covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Instances {
    /// Only instances whose key is the publisher's own name (vehicle id).
    Own,
    /// Any instance.
    Any,
}

/// Who a rule applies to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Publisher {
    /// Every identity with this role.
    Role(Role),
    /// Exactly this identity.
    Identity(Identity),
}

impl Publisher {
    fn parse(s: &str) -> Result<Self, String> {
        if let Some(role) = Role::parse(s) {
            return Ok(Self::Role(role));
        }
        let (role, name) = s.split_once(':').ok_or_else(|| {
            format!("{s:?} is neither a role (\"vehicle\", \"station\") nor \"<role>:<name>\"")
        })?;
        let role = Role::parse(role).ok_or_else(|| {
            format!("unknown role {role:?} (expected \"vehicle\" or \"station\")")
        })?;
        Identity::new(role, name)
            .map(Self::Identity)
            .map_err(|e| e.to_string())
    }

    fn matches(&self, who: &Identity) -> bool {
        match self {
            Self::Role(r) => who.role() == *r,
            Self::Identity(id) => id == who,
        }
    }
}

impl fmt::Display for Publisher {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Role(r) => write!(f, "{r}"),
            Self::Identity(id) => write!(f, "{id}"),
        }
    }
}

/// One `[[allow]]` rule.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rule {
    /// Who may publish.
    pub publisher: Publisher,
    /// Topic names; `"*"` stands for every topic.
    pub topics: Vec<String>,
    /// Which instances.
    pub instances: Instances,
}

impl Rule {
    fn covers_topic(&self, topic: &str) -> bool {
        self.topics.iter().any(|t| t == "*" || t == topic)
    }
}

/// A parsed access policy.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Policy {
    rules: Vec<Rule>,
}

/// Why a publication was denied.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DenyReason {
    /// No rule lets this publisher publish on this topic at all.
    TopicNotAllowed,
    /// Rules allow the topic only for other instances (e.g. only the vehicle's own).
    WrongInstance,
}

/// A publication the policy does not allow.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{identity} may not publish {topic:?}{}", match reason {
    DenyReason::TopicNotAllowed => String::new(),
    DenyReason::WrongInstance => format!(" for instance {instance:?} (not its own)"),
})]
pub struct Denied {
    /// The authenticated publisher.
    pub identity: Identity,
    /// The topic.
    pub topic: String,
    /// The instance key.
    pub instance: String,
    /// Why.
    pub reason: DenyReason,
}

/// Why a policy file was refused; every variant names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PolicyError {
    /// The file could not be read.
    #[error(transparent)]
    File(#[from] FileError),
    /// Not valid TOML, or keys that do not belong (unknown, missing, wrong type).
    #[error("{file}: line {line}, column {column}: {message}")]
    Syntax {
        /// The file (or source name).
        file: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// Well-formed TOML with a value that makes no sense.
    #[error("{file}: line {line}: {key}: {problem}")]
    Invalid {
        /// The file (or source name).
        file: String,
        /// 1-based line of the value.
        line: usize,
        /// The key, e.g. `allow[2].publisher`.
        key: String,
        /// What is wrong.
        problem: String,
    },
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPolicy {
    #[serde(default)]
    allow: Vec<RawRule>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRule {
    publisher: Spanned<String>,
    topics: Spanned<Vec<Spanned<String>>>,
    instances: Instances,
}

/// 1-based line and column of byte `offset` in `text`.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let column = before
        .rsplit('\n')
        .next()
        .map_or(1, |l| l.chars().count() + 1);
    (line, column)
}

impl Policy {
    /// The policy Shoal ships: vehicles publish their own state, announcements, task status,
    /// events and observations; the station publishes anything (tasks are only its; it also
    /// relays what vehicles send over the acoustic link).
    pub fn builtin() -> Self {
        Self {
            rules: vec![
                Rule {
                    publisher: Publisher::Role(Role::Vehicle),
                    topics: VEHICLE_TOPICS.iter().map(|t| (*t).to_owned()).collect(),
                    instances: Instances::Own,
                },
                Rule {
                    publisher: Publisher::Role(Role::Station),
                    topics: vec!["*".to_owned()],
                    instances: Instances::Any,
                },
            ],
        }
    }

    /// A policy from rules (tests and programmatic setups).
    pub fn from_rules(rules: Vec<Rule>) -> Self {
        Self { rules }
    }

    /// The rules, in file order.
    pub fn rules(&self) -> &[Rule] {
        &self.rules
    }

    /// Parses policy TOML; `file` names the source in error messages.
    pub fn from_toml(text: &str, file: &str) -> Result<Self, PolicyError> {
        let raw: RawPolicy = toml::from_str(text).map_err(|e| {
            let (line, column) = line_col(text, e.span().map_or(0, |s| s.start));
            PolicyError::Syntax {
                file: file.to_owned(),
                line,
                column,
                message: e.message().trim().to_owned(),
            }
        })?;
        let invalid = |span: Range<usize>, key: String, problem: String| {
            let (line, _) = line_col(text, span.start);
            PolicyError::Invalid {
                file: file.to_owned(),
                line,
                key,
                problem,
            }
        };
        let mut rules = Vec::with_capacity(raw.allow.len());
        for (i, r) in raw.allow.into_iter().enumerate() {
            let publisher = Publisher::parse(r.publisher.get_ref())
                .map_err(|p| invalid(r.publisher.span(), format!("allow[{i}].publisher"), p))?;
            if r.topics.get_ref().is_empty() {
                return Err(invalid(
                    r.topics.span(),
                    format!("allow[{i}].topics"),
                    "is empty: list topic names, or \"*\" for all".into(),
                ));
            }
            let mut topics = Vec::with_capacity(r.topics.get_ref().len());
            for (j, t) in r.topics.get_ref().iter().enumerate() {
                let name = t.get_ref();
                if name.is_empty() || name.chars().any(char::is_whitespace) {
                    return Err(invalid(
                        t.span(),
                        format!("allow[{i}].topics[{j}]"),
                        format!("{name:?} is not a topic name"),
                    ));
                }
                topics.push(name.clone());
            }
            rules.push(Rule {
                publisher,
                topics,
                instances: r.instances,
            });
        }
        Ok(Self { rules })
    }

    /// Loads a policy file.
    pub fn load(path: &Path) -> Result<Self, PolicyError> {
        let text = files::read_public(path)?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// Whether `who` may publish on `topic` the instance keyed `instance_key` (the vehicle
    /// id the sample speaks for, see [`VehicleOwned`]).
    pub fn check(&self, who: &Identity, topic: &str, instance_key: &str) -> Result<(), Denied> {
        let mut topic_allowed = false;
        for rule in &self.rules {
            if !rule.publisher.matches(who) || !rule.covers_topic(topic) {
                continue;
            }
            topic_allowed = true;
            match rule.instances {
                Instances::Any => return Ok(()),
                Instances::Own if instance_key == who.name() => return Ok(()),
                Instances::Own => {}
            }
        }
        Err(Denied {
            identity: who.clone(),
            topic: topic.to_owned(),
            instance: instance_key.to_owned(),
            reason: if topic_allowed {
                DenyReason::WrongInstance
            } else {
                DenyReason::TopicNotAllowed
            },
        })
    }
}

impl Default for Policy {
    fn default() -> Self {
        Self::builtin()
    }
}

/// A sample that speaks for one vehicle: the instance key [`Policy::check`] takes.
pub trait VehicleOwned {
    /// The vehicle id the sample is about (for a task assignment: the vehicle tasked).
    fn owner_vehicle(&self) -> &str;
}

macro_rules! vehicle_owned {
    ($($t:ty),*) => {$(
        impl VehicleOwned for $t {
            fn owner_vehicle(&self) -> &str {
                &self.vehicle_id
            }
        }
    )*};
}

vehicle_owned!(
    StateVector,
    VehicleAnnouncement,
    TaskAssignment,
    TaskStatus,
    Event,
    EnvironmentObservation
);

#[cfg(test)]
mod tests {
    use super::*;

    fn v(id: &str) -> Identity {
        Identity::vehicle(id).unwrap()
    }

    #[test]
    fn the_shipped_file_is_the_builtin_policy() {
        let p = Policy::from_toml(DEFAULT_POLICY, "policy.default.toml").unwrap();
        assert_eq!(p, Policy::builtin());
    }

    #[test]
    fn vehicles_publish_only_their_own_data_and_never_tasks() {
        let p = Policy::builtin();
        let station = Identity::station("ccs").unwrap();
        p.check(&v("auv-1"), "shoal/state_vector", "auv-1").unwrap();
        let d = p
            .check(&v("auv-1"), "shoal/state_vector", "auv-2")
            .unwrap_err();
        assert_eq!(d.reason, DenyReason::WrongInstance);
        assert!(d.to_string().contains("auv-2"), "{d}");
        let d = p
            .check(&v("auv-1"), "shoal/task_assignment", "auv-1")
            .unwrap_err();
        assert_eq!(d.reason, DenyReason::TopicNotAllowed);
        p.check(&station, "shoal/task_assignment", "auv-1").unwrap();
        p.check(&station, "shoal/state_vector", "auv-9").unwrap();
    }

    #[test]
    fn single_identity_rules_apply_to_that_identity_only() {
        let p = Policy::from_toml(
            "[[allow]]\npublisher = \"vehicle:relay-1\"\ntopics = [\"*\"]\ninstances = \"any\"\n",
            "t.toml",
        )
        .unwrap();
        p.check(&v("relay-1"), "shoal/state_vector", "auv-3")
            .unwrap();
        assert!(p.check(&v("auv-3"), "shoal/state_vector", "auv-3").is_err());
    }

    #[test]
    fn an_empty_policy_denies_everything() {
        let p = Policy::from_toml("", "empty.toml").unwrap();
        assert!(p.rules().is_empty());
        assert!(p.check(&v("a"), "shoal/state_vector", "a").is_err());
    }

    fn err(text: &str) -> String {
        Policy::from_toml(text, "p.toml").unwrap_err().to_string()
    }

    #[test]
    fn parse_errors_name_the_file_line_and_key() {
        let e = err(
            "[[allow]]\npublisher = \"vehicle\"\ntopics = [\"a\"]\ninstances = \"own\"\ncolour = 1\n",
        );
        assert!(e.starts_with("p.toml: line 5, column 1:"), "{e}");
        assert!(e.contains("unknown field `colour`"), "{e}");

        let e = err("[[allow]]\npublisher = \"vehicle\"\ninstances = \"own\"\n");
        assert!(e.starts_with("p.toml: line 1"), "{e}");
        assert!(e.contains("missing field `topics`"), "{e}");

        let e = err("[[allow]]\npublisher = \"robot\"\ntopics = [\"a\"]\ninstances = \"own\"\n");
        assert!(e.starts_with("p.toml: line 2: allow[0].publisher:"), "{e}");

        let e =
            err("[[allow]]\npublisher = \"vehicle:a/b\"\ntopics = [\"a\"]\ninstances = \"own\"\n");
        assert!(e.contains("allow[0].publisher"), "{e}");

        let e = err("[[allow]]\npublisher = \"vehicle\"\ntopics = []\ninstances = \"own\"\n");
        assert!(e.starts_with("p.toml: line 3: allow[0].topics:"), "{e}");

        let e = err(
            "[[allow]]\npublisher = \"station\"\ntopics = [\"*\"]\ninstances = \"any\"\n[[allow]]\npublisher = \"vehicle\"\ntopics = [\"a\", \"\"]\ninstances = \"own\"\n",
        );
        assert!(e.starts_with("p.toml: line 7: allow[1].topics[1]:"), "{e}");

        let e = err("[[allow]]\npublisher = \"vehicle\"\ntopics = [\"a\"]\ninstances = \"some\"\n");
        assert!(e.starts_with("p.toml: line 4"), "{e}");
        assert!(e.contains("some"), "{e}");

        let e = err("[[allow]\n");
        assert!(e.starts_with("p.toml: line 1"), "{e}");
    }

    #[test]
    fn missing_policy_file_names_it() {
        let e = Policy::load(Path::new("/nonexistent/policy.toml")).unwrap_err();
        assert_eq!(e.to_string(), "/nonexistent/policy.toml: missing");
    }

    #[test]
    fn every_topic_type_names_its_vehicle() {
        let sv = StateVector {
            vehicle_id: "auv-1".into(),
            ..serde_json::from_str::<StateVector>(SV_JSON).unwrap()
        };
        assert_eq!(sv.owner_vehicle(), "auv-1");
    }

    const SV_JSON: &str = r#"{"vehicle_id":"x","timestamp_ms":1780000000000,"latitude_deg":43.0,
        "longitude_deg":-8.0,"depth_m":10.0,"altitude_m":5.0,"speed_mps":1.0,"yaw_deg":0.0,
        "pitch_deg":0.0,"roll_deg":0.0,"battery_pct":90.0}"#;
}
