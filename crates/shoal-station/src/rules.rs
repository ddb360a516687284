//! Rules & Policies as the API and the rules file see them: plain JSON documents.
//!
//! The semantic store keeps rules as RDF and runs them on insert; this module gives them a
//! stable JSON shape (`RuleDoc`) for `GET/POST /api/rules` and for the station's rules
//! file, so that user rules and the enabled state of built-in ones survive a restart.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shoal_model::{EventKind, GeoPoint, Severity};
use shoal_semantic::{Condition, RuleError, RuleInfo, RuleSpec};

/// What a rule checks, as JSON (`{"type": "threshold", "expr": "battery_pct < 20"}`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ConditionDoc {
    /// `field op number` on state vectors (native fast path), e.g. `depth_m > 300`.
    Threshold {
        /// The comparison; fields are the state vector's (`battery_pct`, `depth_m` ...).
        expr: String,
    },
    /// The vehicle is outside this polygon (native).
    OutsideArea {
        /// At least three corners, in order.
        polygon: Vec<GeoPoint>,
    },
    /// No state vector for `factor` × the vehicle's expected reporting period.
    LostContact {
        /// Missed periods.
        factor: f64,
    },
    /// A task still active `grace_ms` after its deadline.
    TaskOverdue {
        /// Grace after the deadline, ms.
        grace_ms: i64,
    },
    /// A SPARQL ASK or SELECT with `?this` bound to the changed entity; runs when one of
    /// `watches` changed on it.
    Sparql {
        /// The query (default prefixes `shoal:`, `geo:`, `sosa:` need no declaration).
        query: String,
        /// Watched properties, as IRIs or prefixed names (`shoal:batteryLevel`).
        watches: Vec<String>,
    },
}

fn default_severity() -> Severity {
    Severity::Warning
}

fn default_kind() -> EventKind {
    EventKind::Rule
}

fn yes() -> bool {
    true
}

/// A rule as JSON: what `POST /api/rules` takes and `GET /api/rules` lists.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RuleDoc {
    /// Identifier: 1..=32 of `[A-Za-z0-9_.-]`.
    pub id: String,
    /// What the rule is for, shown to operators.
    #[serde(default)]
    pub description: String,
    /// Severity of the events it raises (default `warning`).
    #[serde(default = "default_severity")]
    pub severity: Severity,
    /// Kind of the events it raises (default `rule`).
    #[serde(default = "default_kind")]
    pub kind: EventKind,
    /// What it checks.
    pub condition: ConditionDoc,
    /// Whether it runs (default true).
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Built-in rules can be disabled but not deleted; ignored on input.
    #[serde(default)]
    pub built_in: bool,
}

impl RuleDoc {
    /// The semantic store's spec; a threshold expression is parsed here.
    pub fn to_spec(&self) -> Result<RuleSpec, RuleError> {
        let condition = match &self.condition {
            ConditionDoc::Threshold { expr } => Condition::Threshold(expr.parse()?),
            ConditionDoc::OutsideArea { polygon } => Condition::OutsideArea {
                polygon: polygon.clone(),
            },
            ConditionDoc::LostContact { factor } => Condition::LostContact { factor: *factor },
            ConditionDoc::TaskOverdue { grace_ms } => Condition::TaskOverdue {
                grace_ms: *grace_ms,
            },
            ConditionDoc::Sparql { query, watches } => Condition::Sparql {
                query: query.clone(),
                watches: watches.clone(),
            },
        };
        Ok(RuleSpec {
            id: self.id.clone(),
            description: self.description.clone(),
            severity: self.severity,
            kind: self.kind,
            condition,
        })
    }

    /// The document of a rule the store lists.
    pub fn from_info(info: &RuleInfo) -> Self {
        let condition = match &info.spec.condition {
            Condition::Threshold(t) => ConditionDoc::Threshold {
                expr: t.to_string(),
            },
            Condition::OutsideArea { polygon } => ConditionDoc::OutsideArea {
                polygon: polygon.clone(),
            },
            Condition::LostContact { factor } => ConditionDoc::LostContact { factor: *factor },
            Condition::TaskOverdue { grace_ms } => ConditionDoc::TaskOverdue {
                grace_ms: *grace_ms,
            },
            Condition::Sparql { query, watches } => ConditionDoc::Sparql {
                query: query.clone(),
                watches: watches.clone(),
            },
            // A condition this version cannot express as JSON shows as its text.
            other => ConditionDoc::Sparql {
                query: other.to_string(),
                watches: Vec::new(),
            },
        };
        Self {
            id: info.spec.id.clone(),
            description: info.spec.description.clone(),
            severity: info.spec.severity,
            kind: info.spec.kind,
            condition,
            enabled: info.enabled,
            built_in: info.built_in,
        }
    }
}

