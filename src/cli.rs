//! The `rig` command line.
//!
//! One clap-derived [`Command`] enum with one variant and one args struct per subcommand, and one
//! arm in [`run`]. To add a subcommand (`run`, `ft`, `sim`, `dataset`, `train`, `eval`, `demo`,
//! `bench`, ...): add a variant with its own `Args` struct and a handler function, and dispatch
//! it in [`run`]. Handlers return `anyhow::Result` with operator-facing messages; `main` prints
//! them and exits with status 1 (clap itself exits with 2 on usage errors). Handlers that need
//! async I/O build their own tokio runtime, so the synchronous ones stay simple.
//!
//! Rig config resolution, shared by every subcommand that needs a rig ([`resolve_config`]):
//! `--config FILE` if given; else `./rig.toml` if present; else the embedded simulated source
//! rig (`rig-configs/sim-source.toml`), announced on stderr.

use std::fmt;
use std::io::{self, IsTerminal, Write};
use std::path::{Path, PathBuf};

use anyhow::{Context, anyhow};
use clap::{Args, Parser, Subcommand};
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;
use serde::Serialize;

use crate::plan::{Plan, PlanError, StageName, Trajectory};

/// File picked up as the rig config when no `--config` is given.
pub const LOCAL_CONFIG: &str = "rig.toml";

/// TransForce rig: contact-plan data collection for vision-based tactile sensors.
#[derive(Debug, Parser)]
#[command(name = "rig", version, about, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands. Add new ones here (one variant, one args struct, one arm in [`run`]).
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Build the contact plan for an indenter and check every waypoint against the safety
    /// limits, without touching the robot.
    Plan(PlanArgs),
    /// List the built-in indenters.
    Indenters(IndentersArgs),
    /// Drive the robot along the contact plan (the simulated rig when no lab rig is configured).
    Run(RunArgs),
    /// Force/torque sensor: calibration, tare, live stream and checks.
    Ft(crate::force::cli::FtArgs),
    /// The contact + optics simulator: render a frame and print its wrench.
    Sim(crate::simcli::SimArgs),
    /// Benchmarks: what accuracy costs in time.
    Bench(crate::bench::BenchArgs),
    /// Recorded datasets: verify completeness and synchronisation.
    Dataset(crate::dataset::DatasetArgs),
    /// The TransForce trainer: `translate` (CycleGAN), then `force` (encoder + LSTM).
    Train(crate::train::TrainArgs),
    /// Evaluate force models on a target-sensor dataset (MAE, R², plots).
    Eval(crate::train::EvalArgs),
    /// The whole story on the simulated rig: collect, translate, train, evaluate.
    Demo(crate::train::demo::DemoArgs),
}

/// Arguments of `rig run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Built-in indenter name (see `rig indenters`) or a path to an indenter .toml or .stl file.
    #[arg(long, value_name = "NAME")]
    pub indenter: String,
    /// Rig config (TOML). Default: ./rig.toml if present, else the built-in simulated rig.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Output directory of the recording (one MCAP file per trajectory and manifest.json).
    /// Default: runs/<indenter>-<sensor id>.
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Continue the recording in the output directory: skip complete trajectories, redo the rest.
    #[arg(long)]
    pub resume: bool,
    /// Run only the first N trajectories of the plan.
    #[arg(long, value_name = "N")]
    pub limit: Option<usize>,
    /// Simulated rig only: run the simulated clock this many times faster than real time.
    #[arg(long, value_name = "F", default_value_t = 10.0)]
    pub speed_factor: f64,
    /// Simulated rig only: how the simulated Nano17 is connected (a Net F/T on UDP, or an F/T
    /// controller on a serial pty).
    #[arg(long, value_enum, value_name = "FRONT_END", default_value = "netft")]
    pub sim_ft: SimFt,
    /// Simulated rig only: inject a fault (a drill for operators, and the fault tests):
    /// KIND@TRAJECTORY/STAGE[+MS], KIND one of protective-stop, rtde-drop, ft-unplug,
    /// camera-stall; MS is clock time after the stage starts. Repeatable.
    #[arg(long, value_name = "FAULT")]
    pub sim_fault: Vec<crate::run::SimFault>,
    /// Serve a live view for the Foxglove app (Foxglove WebSocket) on this loopback address
    /// while the run records (default 127.0.0.1:8765).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub live: Option<std::net::SocketAddr>,
}

