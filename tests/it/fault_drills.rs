//! Faults during `rig run` on the simulated rig, each injected into a running trajectory
//! (`--sim-fault`) or provoked by the config: the run ends in the documented state with a clear
//! message, no completed trajectory is lost, no half-written file is left under a final name,
//! and `--resume` then completes the dataset.
//!
//! Documented states: a protective stop, an RTDE link drop or a force over the limit fails the
//! trajectory; with `safety.on_failure = "stop"` the run stops there (the later trajectories stay
//! pending), with `"continue"` the rig recovers (a protective stop only after UR's 5 s unlock
//! delay), retracts and goes on. A lost or stalled stream (F/T port closed, camera stalled) or
//! a recording error (disk full) always stops the run. A disk that never answers again stops
//! the run once the bookkeeping after the stop has waited the recorder's stall limit (10 s).

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use rig::record::{Manifest, Status, final_name, read_file};

use crate::common;

use common::one_rig_at_a_time as serial;

const T1: &str = "p0-d0.2-a000";
const T2: &str = "p0-d0.2-a030";
const T3: &str = "p0-d0.2-a060";

/// The shipped simulated config with `edits` applied (exact line replacements).
fn config(dir: &Path, edits: &[(&str, &str)]) -> PathBuf {
    common::edited_sim_config(dir, &format!("rig-{}.toml", edits.len()), edits)
}

const CONTINUE: (&str, &str) = ("on_failure = \"stop\"", "on_failure = \"continue\"");

fn rig_run(cfg: &Path, out: &Path, limit: usize, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cone", "--config"])
        .arg(cfg)
        .arg("--out")
        .arg(out)
        .args(["--limit", &limit.to_string()])
        .args(extra)
        .output()
        .unwrap()
}

fn text(out: &Output) -> String {
    common::output_text(out)
}

/// The state every fault must leave: `failed` failed with a reason containing `why`, every
/// trajectory in `complete` complete with a readable file whose counts match the manifest,
/// every one in `pending` still pending; no partial files, no final file for the failed one.
fn assert_state(dir: &Path, failed: &str, why: &str, complete: &[&str], pending: &[&str]) {
    let m = Manifest::load(dir).unwrap();
    let e = m.entry(failed).unwrap();
    assert_eq!(e.status, Status::Failed, "{e:?}");
    let reason = e.reason.as_deref().unwrap_or_default();
    assert!(
        reason.to_lowercase().contains(&why.to_lowercase()),
        "{failed}: reason {reason:?} does not mention {why:?}"
    );
    assert!(!dir.join(final_name(failed)).exists());
    for id in complete {
        let e = m.entry(id).unwrap();
        assert_eq!(e.status, Status::Complete, "{e:?}");
        let c = read_file(&dir.join(final_name(id))).unwrap();
        assert_eq!(c.counts, e.counts, "{id}");
        assert!(c.counts.frames > 100, "{id}: {:?}", c.counts);
    }
    for id in pending {
        assert_eq!(m.entry(id).unwrap().status, Status::Pending, "{id}");
    }
    for f in std::fs::read_dir(dir).unwrap() {
        let name = f.unwrap().file_name().to_string_lossy().into_owned();
        assert!(!name.ends_with(".partial"), "left behind: {name}");
    }
}

/// `--resume` without the fault completes the dataset, and `rig dataset check` agrees.
fn resume_completes(cfg: &Path, dir: &Path, limit: usize, extra: &[&str]) {
    let out = rig_run(cfg, dir, limit, &[&["--resume"], extra].concat());
    assert!(out.status.success(), "resume failed:\n{}", text(&out));
    let check = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(check.status.success(), "{}", text(&check));
}

fn fault(kind: &str, id: &str, stage_ms: &str) -> String {
    format!("--sim-fault={kind}@{id}/{stage_ms}")
}

#[test]
fn a_protective_stop_mid_shear_stops_the_run_and_asks_for_the_pendant() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), &[]);
    let dir = tmp.path().join("run");
    let out = rig_run(&cfg, &dir, 3, &[&fault("protective-stop", T2, "shear+300")]);
    assert!(!out.status.success(), "{}", text(&out));
    let all = text(&out);
    assert!(
        all.contains("safety stop") && all.contains("pendant"),
        "{all}"
    );
    assert!(all.contains(T2), "{all}");
    assert_state(&dir, T2, "protective stop", &[T1], &[T3]);
    resume_completes(&cfg, &dir, 3, &[]);
}

