//! The report page: one self-contained HTML file (inline CSS and SVG, no script, nothing
//! fetched), so it opens offline and can be mailed or archived as it is.

use std::fmt::Write as _;

use shoal_model::geo::LocalFrame;
use shoal_model::{GeoPoint, Severity, TaskState};

use super::{RunRecord, Summary, state_name};

/// Colours for vehicles, in fleet order (repeating beyond eight).
const PALETTE: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2",
];
/// Most points drawn per vehicle and plot: more only makes the file larger.
const MAX_POINTS: usize = 1500;
const WIDTH: f64 = 760.0;
const HEIGHT: f64 = 260.0;
const MARGIN: f64 = 48.0;

fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

fn colour(i: usize) -> &'static str {
    PALETTE[i % PALETTE.len()]
}

/// Every n-th item so that at most `MAX_POINTS` remain (the last always kept).
fn thin<T>(items: &[T]) -> impl Iterator<Item = &T> {
    let step = items.len().div_ceil(MAX_POINTS).max(1);
    items
        .iter()
        .enumerate()
        .filter(move |(i, _)| i % step == 0 || *i + 1 == items.len())
        .map(|(_, x)| x)
}

/// A round tick step giving about `n` ticks over `span`.
fn tick_step(span: f64, n: f64) -> f64 {
    if !(span.is_finite() && span > 0.0) {
        return 1.0;
    }
    let raw = span / n;
    let mag = 10f64.powf(raw.log10().floor());
    let norm = raw / mag;
    let nice = if norm < 1.5 {
        1.0
    } else if norm < 3.5 {
        2.0
    } else if norm < 7.5 {
        5.0
    } else {
        10.0
    };
    nice * mag
}

/// A tick step for a time axis of `span` seconds, about `n` ticks: whole minutes and hours
/// rather than 200 s.
fn time_step(span: f64, n: f64) -> f64 {
    const STEPS: [f64; 15] = [
        1.0, 2.0, 5.0, 10.0, 15.0, 30.0, 60.0, 120.0, 300.0, 600.0, 900.0, 1800.0, 3600.0, 7200.0,
        21_600.0,
    ];
    let raw = span / n;
    STEPS
        .iter()
        .copied()
        .find(|s| *s >= raw)
        .unwrap_or_else(|| (raw / 86_400.0).ceil() * 86_400.0)
}

#[cfg(test)]
pub(super) fn time_step_for_tests(span: f64) -> f64 {
    time_step(span, 6.0)
}

#[cfg(test)]
pub(super) fn tick_step_for_tests(span: f64) -> f64 {
    tick_step(span, 6.0)
}

fn fmt_time(s: f64) -> String {
    let s = s.max(0.0);
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let whole = s.round() as u64;
    if whole >= 3600 {
        format!("{}:{:02}:{:02}", whole / 3600, whole / 60 % 60, whole % 60)
    } else {
        format!("{}:{:02}", whole / 60, whole % 60)
    }
}

/// One plotted line: its label, colour and (simulated seconds, value) points.
struct Series<'a> {
    name: &'a str,
    colour: &'static str,
    points: Vec<(f64, f64)>,
}