/// The simulated Nano17's front end (`rig run --sim-ft`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SimFt {
    Netft,
    Serial,
}

/// Arguments of `rig plan`.
#[derive(Debug, Args)]
pub struct PlanArgs {
    /// Built-in indenter name (see `rig indenters`) or a path to an indenter .toml or .stl file.
    #[arg(long, value_name = "NAME")]
    pub indenter: String,
    /// Rig config (TOML). Default: ./rig.toml if present, else the built-in simulated rig.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Print every trajectory as JSON on stdout instead of a summary.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `rig indenters`.
#[derive(Debug, Args)]
pub struct IndentersArgs {}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Plan(args) => plan_command(&args),
        Command::Indenters(args) => indenters_command(&args),
        Command::Run(args) => run_command(&args),
        Command::Ft(args) => crate::force::cli::run(&args),
        Command::Sim(args) => crate::simcli::run(&args),
        Command::Bench(args) => crate::bench::run(&args),
        Command::Dataset(args) => crate::dataset::run(&args),
        Command::Train(args) => crate::train::train_command(&args),
        Command::Eval(args) => crate::train::eval_command(&args),
        Command::Demo(args) => crate::train::demo::demo_command(&args),
    }
}

fn run_command(args: &RunArgs) -> anyhow::Result<()> {
    let loaded = resolve_config(args.config.as_deref())?;
    let indenter = Indenter::load(&args.indenter)?;
    // Refuse an unsafe plan before anything starts, with the same message as `rig plan`.
    let plan = Plan::build(&loaded.config, &indenter).map_err(|e| plan_error(e, &loaded.source))?;
    let out = match &args.out {
        Some(dir) => dir.clone(),
        None => {
            let dir = Path::new("runs").join(format!("{}-{}", plan.indenter, plan.sensor_id));
            eprintln!("recording into {} (no --out given)", dir.display());
            dir
        }
    };
    if loaded.config.robot.simulated {
        eprintln!(
            "running on the simulated rig: a UR5e on loopback RTDE, a Nano17 ({}) and a GelSight \
             camera driven by one contact scene; clock up to ×{} (slower while the camera cannot keep up)",
            match args.sim_ft {
                SimFt::Netft => "Net F/T on loopback UDP",
                SimFt::Serial => "F/T controller on a pty",
            },
            args.speed_factor
        );
    }
    let opts = crate::run::RunOptions {
        limit: args.limit,
        speed_factor: args.speed_factor,
        progress: io::stderr().is_terminal(),
        resume: args.resume,
        sim_faults: args.sim_fault.clone(),
        sim_ft: match args.sim_ft {
            SimFt::Netft => hardware_mocks::rig_sim::SimFtFrontEnd::NetFt,
            SimFt::Serial => hardware_mocks::rig_sim::SimFtFrontEnd::Serial,
        },
        ..crate::run::RunOptions::new(out.clone())
    };
    let runtime = tokio::runtime::Runtime::new()?;
    let summary = runtime.block_on(async {
        let mut opts = opts;
        let live = match args.live {
            Some(addr) => {
                let live = std::sync::Arc::new(
                    crate::live::LiveView::start(addr)
                        .await
                        .map_err(|e| anyhow::anyhow!("cannot start the live view on {addr}: {e}"))?,
                );
                eprintln!(
                    "live view: in the Foxglove app, open a Foxglove WebSocket connection to ws://{}",
                    live.addr()
                );
                let tap = live.clone();
                opts.tap = Some(std::sync::Arc::new(move |r: &crate::record::Record| tap.publish(r)));
                Some(live)
            }
            None => None,
        };
        let summary = crate::run::run(&loaded.config, &indenter, &opts).await;
        if let Some(live) = live {
            let s = live.stats();
            tracing::info!(
                "live view: {} messages sent, {} dropped for slow clients",
                s.sent,
                s.dropped
            );
        }
        summary
    })?;
    print!("{}", summary.report());
    let report = crate::dataset::check(&out);
    if report.ok() {
        println!(
            "dataset check: OK, {} complete trajectories in {}",
            report.complete,
            out.display()
        );
    } else {
        println!(
            "dataset check: NOT complete: {} complete, {} with problems{}",
            report.complete,
            report.problems,
            report
                .manifest_error
                .as_ref()
                .map(|e| format!(" ({e})"))
                .unwrap_or_default()
        );
        for t in report
            .trajectories
            .iter()
            .filter(|t| t.verdict != crate::dataset::Verdict::Complete)
            .take(5)
        {
            println!(
                "  {}: {}",
                t.id,
                t.reason.as_deref().unwrap_or("not complete")
            );
        }
    }
    if let Some((id, why)) = &summary.failure {
        let what = if summary.not_attempted > 0 {
            format!("run stopped at trajectory {id}: {why}")
        } else {
            format!(
                "{} trajectories failed, the first {id}: {why}",
                summary.failed.len()
            )
        };
        anyhow::bail!(
            "{what}\nfix the cause, then continue with the same command plus --resume (--out {})",
            out.display()
        );
    }
    if !report.ok() {
        anyhow::bail!(
            "the dataset in {} is not complete; `rig dataset check {}` shows why, and the same \
             command plus --resume records what is missing",
            out.display(),
            out.display()
        );
    }
    Ok(())
}

