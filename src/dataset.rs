//! `rig dataset check DIR [--json] [--max-error-pct P]`: is a recorded dataset complete, well
//! synchronised and (on the simulated rig) accurate?
//!
//! The check reads `manifest.json` and every trajectory file completely (each MCAP record and
//! each message decoded, the MCAP summary's counts compared with what was read) and reports, per
//! trajectory: its verdict, message counts, frame sequence gaps (dropped frames), wrench gaps
//! (counter gaps, and time gaps longer than 2.5 median sample periods), and the sync-error
//! statistics (p50/p99/max of the distance from each frame time to its nearest wrench sample).
//!
//! Two more things, per trajectory and dataset-wide:
//!
//! - **Unexplained frame drops**: the frames missing from the file's sequence numbers minus the
//!   drops the manifest entry says the camera itself reported (`frames_dropped` of the entry),
//!   never negative. A drop the camera reported is a known loss; one it did not is a recording
//!   bug.
//! - **Paired vs true wrench**, when a file holds simulator truth (`/sim/true_wrench`, simulated
//!   rig only): every frame with both a paired wrench and a true wrench (joined by frame
//!   sequence number) gets, per axis, `|paired − true| / full range`; the frame's error is its
//!   worst axis. The full range is the manifest calibration's `max_loads` (Fx, Fy, Fz in N, Tx,
//!   Ty, Tz in N·mm), or, when the manifest has none, the Nano17 SI-25-0.25 range
//!   [`NANO17_SI_25_025_MAX_LOADS`] (the report says so). Reported: max and p99 of the
//!   worst-axis error in % of full range, the frames above 2 %, the largest force-component
//!   error in N, and the frames with a truth but no paired wrench (refused: `unpaired`).
//!
//! Verdicts: `complete`; `incomplete` (the manifest says pending or failed, or a stale
//! `.<id>.mcap.partial` is lying around); `missing` (the manifest says complete but the file is
//! gone); `unreadable` (the file does not parse, or disagrees with the manifest's counts);
//! `unlisted` (a trajectory file the manifest does not mention). Anything but `complete` makes
//! the command exit non-zero, after printing the whole report. Accuracy is reported, not judged,
//! unless `--max-error-pct P` is given: then any frame of a complete trajectory whose worst axis
//! is off by more than P % of full range also makes the exit non-zero (when the dataset holds
//! simulator truth; without it there is nothing to judge and the limit is not applied).
//!
//! Dataset-wide figures (frames, drops, sync error, truth comparison) are over the `complete`
//! trajectories only.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::bail;
use clap::{Args, Subcommand};
use rig_core::wrench::Wrench;
use serde::Serialize;

use crate::record::file::{PairedRead, partial_id, read_file};
use crate::record::manifest::{Counts, Manifest, Status};
use crate::sync::SeqGap;

/// Full range of the ATI Nano17 SI-25-0.25: Fx, Fy, Fz (N), Tx, Ty, Tz (N·mm). The fallback when
/// the manifest's calibration carries no `max_loads`.
pub const NANO17_SI_25_025_MAX_LOADS: [f64; 6] = [25.0, 25.0, 35.0, 250.0, 250.0, 250.0];

/// Names of the six axes, in `max_loads` order.
pub const AXES: [&str; 6] = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"];

/// The report counts frames whose worst axis is off by more than this, % of full range.
pub const REPORTED_ERROR_PCT: f64 = 2.0;

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
}

fn parse_pct(s: &str) -> Result<f64, String> {
    match s.trim().trim_end_matches('%').trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        _ => Err(format!(
            "{s:?} is not a percentage (a number ≥ 0, e.g. 2 or 0.5)"
        )),
    }
}

/// What to check beyond completeness.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct CheckOptions {
    /// `--max-error-pct`: the largest paired-vs-true error allowed, % of full range.
    pub max_error_pct: Option<f64>,
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

/// Index of the nearest-rank `p` percentile in a sorted slice of `len` values (`len > 0`).
fn nearest_rank(len: usize, p: f64) -> usize {
    ((p * len as f64).ceil() as usize).clamp(1, len) - 1
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
        Self {
            n: v.len(),
            p50_ns: v[nearest_rank(v.len(), 0.50)],
            p99_ns: v[nearest_rank(v.len(), 0.99)],
            max_ns: v[v.len() - 1],
        }
    }
}

