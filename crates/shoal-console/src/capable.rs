//! `GET /api/fleet/capable?kind=<task kind>&capability=<code>[,<code>...]`: which vehicles can
//! do a task, answered from the semantic model, and which of them the station would give it
//! to now.
//!
//! *Capable* comes from the model: the capability the ontology says the task kind requires
//! (`shoal:requiresCapability`) and any further capability asked for, each held by the
//! vehicle through `shoal:hasCapability` — declared in its announcement or inferred by the
//! reasoner from a hosted sensor (a side-scan sonar gives `sidescan_survey`). *Dispatchable*
//! adds what the station itself checks when a task goes out ([`StationHandle::check_dispatch`]:
//! contact, the announced capability, battery against `min_dispatch_battery_pct`), so the
//! console never offers a vehicle the station would refuse, and says why.
//!
//! Another site's vehicle whose command lease this station holds follows the fleet: a
//! mission here may give it tasks, which go through its site. This station knows of it
//! only what the federation carries (kind, position, battery, age), so its site's station
//! is the one to check capability, contact and battery when a task reaches it.

use std::collections::{BTreeMap, BTreeSet};

use axum::extract::{Query, State};
use axum::response::IntoResponse;
use axum::{Json, extract::rejection::QueryRejection};
use serde::{Deserialize, Serialize};
use shoal_model::TaskKind;
use shoal_station::{Availability, Contact, DispatchError, FederationSnapshot, StationHandle};

use crate::ApiError;

const PREFIXES: &str = "PREFIX shoal: <https://example.invalid/shoal/ontology#>\n\
    PREFIX sosa: <http://www.w3.org/ns/sosa/>\n\
    PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>\n";

/// Most capability codes one request may ask for.
const MAX_CAPABILITIES: usize = 8;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CapableQuery {
    /// A task kind (`goto_waypoint`, `survey_area`, ...): its required capability counts.
    kind: Option<String>,
    /// Further capability codes, comma separated (`sidescan_survey`).
    capability: Option<String>,
}

/// A capability the request needs.
#[derive(Debug, Clone, Serialize)]
struct Requirement {
    /// Its code (`survey`, `sidescan_survey`).
    capability: String,
    /// Its label in the ontology, when it has one.
    label: Option<String>,
    /// Its IRI in the model.
    iri: String,
    /// `kind` when the task kind requires it, `request` when it was asked for.
    from: &'static str,
}

/// How a vehicle holds one required capability.
#[derive(Debug, Serialize)]
struct Held {
    capability: String,
    /// Listed in the vehicle's announcement.
    declared: bool,
    /// Sensor codes the reasoner inferred it from (empty when only declared).
    inferred_from: Vec<String>,
}

/// One vehicle of the fleet against the request.
#[derive(Debug, Serialize)]
struct Candidate {
    vehicle_id: String,
    /// Vehicle kind (`auv`, `usv`, ...).
    kind: String,
    /// Holds every required capability, per the semantic model.
    capable: bool,
    /// The required capabilities it holds, and how.
    capabilities: Vec<Held>,
    /// The required capabilities it lacks.
    missing: Vec<String>,
    /// Absent for another site's vehicle: its own station judges contact.
    contact: Option<Contact>,
    /// Absent for another site's vehicle.
    availability: Option<Availability>,
    /// The site whose vehicle it is, when it is another site's (under a command lease this
    /// station holds); absent for this station's own.
    site: Option<String>,
    /// For another site's vehicle: how old the federation's latest position of it is, ms.
    age_ms: Option<i64>,
    /// Latest battery level, % (absent before the first state or when unknown).
    battery_pct: Option<f64>,
    /// Capable, and the station would send it the task now.
    dispatchable: bool,
    /// Why it is not dispatchable (empty when it is).
    reasons: Vec<String>,
    /// What the operator should know although the station would accept it (busy, stale).
    notes: Vec<String>,
}

#[derive(Debug, Serialize)]
struct CapableAnswer {
    kind: Option<TaskKind>,
    requires: Vec<Requirement>,
    /// Every vehicle of the fleet: dispatchable ones first, then capable, then the rest;
    /// then the other sites' vehicles whose command lease this station holds.
    vehicles: Vec<Candidate>,
}

