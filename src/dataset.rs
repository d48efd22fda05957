//! `rig dataset check DIR [--json]`: is a recorded dataset complete and well synchronised?
//!
//! The check reads `manifest.json` and every trajectory file completely (each MCAP record and
//! each message decoded, the MCAP summary's counts compared with what was read) and reports, per
//! trajectory: its verdict, message counts, frame sequence gaps (dropped frames), wrench gaps
//! (counter gaps, and time gaps longer than 2.5 median sample periods), and the sync-error
//! statistics (p50/p99/max of the distance from each frame time to its nearest wrench sample).
//!
//! Verdicts: `complete`; `incomplete` (the manifest says pending or failed, or a stale
//! `.<id>.mcap.partial` is lying around); `missing` (the manifest says complete but the file is
//! gone); `unreadable` (the file does not parse, or disagrees with the manifest's counts);
//! `unlisted` (a trajectory file the manifest does not mention). Anything but `complete` makes
//! the command exit non-zero, after printing the whole report.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::bail;
use clap::{Args, Subcommand};
use serde::Serialize;

use crate::record::file::{partial_id, read_file};
use crate::record::manifest::{Counts, Manifest, Status};
use crate::sync::SeqGap;

/// Arguments of `rig dataset`.
#[derive(Debug, Args)]
pub struct DatasetArgs {
    #[command(subcommand)]
    pub what: DatasetCommand,
}

#[derive(Debug, Subcommand)]
pub enum DatasetCommand {
    /// Verify a dataset: every file readable, counts, sync-error statistics, gaps. Exits
    /// non-zero when any trajectory is incomplete or unreadable.
    Check {
        /// The dataset directory (`rig run --out DIR`).
        dir: PathBuf,
        /// Print the report as JSON on stdout.
        #[arg(long)]
        json: bool,
    },
}

/// Verdict of one trajectory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Verdict {
    Complete,
    Incomplete,
    Missing,
    Unreadable,
    Unlisted,
}

/// p50/p99/max of a set of values (ns), over `n` values.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Stats {
    pub n: usize,
    pub p50_ns: f64,
    pub p99_ns: f64,
    pub max_ns: f64,
}

impl Stats {
    /// Nearest-rank percentiles.
    pub fn of(values: &[f64]) -> Self {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Self {
            n: v.len(),
            p50_ns: rank(0.50),
            p99_ns: rank(0.99),
            max_ns: v[v.len() - 1],
        }
    }
}

/// Report of one trajectory.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TrajectoryReport {
    pub id: String,
    pub verdict: Verdict,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    pub counts: Counts,
    /// Gaps in the frame sequence found in the file.
    pub frame_gaps: Vec<SeqGap>,
    /// Frames missing according to those gaps.
    pub frames_dropped: u64,
    /// Gaps in the wrench counter.
    pub wrench_seq_gaps: Vec<SeqGap>,
    /// Wrench time gaps longer than 2.5 median periods, and the longest gap, ns.
    pub wrench_time_gaps: usize,
    pub wrench_longest_gap_ns: f64,
    pub sync_error: Stats,
    /// Paired frames by sync status (`ok`, `held`, `gap`, ...).
    pub paired_status: BTreeMap<String, u64>,
    /// Every frame's sync error, ns (for the dataset-wide statistics).
    #[serde(skip)]
    pub sync_errors_ns: Vec<f64>,
}

impl TrajectoryReport {
    fn empty(id: &str, verdict: Verdict, reason: Option<String>) -> Self {
        Self {
            id: id.to_owned(),
            verdict,
            reason,
            counts: Counts::default(),
            frame_gaps: Vec::new(),
            frames_dropped: 0,
            wrench_seq_gaps: Vec::new(),
            wrench_time_gaps: 0,
            wrench_longest_gap_ns: 0.0,
            sync_error: Stats::default(),
            paired_status: BTreeMap::new(),
            sync_errors_ns: Vec::new(),
        }
    }
}

/// Report of a dataset.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DatasetReport {
    pub dir: PathBuf,
    /// Why the manifest could not be used, if it could not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub manifest_error: Option<String>,
    pub trajectories: Vec<TrajectoryReport>,
    /// Partial files found (trajectories interrupted mid-recording).
    pub stale_partials: Vec<String>,
    pub complete: usize,
    /// Trajectories whose verdict is not `complete`.
    pub problems: usize,
    pub frames: u64,
    pub frames_dropped: u64,
    pub wrench_samples: u64,
    /// Sync error over every frame of the complete trajectories.
    pub sync_error: Stats,
}

