//! `rig dataset check`: a recorded dataset passes; each kind of damage gets its own verdict and
//! a non-zero exit; frame drops nothing explains and (simulated rig) the paired wrench against
//! the simulator's true wrench are reported with their real values.

use std::path::Path;
use std::process::{Command, Output};

use rig::dataset::{CheckOptions, RangeSource, Verdict, check, check_with, render};
use rig::record::synthetic::{SyntheticSpec, png_frame, record_dataset};
use rig::record::{
    Counts, Manifest, Record, SensorInfo, Status, TrajectoryWriter, final_name, partial_name,
};
use rig::sync::{PairedFrame, SyncStatus};
use rig_core::wrench::Wrench;

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

// ---------------------------------------------------------------------------------------------
// Unexplained drops and the paired-vs-true wrench, on files written message by message so every
// error is known exactly.

const NANO17: [f64; 6] = [25.0, 25.0, 35.0, 250.0, 250.0, 250.0];

/// One frame of a hand-written trajectory.
struct F {
    seq: i64,
    /// `None`: no paired message; `Some(None)`: a refused pairing (wrench null).
    paired: Option<Option<Wrench>>,
    truth: Option<Wrench>,
}

/// A frame with a paired and a true wrench.
fn both(seq: i64, truth: [f64; 6], delta: [f64; 6]) -> F {
    let paired: Vec<f64> = truth.iter().zip(delta).map(|(t, d)| t + d).collect();
    F {
        seq,
        paired: Some(Some(Wrench::from_array(paired.try_into().unwrap()))),
        truth: Some(Wrench::from_array(truth)),
    }
}

/// A varying but realistic true wrench for frame `k`.
fn truth_at(k: i64) -> [f64; 6] {
    let s = k as f64 * 0.05;
    [
        0.4 * s.sin(),
        -0.2 * s.cos(),
        -3.0 - s,
        12.0 * s.sin(),
        -8.0,
        0.5,
    ]
}

fn dz(fz: f64) -> [f64; 6] {
    [0.0, 0.0, fz, 0.0, 0.0, 0.0]
}

/// Write `<dir>/<id>.mcap` with `frames` (33 ms apart); returns its counts.
fn write_traj(dir: &Path, id: &str, frames: &[F]) -> Counts {
    let mut w = TrajectoryWriter::create(dir, id).unwrap();
    for f in frames {
        let t_ns = 1_000_000_000 + f.seq as u64 * 33_000_000;
        w.write(&Record::Frame {
            seq: f.seq,
            t_ns,
            format: rig::record::ImageFormat::Png,
            data: png_frame(4, 3, f.seq as u64),
        })
        .unwrap();
        if let Some(tw) = f.truth {
            w.write(&Record::Truth {
                frame_seq: f.seq,
                t_ns,
                wrench: tw,
            })
            .unwrap();
        }
        if let Some(p) = f.paired {
            w.write(&Record::Paired(PairedFrame {
                frame_seq: f.seq,
                t_frame_ns: t_ns as f64,
                wrench: p,
                sync_error_ns: p.map(|_| 1000.0),
                status: if p.is_some() {
                    SyncStatus::Ok
                } else {
                    SyncStatus::Gap
                },
                stage: None,
                tcp_pose: None,
            }))
            .unwrap();
        }
    }
    w.finish().unwrap()
}

/// Write `manifest.json` listing `trajs` (id, counts, drops the camera reported) as complete.
fn write_manifest(dir: &Path, calibration: serde_json::Value, trajs: &[(&str, Counts, u64)]) {
    let ids: Vec<String> = trajs.iter().map(|t| t.0.to_owned()).collect();
    let mut m = Manifest::new(
        "cone",
        SensorInfo {
            id: "sim-source".into(),
            role: "source".into(),
        },
        serde_json::json!({}),
        calibration,
        &ids,
    );
    for (id, counts, dropped) in trajs {
        let e = m.entry_mut(id);
        e.status = Status::Complete;
        e.counts = counts.clone();
        e.frames_dropped = *dropped;
        e.file = Some(final_name(id));
    }
    m.save(dir).unwrap();
}

fn rig(dir: &Path, extra: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check"])
        .args(extra)
        .arg(dir)
        .output()
        .unwrap()
}

fn json_of(out: &Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}): {}\n{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )
    })
}

