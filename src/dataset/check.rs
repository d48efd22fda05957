//! Reading every file of a dataset against its manifest: verdicts, counts, gaps, sync-error
//! statistics, and the truth comparison of [`super::truth`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Serialize;

use crate::record::manifest::{Counts, Manifest, Status};
use crate::record::reader::read_file;
use crate::record::writer::partial_id;
use crate::sync::SeqGap;

use super::nearest_rank;
use super::truth::{FrameError, FullRange, TruthComparison, compare_truth};

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
