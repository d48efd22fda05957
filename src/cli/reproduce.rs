//! `rig reproduce`: the paper's experiment on the simulated rig ([`crate::train::reproduce`]).

use std::path::PathBuf;

use clap::Args;

use crate::train::reproduce::{self, Fid, Protocol, Scale};

#[derive(Debug, Args)]
pub struct ReproduceArgs {
    /// How big: `cpu` (the default) runs the whole split on 4 of the 12 directions with small
    /// images and networks, sized to finish in under two hours on 2 CPU cores; `paper` runs
    /// the full protocol (every trajectory, 320 × 240 frames, ResNet-50) and wants a GPU (build
    /// with `--features vulkan`, `wgpu` or `gpu`; docs/trainer.md says what to expect); `tiny`
    /// is the tests' version, a few minutes. The time each phase took in real runs is in
    /// docs/benchmarks.md.
    #[arg(long, value_enum, default_value = "cpu")]
    pub scale: Scale,
    /// Where the data, translator, models, results and figures go. Run again with the same
    /// --out to continue a run that was stopped.
    #[arg(long, default_value = "runs/reproduce")]
    pub out: PathBuf,
    /// Force models per method and modality (seeds 1..=N; default: the scale's, 3).
    #[arg(long, value_name = "N")]
    pub seeds: Option<u64>,
    /// Inception weights for FID/KID (default: $RIG_INCEPTION_WEIGHTS, else
    /// ~/.cache/rig/inception-fid.safetensors, written by scripts/fetch-inception). Without
    /// them `--scale cpu` and `paper` stop before they start; `tiny` goes on without FID/KID.
    #[arg(long, value_name = "FILE")]
    pub inception: Option<PathBuf>,
    /// Leave FID and KID out (no Inception weights needed; the translation table keeps its
    /// colour-statistics distance).
    #[arg(long, conflicts_with = "inception")]
    pub no_fid: bool,
    /// The target sensor's rig config (default: rig-configs/sim-target.toml); a simulated
    /// rig. Use a fresh --out.
    #[arg(long, value_name = "FILE")]
    pub target: Option<PathBuf>,
    /// Magnify the source sensor's frames by the ratio of the two sensors' marker pitches
    /// before translating them, so that shear can cross the translation. It costs accuracy on
    /// normal force, so it is off by default (docs/trainer.md). Use a fresh --out: a finished
    /// translation in --out is reused as it is.
    #[arg(long)]
    pub match_marker_pitch: bool,
}

pub fn run(args: &ReproduceArgs) -> anyhow::Result<()> {
    let target = super::demo::sim_target(args.target.as_deref())?;
    let mut protocol = Protocol::new(args.scale);
    protocol.translate.match_marker_pitch = args.match_marker_pitch;
    if let Some(n) = args.seeds {
        anyhow::ensure!(n >= 1, "--seeds must be at least 1");
        protocol.seeds = (1..=n).collect();
    }
    let fid = if args.no_fid {
        Fid::Skip
    } else {
        Fid::Inception(args.inception.as_deref())
    };
    let r = reproduce::run(&protocol, &args.out, fid, target.as_ref())?;
    println!("{}", reproduce::markdown(&r));
    println!(
        "report: {}",
        args.out.join("results/reproduce.md").display()
    );
    Ok(())
}
