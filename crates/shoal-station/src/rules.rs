//! Rules & Policies as the API and the rules file see them: plain JSON documents.
//!
//! The semantic store keeps rules as RDF and runs them on insert; this module gives them a
//! stable JSON shape (`RuleDoc`) for `GET/POST /api/rules` and for the station's rules
//! file, so that user rules and the enabled state of built-in ones survive a restart.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shoal_model::{EventKind, GeoPoint, Severity};
use shoal_semantic::{Condition, RuleError, RuleInfo, RuleSpec, SemanticStore};
use tracing::{info, warn};

use crate::core::{StationHandle, lock};
use crate::error::RuleChangeError;

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
    /// A rule in the file is refused by the semantic model.
    #[error("rules file {path}: rule {id}: {source}")]
    Rule {
        /// The file.
        path: PathBuf,
        /// The rule's identifier.
        id: String,
        /// Why it is refused.
        source: RuleError,
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

/// Applies the rules file: creates its user rules and switches built-in ones as saved.
pub(crate) fn apply_rules_file(
    semantic: &mut SemanticStore,
    path: &Path,
) -> Result<(), RulesFileError> {
    let file = RulesFile::load(path)?;
    let bad = |id: &str, source| RulesFileError::Rule {
        path: path.into(),
        id: id.to_owned(),
        source,
    };
    for doc in &file.rules {
        if !doc.built_in {
            let spec = doc.to_spec().map_err(|e| bad(&doc.id, e))?;
            semantic.create_rule(spec).map_err(|e| bad(&doc.id, e))?;
        }
        match semantic.set_rule_enabled(&doc.id, doc.enabled) {
            Ok(()) => {}
            // A built-in rule this version no longer has: nothing to switch.
            Err(e) if doc.built_in => {
                warn!(path = %path.display(), rule = %doc.id, error = %e, "saved built-in rule ignored");
            }
            Err(e) => return Err(bad(&doc.id, e)),
        }
    }
    if !file.rules.is_empty() {
        info!(path = %path.display(), rules = file.rules.len(), "rules loaded");
    }
    Ok(())
}

/// The API side of Rules & Policies: every change is applied to the semantic model and
/// saved to the rules file, in the order changes were made.
impl StationHandle {
    /// Every rule, built-in ones included, ordered by identifier.
    pub fn rules(&self) -> Vec<RuleDoc> {
        lock(&self.core.semantic)
            .rules()
            .iter()
            .map(RuleDoc::from_info)
            .collect()
    }

    /// One rule.
    pub fn rule(&self, id: &str) -> Option<RuleDoc> {
        self.rules().into_iter().find(|r| r.id == id)
    }

    /// Creates a user rule (checked and, for SPARQL, parsed now); it is saved for restarts.
    pub fn create_rule(&self, doc: &RuleDoc) -> Result<RuleDoc, RuleChangeError> {
        self.change_rules(&doc.id, |sem| {
            sem.create_rule(doc.to_spec()?)?;
            if !doc.enabled {
                sem.set_rule_enabled(&doc.id, false)?;
            }
            Ok(())
        })
    }

    /// Enables or disables a rule, built-in ones included.
    pub fn set_rule_enabled(&self, id: &str, enabled: bool) -> Result<RuleDoc, RuleChangeError> {
        self.change_rules(id, |sem| sem.set_rule_enabled(id, enabled))
    }

    /// Replaces a user rule's definition (description, severity, kind, condition, enabled)
    /// with `doc`, checked exactly as [`Self::create_rule`] checks a new one. On a refused
    /// definition the rule stays as it was; built-in rules can only be enabled or disabled.
    pub fn replace_rule(&self, doc: &RuleDoc) -> Result<RuleDoc, RuleChangeError> {
        self.change_rules(&doc.id, |sem| {
            let old = sem
                .rules()
                .into_iter()
                .find(|r| r.spec.id == doc.id)
                .ok_or_else(|| RuleError::NotFound(doc.id.clone()))?;
            if old.built_in {
                return Err(RuleError::BuiltIn(doc.id.clone()));
            }
            // A threshold expression is parsed here, before anything changes.
            let spec = doc.to_spec()?;
            // The store has no in-place update: the semantic lock is held throughout, so
            // no datum is ever checked against a half-replaced rule.
            sem.delete_rule(&doc.id)?;
            if let Err(e) = sem.create_rule(spec) {
                // The old definition was accepted before, so it is accepted again.
                if let Err(back) = sem.create_rule(old.spec) {
                    warn!(rule = %doc.id, error = %back, "rule lost while restoring it");
                } else if !old.enabled
                    && let Err(back) = sem.set_rule_enabled(&doc.id, false)
                {
                    warn!(rule = %doc.id, error = %back, "restored rule left enabled");
                }
                return Err(e);
            }
            if !doc.enabled {
                sem.set_rule_enabled(&doc.id, false)?;
            }
            Ok(())
        })
    }

    /// Deletes a user rule (built-in rules can only be disabled).
    pub fn delete_rule(&self, id: &str) -> Result<(), RuleChangeError> {
        let _file = lock(&self.core.rules_file);
        let docs = {
            let mut sem = lock(&self.core.semantic);
            sem.delete_rule(id)?;
            sem.rules().iter().map(RuleDoc::from_info).collect()
        };
        info!(rule = id, "rule deleted");
        self.save_rules(docs)
    }

    fn change_rules(
        &self,
        id: &str,
        change: impl FnOnce(&mut SemanticStore) -> Result<(), RuleError>,
    ) -> Result<RuleDoc, RuleChangeError> {
        let _file = lock(&self.core.rules_file);
        let docs: Vec<RuleDoc> = {
            let mut sem = lock(&self.core.semantic);
            change(&mut sem)?;
            sem.rules().iter().map(RuleDoc::from_info).collect()
        };
        let doc = docs
            .iter()
            .find(|d| d.id == id)
            .cloned()
            .ok_or_else(|| RuleError::NotFound(id.to_owned()))?;
        info!(rule = id, enabled = doc.enabled, condition = ?doc.condition, "rule changed");
        self.save_rules(docs)?;
        Ok(doc)
    }

    fn save_rules(&self, rules: Vec<RuleDoc>) -> Result<(), RuleChangeError> {
        RulesFile { rules }
            .save(&self.core.config.rules_path)
            .map_err(|e| {
                warn!(error = %e, "rules not saved");
                RuleChangeError::Save(e)
            })
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