/// A line chart over simulated time; `down` draws values growing downwards (depth).
fn line_chart(
    out: &mut String,
    title: &str,
    unit: &str,
    span_s: f64,
    series: &[Series<'_>],
    down: bool,
) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for p in series.iter().flat_map(|s| &s.points) {
        lo = lo.min(p.1);
        hi = hi.max(p.1);
    }
    if !lo.is_finite() {
        let _ = write!(out, "<h3>{}</h3><p class=\"none\">No data.</p>", esc(title));
        return;
    }
    if hi - lo < 1e-9 {
        hi = lo + 1.0;
    }
    let span_s = span_s.max(1.0);
    let (pw, ph) = (WIDTH - 2.0 * MARGIN, HEIGHT - 2.0 * MARGIN);
    let x = |t: f64| MARGIN + (t / span_s).clamp(0.0, 1.0) * pw;
    let y = |v: f64| {
        let f = (v - lo) / (hi - lo);
        if down {
            MARGIN + f * ph
        } else {
            MARGIN + (1.0 - f) * ph
        }
    };
    let _ = write!(
        out,
        "<h3>{}</h3><svg class=\"plot\" viewBox=\"0 0 {WIDTH} {HEIGHT}\" role=\"img\" aria-label=\"{}\">",
        esc(title),
        esc(title)
    );
    let _ = write!(
        out,
        "<rect x=\"{MARGIN}\" y=\"{MARGIN}\" width=\"{pw}\" height=\"{ph}\" class=\"frame\"/>"
    );
    let ystep = tick_step(hi - lo, 4.0);
    let mut v = (lo / ystep).ceil() * ystep;
    while v <= hi + 1e-9 {
        let _ = write!(
            out,
            "<line x1=\"{MARGIN}\" x2=\"{:.1}\" y1=\"{y:.1}\" y2=\"{y:.1}\" class=\"grid\"/><text x=\"{:.1}\" y=\"{:.1}\" class=\"tick\" text-anchor=\"end\">{}</text>",
            MARGIN + pw,
            MARGIN - 4.0,
            y(v) + 4.0,
            trim(v),
            y = y(v),
        );
        v += ystep;
    }
    let xstep = time_step(span_s, 6.0);
    let mut t = 0.0;
    while t <= span_s + 1e-9 {
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{:.1}\" class=\"tick\" text-anchor=\"middle\">{}</text>",
            x(t),
            HEIGHT - MARGIN + 16.0,
            fmt_time(t)
        );
        t += xstep;
    }
    let _ = write!(
        out,
        "<text x=\"12\" y=\"{:.1}\" class=\"tick\" transform=\"rotate(-90 12 {:.1})\" text-anchor=\"middle\">{}</text>",
        HEIGHT / 2.0,
        HEIGHT / 2.0,
        esc(unit)
    );
    for s in series.iter().filter(|s| !s.points.is_empty()) {
        let pts: Vec<&(f64, f64)> = s.points.iter().collect();
        let mut d = String::new();
        for p in thin(&pts) {
            let _ = write!(d, "{:.1},{:.1} ", x(p.0), y(p.1));
        }
        let _ = write!(
            out,
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{}\" stroke-width=\"1.6\"><title>{}</title></polyline>",
            d.trim_end(),
            s.colour,
            esc(s.name)
        );
    }
    out.push_str("</svg>");
    legend(
        out,
        series
            .iter()
            .filter(|s| !s.points.is_empty())
            .map(|s| (s.name, s.colour)),
    );
}

fn trim(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_owned()
}

fn legend<'a>(out: &mut String, items: impl Iterator<Item = (&'a str, &'static str)>) {
    out.push_str("<p class=\"legend\">");
    for (name, c) in items {
        let _ = write!(
            out,
            "<span><i style=\"background:{c}\"></i>{}</span>",
            esc(name)
        );
    }
    out.push_str("</p>");
}