fn bad(msg: impl Into<String>) -> ApiError {
    ApiError::BadRequest(msg.into())
}

fn parse_kind(raw: &str) -> Result<TaskKind, ApiError> {
    serde_json::from_value(serde_json::Value::String(raw.to_owned())).map_err(|_| {
        bad(format!(
            "kind: unknown task kind {raw:?}; use goto_waypoint, survey_area, hold, surface, \
             return_home, abort, request_state or set_reporting_rate"
        ))
    })
}

/// Runs a SELECT over the snapshot; each row maps a variable to its value's lexical form.
fn select(
    snapshot: &shoal_semantic::QuerySnapshot,
    query: &str,
) -> Result<Vec<BTreeMap<String, String>>, String> {
    let text = format!("{PREFIXES}{query}");
    let result = snapshot
        .query(&text, &shoal_semantic::QueryLimits::default())
        .map_err(|e| e.to_string())?;
    let bytes = result
        .write(shoal_semantic::ResultFormat::Json, Vec::new())
        .map_err(|e| e.to_string())?;
    // The SPARQL 1.1 JSON results format spares this crate a direct Oxigraph dependency.
    let doc: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| e.to_string())?;
    let bindings = doc["results"]["bindings"]
        .as_array()
        .ok_or("SPARQL answer without results")?;
    Ok(bindings
        .iter()
        .filter_map(serde_json::Value::as_object)
        .map(|row| {
            row.iter()
                .filter_map(|(var, cell)| Some((var.clone(), cell["value"].as_str()?.to_owned())))
                .collect()
        })
        .collect())
}

/// Picks the code to show for a capability: the preferred one if it has it, else the first.
fn code_of(codes: &BTreeSet<String>, preferred: &str) -> String {
    if codes.contains(preferred) {
        return preferred.to_owned();
    }
    codes.iter().next().cloned().unwrap_or_default()
}

/// What the semantic model says: the requirements, and per vehicle id each required
/// capability it holds (IRI → declared, sensors it is inferred from).
type Holdings = BTreeMap<String, BTreeMap<String, (bool, BTreeSet<String>)>>;

