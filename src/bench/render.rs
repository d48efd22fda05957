//! `rig bench render` (being written).

use clap::Args;

#[derive(Debug, Args)]
pub struct RenderBenchArgs {}

pub fn run(_args: &RenderBenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rig bench render` is not implemented yet")
}