/// Every vehicle's track on a local metric plane, north up, with a scale bar.
fn track_map(out: &mut String, r: &RunRecord) {
    let Some(origin) = r.vehicles.iter().find_map(|v| v.track.first()) else {
        out.push_str("<h3>Tracks</h3><p class=\"none\">No positions were stored.</p>");
        return;
    };
    let frame = LocalFrame::new(GeoPoint {
        latitude_deg: origin.latitude_deg,
        longitude_deg: origin.longitude_deg,
    });
    let xy: Vec<Vec<(f64, f64)>> = r
        .vehicles
        .iter()
        .map(|v| {
            v.track
                .iter()
                .map(|s| {
                    frame.to_xy(GeoPoint {
                        latitude_deg: s.latitude_deg,
                        longitude_deg: s.longitude_deg,
                    })
                })
                .collect()
        })
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in xy.iter().flatten() {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    // At least 100 m across, and a margin, so a fleet sitting still is still a picture.
    let span = (x1 - x0).max(y1 - y0).max(100.0) * 1.1;
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let size = 520.0;
    let px = |x: f64| (x - cx) / span * size + size / 2.0;
    let py = |y: f64| size / 2.0 - (y - cy) / span * size;
    let _ = write!(
        out,
        "<h3>Tracks</h3><svg class=\"map\" viewBox=\"0 0 {size} {size}\" role=\"img\" aria-label=\"Tracks\"><rect width=\"{size}\" height=\"{size}\" class=\"sea\"/>"
    );
    for (i, (v, pts)) in r.vehicles.iter().zip(&xy).enumerate() {
        if pts.is_empty() {
            continue;
        }
        let mut d = String::new();
        for p in thin(pts) {
            let _ = write!(d, "{:.1},{:.1} ", px(p.0), py(p.1));
        }
        let c = colour(i);
        let (s, e) = (pts[0], pts[pts.len() - 1]);
        let _ = write!(
            out,
            "<polyline points=\"{}\" fill=\"none\" stroke=\"{c}\" stroke-width=\"1.8\"><title>{}</title></polyline><circle cx=\"{:.1}\" cy=\"{:.1}\" r=\"4\" fill=\"{c}\"/><rect x=\"{:.1}\" y=\"{:.1}\" width=\"7\" height=\"7\" fill=\"none\" stroke=\"{c}\" stroke-width=\"2\"/><text x=\"{:.1}\" y=\"{:.1}\" class=\"label\">{}</text>",
            d.trim_end(),
            esc(&v.id),
            px(s.0),
            py(s.1),
            px(e.0) - 3.5,
            py(e.1) - 3.5,
            px(s.0) + 6.0,
            py(s.1) - 6.0,
            esc(&v.id),
        );
    }
    let bar = tick_step(span / 4.0, 1.0);
    let bar_px = bar / span * size;
    let _ = write!(
        out,
        "<line x1=\"16\" x2=\"{:.1}\" y1=\"{:.1}\" y2=\"{:.1}\" class=\"scale\"/><text x=\"16\" y=\"{:.1}\" class=\"tick\">{} m</text><text x=\"{:.1}\" y=\"20\" class=\"tick\" text-anchor=\"end\">N ↑</text></svg>",
        16.0 + bar_px,
        size - 16.0,
        size - 16.0,
        size - 22.0,
        trim(bar),
        size - 10.0,
    );
    out.push_str("<p class=\"note\">Dot: start. Square: end. North up; distances from a local plane at the first position.</p>");
}

fn state_colour(s: TaskState) -> &'static str {
    match s {
        TaskState::Done => "#2ca02c",
        TaskState::Failed | TaskState::Expired => "#d62728",
        TaskState::Aborted => "#ff7f0e",
        _ => "#1f77b4",
    }
}

/// One row per vehicle, one bar per task from its start to its end (or the run's end).
fn task_timeline(out: &mut String, r: &RunRecord) {
    out.push_str("<h3>Task timeline</h3>");
    if r.tasks.is_empty() {
        out.push_str("<p class=\"none\">No task was issued.</p>");
        return;
    }
    #[allow(clippy::cast_precision_loss)]
    let span = ((r.end_ms - r.start_ms) as f64 / 1000.0).max(1.0);
    let row = 28.0;
    let label_w = 90.0;
    #[allow(clippy::cast_precision_loss)]
    let h = r.vehicles.len() as f64 * row + 40.0;
    let pw = WIDTH - label_w - 16.0;
    #[allow(clippy::cast_precision_loss)]
    let x = |ms: i64| label_w + (((ms - r.start_ms) as f64 / 1000.0) / span).clamp(0.0, 1.0) * pw;
    let _ = write!(
        out,
        "<svg class=\"plot\" viewBox=\"0 0 {WIDTH} {h}\" role=\"img\" aria-label=\"Task timeline\">"
    );
    for (i, v) in r.vehicles.iter().enumerate() {
        #[allow(clippy::cast_precision_loss)]
        let top = i as f64 * row + 8.0;
        let _ = write!(
            out,
            "<text x=\"4\" y=\"{:.1}\" class=\"label\">{}</text><line x1=\"{label_w}\" x2=\"{:.1}\" y1=\"{:.1}\" y2=\"{:.1}\" class=\"grid\"/>",
            top + 15.0,
            esc(&v.id),
            label_w + pw,
            top + row - 2.0,
            top + row - 2.0,
        );
        for t in r.tasks.iter().filter(|t| t.assignment.vehicle_id == v.id) {
            let Some(start) = t
                .started_ms()
                .or_else(|| t.statuses.first().map(|s| s.timestamp_ms))
            else {
                continue;
            };
            let end = t.ended_ms().unwrap_or(r.end_ms);
            let state = t.last_state();
            let (a, b) = (x(start), x(end).max(x(start) + 2.0));
            let _ = write!(
                out,
                "<rect x=\"{a:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"18\" rx=\"3\" fill=\"{}\"><title>{} ({}): {} {}–{}</title></rect>",
                top + 3.0,
                b - a,
                state_colour(state),
                esc(&t.assignment.task_id),
                t.assignment.kind.capability(),
                state_name(state),
                fmt_time(((start - r.start_ms) as f64) / 1000.0),
                fmt_time(((end - r.start_ms) as f64) / 1000.0),
            );
            if b - a > 40.0 {
                let _ = write!(
                    out,
                    "<text x=\"{:.1}\" y=\"{:.1}\" class=\"bar\">{}</text>",
                    a + 4.0,
                    top + 16.0,
                    t.assignment.kind.capability()
                );
            }
        }
    }
    #[allow(clippy::cast_precision_loss)]
    let bottom = r.vehicles.len() as f64 * row + 8.0;
    for f in &r.faults {
        let fx = label_w + (f.at_s / span).clamp(0.0, 1.0) * pw;
        let _ = write!(
            out,
            "<line x1=\"{fx:.1}\" x2=\"{fx:.1}\" y1=\"4\" y2=\"{bottom:.1}\" class=\"fault\"><title>{}: {}</title></line>",
            fmt_time(f.at_s),
            esc(&f.what)
        );
    }
    let step = time_step(span, 6.0);
    let mut t = 0.0;
    #[allow(clippy::cast_precision_loss)]
    let axis = r.vehicles.len() as f64 * row + 28.0;
    while t <= span + 1e-9 {
        let _ = write!(
            out,
            "<text x=\"{:.1}\" y=\"{axis:.1}\" class=\"tick\" text-anchor=\"middle\">{}</text>",
            label_w + t / span * pw,
            fmt_time(t)
        );
        t += step;
    }
    out.push_str("</svg>");
    legend(
        out,
        [
            ("done", state_colour(TaskState::Done)),
            ("failed or expired", state_colour(TaskState::Failed)),
            ("aborted", state_colour(TaskState::Aborted)),
            ("under way at the end", state_colour(TaskState::Running)),
            ("fault (dashed line)", "#b00020"),
        ]
        .into_iter(),
    );
}

