//! `rig dataset …` (being written).

use clap::Args;

/// Arguments of `rig dataset`.
#[derive(Debug, Args)]
pub struct DatasetArgs {}

pub fn run(_args: &DatasetArgs) -> anyhow::Result<()> {
    anyhow::bail!("`rig dataset` is not implemented yet")
}