fn close(a: &serde_json::Value, b: f64) -> bool {
    a.as_f64().is_some_and(|a| (a - b).abs() < 1e-9)
}

/// Three trajectories with every kind of frame:
/// - `a`: 200 frames, paired = truth + 0.3 N on Fz (0.857 % of 35 N) and + 1 N·mm on Tx (0.4 %),
///   except frame 7: + 1.0 N on Fz (2.857 %).
/// - `b`: frames 0..=9 without 5 (a gap the manifest does not explain); frame 2 refused (wrench
///   null), frame 8 paired but without truth, frame 9 with truth but no paired message; the
///   others + 0.25 N on Fx (1 % of 25 N).
/// - `c`: frames 0, 1, 2, 5, 6 (2 missing; the manifest says the camera reported 2), exact.
fn truth_dataset(dir: &Path, calibration: serde_json::Value) {
    let a: Vec<F> = (0..200)
        .map(|k| {
            let mut d = dz(if k == 7 { 1.0 } else { 0.3 });
            d[3] = 1.0;
            both(k, truth_at(k), d)
        })
        .collect();
    let mut b: Vec<F> = [0, 1, 3, 4, 6, 7]
        .into_iter()
        .map(|k| both(k, truth_at(k), [0.25, 0.0, 0.0, 0.0, 0.0, 0.0]))
        .collect();
    b.push(F {
        seq: 2,
        paired: Some(None),
        truth: Some(Wrench::from_array(truth_at(2))),
    });
    b.push(F {
        seq: 8,
        paired: Some(Some(Wrench::from_array(truth_at(8)))),
        truth: None,
    });
    b.push(F {
        seq: 9,
        paired: None,
        truth: Some(Wrench::from_array(truth_at(9))),
    });
    b.sort_by_key(|f| f.seq);
    let c: Vec<F> = [0, 1, 2, 5, 6]
        .into_iter()
        .map(|k| both(k, truth_at(k), [0.0; 6]))
        .collect();
    let ca = write_traj(dir, "a", &a);
    let cb = write_traj(dir, "b", &b);
    let cc = write_traj(dir, "c", &c);
    write_manifest(
        dir,
        calibration,
        &[("a", ca, 0), ("b", cb, 0), ("c", cc, 2)],
    );
}

