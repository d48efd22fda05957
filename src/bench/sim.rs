//! `rig bench sim` (being written).

use clap::Args;

#[derive(Debug, Args)]
pub struct SimBenchArgs {}

pub fn run(_args: &SimBenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rig bench sim` is not implemented yet")
}
