//! `rig run`: drive the robot along the contact plan and record it, one file per trajectory.
//!
//! The order of things is fixed by safety: the config is validated and the whole plan is built
//! and checked against the envelope (every waypoint, [`Plan::build`]) before any connection is
//! opened. The output directory is checked next (an existing recording is only continued with
//! `--resume`), and only then does the rig connect, power the arm up, upload its control program
//! and move.
//!
//! With no lab rig configured (`robot.simulated = true`, as in the embedded default config), the
//! rig is the simulated one of `hardware-mocks` ([`SimRig`]), started in-process: a UR5e on
//! loopback RTDE, dashboard and secondary-interface sockets, a Nano17 behind a Net F/T on
//! loopback UDP (or an F/T controller on a pty), and a GelSight camera, all driven by one
//! contact scene whose indenter follows the simulated UR5e's TCP. Its clock may run faster than
//! real time (`--speed-factor`). The rig code that talks to them is the lab code.
//!
//! # Tasks
//!
//! - the **motion** (this task): per trajectory, the transit to its start at approach height,
//!   the tare of the F/T there (off the gel), then the four stages;
//! - the **robot state** (500 Hz) comes from the RTDE client's own task;
//! - the **F/T** and **camera** streams are each read on their own task ([`streams`]); frames
//!   are PNG-encoded on a dedicated thread;
//! - the **sync task** ([`collect`]) pairs every frame with the wrench interpolated at its
//!   time and queues the open trajectory's records on the [`Recorder`], whose writer thread
//!   writes the MCAP file. Every queue is bounded: a slow disk shows as back-pressure.
//!
//! # Time
//!
//! Every stream is stamped on the rig's clock when it arrives. The robot's states are placed at
//! their controller `timestamp` mapped to the host clock by an offset-and-drift estimator (free
//! of the delivery's jitter); the F/T's sample counter likewise, by the pairer's estimator; camera frames carry
//! host-clock stamps (V4L2 `CLOCK_MONOTONIC` buffer stamps mapped by the V4L2 source; the
//! simulated camera's stamps are on the shared clock), so the frame time is the stamp less the
//! configured exposure latency. Each frame's wrench is interpolated (cubic) at that time, and
//! labelled with the stage in progress and the interpolated TCP pose.
//!
//! # Safety
//!
//! The motion runs under watch of the streams' trips ([`Trip`]): a force above
//! `safety.max_force_n`, a saturated sensor, an F/T or camera stream that stalls or ends. A trip
//! stops the arm (`stopl`), retracts it straight up along the surface normal to the approach
//! height (when the envelope allows and the robot can move), and fails the trajectory with the
//! reason. A protective or emergency stop or a lost RTDE link fails the trajectory through the
//! robot client; the rig recovers and retracts before going on. `safety.on_failure` says
//! whether the run continues with the next trajectory or stops; a lost stream or a recording
//! error (disk full) always stops it.
//!
//! # Recording
//!
//! One MCAP file per trajectory (see [`crate::record`]), written as `.<id>.mcap.partial` and
//! renamed only once complete (fsynced), and a manifest whose entry per trajectory says
//! pending, complete or failed (with the reason). A failed trajectory's partial file is
//! removed. `--resume` skips complete trajectories and redoes the rest.
//!
//! Each trajectory's TCP path is also compared with the planned straight lines, and the largest
//! deviation and depth overshoot are reported.

pub mod collect;
pub mod streams;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, bail};
use hardware_mocks::camera::SimCameraConfig;
use hardware_mocks::rig_sim::{PhysicsConfig, SimFtFrontEnd, SimRig, SimRigOptions};
use indicatif::{ProgressBar, ProgressStyle};
use rig_core::clock::Clock;
use rig_core::config::{CameraKind, ForceSensorKind, OnFailure, RigConfig};
use rig_core::control::robot_mode;
use rig_core::indenter::Indenter;
use rig_core::pose::{self, Pose};
use tokio::sync::{mpsc, oneshot, watch};

use crate::camera::FrameSource;
use crate::force::{self, FrontEndSettings, FtStream};
use crate::plan::{Plan, Stage, StageName, Trajectory};
use crate::record::{self, Manifest, Recorder, RecorderConfig, SensorInfo};
use crate::robot::{Move, MovesLog, Robot, RobotEndpoints, RobotOptions};
use crate::sync::{DeviceTimebase, InterpMethod, PairerConfig};

use collect::{SyncCmd, SyncSettings, Tap, TrajStats};
use streams::{StreamSettings, Streams, Trip};

/// A fault injected into the simulated rig during a run (fault tests, operator drills).
#[derive(Debug, Clone, PartialEq)]
pub struct SimFault {
    pub kind: SimFaultKind,
    /// The trajectory (id) and stage in which it happens.
    pub trajectory: String,
    pub stage: StageName,
    /// Clock time after the stage's start, ms.
    pub after_ms: f64,
}

/// What [`SimFault`] injects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimFaultKind {
    /// The UR5e enters a protective stop.
    ProtectiveStop,
    /// The UR5e closes every connection and refuses new ones for 1 s of clock time.
    RtdeDrop,
    /// The F/T front end is unplugged (a serial front end closes its pty).
    FtUnplug,
    /// The camera stops sending frames.
    CameraStall,
}