#[test]
fn with_continue_a_protective_stop_is_recovered_and_the_run_goes_on() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), &[CONTINUE]);
    let dir = tmp.path().join("run");
    let out = rig_run(&cfg, &dir, 3, &[&fault("protective-stop", T2, "shear+300")]);
    assert!(
        !out.status.success(),
        "a failed trajectory fails the command"
    );
    assert!(
        text(&out).contains("1 trajectories failed"),
        "{}",
        text(&out)
    );
    assert_state(&dir, T2, "protective stop", &[T1, T3], &[]);
    resume_completes(&cfg, &dir, 3, &[]);
}

#[test]
fn an_rtde_link_drop_fails_the_trajectory_and_the_rig_reconnects() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), &[CONTINUE]);
    let dir = tmp.path().join("run");
    let out = rig_run(&cfg, &dir, 3, &[&fault("rtde-drop", T2, "shear+300")]);
    assert!(!out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("RTDE link lost"), "{}", text(&out));
    // The link came back: the next trajectory was recorded over the new connection.
    assert_state(&dir, T2, "RTDE link lost", &[T1, T3], &[]);
    resume_completes(&cfg, &dir, 3, &[]);
}

#[test]
fn the_ft_pty_closing_stops_the_run() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    // Even with continue: nothing can be recorded without the F/T.
    let cfg = config(tmp.path(), &[CONTINUE]);
    let dir = tmp.path().join("run");
    let out = rig_run(
        &cfg,
        &dir,
        3,
        &["--sim-ft", "serial", &fault("ft-unplug", T2, "down+500")],
    );
    assert!(!out.status.success(), "{}", text(&out));
    let all = text(&out);
    assert!(all.contains("F/T"), "{all}");
    assert!(all.contains("nothing more can be recorded"), "{all}");
    assert_state(&dir, T2, "F/T", &[T1], &[T3]);
    resume_completes(&cfg, &dir, 3, &["--sim-ft", "serial"]);
}

#[test]
fn a_camera_stall_mid_shear_stops_the_run() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), &[CONTINUE]);
    let dir = tmp.path().join("run");
    let out = rig_run(&cfg, &dir, 3, &[&fault("camera-stall", T2, "shear+200")]);
    assert!(!out.status.success(), "{}", text(&out));
    assert!(text(&out).contains("camera stalled"), "{}", text(&out));
    assert_state(&dir, T2, "camera stalled", &[T1], &[T3]);
    resume_completes(&cfg, &dir, 3, &[]);
}

#[test]
fn a_force_over_the_limit_fails_the_trajectory_and_the_run_goes_on() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    // The deepest layer: the cone at 0.8 mm pushes about 0.47 N in the run's sensor physics
    // (0.4 mm deep: about 0.1 N; `rig sim forces --indenter cone`); the limit sits between.
    let cfg = config(
        tmp.path(),
        &[
            ("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.4, 0.8]"),
            ("max_force_n = 20.0", "max_force_n = 0.3"),
            CONTINUE,
        ],
    );
    let dir = tmp.path().join("run");
    // The plan order is point, depth, direction: 12 at 0.4 mm, then 0.8 mm.
    let out = rig_run(&cfg, &dir, 14, &[]);
    assert!(!out.status.success(), "{}", text(&out));
    let all = text(&out);
    assert!(all.contains("force limit"), "{all}");
    let m = Manifest::load(&dir).unwrap();
    let ids: Vec<&str> = m.trajectories.iter().map(|t| t.id.as_str()).collect();
    let shallow: Vec<&str> = ids.iter().copied().filter(|i| i.contains("d0.4")).collect();
    let deep: Vec<&str> = ids.iter().copied().filter(|i| i.contains("d0.8")).collect();
    assert_eq!((shallow.len(), deep.len()), (12, 2), "{ids:?}");
    // Both deep ones tripped (with continue, the second after a retract), named with the
    // measured force; the shallow ones are complete.
    for id in &deep {
        let e = m.entry(id).unwrap();
        assert_eq!(e.status, Status::Failed, "{e:?}");
        let r = e.reason.as_deref().unwrap();
        assert!(
            r.contains("force limit") && r.contains("max_force_n = 0.3"),
            "{r}"
        );
    }
    assert_state(&dir, deep[0], "exceeds safety.max_force_n", &shallow, &[]);
}

