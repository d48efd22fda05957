//! `rig demo [--quick]`: the whole TransForce story on the simulated rig ([`crate::train::demo`]).

use std::path::PathBuf;

use clap::Args;

use crate::train::demo;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// A small version (what CI runs; minutes, not hours, on 2 cores in a release build):
    /// fewer indenters and trajectories, smaller images and networks, the image models on R+M
    /// only (marker flow reads D).
    #[arg(long)]
    pub quick: bool,
    /// Where the data, models and results go.
    #[arg(long, default_value = "runs/demo")]
    pub out: PathBuf,
    /// Inception weights for FID/KID (default: $RIG_INCEPTION_WEIGHTS, else
    /// ~/.cache/rig/inception-fid.safetensors, written by scripts/fetch-inception).
    #[arg(long, value_name = "FILE")]
    pub inception: Option<PathBuf>,
    /// The target sensor's rig config (default: the built-in simulated target sensor,
    /// rig-configs/sim-target.toml), e.g. rig-configs/sim-third.toml to check that the demo's
    /// settings carry over to a sensor they were not chosen on. It must be a simulated rig
    /// (the demo records on it); use a fresh --out, since recorded data are reused.
    #[arg(long, value_name = "FILE")]
    pub target: Option<PathBuf>,
    /// Magnify the source sensor's frames by the ratio of the two sensors' marker pitches
    /// before translating them, so that shear can cross the translation. It costs accuracy on
    /// normal force, so it is off by default (docs/trainer.md). Use a fresh --out.
    #[arg(long)]
    pub match_marker_pitch: bool,
}

/// The `--target` sensor's config: a simulated rig (the demo and the reproduction record on it).
pub(super) fn sim_target(
    path: Option<&std::path::Path>,
) -> anyhow::Result<Option<rig_core::config::RigConfig>> {
    let Some(path) = path else {
        return Ok(None);
    };
    let c = rig_core::config::RigConfig::load(path)
        .map_err(|e| anyhow::anyhow!("--target {}: {e}", path.display()))?;
    if !c.robot.simulated {
        anyhow::bail!(
            "--target {}: it is recorded on the simulated rig; this config drives a real robot \
             (robot.simulated = false)",
            path.display()
        );
    }
    Ok(Some(c))
}

pub fn run(args: &DemoArgs) -> anyhow::Result<()> {
    let target = sim_target(args.target.as_deref())?;
    let table = demo::run(
        args.quick,
        &args.out,
        args.inception.as_deref(),
        target.as_ref(),
        args.match_marker_pitch,
    )?;
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
