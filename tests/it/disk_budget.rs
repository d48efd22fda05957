//! The disk budget of `rig run` on the simulated rig, on small tmpfs disks (`unshare -rm` and a
//! tmpfs mount, as the full-disk drill in `fault_drills`): a run the disk cannot hold is
//! refused before anything connects, with both numbers; a disk that fills up mid-run stops the
//! run before the trajectory that no longer fits, cleanly and resumably.

use std::path::Path;
use std::process::Command;

use rig::plan::Plan;
use rig::record::{Manifest, Status, final_name, read_file};
use rig::run::budget::Budget;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use crate::common;

const T1: &str = "p0-d0.2-a000";
const T2: &str = "p0-d0.2-a030";
const T3: &str = "p0-d0.2-a060";

/// The budget `rig run` computes for `cfg` with the cone (its frame rendered at the whole
/// plan's deepest press, as `--limit` leaves it), and the plan's first `n` trajectories.
fn budget(cfg: &Path, n: usize) -> (Budget, Plan) {
    let config = RigConfig::load(cfg).unwrap();
    let indenter = Indenter::builtin("cone").unwrap();
    let mut plan = Plan::build(&config, &indenter).unwrap();
    let budget = Budget::for_run(&config, &plan, &indenter);
    plan.trajectories.truncate(n);
    (budget, plan)
}

/// Every `(N bytes)` of a message, in order.
fn byte_counts(text: &str) -> Vec<u64> {
    text.split('(')
        .skip(1)
        .filter_map(|s| s.split_once(" bytes)"))
        .filter_map(|(n, _)| n.parse().ok())
        .collect()
}

/// `a` within 3 % of `b` (the frame the binary renders for its estimate has its own noise).
fn close(a: u64, b: u64) -> bool {
    a.abs_diff(b) as f64 <= 0.03 * b as f64
}

/// Runs `script` in a user and mount namespace (the tmpfs lives only there).
fn in_namespace(script: &str) {
    let status = Command::new("unshare")
        .args(["-rm", "sh", "-c", script])
        .status()
        .unwrap();
    assert!(status.success(), "the namespace script failed:\n{script}");
}

fn read(p: &Path) -> String {
    std::fs::read_to_string(p).unwrap_or_default()
}

fn rc(p: &Path) -> i32 {
    read(p).trim().parse().unwrap()
}

#[test]
fn a_run_the_disk_cannot_hold_is_refused_before_anything_connects() {
    let _g = common::one_rig_at_a_time();
    common::needs_unshare();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = common::edited_sim_config(tmp.path(), "rig.toml", &[]);
    let (b, plan) = budget(&cfg, 3);
    let est = b.trajectories(&plan.trajectories);
    assert_eq!(est.trajectories, 3);
    // 3 × 5.04 s at 25 fps.
    assert_eq!(est.frames, 3 * 126);
    let need = est.required();
    // A disk of half the estimate (whole pages: tmpfs counts in 4 KiB pages).
    let size = (need / 2).div_ceil(4096) * 4096;
    let mnt = tmp.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let (log, rcf, listing) = (
        tmp.path().join("log"),
        tmp.path().join("rc"),
        tmp.path().join("listing"),
    );
    in_namespace(&format!(
        "mount -t tmpfs -o size={size} tmpfs {mnt} && \
         {rig} run --indenter cone --config {cfg} --out {mnt}/run --limit 3 > {log} 2>&1; \
         echo $? > {rc}; ls -A {mnt}/run > {listing}",
        mnt = mnt.display(),
        rig = env!("CARGO_BIN_EXE_rig"),
        cfg = cfg.display(),
        log = log.display(),
        rc = rcf.display(),
        listing = listing.display(),
    ));
    let log = read(&log);
    assert_ne!(rc(&rcf), 0, "{log}");
    assert!(log.contains("not enough disk space"), "{log}");
    let n = byte_counts(&log);
    assert!(n.len() >= 2, "{log}");
    // The estimate (with its margin) the library computes, and the tmpfs's free bytes.
    assert!(
        close(n[0], need),
        "estimate {} against {need}:\n{log}",
        n[0]
    );
    assert_eq!(n[1], size, "{log}");
    assert!(
        log.contains("--limit") && log.contains("choose another --out"),
        "{log}"
    );
    // Nothing started: no manifest, no trajectory file; the simulated rig never came up, so
    // nothing connected and nothing moved.
    assert_eq!(read(&listing).trim(), "", "{log}");
    assert!(!log.contains("simulated rig: UR5e RTDE"), "{log}");
    assert!(!log.contains("trajectories recorded"), "{log}");
}

