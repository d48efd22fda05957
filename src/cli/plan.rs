//! `rig plan` (build and check the contact plan, print it) and `rig indenters`.

use std::io::{self, Write};
use std::path::PathBuf;

use anyhow::{Context, anyhow};
use clap::Args;
use rig_core::indenter::Indenter;
use serde::Serialize;

use super::config::{ConfigSource, LoadedConfig, resolve_config};
use crate::plan::{Plan, PlanError, StageName, Trajectory};

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

/// JSON document of `rig plan --json`.
#[derive(Serialize)]
struct PlanJson<'a> {
    indenter: &'a str,
    config: String,
    sensor: &'a str,
    surface_frame: [f64; 6],
    trajectories: &'a [Trajectory],
}

pub fn run(args: &PlanArgs) -> anyhow::Result<()> {
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
pub fn plan_error(e: PlanError, source: &ConfigSource) -> anyhow::Error {
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

pub fn indenters(_args: &IndentersArgs) -> anyhow::Result<()> {
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
pub fn finish_stdout(result: io::Result<()>) -> anyhow::Result<()> {
    match result {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => other.context("cannot write to stdout"),
    }
}