const STYLE: &str = "body{font:14px/1.45 system-ui,sans-serif;margin:24px auto;max-width:820px;color:#1b2733}\
h1{font-size:22px;margin-bottom:4px}h2{font-size:17px;margin-top:28px;border-bottom:1px solid #ccd}\
h3{font-size:15px;margin:18px 0 6px}table{border-collapse:collapse;width:100%;font-size:13px}\
td,th{border-bottom:1px solid #e3e6ea;padding:3px 6px;text-align:left}th{background:#f2f4f7}\
td.n{text-align:right;font-variant-numeric:tabular-nums}.plot,.map{width:100%;height:auto;background:#fff}\
.map{max-width:520px}.sea{fill:#eef5fb}.frame{fill:none;stroke:#99a}.grid{stroke:#e3e6ea}\
.tick{font-size:11px;fill:#556}.label{font-size:12px;fill:#1b2733}.bar{font-size:11px;fill:#fff}\
.scale{stroke:#1b2733;stroke-width:2}.legend span{margin-right:14px;font-size:12px}\
.legend i{display:inline-block;width:10px;height:10px;margin-right:4px;border-radius:2px}\
.note,.none{color:#556;font-size:12px}.alarm{color:#b00020}\
.fault{stroke:#b00020;stroke-width:1.5;stroke-dasharray:4 3}";