#[test]
fn a_disk_filled_mid_run_stops_before_the_next_trajectory_and_resume_completes() {
    let _g = common::one_rig_at_a_time();
    common::needs_unshare();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = common::edited_sim_config(tmp.path(), "rig.toml", &[]);
    let (b, plan) = budget(&cfg, 3);
    let [t1, t2, t3] = [0, 1, 2].map(|k| b.trajectory(&plan.trajectories[k]));
    let need3 = (t1 + t2 + t3).required();
    // The disk holds the whole run at the start; a filler written while the first trajectory
    // records leaves its estimate (what it still writes, if the estimate is right) and half a
    // MiB: less than the second's estimate with its margin.
    let size = (need3 + (4 << 20)).div_ceil(4096) * 4096;
    let leave = t1.bytes + (512 << 10);
    assert!(leave < t2.required(), "{leave} {}", t2.required());
    let mnt = tmp.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let f = |name: &str| tmp.path().join(name);
    let (log1, rc1, log2, rc2, du) = (f("log1"), f("rc1"), f("log2"), f("rc2"), f("du"));
    let (copy1, copy2) = (f("copy1"), f("copy2"));
    let run = format!(
        "{rig} run --indenter cone --config {cfg} --out {mnt}/run --limit 3",
        rig = env!("CARGO_BIN_EXE_rig"),
        cfg = cfg.display(),
        mnt = mnt.display(),
    );
    in_namespace(&format!(
        "set -u; mount -t tmpfs -o size={size} tmpfs {mnt} || exit 1; \
         {run} > {log1} 2>&1 & pid=$!; \
         while [ ! -e {mnt}/run/.{T1}.mcap.partial ] && kill -0 $pid 2>/dev/null; do sleep 0.01; done; \
         avail=$(df -B1 --output=avail {mnt} | tail -n 1); \
         head -c $((avail - {leave})) /dev/zero > {mnt}/filler; \
         wait $pid; echo $? > {rc1}; cp -a {mnt}/run {copy1}; \
         rm {mnt}/filler; \
         {run} --resume > {log2} 2>&1; echo $? > {rc2}; \
         du -sb {mnt}/run > {du}; cp -a {mnt}/run {copy2}",
        mnt = mnt.display(),
        log1 = log1.display(),
        rc1 = rc1.display(),
        copy1 = copy1.display(),
        log2 = log2.display(),
        rc2 = rc2.display(),
        du = du.display(),
        copy2 = copy2.display(),
    ));
    let (log1, log2) = (read(&log1), read(&log2));
    // The run started (the rig came up), recorded the first trajectory, and stopped before the
    // second with the numbers and what to do.
    assert_ne!(rc(&rc1), 0, "{log1}");
    assert!(log1.contains("simulated rig: UR5e RTDE"), "{log1}");
    let line = log1
        .lines()
        .find(|l| l.contains("not enough disk space left to record trajectory"))
        .unwrap_or_else(|| panic!("no disk-budget stop:\n{log1}"));
    assert!(line.contains(T2), "{line}");
    assert!(line.contains("--resume"), "{line}");
    let n = byte_counts(line);
    assert_eq!(n.len(), 3, "{line}");
    // Free: what the filler left, less the rest of the first trajectory's file.
    assert!(
        n[0] > 0 && n[0] <= leave,
        "free {} (left {leave}): {line}",
        n[0]
    );
    assert!(
        close(n[1], t2.required()),
        "{} against {}: {line}",
        n[1],
        t2.required()
    );
    assert!(
        close(n[2], (t2 + t3).required()),
        "{} against {}: {line}",
        n[2],
        (t2 + t3).required()
    );
    assert!(!log1.contains("No space left on device"), "{log1}");
    assert!(
        log1.contains(&format!("run stopped at trajectory {T2}")),
        "{log1}"
    );
    // The first trajectory is intact; the others pending (never started), no partial file.
    let m = Manifest::load(&copy1).unwrap();
    let e = m.entry(T1).unwrap();
    assert_eq!(e.status, Status::Complete, "{e:?}");
    let c = read_file(&copy1.join(final_name(T1))).unwrap();
    assert_eq!(c.counts, e.counts);
    assert!(c.counts.frames > 100, "{:?}", c.counts);
    for id in [T2, T3] {
        assert_eq!(m.entry(id).unwrap().status, Status::Pending, "{id}");
        assert!(!copy1.join(final_name(id)).exists(), "{id}");
    }
    let names: Vec<String> = std::fs::read_dir(&copy1)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.ends_with(".partial")), "{names:?}");

    // With the filler gone, --resume records the rest.
    assert_eq!(rc(&rc2), 0, "{log2}");
    assert!(log2.contains("1 skipped"), "{log2}");
    let m = Manifest::load(&copy2).unwrap();
    for id in [T1, T2, T3] {
        assert_eq!(m.entry(id).unwrap().status, Status::Complete, "{id}");
    }
    // The closing report's disk line: the directory's size as `du -sb` counts it, per frame.
    let du: u64 = read(&du)
        .split_whitespace()
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap();
    let frames: u64 = m.trajectories.iter().map(|t| t.counts.frames).sum();
    let disk = log2
        .lines()
        .find(|l| l.starts_with("disk: "))
        .unwrap_or_else(|| panic!("no disk line:\n{log2}"));
    assert!(
        disk.contains(&format!("({du} bytes) written")),
        "{disk} (du {du})"
    );
    assert!(
        disk.contains(&format!(
            "{} bytes per frame over its {frames} frames",
            du / frames
        )),
        "{disk}"
    );
    // The recording fits its estimate: the files of the three trajectories under it.
    let files: u64 = [T1, T2, T3]
        .iter()
        .map(|id| std::fs::metadata(copy2.join(final_name(id))).unwrap().len())
        .sum();
    assert!(
        files < (t1 + t2 + t3).bytes,
        "{files} >= {}",
        (t1 + t2 + t3).bytes
    );
}

