//! One trajectory of a run: its moves, its recording, what goes wrong, and what is done about
//! it.
//!
//! [`record`] clears the gel (a retract along the surface normal if the arm is below the
//! approach height), checks and runs the transit to the trajectory's start at approach height,
//! tares the F/T there, runs the four stages under watch of the supervisor's trips
//! ([`guarded`]) while the collector writes their records, completes the file and compares the
//! logged TCP path with the planned lines ([`assess`]). [`fail`] handles a failure in safety's
//! order: the stop first (after a trip), then [`after_failure`] recovers and retracts the arm
//! as far as is safe and says whether the run must stop, and only then is the open file
//! aborted and marked failed.

use std::time::Duration;

use anyhow::{Context, bail};
use indicatif::ProgressBar;
use rig_core::clock::Clock;
use rig_core::config::{OnFailure, RigConfig};
use rig_core::pose::{self, Pose};
use tokio::sync::{mpsc, oneshot, watch};

use super::collector::{CollectCmd, TrajStats};
use super::events::Trip;
use super::streams::Streams;
use super::summary::{Retract, TrajectoryOutcome};
use crate::plan::{Plan, Stage, StageName, Trajectory};
use crate::record::Recorder;
use crate::robot::{Move, MovesLog, Robot};
use crate::simrig::RunningSimRig;

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

/// Distance (m) of `p` from the planned segment of the move labelled `label`.
fn deviation(moves: &[(Move, Pose)], label: &str, p: &Pose) -> Option<f64> {
    let (m, from) = moves.iter().find(|(m, _)| m.label == label)?;
    Some(segment_distance(&p.position(), from, &m.pose))
}

/// Compare a trajectory's logged TCP path with its plan.
pub fn assess(plan: &Plan, t: &Trajectory, log: &MovesLog) -> TrajectoryOutcome {
    let moves = trajectory_moves(t);
    let frame_inv = pose::pose_inv(&plan.surface_frame);
    let mut max_dev: f64 = 0.0;
    let mut max_over: f64 = 0.0;
    for s in &log.samples {
        let p = s.state.actual_tcp_pose;
        let Some(d) = deviation(&moves, &s.label, &p) else {
            continue;
        };
        max_dev = max_dev.max(d);
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
        sim_tip_path_deviation_mm: None,
        sim_tip_samples: 0,
    }
}

/// Why a trajectory failed.
pub(super) enum TrajectoryError {
    /// The robot could not do it (fault, stop, link loss): the run may continue after recovery.
    Motion(String),
    /// A stream tripped the safety watch; the arm was stopped.
    Trip(Trip),
    /// The recording failed (disk full, I/O error): the run stops.
    Record(String),
    /// The arm is somewhere no move may start from (outside the envelope, a non-finite pose):
    /// nothing moved, and the run stops.
    Unsafe(String),
}

impl TrajectoryError {
    pub(super) fn reason(&self) -> String {
        match self {
            TrajectoryError::Motion(r)
            | TrajectoryError::Record(r)
            | TrajectoryError::Unsafe(r) => r.clone(),
            TrajectoryError::Trip(t) => t.to_string(),
        }
    }
}

