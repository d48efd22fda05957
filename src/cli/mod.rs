//! The command layer: the `rig` command line, one file per subcommand.
//!
//! [`Cli`] is one clap-derived [`Command`] enum with one variant per subcommand; each variant's
//! args struct and handler live in the subcommand's own file here (`plan.rs`: `rig plan` and
//! `rig indenters`; `run.rs`, `ft.rs`, `sim.rs`, `dataset.rs`, `train.rs` (`train` and `eval`),
//! `demo.rs`, `reproduce.rs`, `predict.rs`, and `bench/`), and [`run()`] dispatches. To add a subcommand: a file with its
//! `Args` and a handler, a variant, and an arm in [`run()`]. Handlers return `anyhow::Result`
//! with operator-facing messages; `main` prints them and exits with status 1 (clap itself exits
//! with 2 on usage errors). Handlers that need async I/O build their own tokio runtime, so the
//! synchronous ones stay simple.
//!
//! This layer parses, resolves the rig config ([`config::resolve_config`]), calls the domain
//! modules and prints; the domain modules (`run`, `force`, `dataset`, `train`, ...) never import
//! it back.

pub mod bench;
pub mod config;
pub mod dataset;
pub mod demo;
pub mod ft;
pub mod plan;
pub mod predict;
pub mod reproduce;
pub mod run;
pub mod sim;
pub mod train;

use clap::{Parser, Subcommand};

pub use config::{ConfigSource, LOCAL_CONFIG, LoadedConfig, resolve_config};

/// TransForce rig: contact-plan data collection for vision-based tactile sensors.
#[derive(Debug, Parser)]
#[command(name = "rig", version, about, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands. Add new ones here (one variant, its file's args struct, one arm in [`run()`]).
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Build the contact plan for an indenter and check every waypoint against the safety
    /// limits, without touching the robot.
    Plan(plan::PlanArgs),
    /// List the built-in indenters.
    Indenters(plan::IndentersArgs),
    /// Drive the robot along the contact plan (the simulated rig when no lab rig is configured).
    Run(run::RunArgs),
    /// Force/torque sensor: calibration, tare, live stream and checks.
    Ft(ft::FtArgs),
    /// The contact + optics simulator: render a frame and print its wrench.
    Sim(sim::SimArgs),
    /// Benchmarks: what accuracy costs in time.
    Bench(bench::BenchArgs),
    /// Recorded datasets: verify completeness and synchronisation.
    Dataset(dataset::DatasetArgs),
    /// The TransForce trainer: `translate` (CycleGAN), then `force` (encoder + LSTM).
    Train(train::TrainArgs),
    /// Evaluate force models on a target-sensor dataset (MAE, R², plots).
    Eval(train::EvalArgs),
    /// The whole story on the simulated rig: collect, translate, train, evaluate.
    Demo(demo::DemoArgs),
    /// The paper's experiment on the simulated rig: 18 indenters, 3 modalities, 3 methods, 3
    /// seeds, with the paper's numbers and a verdict per claim.
    Reproduce(reproduce::ReproduceArgs),
    /// A trained force model on the target sensor's camera (or a replayed recording): force
    /// estimates frame by frame, with a summary of frames, skipped frames, latency and error.
    Predict(predict::PredictArgs),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Plan(args) => plan::run(&args),
        Command::Indenters(args) => plan::indenters(&args),
        Command::Run(args) => run::run(&args),
        Command::Ft(args) => ft::run(&args),
        Command::Sim(args) => sim::run(&args),
        Command::Bench(args) => bench::run(&args),
        Command::Dataset(args) => dataset::run(&args),
        Command::Train(args) => train::train(&args),
        Command::Eval(args) => train::eval(&args),
        Command::Demo(args) => demo::run(&args),
        Command::Reproduce(args) => reproduce::run(&args),
        Command::Predict(args) => predict::run(&args),
    }
}
