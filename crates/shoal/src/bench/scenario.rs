//! `shoal bench scenario`: a scenario run headless at a speed-up (by default the shipped
//! `harbour-survey`, one simulated hour at 60×, four vehicles and eight tasks), timed from
//! start to the report written, against the target of two minutes.

use std::time::Instant;

use anyhow::{Context, Result};
use tokio_util::sync::CancellationToken;

use crate::config::ShoalConfig;
use crate::scenario::run::{RunArgs, run};

/// The target: a one-hour scenario at 60× with its report, seconds.
const TARGET_S: f64 = 120.0;

/// Runs `scenario` for `duration_s` at `speed` into a temporary directory and prints the
/// figures.
pub(super) async fn scenario(
    cfg: &ShoalConfig,
    scenario: &str,
    speed: f64,
    duration_s: f64,
    domain: u16,
) -> Result<()> {
    // A fresh directory of its own, removed at the end (the run refuses one not empty).
    let out = std::env::temp_dir().join(format!(
        "shoal-bench-scenario-{}-{}",
        std::process::id(),
        shoal_model::now_ms()
    ));
    let args = RunArgs::new(scenario, speed, duration_s, &out, domain);
    eprintln!("scenario: {scenario}, {duration_s} simulated s at {speed}x...");
    let started = Instant::now();
    run(cfg, &args, CancellationToken::new()).await?;
    let total_s = started.elapsed().as_secs_f64();
    let text = std::fs::read_to_string(out.join("summary.json")).context("no summary.json");
    let _ = std::fs::remove_dir_all(&out);
    let summary: serde_json::Value =
        serde_json::from_str(&text?).context("summary.json is not JSON")?;
    let states: u64 = summary["vehicles"].as_object().map_or(0, |vs| {
        vs.values().filter_map(|v| v["states"].as_u64()).sum()
    });
    let tasks = &summary["tasks"];
    println!("| figure | value |");
    println!("| --- | --- |");
    println!("| scenario | {scenario} |");
    println!("| simulated | {} s at {speed}x |", summary["simulated_s"]);
    println!("| run (station and fleet) | {} s |", summary["wall_s"]);
    println!(
        "| start to report written | {total_s:.1} s (target for one hour at 60x: <= {TARGET_S} s: {}) |",
        if total_s <= TARGET_S {
            "met"
        } else {
            "NOT met"
        }
    );
    println!("| state vectors stored | {states} |");
    println!(
        "| tasks | {} in all, {} done |",
        tasks["total"].as_u64().unwrap_or(0),
        tasks["done"].as_u64().unwrap_or(0)
    );
    println!(
        "| samples refused | {} |",
        summary["station"]["rejected"].as_u64().unwrap_or(0)
    );
    Ok(())
}
