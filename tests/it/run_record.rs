//! `rig run` records: one complete MCAP file per trajectory and a manifest; a run killed with
//! SIGKILL leaves no half-written file under a final name and `--resume` completes it into the
//! same dataset an uninterrupted run gives; an existing recording is only continued with
//! `--resume`.
//!
//! The runs use the built-in simulated rig at `--speed-factor 20`, with the controller's RTDE
//! watchdog relaxed to 1 Hz of simulated time (50 ms of real time): at the default 10 Hz the
//! watchdog allows only 5 ms of real silence at 20×, which a loaded two-core machine running
//! the test suite in parallel does not always give the heartbeat task.

use std::collections::BTreeMap;
use std::os::unix::process::ExitStatusExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use rig::record::{Counts, Manifest, Status, final_name, read_file};

use crate::common;

use common::one_rig_at_a_time as serial;

/// The built-in simulated rig's config, as shipped (the run scales its watchdog to the
/// simulated clock's speed, so ×20 needs no relaxed settings).
fn config() -> PathBuf {
    common::sim_config()
}

fn rig_run(cfg: &Path, out: &Path, limit: usize, extra: &[&str]) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_rig"));
    cmd.args(["run", "--indenter", "cone", "--config"])
        .arg(cfg)
        .arg("--out")
        .arg(out)
        .args(["--limit", &limit.to_string(), "--speed-factor", "20"])
        .args(extra);
    cmd
}

fn text(out: &Output) -> String {
    common::output_text(out)
}

fn run_ok(cmd: &mut Command) -> Output {
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "rig run failed:\n{}", text(&out));
    out
}

fn dataset_check_ok(dir: &Path) {
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check"])
        .arg(dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "rig dataset check {} failed:\n{}",
        dir.display(),
        text(&out)
    );
}

/// Every file under a final name (`<id>.mcap`) reads back completely; returns their counts.
fn final_files(dir: &Path) -> BTreeMap<String, Counts> {
    let mut files = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let name = e.unwrap().file_name().to_string_lossy().into_owned();
        if let Some(id) = name.strip_suffix(".mcap")
            && !name.starts_with('.')
        {
            let c = read_file(&dir.join(&name))
                .unwrap_or_else(|e| panic!("{name} is under its final name but unreadable: {e}"));
            files.insert(id.to_owned(), c.counts);
        }
    }
    files
}

/// The manifest lists exactly `files`, all complete with the files' counts; each trajectory has
/// its four stage records and TCP poses. Returns the manifest's ids in order.
fn assert_complete(dir: &Path, n: usize) -> Vec<String> {
    let m = Manifest::load(dir).unwrap();
    let files = final_files(dir);
    assert_eq!(m.indenter, "cone");
    assert_eq!(m.sensor.id, "sim-source");
    assert_eq!(m.trajectories.len(), n, "{m:#?}");
    assert_eq!(files.len(), n, "{files:#?}");
    for t in &m.trajectories {
        assert_eq!(t.status, Status::Complete, "{t:?}");
        assert_eq!(t.file.as_deref(), Some(final_name(&t.id).as_str()));
        let counts = &files[&t.id];
        assert_eq!(&t.counts, counts, "{}", t.id);
        assert_eq!(counts.stages, 4, "{}: down, shear, reverse, up", t.id);
        assert!(counts.poses > 100, "{}: {counts:?}", t.id);
        // A trajectory of the cone plan lasts over 5 s of clock time: at 25 fps and 1 kHz,
        // over 100 frames and 4000 wrench samples; every frame has its pair and its truth.
        assert!(counts.frames > 100, "{}: {counts:?}", t.id);
        assert!(counts.wrench > 4000, "{}: {counts:?}", t.id);
        assert_eq!(counts.paired, counts.frames, "{}: {counts:?}", t.id);
        assert_eq!(counts.truth, counts.frames, "{}: {counts:?}", t.id);
        assert_eq!(t.frames_dropped, 0, "{}", t.id);
    }
    m.trajectories.iter().map(|t| t.id.clone()).collect()
}

#[test]
fn a_run_records_one_complete_file_per_trajectory() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let out_dir = tmp.path().join("run");
    let out = run_ok(&mut rig_run(&cfg, &out_dir, 3, &[]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("3 trajectories recorded"), "{}", text(&out));
    assert!(stdout.contains("dataset check: OK"), "{}", text(&out));
    assert_complete(&out_dir, 3);
    dataset_check_ok(&out_dir);
}

