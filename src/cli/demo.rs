//! `rig demo [--quick]`: the whole TransForce story on the simulated rig ([`crate::train::demo`]).

use std::path::PathBuf;

use clap::Args;

use crate::train::demo;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// A small version (what CI runs; about 10 minutes on 2 cores): fewer
    /// indenters and trajectories, smaller images and networks, R+M only.
    #[arg(long)]
    pub quick: bool,
    /// Where the data, models and results go.
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Inception weights for FID/KID (default: $RIG_INCEPTION_WEIGHTS, else
    /// ~/.cache/rig/inception-fid.safetensors, written by scripts/fetch-inception).
    #[arg(long, value_name = "FILE")]
    pub inception: Option<PathBuf>,
}

pub fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let table = demo::run(args.quick, &args.out, args.inception.as_deref())?;
    println!("{}", table.markdown());
    for (modality, group, wins) in demo::beats_source_only(&table.rows) {
        let axes: Vec<&str> = ["Fx", "Fy", "Fz"]
            .iter()
            .zip(wins)
            .map(|(a, w)| if w { *a } else { "-" })
            .collect();
        println!(
            "TransForce beats source-only ({modality}, {group}): {} [{}]",
            if wins.iter().all(|w| *w) {
                "yes, on every axis"
            } else {
                "NOT on every axis"
            },
            axes.join(" ")
        );
    }
    println!("results in {}", args.out.join("results").display());
    Ok(())
}