/// Where the rig config came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConfigSource {
    /// `--config FILE`.
    Explicit(PathBuf),
    /// `./rig.toml` in the working directory.
    Local(PathBuf),
    /// The embedded `rig-configs/sim-source.toml`.
    EmbeddedSimSource,
}

impl fmt::Display for ConfigSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigSource::Explicit(p) | ConfigSource::Local(p) => write!(f, "{}", p.display()),
            ConfigSource::EmbeddedSimSource => {
                f.write_str("built-in simulated rig (rig-configs/sim-source.toml)")
            }
        }
    }
}

/// A validated rig config and where it came from.
#[derive(Debug, Clone)]
pub struct LoadedConfig {
    pub config: RigConfig,
    pub source: ConfigSource,
}

/// `--config FILE` if given; else `./rig.toml` if present; else the embedded simulated rig, which
/// is announced on stderr so nobody mistakes it for their lab rig.
pub fn resolve_config(explicit: Option<&Path>) -> anyhow::Result<LoadedConfig> {
    if let Some(path) = explicit {
        let config = RigConfig::load(path)?;
        return Ok(LoadedConfig {
            config,
            source: ConfigSource::Explicit(path.to_owned()),
        });
    }
    let local = Path::new(LOCAL_CONFIG);
    if local.is_file() {
        let config = RigConfig::load(local)?;
        return Ok(LoadedConfig {
            config,
            source: ConfigSource::Local(local.to_owned()),
        });
    }
    eprintln!(
        "note: no --config given and no ./{LOCAL_CONFIG} here; using the built-in simulated rig \
         (rig-configs/sim-source.toml)"
    );
    Ok(LoadedConfig {
        config: RigConfig::sim_source(),
        source: ConfigSource::EmbeddedSimSource,
    })
}

/// JSON document of `rig plan --json`.
#[derive(Serialize)]
struct PlanJson<'a> {
    indenter: &'a str,
    config: String,
    sensor: &'a str,
    surface_frame: [f64; 6],
    trajectories: &'a [Trajectory],
}

fn plan_command(args: &PlanArgs) -> anyhow::Result<()> {
    let loaded = resolve_config(args.config.as_deref())?;
    let indenter = Indenter::load(&args.indenter)?;
    let plan = Plan::build(&loaded.config, &indenter).map_err(|e| plan_error(e, &loaded.source))?;
    tracing::debug!(
        trajectories = plan.trajectories.len(),
        indenter = %plan.indenter,
        "plan built and checked"
    );

    let mut out = io::BufWriter::new(io::stdout().lock());
    let written = if args.json {
        let doc = PlanJson {
            indenter: &plan.indenter,
            config: loaded.source.to_string(),
            sensor: &plan.sensor_id,
            surface_frame: plan.surface_frame.to_array(),
            trajectories: &plan.trajectories,
        };
        serde_json::to_writer(&mut out, &doc)
            .map_err(io::Error::from)
            .and_then(|()| writeln!(out))
    } else {
        write_summary(&mut out, &plan, &loaded, &indenter)
    };
    finish_stdout(written.and_then(|()| out.flush()))
}

