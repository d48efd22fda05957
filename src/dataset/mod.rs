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

//!
//! The files: [`check`] reads and judges, `truth` compares with the simulator's truth,
//! `report` renders, [`export`] writes a dataset out in other tools' layouts (`rig dataset
//! export`); the command is `crate::cli::dataset`. Both read recordings of either format
//! (protobuf, or the first JSON one) through [`crate::record::reader`].

mod check;
pub mod export;
mod report;
mod truth;

pub use check::*;
pub use report::{failure, render};
pub use truth::*;

/// Full range of the ATI Nano17 SI-25-0.25: Fx, Fy, Fz (N), Tx, Ty, Tz (N·mm). The fallback when
/// the manifest's calibration carries no `max_loads`.
pub const NANO17_SI_25_025_MAX_LOADS: [f64; 6] = [25.0, 25.0, 35.0, 250.0, 250.0, 250.0];

/// Names of the six axes, in `max_loads` order.
pub const AXES: [&str; 6] = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"];

/// The report counts frames whose worst axis is off by more than this, % of full range.
pub const REPORTED_ERROR_PCT: f64 = 2.0;

/// Index of the nearest-rank `p` percentile in a sorted slice of `len` values (`len > 0`).
fn nearest_rank(len: usize, p: f64) -> usize {
    ((p * len as f64).ceil() as usize).clamp(1, len) - 1
}