impl std::str::FromStr for SimFault {
    type Err = String;
    /// `KIND@TRAJECTORY/STAGE[+MS]`, e.g. `protective-stop@p0-d0.4-a030/shear+200`.
    fn from_str(s: &str) -> Result<Self, String> {
        let usage = "expected KIND@TRAJECTORY/STAGE[+MS], e.g. protective-stop@p0-d0.4-a030/shear+200 \
                     (KIND: protective-stop, rtde-drop, ft-unplug, camera-stall)";
        let (kind, rest) = s.split_once('@').ok_or_else(|| format!("{s:?}: {usage}"))?;
        let kind = match kind {
            "protective-stop" => SimFaultKind::ProtectiveStop,
            "rtde-drop" => SimFaultKind::RtdeDrop,
            "ft-unplug" => SimFaultKind::FtUnplug,
            "camera-stall" => SimFaultKind::CameraStall,
            other => return Err(format!("unknown fault kind {other:?}: {usage}")),
        };
        let (traj, stage_ms) = rest
            .rsplit_once('/')
            .ok_or_else(|| format!("{s:?}: {usage}"))?;
        let (stage, ms) = match stage_ms.split_once('+') {
            Some((st, ms)) => (
                st,
                ms.parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| format!("{s:?}: bad delay {ms:?}: {usage}"))?,
            ),
            None => (stage_ms, 0.0),
        };
        let stage = match stage {
            "down" => StageName::Down,
            "shear" => StageName::Shear,
            "reverse" => StageName::Reverse,
            "up" => StageName::Up,
            other => return Err(format!("unknown stage {other:?}: {usage}")),
        };
        Ok(SimFault {
            kind,
            trajectory: traj.to_owned(),
            stage,
            after_ms: ms,
        })
    }
}

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
    /// Simulated rig only: the contact physics (see [`default_sim_physics`]).
    pub sim_physics: PhysicsConfig,
    /// Simulated rig only: how the simulated Nano17 is connected.
    pub sim_ft: SimFtFrontEnd,
    /// Simulated rig only: faults to inject.
    pub sim_faults: Vec<SimFault>,
    /// Sees every record written (the Foxglove live view).
    pub tap: Option<Tap>,
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
            .field("sim_faults", &self.sim_faults)
            .field("tap", &self.tap.is_some())
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
            sim_physics: default_sim_physics(),
            sim_ft: SimFtFrontEnd::NetFt,
            sim_faults: Vec::new(),
            tap: None,
        }
    }
}

/// The contact physics of a simulated run: the Winkler foundation with incremental friction
/// at 250 Hz of clock time. It is what a run can afford: one step costs tens of µs, so the
/// physics keeps up with a clock running several times faster than real time and every F/T
/// sample and frame sees the contact at its own time. The finite-layer model (more accurate,
/// see `rig bench sim`) costs milliseconds per step: the physics then falls behind the clock,
/// the F/T reads forces that are tens of ms stale, and the pairing cannot be checked against
/// the truth. Choose it (`RunOptions::sim_physics`) only with a slow clock.
pub fn default_sim_physics() -> PhysicsConfig {
    PhysicsConfig {
        contact: hardware_mocks::sim::ContactModel::Winkler,
        on_demand: true,
        ..PhysicsConfig::default()
    }
}

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
    /// simulated device or the runtime that fell behind (a stalled or busy host).
    pub clock_holds: rig_core::clock::HoldStats,
    /// Times a stream or the sync task waited for the writer (slow disk).
    pub backpressure_waits: u64,
    /// Frames received from the camera in the whole run (recorded or not).
    pub frames_received: u64,
    /// Frames the camera's sequence numbers say were lost in the whole run.
    pub frames_lost: u64,
}

/// Moves of one stage: a moveL to each waypoint after the first, with the waypoint it starts
/// from. Labels read `<trajectory>/<stage>/<k>` so an error names both.
pub fn stage_moves(t: &Trajectory, stage: &Stage) -> Vec<(Move, Pose)> {
    stage
        .waypoints
        .windows(2)
        .enumerate()
        .map(|(k, pair)| {
            (
                Move {
                    label: format!("{}/{}/{k}", t.id, stage.name),
                    pose: pair[1],
                    speed_m_s: stage.speed_mm_s * 1e-3,
                    accel_m_s2: stage.accel_mm_s2 * 1e-3,
                },
                pair[0],
            )
        })
        .collect()
}

/// Moves of one trajectory: every stage's [`stage_moves`], in order.
pub fn trajectory_moves(t: &Trajectory) -> Vec<(Move, Pose)> {
    t.stages.iter().flat_map(|s| stage_moves(t, s)).collect()
}
/// Distance (m) of `p` from the segment `a`–`b`.
fn segment_distance(p: &nalgebra::Vector3<f64>, a: &Pose, b: &Pose) -> f64 {
    let (a, b) = (a.position(), b.position());
    let ab = b - a;
    let len2 = ab.norm_squared();
    let s = if len2 > 0.0 {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + ab * s)).norm()
}

/// Compare a trajectory's logged TCP path with its plan.
pub fn assess(plan: &Plan, t: &Trajectory, log: &MovesLog) -> TrajectoryOutcome {
    let moves = trajectory_moves(t);
    let frame_inv = pose::pose_inv(&plan.surface_frame);
    let mut max_dev: f64 = 0.0;
    let mut max_over: f64 = 0.0;
    for s in &log.samples {
        let Some((m, from)) = moves.iter().find(|(m, _)| m.label == s.label) else {
            continue;
        };
        let p = s.state.actual_tcp_pose;
        max_dev = max_dev.max(segment_distance(&p.position(), from, &m.pose));
        // Depth below the undeformed surface, in the surface frame (its +z is the normal).
        let local = pose::pose_trans(&frame_inv, &p);
        max_over = max_over.max(-local.z * 1e3 - t.depth_mm);
    }
    let t_first = log.samples.first().map(|s| s.state.t_host_ns).unwrap_or(0);
    let t_last = log.samples.last().map(|s| s.state.t_host_ns).unwrap_or(0);
    TrajectoryOutcome {
        id: t.id.clone(),
        max_path_deviation_mm: max_dev * 1e3,
        max_depth_overshoot_mm: max_over.max(0.0),
        samples: log.samples.len(),
        poses_recorded: 0,
        duration_s: (t_last.saturating_sub(t_first)) as f64 * 1e-9,
        wall_time_s: 0.0,
        stats: TrajStats::default(),
    }
}

/// The recording to write into: the manifest to start the [`Recorder`] with, and the planned
/// trajectories an earlier run already recorded completely.
struct Output {
    manifest: Manifest,
    complete: Vec<String>,
}