#[test]
fn a_full_disk_fails_the_trajectory_and_keeps_the_completed_ones() {
    let _g = serial();
    common::needs_unshare();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), &[CONTINUE]);
    let mnt = tmp.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let copy = tmp.path().join("copy");
    let rc = tmp.path().join("rc");
    let log = tmp.path().join("log");
    // The disk holds the whole run when it starts (the run's disk budget refuses one that does
    // not, and stops before a trajectory that no longer fits): another process fills it once
    // the second trajectory is under way, leaving 256 KiB, so that trajectory's own writes
    // run into the full disk. The tmpfs lives only in the namespace, so the result is copied
    // out before it ends.
    let config = rig_core::config::RigConfig::load(&cfg).unwrap();
    let indenter = rig_core::indenter::Indenter::builtin("cone").unwrap();
    let plan = rig::plan::Plan::build(&config, &indenter).unwrap();
    let budget = rig::run::budget::Budget::for_run(&config, &plan, &indenter);
    let need = budget.trajectories(&plan.trajectories[..3]).required();
    let size = (need + (4 << 20)).div_ceil(4096) * 4096;
    let script = format!(
        "mount -t tmpfs -o size={size} tmpfs {mnt} || exit 1; \
         {rig} run --indenter cone --config {cfg} --out {mnt}/run --limit 3 > {log} 2>&1 & pid=$!; \
         while [ ! -e {mnt}/run/.{T2}.mcap.partial ] && kill -0 $pid 2>/dev/null; do sleep 0.01; done; \
         avail=$(df -B1 --output=avail {mnt} | tail -n 1); \
         head -c $((avail - 262144)) /dev/zero > {mnt}/filler; \
         wait $pid; echo $? > {rc}; cp -a {mnt}/run {copy}",
        mnt = mnt.display(),
        rig = env!("CARGO_BIN_EXE_rig"),
        cfg = cfg.display(),
        log = log.display(),
        rc = rc.display(),
        copy = copy.display(),
    );
    let status = Command::new("unshare")
        .args(["-rm", "sh", "-c", &script])
        .status()
        .unwrap();
    assert!(status.success(), "the namespace script failed");
    let log = std::fs::read_to_string(&log).unwrap();
    let rc: i32 = std::fs::read_to_string(&rc)
        .unwrap()
        .trim()
        .parse()
        .unwrap();
    assert_ne!(rc, 0, "{log}");
    assert!(log.contains("No space left on device"), "{log}");
    assert!(log.contains("the recording failed"), "{log}");
    assert_state(&copy, T2, "No space left on device", &[T1], &[T3]);
}

/// The longest a stalled-disk drill may take before the test calls it hung: far beyond the
/// trajectories and the recorder's 10 s stall limit (a guard against a hang, not a speed test).
const HANG_GUARD: std::time::Duration = std::time::Duration::from_secs(300);

#[test]
fn a_disk_that_never_comes_back_ends_the_run_with_the_arm_retracted_and_resume_completes_it() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config(tmp.path(), &[]);
    let dir = tmp.path().join("run");
    // The disk stops answering early in T2's press, with the recording under way; later in
    // the press the F/T's pty closes, which trips the supervisor: the arm is stopped and
    // retracted, and the bookkeeping after the stop (the aborts, the manifest, the close)
    // then waits on a writer that never returns.
    let mut child = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cone", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&dir)
        .args(["--limit", "2", "--sim-ft", "serial"])
        .arg(fault("disk-stall", T2, "down+100"))
        .arg(fault("ft-unplug", T2, "shear+200"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t0.elapsed() > HANG_GUARD {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "the run hung on its stalled disk for {HANG_GUARD:?}:\n{}",
                text(&out)
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    let out = child.wait_with_output().unwrap();
    let all = text(&out);
    assert!(!out.status.success(), "{all}");
    assert!(all.contains("F/T"), "{all}");
    assert!(
        all.contains("completed no write for 10 s") && all.contains("stalled or unreachable"),
        "{all}"
    );
    assert!(all.contains("--resume"), "{all}");
    // The arm was retracted after the stop, before the bookkeeping gave up.
    assert!(
        all.contains(&format!("retracted: {T2}/retract along the surface normal")),
        "{all}"
    );
    // The dataset is as the disk last took it: T1 complete, T2 still pending (its abort
    // never reached the manifest) with its partial file, which --resume removes.
    let m = Manifest::load(&dir).unwrap();
    assert_eq!(m.entry(T1).unwrap().status, Status::Complete);
    assert_eq!(m.entry(T2).unwrap().status, Status::Pending);
    assert!(!dir.join(final_name(T2)).exists());
    assert!(dir.join(format!(".{T2}.mcap.partial")).exists());

    // "The disk comes back": the same command with --resume, without the faults.
    resume_completes(&cfg, &dir, 2, &["--sim-ft", "serial"]);
    let m = Manifest::load(&dir).unwrap();
    for id in [T1, T2] {
        assert_eq!(m.entry(id).unwrap().status, Status::Complete, "{id}");
    }
}
