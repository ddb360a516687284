//! Prints the semantic store benchmark: `cargo run --release -p shoal-semantic --example
//! semantic_bench [vehicles] [updates_per_vehicle] [samples]`.

use shoal_semantic::bench::{self, BenchOptions, MemoryFigures, QueryFigures};

fn print_queries(title: &str, figures: &[QueryFigures]) {
    println!("{title}");
    for f in figures {
        println!(
            "  {:<30} rows {:>5}  p50 {:>9.3} ms  p95 {:>9.3} ms",
            f.name,
            f.rows,
            f.p50.as_secs_f64() * 1e3,
            f.p95.as_secs_f64() * 1e3
        );
    }
}

fn print_memory(title: &str, m: &MemoryFigures) {
    println!(
        "{title}: quads {} garbage {} rss {:?} KiB",
        m.quads, m.garbage_quads, m.rss_kib
    );
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1).map(|a| a.parse::<usize>());
    let d = BenchOptions::default();
    let options = BenchOptions {
        vehicles: args.next().transpose()?.unwrap_or(d.vehicles),
        updates_per_vehicle: args.next().transpose()?.unwrap_or(d.updates_per_vehicle),
        samples: args.next().transpose()?.unwrap_or(d.samples),
    };
    let r = bench::run(options)?;
    println!("{options:?}; populate {:?}", r.populate);
    print_queries("fresh", &r.fresh);
    print_memory("fresh", &r.fresh_memory);
    println!(
        "update_state {:.0}/s, state mirrors {:.0}/s",
        r.update_state_per_s, r.flushes_per_s
    );
    print_queries("after updates, before compaction", &r.after_updates);
    print_memory("after updates", &r.after_updates_memory);
    println!("compaction: {:?}", r.compaction);
    print_queries("after compaction", &r.after_compaction);
    print_memory("after compaction", &r.after_compaction_memory);
    Ok(())
}
