//! `rig dataset check` and `rig dataset export`: the commands over [`crate::dataset`].

use std::path::PathBuf;

use anyhow::bail;
use clap::{Args, Subcommand};

use crate::dataset::export::{ExportFormat, default_out, export};
use crate::dataset::{CheckOptions, check_with, failure, render};

/// Arguments of `rig dataset`.
#[derive(Debug, Args)]
pub struct DatasetArgs {
    #[command(subcommand)]
    pub what: DatasetCommand,
}

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Verify a dataset: every file readable, counts, sync-error statistics, gaps, unexplained
    /// frame drops and (simulated rig) the paired wrench against the true one. Exits non-zero
    /// when any trajectory is incomplete or unreadable.
    Check {
        /// The dataset directory (`rig run --out DIR`).
        dir: PathBuf,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
        /// Also exit non-zero when a frame's paired wrench is off the simulator's true wrench by
        /// more than P % of full range on any axis (only when the dataset holds simulator truth).
        #[arg(long, value_name = "P", value_parser = parse_pct)]
        max_error_pct: Option<f64>,
    },
    /// Write a dataset out in another layout: `folder` is one directory per trajectory with its
    /// frames as image files (as stored: PNG, or JPEG from an MJPEG camera) and `force.csv`
    /// (per frame: time, paired wrench, stage, pairing status, TCP pose).
    Export {
        /// The dataset directory (`rig run --out DIR`).
        dir: PathBuf,
        /// The layout to write.
        #[arg(long, value_enum)]
        format: ExportFormat,
        /// Output directory (must not exist or be empty; default: `<DIR>-<format>` beside DIR).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
}

fn parse_pct(s: &str) -> Result<f64, String> {
    match s.trim().trim_end_matches('%').trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!(
            "{s:?} is not a percentage (a number ≥ 0, e.g. 2 or 0.5)"
        )),
    }
}

pub fn run(args: &DatasetArgs) -> anyhow::Result<()> {
    match &args.what {
        DatasetCommand::Export { dir, format, out } => {
            let out = out.clone().unwrap_or_else(|| default_out(dir, *format));
            let report = export(dir, &out, *format)?;
            let frames: usize = report.trajectories.iter().map(|(_, n)| n).sum();
            println!(
                "exported {} trajectories ({frames} frames) to {}",
                report.trajectories.len(),
                out.display()
            );
            for (id, status) in &report.skipped {
                println!("skipped {id}: {status}");
            }
            Ok(())
        }
        DatasetCommand::Check {
            dir,
            json,
            max_error_pct,
        } => {
            let report = check_with(
                dir,
                &CheckOptions {
                    max_error_pct: *max_error_pct,
                },
            );
            if *json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{}", render(&report));
            }
            if let Some(l) = &report.error_limit
                && !l.applied
            {
                eprintln!(
                    "note: {} holds no simulator truth (/sim/true_wrench): --max-error-pct {} was not applied",
                    dir.display(),
                    l.max_error_pct
                );
            }
            if let Some(why) = failure(&report) {
                bail!("{why}");
            }
            Ok(())
        }
    }
}
