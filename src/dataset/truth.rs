//! The paired wrench against the simulator's true wrench: per-frame worst-axis error as a
//! share of the sensor's full range, and the dataset-wide summary of it.

use std::collections::BTreeMap;

use rig_core::wrench::Wrench;
use serde::Serialize;

use crate::record::reader::{PairedRead, TruthRead};

use super::{AXES, NANO17_SI_25_025_MAX_LOADS, REPORTED_ERROR_PCT, nearest_rank};

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
    pub(super) fn of<'a>(
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
pub(super) fn compare_truth(
    id: &str,
    paired: &[PairedRead],
    truth: &[TruthRead],
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
