//! How a run went: per trajectory ([`TrajectoryOutcome`]) and as a whole ([`RunSummary`]),
//! with the operator's end-of-run report and the progress bar's line.

use std::path::PathBuf;

use super::collector::TrajStats;
use super::events;

/// How one trajectory went.
#[derive(Debug, Clone)]
pub struct TrajectoryOutcome {
    pub id: String,
    /// Largest distance of a logged TCP position from its planned straight segment, mm.
    pub max_path_deviation_mm: f64,
    /// Largest depth below the surface beyond the planned depth, mm (0 if never deeper).
    pub max_depth_overshoot_mm: f64,
    /// RTDE samples logged during the trajectory's moves.
    pub samples: usize,
    /// TCP poses recorded in its file (every state from its first stage's start to its end).
    pub poses_recorded: u64,
    /// Clock time the trajectory took, s.
    pub duration_s: f64,
    /// Wall-clock time from its start (transit included) to its file being complete, s.
    pub wall_time_s: f64,
    /// What its recording holds.
    pub stats: TrajStats,
    /// Simulated rig only: the largest distance of the simulated indenter's physical tip from
    /// the planned segments, mm, over `sim_tip_samples` of the stages' RTDE states.
    pub sim_tip_path_deviation_mm: Option<f64>,
    pub sim_tip_samples: usize,
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct RunSummary {
    pub simulated: bool,
    /// The output directory.
    pub out: PathBuf,
    /// Trajectories recorded completely in this run.
    pub trajectories: Vec<TrajectoryOutcome>,
    /// Trajectories skipped because an earlier run recorded them completely (`--resume`).
    pub skipped: usize,
    /// Trajectories that failed in this run: id and reason.
    pub failed: Vec<(String, String)>,
    /// Trajectories of the plan (after `--limit`) never attempted because the run stopped.
    pub not_attempted: usize,
    /// The first failure, if the run stopped early or a trajectory failed: id and reason.
    pub failure: Option<(String, String)>,
    /// Why the run stopped before the end of the plan, if it did.
    pub stopped: Option<String>,
    /// Clock time of the whole run, s.
    pub clock_time_s: f64,
    /// Wall-clock time of the whole run, s.
    pub wall_time_s: f64,
    /// Simulated rig only: how often, and how long in real time, simulated time held for a
    /// simulated device or the runtime that fell behind (a stalled or busy host), or the
    /// contact physics pacing it (each of its steps costs milliseconds).
    pub clock_holds: rig_core::clock::HoldStats,
    /// Simulated rig only: the largest gap between a frame's capture time and the time of the
    /// contact the simulated camera drew in it, ms.
    pub image_lag_max_ms: Option<f64>,
    /// Simulated rig only: the contact physics' counters (steps, steps in contact).
    pub sim_physics: Option<crate::simrig::PhysicsStats>,
    /// Simulated rig with a contact cache: what was replayed, solved and written.
    pub sim_tapes: Option<crate::simrig::TapeStats>,
    /// Times a stream or the collector waited for the writer (slow disk).
    pub backpressure_waits: u64,
    /// Frames received from the camera in the whole run (recorded or not).
    pub frames_received: u64,
    /// Frames the camera's sequence numbers say were lost in the whole run.
    pub frames_lost: u64,
    /// F/T samples and frames lost for the recording because it fell too far behind (each
    /// failed its trajectory).
    pub recording_lost: u64,
    /// The box the robot's reported TCP stayed in over the run, m: `[min, max]`.
    pub tcp_extent_m: Option<[[f64; 3]; 2]>,
    /// Every stop the safety supervisor commanded, with when it detected the trip and when the
    /// stop request went out.
    pub safety_stops: Vec<super::safety::SafetyStop>,
    /// Every retract along the surface normal: label, from, to.
    pub retracts: Vec<Retract>,
    /// What the output directory holds at the end of the run, against the disk budget (not
    /// measured when the disk stalled).
    pub disk: Option<super::budget::DiskUse>,
    /// The recording's disk stopped answering (see [`crate::record::STALL_LIMIT`]): why. The
    /// run stopped; the writer was left hanging, and the directory is as it last saved it.
    pub recording_stalled: Option<String>,
    /// No F/T sensor: nothing was paired, and the force limit was watched on the UR5e's flange
    /// sensor ([`super::flange`]).
    pub flange_watch: bool,
}

/// A retract along the surface normal to the approach height.
#[derive(Debug, Clone, PartialEq)]
pub struct Retract {
    pub label: String,
    pub from: rig_core::pose::Pose,
    pub to: rig_core::pose::Pose,
}

/// A simulated frame shows the contact of the newest physics step at or before its capture
/// time: steps are one physics period apart (4 ms at the default 250 Hz) at the poses of the
/// controller's ticks (2 ms). More lag than this means the physics fell behind.
const SIM_IMAGE_LAG_WARN_MS: f64 = 10.0;

pub(super) fn progress_message(s: &TrajStats, c: &events::StreamCounters) -> String {
    let fps = match (s.first_frame_ns, s.last_frame_ns) {
        (Some(a), Some(b)) if b > a && s.frames > 1 => {
            (s.frames - 1) as f64 / ((b - a) as f64 * 1e-9)
        }
        _ => 0.0,
    };
    let fz = if s.force_min[2].is_finite() {
        format!("Fz {:.2}..{:.2} N", s.force_min[2], s.force_max[2])
    } else {
        "no force".into()
    };
    format!(
        "{fps:.1} fps  {fz}  {} frames, {} lost",
        c.frames(),
        c.frames_dropped()
    )
}

impl RunSummary {
    /// Trajectory `id` failed for `reason`.
    pub(super) fn note_failure(&mut self, id: &str, reason: String) {
        if self.failure.is_none() {
            self.failure = Some((id.to_owned(), reason.clone()));
        }
        self.failed.push((id.to_owned(), reason));
    }