#[test]
fn rig_reproduce_sums_every_recording_and_refuses_before_recording_any() {
    common::needs_unshare();
    let tmp = tempfile::tempdir().unwrap();
    let mnt = tmp.path().join("small");
    std::fs::create_dir(&mnt).unwrap();
    let size: u64 = 4 << 20;
    let (log, rcf, listing) = (
        tmp.path().join("log"),
        tmp.path().join("rc"),
        tmp.path().join("listing"),
    );
    in_namespace(&format!(
        "mount -t tmpfs -o size={size} tmpfs {mnt} && \
         {rig} reproduce --scale tiny --no-fid --out {mnt}/rep > {log} 2>&1; \
         echo $? > {rc}; find {mnt}/rep -name '*.mcap' -o -name manifest.json > {listing}",
        mnt = mnt.display(),
        rig = env!("CARGO_BIN_EXE_rig"),
        log = log.display(),
        rc = rcf.display(),
        listing = listing.display(),
    ));
    let log = read(&log);
    assert_ne!(rc(&rcf), 0, "{log}");
    let line = log
        .lines()
        .find(|l| l.contains("not enough disk space for rig reproduce's recordings"))
        .unwrap_or_else(|| panic!("no refusal:\n{log}"));
    // Three indenters × two sensors, two trajectories each (the tiny scale).
    assert!(line.contains("6 recordings of 12 trajectories"), "{line}");
    let n = byte_counts(line);
    assert_eq!(n.len(), 2, "{line}");
    assert!(n[0] > size, "{line}");
    assert_eq!(n[1], size, "{line}");
    assert_eq!(read(&listing).trim(), "", "{log}");
}