fn ask_model(
    snapshot: &shoal_semantic::QuerySnapshot,
    kind: Option<TaskKind>,
    codes: &[String],
) -> Result<Result<(Vec<Requirement>, Holdings), ApiError>, String> {
    let mut requires: Vec<Requirement> = Vec::new();
    let mut add = |iri: String, codes: &BTreeSet<String>, prefer: &str, label, from| {
        if !requires.iter().any(|r| r.iri == iri) {
            requires.push(Requirement {
                capability: code_of(codes, prefer),
                label,
                iri,
                from,
            });
        }
    };
    if let Some(k) = kind {
        // `kind` parsed as a TaskKind, so the literal is one of eight fixed codes.
        let code = serde_json::to_value(k)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default();
        let rows = select(
            snapshot,
            &format!(
                "SELECT ?task ?cap ?code ?label WHERE {{ ?task shoal:code \"{code}\" ; \
                 rdfs:subClassOf shoal:Task . OPTIONAL {{ ?task shoal:requiresCapability ?cap . \
                 ?cap shoal:code ?code . OPTIONAL {{ ?cap rdfs:label ?label }} }} }}"
            ),
        )?;
        if rows.is_empty() {
            return Ok(Err(bad(format!(
                "kind: the ontology has no task class with code {code:?}"
            ))));
        }
        let mut caps: BTreeMap<String, (BTreeSet<String>, Option<String>)> = BTreeMap::new();
        for r in &rows {
            if let (Some(cap), Some(c)) = (r.get("cap"), r.get("code")) {
                let e = caps.entry(cap.clone()).or_default();
                e.0.insert(c.clone());
                if e.1.is_none() {
                    e.1 = r.get("label").cloned();
                }
            }
        }
        for (iri, (cs, label)) in caps {
            add(iri, &cs, k.capability(), label, "kind");
        }
    }
    for code in codes {
        // Checked as an identifier by the caller: safe inside a string literal.
        let rows = select(
            snapshot,
            &format!(
                "SELECT DISTINCT ?cap ?code ?label WHERE {{ ?cap shoal:code \"{code}\" ; a ?cls ; \
                 shoal:code ?code . ?cls rdfs:subClassOf* shoal:Capability . \
                 OPTIONAL {{ ?cap rdfs:label ?label }} }}"
            ),
        )?;
        let Some(first) = rows.first() else {
            return Ok(Err(bad(format!(
                "capability: {code:?} is neither in the ontology nor announced by any vehicle"
            ))));
        };
        let iri = first.get("cap").cloned().unwrap_or_default();
        let cs: BTreeSet<String> = rows
            .iter()
            .filter(|r| r.get("cap") == Some(&iri))
            .filter_map(|r| r.get("code").cloned())
            .collect();
        add(iri, &cs, code, first.get("label").cloned(), "request");
    }
    // Every (vehicle, capability) the model holds, declared or inferred; the requirements
    // are few, so filtering here beats building a VALUES clause out of model IRIs.
    let rows = select(
        snapshot,
        "SELECT ?id ?cap ?declared ?sensor WHERE { ?v shoal:vehicleId ?id ; \
         shoal:hasCapability ?cap . \
         OPTIONAL { ?v shoal:declaresCapability ?cap . BIND(true AS ?declared) } \
         OPTIONAL { ?v sosa:hosts ?s . ?s a ?cls ; shoal:sensorCode ?sensor . \
                    ?cls shoal:enablesCapability ?cap } }",
    )?;
    let mut holdings: Holdings = BTreeMap::new();
    for r in rows {
        let (Some(id), Some(cap)) = (r.get("id"), r.get("cap")) else {
            continue;
        };
        if !requires.iter().any(|q| &q.iri == cap) {
            continue;
        }
        let e = holdings
            .entry(id.clone())
            .or_default()
            .entry(cap.clone())
            .or_default();
        e.0 |= r.get("declared").is_some_and(|d| d == "true");
        if let Some(s) = r.get("sensor") {
            e.1.insert(s.clone());
        }
    }
    Ok(Ok((requires, holdings)))
}

/// How old another site's data may be before the console is told so (its positions cross
/// at a fraction of a hertz, so a few seconds is normal).
const REMOTE_OLD_MS: i64 = 60_000;

/// The other sites' vehicles whose command lease this station holds, as candidates: this
/// station cannot judge their capabilities (they are not in its semantic model), so they
/// count as capable; they are dispatchable while their site is online, since a task for
/// one goes through that site.
fn leased_elsewhere(federation: &FederationSnapshot) -> Vec<Candidate> {
    let mut out: Vec<Candidate> = federation
        .leases
        .iter()
        .filter(|l| l.held_here && l.home != federation.site)
        .map(|lease| {
            let site = &lease.home;
            let seen = federation
                .vehicles
                .iter()
                .find(|v| &v.site == site && v.vehicle_id == lease.vehicle_id);
            let online = federation.sites.iter().any(|s| &s.site == site && s.online);
            let mut reasons = Vec::new();
            if !online {
                reasons.push(format!(
                    "site {site} is offline: a task for its vehicle could not reach it"
                ));
            }
            if seen.is_none() {
                reasons.push(format!(
                    "no position of {} from site {site} yet",
                    lease.vehicle_id
                ));
            }
            let mut notes = vec![format!(
                "at site {site}: its station checks capability, contact and battery when the \
                 task reaches it; this station holds the command lease (term {})",
                lease.term
            )];
            if let Some(v) = seen.filter(|v| v.age_ms > REMOTE_OLD_MS) {
                notes.push(format!(
                    "old data: the latest position from {site} is {} s old",
                    v.age_ms / 1000
                ));
            }
            Candidate {
                vehicle_id: lease.vehicle_id.clone(),
                kind: seen.map(|v| v.kind.as_str().to_owned()).unwrap_or_default(),
                capable: true,
                capabilities: Vec::new(),
                missing: Vec::new(),
                contact: None,
                availability: None,
                site: Some(site.clone()),
                age_ms: seen.map(|v| v.age_ms),
                battery_pct: seen
                    .map(|v| v.battery_pct)
                    .filter(|b| (0.0..=100.0).contains(b)),
                dispatchable: reasons.is_empty(),
                reasons,
                notes,
            }
        })
        .collect();
    out.sort_by(|a, b| {
        (!a.dispatchable, &a.site, &a.vehicle_id).cmp(&(!b.dispatchable, &b.site, &b.vehicle_id))
    });
    out
}