    /// Sync error of every paired frame recorded in this run: nearest-rank p50 and p99, ns;
    /// NaN when no frame was paired (no camera), not a zero statistic.
    pub fn sync_error_p50_p99_ns(&self) -> (f64, f64) {
        let all: Vec<f64> = self
            .trajectories
            .iter()
            .flat_map(|t| t.stats.sync_errors_ns.iter().copied())
            .collect();
        let st = crate::dataset::Stats::of(&all);
        if st.n == 0 {
            (f64::NAN, f64::NAN)
        } else {
            (st.p50_ns, st.p99_ns)
        }
    }

    /// Largest |paired − true| force component over the run (simulated rig only).
    pub fn truth_max_error_n(&self) -> Option<f64> {
        self.trajectories
            .iter()
            .filter_map(|t| t.stats.truth_max_error_n)
            .reduce(f64::max)
    }

    /// Frames recorded in this run.
    pub fn frames(&self) -> u64 {
        self.trajectories.iter().map(|t| t.stats.frames).sum()
    }

    /// Operator-facing end-of-run report.
    pub fn report(&self) -> String {
        let done = self.trajectories.len();
        let max_dev = self
            .trajectories
            .iter()
            .map(|t| t.max_path_deviation_mm)
            .fold(0.0, f64::max);
        let max_over = self
            .trajectories
            .iter()
            .map(|t| t.max_depth_overshoot_mm)
            .fold(0.0, f64::max);
        let sum =
            |f: fn(&TrajStats) -> u64| self.trajectories.iter().map(|t| f(&t.stats)).sum::<u64>();
        let frames = self.frames();
        let wrench = sum(|s| s.wrench);
        let poses = sum(|s| s.poses);
        let dropped = sum(|s| s.frames_dropped);
        let (ok, held, refused) = (
            sum(|s| s.paired_ok),
            sum(|s| s.paired_held),
            sum(|s| s.paired_refused),
        );
        let (p50, p99) = self.sync_error_p50_p99_ns();
        let truth = self.truth_max_error_n();
        let mut s = format!(
            "{} rig: {done} trajectories recorded, {} failed, {} skipped (already complete), \
             {} not attempted; {:.1} s of {} time in {:.1} s\n",
            if self.simulated { "simulated" } else { "lab" },
            self.failed.len(),
            self.skipped,
            self.not_attempted,
            self.clock_time_s,
            if self.simulated {
                "simulated"
            } else {
                "wall-clock"
            },
            self.wall_time_s,
        );
        s.push_str(&format!(
            "recorded: {frames} frames ({dropped} dropped), {wrench} wrench samples, {poses} TCP poses\n"
        ));
        if self.flange_watch {
            s.push_str(
                "pairing: none (no F/T sensor: images, TCP poses and stages only; the force \
                 limit was watched on the UR5e's flange sensor)\n",
            );
        } else {
            s.push_str(&format!(
                "pairing: {ok} ok, {held} held at a stream end, {refused} refused; sync error p50 {:.3} ms, p99 {:.3} ms\n",
                p50 * 1e-6,
                p99 * 1e-6
            ));
        }
        if let Some(e) = truth {
            s.push_str(&format!(
                "paired vs simulator's true force: largest error {e:.4} N\n"
            ));
        }
        s.push_str(&format!(
            "TCP path: max deviation from the planned lines {max_dev:.4} mm, max depth beyond plan {max_over:.4} mm\n"
        ));
        let h = &self.clock_holds;
        if h.holds > 0 {
            s.push_str(&format!(
                "simulated time waited {} times ({:.2} s of real time; last for the {}): it runs as fast as the slowest simulated device\n",
                h.holds,
                h.held_s,
                h.last_holder.unwrap_or("a device")
            ));
        }
        if let Some(lag) = self.image_lag_max_ms.filter(|l| *l > SIM_IMAGE_LAG_WARN_MS) {
            s.push_str(&format!(
                "simulated images: contact drawn up to {lag:.1} ms before a frame's capture time (the contact physics fell behind)\n"
            ));
        }
        if let Some(t) = &self.sim_tapes {
            let steps = t.replayed_steps + t.solved_steps;
            s.push_str(&format!(
                "contact cache: {} of {steps} contact steps replayed from the {} tapes a run with the same gel left (simulate once, render per sensor), {} solved; {} episodes left their tapes and went on live; {} new tapes\n",
                t.replayed_steps, t.tapes_found, t.solved_steps, t.episodes_left, t.tapes_written
            ));
        }
        if self.backpressure_waits > 0 {
            s.push_str(&format!(
                "back-pressure: the writer fell behind {} times (slow disk?); nothing was dropped\n",
                self.backpressure_waits
            ));
        }
        s.push_str(&format!("output: {}\n", self.out.display()));
        if let Some(d) = &self.disk {
            s.push_str(&d.line());
        }
        for r in &self.retracts {
            s.push_str(&format!(
                "retracted: {} along the surface normal, {:.3} mm up to the approach height\n",
                r.label,
                rig_core::pose::translation_distance(&r.from, &r.to) * 1e3
            ));
        }
        for (id, why) in &self.failed {
            s.push_str(&format!("failed: trajectory {id}: {why}\n"));
        }
        if let Some(why) = &self.recording_stalled {
            s.push_str(&format!("recording stalled: {why}\n"));
        }
        if let Some(why) = &self.stopped {
            s.push_str(&format!("the run stopped early: {why}\n"));
        }
        s
    }
}
