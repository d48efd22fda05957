//! `rig bench …`: what accuracy costs in time. Each benchmark prints a table and writes a plot.

pub mod predict;
pub mod record;
pub mod render;
pub mod run;
pub mod sim;
pub mod sync;
pub mod train;

use clap::{Args, Subcommand};

/// Arguments of `rig bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchCommand,
}

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Contact simulator: force error against time per frame, per model and grid resolution.
    Sim(sim::SimBenchArgs),
    /// Optics: rendering frames per second at 320×240 and 640×480, each effect on and off.
    Render(render::RenderBenchArgs),
    /// Synchronisation: interpolation and drift estimation against the true signal.
    Sync(sync::SyncBenchArgs),
    /// The recorder: write throughput on one core against a run's data rate.
    Record(record::RecordBenchArgs),
    /// The whole `rig run` on the simulated rig: wall-clock time, effective speed, accuracy.
    Run(run::RunBenchArgs),
    /// The force model: training throughput and inference latency per encoder depth, and
    /// held-out MAE against training time for a few model sizes.
    Train(train::TrainBenchArgs),
    /// `rig predict`: per-frame latency (decode, modality, model) on one core at 320×240.
    Predict(predict::PredictBenchArgs),
}

pub fn run(args: &BenchArgs) -> anyhow::Result<()> {
    match &args.what {
        BenchCommand::Sim(a) => sim::run(a),
        BenchCommand::Render(a) => render::run(a),
        BenchCommand::Sync(a) => sync::run(a),
        BenchCommand::Record(a) => record::run(a),
        BenchCommand::Run(a) => run::run(a),
        BenchCommand::Train(a) => train::run(a),
        BenchCommand::Predict(a) => predict::run(a),
    }
}