#[test]
fn paired_vs_true_wrench_and_unexplained_drops_are_reported_with_their_values() {
    let dir = tempfile::tempdir().unwrap();
    truth_dataset(dir.path(), serde_json::json!({ "max_loads": NANO17 }));
    let out = rig(dir.path(), &["--json"]);
    // Accuracy is reported, not judged, without --max-error-pct.
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j = json_of(&out);
    assert_eq!(j["complete"], 3);
    assert_eq!(j["full_range"]["source"], "manifest");
    assert_eq!(j["full_range"]["note"], serde_json::Value::Null);
    assert_eq!(j["error_limit"], serde_json::Value::Null);

    let a = &j["trajectories"][0];
    assert_eq!(a["id"], "a");
    let ta = &a["truth"];
    assert_eq!(ta["frames_with_truth"], 200);
    assert_eq!(ta["compared"], 200);
    assert_eq!(ta["unpaired"], 0);
    assert!(close(&ta["worst_axis_max_pct"], 1.0 / 35.0 * 100.0), "{ta}");
    // 199 frames at 0.3 N of 35 N: the p99 of 200 frames (nearest rank 198) is 0.857 %.
    assert!(close(&ta["worst_axis_p99_pct"], 0.3 / 35.0 * 100.0), "{ta}");
    assert_eq!(ta["frames_above_2pct"], 1);
    assert!(close(&ta["max_force_error_n"], 1.0), "{ta}");
    assert!(close(&ta["axis_max_pct"][3], 0.4), "{ta}");
    assert!(close(&ta["axis_max_pct"][0], 0.0), "{ta}");
    assert_eq!(ta["worst"]["trajectory"], "a");
    assert_eq!(ta["worst"]["frame_seq"], 7);
    assert_eq!(ta["worst"]["axis"], "Fz");
    assert!(close(&ta["worst"]["abs_error"], 1.0), "{ta}");
    assert_eq!(a["frames_dropped"], 0);
    assert_eq!(a["frames_dropped_unexplained"], 0);

    let b = &j["trajectories"][1];
    let tb = &b["truth"];
    assert_eq!(tb["frames_with_truth"], 8);
    assert_eq!(tb["compared"], 6);
    assert_eq!(
        tb["unpaired"], 2,
        "refused frame 2 and frame 9 without a pairing"
    );
    assert_eq!(tb["paired_without_truth"], 1);
    assert!(close(&tb["worst_axis_max_pct"], 1.0), "{tb}");
    assert_eq!(tb["worst"]["axis"], "Fx");
    assert_eq!(tb["frames_above_2pct"], 0);
    assert_eq!(b["frames_dropped"], 1);
    assert_eq!(b["frames_dropped_reported"], 0);
    assert_eq!(b["frames_dropped_unexplained"], 1);

    let c = &j["trajectories"][2];
    assert!(close(&c["truth"]["worst_axis_max_pct"], 0.0));
    assert_eq!(c["frames_dropped"], 2);
    assert_eq!(c["frames_dropped_reported"], 2);
    assert_eq!(c["frames_dropped_unexplained"], 0);

    // Dataset-wide.
    assert_eq!(j["frames_dropped"], 3);
    assert_eq!(j["frames_dropped_reported"], 2);
    assert_eq!(j["frames_dropped_unexplained"], 1);
    let t = &j["truth"];
    assert_eq!(t["compared"], 211);
    assert_eq!(t["frames_with_truth"], 213);
    assert_eq!(t["unpaired"], 2);
    assert_eq!(t["paired_without_truth"], 1);
    assert_eq!(t["frames_above_2pct"], 1);
    assert!(close(&t["worst_axis_max_pct"], 1.0 / 35.0 * 100.0), "{t}");
    // 211 frames: 5 at 0, 199 at 0.857 %, 6 at 1 %, 1 at 2.857 %; nearest rank 209 is 1 %.
    assert!(close(&t["worst_axis_p99_pct"], 1.0), "{t}");
    assert!(close(&t["max_force_error_n"], 1.0), "{t}");
    assert!(close(&t["axis_max_pct"][0], 1.0), "{t}");
    assert_eq!(t["worst"]["trajectory"], "a");
    assert_eq!(t["worst"]["frame_seq"], 7);

    // The operator's report: one line each.
    let out = rig(dir.path(), &[]);
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains(
            "  paired vs true wrench: worst axis max 2.86 % of full range, p99 1.00 %, \
             1 frames above 2 %; max |ΔF| 1.000 N; 2 unpaired\n"
        ),
        "{text}"
    );
    assert!(
        text.contains("  frame drops: 3 (1 unexplained)\n"),
        "{text}"
    );
    assert!(
        text.contains("  sync error p50 1.0 µs p99 1.0 µs max 1.0 µs\n"),
        "{text}"
    );
    assert!(
        text.contains(
            "frames: 1 missing from the sequence, 0 reported lost by the camera: 1 unexplained"
        ),
        "{text}"
    );
    assert!(!text.contains("fallback"), "{text}");
}

#[test]
fn max_error_pct_fails_the_check_naming_the_worst_trajectory_and_frame() {
    let dir = tempfile::tempdir().unwrap();
    truth_dataset(dir.path(), serde_json::json!({ "max_loads": NANO17 }));

    let out = rig(dir.path(), &["--json", "--max-error-pct", "2"]);
    assert!(!out.status.success(), "frame a/7 is 2.86 % off");
    let j = json_of(&out);
    assert_eq!(j["error_limit"]["max_error_pct"], 2.0);
    assert_eq!(j["error_limit"]["applied"], true);
    assert_eq!(j["error_limit"]["frames_above"], 1);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("trajectory a frame 7"), "{err}");
    assert!(err.contains("Fz off by 2.86 %"), "{err}");
    assert!(err.contains("more than 2 % of full range"), "{err}");

    // Every frame of a (0.857 % at least) and the 6 compared frames of b (1 %) are above 0.5 %.
    let r = check_with(
        dir.path(),
        &CheckOptions {
            max_error_pct: Some(0.5),
        },
    );
    assert!(r.ok(), "the dataset itself is complete");
    assert_eq!(r.error_limit.as_ref().unwrap().frames_above, 206);
    assert!(!r.within_error_limit());
    assert!(
        render(&r).contains("  error limit 0.5 %: 206 frames above; worst: a frame 7, Fz 2.86 %\n"),
        "{}",
        render(&r)
    );

    let out = rig(dir.path(), &["--max-error-pct", "3"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("  error limit 3 %: 0 frames above\n"));

    let out = rig(dir.path(), &["--max-error-pct", "-1"]);
    assert!(!out.status.success(), "a negative limit is refused");
}

