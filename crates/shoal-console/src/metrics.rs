//! `GET /metrics`: the health figures, the ingest counters and the HTTP limits hit, in
//! the Prometheus text format (0.0.4) written by `prometheus-client`. With logins on it
//! needs the viewer role, like every other read: a scraper sends a viewer API token
//! (`authorization: credentials_file` in Prometheus's scrape configuration).
//!
//! The figures live in the station and the console already; each scrape copies them into
//! a fresh registry, so nothing is counted twice and no metric can drift from
//! `/api/stats`.

use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use prometheus_client::encoding::prometheus_text;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::Registry;

use crate::{ApiError, AppState};

type Labels = Vec<(&'static str, String)>;

/// A registry being filled, with shorthands for the metric shapes used here.
struct Scrape(Registry);

impl Scrape {
    fn counter(&mut self, name: &str, help: &str, value: u64) {
        let c: Counter = Counter::default();
        c.inc_by(value);
        self.0.register(name, help, c);
    }

    fn gauge(&mut self, name: &str, help: &str, value: i64) {
        let g: Gauge = Gauge::default();
        g.set(value);
        self.0.register(name, help, g);
    }

    fn gauge_f64(&mut self, name: &str, help: &str, value: f64) {
        let g: Gauge<f64, std::sync::atomic::AtomicU64> = Gauge::default();
        g.set(value);
        self.0.register(name, help, g);
    }

    fn counters<'a>(
        &mut self,
        name: &str,
        help: &str,
        label: &'static str,
        values: impl IntoIterator<Item = (&'a str, u64)>,
    ) {
        let family = Family::<Labels, Counter>::default();
        for (value, n) in values {
            family
                .get_or_create(&vec![(label, value.to_owned())])
                .inc_by(n);
        }
        self.0.register(name, help, family);
    }
}

fn flag(b: bool) -> i64 {
    i64::from(b)
}

fn signed(n: u64) -> i64 {
    i64::try_from(n).unwrap_or(i64::MAX)
}

pub(crate) async fn metrics(State(app): State<AppState>) -> Result<Response, ApiError> {
    let (h, verdict) = crate::health::measure(&app).await?;
    let stats = app.station.stats();
    let mut m = Scrape(Registry::default());

    m.gauge(
        "shoal_health_degraded",
        "1 when /api/health answers 503 (degraded)",
        flag(!verdict.is_ok()),
    );
    m.gauge(
        "shoal_vehicles",
        "Vehicles the station knows",
        signed(app.station.fleet().len() as u64),
    );
    m.gauge(
        "shoal_dds_participant_up",
        "1 while the station's DDS participant is up",
        flag(h.dds.participant_up),
    );
    m.gauge(
        "shoal_dds_task_readers",
        "Remote readers of tasks matched now",
        i64::from(h.dds.task_readers),
    );
    m.gauge(
        "shoal_history_writer_running",
        "1 while the history writer thread runs",
        flag(h.history.writer_running),
    );
    m.counter(
        "shoal_history_submitted",
        "Records handed to the history writer",
        h.history.submitted,
    );
    m.counter(
        "shoal_history_committed",
        "Records committed to the history",
        h.history.committed,
    );
    m.gauge(
        "shoal_history_lag_records",
        "Records submitted to the history but not yet committed",
        signed(h.history.lag),
    );
    m.counter(
        "shoal_history_retries",
        "Failed history commit attempts (each retried)",
        h.history.retries,
    );
    m.gauge_f64(
        "shoal_history_seconds_since_commit",
        "Seconds since the history last committed (or since the console started)",
        h.history.since_last_commit_ms.unwrap_or(0) as f64 / 1000.0,
    );
    m.gauge_f64(
        "shoal_semantic_lock_wait_seconds",
        "How long a probe waited for the semantic store's lock (at most the health threshold)",
        h.semantic.lock_wait_ms as f64 / 1000.0,
    );
    m.gauge(
        "shoal_rules_disabled",
        "Rules disabled, built-in ones included (-1: unknown, the semantic lock was held)",
        h.semantic
            .disabled_rules
            .map_or(-1, |r| signed(r.len() as u64)),
    );
    m.gauge_f64(
        "shoal_clock_skew_seconds",
        "System clock minus station time",
        h.clock_skew_ms as f64 / 1000.0,
    );

    m.counters(
        "shoal_ingest_accepted",
        "Data accepted from vehicles, by kind",
        "kind",
        [
            ("state", stats.states_accepted),
            ("announcement", stats.announcements),
            ("task_status", stats.task_status),
            ("event", stats.events),
            ("observation", stats.observations),
        ],
    );
    m.counters(
        "shoal_ingest_rejected",
        "Data rejected, by reason code",
        "reason",
        stats.rejected.iter().map(|(r, n)| (r.as_str(), *n)),
    );
    m.counters(
        "shoal_ingest_malformed",
        "Samples that could not be decoded, by topic",
        "topic",
        stats.malformed.iter().map(|(t, n)| (t.as_str(), *n)),
    );
    m.counter(
        "shoal_tasks_dispatched",
        "Tasks the station dispatched",
        stats.tasks_dispatched,
    );
    m.counter(
        "shoal_tasks_retired",
        "Ended tasks retired from the bus",
        stats.tasks_retired,
    );
    m.counter(
        "shoal_tasks_not_retired",
        "Ended tasks the bus would not retire",
        stats.tasks_not_retired,
    );
    m.counter(
        "shoal_rule_firings",
        "Events raised by rules as data arrived",
        stats.rule_firings,
    );
    m.counter(
        "shoal_rules_over_budget",
        "User rules disabled because an evaluation ran over its time budget",
        stats.rules_over_budget,
    );
    m.counter(
        "shoal_states_held_for_announcement",
        "State vectors that arrived before their vehicle's announcement and waited for it",
        stats.states_held_for_announcement,
    );
    m.counter(
        "shoal_rejections_not_logged",
        "Rejected data counted but not logged (beyond the log budget)",
        stats.rejections_not_logged,
    );

    m.counters(
        "shoal_http_limit_hits",
        "Times each HTTP limit of [console.limits] was hit",
        "limit",
        app.limits.hits().labelled(),
    );
    m.counters(
        "shoal_http_refused",
        "Requests refused by the console's gate: Host, Origin, CSRF token, login limits",
        "reason",
        app.gate.refusals().labelled(),
    );
    let in_use = app.limits.in_use();
    m.gauge(
        "shoal_http_connections",
        "Open HTTP connections",
        signed(in_use.connections as u64),
    );
    m.gauge(
        "shoal_http_ws_clients",
        "Live feed clients",
        signed(in_use.ws_clients as u64),
    );
    m.gauge(
        "shoal_http_sparql_running",
        "SPARQL queries running",
        signed(in_use.sparql_running as u64),
    );
    m.gauge(
        "shoal_http_sparql_queued",
        "SPARQL queries waiting for a turn",
        signed(in_use.sparql_queued as u64),
    );

    let mut text = String::new();
    prometheus_text::encode(&mut text, &m.0).map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok((
        [(header::CONTENT_TYPE, prometheus_text::CONTENT_TYPE)],
        text,
    )
        .into_response())
}