/// Everything a trajectory needs besides the robot.
pub(super) struct Ctx<'a> {
    pub config: &'a RigConfig,
    pub plan: &'a Plan,
    pub clock: &'a Clock,
    pub rec: &'a Recorder,
    pub streams: &'a Streams,
    pub collector: &'a mpsc::UnboundedSender<CollectCmd>,
    pub tare_samples: u64,
    pub tare_timeout: Duration,
    /// Stage starts, announced to the fault injector (simulated rig).
    pub stage_tx: &'a watch::Sender<Option<(String, StageName)>>,
    /// Every retract made, for the summary.
    pub retracts: &'a std::sync::Mutex<Vec<Retract>>,
    /// The simulated rig, whose indenter tip each stage's path is checked against.
    pub sim: Option<&'a RunningSimRig>,
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
) -> Result<(MovesLog, TrajStats, TipPath), TrajectoryError> {
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
    let lost_before = ctx.streams.counters().recording_lost();
    let _ = ctx.collector.send(CollectCmd::Begin);
    let mut log = MovesLog::default();
    let mut tip = TipPath::default();
    for stage in &t.stages {
        let moves: Vec<Move> = stage_moves(t, stage).into_iter().map(|(m, _)| m).collect();
        let t0 = ctx.clock.now_ns();
        let _ = ctx.collector.send(CollectCmd::Stage {
            t_ns: t0,
            stage: stage.name,
        });
        ctx.stage_tx.send_replace(Some((t.id.clone(), stage.name)));
        let n0 = log.samples.len();
        guarded(&mut trips, robot.run_moves_logged(&moves, &mut log)).await?;
        // The simulated tip's path, read back while the controller's history still holds it.
        if let Some(sim) = ctx.sim {
            let planned = stage_moves(t, stage);
            for s in &log.samples[n0..] {
                let d = sim
                    .tip_pose_at(s.state.t_host_ns)
                    .and_then(|p| deviation(&planned, &s.label, &p));
                if let Some(d) = d {
                    tip.max_m = tip.max_m.max(d);
                    tip.samples += 1;
                }
            }
        }
    }
    let t_end_ns = log
        .samples
        .last()
        .map_or_else(|| ctx.clock.now_ns(), |s| s.state.t_host_ns);
    let (reply, rx) = oneshot::channel();
    let _ = ctx.collector.send(CollectCmd::End { t_end_ns, reply });
    // The last frames and samples are still coming: a stream that stalls now fails it too. The
    // collector may be waiting on a stalled writer (its queue full): that wait is watched.
    let stats = tokio::select! {
        r = ctx.rec.watch("writing the trajectory's last records", rx) => r
            .map_err(|e| TrajectoryError::Record(e.to_string()))?
            .map_err(|_| TrajectoryError::Record("the collector stopped".into()))?
            .map_err(TrajectoryError::Record)?,
        t = trips.wait_for(|t| t.is_some()) => {
            return Err(TrajectoryError::Trip(
                t.ok().and_then(|t| t.clone()).unwrap_or(Trip::FtLost("the safety watch ended".into())),
            ));
        }
    };
    let lost = ctx.streams.counters().recording_lost() - lost_before;
    if lost > 0 {
        return Err(TrajectoryError::Record(format!(
            "{lost} F/T samples or frames could not be queued for the recording (it fell too far \
             behind the streams: a stalled or very slow disk?)"
        )));
    }
    Ok((log, stats, tip))
}

/// The simulated indenter tip's largest distance from the planned segments, m, over `samples`
/// states.
#[derive(Debug, Default)]
struct TipPath {
    max_m: f64,
    samples: usize,
}

/// Stop the collector's writing of the open trajectory. It may be waiting on a stalled writer
/// (its queue full): that wait is watched ([`Recorder::watch`]).
async fn abort_collector(
    collector: &mpsc::UnboundedSender<CollectCmd>,
    rec: &Recorder,
) -> Result<(), crate::record::RecordError> {
    let (reply, rx) = oneshot::channel();
    if collector.send(CollectCmd::Abort { reply }).is_ok() {
        let _ = rec.watch("stopping the collector's writing", rx).await?;
    }
    Ok(())
}

/// Move straight up (surface normal) from wherever the arm is to the approach height, keeping
/// its orientation. Refused when the target leaves the envelope.
async fn retract(robot: &mut Robot, ctx: &Ctx<'_>, label: &str) -> anyhow::Result<()> {
    let (config, plan) = (ctx.config, ctx.plan);
    let here = robot
        .state()
        .map(|s| s.actual_tcp_pose)
        .context("no robot state to retract from")?;
    if !finite(&here) {
        bail!(
            "the controller reports a non-finite TCP pose {:?}; not moving. Check the robot, \
             jog the arm clear of the gel on the teach pendant",
            here.to_array()
        );
    }
    let frame = plan.surface_frame;
    let mut local = pose::pose_trans(&pose::pose_inv(&frame), &here);
    let approach = config.plan.approach_height_mm * 1e-3;
    if local.z >= approach - APPROACH_TOLERANCE_M {
        return Ok(());
    }
    tracing::warn!(
        "{label}: the arm is {:.3} mm below the approach height over the gel; retracting along \
         the surface normal first",
        (approach - local.z) * 1e3
    );
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
    let label = format!("{label}/retract");
    ctx.retracts
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .push(Retract {
            label: label.clone(),
            from: here,
            to: target,
        });
    robot
        .run_moves(&[Move {
            label,
            pose: target,
            speed_m_s: config.plan.up.speed_mm_s * 1e-3,
            accel_m_s2: config.plan.up.accel_mm_s2 * 1e-3,
        }])
        .await?;
    Ok(())
}

/// How long a healthy supervisor may take to write its next heartbeat, clock time (it beats
/// on every RTDE state, every 2 ms on an e-Series).
const SUPERVISOR_RESPONSE: Duration = Duration::from_millis(500);