#[test]
fn the_manifest_full_range_is_used_and_a_missing_one_falls_back_to_the_nano17() {
    // A smaller sensor: 0.3 N on Fz of a 10 N range is 3 %.
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<F> = (0..5).map(|k| both(k, truth_at(k), dz(0.3))).collect();
    let counts = write_traj(dir.path(), "t", &frames);
    write_manifest(
        dir.path(),
        serde_json::json!({"max_loads": [10.0, 10.0, 10.0, 100.0, 100.0, 100.0], "serial": "FT0"}),
        &[("t", counts.clone(), 0)],
    );
    let r = check(dir.path());
    assert_eq!(r.full_range.source, RangeSource::Manifest);
    let t = r.truth.as_ref().unwrap();
    assert!((t.worst_axis_max_pct - 3.0).abs() < 1e-9, "{t:?}");
    assert_eq!(t.frames_above_2pct, 5);

    // No calibration at all: the Nano17 SI-25-0.25 range, and the report says so.
    write_manifest(
        dir.path(),
        serde_json::Value::Null,
        &[("t", counts.clone(), 0)],
    );
    let r = check(dir.path());
    assert!(r.ok());
    assert_eq!(r.full_range.source, RangeSource::Fallback);
    assert_eq!(r.full_range.max_loads, NANO17);
    let t = r.truth.as_ref().unwrap();
    assert!(
        (t.worst_axis_max_pct - 0.3 / 35.0 * 100.0).abs() < 1e-9,
        "{t:?}"
    );
    assert_eq!(t.frames_above_2pct, 0);
    let text = render(&r);
    assert!(
        text.contains(
            "  full range: Nano17 SI-25-0.25 fallback [25, 25, 35, 250, 250, 250] (N, N·mm): \
             the manifest's calibration has no max_loads\n"
        ),
        "{text}"
    );
    assert!(
        text.contains("worst axis max 0.86 % of full range, p99 0.86 %, 0 frames above 2 %; max |ΔF| 0.300 N\n"),
        "{text}"
    );
    let j = json_of(&rig(dir.path(), &["--json"]));
    assert_eq!(j["full_range"]["source"], "fallback");
    assert!(
        j["full_range"]["note"]
            .as_str()
            .unwrap()
            .contains("no max_loads")
    );

    // A malformed max_loads is not trusted either.
    write_manifest(
        dir.path(),
        serde_json::json!({"max_loads": [25.0, 0.0, 35.0]}),
        &[("t", counts, 0)],
    );
    let r = check(dir.path());
    assert_eq!(r.full_range.source, RangeSource::Fallback);
    assert!(
        r.full_range
            .note
            .as_deref()
            .unwrap()
            .contains("six positive numbers")
    );
}