/// Where the full range used for the truth comparison came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RangeSource {
    /// The manifest calibration's `max_loads`.
    Manifest,
    /// [`NANO17_SI_25_025_MAX_LOADS`], because the manifest has no usable `max_loads`.
    Fallback,
}

/// The F/T sensor's full range per axis, the denominator of the truth comparison.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FullRange {
    /// Fx, Fy, Fz (N), Tx, Ty, Tz (N·mm).
    pub max_loads: [f64; 6],
    pub source: RangeSource,
    /// Why the fallback was used (`null` when the range is the manifest's).
    pub note: Option<String>,
}

impl FullRange {
    /// The Nano17 SI-25-0.25 range, with the reason it is used.
    pub fn fallback(why: impl Into<String>) -> Self {
        Self {
            max_loads: NANO17_SI_25_025_MAX_LOADS,
            source: RangeSource::Fallback,
            note: Some(why.into()),
        }
    }

    /// `max_loads` of a manifest's calibration object: six finite, positive numbers, else the
    /// fallback.
    pub fn from_calibration(calibration: &serde_json::Value) -> Self {
        let Some(v) = calibration.get("max_loads") else {
            return Self::fallback("the manifest's calibration has no max_loads");
        };
        let values: Option<[f64; 6]> = v
            .as_array()
            .and_then(|a| {
                a.iter()
                    .map(serde_json::Value::as_f64)
                    .collect::<Option<Vec<_>>>()
            })
            .and_then(|a| a.try_into().ok());
        match values {
            Some(max_loads) if max_loads.iter().all(|x| x.is_finite() && *x > 0.0) => Self {
                max_loads,
                source: RangeSource::Manifest,
                note: None,
            },
            _ => Self::fallback(format!(
                "the manifest's calibration max_loads {v} is not six positive numbers"
            )),
        }
    }
}

/// One compared frame: its worst axis.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FrameError {
    pub frame_seq: i64,
    /// Index into [`AXES`] of the axis furthest off, relative to its full range.
    pub axis: usize,
    /// That axis's `|paired − true|`, % of its full range.
    pub pct: f64,
    /// That axis's `|paired − true|`, N or N·mm.
    pub abs_error: f64,
    /// The largest `|paired − true|` of Fx, Fy, Fz, N.
    pub force_error_n: f64,
}

/// The frame furthest off the truth.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WorstFrame {
    pub trajectory: String,
    pub frame_seq: i64,
    /// `Fx` … `Tz`.
    pub axis: String,
    /// `|paired − true|` on that axis, % of its full range.
    pub pct: f64,
    /// `|paired − true|` on that axis, N or N·mm.
    pub abs_error: f64,
}

/// Paired wrench against the simulator's true wrench, of a trajectory or a dataset.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TruthComparison {
    /// Frames with a true wrench.
    pub frames_with_truth: u64,
    /// Frames with both a true and a paired wrench: the frames compared.
    pub compared: u64,
    /// Frames with a true wrench but no paired wrench (refused, or no paired message).
    pub unpaired: u64,
    /// Paired-wrench messages of frames without a true wrench.
    pub paired_without_truth: u64,
    /// Max over compared frames of the worst-axis error, % of full range.
    pub worst_axis_max_pct: f64,
    /// p99 (nearest rank) of the worst-axis error, % of full range.
    pub worst_axis_p99_pct: f64,
    /// Compared frames whose worst-axis error is above 2 % of full range.
    pub frames_above_2pct: u64,
    /// The largest force-component error `max(|ΔFx|, |ΔFy|, |ΔFz|)`, N.
    pub max_force_error_n: f64,
    /// Per axis (Fx … Tz), the largest error, % of full range (torque axes count only where the
    /// paired message has a torque).
    pub axis_max_pct: [f64; 6],
    /// The frame with the largest worst-axis error (`null` when none was compared).
    pub worst: Option<WorstFrame>,
}