/// How far below the approach height the arm may be and still count as clear of the gel, m:
/// well above a UR5e's ±0.03 mm pose repeatability (UR5e data sheet), well below any approach
/// height (millimetres above the gel).
const APPROACH_TOLERANCE_M: f64 = 0.2e-3;

fn finite(p: &Pose) -> bool {
    p.to_array().iter().all(|v| v.is_finite())
}

/// Where the arm is, refused when the controller reports a non-finite pose or one outside the
/// envelope: no move may start from there.
fn checked_pose(robot: &Robot, config: &RigConfig) -> Result<Pose, String> {
    let here = robot
        .state()
        .map(|s| s.actual_tcp_pose)
        .ok_or("no robot state yet: the RTDE stream is silent")?;
    if !finite(&here) {
        return Err(format!(
            "the controller reports a non-finite TCP pose {:?}; nothing was moved. Check the \
             robot (pendant, calibration) and the RTDE link, then run again",
            here.to_array()
        ));
    }
    let e = &config.safety.envelope;
    if !e.contains([here.x, here.y, here.z]) {
        return Err(format!(
            "the arm's TCP is at ({:.1}, {:.1}, {:.1}) mm, outside the safety envelope (x \
             {:.1}..{:.1}, y {:.1}..{:.1}, z {:.1}..{:.1} mm); nothing was moved. Jog it into the \
             envelope on the teach pendant, then run again (--resume continues the recording)",
            here.x * 1e3,
            here.y * 1e3,
            here.z * 1e3,
            e.min_x * 1e3,
            e.max_x * 1e3,
            e.min_y * 1e3,
            e.max_y * 1e3,
            e.min_z * 1e3,
            e.max_z * 1e3,
        ));
    }
    Ok(here)
}

/// Before the first move of a run (or a resume): the arm's pose must be finite and inside the
/// envelope, or nothing moves.
pub(super) fn check_start(robot: &Robot, config: &RigConfig) -> anyhow::Result<()> {
    checked_pose(robot, config)
        .map(drop)
        .map_err(anyhow::Error::msg)
}

/// The transit from `from` to `to` is a straight line: inside the box envelope when both ends
/// are (a box is convex), and never lower over the gel than its lower end. Both ends must be
/// at or above the approach height, so the line never enters the gel.
pub fn check_transit(
    config: &RigConfig,
    plan: &Plan,
    from: &Pose,
    to: &Pose,
) -> Result<(), String> {
    let e = &config.safety.envelope;
    for (what, p) in [("start", from), ("end", to)] {
        if !finite(p) {
            return Err(format!(
                "the transit's {what} {:?} is not finite",
                p.to_array()
            ));
        }
        if !e.contains([p.x, p.y, p.z]) {
            return Err(format!(
                "the transit's {what} ({:.1}, {:.1}, {:.1}) mm is outside the safety envelope",
                p.x * 1e3,
                p.y * 1e3,
                p.z * 1e3
            ));
        }
        let local = pose::pose_trans(&pose::pose_inv(&plan.surface_frame), p);
        let approach = config.plan.approach_height_mm * 1e-3;
        if local.z < approach - APPROACH_TOLERANCE_M {
            return Err(format!(
                "the transit's {what} is {:.3} mm below the approach height over the gel",
                (approach - local.z) * 1e3
            ));
        }
    }
    Ok(())
}

/// Records trajectory `t`: clear of the gel first (a retract along the surface normal when
/// the arm is below the approach height), the checked transit to its start, the tare, its
/// stages and its file; then compares its path with the plan.
pub(super) async fn record(
    robot: &mut Robot,
    ctx: &Ctx<'_>,
    t: &Trajectory,
) -> Result<TrajectoryOutcome, TrajectoryError> {
    let wall_start = std::time::Instant::now();
    let start = t.stages[0].waypoints[0];
    checked_pose(robot, ctx.config).map_err(TrajectoryError::Unsafe)?;
    retract(robot, ctx, &t.id).await.map_err(|e| {
        TrajectoryError::Unsafe(format!("clearing the gel before the transit: {e:#}"))
    })?;
    let here = checked_pose(robot, ctx.config).map_err(TrajectoryError::Unsafe)?;
    let transit = (pose::translation_distance(&here, &start) > 1e-6
        || pose::rotation_distance(&here, &start) > 1e-6)
        .then(|| Move {
            label: format!("{}/transit", t.id),
            pose: start,
            speed_m_s: ctx.config.plan.up.speed_mm_s * 1e-3,
            accel_m_s2: ctx.config.plan.up.accel_mm_s2 * 1e-3,
        });
    if transit.is_some() {
        check_transit(ctx.config, ctx.plan, &here, &start)
            .map_err(|e| TrajectoryError::Unsafe(format!("{}/transit refused: {e}", t.id)))?;
    }
    ctx.rec
        .begin(&t.id)
        .await
        .map_err(|e| TrajectoryError::Record(e.to_string()))?;
    let (log, stats, tip) = run_trajectory(robot, ctx, t, transit).await?;
    let counts = ctx
        .rec
        .finish(stats.frames_dropped)
        .await
        .map_err(|e| TrajectoryError::Record(e.to_string()))?;
    let mut outcome = assess(ctx.plan, t, &log);
    outcome.poses_recorded = counts.poses;
    outcome.wall_time_s = wall_start.elapsed().as_secs_f64();
    outcome.stats = stats;
    if ctx.sim.is_some() {
        outcome.sim_tip_path_deviation_mm = Some(tip.max_m * 1e3);
        outcome.sim_tip_samples = tip.samples;
    }
    Ok(outcome)
}