/// Whether `dir` holds anything at all.
fn dir_has_entries(dir: &Path) -> anyhow::Result<bool> {
    match std::fs::read_dir(dir) {
        Ok(mut rd) => Ok(rd.next().is_some()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(false),
        Err(e) => Err(e).with_context(|| {
            format!(
                "cannot read the output directory {}; check its permissions or choose another --out",
                dir.display()
            )
        }),
    }
}

/// Check the output directory against `--resume` before anything moves, and work out what is
/// left to record. `fresh` is the manifest of a new recording of this plan.
fn prepare_output(
    dir: &Path,
    resume: bool,
    ids: &[String],
    fresh: Manifest,
) -> anyhow::Result<Output> {
    if dir.exists() && !dir.is_dir() {
        bail!(
            "--out {} is a file, not a directory; choose another --out",
            dir.display()
        );
    }
    let has_manifest = dir.join(record::MANIFEST_NAME).exists();
    let non_empty = dir_has_entries(dir)?;
    if !resume {
        if has_manifest && non_empty {
            bail!(
                "{} already holds a recording ({}); add --resume to continue it, or choose another --out",
                dir.display(),
                record::MANIFEST_NAME
            );
        }
        if non_empty {
            bail!(
                "{} is not empty and holds no {}, so it is not a rig recording; choose another (or an empty) --out",
                dir.display(),
                record::MANIFEST_NAME
            );
        }
        return Ok(Output {
            manifest: fresh,
            complete: Vec::new(),
        });
    }
    if !has_manifest {
        if non_empty {
            bail!(
                "--resume: {} holds files but no {}, so it is not a rig recording; choose another --out",
                dir.display(),
                record::MANIFEST_NAME
            );
        }
        eprintln!(
            "--resume: nothing recorded in {} yet; starting a new recording",
            dir.display()
        );
        return Ok(Output {
            manifest: fresh,
            complete: Vec::new(),
        });
    }
    // Compare before `resume` touches anything (it deletes stale partial files).
    let mut old = Manifest::load(dir).map_err(|e| {
        anyhow::anyhow!(
            "--resume: {e}; the recording in {} cannot be continued, choose another --out",
            dir.display()
        )
    })?;
    if old.indenter != fresh.indenter {
        bail!(
            "--resume: {} was recorded with indenter `{}`, not `{}`; resume it with --indenter {}, \
             or choose another --out for `{}`",
            dir.display(),
            old.indenter,
            fresh.indenter,
            old.indenter,
            fresh.indenter
        );
    }
    if old.config != fresh.config {
        bail!(
            "--resume: {} was recorded with a different rig config (differs in: {}; see config in \
             its {}); resume it with the same --config, or choose another --out",
            dir.display(),
            differing_keys(&old.config, &fresh.config),
            record::MANIFEST_NAME
        );
    }
    let verdict = record::resume(dir, ids)
        .with_context(|| format!("--resume: cannot inspect {}", dir.display()))?;
    for name in &verdict.removed_partials {
        eprintln!("--resume: removed the interrupted recording {name}");
    }
    for (id, why) in &verdict.redo {
        tracing::debug!("--resume: {id} is redone ({why})");
    }
    eprintln!(
        "--resume: {} of {} trajectories already complete in {}; {} to record",
        verdict.complete.len(),
        ids.len(),
        dir.display(),
        verdict.redo.len()
    );
    // Every planned trajectory is listed, so an unfinished run shows what is still pending.
    for id in ids {
        old.entry_mut(id);
    }
    Ok(Output {
        manifest: old,
        complete: verdict.complete,
    })
}

/// The top-level config sections in which two configs differ, for an operator message.
fn differing_keys(a: &serde_json::Value, b: &serde_json::Value) -> String {
    let (Some(a), Some(b)) = (a.as_object(), b.as_object()) else {
        return "the whole config".into();
    };
    let mut keys: Vec<&str> = a
        .keys()
        .chain(b.keys())
        .map(String::as_str)
        .filter(|k| a.get(*k) != b.get(*k))
        .collect();
    keys.sort_unstable();
    keys.dedup();
    if keys.is_empty() {
        "the whole config".into()
    } else {
        keys.iter()
            .map(|k| format!("[{k}]"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// Why a trajectory failed.
enum TrajectoryError {
    /// The robot could not do it (fault, stop, link loss): the run may continue after recovery.
    Motion(String),
    /// A stream tripped the safety watch; the arm was stopped.
    Trip(Trip),
    /// The recording failed (disk full, I/O error): the run stops.
    Record(String),
}

impl TrajectoryError {
    fn reason(&self) -> String {
        match self {
            TrajectoryError::Motion(r) | TrajectoryError::Record(r) => r.clone(),
            TrajectoryError::Trip(t) => t.to_string(),
        }
    }
}

/// Everything a trajectory needs besides the robot.
struct Ctx<'a> {
    config: &'a RigConfig,
    plan: &'a Plan,
    clock: &'a Clock,
    rec: &'a Recorder,
    streams: &'a Streams,
    sync: &'a mpsc::UnboundedSender<SyncCmd>,
    tare_samples: u64,
    tare_timeout: Duration,
    /// Stage starts, announced to the fault injector (simulated rig).
    stage_tx: &'a watch::Sender<Option<(String, StageName)>>,
}

/// Run `fut` (a motion) unless a trip comes first.
async fn guarded<T>(
    trips: &mut watch::Receiver<Option<Trip>>,
    fut: impl std::future::Future<Output = Result<T, crate::robot::MotionError>>,
) -> Result<T, TrajectoryError> {
    if let Some(t) = trips.borrow_and_update().clone() {
        return Err(TrajectoryError::Trip(t));
    }
    tokio::select! {
        r = fut => r.map_err(|e| TrajectoryError::Motion(e.to_string())),
        t = trips.wait_for(|t| t.is_some()) => Err(TrajectoryError::Trip(
            t.ok().and_then(|t| t.clone()).unwrap_or(Trip::FtLost("the safety watch ended".into())),
        )),
    }
}

/// Transit to `t`'s start, tare, then run and record its stages. The recording is begun.
async fn run_trajectory(
    robot: &mut Robot,
    ctx: &Ctx<'_>,
    t: &Trajectory,
    transit: Option<Move>,
) -> Result<(MovesLog, TrajStats), TrajectoryError> {
    let mut trips = ctx.streams.trips();
    if let Some(transit) = transit {
        guarded(&mut trips, robot.run_moves(std::slice::from_ref(&transit))).await?;
    }
    // Tare at approach height, off the gel; the stream keeps flowing meanwhile.
    if ctx.tare_samples > 0 {
        match ctx
            .clock
            .timeout(ctx.tare_timeout, ctx.streams.tare(ctx.tare_samples))
            .await
        {
            Ok(Ok(r)) => {
                tracing::debug!(
                    "{}: tared over {} samples, bias F = {:.4?} N, noise σ = {:.4?}",
                    t.id,
                    r.wrench.n,
                    &r.wrench.mean[..3],
                    &r.wrench.std[..3]
                );
                // A few samples' margin: every sample a frame after `Begin` is paired with
                // comes after the new bias took effect.
                ctx.clock.sleep(Duration::from_millis(10)).await;
            }
            Ok(Err(e)) => {
                return Err(TrajectoryError::Trip(Trip::FtLost(format!(
                    "tare failed: {e}"
                ))));
            }
            Err(_) => {
                return Err(TrajectoryError::Trip(Trip::FtStalled {
                    after_ms: ctx.tare_timeout.as_secs_f64() * 1e3,
                }));
            }
        }
    }
    let _ = ctx.sync.send(SyncCmd::Begin);
    let mut log = MovesLog::default();
    for stage in &t.stages {
        let moves: Vec<Move> = stage_moves(t, stage).into_iter().map(|(m, _)| m).collect();
        let t0 = ctx.clock.now_ns();
        let _ = ctx.sync.send(SyncCmd::Stage {
            t_ns: t0,
            stage: stage.name,
        });
        ctx.stage_tx.send_replace(Some((t.id.clone(), stage.name)));
        guarded(&mut trips, robot.run_moves_logged(&moves, &mut log)).await?;
    }
    let t_end_ns = log
        .samples
        .last()
        .map_or_else(|| ctx.clock.now_ns(), |s| s.state.t_host_ns);
    let (reply, rx) = oneshot::channel();
    let _ = ctx.sync.send(SyncCmd::End { t_end_ns, reply });
    // The last frames and samples are still coming: a stream that stalls now fails it too.
    let stats = tokio::select! {
        r = rx => r
            .map_err(|_| TrajectoryError::Record("the sync task stopped".into()))?
            .map_err(TrajectoryError::Record)?,
        t = trips.wait_for(|t| t.is_some()) => {
            return Err(TrajectoryError::Trip(
                t.ok().and_then(|t| t.clone()).unwrap_or(Trip::FtLost("the safety watch ended".into())),
            ));
        }
    };
    Ok((log, stats))
}

/// Stop the sync task's writing of the open trajectory.
async fn abort_sync(sync: &mpsc::UnboundedSender<SyncCmd>) {
    let (reply, rx) = oneshot::channel();
    if sync.send(SyncCmd::Abort { reply }).is_ok() {
        let _ = rx.await;
    }
}

/// Move straight up (surface normal) from wherever the arm is to the approach height, keeping
/// its orientation. Refused when the target leaves the envelope.
async fn retract(
    robot: &mut Robot,
    config: &RigConfig,
    plan: &Plan,
    label: &str,
) -> anyhow::Result<()> {
    let here = robot
        .state()
        .map(|s| s.actual_tcp_pose)
        .context("no robot state to retract from")?;
    let frame = plan.surface_frame;
    let mut local = pose::pose_trans(&pose::pose_inv(&frame), &here);
    let approach = config.plan.approach_height_mm * 1e-3;
    if local.z >= approach - 1e-6 {
        return Ok(());
    }
    local.z = approach;
    let target = pose::pose_trans(&frame, &local);
    if !config
        .safety
        .envelope
        .contains([target.x, target.y, target.z])
    {
        bail!(
            "the retract target {:?} is outside the safety envelope; jog the arm up by hand",
            target.to_array()
        );
    }
    robot
        .run_moves(&[Move {
            label: format!("{label}/retract"),
            pose: target,
            speed_m_s: config.plan.up.speed_mm_s * 1e-3,
            accel_m_s2: config.plan.up.accel_mm_s2 * 1e-3,
        }])
        .await?;
    Ok(())
}

/// Handles of the simulated rig that faults are injected through.
struct FaultTargets {
    ur5e: Arc<hardware_mocks::ur5e::Ur5e>,
    ft: Arc<hardware_mocks::nano17::Faults>,
    camera: Option<hardware_mocks::camera::CameraFaults>,
}

/// Injects `faults` when their stage starts (plus their delay).
async fn inject_faults(
    faults: Vec<SimFault>,
    targets: FaultTargets,
    clock: Clock,
    mut stages: watch::Receiver<Option<(String, StageName)>>,
) {
    let mut pending = faults;
    while !pending.is_empty() {
        if stages.changed().await.is_err() {
            return;
        }
        let Some((id, stage)) = stages.borrow_and_update().clone() else {
            continue;
        };
        let (now, later): (Vec<_>, Vec<_>) = pending
            .into_iter()
            .partition(|f| f.trajectory == id && f.stage == stage);
        pending = later;
        for f in now {
            let (ur, ft, cam, clock) = (
                targets.ur5e.clone(),
                targets.ft.clone(),
                targets.camera.clone(),
                clock.clone(),
            );
            tokio::spawn(async move {
                clock
                    .sleep(Duration::from_secs_f64(f.after_ms * 1e-3))
                    .await;
                tracing::warn!(
                    "simulated fault: {:?} in {}/{}",
                    f.kind,
                    f.trajectory,
                    f.stage
                );
                match f.kind {
                    SimFaultKind::ProtectiveStop => ur.faults().protective_stop(),
                    SimFaultKind::RtdeDrop => ur.faults().drop_connections(Duration::from_secs(1)),
                    SimFaultKind::FtUnplug => ft.unplug(),
                    SimFaultKind::CameraStall => {
                        if let Some(c) = cam {
                            c.set_stalled(true);
                        }
                    }
                }
            });
        }
    }
}

/// The F/T stream, the camera and the ground truth of the rig.
struct Devices {
    ft: FtStream,
    camera: Option<Box<dyn FrameSource>>,
    truth: Option<hardware_mocks::truth::SharedWrenchSource>,
    /// Simulated camera only: its fault injection.
    camera_faults: Option<hardware_mocks::camera::CameraFaults>,
    /// The F/T's full range and front end, for the manifest.
    calibration: serde_json::Value,
    ft_rate_hz: f64,
}

async fn open_sim_devices(
    config: &RigConfig,
    sim: &mut SimRig,
    clock: &Clock,
    front_end: SimFtFrontEnd,
) -> anyhow::Result<Devices> {
    let fs = config
        .force_sensor
        .as_ref()
        .context("the simulated rig needs a [force_sensor] section (kind = \"sim\")")?;
    let mut settings = FrontEndSettings::from_config(fs)?;
    let ft = match front_end {
        SimFtFrontEnd::NetFt => {
            let addr = sim
                .netft_addr()
                .context("the simulated Net F/T is not running")?;
            force::netft::open(&addr.to_string(), false, settings.clone(), clock.clone()).await?
        }
        SimFtFrontEnd::Serial => {
            let path = sim
                .ft_serial_path()
                .context("the simulated F/T controller is not running")?
                .to_string_lossy()
                .into_owned();
            // The simulated controller's counts (its factory defaults).
            let mock = hardware_mocks::nano17::serial::SerialMockConfig::default();
            settings.counts_per_force = mock.counts_per_force;
            settings.counts_per_torque = mock.counts_per_torque;
            force::serial::open(
                force::serial::SerialOptions {
                    port: path,
                    baud: 921_600,
                    output: rig_core::ft::serial::OutputMode::Binary,
                    device_bias: false,
                },
                settings.clone(),
                clock.clone(),
            )
            .await?
        }
    };
    let mut camera_faults = None;
    let camera: Option<Box<dyn FrameSource>> = match (&config.camera, sim.take_camera()) {
        (Some(c), Some(cam)) => {
            camera_faults = Some(cam.faults());
            Some(Box::new(crate::camera::sim::SimFrameSource::new(
                cam,
                clock.clone(),
                c.width_px,
                c.height_px,
            )))
        }
        _ => None,
    };
    Ok(Devices {
        calibration: calibration_json(&settings, &ft.description),
        ft,
        camera,
        camera_faults,
        truth: Some(Arc::new(sim.physics().clone())),
        ft_rate_hz: settings.rate_hz,
    })
}

fn calibration_json(settings: &FrontEndSettings, description: &str) -> serde_json::Value {
    serde_json::json!({
        "front_end": description,
        "max_loads": settings.max_loads,
        "max_loads_units": "Fx Fy Fz in N, Tx Ty Tz in N·mm",
        "counts_per_force": settings.counts_per_force,
        "counts_per_torque": settings.counts_per_torque,
        "rate_hz": settings.rate_hz,
        "calibration_file": settings.calibration.as_ref().map(|c| serde_json::json!({
            "serial": c.serial,
            "max_loads": c.max_loads,
        })),
    })
}

async fn open_lab_devices(config: &RigConfig, clock: &Clock) -> anyhow::Result<Devices> {
    let fs = config.force_sensor.as_ref().context(
        "the rig config has no [force_sensor]: `rig run` records forces; add the section (see \
         rig-configs/lab-example.toml)",
    )?;
    if fs.kind == ForceSensorKind::Sim {
        bail!(
            "force_sensor.kind = \"sim\" needs the simulated rig (robot.simulated = true): a lab \
             robot pressing on a simulated sensor would record nothing real"
        );
    }
    let settings = FrontEndSettings::from_config(fs)?;
    let ft = force::open(fs, clock.clone()).await?;
    let camera: Option<Box<dyn FrameSource>> = match &config.camera {
        None => None,
        Some(c) if c.kind == CameraKind::Sim => {
            bail!("camera.kind = \"sim\" needs the simulated rig (robot.simulated = true)")
        }
        Some(c) => Some(open_v4l2(c, clock)?),
    };
    Ok(Devices {
        calibration: calibration_json(&settings, &ft.description),
        ft,
        camera,
        camera_faults: None,
        truth: None,
        ft_rate_hz: settings.rate_hz,
    })
}

#[cfg(feature = "v4l")]
fn open_v4l2(
    c: &rig_core::config::CameraConfig,
    clock: &Clock,
) -> anyhow::Result<Box<dyn FrameSource>> {
    use crate::camera::v4l2;
    let device = c
        .device
        .as_deref()
        .context("camera.device is required for a V4L2 camera (e.g. /dev/video0)")?;
    let src = v4l2::device::open(
        device,
        clock.clone(),
        &v4l2::Request::new(c.width_px, c.height_px, c.fps),
        &v4l2::V4l2Options::default(),
    )?;
    Ok(Box::new(src))
}

#[cfg(not(feature = "v4l"))]
fn open_v4l2(
    _c: &rig_core::config::CameraConfig,
    _clock: &Clock,
) -> anyhow::Result<Box<dyn FrameSource>> {
    bail!("this rig binary was built without V4L2 support; rebuild with `--features v4l`")
}

/// Build and check the plan, check the output directory, then run and record the plan on the
/// configured rig (the simulated one when `config.robot.simulated`).
pub async fn run(
    config: &RigConfig,
    indenter: &Indenter,
    opts: &RunOptions,
) -> anyhow::Result<RunSummary> {
    let wall0 = std::time::Instant::now();
    // Safety first: nothing connects before every waypoint has been checked.
    let plan = Plan::build(config, indenter)?;
    let n = opts
        .limit
        .unwrap_or(usize::MAX)
        .min(plan.trajectories.len());
    let planned = &plan.trajectories[..n];
    if planned.is_empty() {
        bail!("the plan has no trajectories to run (--limit 0?)");
    }
    let simulated = config.robot.simulated;
    if simulated && !(opts.speed_factor.is_finite() && opts.speed_factor > 0.0) {
        bail!(
            "--speed-factor must be a positive number, got {}",
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
    let speed = if simulated { opts.speed_factor } else { 1.0 };

    let ids: Vec<String> = planned.iter().map(|t| t.id.clone()).collect();
    let role = serde_json::to_value(config.sensor.role)
        .ok()
        .and_then(|v| v.as_str().map(str::to_owned))
        .unwrap_or_else(|| "source".into());
    let config_json =
        serde_json::to_value(config).context("serialising the rig config for the manifest")?;
    let mk_manifest = |calibration: serde_json::Value| {
        Manifest::new(
            &plan.indenter,
            SensorInfo {
                id: plan.sensor_id.clone(),
                role: role.clone(),
            },
            config_json.clone(),
            calibration,
            &ids,
        )
    };
    // Checked before anything starts; the calibration is filled in once the F/T is open.
    let output = prepare_output(
        &opts.out,
        opts.resume,
        &ids,
        mk_manifest(serde_json::Value::Null),
    )?;
    let todo: Vec<&Trajectory> = planned
        .iter()
        .filter(|t| !output.complete.contains(&t.id))
        .collect();
    let mut summary = RunSummary {
        simulated,
        out: opts.out.clone(),
        skipped: n - todo.len(),
        ..Default::default()
    };
    let Some(first) = todo.first() else {
        eprintln!(
            "all {n} trajectories are already recorded in {}; nothing to do",
            opts.out.display()
        );
        return Ok(summary);
    };
    let home = first.stages[0].waypoints[0];

    // The rig: the simulated one in-process, or the lab's.
    let clock = if simulated {
        Clock::governed(opts.speed_factor)
    } else {
        Clock::system()
    };
    let mut sim = None;
    let (endpoints, devices) = if simulated {
        // The simulated camera stamps its buffers on the shared clock, as a UVC camera under
        // V4L2 stamps them on the host's CLOCK_MONOTONIC. It keeps as many buffers as give the
        // reader the real-time slack the V4L2 reader's queue has at 1×: at ×10, 16 buffers were
        // 64 ms of real time, and a busy CI machine once let the reader fall that far behind,
        // so a frame was overrun before the governor could slow the clock.
        let real_slack = crate::camera::v4l2::V4l2Options::default().queue_len as f64;
        let buffers = (real_slack * opts.speed_factor).ceil().clamp(16.0, 256.0) as usize;
        let camera = config.camera.as_ref().map(|c| SimCameraConfig {
            device_offset_ns: 0,
            queue_len: buffers,
            ..SimCameraConfig::ideal(c.fps)
        });
        let sim_opts = SimRigOptions {
            home_pose: Some(home),
            camera,
            initial_robot_mode: robot_mode::POWER_OFF,
            physics: opts.sim_physics.clone(),
            ft_front_end: opts.sim_ft,
            ..SimRigOptions::for_config(config)
        };
        let mut rig = SimRig::start(config, Arc::new(indenter.clone()), clock.clone(), sim_opts)
            .await
            .context("starting the simulated rig on loopback")?;
        let ep = RobotEndpoints {
            rtde: rig.ur5e().rtde_addr(),
            dashboard: rig.ur5e().dashboard_addr(),
            script: rig.ur5e().script_addr(),
        };
        let devices = open_sim_devices(config, &mut rig, &clock, opts.sim_ft).await?;
        tracing::info!(
            "simulated rig: UR5e RTDE {}, {}, camera {}; clock ×{}",
            ep.rtde,
            devices.ft.description,
            if devices.camera.is_some() {
                "on"
            } else {
                "off"
            },
            opts.speed_factor
        );
        sim = Some(rig);
        (ep, devices)
    } else {
        let ip = tokio::net::lookup_host((config.robot.host.as_str(), config.robot.rtde_port))
            .await
            .with_context(|| format!("resolving robot.host {:?}", config.robot.host))?
            .next()
            .with_context(|| format!("robot.host {:?} has no address", config.robot.host))?
            .ip();
        let ep = RobotEndpoints {
            rtde: std::net::SocketAddr::new(ip, config.robot.rtde_port),
            dashboard: std::net::SocketAddr::new(ip, config.robot.dashboard_port),
            script: std::net::SocketAddr::new(ip, config.robot.script_port),
        };
        (ep, open_lab_devices(config, &clock).await?)
    };

    // The recorder (and the manifest, every trajectory pending) starts before the robot's
    // program is armed, so even a run that cannot reach the robot is continued with --resume.
    let mut manifest = output.manifest;
    manifest.calibration = devices.calibration.clone();
    let rec = Arc::new(
        Recorder::start(&opts.out, manifest, RecorderConfig::default()).with_context(|| {
            format!(
                "cannot record into {}; check the path and its permissions, or choose another --out",
                opts.out.display()
            )
        })?,
    );

    // The watchdog guards against the rig going silent in real time. On the simulated rig the
    // controller counts clock time, which runs `speed_factor` times faster, so the same real
    // tolerance needs a rate that many times lower.
    // A link lost mid-trajectory fails it (its streams have a hole and the arm paused in the
    // gel); the client reconnects and the run recovers and retracts before going on.
    let robot_opts = RobotOptions {
        frequency_hz: Some(config.robot.rtde_frequency_hz),
        watchdog_min_hz: config.robot.watchdog_min_hz / speed,
        link_loss: crate::robot::LinkLossPolicy::Abort,
        ..Default::default()
    };
    let mut robot = Robot::connect(endpoints, robot_opts, clock.clone())
        .await
        .context("connecting to the robot")?;
    robot.prepare().await.context("preparing the robot")?;

    // Streams and the sync task.
    let camera_fps = config.camera.as_ref().map_or(30.0, |c| c.fps);
    let (ev_tx, ev_rx) = mpsc::channel(8192);
    let truth = devices.truth.clone();
    let ft_faults = sim.as_ref().map(|s| s.ft().faults().clone());
    let sim_cam_faults = devices.camera_faults.clone();
    let streams = Streams::start(
        devices.ft,
        devices.camera,
        truth,
        clock.clone(),
        StreamSettings {
            max_force_n: config.safety.max_force_n,
            // Stall limits in real time (a busy machine), expressed in clock time.
            ft_stall: Duration::from_secs_f64(0.5 * speed),
            camera_stall: Duration::from_secs_f64((0.5f64).max(10.0 / camera_fps) * speed),
        },
        ev_tx,
    );
    let (sync_tx, sync_rx) = mpsc::unbounded_channel();
    let pairer = PairerConfig {
        method: InterpMethod::Cubic,
        frame_timebase: DeviceTimebase::HostNanos,
        wrench_timebase: DeviceTimebase::Counter {
            bits: 63,
            nominal_hz: devices.ft_rate_hz,
        },
        // A sample counter never jumps: a late burst of samples is a delivery stall (a busy
        // machine; tens of ms of clock time on a fast simulated clock), not a new clock.
        wrench_clock: crate::sync::EstimatorConfig {
            jump_tolerance_ns: 1e9 * speed,
            ..crate::sync::EstimatorConfig::default()
        },
        ..PairerConfig::default()
    };
    let sync_task = collect::spawn(
        rec.clone(),
        opts.tap.clone(),
        SyncSettings {
            pairer,
            grace_ns: 20_000_000,
            // Longer than the stall limits, so a stalled stream trips first and is named.
            end_timeout: Duration::from_secs_f64(2.0 * speed),
            camera: config.camera.is_some(),
            // The controller's clock is a real-time clock: no jumps from delivery stalls.
            rtde_clock: crate::sync::EstimatorConfig {
                jump_tolerance_ns: 1e9 * speed,
                ..crate::sync::EstimatorConfig::default()
            },
        },
        clock.clone(),
        ev_rx,
        robot.rtde().samples(),
        sync_rx,
    );
    let governor = (simulated && config.camera.is_some()).then(|| {
        tokio::spawn(govern(
            clock.clone(),
            opts.speed_factor,
            streams.counters().clone(),
            1e9 / camera_fps,
        ))
    });
    let (stage_tx, stage_rx) = watch::channel(None);
    let injector = match (&sim, opts.sim_faults.is_empty()) {
        (Some(s), false) => Some(tokio::spawn(inject_faults(
            opts.sim_faults.clone(),
            FaultTargets {
                ur5e: s.ur5e_arc(),
                ft: ft_faults.clone().expect("simulated F/T"),
                camera: sim_cam_faults,
            },
            clock.clone(),
            stage_rx,
        ))),
        _ => None,
    };

    let bar = if opts.progress {
        let bar = ProgressBar::new(n as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:25} {pos}/{len} trajectories  ETA {eta}  {msg}",
            )
            .expect("static template"),
        );
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    } else {
        ProgressBar::hidden()
    };
    bar.inc(summary.skipped as u64);

    let ctx = Ctx {
        config,
        plan: &plan,
        clock: &clock,
        rec: &rec,
        streams: &streams,
        sync: &sync_tx,
        tare_samples: config
            .force_sensor
            .as_ref()
            .map_or(0, |f| u64::from(f.tare_samples)),
        tare_timeout: Duration::from_secs_f64(5.0 * speed),
        stage_tx: &stage_tx,
    };
    if ctx.tare_samples == 0 {
        // No tare asked for: the readings are taken as they are, limit included.
        streams.arm_force_limit();
    }
    let t0 = clock.now_ns();
    let transit_speed = config.plan.up.speed_mm_s * 1e-3;
    let transit_accel = config.plan.up.accel_mm_s2 * 1e-3;
    let mut attempted = 0usize;
    for t in &todo {
        attempted += 1;
        let wall_start = std::time::Instant::now();
        let start = t.stages[0].waypoints[0];
        let here = robot.state().map(|s| s.actual_tcp_pose).unwrap_or(home);
        let transit = (pose::translation_distance(&here, &start) > 1e-6
            || pose::rotation_distance(&here, &start) > 1e-6)
            .then(|| Move {
                label: format!("{}/transit", t.id),
                pose: start,
                speed_m_s: transit_speed,
                accel_m_s2: transit_accel,
            });
        let result = match ctx.rec.begin(&t.id).await {
            Ok(()) => run_trajectory(&mut robot, &ctx, t, transit).await,
            Err(e) => Err(TrajectoryError::Record(e.to_string())),
        };
        let result = match result {
            Ok((log, stats)) => match rec.finish(stats.frames_dropped).await {
                Ok(counts) => Ok((log, stats, counts)),
                Err(e) => Err(TrajectoryError::Record(e.to_string())),
            },
            Err(e) => Err(e),
        };
        match result {
            Ok((log, stats, counts)) => {
                let mut outcome = assess(&plan, t, &log);
                outcome.poses_recorded = counts.poses;
                outcome.wall_time_s = wall_start.elapsed().as_secs_f64();
                bar.set_message(progress_message(&stats, streams.counters()));
                outcome.stats = stats;
                summary.trajectories.push(outcome);
                bar.inc(1);
            }
            Err(e) => {
                abort_sync(&sync_tx).await;
                let reason = format!("{}: {}", t.id, e.reason());
                tracing::error!("trajectory {reason}");
                bar.suspend(|| eprintln!("trajectory {reason}"));
                // The manifest marks it failed; its partial file is removed.
                if let Err(ae) = rec.abort(&e.reason()).await {
                    tracing::error!("trajectory {}: could not mark it failed: {ae}", t.id);
                }
                summary.failed.push((t.id.clone(), e.reason()));
                if summary.failure.is_none() {
                    summary.failure = Some((t.id.clone(), e.reason()));
                }
                bar.inc(1);
                let stop = after_failure(&mut robot, &ctx, t, &e).await;
                if let Some(why) = stop {
                    summary.stopped = Some(why);
                    break;
                }
            }
        }
    }
    bar.finish_and_clear();
    summary.not_attempted = todo.len() - attempted;
    summary.clock_time_s = (clock.now_ns() - t0) as f64 * 1e-9;
    summary.clock_holds = clock.hold_stats();
    let c = streams.counters().clone();
    summary.frames_received = c.frames();
    summary.frames_lost = c.frames_dropped();
    summary.backpressure_waits = c
        .backpressure_waits
        .load(std::sync::atomic::Ordering::Relaxed)
        + rec
            .stats()
            .backpressure_waits
            .load(std::sync::atomic::Ordering::Relaxed);

    // Orderly shutdown: streams, sync task, recorder (every queued record written), rig.
    if let Some(i) = injector {
        i.abort();
    }
    if let Some(g) = governor {
        g.abort();
    }
    streams.shutdown().await;
    drop(sync_tx);
    let _ = sync_task.await;
    let rec = Arc::into_inner(rec).context("the recorder is still in use at the end of the run")?;
    rec.close()
        .await
        .with_context(|| format!("finishing the recording in {}", opts.out.display()))?;
    drop(robot);
    if let Some(s) = sim {
        s.shutdown().await;
    }
    summary.wall_time_s = wall0.elapsed().as_secs_f64();
    // The arm is left above the gel: every trajectory ends its Up stage at approach height.
    Ok(summary)
}

/// Keeps the simulated clock as fast as the simulated camera can follow, up to `max`: the
/// camera renders each frame after its capture time, so when rendering falls behind, the clock
/// slows down (every simulated device follows it) and frames stay on time; when it catches up,
/// the clock speeds up again. Lag is measured in frame periods between the clock and the
/// newest frame handed to the recording.
async fn govern(clock: Clock, max: f64, counters: Arc<streams::StreamCounters>, period_ns: f64) {
    let floor = max.min(0.25);
    let mut rate = clock.rate();
    let mut last_stamp = 0;
    let mut last_advance = std::time::Instant::now();
    loop {
        // Real time: the governor watches the machine, not the simulation.
        tokio::time::sleep(Duration::from_millis(20)).await;
        let newest = counters
            .newest_frame_stamp_ns
            .load(std::sync::atomic::Ordering::Relaxed);
        if newest == 0 {
            continue;
        }
        if newest != last_stamp {
            last_stamp = newest;
            last_advance = std::time::Instant::now();
        } else if last_advance.elapsed() > Duration::from_millis(300) {
            // No frame for a long real time is not slowness but a stalled camera: the stall
            // watch handles that, and slowing the clock would only delay its verdict.
            continue;
        }
        let lag = clock.now_ns().saturating_sub(newest) as f64 / period_ns;
        let next = if lag > 8.0 {
            rate * 0.6
        } else if lag > 4.0 {
            rate * 0.9
        } else if lag < 2.5 {
            rate * 1.05
        } else {
            rate
        }
        .clamp(floor, max);
        if (next - rate).abs() > 1e-6 * max {
            clock.set_rate(next);
            rate = next;
        }
    }
}

/// After a failed trajectory: stop and retract the arm as far as it is safe, and say whether
/// the run must stop (and why).
async fn after_failure(
    robot: &mut Robot,
    ctx: &Ctx<'_>,
    t: &Trajectory,
    e: &TrajectoryError,
) -> Option<String> {
    let continue_ok = ctx.config.safety.on_failure == OnFailure::Continue;
    match e {
        TrajectoryError::Trip(trip) => {
            if let Err(se) = robot.stop().await {
                tracing::error!("{}: stopping the arm: {se}", t.id);
            }
            if let Err(re) = retract(robot, ctx.config, ctx.plan, &t.id).await {
                return Some(format!(
                    "{}: the arm could not be retracted after the stop ({re}); inspect the rig",
                    t.id
                ));
            }
            let left = ctx.streams.clear_trip();
            if trip.is_fatal() || left.is_some() {
                return Some(format!(
                    "{}: {}; nothing more can be recorded",
                    t.id,
                    left.as_ref().unwrap_or(trip)
                ));
            }
            (!continue_ok).then(|| format!("{}: safety.on_failure = \"stop\"", t.id))
        }
        TrajectoryError::Motion(_) => {
            let safety_stop = robot.state().is_some_and(|s| !s.safety_ok());
            if safety_stop && !continue_ok {
                // UR: always inspect the cause of a protective stop before unlocking it. The
                // rig does not unlock it on the operator's behalf unless told to continue.
                return Some(format!(
                    "{}: the robot is in a safety stop, possibly touching the gel; inspect the \
                     cause, unlock it on the teach pendant, jog the arm up, then --resume",
                    t.id
                ));
            }
            // Recover (unlock a protective stop once UR's 5 s delay has passed, restart the
            // program), then leave the gel before anything else moves.
            let mut attempt = 0;
            while let Err(re) = robot.recover().await {
                attempt += 1;
                if attempt > 8 {
                    return Some(format!("{}: recovery failed: {re}", t.id));
                }
                tracing::info!(
                    "{}: recovery not possible yet ({re}); retrying in 1 s",
                    t.id
                );
                ctx.clock.sleep(Duration::from_secs(1)).await;
            }
            if let Err(re) = retract(robot, ctx.config, ctx.plan, &t.id).await {
                return Some(format!(
                    "{}: the arm could not be retracted after recovery ({re}); inspect the rig",
                    t.id
                ));
            }
            // A stream that died meanwhile ends the run.
            if let Some(trip) = ctx.streams.clear_trip() {
                return Some(format!("{}: {trip}; nothing more can be recorded", t.id));
            }
            (!continue_ok).then(|| format!("{}: safety.on_failure = \"stop\"", t.id))
        }
        TrajectoryError::Record(r) => {
            // The arm finished its stages (a recording error shows at the end) or was stopped
            // by the robot's own error; make sure it is off the gel.
            let _ = retract(robot, ctx.config, ctx.plan, &t.id).await;
            Some(format!("{}: the recording failed ({r})", t.id))
        }
    }
}

fn progress_message(s: &TrajStats, c: &streams::StreamCounters) -> String {
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
            "recorded: {frames} frames ({dropped} dropped), {wrench} wrench samples, {poses} TCP poses\n\
             pairing: {ok} ok, {held} held at a stream end, {refused} refused; sync error p50 {:.3} ms, p99 {:.3} ms\n",
            p50 * 1e-6,
            p99 * 1e-6
        ));
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
                "simulated time held {} times ({:.2} s of real time; last for the {}): the host fell behind\n",
                h.holds,
                h.held_s,
                h.last_holder.unwrap_or("a device")
            ));
        }
        if self.backpressure_waits > 0 {
            s.push_str(&format!(
                "back-pressure: the writer fell behind {} times (slow disk?); nothing was dropped\n",
                self.backpressure_waits
            ));
        }
        s.push_str(&format!("output: {}\n", self.out.display()));
        for (id, why) in &self.failed {
            s.push_str(&format!("failed: trajectory {id}: {why}\n"));
        }
        if let Some(why) = &self.stopped {
            s.push_str(&format!("the run stopped early: {why}\n"));
        }
        s
    }
}