pub(crate) async fn capable(
    State(s): State<StationHandle>,
    q: Result<Query<CapableQuery>, QueryRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Query(q) = q.map_err(|e| bad(e.body_text()))?;
    let kind = match q.kind.as_deref().map(str::trim) {
        None | Some("") => None,
        Some(k) => Some(parse_kind(k)?),
    };
    let codes: Vec<String> = q
        .capability
        .as_deref()
        .unwrap_or("")
        .split(',')
        .map(str::trim)
        .filter(|c| !c.is_empty())
        .map(str::to_owned)
        .collect();
    if kind.is_none() && codes.is_empty() {
        return Err(bad(
            "give kind=<task kind> (e.g. survey_area), capability=<code>[,<code>...], or both",
        ));
    }
    if codes.len() > MAX_CAPABILITIES {
        return Err(bad(format!("capability: at most {MAX_CAPABILITIES} codes")));
    }
    if let Some(c) = codes
        .iter()
        .find(|c| !shoal_model::is_identifier(c, shoal_model::MAX_ID_LEN))
    {
        return Err(bad(format!(
            "capability: {c:?} is not a code (1 to 64 letters, digits, \"_\", \".\" or \"-\")"
        )));
    }
    let snapshot = s.semantic_snapshot();
    let (requires, holdings) =
        tokio::task::spawn_blocking(move || ask_model(&snapshot, kind, &codes))
            .await
            .map_err(|e| ApiError::Internal(e.to_string()))?
            .map_err(ApiError::Internal)??;

    let mut vehicles: Vec<Candidate> = s
        .fleet()
        .into_iter()
        .map(|v| {
            let id = v.announcement.vehicle_id.clone();
            let held = holdings.get(&id);
            let mut capabilities = Vec::new();
            let mut missing = Vec::new();
            for r in &requires {
                match held.and_then(|h| h.get(&r.iri)) {
                    Some((declared, sensors)) => capabilities.push(Held {
                        capability: r.capability.clone(),
                        declared: *declared,
                        inferred_from: sensors.iter().cloned().collect(),
                    }),
                    None => missing.push(r.capability.clone()),
                }
            }
            let capable = missing.is_empty();
            let mut reasons: Vec<String> = missing
                .iter()
                .map(|m| format!("no {m:?} capability: neither announced nor given by a sensor"))
                .collect();
            if let Some(k) = kind
                && let Err(e) = s.check_dispatch(&id, k)
            {
                // The station's own word on the kind's capability repeats `missing`.
                let repeated = matches!(&e, DispatchError::Incapable { capability, .. }
                    if missing.iter().any(|m| m == capability));
                if !repeated {
                    reasons.push(e.to_string());
                }
            } else if kind.is_none() && v.contact == Contact::Lost {
                reasons.push(format!("vehicle {id} is lost: no contact"));
            }
            let mut notes = Vec::new();
            match v.contact {
                Contact::Stale => notes.push("stale: no state vector for a while".to_owned()),
                Contact::Silent => notes.push("silent: no state vector yet".to_owned()),
                _ => {}
            }
            match v.availability {
                Availability::Busy => {
                    notes.push("busy: a task is under way; a new one is sent as well".to_owned());
                }
                Availability::Fault => notes.push("reported a fault recently".to_owned()),
                Availability::Charging => notes.push("charging at the surface".to_owned()),
                _ => {}
            }
            let battery_pct = v
                .latest
                .as_ref()
                .map(|l| l.battery_pct)
                .filter(|b| *b != shoal_model::UNKNOWN);
            Candidate {
                vehicle_id: id,
                kind: v.announcement.kind.as_str().to_owned(),
                capable,
                capabilities,
                missing,
                contact: Some(v.contact),
                availability: Some(v.availability),
                site: None,
                age_ms: None,
                battery_pct,
                dispatchable: capable && reasons.is_empty(),
                reasons,
                notes,
            }
        })
        .collect();
    vehicles.sort_by(|a, b| {
        (!a.dispatchable, !a.capable, &a.vehicle_id).cmp(&(
            !b.dispatchable,
            !b.capable,
            &b.vehicle_id,
        ))
    });
    if let Some(federation) = s.federation() {
        vehicles.extend(leased_elsewhere(&federation));
    }
    Ok(Json(CapableAnswer {
        kind,
        requires,
        vehicles,
    }))
}

