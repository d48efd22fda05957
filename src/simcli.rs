//! `rig sim …` (being written).

use clap::Args;

/// Arguments of `rig sim`.
#[derive(Debug, Args)]
pub struct SimArgs {}

pub fn run(_args: &SimArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rig sim` is not implemented yet")
}
