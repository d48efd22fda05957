//! `rig run`: drive the robot along the contact plan and record it, one file per trajectory.
//!
//! The order of things is fixed by safety: the config is validated and the whole plan is built
//! and checked against the envelope (every waypoint, [`Plan::build`]) before any connection is
//! opened. The output directory is checked next (an existing recording is only continued with
//! `--resume`), and only then does the rig connect, power the arm up, upload its control program
//! and move.
//!
//! With no lab rig configured (`robot.simulated = true`, as in the embedded default config), the
//! rig is the simulated one ([`crate::simrig::start`]), started in-process, whose clock may run
//! faster than real time (`--speed-factor`). The rig code that talks to it is the lab code.
//!
//! # Tasks
//!
//! - the **motion** (this task): per trajectory, the transit to its start at approach height,
//!   the tare of the F/T there (off the gel), then the four stages;
//! - the **robot state** (500 Hz) comes from the RTDE client's own task;
//! - the **F/T** and **camera** streams are each read on their own task ([`streams`]); frames
//!   are readied for the file on a dedicated thread (an MJPEG camera's JPEG kept as sent, raw
//!   pixels encoded as PNG);
//! - the **collector** ([`collector`]) pairs every frame with the wrench interpolated at its
//!   time and queues the open trajectory's records on the [`Recorder`](crate::record::Recorder), whose writer thread
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
//! The motion runs under watch of the streams' trips ([`Trip`](events::Trip)): a force above
//! `safety.max_force_n`, a saturated sensor, an F/T or camera stream that stalls or ends.
//! A target sensor recorded without an F/T sensor (no `[force_sensor]`: images, TCP poses
//! and stage labels only) is watched on the UR5e's own flange force instead, with a margin for
//! that sensor's accuracy ([`flange`]). A trip
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
//! A disk that stops answering does not hang the run: every wait on the recorder (a
//! trajectory's start and finish, the aborts after a failure, the end-of-run close) gives up
//! once its writer has held work for [`crate::record::STALL_LIMIT`] without completing any.
//! The arm is stopped and retracted first, as after any failure; the run then stops with
//! [`RunSummary::recording_stalled`] saying so, leaving the manifest as last saved (the
//! trajectory under way pending), for `--resume` once the disk is back.
//!
//! The disk space is budgeted ([`budget`]): a run whose estimate (frames × the sensor's
//! measured bytes per frame, plus the other channels) the output's file system cannot hold is
//! refused before anything connects, and a trajectory that no longer fits is not started: the
//! run stops there as after any stop, the rest pending for `--resume`.
//!
//! Each trajectory's TCP path is also compared with the planned straight lines, and the largest
//! deviation and depth overshoot are reported.
//!
//! # Files
//!
//! [`run()`] below tells the story; the chapters are `options` (what was asked, checked against
//! the plan), `output` (the output directory and `--resume`), `devices` (the rig, its
//! clock, the recorder and the robot), `pipeline` (streams, collector, governor, injector),
//! `trajectory` (one trajectory, its failure and the recovery), [`budget`] (the disk space
//! it needs, checked before anything connects and before each trajectory) and `summary`
//! (the report).

pub mod budget;
pub mod collector;
mod devices;
pub mod events;
pub mod flange;
mod options;
mod output;
mod pipeline;
pub mod safety;
pub mod streams;
mod summary;
mod trajectory;

use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use crate::plan::{Plan, Trajectory};
use crate::record::RecordError;
use devices::Rig;
use pipeline::Pipeline;
use trajectory::Ctx;

pub use options::RunOptions;
pub use summary::{Retract, RunSummary, TrajectoryOutcome};
pub use trajectory::{assess, stage_moves, trajectory_moves};

