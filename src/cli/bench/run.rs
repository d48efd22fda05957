//! `rig bench run`: how long the simulated rig takes to record the contact plan, and what the
//! recording's accuracy is for that time.
//!
//! It runs `rig run --indenter cone` on the built-in simulated rig into a scratch directory
//! (deleted afterwards unless `--keep`), then prints one table: trajectories, simulated and
//! wall-clock time, the effective clock speed (the governed clock runs as fast as the simulated
//! camera can render, up to `--speed-factor`), frames and their rate, the sync error p50/p99,
//! and the largest difference between a frame's paired force and the simulator's true force.
//! It writes a CSV of every trajectory (wall time, frames, depth) and an SVG plot of the
//! cumulative wall time against trajectories, with the 3-minute goal for the full plan.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use plotters::prelude::*;

use crate::chart;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use crate::run::{RunOptions, RunSummary};

/// Goal for the full 240-trajectory plan on a 2-core machine, s.
pub const FULL_RUN_GOAL_S: f64 = 180.0;

/// Arguments of `rig bench run`.
#[derive(Debug, Args)]
pub struct RunBenchArgs {
    /// Only the first N trajectories (default: the whole plan).
    #[arg(long, value_name = "N")]
    pub limit: Option<usize>,
    /// 12 trajectories instead of the whole plan (a smoke test of the benchmark).
    #[arg(long)]
    pub quick: bool,
    /// Indenter.
    #[arg(long, default_value = "cone")]
    pub indenter: String,
    /// Fastest the simulated clock may run.
    #[arg(long, value_name = "F", default_value_t = 10.0)]
    pub speed_factor: f64,
    /// Where the table's CSV and the plot go.
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    pub out: PathBuf,
    /// Keep the recorded dataset (in OUT/run-dataset).
    #[arg(long)]
    pub keep: bool,
}

/// The table of a run.
pub fn table(s: &RunSummary) -> String {
    let n = s.trajectories.len();
    let frames = s.frames();
    let (p50, p99) = s.sync_error_p50_p99_ns();
    let truth = s.truth_max_error_n().unwrap_or(0.0);
    let rows = [
        ("trajectories", format!("{n} ({} failed)", s.failed.len())),
        ("simulated time", format!("{:.1} s", s.clock_time_s)),
        ("wall-clock time", format!("{:.1} s", s.wall_time_s)),
        (
            "effective speed",
            format!("×{:.2}", s.clock_time_s / s.wall_time_s.max(1e-9)),
        ),
        (
            "frames",
            format!(
                "{frames} ({:.1} per wall second, {} lost)",
                frames as f64 / s.wall_time_s.max(1e-9),
                s.frames_lost
            ),
        ),
        (
            "sync error p50 / p99",
            format!("{:.3} / {:.3} ms", p50 * 1e-6, p99 * 1e-6),
        ),
        ("max |paired − true| force", format!("{truth:.4} N")),
        (
            "contact physics steps",
            s.sim_physics.map_or("-".into(), |p| {
                format!(
                    "{} ({} in contact, {:.0} per clock s; {} F/T reads asked for a step off the grid)",
                    p.steps,
                    p.contact_steps,
                    p.steps as f64 / s.clock_time_s.max(1e-9),
                    p.off_grid_steps
                )
            }),
        ),
        (
            "full plan (240), extrapolated",
            if n > 0 {
                format!(
                    "{:.0} s (goal {FULL_RUN_GOAL_S:.0} s)",
                    s.wall_time_s / n as f64 * 240.0
                )
            } else {
                "-".into()
            },
        ),
    ];
    let mut out = String::new();
    for (k, v) in rows {
        out.push_str(&format!("{k:<32} {v}\n"));
    }
    out
}

fn plot(s: &RunSummary, path: &std::path::Path) -> anyhow::Result<()> {
    let mut cum = Vec::with_capacity(s.trajectories.len());
    let mut acc = 0.0;
    for (i, t) in s.trajectories.iter().enumerate() {
        acc += t.wall_time_s;
        cum.push(((i + 1) as f64, acc));
    }
    let x_max = (cum.len() as f64).max(240.0);
    let y_max = acc.max(FULL_RUN_GOAL_S) * 1.1;
    chart::svg(path, (900, 480), |root| {
        let mut chart = chart::builder(
            root,
            "rig run on the simulated rig: cumulative wall-clock time",
        )
        .build_cartesian_2d(0f64..x_max, 0f64..y_max)?;
        chart
            .configure_mesh()
            .x_desc("trajectories recorded")
            .y_desc("wall-clock time, s")
            .draw()?;
        chart
            .draw_series(LineSeries::new(cum, BLUE.stroke_width(2)))?
            .label("measured")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        chart
            .draw_series(LineSeries::new(
                vec![(0.0, 0.0), (240.0, FULL_RUN_GOAL_S)],
                RED.stroke_width(1),
            ))?
            .label("goal: 240 trajectories in 3 min")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        chart::legend(&mut chart)?;
        Ok(())
    })
}

pub fn run(args: &RunBenchArgs) -> anyhow::Result<()> {
    if cfg!(debug_assertions) {
        eprintln!("note: a debug build; use `cargo run --release` for representative numbers");
    }
    let config = RigConfig::sim_source();
    let indenter = Indenter::load(&args.indenter)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let dataset = args.out.join("run-dataset");
    if dataset.exists() {
        std::fs::remove_dir_all(&dataset)
            .with_context(|| format!("cannot clear {}", dataset.display()))?;
    }
    let limit = args.limit.or(args.quick.then_some(12));
    let opts = RunOptions {
        limit,
        speed_factor: args.speed_factor,
        progress: std::io::IsTerminal::is_terminal(&std::io::stderr()),
        ..RunOptions::new(&dataset)
    };
    eprintln!(
        "recording {} trajectories of `{}` on the simulated rig into {} …",
        limit.map_or("all".to_string(), |n| n.to_string()),
        args.indenter,
        dataset.display()
    );
    let runtime = tokio::runtime::Runtime::new()?;
    let summary = runtime.block_on(crate::run::run(&config, &indenter, &opts))?;
    print!("{}", table(&summary));
    let csv = args.out.join("run_trajectories.csv");
    let mut text = String::from("id,wall_s,clock_s,frames,wrench,max_abs_force_error_n\n");
    for t in &summary.trajectories {
        text.push_str(&format!(
            "{},{:.3},{:.3},{},{},{}\n",
            t.id,
            t.wall_time_s,
            t.duration_s,
            t.stats.frames,
            t.stats.wrench,
            t.stats
                .truth_max_error_n
                .map_or(String::new(), |e| format!("{e:.5}"))
        ));
    }
    std::fs::write(&csv, text).with_context(|| format!("cannot write {}", csv.display()))?;
    let svg = args.out.join("run_time.svg");
    plot(&summary, &svg)?;
    println!("table: {}\nplot: {}", csv.display(), svg.display());
    if !args.keep {
        std::fs::remove_dir_all(&dataset).ok();
    }
    if let Some((id, why)) = &summary.failure {
        anyhow::bail!("the benchmark run failed at {id}: {why}");
    }
    Ok(())
}