/// The rules file: user rules, and which built-in rules an operator switched.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct RulesFile {
    /// Every rule, built-in ones included (only their `enabled` is applied).
    pub(crate) rules: Vec<RuleDoc>,
}

/// A rules file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum RulesFileError {
    /// Reading or writing failed.
    #[error("rules file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not a valid rules document.
    #[error("rules file {path}: {detail}")]
    Format {
        /// The file.
        path: PathBuf,
        /// The parser's message, with the JSON path of the bad value.
        detail: String,
    },
}

impl RulesFile {
    /// Reads the file; a missing file is an empty one.
    pub(crate) fn load(path: &Path) -> Result<Self, RulesFileError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Self::default()),
            Err(source) => {
                return Err(RulesFileError::Io {
                    path: path.into(),
                    source,
                });
            }
        };
        let de = &mut serde_json::Deserializer::from_str(&text);
        serde_path_to_error::deserialize(de).map_err(|e| RulesFileError::Format {
            path: path.into(),
            detail: format!("at {}: {}", e.path(), e.inner()),
        })
    }

    /// Writes the file atomically (temporary file, then rename), creating its directory.
    pub(crate) fn save(&self, path: &Path) -> Result<(), RulesFileError> {
        let io = |source| RulesFileError::Io {
            path: path.into(),
            source,
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
        let json = serde_json::to_string_pretty(self).map_err(|e| RulesFileError::Format {
            path: path.into(),
            detail: e.to_string(),
        })?;
        let mut tmp = path.as_os_str().to_owned();
        tmp.push(".tmp");
        let tmp = PathBuf::from(tmp);
        std::fs::write(&tmp, json + "\n").map_err(io)?;
        std::fs::rename(&tmp, path).map_err(io)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_threshold_rule_reads_from_json_with_defaults() {
        let doc: RuleDoc = serde_json::from_str(
            r#"{"id":"deep","condition":{"type":"threshold","expr":"depth_m > 300"}}"#,
        )
        .unwrap();
        assert_eq!(doc.severity, Severity::Warning);
        assert_eq!(doc.kind, EventKind::Rule);
        assert!(doc.enabled);
        let spec = doc.to_spec().unwrap();
        assert_eq!(spec.condition.to_string(), "depth_m > 300");
    }

    #[test]
    fn a_bad_expression_is_a_parse_error() {
        let doc: RuleDoc = serde_json::from_str(
            r#"{"id":"x","condition":{"type":"threshold","expr":"depth_m ~ 3"}}"#,
        )
        .unwrap();
        assert!(matches!(doc.to_spec(), Err(RuleError::Parse(_))));
    }

    #[test]
    fn unknown_fields_and_types_are_refused() {
        assert!(
            serde_json::from_str::<RuleDoc>(
                r#"{"id":"x","colour":"red","condition":{"type":"threshold","expr":"depth_m > 3"}}"#
            )
            .is_err()
        );
        assert!(
            serde_json::from_str::<RuleDoc>(r#"{"id":"x","condition":{"type":"magic"}}"#).is_err()
        );
    }

    #[test]
    fn the_rules_file_round_trips_and_names_its_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/rules.json");
        assert_eq!(RulesFile::load(&path).unwrap(), RulesFile::default());
        let file = RulesFile {
            rules: vec![RuleDoc {
                id: "deep".into(),
                description: "too deep".into(),
                severity: Severity::Alarm,
                kind: EventKind::Rule,
                condition: ConditionDoc::Threshold {
                    expr: "depth_m > 300".into(),
                },
                enabled: false,
                built_in: false,
            }],
        };
        file.save(&path).unwrap();
        assert_eq!(RulesFile::load(&path).unwrap(), file);
        std::fs::write(
            &path,
            r#"{"rules":[{"id":"x","condition":{"type":"threshold"}}]}"#,
        )
        .unwrap();
        let err = RulesFile::load(&path).unwrap_err().to_string();
        assert!(
            err.contains("rules.json") && err.contains("rules[0]"),
            "{err}"
        );
    }
}