/// Build and check the plan, check the output directory, then run and record the plan on the
/// configured rig (the simulated one when `config.robot.simulated`).
pub async fn run(
    config: &RigConfig,
    indenter: &Indenter,
    opts: &RunOptions,
) -> anyhow::Result<RunSummary> {
    let wall0 = std::time::Instant::now();
    // Safety first: nothing connects before every waypoint has been checked,
    let plan = Plan::build(config, indenter)?;
    let planned = options::planned(config, &plan, opts)?;
    // nor before the force watch is known to hold: a config without an F/T sensor is watched on
    // the UR5e's flange sensor, which must be able to enforce the limit.
    let flange = flange::guard(config)?;
    let speed = opts.clock_speed(config);
    // nor before the output directory is (an existing recording is only continued on --resume).
    let ids: Vec<String> = planned.iter().map(|t| t.id.clone()).collect();
    let output = output::prepare(config, &plan, &ids, &opts.out, opts.resume)?;
    let _out_lock = output.lock;
    let todo: Vec<&Trajectory> = planned
        .iter()
        .filter(|t| !output.complete.contains(&t.id))
        .collect();
    let mut summary = RunSummary {
        simulated: config.robot.simulated,
        out: opts.out.clone(),
        skipped: planned.len() - todo.len(),
        flange_watch: flange.is_some(),
        ..Default::default()
    };
    let Some(first) = todo.first() else {
        eprintln!(
            "all {} trajectories are already recorded in {}; nothing to do",
            planned.len(),
            opts.out.display()
        );
        return Ok(summary);
    };
    let home = first.stages[0].waypoints[0];
    // Nor before the disk is known to hold what is still to record (a lab camera's frames are
    // measured once it streams, below).
    let mut disk = budget::preflight(
        config,
        &plan,
        indenter,
        planned,
        &output.complete,
        &opts.out,
    )?;

    // The rig, the recorder (before the robot: a run that cannot reach the robot is continued
    // with --resume), the robot, and the tasks around the motion.
    let Rig {
        clock,
        endpoints,
        devices,
        sim,
    } = devices::open_rig(config, indenter, opts, home).await?;
    let rec = devices::start_recorder(opts, output.manifest, &devices, _out_lock.as_ref())?;
    let mut robot = devices::connect_robot(config, endpoints, speed, &clock).await?;
    let pipeline = Pipeline::start(
        config,
        opts,
        flange,
        devices,
        sim.as_ref(),
        &clock,
        speed,
        rec.clone(),
        &robot,
    );
    let retracts = std::sync::Mutex::new(Vec::new());
    let bar = progress_bar(opts.progress, planned.len(), summary.skipped);
    let ctx = Ctx {
        config,
        plan: &plan,
        clock: &clock,
        rec: &rec,
        streams: &pipeline.streams,
        collector: &pipeline.collector,
        tare_samples: config
            .force_sensor
            .as_ref()
            .map_or(0, |f| u64::from(f.tare_samples)),
        tare_timeout: Duration::from_secs_f64(5.0 * speed),
        stage_tx: &pipeline.stage_tx,
        retracts: &retracts,
        sim: sim.as_ref(),
    };
    if ctx.tare_samples == 0 {
        // No tare asked for: the readings are taken as they are, limit included.
        pipeline.streams.arm_force_limit();
    }

    // Nothing moves from a pose that is not finite or outside the envelope (each trajectory
    // then clears the gel and checks its transit before it moves).
    trajectory::check_start(&robot, config)?;

    // A lab camera's frames are measured before the first motion: the first trajectory's
    // disk check counts what the camera really sends.
    if disk.frame.basis == budget::FrameBasis::FormatBound {
        budget::await_frames(
            pipeline.streams.counters(),
            &clock,
            5,
            Duration::from_secs_f64(3.0 * speed),
        )
        .await;
    }

    // The trajectories, one after the other, each only when the disk holds it.
    let t0 = clock.now_ns();
    let mut attempted = 0usize;
    for (k, t) in todo.iter().enumerate() {
        let (n, bytes) = pipeline.streams.counters().stored_frame_sizes();
        disk.refine(n, bytes);
        if let Err(why) =
            budget::check_before(&disk, &todo[k..], &opts.out, summary.trajectories.len())
        {
            bar.suspend(|| eprintln!("{why}"));
            summary.failure = Some((t.id.clone(), why.clone()));
            summary.stopped = Some(why);
            break;
        }
        attempted += 1;
        match trajectory::record(&mut robot, &ctx, t).await {
            Ok(outcome) => {
                let counters = pipeline.streams.counters();
                bar.set_message(summary::progress_message(&outcome.stats, counters));
                summary.trajectories.push(outcome);
                bar.inc(1);
            }
            Err(e) => {
                let stop = trajectory::fail(&mut robot, &ctx, t, &e, &bar).await;
                summary.note_failure(&t.id, e.reason());
                bar.inc(1);
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
    summary.image_lag_max_ms = sim.as_ref().map(|s| s.image_lag_max_ms());
    summary.sim_physics = sim.as_ref().map(|s| s.physics_stats());
    pipeline.count_into(&mut summary, &rec);
    if let Some(s) = &sim {
        // When each supervisor stop reached the simulated controller.
        let received = s.stop_requests_received();
        for stop in &mut summary.safety_stops {
            let seen = stop
                .request
                .and_then(|r| received.iter().find(|x| x.request == r));
            stop.reached_controller_ns = seen.map(|x| x.t_ns);
            stop.tcp_at_controller = seen.map(|x| x.tcp_pose);
        }
    }
    summary.retracts = retracts.lock().unwrap_or_else(|e| e.into_inner()).clone();

    // Orderly shutdown: streams, collector, recorder (every queued record written), rig. A
    // stalled disk ends it early: the writer is left hanging (it keeps the directory's lock),
    // what it saved stays as `--resume` finds it, and nothing else reads the disk.
    pipeline.shutdown(&rec).await;
    let rec = Arc::into_inner(rec).context("the recorder is still in use at the end of the run")?;
    match rec.close().await {
        Ok(_) => {}
        Err(e @ RecordError::Stalled { .. }) => {
            let why = e.to_string();
            if summary.failure.is_none() {
                let id = todo
                    .get(attempted.saturating_sub(1))
                    .map_or_else(String::new, |t| t.id.clone());
                summary.failure = Some((id, why.clone()));
            }
            summary.stopped.get_or_insert_with(|| why.clone());
            summary.recording_stalled = Some(why);
        }
        Err(e) => {
            return Err(e)
                .with_context(|| format!("finishing the recording in {}", opts.out.display()));
        }
    }
    drop(robot);
    if let Some(s) = sim {
        summary.sim_tapes = s.shutdown().await;
    }
    if summary.recording_stalled.is_none() {
        summary.disk = budget::DiskUse::of(&opts.out, &disk);
    }
    summary.wall_time_s = wall0.elapsed().as_secs_f64();
    // The arm is left above the gel: every trajectory ends its Up stage at approach height.
    Ok(summary)
}

/// The run's progress bar over `n` trajectories, `skipped` of them already done (hidden unless
/// `show`).
fn progress_bar(show: bool, n: usize, skipped: usize) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(n as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:25} {pos}/{len} trajectories  ETA {eta}  {msg}",
        )
        .expect("static template"),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    bar.inc(skipped as u64);
    bar
}
