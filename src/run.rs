//! `rig run`: drive the robot along the contact plan and record it, one file per trajectory.
//!
//! The order of things is fixed by safety: the config is validated and the whole plan is built
//! and checked against the envelope (every waypoint, [`Plan::build`]) before any connection is
//! opened. The output directory is checked next (an existing recording is only continued with
//! `--resume`), and only then does the rig connect, power the arm up, upload its control program
//! and move.
//!
//! With no lab rig configured (`robot.simulated = true`, as in the embedded default config), the
//! robot is the simulated UR5e of `hardware-mocks`, started in-process on loopback ports and
//! driven over real RTDE, dashboard and secondary-interface sockets, exactly as a lab controller
//! would be. Its clock may run faster than real time (`--speed-factor`).
//!
//! Moves between trajectories (from one trajectory's end above the gel to the next one's start
//! above the gel) are straight lines at approach height between two checked waypoints; the
//! envelope is a box, hence convex, so such a line never leaves it.
//!
//! # Recording
//!
//! Every run records into an output directory through the [`Recorder`]: a manifest
//! (`manifest.json`: config, indenter, sensor, each trajectory's status) and one MCAP file per
//! trajectory, written as `.<id>.mcap.partial` and renamed to `<id>.mcap` only once complete
//! (fsynced), so a crash never leaves a half-written file under a final name. Per trajectory:
//! [`Recorder::begin`], the transit to its start (not recorded), then a stage record at each
//! stage's start and a TCP-pose record for every RTDE state from the first stage's start to the
//! last state logged by its moves (so also the few states between two stages), then
//! [`Recorder::finish`]; a failed trajectory is [`Recorder::abort`]ed and the manifest marks it
//! failed with the reason. The recorder (and the manifest, every trajectory pending) starts
//! before the robot is connected, so even a run that cannot reach the robot is continued with
//! `--resume`.
//!
//! The records are streamed while the robot moves: a recording future receives every RTDE state
//! from the client's sample broadcast (the same states [`Robot::run_moves_logged`] logs) and
//! queues it on the recorder's bounded queue, beside the motion future on the same task. A slow
//! disk makes the recording wait (back-pressure) while the broadcast buffers the states
//! (16 384, about 30 s at 500 Hz); should it ever fall further behind, states would be lost,
//! so the trajectory fails instead of keeping an incomplete file. The force and camera streams,
//! which join later, will be fed the same way from their own tasks.
//!
//! `--resume` uses [`record::resume`]: complete trajectories (file readable, manifest complete
//! with matching counts) are skipped, stale partial files deleted, everything else redone. The
//! manifest's config and indenter must match this run's.
//!
//! Each trajectory's TCP path is also compared with the planned straight lines, and the largest
//! deviation and depth overshoot are reported.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use rig_core::clock::Clock;
use rig_core::config::RigConfig;
use rig_core::control::robot_mode;
use rig_core::indenter::Indenter;
use rig_core::pose::{self, Pose};
use tokio::sync::broadcast::{self, error::RecvError, error::TryRecvError};
use tokio::sync::watch;

use crate::plan::{Plan, Stage, StageName, Trajectory};
use crate::record::{self, Manifest, Record, Recorder, RecorderConfig, SensorInfo};
use crate::robot::{Move, MovesLog, Robot, RobotEndpoints, RobotOptions, RobotState};

/// Options of one run.
#[derive(Debug, Clone)]
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
    /// Clock time of the whole run, s.
    pub clock_time_s: f64,
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
    /// The recording failed (disk full, I/O error): the run stops.
    Record(String),
}

impl TrajectoryError {
    fn reason(&self) -> &str {
        match self {
            TrajectoryError::Motion(r) | TrajectoryError::Record(r) => r,
        }
    }
}

/// Transit to `t`'s start, then run and record its stages. The recording is already begun.
///
/// Two futures run concurrently on this task: the motion (stage by stage, through
/// [`Robot::run_moves_logged`]) and the recording, which receives every RTDE state from the
/// client's sample broadcast and queues it as a pose record while the robot moves. Each stage's
/// start time is handed from the motion to the recording, which writes the stage record before
/// the first state at or after it. When the motion ends it tells the recording the time of the
/// last state it logged; the recording drains the broadcast up to that state and stops.
async fn run_trajectory(
    robot: &mut Robot,
    rec: &Recorder,
    clock: &Clock,
    t: &Trajectory,
    transit: Option<Move>,
) -> Result<(MovesLog, record::Counts), TrajectoryError> {
    if let Some(transit) = transit {
        robot
            .run_moves(&[transit])
            .await
            .map_err(|e| TrajectoryError::Motion(e.to_string()))?;
    }
    let samples = robot.rtde().samples();
    let stages: RefCell<VecDeque<(u64, StageName)>> = RefCell::new(VecDeque::new());
    let (end_tx, end_rx) = watch::channel(None::<u64>);
    let motion = async {
        let mut log = MovesLog::default();
        let mut result = Ok(());
        for stage in &t.stages {
            let moves: Vec<Move> = stage_moves(t, stage).into_iter().map(|(m, _)| m).collect();
            stages.borrow_mut().push_back((clock.now_ns(), stage.name));
            result = robot.run_moves_logged(&moves, &mut log).await;
            if result.is_err() {
                break;
            }
        }
        // On failure the recording stops at once: the trajectory is aborted anyway.
        let end = match &result {
            Ok(()) => log.samples.last().map_or(0, |s| s.state.t_host_ns),
            Err(_) => 0,
        };
        let _ = end_tx.send(Some(end));
        result
            .map(|()| log)
            .map_err(|e| TrajectoryError::Motion(e.to_string()))
    };
    let recording = record_stream(rec, samples, &stages, end_rx);
    let (moved, recorded) = tokio::join!(motion, recording);
    let log = moved?;
    recorded?;
    let counts = rec
        .finish(0)
        .await
        .map_err(|e| TrajectoryError::Record(e.to_string()))?;
    Ok((log, counts))
}

