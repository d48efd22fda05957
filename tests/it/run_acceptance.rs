//! The recording of `rig run` on the simulated rig is paired correctly: every frame's paired
//! wrench matches the simulator's true wrench at the frame's capture time, within 2 % of the
//! sensor's full range (the acceptance criterion) and within a bound derived from the
//! simulated Nano17's noise; every sync error is below 1 ms; no frame is lost; every stage is
//! labelled. Read with the recording reader, independently of `rig dataset check`'s checks.
//!
//! The run uses the deepest layer of the cone plan (0.8 mm), where the contact force is
//! largest and changes fastest, so a timing error would show as a force error.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::process::Command;

use rig::record::Manifest;
use rig::record::reader::{Message, messages};

use crate::common;

/// The simulated Nano17's force noise, σ per axis: its resolution, 1/160 N.
const FORCE_NOISE_N: f64 = 1.0 / 160.0;

/// A paired record: force, status, sync error (ns), stage.
type Paired = (Option<[f64; 3]>, String, Option<f64>, Option<String>);

struct Frames {
    /// seq → true force at capture time.
    truth: BTreeMap<i64, [f64; 3]>,
    /// seq → (paired force, status, sync error ns, stage).
    paired: BTreeMap<i64, Paired>,
    images: BTreeSet<i64>,
}

fn read(path: &Path) -> Frames {
    let bytes = std::fs::read(path).unwrap();
    let mut f = Frames {
        truth: BTreeMap::new(),
        paired: BTreeMap::new(),
        images: BTreeSet::new(),
    };
    for m in messages(&bytes).unwrap() {
        match m.unwrap() {
            Message::Truth(t) => {
                f.truth.insert(t.frame_seq, t.wrench.force_n);
            }
            Message::Paired(p) => {
                f.paired
                    .insert(p.frame_seq, (p.force_n, p.status, p.sync_error_ns, p.stage));
            }
            Message::Frame { seq, .. } => {
                f.images.insert(seq);
            }
            _ => {}
        }
    }
    f
}

/// `rig run --indenter NAME` with `extra` arguments on the simulated rig's config edited to its
/// deepest layer only (0.8 mm, where the contact force is largest and changes fastest), into
/// `dir/NAME`; asserts it succeeded and returns the output directory.
fn run_deep(dir: &Path, name: &str, extra: &[&str]) -> std::path::PathBuf {
    let cfg = common::edited_sim_config(
        dir,
        "deep.toml",
        &[("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.8]")],
    );
    let out_dir = dir.join(name);
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", name])
        .args(extra)
        .arg("--config")
        .arg(&cfg)
        .arg("--out")
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "rig run {name}: {}",
        common::output_text(&out)
    );
    out_dir
}