impl DatasetReport {
    /// Whether every trajectory is complete and readable.
    pub fn ok(&self) -> bool {
        self.manifest_error.is_none() && self.problems == 0 && self.stale_partials.is_empty()
    }
}

fn seq_gaps(seqs: &[i64]) -> Vec<SeqGap> {
    seqs.windows(2)
        .filter(|w| w[1] > w[0] + 1)
        .map(|w| SeqGap {
            after_seq: w[0],
            missing: (w[1] - w[0] - 1) as u64,
        })
        .collect()
}

fn inspect_file(id: &str, path: &Path, expected: Option<&Counts>) -> TrajectoryReport {
    let c = match read_file(path) {
        Ok(c) => c,
        Err(e) => return TrajectoryReport::empty(id, Verdict::Unreadable, Some(e)),
    };
    let frame_gaps = seq_gaps(&c.frame_seqs);
    let dts: Vec<f64> = c
        .wrench_times_ns
        .windows(2)
        .map(|w| w[1].saturating_sub(w[0]) as f64)
        .collect();
    let median = Stats::of(&dts).p50_ns;
    let mut r = TrajectoryReport {
        id: id.to_owned(),
        verdict: Verdict::Complete,
        reason: None,
        counts: c.counts.clone(),
        frames_dropped: frame_gaps.iter().map(|g| g.missing).sum(),
        frame_gaps,
        wrench_seq_gaps: seq_gaps(&c.wrench_seqs),
        wrench_time_gaps: dts.iter().filter(|&&d| d > 2.5 * median).count(),
        wrench_longest_gap_ns: dts.iter().copied().fold(0.0, f64::max),
        sync_error: Stats::of(&c.sync_errors_ns),
        paired_status: c.paired_status.clone(),
        sync_errors_ns: c.sync_errors_ns.clone(),
    };
    if let Some(exp) = expected
        && *exp != c.counts
    {
        r.verdict = Verdict::Unreadable;
        r.reason = Some(format!(
            "the file holds {:?} but the manifest recorded {:?}",
            c.counts, exp
        ));
    }
    r
}

/// Check the dataset in `dir`. Never fails: every problem is a verdict in the report.
pub fn check(dir: &Path) -> DatasetReport {
    let mut stale_partials = Vec::new();
    let mut files = Vec::new();
    let mut list_error = None;
    match std::fs::read_dir(dir) {
        Ok(rd) => {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if partial_id(&name).is_some() {
                    stale_partials.push(name);
                } else if let Some(id) = name.strip_suffix(".mcap")
                    && !name.starts_with('.')
                {
                    files.push(id.to_owned());
                }
            }
        }
        Err(e) => list_error = Some(format!("cannot list {}: {e}", dir.display())),
    }
    stale_partials.sort();
    files.sort();
    let (manifest, manifest_error) = match (&list_error, Manifest::load(dir)) {
        (Some(e), _) => (None, Some(e.clone())),
        (None, Ok(m)) => (Some(m), None),
        (None, Err(e)) => (None, Some(e)),
    };
    let mut trajectories = Vec::new();
    let mut listed = std::collections::BTreeSet::new();
    if let Some(m) = &manifest {
        for t in &m.trajectories {
            listed.insert(t.id.clone());
            let path = dir.join(crate::record::final_name(&t.id));
            let partial = stale_partials
                .iter()
                .any(|p| partial_id(p) == Some(t.id.as_str()));
            let r = match t.status {
                Status::Complete if path.exists() => {
                    let mut r = inspect_file(&t.id, &path, Some(&t.counts));
                    if partial && r.verdict == Verdict::Complete {
                        r.verdict = Verdict::Incomplete;
                        r.reason = Some("a stale partial file lies beside the complete one".into());
                    }
                    r
                }
                Status::Complete => TrajectoryReport::empty(
                    &t.id,
                    Verdict::Missing,
                    Some(format!(
                        "the manifest says complete but {} is missing",
                        path.display()
                    )),
                ),
                Status::Pending | Status::Failed => {
                    let state = if t.status == Status::Pending {
                        "pending"
                    } else {
                        "failed"
                    };
                    let mut why = match &t.reason {
                        Some(r) => format!("{state}: {r}"),
                        None => state.to_owned(),
                    };
                    if partial {
                        why.push_str(" (partial file left by an interrupted recording)");
                    }
                    TrajectoryReport::empty(&t.id, Verdict::Incomplete, Some(why))
                }
            };
            trajectories.push(r);
        }
    }
    for id in files.iter().filter(|id| !listed.contains(*id)) {
        let mut r = inspect_file(id, &dir.join(crate::record::final_name(id)), None);
        if r.verdict == Verdict::Complete {
            r.verdict = Verdict::Unlisted;
            r.reason = Some("the manifest does not list this file".into());
        }
        trajectories.push(r);
    }
    let good: Vec<&TrajectoryReport> = trajectories
        .iter()
        .filter(|t| t.verdict == Verdict::Complete)
        .collect();
    let all_errors: Vec<f64> = good
        .iter()
        .flat_map(|t| t.sync_errors_ns.iter().copied())
        .collect();
    DatasetReport {
        dir: dir.to_owned(),
        manifest_error,
        complete: good.len(),
        problems: trajectories.len() - good.len(),
        frames: good.iter().map(|t| t.counts.frames).sum(),
        frames_dropped: good.iter().map(|t| t.frames_dropped).sum(),
        wrench_samples: good.iter().map(|t| t.counts.wrench).sum(),
        sync_error: Stats::of(&all_errors),
        trajectories,
        stale_partials,
    }
}

