//! Prints the semantic store benchmark.
//!
//! - `semantic_bench [vehicles] [updates_per_vehicle] [samples]`: fresh fleet, after a burst
//!   of state mirrors, and the copy a write makes while a query snapshot is alive.
//! - `semantic_bench hour [vehicles] [seconds] [sample_every_s]`: a simulated hour of
//!   traffic through the normal write path, the standard queries running in turn between
//!   the writes, printing their p50 and the memory every `sample_every_s` simulated
//!   seconds.
//!
//! Run with `cargo run --release -p shoal-semantic --example semantic_bench -- ...`.

use shoal_semantic::StoreConfig;

/// The allocator the `shoal` binary runs the store with.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;
use shoal_semantic::bench::{self, BenchOptions, HourOptions, MemoryFigures, QueryFigures};

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

fn print_queries(title: &str, figures: &[QueryFigures]) {
    println!("{title}");
    for f in figures {
        println!(
            "  {:<30} rows {:>5}  min {:>8.3} ms  p50 {:>8.3} ms  p95 {:>8.3} ms",
            f.name,
            f.rows,
            f.min.as_secs_f64() * 1e3,
            ms(f.p50),
            ms(f.p95)
        );
    }
}

fn print_memory(title: &str, m: &MemoryFigures) {
    println!(
        "{title}: quads {} terms {} rss {} KiB",
        m.quads,
        m.terms,
        m.rss_kib.map_or("?".into(), |r| r.to_string())
    );
}

fn burst(args: &[usize]) -> Result<(), Box<dyn std::error::Error>> {
    let d = BenchOptions::default();
    let options = BenchOptions {
        vehicles: args.first().copied().unwrap_or(d.vehicles),
        updates_per_vehicle: args.get(1).copied().unwrap_or(d.updates_per_vehicle),
        samples: args.get(2).copied().unwrap_or(d.samples),
    };
    let r = bench::run(options)?;
    println!("{options:?}; populate {:?}", r.populate);
    print_queries("fresh", &r.fresh);
    print_memory("fresh", &r.fresh_memory);
    println!(
        "update_state {:.0}/s, state mirrors {:.0}/s",
        r.update_state_per_s, r.flushes_per_s
    );
    print_queries("after updates", &r.after_updates);
    print_memory("after updates", &r.after_updates_memory);
    println!(
        "a write while a query snapshot is alive copies the model once: {:.1} ms",
        ms(r.snapshot_copy)
    );
    Ok(())
}

fn hour(args: &[usize]) -> Result<(), Box<dyn std::error::Error>> {
    let d = HourOptions::default();
    let options = HourOptions {
        vehicles: args.first().copied().unwrap_or(d.vehicles),
        seconds: args.get(1).map_or(d.seconds, |&s| s as u64),
        sample_every_s: args.get(2).map_or(d.sample_every_s, |&s| s as u64),
        ..d
    };
    println!("{options:?}");
    let r = bench::run_hour(options, StoreConfig::default())?;
    print_queries("fresh", &r.fresh);
    print_memory("fresh", &r.fresh_memory);
    let names: Vec<&str> = r.fresh.iter().map(|q| q.name).collect();
    println!(
        "\n{:>6} {:>9} {:>7} {:>8} {:>9} {:>8}  p50 ms: {}",
        "sim_s",
        "mirrors",
        "quads",
        "terms",
        "rss_KiB",
        "write_s",
        names
            .iter()
            .map(|n| n.split('_').next().unwrap_or(n))
            .collect::<Vec<_>>()
            .join("    ")
    );
    for s in &r.series {
        println!(
            "{:>6} {:>9} {:>7} {:>8} {:>9} {:>8.1}  {}",
            s.sim_s,
            s.state_mirrors,
            s.memory.quads,
            s.memory.terms,
            s.memory.rss_kib.map_or("?".into(), |r| r.to_string()),
            s.write_time.as_secs_f64(),
            s.queries
                .iter()
                .map(|q| format!("{:>5.2}", ms(q.p50)))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    println!(
        "\nback to back at each sample ({} runs each), p50 ms:",
        r.options.samples
    );
    for s in &r.series {
        println!(
            "{:>6}  {}",
            s.sim_s,
            s.back_to_back
                .iter()
                .map(|q| format!("{:>6.2}", ms(q.p50)))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    if let Some(last) = r.series.last() {
        print_queries("\nduring the last interval, between writes", &last.queries);
        print_queries("at the end, back to back", &last.back_to_back);
    }
    println!("events raised and added: {}", r.events_raised);
    if let Some(last) = r.series.last() {
        print_memory("at the end", &last.memory);
    }
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let hour_mode = args.first().is_some_and(|a| a == "hour");
    if hour_mode {
        args.remove(0);
    }
    let numbers = args
        .iter()
        .map(|a| a.parse::<usize>())
        .collect::<Result<Vec<_>, _>>()?;
    if hour_mode {
        hour(&numbers)
    } else {
        burst(&numbers)
    }
}