/// Trajectory `t` failed with `e`: stop the arm (after a trip), recover and retract it
/// ([`after_failure`]), then stop writing the trajectory and mark it failed in the manifest
/// (its partial file is removed). Returns why the run must stop, if it must.
pub(super) async fn fail(
    robot: &mut Robot,
    ctx: &Ctx<'_>,
    t: &Trajectory,
    e: &TrajectoryError,
    bar: &ProgressBar,
) -> Option<String> {
    if matches!(e, TrajectoryError::Trip(_)) {
        // Stop first. The supervisor already wrote its stop request before it published the
        // trip; this is the motion's own stop through the command registers, confirmed by
        // the program, before any bookkeeping.
        if let Err(se) = robot.stop().await {
            tracing::error!("{}: stopping the arm: {se}", t.id);
        }
    }
    let reason = format!("{}: {}", t.id, e.reason());
    tracing::error!("trajectory {reason}");
    // Off the gel before any bookkeeping: the aborts below wait on the recording, which a
    // stalled disk can hold up indefinitely. Each of those waits gives up once the writer has
    // held work without completing any for its stall limit (`record::STALL_LIMIT`), and the
    // run then stops: nothing more can be recorded.
    let stop = after_failure(robot, ctx, t, e).await;
    bar.suspend(|| eprintln!("trajectory {reason}"));
    let aborted = match abort_collector(ctx.collector, ctx.rec).await {
        Ok(()) => ctx.rec.abort(&e.reason()).await,
        Err(stalled) => Err(stalled),
    };
    match aborted {
        Ok(()) => stop,
        Err(ae @ crate::record::RecordError::Stalled { .. }) => {
            tracing::error!("trajectory {}: could not mark it failed: {ae}", t.id);
            Some(format!("{}: {ae}", t.id))
        }
        Err(ae) => {
            tracing::error!("trajectory {}: could not mark it failed: {ae}", t.id);
            stop
        }
    }
}

/// After a failed trajectory (the arm already stopped after a trip): recover and retract the
/// arm as far as it is safe, and say whether the run must stop (and why).
pub(super) async fn after_failure(
    robot: &mut Robot,
    ctx: &Ctx<'_>,
    t: &Trajectory,
    e: &TrajectoryError,
) -> Option<String> {
    let continue_ok = ctx.config.safety.on_failure == OnFailure::Continue;
    match e {
        TrajectoryError::Trip(trip) => {
            // The arm was stopped first (by the supervisor, then by `fail`).
            if let Err(re) = retract(robot, ctx, &t.id).await {
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
            // Nothing moves again without the supervisor that watches the force and feeds the
            // watchdog (a hung supervisor is why the controller stopped the program).
            if !ctx
                .streams
                .supervisor_responds(ctx.clock, SUPERVISOR_RESPONSE)
                .await
            {
                return Some(format!(
                    "{}: the safety supervisor stopped feeding the controller's watchdog (it \
                     hung), so the controller stopped the arm; nothing moves without it. Inspect \
                     the rig, then run again with --resume",
                    t.id
                ));
            }
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
            if let Err(re) = retract(robot, ctx, &t.id).await {
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
        TrajectoryError::Unsafe(r) => Some(format!("{}: {r}", t.id)),
        TrajectoryError::Record(r) => {
            // The arm finished its stages (a recording error shows at the end) or was stopped
            // by the robot's own error; make sure it is off the gel.
            let _ = retract(robot, ctx, &t.id).await;
            Some(format!("{}: the recording failed ({r})", t.id))
        }
    }
}