/// What each acoustic link carried and lost, and why.
fn acoustic_table(out: &mut String, r: &RunRecord, s: &Summary) {
    if r.links.is_empty() && s.acoustic_channel_use_pct.is_none() {
        return;
    }
    out.push_str("<h2>Acoustic network</h2><table><tr><th>Link</th><th>Frames</th><th>Delivered</th><th>Lost (channel)</th><th>Collisions</th><th>Half duplex</th><th>Outage</th></tr>");
    for l in &r.links {
        let pct = l
            .delivery_pct()
            .map_or_else(String::new, |p| format!(" ({p} %)"));
        let _ = write!(
            out,
            "<tr><td>{} → {}</td><td class=\"n\">{}</td><td class=\"n\">{}{pct}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
            esc(&l.from),
            esc(&l.to),
            l.frames,
            l.delivered,
            l.lost,
            l.collisions,
            l.half_duplex,
            l.outage
        );
    }
    out.push_str("</table><p class=\"note\">Counted by the emulated sea, per frame addressed over each link.</p>");
    if let Some(pct) = s.acoustic_channel_use_pct {
        let _ = write!(
            out,
            "<p>The channel carried a transmission {pct} % of the run: {}.</p>",
            s.acoustic_airtime_s
                .iter()
                .map(|(m, a)| format!("{} {a} s", esc(m)))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if !s.acoustic_latency.is_empty() {
        out.push_str("<h3>State vector age on reaching the station</h3><table><tr><th>Vehicle</th><th>State vectors</th><th>Median</th><th>95th percentile</th><th>Largest</th></tr>");
        for (v, l) in &s.acoustic_latency {
            let _ = write!(
                out,
                "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{} s</td><td class=\"n\">{} s</td><td class=\"n\">{} s</td></tr>",
                esc(v),
                l.samples,
                l.p50_s,
                l.p95_s,
                l.max_s
            );
        }
        out.push_str("</table><p class=\"note\">From the vehicle's timestamp to the relayed sample's arrival on the station's domain, in simulated time: the VDT's queue (the freshest state goes, one every few seconds), time on air, propagation and retransmissions.</p>");
    }
    #[allow(clippy::cast_precision_loss)]
    let at = |ms: i64| (ms - r.start_ms) as f64 / 1000.0;
    let series: Vec<Series<'_>> = r
        .link_quality
        .iter()
        .enumerate()
        .map(|(i, (v, samples))| Series {
            name: v,
            colour: colour(i),
            points: samples
                .iter()
                .filter_map(|p| Some((at(p.at_ms), f64::from(p.rssi_db?))))
                .collect(),
        })
        .collect();
    if series.iter().any(|s| !s.points.is_empty()) {
        line_chart(
            out,
            "Acoustic link quality (RSSI at the relay)",
            "dB",
            s.simulated_s,
            &series,
            false,
        );
    }
}

/// Which rules fired, how often, first when and about which vehicles.
fn rule_table(out: &mut String, s: &Summary) {
    out.push_str("<h2>Rule firings</h2>");
    if s.rule_firings.is_empty() {
        out.push_str("<p>No rule fired.</p>");
        return;
    }
    out.push_str("<table><tr><th>Rule</th><th>Firings</th><th>First at</th><th>Vehicles</th></tr>");
    for (rule, f) in &s.rule_firings {
        let _ = write!(
            out,
            "<tr><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
            esc(rule),
            f.count,
            fmt_time(f.first_s),
            esc(&f.vehicles.join(", "))
        );
    }
    out.push_str("</table>");
}

/// What the fleet measured of the environment: per property, the range and where its
/// extremes were (a plume shows as an extreme away from the rest).
fn environment_table(out: &mut String, s: &Summary) {
    if s.environment.is_empty() {
        return;
    }
    out.push_str("<h2>Environment</h2><table><tr><th>Property</th><th>Unit</th><th>Observations</th><th>Vehicles</th><th>Min (where)</th><th>Mean</th><th>Max (where)</th></tr>");
    let place = |p: &[f64; 3]| format!("{:.5}, {:.5}, {:.1} m", p[0], p[1], p[2]);
    for (property, e) in &s.environment {
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td>{}</td><td class=\"n\">{} ({})</td><td class=\"n\">{}</td><td class=\"n\">{} ({})</td></tr>",
            esc(property),
            esc(&e.unit),
            e.observations,
            esc(&e.vehicles.join(", ")),
            trim(e.min),
            place(&e.min_at),
            trim(e.mean),
            trim(e.max),
            place(&e.max_at),
        );
    }
    out.push_str("</table>");
}

/// The report page of a run.
pub fn render_html(r: &RunRecord, s: &Summary) -> String {
    let mut out = String::with_capacity(64 * 1024);
    let _ = write!(
        out,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>Shoal scenario report: {}</title><style>{STYLE}</style></head><body>",
        esc(&r.scenario)
    );
    let _ = write!(
        out,
        "<h1>Scenario “{}”</h1><p>{}</p><p class=\"note\">Simulated {} at {}× in {:.1} s of real time, seed {}. Times are simulated, from the start of the run.</p>",
        esc(&r.scenario),
        esc(&r.description),
        fmt_time(s.simulated_s),
        trim(r.speed),
        r.wall_s,
        r.seed
    );
    out.push_str("<h2>Vehicles</h2><table><tr><th>Vehicle</th><th>Kind</th><th>States</th><th>Distance, m</th><th>Deepest, m</th><th>Battery start → end (min), %</th><th>First motion</th></tr>");
    for (id, v) in &s.vehicles {
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{} → {} ({})</td><td class=\"n\">{}</td></tr>",
            esc(id),
            esc(&v.kind),
            v.states,
            trim(v.distance_m),
            trim(v.max_depth_m),
            trim(v.battery_start_pct),
            trim(v.battery_end_pct),
            trim(v.battery_min_pct),
            v.first_motion_s
                .map_or_else(|| "never".to_owned(), fmt_time),
        );
    }
    out.push_str("</table>");
    track_map(&mut out, r);
    #[allow(clippy::cast_precision_loss)]
    let at = |ms: i64| (ms - r.start_ms) as f64 / 1000.0;
    let series = |value: fn(&shoal_model::StateVector) -> f64| -> Vec<Series<'_>> {
        r.vehicles
            .iter()
            .enumerate()
            .map(|(i, v)| Series {
                name: &v.id,
                colour: colour(i),
                points: v
                    .track
                    .iter()
                    .map(|p| (at(p.timestamp_ms), value(p)))
                    .collect(),
            })
            .collect()
    };
    line_chart(
        &mut out,
        "Depth",
        "m",
        s.simulated_s,
        &series(|p| p.depth_m),
        true,
    );
    line_chart(
        &mut out,
        "Battery",
        "%",
        s.simulated_s,
        &series(|p| p.battery_pct),
        false,
    );
    line_chart(
        &mut out,
        "Speed",
        "m/s",
        s.simulated_s,
        &series(|p| p.speed_mps),
        false,
    );
    out.push_str("<h2>Tasks</h2>");
    task_timeline(&mut out, r);
    out.push_str("<table><tr><th>Task</th><th>Vehicle</th><th>Kind</th><th>State</th><th>Started</th><th>Took</th></tr>");
    for t in &r.tasks {
        let id = &t.assignment.task_id;
        let took = s
            .task_outcomes
            .get(&super::task_key(&t.assignment))
            .and_then(|o| o.duration_s);
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
            esc(id),
            esc(&t.assignment.vehicle_id),
            t.assignment.kind.capability(),
            state_name(t.last_state()),
            t.started_ms()
                .map_or_else(|| "–".to_owned(), |ms| fmt_time(at(ms))),
            took.map_or_else(|| "–".to_owned(), fmt_time),
        );
    }
    out.push_str("</table>");
    if !r.faults.is_empty() {
        out.push_str("<h2>Faults injected</h2><table><tr><th>At</th><th>What</th></tr>");
        for f in &r.faults {
            let _ = write!(
                out,
                "<tr><td class=\"n\">{}</td><td>{}</td></tr>",
                fmt_time(f.at_s),
                esc(&f.what)
            );
        }
        out.push_str("</table>");
    }
    acoustic_table(&mut out, r, s);
    environment_table(&mut out, s);
    rule_table(&mut out, s);
    out.push_str("<h2>Events</h2>");
    let notable: Vec<_> = r
        .events
        .iter()
        .filter(|e| e.severity != Severity::Info)
        .collect();
    let _ = write!(
        out,
        "<p>{} events: {}.</p>",
        r.events.len(),
        s.events
            .iter()
            .map(|(k, n)| format!("{n} {k}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    if !notable.is_empty() {
        out.push_str("<table><tr><th>At</th><th>Severity</th><th>Vehicle</th><th>What</th></tr>");
        for e in notable.iter().take(500) {
            let cls = if matches!(e.severity, Severity::Alarm | Severity::Critical) {
                " class=\"alarm\""
            } else {
                ""
            };
            let _ = write!(
                out,
                "<tr{cls}><td class=\"n\">{}</td><td>{:?}</td><td>{}</td><td>{}</td></tr>",
                fmt_time(at(e.timestamp_ms)),
                e.severity,
                esc(&e.vehicle_id),
                esc(&e.text)
            );
        }
        out.push_str("</table>");
    }
    let _ = write!(
        out,
        "<h2>Station</h2><p>{} state vectors accepted, {} samples refused, {} rule firings, {} records committed to the history store.</p>",
        s.station.states_accepted,
        s.station.rejected,
        s.station.rule_firings,
        s.station.history_committed
    );
    out.push_str("<p class=\"note\">The run's data is in <code>history.sqlite</code> and <code>recording/</code> beside this page.</p></body></html>");
    out
}
