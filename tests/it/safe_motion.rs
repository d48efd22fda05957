//! Safe motion on the simulated rig, run in-process (`rig::run::run`) so the run's summary and
//! the recording can be read together: where the arm starts is checked before anything moves,
//! an arm left at depth is retracted along the surface normal first, and no move leaves the
//! envelope. Real sockets throughout (RTDE, dashboard, script port, Net F/T over UDP); times are
//! simulated clock time.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use rig::plan::{Plan, StageName};
use rig::record::{Manifest, Record, Status};
use rig::run::{RunOptions, RunSummary, run};
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;
use rig_core::pose::{self, Pose};

use crate::common;

fn setup() -> (RigConfig, Indenter, Plan) {
    let config = RigConfig::load(common::sim_config()).unwrap();
    let indenter = Indenter::load("cone").unwrap();
    let plan = Plan::build(&config, &indenter).unwrap();
    (config, indenter, plan)
}

fn status(out: &std::path::Path, id: &str) -> Option<Status> {
    Manifest::load(out).unwrap().entry(id).map(|e| e.status)
}

/// Height of `p` over the undeformed gel surface, along its normal, m.
fn height(plan: &Plan, p: &Pose) -> Pose {
    pose::pose_trans(&pose::pose_inv(&plan.surface_frame), p)
}

fn inside(config: &RigConfig, extent: [[f64; 3]; 2]) -> bool {
    extent.iter().all(|p| config.safety.envelope.contains(*p))
}

