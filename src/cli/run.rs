//! `rig run`: the operator's side of a run (config, output directory, live view, the closing
//! dataset check and what to do next); the run itself is [`crate::run`].

use std::io::{self, IsTerminal};
use std::path::{Path, PathBuf};

use clap::Args;
use rig_core::indenter::Indenter;

use super::config::resolve_config;
use super::plan::plan_error;
use crate::plan::Plan;

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
    /// Default: `runs/<indenter>-<sensor id>`.
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
    /// Simulated rig only: how the simulated Nano17 is connected (a Net F/T on UDP, an F/T
    /// controller on a serial pty, or an NI card read through the stand-in NI-DAQmx library,
    /// found beside the rig executable or at RIG_NIDAQMX_LIBRARY).
    #[arg(long, value_enum, value_name = "FRONT_END", default_value = "netft")]
    pub sim_ft: SimFt,
    /// Simulated rig only: inject a fault (a drill for operators, and the fault tests):
    /// KIND@TRAJECTORY/STAGE[+MS], KIND one of protective-stop, rtde-drop, ft-unplug,
    /// camera-stall, supervisor-freeze, disk-stall; MS is clock time after the stage starts.
    /// Repeatable.
    #[arg(long, value_name = "FAULT")]
    pub sim_fault: Vec<crate::simrig::SimFault>,
    /// Serve a live view for the Foxglove app (Foxglove WebSocket) on this loopback address
    /// while the run records (default 127.0.0.1:8765).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub live: Option<std::net::SocketAddr>,
    /// Also serve the live view to pages of this origin (`SCHEME://HOST[:PORT]`, e.g.
    /// `https://app.foxglove.dev` for Foxglove's web app). Repeatable.
    #[arg(long, value_name = "ORIGIN", requires = "live")]
    pub live_allow_origin: Vec<crate::live::AllowedOrigin>,
    /// Simulated rig only: keep the contact physics' tapes in DIR (default ~/.cache/rig/contact,
    /// or $RIG_CONTACT_CACHE) and replay the ones a run with the same gel, indenter and physics
    /// left there (simulate once, render per sensor): a second sensor's run renders its own
    /// optics from the first's contact. About 1 MB a trajectory (254 MB for the cone's full
    /// plan). Without it every contact is solved and nothing is kept.
    #[arg(long, value_name = "DIR", num_args = 0..=1, default_missing_value = "")]
    pub contact_cache: Option<PathBuf>,
}

/// Where `rig run` keeps the simulated rig's contact tapes (see [`RunArgs::contact_cache`]).
fn contact_cache_dir(args: &RunArgs) -> Option<PathBuf> {
    let dir = args.contact_cache.as_ref()?;
    if !dir.as_os_str().is_empty() {
        return Some(dir.clone());
    }
    Some(match std::env::var_os("RIG_CONTACT_CACHE") {
        Some(v) if !v.is_empty() => PathBuf::from(v),
        _ => crate::cache_root().join("contact"),
    })
}

/// The simulated Nano17's front end (`rig run --sim-ft`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SimFt {
    Netft,
    Serial,
    /// An NI card behind the stand-in NI-DAQmx library (`cargo build -p nidaqmx-standin`).
    Nidaqmx,
}

pub fn run(args: &RunArgs) -> anyhow::Result<()> {
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
                SimFt::Nidaqmx => "NI card behind the stand-in NI-DAQmx library",
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
        sim_contact_cache: contact_cache_dir(args),
        sim_ft: match args.sim_ft {
            SimFt::Netft => crate::simrig::SimFtFrontEnd::NetFt,
            SimFt::Serial => crate::simrig::SimFtFrontEnd::Serial,
            SimFt::Nidaqmx => crate::simrig::SimFtFrontEnd::NiDaqmx,
        },
        ..crate::run::RunOptions::new(out.clone())
    };
    let runtime = tokio::runtime::Runtime::new()?;
    let summary = runtime.block_on(async {
        let mut opts = opts;
        let live = match args.live {
            Some(addr) => {
                let live = std::sync::Arc::new(
                    crate::live::LiveView::start_with_options(
                        addr,
                        crate::live::LiveOptions {
                            allowed_origins: args.live_allow_origin.clone(),
                            ..crate::live::LiveOptions::default()
                        },
                    )
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
    if let Some(why) = &summary.recording_stalled {
        // The dataset check would read the stalled disk too, and wait on it for ever.
        anyhow::bail!(
            "the run stopped: {why}\nthe arm was stopped and left clear of the gel; the \
             recording in {} is as the disk last took it (`rig dataset check` shows what is \
             missing once it answers again)",
            out.display()
        );
    }
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