#[test]
fn a_dataset_without_truth_has_no_comparison_and_the_error_limit_is_not_applied() {
    let dir = tempfile::tempdir().unwrap();
    build(dir.path(), vec![4, 5]);
    let out = rig(dir.path(), &["--json", "--max-error-pct", "0.1"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let j = json_of(&out);
    assert_eq!(j["truth"], serde_json::Value::Null);
    assert_eq!(j["trajectories"][0]["truth"], serde_json::Value::Null);
    assert_eq!(j["error_limit"]["applied"], false);
    assert_eq!(j["error_limit"]["frames_above"], 0);
    // The synthetic recorder reports the drops it left out: known, not unexplained.
    assert_eq!(j["frames_dropped"], 6);
    assert_eq!(j["frames_dropped_reported"], 6);
    assert_eq!(j["frames_dropped_unexplained"], 0);
    assert!(String::from_utf8_lossy(&out.stderr).contains("not applied"));
    let text = String::from_utf8_lossy(&rig(dir.path(), &[]).stdout).into_owned();
    assert!(
        text.contains(
            "  paired vs true wrench: no simulator truth (/sim/true_wrench) in this dataset\n"
        ),
        "{text}"
    );
    assert!(
        text.contains("  frame drops: 6 (0 unexplained)\n"),
        "{text}"
    );

    // The same drops with a manifest that does not account for them are unexplained.
    let mut m = Manifest::load(dir.path()).unwrap();
    for t in &mut m.trajectories {
        t.frames_dropped = 0;
    }
    m.save(dir.path()).unwrap();
    let r = check(dir.path());
    assert!(r.ok());
    assert_eq!(r.frames_dropped_unexplained, 6);
    assert_eq!(r.trajectories[0].frames_dropped_unexplained, 2);
}

#[test]
fn a_synthetic_recording_with_truth_pairs_to_the_true_wrench() {
    let dir = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let spec = SyntheticSpec {
        truth: true,
        drop_frames: vec![3],
        ..Default::default()
    };
    rt.block_on(record_dataset(dir.path(), &ids(), &spec))
        .unwrap();
    let r = check_with(
        dir.path(),
        &CheckOptions {
            max_error_pct: Some(0.01),
        },
    );
    assert!(r.ok() && r.within_error_limit(), "{}", render(&r));
    for t in &r.trajectories {
        assert_eq!(t.counts.truth, 12, "one truth per recorded frame");
        let c = t.truth.as_ref().unwrap();
        assert_eq!(c.frames_with_truth, 12);
        assert_eq!(c.compared + c.unpaired, 12);
        assert_eq!(c.paired_without_truth, 0);
        assert_eq!(t.frames_dropped_unexplained, 0);
    }
    let t = r.truth.as_ref().unwrap();
    // Frames fall on wrench samples: the interpolated wrench is the true one.
    assert!(t.compared >= 30, "{t:?}");
    assert!(t.worst_axis_max_pct < 0.01, "{t:?}");
    assert!(t.max_force_error_n < 1e-3, "{t:?}");
}

#[test]
fn an_empty_trajectory_is_complete_with_zero_frames() {
    let dir = tempfile::tempdir().unwrap();
    let empty = write_traj(dir.path(), "empty", &[]);
    assert_eq!(empty, Counts::default());
    // The manifest claims drops the file cannot show: unexplained stays 0, never negative.
    write_manifest(
        dir.path(),
        serde_json::Value::Null,
        &[("empty", empty.clone(), 4)],
    );
    let r = check(dir.path());
    assert!(r.ok(), "{}", render(&r));
    let t = &r.trajectories[0];
    assert_eq!(t.verdict, Verdict::Complete);
    assert_eq!(t.counts.frames, 0);
    assert_eq!(t.frames_dropped, 0);
    assert_eq!(t.frames_dropped_reported, 4);
    assert_eq!(t.frames_dropped_unexplained, 0);
    assert!(t.truth.is_none());
    assert!(r.truth.is_none());
    assert_eq!(r.sync_error.n, 0);
    let text = render(&r);
    assert!(
        text.contains("  frame drops: 0 (0 unexplained)\n"),
        "{text}"
    );
    assert!(text.contains("no simulator truth"), "{text}");

    // Beside a trajectory with truth, the empty one changes nothing in the comparison.
    let frames: Vec<F> = (0..3).map(|k| both(k, truth_at(k), dz(-0.3))).collect();
    let full = write_traj(dir.path(), "full", &frames);
    write_manifest(
        dir.path(),
        serde_json::json!({ "max_loads": NANO17 }),
        &[("empty", empty, 0), ("full", full, 0)],
    );
    let j = json_of(&rig(dir.path(), &["--json"]));
    assert_eq!(j["complete"], 2);
    assert_eq!(j["trajectories"][0]["truth"], serde_json::Value::Null);
    assert_eq!(j["truth"]["compared"], 3);
    assert!(close(&j["truth"]["worst_axis_max_pct"], 0.3 / 35.0 * 100.0));

    // Only refused pairings: compared nothing, every frame unpaired.
    let refused: Vec<F> = (0..4)
        .map(|k| F {
            seq: k,
            paired: Some(None),
            truth: Some(Wrench::from_array(truth_at(k))),
        })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let counts = write_traj(dir.path(), "refused", &refused);
    write_manifest(
        dir.path(),
        serde_json::json!({ "max_loads": NANO17 }),
        &[("refused", counts, 0)],
    );
    let r = check(dir.path());
    let c = r.truth.as_ref().unwrap();
    assert_eq!((c.compared, c.unpaired), (0, 4));
    assert_eq!(c.worst, None);
    assert_eq!(c.worst_axis_max_pct, 0.0);
    assert!(
        render(&r).contains("  paired vs true wrench: no frame has both; 4 unpaired\n"),
        "{}",
        render(&r)
    );
}