#[test]
fn every_frame_is_paired_with_the_true_wrench_at_its_capture_time() {
    let _g = common::one_rig_at_a_time();
    let tmp = tempfile::tempdir().unwrap();
    let out_dir = run_deep(tmp.path(), "cone", &["--limit", "2"]);

    let manifest = Manifest::load(&out_dir).unwrap();
    let full: Vec<f64> = manifest.calibration["max_loads"]
        .as_array()
        .expect("the manifest stores the sensor's full range")
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(
        full,
        [25.0, 25.0, 35.0, 250.0, 250.0, 250.0],
        "Nano17 SI-25-0.25"
    );

    let mut worst_fraction: f64 = 0.0;
    let mut deepest_fz: f64 = 0.0;
    for t in &manifest.trajectories {
        let f = read(&out_dir.join(format!("{}.mcap", t.id)));
        assert!(f.images.len() > 100, "{}: {} frames", t.id, f.images.len());
        // No frame lost: the recorded sequence numbers are consecutive.
        let seqs: Vec<i64> = f.images.iter().copied().collect();
        assert_eq!(
            seqs.last().unwrap() - seqs[0] + 1,
            seqs.len() as i64,
            "{}: a gap in the frame sequence",
            t.id
        );
        assert_eq!(
            f.truth.keys().copied().collect::<Vec<_>>(),
            seqs,
            "{}",
            t.id
        );
        assert_eq!(
            f.paired.keys().copied().collect::<Vec<_>>(),
            seqs,
            "{}",
            t.id
        );
        let mut stages = BTreeSet::new();
        for (seq, (paired, status, sync_ns, stage)) in &f.paired {
            assert_eq!(status, "ok", "{} frame {seq}", t.id);
            let sync_ns = sync_ns.expect("a sync error for every paired frame");
            assert!(
                sync_ns < 1e6,
                "{} frame {seq}: sync error {sync_ns} ns",
                t.id
            );
            if let Some(s) = stage {
                stages.insert(s.clone());
            }
            let paired = paired.expect("status ok has a wrench");
            let truth = f.truth[seq];
            deepest_fz = deepest_fz.min(truth[2]);
            for k in 0..3 {
                let err = (paired[k] - truth[k]).abs();
                worst_fraction = worst_fraction.max(err / full[k]);
                // The paired force is the cubic interpolation of noisy 1 kHz samples at the
                // frame time: its error is the sensor noise (σ = 1/160 N per axis) plus the
                // interpolation error, which is tiny at the plan's speeds. 8σ bounds the
                // largest of a few hundred frames × 3 axes with a margin; a timing error of a
                // few ms would exceed it while the cone loads the gel (about 2 N/s).
                assert!(
                    err < 8.0 * FORCE_NOISE_N,
                    "{} frame {seq} axis {k}: paired {:.4} N, true {:.4} N",
                    t.id,
                    paired[k],
                    truth[k]
                );
            }
        }
        for s in ["down", "shear", "reverse", "up"] {
            assert!(
                stages.contains(s),
                "{}: no frame labelled {s}: {stages:?}",
                t.id
            );
        }
    }
    // The same verdicts from `rig dataset check` (the operator's tool), as JSON.
    let check = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check", "--json", "--max-error-pct", "2"])
        .arg(&out_dir)
        .output()
        .unwrap();
    assert!(
        check.status.success(),
        "rig dataset check failed:\n{}",
        String::from_utf8_lossy(&check.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&check.stdout).unwrap();
    assert_eq!(report["complete"], 2, "{report:#}");
    assert_eq!(report["frames_dropped_unexplained"], 0, "{report:#}");
    assert_eq!(report["truth"]["frames_above_2pct"], 0, "{report:#}");
    assert_eq!(report["truth"]["unpaired"], 0, "{report:#}");
    assert!(
        report["sync_error"]["p99_ns"].as_f64().unwrap() < 1e6,
        "{report:#}"
    );
    assert!(
        report["truth"]["worst_axis_max_pct"].as_f64().unwrap() < 2.0,
        "{report:#}"
    );

    // The acceptance line: within 2 % of full range (here far inside it).
    assert!(
        worst_fraction < 0.02,
        "worst error {:.3} % of full range",
        worst_fraction * 100.0
    );
    // The run really pressed the gel (the cone at 0.8 mm pushes well over 0.1 N).
    assert!(deepest_fz < -0.1, "deepest true Fz {deepest_fz} N");
}

/// The label bound on the indenters whose labels were worst over their full plans: paralines
/// (flat bars whose slide re-settles as it stops) and the flat-ended cylinder (the fastest
/// unloading, about 0.08 N/ms at 5 mm/s). At 0.8 mm deep, three directions each, every axis
/// of every frame is within 0.05 N of the simulator's true force, as over the full plans
/// (`docs/experiments.md`). The F/T's noise (σ = 1/160 N) takes about half of that over a few
/// thousand values; the rest is what the physics and the timing may add. The clock runs at ×2
/// here, not the benchmark's ×10: at ×10 the host's scheduling delays (tens of µs) become
/// hundreds of µs of clock time, and a test beside others on two cores should not be judged
/// on them (`rig bench run` measures ×10 on an idle machine).
#[test]
fn labels_on_the_flat_faces_stay_within_0_05_n() {
    let _g = common::one_rig_at_a_time();
    let tmp = tempfile::tempdir().unwrap();
    for name in ["paralines", "cylinder"] {
        let out_dir = run_deep(tmp.path(), name, &["--limit", "3", "--speed-factor", "2"]);
        let manifest = Manifest::load(&out_dir).unwrap();
        assert_eq!(manifest.trajectories.len(), 3, "{name}");
        let (mut worst, mut at) = (0.0f64, String::new());
        let (mut frames, mut deepest_fz) = (0, 0.0f64);
        for t in &manifest.trajectories {
            let f = read(&out_dir.join(format!("{}.mcap", t.id)));
            for (seq, (paired, status, _, stage)) in &f.paired {
                assert_eq!(status, "ok", "{name} {} frame {seq}", t.id);
                let paired = paired.expect("status ok has a wrench");
                let truth = f.truth[seq];
                frames += 1;
                deepest_fz = deepest_fz.min(truth[2]);
                for k in 0..3 {
                    let err = (paired[k] - truth[k]).abs();
                    if err > worst {
                        worst = err;
                        at = format!("{} frame {seq} ({stage:?}) axis {k}", t.id);
                    }
                }
            }
        }
        assert!(frames > 300, "{name}: {frames} frames");
        // Pressed for real: a flat face 0.8 mm deep loads the gel with several newtons.
        assert!(deepest_fz < -5.0, "{name}: deepest true Fz {deepest_fz} N");
        assert!(
            worst <= 0.05,
            "{name}: |paired − true| {worst:.4} N at {at} (bound 0.05 N)"
        );
        eprintln!("{name}: {frames} frames, largest |paired − true| {worst:.4} N at {at}");
    }
}
