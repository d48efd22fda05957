//! `rig run`: drive the robot along the contact plan.
//!
//! The order of things is fixed by safety: the config is validated and the whole plan is built
//! and checked against the envelope (every waypoint, [`Plan::build`]) before any connection is
//! opened. Only then does the rig connect, power the arm up, upload its control program and move.
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
//! This stage of the product moves and tracks the robot only: force and camera streams and the
//! per-trajectory recording join in later work. Each trajectory's TCP path is compared with the
//! planned straight lines, and the largest deviation and depth overshoot are reported.

use std::time::Duration;

use anyhow::{Context, bail};
use indicatif::{ProgressBar, ProgressStyle};
use rig_core::clock::Clock;
use rig_core::config::RigConfig;
use rig_core::control::robot_mode;
use rig_core::indenter::Indenter;
use rig_core::pose::{self, Pose};

use crate::plan::{Plan, Trajectory};
use crate::robot::{Move, MovesLog, Robot, RobotEndpoints, RobotOptions};

/// Options of one run.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Run only the first `limit` trajectories.
    pub limit: Option<usize>,
    /// Simulated rig only: how many times faster than real time the simulated clock runs.
    pub speed_factor: f64,
    /// Show a progress bar (off in tests and when stderr is not a terminal).
    pub progress: bool,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            limit: None,
            speed_factor: 10.0,
            progress: true,
        }
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
    /// RTDE samples logged during the trajectory.
    pub samples: usize,
    /// Clock time the trajectory took, s.
    pub duration_s: f64,
}

/// What a run did.
#[derive(Debug, Clone, Default)]
pub struct RunSummary {
    pub simulated: bool,
    pub trajectories: Vec<TrajectoryOutcome>,
    /// The first failure, if the run stopped early: trajectory id and reason.
    pub failure: Option<(String, String)>,
    /// Clock time of the whole run, s.
    pub clock_time_s: f64,
}

/// Moves of one trajectory: for every stage, a moveL to each waypoint after the first. Labels
/// read `<trajectory>/<stage>/<k>` so an error names both.
pub fn trajectory_moves(t: &Trajectory) -> Vec<(Move, Pose)> {
    let mut moves = Vec::new();
    for stage in &t.stages {
        for (k, pair) in stage.waypoints.windows(2).enumerate() {
            moves.push((
                Move {
                    label: format!("{}/{}/{k}", t.id, stage.name),
                    pose: pair[1],
                    speed_m_s: stage.speed_mm_s * 1e-3,
                    accel_m_s2: stage.accel_mm_s2 * 1e-3,
                },
                pair[0],
            ));
        }
    }
    moves
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
        duration_s: (t_last.saturating_sub(t_first)) as f64 * 1e-9,
    }
}

/// Build and check the plan, then run it on the configured robot (the simulated one when
/// `config.robot.simulated`).
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
    let trajectories = &plan.trajectories[..n];
    let Some(first) = trajectories.first() else {
        bail!("the plan has no trajectories to run");
    };
    let home = first.stages[0].waypoints[0];

    let simulated = config.robot.simulated;
    let (clock, endpoints, _sim) = if simulated {
        if !(opts.speed_factor.is_finite() && opts.speed_factor > 0.0) {
            bail!(
                "--speed-factor must be a positive number, got {}",
                opts.speed_factor
            );
        }
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

    let robot_opts = RobotOptions {
        frequency_hz: Some(config.robot.rtde_frequency_hz),
        watchdog_min_hz: config.robot.watchdog_min_hz,
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

    let t0 = clock.now_ns();
    let mut summary = RunSummary {
        simulated,
        ..Default::default()
    };
    let transit_speed = config.plan.up.speed_mm_s * 1e-3;
    let transit_accel = config.plan.up.accel_mm_s2 * 1e-3;
    for t in trajectories {
        // Transit at approach height to this trajectory's start, when not already there.
        let start = t.stages[0].waypoints[0];
        let here = robot.state().map(|s| s.actual_tcp_pose).unwrap_or(home);
        if pose::translation_distance(&here, &start) > 1e-6
            || pose::rotation_distance(&here, &start) > 1e-6
        {
            let transit = Move {
                label: format!("{}/transit", t.id),
                pose: start,
                speed_m_s: transit_speed,
                accel_m_s2: transit_accel,
            };
            if let Err(e) = robot.run_moves(&[transit]).await {
                summary.failure = Some((t.id.clone(), e.to_string()));
                break;
            }
        }
        let moves: Vec<Move> = trajectory_moves(t).into_iter().map(|(m, _)| m).collect();
        match robot.run_moves(&moves).await {
            Ok(log) => {
                let outcome = assess(&plan, t, &log);
                bar.set_message(format!(
                    "{}: path ≤ {:.4} mm",
                    t.id, outcome.max_path_deviation_mm
                ));
                summary.trajectories.push(outcome);
                bar.inc(1);
            }
            Err(e) => {
                tracing::error!("trajectory {} failed: {e}", t.id);
                summary.failure = Some((t.id.clone(), e.to_string()));
                if config.safety.on_failure == rig_core::config::OnFailure::Stop {
                    break;
                }
                if robot.recover().await.is_err() {
                    break;
                }
            }
        }
    }
    bar.finish_and_clear();
    summary.clock_time_s = (clock.now_ns() - t0) as f64 * 1e-9;
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
        let samples: usize = self.trajectories.iter().map(|t| t.samples).sum();
        let mut s = format!(
            "{} rig: {done} trajectories completed in {:.1} s of {} time\n\
             TCP path: max deviation from the planned lines {max_dev:.4} mm, \
             max depth beyond plan {max_over:.4} mm, {samples} RTDE samples\n",
            if self.simulated { "simulated" } else { "lab" },
            self.clock_time_s,
            if self.simulated {
                "simulated"
            } else {
                "wall-clock"
            },
        );
        if let Some((id, why)) = &self.failure {
            s.push_str(&format!("stopped at trajectory {id}: {why}\n"));
        }
        s
    }
}
