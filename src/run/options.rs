//! What a run is asked to do ([`RunOptions`]), and the checks of those options against the plan
//! made before anything connects.

use std::path::PathBuf;

use anyhow::bail;
use rig_core::config::RigConfig;

use rig_core::pose::Pose;

use super::collector::Tap;
use crate::plan::{Plan, Trajectory};
use crate::record::WriterGate;
use crate::simrig::{self, PhysicsConfig, SimFault, SimFtFrontEnd};

/// The fastest a simulated run's clock may be asked to run (`--speed-factor`): the rig's
/// devices cannot keep up far beyond the default ×10, and the governor slows the clock to what
/// they can, so more only risks overflowing clock arithmetic.
pub const MAX_SPEED_FACTOR: f64 = 1000.0;

/// Options of one run.
#[derive(Clone)]
pub struct RunOptions {
    /// Run only the first `limit` trajectories.
    pub limit: Option<usize>,
    /// Simulated rig only: how many times faster than real time the simulated clock runs.
    pub speed_factor: f64,
    /// Show a progress bar (off in tests and when stderr is not a terminal).
    pub progress: bool,
    /// Output directory of the recording.
    pub out: PathBuf,
    /// Continue the recording in `out` instead of refusing to touch it.
    pub resume: bool,
    /// Simulated rig only: the contact physics (see [`simrig::default_physics`]).
    pub sim_physics: PhysicsConfig,
    /// Simulated rig only: how the simulated Nano17 is connected.
    pub sim_ft: SimFtFrontEnd,
    /// Simulated rig only: the contact cache's root directory (simulate once, render per
    /// sensor: a run replays the contact a run with the same gel, indenter and physics left
    /// there, and leaves its own). `None`: every contact is solved.
    pub sim_contact_cache: Option<PathBuf>,
    /// Simulated rig only: faults to inject.
    pub sim_faults: Vec<SimFault>,
    /// Sees every record written (the Foxglove live view).
    pub tap: Option<Tap>,
    /// Simulated rig only: where the arm's TCP is when the rig starts (default: the first
    /// trajectory's start). A lab arm is wherever the last run left it, e.g. at depth after a
    /// kill; this puts the simulated one there.
    pub sim_start_pose: Option<Pose>,
    /// Hold the recorder's writer (a stalled disk, for drills and tests).
    pub recorder_gate: Option<WriterGate>,
    /// Sees every stop the safety supervisor commands (see [`super::safety::StopObserver`]).
    pub on_safety_stop: Option<super::safety::StopObserver>,
}

impl std::fmt::Debug for RunOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunOptions")
            .field("limit", &self.limit)
            .field("speed_factor", &self.speed_factor)
            .field("out", &self.out)
            .field("resume", &self.resume)
            .field("sim_physics", &self.sim_physics)
            .field("sim_ft", &self.sim_ft)
            .field("sim_contact_cache", &self.sim_contact_cache)
            .field("sim_faults", &self.sim_faults)
            .field("tap", &self.tap.is_some())
            .field("sim_start_pose", &self.sim_start_pose)
            .finish_non_exhaustive()
    }
}

impl RunOptions {
    /// Defaults for recording into `out`: whole plan, clock ×10, no progress bar.
    pub fn new(out: impl Into<PathBuf>) -> Self {
        Self {
            limit: None,
            speed_factor: 10.0,
            progress: false,
            out: out.into(),
            resume: false,
            sim_physics: simrig::default_physics(),
            sim_ft: SimFtFrontEnd::NetFt,
            sim_contact_cache: None,
            sim_faults: Vec::new(),
            tap: None,
            sim_start_pose: None,
            recorder_gate: None,
            on_safety_stop: None,
        }
    }
}

/// The planned trajectories of this run (the first `--limit`), once the options are checked
/// against them and the rig.
pub(super) fn planned<'p>(
    config: &RigConfig,
    plan: &'p Plan,
    opts: &RunOptions,
) -> anyhow::Result<&'p [Trajectory]> {
    let n = opts
        .limit
        .unwrap_or(usize::MAX)
        .min(plan.trajectories.len());
    let planned = &plan.trajectories[..n];
    if planned.is_empty() {
        bail!("the plan has no trajectories to run (--limit 0?)");
    }
    let simulated = config.robot.simulated;
    if simulated
        && !(opts.speed_factor.is_finite()
            && opts.speed_factor > 0.0
            && opts.speed_factor <= MAX_SPEED_FACTOR)
    {
        bail!(
            "--speed-factor must be a number above 0 and at most {MAX_SPEED_FACTOR}, got {} \
             (the simulated rig cannot keep up far beyond the default 10; its clock slows down to what it can)",
            opts.speed_factor
        );
    }
    if !simulated && !opts.sim_faults.is_empty() {
        bail!("simulated faults can only be injected into the simulated rig");
    }
    for f in &opts.sim_faults {
        if !planned.iter().any(|t| t.id == f.trajectory) {
            bail!(
                "simulated fault {:?}: trajectory {} is not in this run's plan",
                f.kind,
                f.trajectory
            );
        }
    }
    Ok(planned)
}

impl RunOptions {
    /// How many times faster than real time the rig's clock runs: `speed_factor` on the
    /// simulated rig, 1 on the lab's. Real-time tolerances (stalls, watchdog) scale with it.
    pub(super) fn clock_speed(&self, config: &RigConfig) -> f64 {
        if config.robot.simulated {
            self.speed_factor
        } else {
            1.0
        }
    }
}
