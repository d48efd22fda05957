//! `rig dataset check`: a recorded dataset passes; each kind of damage gets its own verdict and
//! a non-zero exit.

use std::path::Path;
use std::process::Command;

use rig::dataset::{Verdict, check};
use rig::record::synthetic::{SyntheticSpec, record_dataset};
use rig::record::{final_name, partial_name};

fn ids() -> Vec<String> {
    (0..3).map(|i| format!("p{i}-d1-a30")).collect()
}

fn build(dir: &Path, drops: Vec<u64>) {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let spec = SyntheticSpec {
        drop_frames: drops,
        ..Default::default()
    };
    rt.block_on(record_dataset(dir, &ids(), &spec)).unwrap();
}

fn rig_check(dir: &Path) -> (bool, serde_json::Value) {
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check", "--json"])
        .arg(dir)
        .output()
        .unwrap();
    let json = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}): {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    });
    (out.status.success(), json)
}

#[test]
fn a_complete_dataset_passes_with_counts_and_sync_statistics() {
    let dir = tempfile::tempdir().unwrap();
    build(dir.path(), vec![4, 5]);
    let (ok, j) = rig_check(dir.path());
    assert!(ok, "{j:#}");
    assert_eq!(j["complete"], 3);
    assert_eq!(j["problems"], 0);
    let t = &j["trajectories"][0];
    assert_eq!(t["verdict"], "complete");
    assert_eq!(t["counts"]["frames"], 11);
    assert_eq!(t["counts"]["wrench"], 401);
    assert_eq!(t["counts"]["poses"], 201);
    assert_eq!(t["frames_dropped"], 2);
    assert_eq!(t["frame_gaps"][0]["after_seq"], 3);
    assert_eq!(t["frame_gaps"][0]["missing"], 2);
    assert_eq!(t["wrench_seq_gaps"].as_array().unwrap().len(), 0);
    // Frames fall exactly on wrench samples in the synthetic data.
    assert_eq!(t["sync_error"]["n"], 11);
    assert!(t["sync_error"]["max_ns"].as_f64().unwrap() < 1.0);
    assert_eq!(j["frames_dropped"], 6);
}

#[test]
fn truncated_missing_partial_and_failed_trajectories_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    build(dir.path(), vec![]);
    let ids = ids();
    // 0: truncated file.
    let p0 = dir.path().join(final_name(&ids[0]));
    let len = std::fs::metadata(&p0).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p0)
        .unwrap()
        .set_len(len - 100)
        .unwrap();
    // 1: removed file.
    std::fs::remove_file(dir.path().join(final_name(&ids[1]))).unwrap();
    // 2: stale partial beside the complete file.
    std::fs::write(dir.path().join(partial_name(&ids[2])), b"partial").unwrap();

    let r = check(dir.path());
    let v: Vec<Verdict> = r.trajectories.iter().map(|t| t.verdict).collect();
    assert_eq!(
        v,
        vec![Verdict::Unreadable, Verdict::Missing, Verdict::Incomplete]
    );
    assert_eq!(r.stale_partials, vec![partial_name(&ids[2])]);
    assert!(!r.ok());
    let (ok, j) = rig_check(dir.path());
    assert!(!ok, "damaged dataset must exit non-zero");
    assert_eq!(j["problems"], 3);
}

#[test]
fn failed_pending_and_unlisted_trajectories_fail_the_check() {
    let dir = tempfile::tempdir().unwrap();
    build(dir.path(), vec![]);
    let ids = ids();
    let mut m = rig::record::Manifest::load(dir.path()).unwrap();
    m.entry_mut(&ids[0]).status = rig::record::Status::Failed;
    m.entry_mut(&ids[0]).reason = Some("protective stop".into());
    m.entry_mut(&ids[1]).status = rig::record::Status::Pending;
    m.trajectories.retain(|t| t.id != ids[2]);
    m.save(dir.path()).unwrap();
    let r = check(dir.path());
    let v: Vec<(String, Verdict)> = r
        .trajectories
        .iter()
        .map(|t| (t.id.clone(), t.verdict))
        .collect();
    assert_eq!(
        v,
        vec![
            (ids[0].clone(), Verdict::Incomplete),
            (ids[1].clone(), Verdict::Incomplete),
            (ids[2].clone(), Verdict::Unlisted),
        ]
    );
    assert!(
        r.trajectories[0]
            .reason
            .as_deref()
            .unwrap()
            .contains("protective stop")
    );
    assert!(!rig_check(dir.path()).0);
}

#[test]
fn a_directory_without_manifest_fails_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let r = check(dir.path());
    assert!(
        r.manifest_error
            .as_deref()
            .unwrap()
            .contains("manifest.json")
    );
    assert!(!r.ok());
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check"])
        .arg(dir.path().join("nope"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not complete"));
}