#[test]
fn a_killed_run_resumes_into_the_same_dataset() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();

    // The reference: an uninterrupted run.
    let reference = tmp.path().join("reference");
    run_ok(&mut rig_run(&cfg, &reference, 4, &[]));
    let ref_ids = assert_complete(&reference, 4);

    // The same run, killed once its first trajectory is complete.
    let crashed = tmp.path().join("crashed");
    let log = std::fs::File::create(tmp.path().join("killed.log")).unwrap();
    let mut child = rig_run(&cfg, &crashed, 4, &[])
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .unwrap();
    // Killed once the first file exists and the manifest marks it complete (the manifest is
    // rewritten atomically, so reading it meanwhile is safe), so the resume has one to skip.
    let first = crashed.join(final_name(&ref_ids[0]));
    let first_done = || {
        first.exists()
            && Manifest::load(&crashed).is_ok_and(|m| {
                m.entry(&ref_ids[0])
                    .is_some_and(|e| e.status == Status::Complete)
            })
    };
    let t0 = Instant::now();
    while !first_done() {
        if let Some(status) = child.try_wait().unwrap() {
            panic!(
                "the run ended ({status:?}) before {} appeared:\n{}",
                first.display(),
                std::fs::read_to_string(tmp.path().join("killed.log")).unwrap_or_default()
            );
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "{} never appeared",
            first.display()
        );
        std::thread::sleep(Duration::from_millis(1));
    }
    assert!(
        child.try_wait().unwrap().is_none(),
        "the run ended before it could be killed"
    );
    child.kill().unwrap(); // SIGKILL on Unix
    let status = child.wait().unwrap();
    assert_eq!(status.signal(), Some(9), "{status:?}");

    // Nothing half-written under a final name, and the run really was cut short.
    let files = final_files(&crashed);
    assert!(files.contains_key(&ref_ids[0]));
    let m = Manifest::load(&crashed).unwrap();
    assert!(
        m.trajectories.iter().any(|t| t.status != Status::Complete),
        "the killed run had already finished: {m:#?}"
    );
    for t in m
        .trajectories
        .iter()
        .filter(|t| t.status == Status::Complete)
    {
        assert!(files.contains_key(&t.id), "{} complete but no file", t.id);
    }

    let out = run_ok(&mut rig_run(&cfg, &crashed, 4, &["--resume"]));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("already complete"),
        "resume did not say what it skipped:\n{}",
        text(&out)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        !stdout.contains(" 0 skipped"),
        "nothing skipped:\n{}",
        text(&out)
    );

    let ids = assert_complete(&crashed, 4);
    assert_eq!(ids, ref_ids);
    assert_eq!(
        final_files(&crashed).keys().collect::<Vec<_>>(),
        final_files(&reference).keys().collect::<Vec<_>>()
    );
    let leftovers: Vec<String> = std::fs::read_dir(&crashed)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    dataset_check_ok(&crashed);
    dataset_check_ok(&reference);
}

#[test]
fn an_existing_recording_is_only_continued_with_resume() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let out_dir = tmp.path().join("run");
    run_ok(&mut rig_run(&cfg, &out_dir, 1, &[]));
    let before = final_files(&out_dir);

    let out = rig_run(&cfg, &out_dir, 1, &[]).output().unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("--resume"), "{}", text(&out));
    assert!(stderr.contains("--out"), "{}", text(&out));
    // Refused before anything connected or was written.
    assert!(!stderr.contains("simulated UR5e on"), "{}", text(&out));
    assert_eq!(final_files(&out_dir), before);
    dataset_check_ok(&out_dir);
}

#[test]
fn resume_refuses_another_indenter_or_config() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let out_dir = tmp.path().join("run");
    run_ok(&mut rig_run(&cfg, &out_dir, 1, &[]));

    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cylinder", "--resume", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("indenter `cone`"), "{}", text(&out));

    // Another shear distance: the same indenter, a different [plan].
    let other_cfg = common::edited_sim_config(
        tmp.path(),
        "other.toml",
        &[("shear_distance_mm = 2.0", "shear_distance_mm = 1.5")],
    );
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cone", "--resume", "--config"])
        .arg(&other_cfg)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("different rig config") && stderr.contains("[plan]"),
        "{}",
        text(&out)
    );
    assert_complete(&out_dir, 1);
}

#[test]
fn the_default_output_is_named_after_indenter_and_sensor() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let out = run_ok(
        Command::new(env!("CARGO_BIN_EXE_rig"))
            .args(["run", "--indenter", "cone", "--config"])
            .arg(&cfg)
            .args(["--limit", "1", "--speed-factor", "20"])
            .current_dir(tmp.path()),
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("recording into runs/cone-sim-source"),
        "{}",
        text(&out)
    );
    assert_complete(&tmp.path().join("runs/cone-sim-source"), 1);
}