#[test]
fn a_run_killed_at_depth_resumes_by_retracting_along_the_normal_first() {
    let _rig = common::one_rig_at_a_time();
    let (config, indenter, plan) = setup();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rec");
    let rt = tokio::runtime::Runtime::new().unwrap();

    // The first run is killed as its second trajectory starts shearing: the indenter is at
    // depth in the gel.
    let shears = Arc::new(AtomicUsize::new(0));
    let last_pose = Arc::new(Mutex::new(None::<Pose>));
    let (kill_tx, kill_rx) = tokio::sync::watch::channel(false);
    let tap: rig::run::collector::Tap = {
        let (shears, last_pose) = (shears.clone(), last_pose.clone());
        Arc::new(move |r: &Record| match r {
            Record::Stage {
                stage: StageName::Shear,
                ..
            } => {
                shears.fetch_add(1, Ordering::SeqCst);
            }
            Record::Pose { pose, .. } => {
                *last_pose.lock().unwrap() = Some(*pose);
                if shears.load(Ordering::SeqCst) == 2 {
                    kill_tx.send_replace(true);
                }
            }
            _ => {}
        })
    };
    let opts = RunOptions {
        limit: Some(2),
        tap: Some(tap),
        ..RunOptions::new(&out)
    };
    let (c, i) = (config.clone(), indenter.clone());
    rt.block_on(async {
        let run = tokio::spawn(async move { run(&c, &i, &opts).await });
        let mut kill_rx = kill_rx;
        tokio::select! {
            r = run => panic!("the run ended before it was killed: {:?}", r.map(|r| r.map(|s| s.report()))),
            _ = kill_rx.wait_for(|k| *k) => {}
        }
    });
    // Dropping the runtime kills every task of the run, the simulated rig's included.
    drop(rt);
    // A killed process's lock on the output directory goes with it. In-process, the recorder's
    // writer thread (a std thread, outside the runtime) holds it until it sees its commands
    // end: wait for that, as a second `rig run` after a real kill would find it free.
    let dir = std::fs::File::open(&out).unwrap();
    let t0 = std::time::Instant::now();
    while dir.try_lock().is_err() {
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(30),
            "the killed run's writer still holds the output directory's lock after 30 s"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    dir.unlock().unwrap();
    drop(dir);
    let killed_at = last_pose.lock().unwrap().expect("no pose was recorded");
    let [t0, t1] = [&plan.trajectories[0].id, &plan.trajectories[1].id];
    assert_eq!(status(&out, t0), Some(Status::Complete));
    assert_ne!(status(&out, t1), Some(Status::Complete));
    let depth_mm = -height(&plan, &killed_at).z * 1e3;
    assert!(
        depth_mm > 0.1,
        "the arm was not in the gel when the run was killed ({depth_mm:.3} mm deep)"
    );

    // The lab arm stays where the kill left it: the simulated one starts there.
    let rt = tokio::runtime::Runtime::new().unwrap();
    let opts = RunOptions {
        limit: Some(2),
        resume: true,
        sim_start_pose: Some(killed_at),
        ..RunOptions::new(&out)
    };
    let summary: RunSummary = rt.block_on(run(&config, &indenter, &opts)).unwrap();
    assert_eq!(summary.skipped, 1, "{}", summary.report());
    assert_eq!(summary.trajectories.len(), 1, "{}", summary.report());
    assert!(summary.failed.is_empty(), "{}", summary.report());

    // The first motion is the retract, from exactly where the kill left the arm, straight up
    // the surface normal to the approach height.
    let r = summary.retracts.first().expect("no retract was made");
    assert_eq!(r.label, format!("{t1}/retract"));
    assert!(
        pose::translation_distance(&r.from, &killed_at) < 1e-9,
        "something moved the arm before the retract: it started from {:?}, not {:?}",
        r.from,
        killed_at
    );
    let (from, to) = (height(&plan, &r.from), height(&plan, &r.to));
    let approach_m = config.plan.approach_height_mm * 1e-3;
    assert!((to.z - approach_m).abs() < 1e-9, "retract to {:.6} m", to.z);
    assert!(
        (to.x - from.x).abs() < 1e-9 && (to.y - from.y).abs() < 1e-9,
        "the retract was not along the normal: {from:?} -> {to:?}"
    );
    assert!(pose::rotation_distance(&r.from, &r.to) < 1e-9);
    assert_eq!(summary.retracts.len(), 1, "{:?}", summary.retracts);

    // Every reported TCP position of the resumed run, transits included, stayed in the
    // envelope; nothing tripped.
    let extent = summary.tcp_extent_m.expect("no robot state was seen");
    assert!(inside(&config, extent), "{extent:?}");
    assert!(
        summary.safety_stops.is_empty(),
        "{:?}",
        summary.safety_stops
    );

    // The dataset is complete.
    assert_eq!(status(&out, t1), Some(Status::Complete));
    let report = rig::dataset::check(&out);
    assert!(report.ok(), "{}", rig::dataset::render(&report));
}

#[test]
fn a_non_finite_or_outside_the_envelope_start_pose_is_refused_before_any_motion() {
    let _rig = common::one_rig_at_a_time();
    let (config, indenter, plan) = setup();
    let start = plan.trajectories[0].stages[0].waypoints[0];
    let mut nan = start;
    nan.y = f64::NAN;
    let mut outside = start;
    outside.x = config.safety.envelope.max_x + 0.05;
    for (pose, expected) in [
        (nan, "non-finite TCP pose"),
        (outside, "outside the safety envelope"),
    ] {
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path().join("rec");
        let opts = RunOptions {
            limit: Some(1),
            sim_start_pose: Some(pose),
            ..RunOptions::new(&out)
        };
        let rt = tokio::runtime::Runtime::new().unwrap();
        let err = rt
            .block_on(run(&config, &indenter, &opts))
            .expect_err("the run moved from a bad start pose");
        let msg = format!("{err:#}");
        assert!(msg.contains(expected), "{msg}");
        assert!(msg.contains("nothing was moved"), "{msg}");
        // No trajectory was begun.
        assert_eq!(
            status(&out, &plan.trajectories[0].id),
            Some(Status::Pending),
            "{msg}"
        );
    }
}

#[test]
fn a_frozen_supervisor_starves_the_watchdog_and_the_controller_stops_the_arm() {
    let _rig = common::one_rig_at_a_time();
    let (config, indenter, plan) = setup();
    let t = &plan.trajectories[0];
    let shear = t
        .stages
        .iter()
        .find(|s| s.name == StageName::Shear)
        .unwrap();
    let planned_shear_m =
        pose::translation_distance(&shear.waypoints[0], shear.waypoints.last().unwrap());
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("rec");
    // The supervisor hangs 200 ms into the shear; the arm keeps shearing at 1 mm/s until the
    // controller's watchdog (10 Hz minimum: 100 ms without a heartbeat) stops the program. The
    // watchdog runs in real time, so the clock runs at real speed here: 100 ms of clock time.
    let fault: rig::simrig::SimFault = format!("supervisor-freeze@{}/shear+200", t.id)
        .parse()
        .unwrap();
    let poses = Arc::new(Mutex::new(Vec::<(u64, Pose)>::new()));
    let shear_start = Arc::new(Mutex::new(None::<u64>));
    let tap: rig::run::collector::Tap = {
        let (poses, shear_start) = (poses.clone(), shear_start.clone());
        Arc::new(move |r: &Record| match r {
            Record::Stage {
                t_ns,
                stage: StageName::Shear,
            } => {
                *shear_start.lock().unwrap() = Some(*t_ns);
            }
            Record::Pose { t_ns, pose } => poses.lock().unwrap().push((*t_ns, *pose)),
            _ => {}
        })
    };
    let opts = RunOptions {
        limit: Some(2),
        sim_faults: vec![fault],
        tap: Some(tap),
        speed_factor: 1.0,
        ..RunOptions::new(&out)
    };
    let watchdog_s = opts.speed_factor / config.robot.watchdog_min_hz;
    let rt = tokio::runtime::Runtime::new().unwrap();
    let summary = rt.block_on(run(&config, &indenter, &opts)).unwrap();

    // The controller stopped the program (the rig commanded no stop: its supervisor hung),
    // and the run stopped because the supervisor no longer answers.
    let (id, why) = summary
        .failure
        .clone()
        .expect("the trajectory did not fail");
    assert_eq!(id, t.id);
    assert!(why.contains("control program stopped"), "{why}");
    let stopped = summary.stopped.clone().unwrap_or_default();
    assert!(stopped.contains("safety supervisor stopped"), "{stopped}");
    assert!(
        summary.safety_stops.is_empty(),
        "{:?}",
        summary.safety_stops
    );
    assert_eq!(summary.not_attempted, 1, "{}", summary.report());

    // The arm stopped well short of the planned shear: it sheared for the 200 ms before the
    // freeze plus the watchdog's 100 ms (0.3 mm at 1 mm/s; 0.1 s of margin for a busy host),
    // not the planned 1 mm.
    let t_shear = shear_start.lock().unwrap().expect("the shear never began");
    let poses = poses.lock().unwrap();
    let at_shear = poses
        .iter()
        .find(|(t, _)| *t >= t_shear)
        .map(|(_, p)| *p)
        .unwrap();
    let last = poses.last().map(|(_, p)| *p).unwrap();
    let travel = pose::translation_distance(&at_shear, &last);
    let speed = config.plan.shear.speed_mm_s * 1e-3;
    assert!(speed * (0.2 + watchdog_s + 0.1) < 0.5 * planned_shear_m);
    assert!(
        travel > 0.1 * speed && travel < speed * (0.2 + watchdog_s + 0.1),
        "sheared {:.3} mm of the planned {:.3} mm before the controller stopped it",
        travel * 1e3,
        planned_shear_m * 1e3
    );
}

/// Force limit for the blocked-recorder drill, N: crossed at about 0.65 mm in the deepest press
/// of the cone (0.47 N at 0.8 mm on the simulated gel: `rig sim forces --indenter cone`).
const DRILL_FORCE_LIMIT_N: f64 = 0.3;

#[test]
fn a_blocked_recorder_does_not_delay_the_stop_on_a_force_limit_crossing() {
    let _rig = common::one_rig_at_a_time();
    let tmp = tempfile::tempdir().unwrap();
    // The deepest layer, pressed slowly (0.25 mm/s: 11 s from the approach height to 0.8 mm),
    // so the stalled disk has backed the recording up well before the force crosses the limit.
    let cfg = common::edited_sim_config(
        tmp.path(),
        "blocked.toml",
        &[
            ("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.8]"),
            (
                "down = { speed_mm_s = 1.0, accel_mm_s2 = 10.0 }",
                "down = { speed_mm_s = 0.25, accel_mm_s2 = 10.0 }",
            ),
            (
                "max_force_n = 20.0",
                &format!("max_force_n = {DRILL_FORCE_LIMIT_N}"),
            ),
        ],
    );
    let config = RigConfig::load(&cfg).unwrap();
    let indenter = Indenter::load("cone").unwrap();
    let out = tmp.path().join("rec");
    // The writer is stalled from the start; the first stop opens it again (so the run can
    // finish its bookkeeping), after noting whether the recording was backed up by then.
    let gate = rig::record::WriterGate::new();
    gate.close();
    let observer: rig::run::safety::StopObserver = {
        let gate = gate.clone();
        Arc::new(move |_| gate.open())
    };
    let opts = RunOptions {
        limit: Some(1),
        recorder_gate: Some(gate),
        on_safety_stop: Some(observer),
        // The 4 ms are a real-time budget (the host's own latencies, a few hundred µs, would
        // count ten times over on a ×10 clock): simulated time runs at real speed here.
        speed_factor: 1.0,
        ..RunOptions::new(&out)
    };
    // If the force never crossed the limit, nothing would open the writer and the run would
    // wait on its recording for ever: a guard opens it after far longer than the trajectory
    // takes (about 30 s at this clock's real speed), so the test fails below instead of hanging.
    let finished = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let guard = {
        let (gate, finished) = (opts.recorder_gate.clone().unwrap(), finished.clone());
        std::thread::spawn(move || {
            for _ in 0..3000 {
                if finished.load(std::sync::atomic::Ordering::Relaxed) {
                    return false;
                }
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
            gate.open();
            true
        })
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let summary = rt.block_on(run(&config, &indenter, &opts)).unwrap();
    finished.store(true, std::sync::atomic::Ordering::Relaxed);
    let guard_opened = guard.join().unwrap();

    let stop = summary.safety_stops.first().unwrap_or_else(|| {
        panic!(
            "no safety stop{}: {}",
            if guard_opened {
                " (the run waited on its stalled recording until the test's guard opened it)"
            } else {
                ""
            },
            summary.report()
        )
    });
    assert!(
        matches!(stop.trip, rig::run::events::Trip::ForceLimit { limit_n, .. } if limit_n == DRILL_FORCE_LIMIT_N),
        "{stop:?}"
    );
    assert!(
        stop.recording_backed_up,
        "the recording was not backed up when the force crossed the limit: the drill tested \
         nothing ({stop:?})"
    );
    let commanded = stop.commanded_ns.expect("the stop request was not written");
    assert!(commanded >= stop.detected_ns);
    // The spec: at most 4 ms of simulated time from the crossing sample to the stop command
    // reaching the controller.
    let reached = stop
        .reached_controller_ns
        .expect("the controller never saw the stop request");
    let latency_ms = (reached.saturating_sub(stop.detected_ns)) as f64 * 1e-6;
    eprintln!("stop reached the controller {latency_ms:.3} ms after the crossing");
    assert!(
        latency_ms <= 4.0,
        "stop reached the controller {latency_ms:.3} ms after the crossing"
    );

    // Once the request has reached the controller, the arm comes to rest within what one more
    // controller step at the indentation speed and the stop deceleration allow.
    let v = config.plan.down.speed_mm_s * 1e-3;
    let (travel, _, allowed) = common::assert_stop_travel(stop, &summary, v);
    eprintln!(
        "travel after the request reached the controller {:.4} mm (allowed {:.4} mm)",
        travel * 1e3,
        allowed * 1e3
    );
    let (id, why) = summary.failure.clone().unwrap();
    assert!(why.contains("force limit"), "{id}: {why}");
}

/// `robot.tcp_offset` of the rig's indenter: 100 mm along tool z.
const TCP_LINE: (&str, &str) = (
    "watchdog_min_hz = 10.0      # the controller stops motion if the rig talks less often than this",
    "watchdog_min_hz = 10.0\ntcp_offset = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]",
);

#[test]
fn with_a_100_mm_tcp_offset_the_tip_follows_the_plan_and_the_envelope_applies_to_the_tip() {
    let _rig = common::one_rig_at_a_time();
    let tmp = tempfile::tempdir().unwrap();
    let indenter = Indenter::load("cone").unwrap();
    // The simulated indenter is mounted 100 mm from the flange; the program sets that TCP.
    let cfg = common::edited_sim_config(tmp.path(), "tcp.toml", &[TCP_LINE]);
    let config = RigConfig::load(&cfg).unwrap();
    assert_eq!(
        config.robot.tcp_offset,
        Some([0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
    );
    let opts = RunOptions {
        limit: Some(1),
        ..RunOptions::new(tmp.path().join("rec"))
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let summary = rt.block_on(run(&config, &indenter, &opts)).unwrap();
    let t = summary
        .trajectories
        .first()
        .unwrap_or_else(|| panic!("{}", summary.report()));
    // Every state of every stage was checked against the physical tip (not the reported TCP),
    // and the tip stayed within 0.05 mm of the planned lines. (Were the TCP the flange, the
    // tip would be 100 mm deep in the gel, and the reported TCP 100 mm above the envelope.)
    assert!(t.samples > 100, "{t:?}");
    assert_eq!(t.sim_tip_samples, t.samples);
    let dev = t.sim_tip_path_deviation_mm.unwrap();
    eprintln!("tip path deviation {dev:.5} mm over {} states", t.samples);
    assert!(dev < 0.05, "the tip left the plan by {dev:.4} mm");
    assert!(
        summary.safety_stops.is_empty(),
        "{:?}",
        summary.safety_stops
    );

    // The envelope applies to the tip: a floor 0.5 mm below the surface refuses the deeper
    // presses (the flange, 100 mm above the tip, would be far inside it).
    let cfg = common::edited_sim_config(
        tmp.path(),
        "tcp-floor.toml",
        &[TCP_LINE, ("min_z = 0.199", "min_z = 0.1995")],
    );
    let config = RigConfig::load(&cfg).unwrap();
    let err = rt
        .block_on(run(&config, &indenter, &opts))
        .expect_err("a plan whose tip leaves the envelope ran");
    let msg = format!("{err:#}");
    assert!(
        msg.contains("unsafe plan") && msg.contains("min_z"),
        "{msg}"
    );
}
