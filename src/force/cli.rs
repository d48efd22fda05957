//! `rig ft …` (being written).

use clap::Args;

/// Arguments of `rig ft`.
#[derive(Debug, Args)]
pub struct FtArgs {}

pub fn run(_args: &FtArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rig ft` is not implemented yet")
}