impl TruthComparison {
    /// Statistics of `errors` (trajectory id, frame), with the frame counts given.
    fn of<'a>(
        errors: impl Iterator<Item = (&'a str, &'a FrameError)>,
        frames_with_truth: u64,
        unpaired: u64,
        paired_without_truth: u64,
        axis_max_pct: [f64; 6],
    ) -> Self {
        let mut pcts = Vec::new();
        let mut worst: Option<(&str, &FrameError)> = None;
        let mut max_force_error_n: f64 = 0.0;
        for (id, e) in errors {
            pcts.push(e.pct);
            max_force_error_n = max_force_error_n.max(e.force_error_n);
            if worst.is_none_or(|(_, w)| e.pct > w.pct) {
                worst = Some((id, e));
            }
        }
        pcts.sort_by(f64::total_cmp);
        let at = |p: f64| {
            if pcts.is_empty() {
                0.0
            } else {
                pcts[nearest_rank(pcts.len(), p)]
            }
        };
        Self {
            frames_with_truth,
            compared: pcts.len() as u64,
            unpaired,
            paired_without_truth,
            worst_axis_max_pct: pcts.last().copied().unwrap_or(0.0),
            worst_axis_p99_pct: at(0.99),
            frames_above_2pct: pcts.iter().filter(|&&p| p > REPORTED_ERROR_PCT).count() as u64,
            max_force_error_n,
            axis_max_pct,
            worst: worst.map(|(id, e)| WorstFrame {
                trajectory: id.to_owned(),
                frame_seq: e.frame_seq,
                axis: AXES[e.axis].to_owned(),
                pct: e.pct,
                abs_error: e.abs_error,
            }),
        }
    }
}

/// Compare a file's paired wrenches with its true ones. Returns the comparison (`None` when
/// the file holds no truth) and every compared frame.
fn compare_truth(
    id: &str,
    paired: &[PairedRead],
    truth: &[crate::record::file::TruthRead],
    range: &FullRange,
) -> (Option<TruthComparison>, Vec<FrameError>) {
    if truth.is_empty() {
        return (None, Vec::new());
    }
    let paired: BTreeMap<i64, &PairedRead> = paired.iter().map(|p| (p.frame_seq, p)).collect();
    let truth: BTreeMap<i64, &Wrench> = truth.iter().map(|t| (t.frame_seq, &t.wrench)).collect();
    let mut errors = Vec::new();
    let mut unpaired = 0;
    let mut axis_max_pct = [0.0f64; 6];
    for (&seq, tw) in &truth {
        let Some((p, force)) = paired.get(&seq).and_then(|p| p.force_n.map(|f| (*p, f))) else {
            unpaired += 1;
            continue;
        };
        let mut abs = [None; 6];
        for k in 0..3 {
            abs[k] = Some((force[k] - tw.force_n[k]).abs());
            if let Some(t) = p.torque_nmm {
                abs[3 + k] = Some((t[k] - tw.torque_nmm[k]).abs());
            }
        }
        let mut e = FrameError {
            frame_seq: seq,
            axis: 0,
            pct: f64::NEG_INFINITY,
            abs_error: 0.0,
            force_error_n: abs[..3].iter().flatten().copied().fold(0.0, f64::max),
        };
        for (k, a) in abs.iter().enumerate() {
            let Some(a) = *a else { continue };
            let pct = a / range.max_loads[k] * 100.0;
            axis_max_pct[k] = axis_max_pct[k].max(pct);
            if pct > e.pct {
                (e.axis, e.pct, e.abs_error) = (k, pct, a);
            }
        }
        errors.push(e);
    }
    let paired_without_truth = paired.keys().filter(|s| !truth.contains_key(s)).count() as u64;
    let cmp = TruthComparison::of(
        errors.iter().map(|e| (id, e)),
        truth.len() as u64,
        unpaired,
        paired_without_truth,
        axis_max_pct,
    );
    (Some(cmp), errors)
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
    /// Frames the camera reported lost, according to the manifest entry (0 when unlisted).
    pub frames_dropped_reported: u64,
    /// `frames_dropped − frames_dropped_reported`, never negative: gaps nothing explains.
    pub frames_dropped_unexplained: u64,
    /// Gaps in the wrench counter.
    pub wrench_seq_gaps: Vec<SeqGap>,
    /// Wrench time gaps longer than 2.5 median periods (only for a stream without a sample
    /// counter), and the longest gap between two arrivals, ns.
    pub wrench_time_gaps: usize,
    pub wrench_longest_gap_ns: f64,
    pub sync_error: Stats,
    /// Paired frames by sync status (`ok`, `held`, `gap`, ...).
    pub paired_status: BTreeMap<String, u64>,
    /// Paired vs true wrench (`null` when the file holds no simulator truth).
    pub truth: Option<TruthComparison>,
    /// Every frame's sync error, ns (for the dataset-wide statistics).
    #[serde(skip)]
    pub sync_errors_ns: Vec<f64>,
    /// Every compared frame's error (for the dataset-wide statistics and the error limit).
    #[serde(skip)]
    pub truth_errors: Vec<FrameError>,
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
            frames_dropped_reported: 0,
            frames_dropped_unexplained: 0,
            wrench_seq_gaps: Vec::new(),
            wrench_time_gaps: 0,
            wrench_longest_gap_ns: 0.0,
            sync_error: Stats::default(),
            paired_status: BTreeMap::new(),
            truth: None,
            sync_errors_ns: Vec::new(),
            truth_errors: Vec::new(),
        }
    }
}

