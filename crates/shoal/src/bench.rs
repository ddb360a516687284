//! `shoal bench`: programs that print figures.

use anyhow::Result;
use clap::Subcommand;

use crate::config::ShoalConfig;

/// Which benchmark to run.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Placeholder until the bus benchmark lands.
    Bus,
}

/// Runs one benchmark.
pub async fn run(which: BenchCommand, _cfg: &ShoalConfig) -> Result<()> {
    match which {
        BenchCommand::Bus => anyhow::bail!("not yet"),
    }
}