fn us(ns: f64) -> String {
    format!("{:.1} µs", ns * 1e-3)
}

/// The report as an operator reads it.
pub fn render(r: &DatasetReport) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    let _ = writeln!(s, "dataset {}", r.dir.display());
    if let Some(e) = &r.manifest_error {
        let _ = writeln!(s, "  manifest: {e}");
    }
    let _ = writeln!(
        s,
        "  {:<28} {:<10} {:>6} {:>7} {:>6} {:>5} {:>10} {:>10} {:>10}",
        "trajectory",
        "verdict",
        "frames",
        "wrench",
        "poses",
        "drops",
        "sync p50",
        "sync p99",
        "sync max"
    );
    for t in &r.trajectories {
        let _ = writeln!(
            s,
            "  {:<28} {:<10} {:>6} {:>7} {:>6} {:>5} {:>10} {:>10} {:>10}",
            t.id,
            serde_json::to_value(t.verdict)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default(),
            t.counts.frames,
            t.counts.wrench,
            t.counts.poses,
            t.frames_dropped,
            us(t.sync_error.p50_ns),
            us(t.sync_error.p99_ns),
            us(t.sync_error.max_ns)
        );
        if let Some(why) = &t.reason {
            let _ = writeln!(s, "      {why}");
        }
        if !t.wrench_seq_gaps.is_empty() || t.wrench_time_gaps > 0 {
            let _ = writeln!(
                s,
                "      wrench: {} counter gaps ({} samples lost), {} time gaps, longest {}",
                t.wrench_seq_gaps.len(),
                t.wrench_seq_gaps.iter().map(|g| g.missing).sum::<u64>(),
                t.wrench_time_gaps,
                us(t.wrench_longest_gap_ns)
            );
        }
    }
    for p in &r.stale_partials {
        let _ = writeln!(s, "  stale partial file: {p} (rerun with --resume)");
    }
    let _ = writeln!(
        s,
        "  {} complete, {} with problems; {} frames ({} dropped), {} wrench samples; sync error p50 {} p99 {} max {}",
        r.complete,
        r.problems,
        r.frames,
        r.frames_dropped,
        r.wrench_samples,
        us(r.sync_error.p50_ns),
        us(r.sync_error.p99_ns),
        us(r.sync_error.max_ns)
    );
    s
}

pub fn run(args: &DatasetArgs) -> anyhow::Result<()> {
    match &args.what {
        DatasetCommand::Check { dir, json } => {
            let report = check(dir);
            if *json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                print!("{}", render(&report));
            }
            if !report.ok() {
                bail!(
                    "dataset {} is not complete: {} trajectories with problems, {} stale partial files{}",
                    dir.display(),
                    report.problems,
                    report.stale_partials.len(),
                    report
                        .manifest_error
                        .as_ref()
                        .map(|e| format!(", {e}"))
                        .unwrap_or_default()
                );
            }
            Ok(())
        }
    }
}