/// The outcome of `--max-error-pct`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ErrorLimit {
    /// The limit, % of full range.
    pub max_error_pct: f64,
    /// Whether any complete trajectory held simulator truth to judge (without, the limit is not
    /// applied and passes).
    pub applied: bool,
    /// Frames of complete trajectories whose worst-axis error is above the limit.
    pub frames_above: u64,
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
    /// Of those, the drops the camera reported (manifest) and the rest.
    pub frames_dropped_reported: u64,
    pub frames_dropped_unexplained: u64,
    pub wrench_samples: u64,
    /// Sync error over every frame of the complete trajectories.
    pub sync_error: Stats,
    /// The full range the truth comparison divides by.
    pub full_range: FullRange,
    /// Paired vs true wrench over the complete trajectories that hold simulator truth (`null`
    /// when none does).
    pub truth: Option<TruthComparison>,
    /// The `--max-error-pct` verdict (`null` when the option was not given).
    pub error_limit: Option<ErrorLimit>,
}

impl DatasetReport {
    /// Whether every trajectory is complete and readable.
    pub fn ok(&self) -> bool {
        self.manifest_error.is_none() && self.problems == 0 && self.stale_partials.is_empty()
    }

    /// Whether no frame exceeds `--max-error-pct` (true when it was not given or not applied).
    pub fn within_error_limit(&self) -> bool {
        self.error_limit
            .as_ref()
            .is_none_or(|l| l.frames_above == 0)
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

/// What the manifest says about a trajectory file.
struct Expected<'a> {
    counts: &'a Counts,
    frames_dropped: u64,
}

fn inspect_file(
    id: &str,
    path: &Path,
    expected: Option<Expected<'_>>,
    range: &FullRange,
) -> TrajectoryReport {
    let c = match read_file(path) {
        Ok(c) => c,
        Err(e) => return TrajectoryReport::empty(id, Verdict::Unreadable, Some(e)),
    };
    let frame_gaps = seq_gaps(&c.frame_seqs);
    let frames_dropped: u64 = frame_gaps.iter().map(|g| g.missing).sum();
    let reported = expected.as_ref().map_or(0, |e| e.frames_dropped);
    let dts: Vec<f64> = c
        .wrench_times_ns
        .windows(2)
        .map(|w| w[1].saturating_sub(w[0]) as f64)
        .collect();
    let median = Stats::of(&dts).p50_ns;
    let (truth, truth_errors) = compare_truth(id, &c.paired, &c.truth, range);
    let mut r = TrajectoryReport {
        id: id.to_owned(),
        verdict: Verdict::Complete,
        reason: None,
        counts: c.counts.clone(),
        frames_dropped,
        frames_dropped_reported: reported,
        frames_dropped_unexplained: frames_dropped.saturating_sub(reported),
        frame_gaps,
        wrench_seq_gaps: seq_gaps(&c.wrench_seqs),
        // With a counter, the counter says exactly what was lost; the arrival times of a
        // bursty transport (UDP, a busy machine, a fast simulated clock) are not gaps.
        wrench_time_gaps: if c.wrench_seqs.is_empty() {
            dts.iter().filter(|&&d| d > 2.5 * median).count()
        } else {
            0
        },
        wrench_longest_gap_ns: dts.iter().copied().fold(0.0, f64::max),
        sync_error: Stats::of(&c.sync_errors_ns),
        paired_status: c.paired_status,
        truth,
        sync_errors_ns: c.sync_errors_ns,
        truth_errors,
    };
    if let Some(exp) = expected
        && *exp.counts != c.counts
    {
        r.verdict = Verdict::Unreadable;
        r.reason = Some(format!(
            "the file holds {:?} but the manifest recorded {:?}",
            c.counts, exp.counts
        ));
    }
    r
}

/// Check the dataset in `dir` for completeness (no error limit). Never fails: every problem is
/// a verdict in the report.
pub fn check(dir: &Path) -> DatasetReport {
    check_with(dir, &CheckOptions::default())
}

/// Check the dataset in `dir` with `opts`. Never fails: every problem is a verdict in the
/// report.
pub fn check_with(dir: &Path, opts: &CheckOptions) -> DatasetReport {
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
    let full_range = match &manifest {
        Some(m) => FullRange::from_calibration(&m.calibration),
        None => FullRange::fallback("no manifest"),
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
                    let expected = Expected {
                        counts: &t.counts,
                        frames_dropped: t.frames_dropped,
                    };
                    let mut r = inspect_file(&t.id, &path, Some(expected), &full_range);
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
        let path = dir.join(crate::record::final_name(id));
        let mut r = inspect_file(id, &path, None, &full_range);
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
    let with_truth: Vec<(&TrajectoryReport, &TruthComparison)> = good
        .iter()
        .filter_map(|t| Some((*t, t.truth.as_ref()?)))
        .collect();
    let truth = (!with_truth.is_empty()).then(|| {
        let sum = |f: fn(&TruthComparison) -> u64| with_truth.iter().map(|(_, c)| f(c)).sum();
        let mut axis_max_pct = [0.0f64; 6];
        for (_, c) in &with_truth {
            for (m, v) in axis_max_pct.iter_mut().zip(c.axis_max_pct) {
                *m = m.max(v);
            }
        }
        TruthComparison::of(
            with_truth
                .iter()
                .flat_map(|(t, _)| t.truth_errors.iter().map(|e| (t.id.as_str(), e))),
            sum(|c| c.frames_with_truth),
            sum(|c| c.unpaired),
            sum(|c| c.paired_without_truth),
            axis_max_pct,
        )
    });
    let error_limit = opts.max_error_pct.map(|limit| ErrorLimit {
        max_error_pct: limit,
        applied: truth.is_some(),
        frames_above: with_truth
            .iter()
            .flat_map(|(t, _)| &t.truth_errors)
            .filter(|e| e.pct > limit)
            .count() as u64,
    });
    DatasetReport {
        dir: dir.to_owned(),
        manifest_error,
        complete: good.len(),
        problems: trajectories.len() - good.len(),
        frames: good.iter().map(|t| t.counts.frames).sum(),
        frames_dropped: good.iter().map(|t| t.frames_dropped).sum(),
        frames_dropped_reported: good.iter().map(|t| t.frames_dropped_reported).sum(),
        frames_dropped_unexplained: good.iter().map(|t| t.frames_dropped_unexplained).sum(),
        wrench_samples: good.iter().map(|t| t.counts.wrench).sum(),
        sync_error: Stats::of(&all_errors),
        full_range,
        truth,
        error_limit,
        trajectories,
        stale_partials,
    }
}

fn us(ns: f64) -> String {
    format!("{:.1} µs", ns * 1e-3)
}

fn pct(p: f64) -> String {
    format!("{p:.2} %")
}

/// A percentage limit as the operator typed it (`2`, `0.5`).
fn limit(p: f64) -> String {
    format!("{p} %")
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
        "  {:<28} {:<10} {:>6} {:>7} {:>6} {:>5} {:>6} {:>10} {:>10} {:>10} {:>9}",
        "trajectory",
        "verdict",
        "frames",
        "wrench",
        "poses",
        "drops",
        "unexpl",
        "sync p50",
        "sync p99",
        "sync max",
        "true err"
    );
    for t in &r.trajectories {
        let _ = writeln!(
            s,
            "  {:<28} {:<10} {:>6} {:>7} {:>6} {:>5} {:>6} {:>10} {:>10} {:>10} {:>9}",
            t.id,
            serde_json::to_value(t.verdict)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default(),
            t.counts.frames,
            t.counts.wrench,
            t.counts.poses,
            t.frames_dropped,
            t.frames_dropped_unexplained,
            us(t.sync_error.p50_ns),
            us(t.sync_error.p99_ns),
            us(t.sync_error.max_ns),
            t.truth
                .as_ref()
                .filter(|c| c.compared > 0)
                .map_or_else(|| "-".to_owned(), |c| pct(c.worst_axis_max_pct))
        );
        if let Some(why) = &t.reason {
            let _ = writeln!(s, "      {why}");
        }
        if t.frames_dropped_unexplained > 0 {
            let _ = writeln!(
                s,
                "      frames: {} missing from the sequence, {} reported lost by the camera: {} unexplained",
                t.frames_dropped, t.frames_dropped_reported, t.frames_dropped_unexplained
            );
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
        if let Some(c) = &t.truth
            && (c.frames_above_2pct > 0 || c.unpaired > 0 || c.paired_without_truth > 0)
        {
            let worst = c
                .worst
                .as_ref()
                .map(|w| format!(" (worst: frame {}, {} {})", w.frame_seq, w.axis, pct(w.pct)))
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "      true wrench: {} frames above 2 %{worst}, {} unpaired, {} paired without truth",
                c.frames_above_2pct, c.unpaired, c.paired_without_truth
            );
        }
    }
    for p in &r.stale_partials {
        let _ = writeln!(s, "  stale partial file: {p} (rerun with --resume)");
    }
    let _ = writeln!(
        s,
        "  {} complete, {} with problems; {} frames, {} wrench samples",
        r.complete, r.problems, r.frames, r.wrench_samples
    );
    let _ = writeln!(
        s,
        "  sync error p50 {} p99 {} max {}",
        us(r.sync_error.p50_ns),
        us(r.sync_error.p99_ns),
        us(r.sync_error.max_ns)
    );
    let _ = writeln!(
        s,
        "  frame drops: {} ({} unexplained)",
        r.frames_dropped, r.frames_dropped_unexplained
    );
    match &r.truth {
        None => {
            let _ = writeln!(
                s,
                "  paired vs true wrench: no simulator truth (/sim/true_wrench) in this dataset"
            );
        }
        Some(c) => {
            let unpaired = if c.unpaired > 0 {
                format!("; {} unpaired", c.unpaired)
            } else {
                String::new()
            };
            if c.compared == 0 {
                let _ = writeln!(s, "  paired vs true wrench: no frame has both{unpaired}");
            } else {
                let _ = writeln!(
                    s,
                    "  paired vs true wrench: worst axis max {} of full range, p99 {}, {} frames above 2 %; max |ΔF| {:.3} N{unpaired}",
                    pct(c.worst_axis_max_pct),
                    pct(c.worst_axis_p99_pct),
                    c.frames_above_2pct,
                    c.max_force_error_n
                );
            }
            if let Some(note) = &r.full_range.note {
                let l = r.full_range.max_loads;
                let _ = writeln!(
                    s,
                    "  full range: Nano17 SI-25-0.25 fallback [{}, {}, {}, {}, {}, {}] (N, N·mm): {note}",
                    l[0], l[1], l[2], l[3], l[4], l[5]
                );
            }
        }
    }
    if let Some(l) = &r.error_limit {
        if !l.applied {
            let _ = writeln!(
                s,
                "  error limit {}: not applied (no simulator truth)",
                limit(l.max_error_pct)
            );
        } else {
            let worst = r
                .truth
                .as_ref()
                .and_then(|c| c.worst.as_ref())
                .filter(|_| l.frames_above > 0)
                .map(|w| {
                    format!(
                        "; worst: {} frame {}, {} {}",
                        w.trajectory,
                        w.frame_seq,
                        w.axis,
                        pct(w.pct)
                    )
                })
                .unwrap_or_default();
            let _ = writeln!(
                s,
                "  error limit {}: {} frames above{worst}",
                limit(l.max_error_pct),
                l.frames_above
            );
        }
    }
    s
}

/// Why the exit is non-zero, if it is.
fn failure(r: &DatasetReport) -> Option<String> {
    let mut why = Vec::new();
    if !r.ok() {
        why.push(format!(
            "dataset {} is not complete: {} trajectories with problems, {} stale partial files{}",
            r.dir.display(),
            r.problems,
            r.stale_partials.len(),
            r.manifest_error
                .as_ref()
                .map(|e| format!(", {e}"))
                .unwrap_or_default()
        ));
    }
    if let Some(l) = &r.error_limit
        && l.frames_above > 0
    {
        let worst = r
            .truth
            .as_ref()
            .and_then(|c| c.worst.as_ref())
            .map(|w| {
                let unit = if w.axis.starts_with('F') {
                    "N"
                } else {
                    "N·mm"
                };
                format!(
                    "; worst: trajectory {} frame {}, {} off by {} ({:.4} {unit})",
                    w.trajectory,
                    w.frame_seq,
                    w.axis,
                    pct(w.pct),
                    w.abs_error
                )
            })
            .unwrap_or_default();
        why.push(format!(
            "dataset {}: {} frames' paired wrench is off the true wrench by more than {} of full range{worst}",
            r.dir.display(),
            l.frames_above,
            limit(l.max_error_pct)
        ));
    }
    (!why.is_empty()).then(|| why.join("\n"))
}

pub fn run(args: &DatasetArgs) -> anyhow::Result<()> {
    match &args.what {
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
