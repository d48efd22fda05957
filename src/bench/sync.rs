//! `rig bench sync` (being written).

use clap::Args;

#[derive(Debug, Args)]
pub struct SyncBenchArgs {}

pub fn run(_args: &SyncBenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rig bench sync` is not implemented yet")
}