/// The recording half of [`run_trajectory`]: stage and pose records from the sample broadcast,
/// from the first stage's start to the end time the motion sends on `end`.
async fn record_stream(
    rec: &Recorder,
    mut samples: broadcast::Receiver<RobotState>,
    stages: &RefCell<VecDeque<(u64, StageName)>>,
    mut end: watch::Receiver<Option<u64>>,
) -> Result<(), TrajectoryError> {
    let rec_err = |e: record::RecordError| TrajectoryError::Record(e.to_string());
    let lagged = |n: u64| {
        TrajectoryError::Record(format!(
            "the recording fell {n} RTDE samples behind the robot's state stream (the disk is too \
             slow); the trajectory cannot be recorded completely"
        ))
    };
    // Start of the first stage: states before it belong to the transit, not the trajectory.
    let mut started_ns: Option<u64> = None;
    let mut end_ns: Option<u64> = None;
    loop {
        let state = match end_ns {
            // The motion is over: everything it logged is already in the broadcast buffer.
            Some(end_ns) => match samples.try_recv() {
                Ok(s) if s.t_host_ns <= end_ns => s,
                Ok(_) | Err(TryRecvError::Empty | TryRecvError::Closed) => break,
                Err(TryRecvError::Lagged(n)) => return Err(lagged(n)),
            },
            None => tokio::select! {
                biased;
                r = samples.recv() => match r {
                    Ok(s) => s,
                    Err(RecvError::Lagged(n)) => return Err(lagged(n)),
                    // The RTDE client stopped: the motion fails with the reason.
                    Err(RecvError::Closed) => return Ok(()),
                },
                r = end.changed() => {
                    end_ns = match r {
                        Ok(()) => *end.borrow_and_update(),
                        Err(_) => Some(0),
                    };
                    continue;
                }
            },
        };
        // Stage records due before this state (the borrow ends before any await).
        let due: Vec<(u64, StageName)> = {
            let mut q = stages.borrow_mut();
            let mut due = Vec::new();
            while let Some(&(t0, name)) = q.front()
                && t0 <= state.t_host_ns
            {
                due.push((t0, name));
                q.pop_front();
            }
            due
        };
        for (t0, stage) in due {
            started_ns.get_or_insert(t0);
            rec.send(Record::Stage { t_ns: t0, stage })
                .await
                .map_err(rec_err)?;
        }
        if started_ns.is_some_and(|t0| state.t_host_ns >= t0) {
            rec.send(Record::Pose {
                t_ns: state.t_host_ns,
                pose: state.actual_tcp_pose,
            })
            .await
            .map_err(rec_err)?;
        }
    }
    // A stage whose start no state followed (possible only if it had no moves).
    let rest: Vec<(u64, StageName)> = stages.borrow_mut().drain(..).collect();
    for (t0, stage) in rest {
        rec.send(Record::Stage { t_ns: t0, stage })
            .await
            .map_err(rec_err)?;
    }
    Ok(())
}

