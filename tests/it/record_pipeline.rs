//! The recorder: files appear under their final name only when complete, aborts and write
//! errors leave none, a slow disk is back-pressure (nothing dropped), and resume tells complete
//! from incomplete.

use std::path::Path;
use std::sync::atomic::Ordering;

use rig::record::synthetic::{SyntheticSpec, png_frame, record_one};
use rig::record::{
    Manifest, Record, RecordError, Recorder, RecorderConfig, SensorInfo, Status, WriterGate,
    final_name, partial_name, read_file, resume,
};
use rig_core::wrench::Wrench;

fn ids(n: usize) -> Vec<String> {
    (0..n).map(|i| format!("p0-d{i}-a0")).collect()
}

fn manifest(ids: &[String]) -> Manifest {
    Manifest::new(
        "cone",
        SensorInfo {
            id: "gs-mini-1".into(),
            role: "source".into(),
        },
        serde_json::json!({"robot": {"simulated": true}}),
        serde_json::json!({"bias": [0, 0, 0, 0, 0, 0]}),
        ids,
    )
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn complete_trajectory_is_renamed_and_recorded_in_the_manifest() {
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(1);
    let rec = Recorder::start(dir.path(), manifest(&ids), RecorderConfig::default()).unwrap();
    let spec = SyntheticSpec::default();
    let counts = record_one(&rec, &ids[0], &spec).await.unwrap();
    let m = rec.close().await.unwrap();
    // 400 ms: 401 wrench samples, 201 poses, frames every 33 ms (13), 4 stage changes.
    assert_eq!(
        (counts.wrench, counts.poses, counts.frames, counts.stages),
        (401, 201, 13, 4)
    );
    assert_eq!(counts.paired, 13);
    assert_eq!(
        names(dir.path()),
        vec!["manifest.json".to_owned(), final_name(&ids[0])]
    );
    let on_disk = Manifest::load(dir.path()).unwrap();
    assert_eq!(on_disk, m);
    let e = on_disk.entry(&ids[0]).unwrap();
    assert_eq!(e.status, Status::Complete);
    assert_eq!(e.counts, counts);
    assert_eq!(on_disk.indenter, "cone");
    assert_eq!(on_disk.calibration["bias"][0], 0);
    assert_eq!(on_disk.software_version, env!("CARGO_PKG_VERSION"));
    let c = read_file(&dir.path().join(final_name(&ids[0]))).unwrap();
    assert_eq!(c.counts, counts);
    assert_eq!(c.frame_seqs, (0..13).collect::<Vec<i64>>());
    assert_eq!(c.paired_status.get("ok"), Some(&13));
    assert_eq!(
        c.channels.get("/camera/image").unwrap(),
        "foxglove.CompressedImage"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn aborted_trajectory_leaves_no_file_and_is_marked_failed() {
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(2);
    let rec = Recorder::start(dir.path(), manifest(&ids), RecorderConfig::default()).unwrap();
    record_one(&rec, &ids[0], &SyntheticSpec::default())
        .await
        .unwrap();
    rec.begin(&ids[1]).await.unwrap();
    rec.send(Record::Frame {
        seq: 0,
        t_ns: 1,
        format: rig::record::ImageFormat::Png,
        data: png_frame(8, 8, 0),
    })
    .await
    .unwrap();
    rec.abort("protective stop during shear").await.unwrap();
    let m = rec.close().await.unwrap();
    assert_eq!(
        names(dir.path()),
        vec!["manifest.json".to_owned(), final_name(&ids[0])]
    );
    let e = m.entry(&ids[1]).unwrap();
    assert_eq!(e.status, Status::Failed);
    assert_eq!(e.reason.as_deref(), Some("protective stop during shear"));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disk_full_fails_the_trajectory_and_keeps_earlier_files() {
    if !Path::new("/dev/full").exists() {
        panic!("this test needs /dev/full (Linux) to produce a real ENOSPC");
    }
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(2);
    let rec = Recorder::start(dir.path(), manifest(&ids), RecorderConfig::default()).unwrap();
    record_one(&rec, &ids[0], &SyntheticSpec::default())
        .await
        .unwrap();
    let before = std::fs::read(dir.path().join(final_name(&ids[0]))).unwrap();
    // The second trajectory's partial file is /dev/full: every write fails with ENOSPC.
    std::os::unix::fs::symlink("/dev/full", dir.path().join(partial_name(&ids[1]))).unwrap();
    let spec = SyntheticSpec {
        width: 320,
        height: 240,
        ..Default::default()
    };
    let err = record_one(&rec, &ids[1], &spec)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains(&ids[1]), "{err}");
    assert!(err.contains("disk is full"), "{err}");
    let m = rec.close().await.unwrap();
    let e = m.entry(&ids[1]).unwrap();
    assert_eq!(e.status, Status::Failed);
    assert!(e.reason.as_deref().unwrap().contains("disk is full"));
    assert!(!dir.path().join(final_name(&ids[1])).exists());
    assert_eq!(
        std::fs::read(dir.path().join(final_name(&ids[0]))).unwrap(),
        before
    );
    assert_eq!(m.entry(&ids[0]).unwrap().status, Status::Complete);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_disk_is_back_pressure_and_nothing_is_dropped() {
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(1);
    let gate = WriterGate::new();
    gate.close();
    let rec = std::sync::Arc::new(
        Recorder::start(
            dir.path(),
            manifest(&ids),
            RecorderConfig {
                queue_capacity: 4,
                gate: Some(gate.clone()),
                ..RecorderConfig::default()
            },
        )
        .unwrap(),
    );
    let r2 = rec.clone();
    let id = ids[0].clone();
    let producer = tokio::spawn(async move {
        r2.begin(&id).await.unwrap();
        for k in 0..200u64 {
            r2.send(Record::Wrench {
                t_ns: k * 1_000_000,
                seq: Some(k as i64),
                wrench: Wrench::from_array([k as f64, 0.0, 0.0, 0.0, 0.0, 0.0]),
            })
            .await
            .unwrap();
        }
        r2.finish(0).await.unwrap()
    });
    // The producer must block on the full queue while the writer is held.
    while rec.stats().backpressure_waits.load(Ordering::Relaxed) == 0 {
        tokio::task::yield_now().await;
    }
    assert!(!producer.is_finished());
    assert!(rec.queue_depth() >= 3, "depth {}", rec.queue_depth());
    gate.open();
    let counts = producer.await.unwrap();
    assert_eq!(counts.wrench, 200);
    let c = read_file(&dir.path().join(final_name(&ids[0]))).unwrap();
    assert_eq!(c.wrench_seqs, (0..200).collect::<Vec<i64>>());
    assert_eq!(rec.stats().discarded.load(Ordering::Relaxed), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn resume_skips_complete_and_redoes_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(4);
    let rec = Recorder::start(dir.path(), manifest(&ids), RecorderConfig::default()).unwrap();
    let spec = SyntheticSpec {
        duration_ms: 120,
        ..Default::default()
    };
    record_one(&rec, &ids[0], &spec).await.unwrap();
    rec.begin(&ids[1]).await.unwrap();
    rec.abort("force limit exceeded").await.unwrap();
    record_one(&rec, &ids[2], &spec).await.unwrap();
    rec.close().await.unwrap();
    // A crash mid-trajectory 3 left its partial behind.
    std::fs::write(dir.path().join(partial_name(&ids[3])), b"MCAP half").unwrap();
    // And trajectory 2's file was damaged after the fact.
    let p2 = dir.path().join(final_name(&ids[2]));
    let len = std::fs::metadata(&p2).unwrap().len();
    std::fs::OpenOptions::new()
        .write(true)
        .open(&p2)
        .unwrap()
        .set_len(len / 2)
        .unwrap();

    let plan = resume(dir.path(), &ids).unwrap();
    assert_eq!(plan.complete, vec![ids[0].clone()]);
    let redo: Vec<&str> = plan.redo.iter().map(|(id, _)| id.as_str()).collect();
    assert_eq!(redo, vec![&ids[1], &ids[2], &ids[3]]);
    assert!(
        plan.redo[0].1.contains("force limit exceeded"),
        "{:?}",
        plan.redo[0]
    );
    assert!(plan.redo[1].1.contains("unreadable"), "{:?}", plan.redo[1]);
    assert_eq!(plan.removed_partials, vec![partial_name(&ids[3])]);
    assert!(!dir.path().join(partial_name(&ids[3])).exists());

    // Redo them with the manifest found, and everything is complete.
    let rec = Recorder::start(
        dir.path(),
        plan.manifest.unwrap(),
        RecorderConfig::default(),
    )
    .unwrap();
    for (id, _) in &plan.redo {
        record_one(&rec, id, &spec).await.unwrap();
    }
    rec.close().await.unwrap();
    let again = resume(dir.path(), &ids).unwrap();
    assert_eq!(again.complete, ids);
    assert!(again.redo.is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_ids_are_refused_before_touching_the_disk() {
    let dir = tempfile::tempdir().unwrap();
    let rec = Recorder::start(dir.path(), manifest(&[]), RecorderConfig::default()).unwrap();
    for bad in ["../escape", "", ".hidden", "a/b"] {
        assert!(rec.begin(bad).await.is_err(), "{bad:?} accepted");
    }
    rec.close().await.unwrap();
    assert_eq!(names(dir.path()), vec!["manifest.json".to_owned()]);
}

/// Whether `dir`'s advisory lock (the one `rig run` takes) is free now.
fn lock_free(dir: &Path) -> bool {
    let f = std::fs::File::open(dir).unwrap();
    f.try_lock().is_ok()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_writer_that_never_returns_is_given_up_on_after_the_stall_limit() {
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(2);
    let gate = WriterGate::new();
    let lock = std::fs::File::open(dir.path()).unwrap();
    lock.try_lock().unwrap();
    let rec = Recorder::start(
        dir.path(),
        manifest(&ids),
        RecorderConfig {
            gate: Some(gate.clone()),
            stall_limit: std::time::Duration::from_millis(300),
            dir_lock: Some(std::sync::Arc::new(lock.try_clone().unwrap())),
            ..RecorderConfig::default()
        },
    )
    .unwrap();
    let spec = SyntheticSpec::default();
    record_one(&rec, &ids[0], &spec).await.unwrap();
    rec.begin(&ids[1]).await.unwrap();
    rec.send(Record::Wrench {
        t_ns: 1,
        seq: Some(1),
        wrench: Wrench::from_array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
    })
    .await
    .unwrap();
    // Everything queued so far is written (the second trajectory's file is open)...
    let mut waited = 0;
    while rec.stats().written.load(Ordering::Relaxed) < rec.stats().queued.load(Ordering::Relaxed) {
        waited += 1;
        assert!(waited < 3000, "the writer never caught up");
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    // ...when the disk stops answering: the writer never returns from its next command.
    gate.close();
    let e = rec.abort("force limit exceeded").await.unwrap_err();
    assert!(
        matches!(e, RecordError::Stalled { ref what, .. } if what.contains("manifest")),
        "{e:?}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains("stalled or unreachable") && msg.contains("--resume"),
        "{msg}"
    );
    assert!(rec.is_stalled());
    // Given up on: the next waits do not wait again.
    assert!(matches!(
        rec.finish(0).await.unwrap_err(),
        RecordError::Stalled { .. }
    ));
    assert!(matches!(
        rec.close().await.unwrap_err(),
        RecordError::Stalled { .. }
    ));
    // The run is over, but the hanging writer keeps the directory's lock (a duplicate of the
    // run's), so no other run writes there while it might still.
    drop(lock);
    assert!(!lock_free(dir.path()));
    // On disk: the first trajectory complete, the second as the writer last saved it.
    let on_disk = Manifest::load(dir.path()).unwrap();
    assert_eq!(on_disk.entry(&ids[0]).unwrap().status, Status::Complete);
    assert_eq!(on_disk.entry(&ids[1]).unwrap().status, Status::Pending);
    assert!(dir.path().join(partial_name(&ids[1])).exists());

    // The disk comes back: the writer completes what it held (the abort, the close) and ends,
    // which frees the lock; resume then redoes the second trajectory only.
    gate.open();
    let mut waited = 0;
    while !lock_free(dir.path()) {
        waited += 1;
        assert!(
            waited < 3000,
            "the writer never ended after the gate opened"
        );
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    let on_disk = Manifest::load(dir.path()).unwrap();
    let second = on_disk.entry(&ids[1]).unwrap();
    assert_eq!(second.status, Status::Failed, "{second:?}");
    assert_eq!(second.reason.as_deref(), Some("force limit exceeded"));
    let plan = resume(dir.path(), &ids).unwrap();
    assert_eq!(plan.complete, vec![ids[0].clone()]);
    assert_eq!(plan.redo.len(), 1);
    let rec = Recorder::start(
        dir.path(),
        plan.manifest.unwrap(),
        RecorderConfig::default(),
    )
    .unwrap();
    record_one(&rec, &ids[1], &spec).await.unwrap();
    rec.close().await.unwrap();
    assert_eq!(resume(dir.path(), &ids).unwrap().complete, ids);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_slow_disk_that_still_writes_is_never_called_stalled() {
    let dir = tempfile::tempdir().unwrap();
    let ids = ids(1);
    let gate = WriterGate::new();
    gate.close();
    let limit = std::time::Duration::from_secs(1);
    let rec = Recorder::start(
        dir.path(),
        manifest(&ids),
        RecorderConfig {
            gate: Some(gate.clone()),
            stall_limit: limit,
            ..RecorderConfig::default()
        },
    )
    .unwrap();
    // The disk takes one command at a time, each a quarter of the stall limit after the last:
    // the trajectory takes far longer than the limit, but the writer keeps completing work.
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let pacer = {
        let (gate, done) = (gate.clone(), done.clone());
        tokio::spawn(async move {
            let mut passes = 0u32;
            while !done.load(Ordering::Relaxed) {
                tokio::time::sleep(limit / 4).await;
                gate.let_through(1);
                passes += 1;
            }
            gate.open();
            passes
        })
    };
    let id = ids[0].clone();
    rec.begin(&id).await.unwrap();
    for k in 0..8u64 {
        rec.send(Record::Wrench {
            t_ns: k * 1_000_000,
            seq: Some(k as i64),
            wrench: Wrench::from_array([k as f64, 0.0, 0.0, 0.0, 0.0, 0.0]),
        })
        .await
        .unwrap();
    }
    let counts = rec.finish(0).await.unwrap();
    done.store(true, Ordering::Relaxed);
    let passes = pacer.await.unwrap();
    assert_eq!(counts.wrench, 8);
    // Every command was queued at once (the begin, 8 messages, the finish): the finish waited
    // for ten passes, two and a half stall limits.
    assert!(
        passes >= 10,
        "{passes} passes: the drill did not slow the disk"
    );
    assert!(!rec.is_stalled());
    rec.close().await.unwrap();
}