/// Absurd command-line values are refused with an error that names them, before anything
/// starts, never with a panic (exit code 101).
#[test]
fn extreme_command_line_values_are_errors_not_panics() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let run = |extra: &[&str]| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_rig"));
        cmd.args(["run", "--indenter", "cone", "--config"])
            .arg(&cfg)
            .arg("--out")
            .arg(tmp.path().join("never"))
            .args(["--limit", "1"])
            .args(extra);
        cmd.output().unwrap()
    };
    for factor in ["1e308", "inf", "NaN", "0", "-1", "1001"] {
        let out = run(&[&format!("--speed-factor={factor}")]);
        let t = text(&out);
        assert!(
            matches!(out.status.code(), Some(1 | 2)),
            "--speed-factor {factor}:\n{t}"
        );
        assert!(!t.contains("panicked"), "--speed-factor {factor}:\n{t}");
        assert!(
            t.contains("--speed-factor"),
            "--speed-factor {factor}:\n{t}"
        );
        assert!(!t.contains("simulated UR5e on"), "started the rig:\n{t}");
    }
    let out = run(&["--sim-fault", "protective-stop@p0-d0.2-a000/down+1e300"]);
    let t = text(&out);
    assert_eq!(out.status.code(), Some(2), "{t}");
    assert!(t.contains("at most 3600000 ms"), "{t}");
    assert!(!tmp.path().join("never").exists());
}

/// The F/T calibration file replaced between a run and its resume (same config, same path):
/// the resume is refused before anything moves, naming the calibration, and the recording is
/// left as it was.
#[test]
fn resume_refuses_another_ft_calibration() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cal = tmp.path().join("ft.cal");
    let original = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/nano17_axis_only.cal"
    ))
    .unwrap();
    std::fs::write(&cal, &original).unwrap();
    let line = "kind = \"sim\"                # the simulated Nano17";
    let cfg = common::edited_sim_config(
        tmp.path(),
        "cal.toml",
        &[(
            line,
            &format!("{line}\ncalibration_file = {:?}", cal.display().to_string()),
        )],
    );
    let out_dir = tmp.path().join("run");
    run_ok(&mut rig_run(&cfg, &out_dir, 1, &[]));
    let before = final_files(&out_dir);

    assert!(original.contains("Serial=\"FT90018\""));
    std::fs::write(
        &cal,
        original.replace("Serial=\"FT90018\"", "Serial=\"FT90099\""),
    )
    .unwrap();
    let out = rig_run(&cfg, &out_dir, 2, &["--resume"]).output().unwrap();
    assert_eq!(out.status.code(), Some(1), "{}", text(&out));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("another F/T calibration") && stderr.contains("calibration_file"),
        "{}",
        text(&out)
    );
    assert_eq!(final_files(&out_dir), before);

    // The original file back: the resume goes on.
    std::fs::write(&cal, &original).unwrap();
    run_ok(&mut rig_run(&cfg, &out_dir, 2, &["--resume"]));
    assert_complete(&out_dir, 2);
}

/// Two runs into one `--out`: the second is refused at once, even with --resume, while the first
/// records on undisturbed; after it ends the lock is gone and a resume is accepted.
#[test]
fn a_second_run_into_the_same_out_is_refused_while_the_first_records() {
    let _g = serial();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = config();
    let out_dir = tmp.path().join("run");
    let first = rig_run(&cfg, &out_dir, 2, &[])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The manifest is written once the first run holds the lock and has started recording.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    while !out_dir.join("manifest.json").exists() {
        assert!(
            std::time::Instant::now() < deadline,
            "the first run never started recording"
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let second = rig_run(&cfg, &out_dir, 2, &["--resume"]).output().unwrap();
    let first = first.wait_with_output().unwrap();
    assert!(first.status.success(), "first run:\n{}", text(&first));
    assert_eq!(second.status.code(), Some(1), "{}", text(&second));
    assert!(
        String::from_utf8_lossy(&second.stderr).contains("another rig run is writing into"),
        "{}",
        text(&second)
    );
    assert_complete(&out_dir, 2);
    // The lock went with the first process.
    let again = run_ok(&mut rig_run(&cfg, &out_dir, 2, &["--resume"]));
    assert!(text(&again).contains("nothing to do"), "{}", text(&again));
}