/// Build and check the plan, check the output directory, then run and record the plan on the
/// configured robot (the simulated one when `config.robot.simulated`).
pub async fn run(
    config: &RigConfig,
    indenter: &Indenter,
    opts: &RunOptions,
) -> anyhow::Result<RunSummary> {
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

    let ids: Vec<String> = planned.iter().map(|t| t.id.clone()).collect();
    let fresh = Manifest::new(
        &plan.indenter,
        SensorInfo {
            id: plan.sensor_id.clone(),
            role: serde_json::to_value(config.sensor.role)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_else(|| "source".into()),
        },
        serde_json::to_value(config).context("serialising the rig config for the manifest")?,
        // No F/T stream is recorded yet, so there is no calibration to store.
        serde_json::Value::Null,
        &ids,
    );
    let output = prepare_output(&opts.out, opts.resume, &ids, fresh)?;
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

    // The recorder starts (and writes the manifest) before the robot's program is armed: its
    // watchdog must not see a stall while the directory is created and fsynced.
    let rec = Recorder::start(&opts.out, output.manifest, RecorderConfig::default())
        .with_context(|| {
            format!(
                "cannot record into {}; check the path and its permissions, or choose another --out",
                opts.out.display()
            )
        })?;

    let (clock, endpoints, _sim) = if simulated {
        let clock = Clock::scaled(opts.speed_factor);
        let cfg = hardware_mocks::ur5e::Ur5eConfig {
            home_pose: home,
            initial_robot_mode: robot_mode::POWER_OFF,
            ..Default::default()
        };
        let sim = hardware_mocks::ur5e::Ur5e::start(cfg, clock.clone())
            .await
            .context("starting the simulated UR5e on loopback")?;
        let ep = RobotEndpoints {
            rtde: sim.rtde_addr(),
            dashboard: sim.dashboard_addr(),
            script: sim.script_addr(),
        };
        tracing::info!(
            "simulated UR5e on {} (RTDE), {} (dashboard), {} (script); clock ×{}",
            ep.rtde,
            ep.dashboard,
            ep.script,
            opts.speed_factor
        );
        (clock, ep, Some(sim))
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
        (Clock::system(), ep, None)
    };

    // The watchdog guards against the rig going silent in real time. On the simulated rig the
    // controller counts clock time, which runs `speed_factor` times faster, so the same real
    // tolerance needs a rate that many times lower (10 Hz at ×20 would leave 5 ms of real
    // time, which a busy 2-core machine does not always give).
    let watchdog_min_hz = if simulated {
        config.robot.watchdog_min_hz / opts.speed_factor
    } else {
        config.robot.watchdog_min_hz
    };
    let robot_opts = RobotOptions {
        frequency_hz: Some(config.robot.rtde_frequency_hz),
        watchdog_min_hz,
        ..Default::default()
    };
    let mut robot = Robot::connect(endpoints, robot_opts, clock.clone())
        .await
        .context("connecting to the robot")?;
    robot.prepare().await.context("preparing the robot")?;

    let bar = if opts.progress {
        let bar = ProgressBar::new(n as u64);
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} trajectories  ETA {eta}  {msg}",
            )
            .expect("static template"),
        );
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    } else {
        ProgressBar::hidden()
    };
    bar.inc(summary.skipped as u64);

    let t0 = clock.now_ns();
    let transit_speed = config.plan.up.speed_mm_s * 1e-3;
    let transit_accel = config.plan.up.accel_mm_s2 * 1e-3;
    let mut attempted = 0usize;
    for t in &todo {
        attempted += 1;
        // Transit at approach height to this trajectory's start, when not already there.
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
        let result = match rec.begin(&t.id).await {
            Ok(()) => run_trajectory(&mut robot, &rec, &clock, t, transit).await,
            Err(e) => Err(TrajectoryError::Record(e.to_string())),
        };
        match result {
            Ok((log, counts)) => {
                let mut outcome = assess(&plan, t, &log);
                outcome.poses_recorded = counts.poses;
                bar.set_message(format!(
                    "{}: path ≤ {:.4} mm",
                    t.id, outcome.max_path_deviation_mm
                ));
                summary.trajectories.push(outcome);
                bar.inc(1);
            }
            Err(e) => {
                let reason = e.reason().to_owned();
                tracing::error!("trajectory {} failed: {reason}", t.id);
                // The manifest marks it failed; its partial file is removed.
                if let Err(ae) = rec.abort(&reason).await {
                    tracing::error!("trajectory {}: could not mark it failed: {ae}", t.id);
                }
                summary.failed.push((t.id.clone(), reason.clone()));
                if summary.failure.is_none() {
                    summary.failure = Some((t.id.clone(), reason));
                }
                bar.inc(1);
                if matches!(e, TrajectoryError::Record(_))
                    || config.safety.on_failure == rig_core::config::OnFailure::Stop
                {
                    break;
                }
                if let Err(re) = robot.recover().await {
                    tracing::error!("recovery failed: {re}");
                    break;
                }
            }
        }
    }
    bar.finish_and_clear();
    summary.not_attempted = todo.len() - attempted;
    summary.clock_time_s = (clock.now_ns() - t0) as f64 * 1e-9;
    rec.close()
        .await
        .with_context(|| format!("finishing the recording in {}", opts.out.display()))?;
    // The arm is left above the gel: every trajectory ends its Up stage at approach height.
    Ok(summary)
}

impl RunSummary {
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
        let poses: u64 = self.trajectories.iter().map(|t| t.poses_recorded).sum();
        let mut s = format!(
            "{} rig: {done} trajectories recorded, {} failed, {} skipped (already complete), \
             {} not attempted; {:.1} s of {} time\n\
             TCP path: max deviation from the planned lines {max_dev:.4} mm, \
             max depth beyond plan {max_over:.4} mm; {poses} TCP poses (RTDE samples) recorded\n\
             output: {}\n",
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
            self.out.display(),
        );
        for (id, why) in &self.failed {
            s.push_str(&format!("failed: trajectory {id}: {why}\n"));
        }
        s
    }
}