/// Turns a plan refusal into an operator message: what is wrong, where, and what to do.
fn plan_error(e: PlanError, source: &ConfigSource) -> anyhow::Error {
    match &e {
        PlanError::Unsafe(violations) => {
            let mut msg = e.to_string();
            for v in violations.iter().skip(1).take(4) {
                msg.push_str(&format!("\n  also: {v}"));
            }
            if violations.len() > 5 {
                msg.push_str(&format!("\n  … {} more", violations.len() - 5));
            }
            msg.push_str(&format!(
                "\nnothing was moved; adjust [safety] or [plan] in {source} and run `rig plan` again"
            ));
            anyhow!(msg)
        }
        _ => anyhow::Error::new(e),
    }
}

fn write_summary(
    out: &mut impl Write,
    plan: &Plan,
    loaded: &LoadedConfig,
    indenter: &Indenter,
) -> io::Result<()> {
    let c = &loaded.config;
    let p = &c.plan;
    let n = plan.trajectories.len();
    writeln!(
        out,
        "contact plan: indenter `{}` ({}) on sensor `{}`",
        plan.indenter,
        indenter.description(),
        plan.sensor_id
    )?;
    writeln!(out, "config: {}", loaded.source)?;
    writeln!(
        out,
        "{n} trajectories = {} contact points × {} depths × {} directions; {} waypoints",
        p.contact_points_mm.len(),
        p.depths_mm.len(),
        p.directions_deg.len(),
        plan.waypoint_count()
    )?;
    let points: Vec<String> = p
        .contact_points_mm
        .iter()
        .map(|[x, y]| format!("({x}, {y})"))
        .collect();
    writeln!(
        out,
        "  contact points (mm, surface frame): {}",
        points.join(" ")
    )?;
    let depths: Vec<String> = p.depths_mm.iter().map(|d| d.to_string()).collect();
    writeln!(out, "  depths (mm): {}", depths.join(" "))?;
    let dirs: Vec<String> = p.directions_deg.iter().map(|a| a.to_string()).collect();
    writeln!(out, "  directions (deg): {}", dirs.join(" "))?;
    writeln!(
        out,
        "  shear distance {} mm, approach height {} mm",
        p.shear_distance_mm, p.approach_height_mm
    )?;

    writeln!(
        out,
        "estimated motion time (moves between contact points not included):"
    )?;
    for (name, total_s) in plan.stage_durations_s() {
        let m = match name {
            StageName::Down => &p.down,
            StageName::Shear | StageName::Reverse => &p.shear,
            StageName::Up => &p.up,
        };
        writeln!(
            out,
            "  {:<8} {:>9} total, {:>6.2} s per trajectory on average ({} mm/s, {} mm/s²)",
            name.as_str(),
            hms(total_s),
            total_s / n.max(1) as f64,
            m.speed_mm_s,
            m.accel_mm_s2
        )?;
    }
    writeln!(out, "  {:<8} {:>9}", "all", hms(plan.duration_estimate_s()))?;

    writeln!(
        out,
        "safety: every waypoint is inside safety.envelope, at most safety.max_depth_mm = {} mm \
         deep (elastomer {} mm thick)",
        c.safety.max_depth_mm, c.elastomer.thickness_mm
    )?;
    writeln!(out, "  envelope margins (closest waypoint to each face):")?;
    let margins = plan.envelope_margins(&c.safety.envelope);
    let faces = margins.faces();
    for pair in faces.chunks(2) {
        writeln!(
            out,
            "    {:<6} {:>9.3} mm    {:<6} {:>9.3} mm",
            pair[0].0, pair[0].1, pair[1].0, pair[1].1
        )?;
    }
    Ok(())
}

/// `h:mm:ss` for a duration in seconds.
fn hms(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

fn indenters_command(_args: &IndentersArgs) -> anyhow::Result<()> {
    let mut out = io::BufWriter::new(io::stdout().lock());
    let names = Indenter::list_builtin();
    let width = names.iter().map(|n| n.len()).max().unwrap_or(0);
    let mut written = Ok(());
    for name in names {
        let ind = Indenter::builtin(name)
            .with_context(|| format!("built-in indenter {name} is broken"))?;
        written = writeln!(out, "{name:<width$}  {}", ind.description());
        if written.is_err() {
            break;
        }
    }
    let written = written.and_then(|()| {
        writeln!(
            out,
            "\nAny indenter .toml or .stl file can be given as --indenter PATH as well."
        )
    });
    finish_stdout(written.and_then(|()| out.flush()))
}

/// A closed stdout (`rig plan --json | head`) is not an error worth reporting.
fn finish_stdout(result: io::Result<()>) -> anyhow::Result<()> {
    match result {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("cannot write to stdout"),
    }
}