#[cfg(test)]
mod tests {
    use shoal_model::VehicleKind;
    use shoal_station::{LeaseView, RemoteVehicleView, SiteView};

    use super::*;

    fn lease(vehicle: &str, home: &str, holder: &str) -> LeaseView {
        LeaseView {
            vehicle_id: vehicle.into(),
            holder: holder.into(),
            home: home.into(),
            standby: String::new(),
            term: 2,
            reason: "handover",
            granted_ms: 0,
            held_here: holder == "shore",
        }
    }

    fn seen(vehicle: &str, site: &str, age_ms: i64) -> RemoteVehicleView {
        RemoteVehicleView {
            site: site.into(),
            vehicle_id: vehicle.into(),
            kind: VehicleKind::Usv,
            timestamp_ms: 0,
            latitude_deg: 63.4,
            longitude_deg: 10.4,
            depth_m: 0.0,
            heading_deg: 0.0,
            speed_mps: 0.0,
            battery_pct: 71.0,
            age_ms,
        }
    }

    fn shore(online: bool) -> FederationSnapshot {
        FederationSnapshot {
            site: "shore".into(),
            sites: vec![SiteView {
                site: "ship".into(),
                online,
                since_ms: 0,
            }],
            vehicles: vec![
                seen("ship-usv-1", "ship", 90_000),
                seen("ship-auv-2", "ship", 3_000),
            ],
            lease_enabled: true,
            leases: vec![
                lease("ship-usv-1", "ship", "shore"),
                lease("ship-auv-2", "ship", "ship"),
                lease("ship-auv-3", "ship", "shore"),
                lease("auv-1", "shore", "shore"),
            ],
            ..FederationSnapshot::default()
        }
    }

    #[test]
    fn another_sites_vehicle_is_offered_only_under_a_lease_held_here_and_while_its_site_is_online()
    {
        let got = leased_elsewhere(&shore(true));
        // Not the one the ship holds, nor this station's own vehicle (in the fleet already).
        let ids: Vec<&str> = got.iter().map(|c| c.vehicle_id.as_str()).collect();
        assert_eq!(ids, ["ship-usv-1", "ship-auv-3"]);
        let usv = &got[0];
        assert!(usv.dispatchable && usv.capable, "{usv:?}");
        assert_eq!(usv.site.as_deref(), Some("ship"));
        assert_eq!((usv.kind.as_str(), usv.battery_pct), ("usv", Some(71.0)));
        assert_eq!(
            (usv.contact, usv.availability, usv.age_ms),
            (None, None, Some(90_000))
        );
        assert!(usv.notes[0].starts_with("at site ship:"), "{:?}", usv.notes);
        assert!(usv.notes[1].contains("90 s old"), "{:?}", usv.notes);
        // Never heard of: listed with why, not offered.
        let unseen = &got[1];
        assert!(!unseen.dispatchable);
        assert_eq!(
            unseen.reasons,
            ["no position of ship-auv-3 from site ship yet"]
        );

        let offline = leased_elsewhere(&shore(false));
        assert!(offline.iter().all(|c| !c.dispatchable));
        assert!(
            offline[0].reasons[0].contains("site ship is offline"),
            "{:?}",
            offline[0]
        );
    }
}
