//! The recording format of issue 16: old JSON recordings still read (check and trainer), a
//! chunk write failure fails only its trajectory, MJPEG frames are recorded byte for byte,
//! `rig dataset export --format folder`, and the Python snippet of docs/recording-format.md.

use std::collections::{BTreeMap, VecDeque};
use std::path::Path;
use std::process::Command;
use std::sync::{Arc, Mutex};

use rig::camera::FrameSource;
use rig::camera::PixelFormat;
use rig::camera::v4l2::{OfferedMode, RawFrame, Request, V4l2Options, V4l2Source};
use rig::record::reader::{Message, Paired, messages, read_file};
use rig::record::synthetic::{SyntheticSpec, record_dataset, record_one};
use rig::record::{
    ImageFormat, Manifest, Recorder, RecorderConfig, SensorInfo, Status, TrajectoryWriter,
    final_name, partial_name,
};
use rig::run::streams::stored_image;
use rig_core::clock::Clock;

use super::camera_v4l2::FakeDevice;

const LEGACY: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/legacy-json");

fn copy_dir(from: &Path, to: &Path) {
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
    }
}

/// Frames by sequence number: format and image bytes.
type Frames = BTreeMap<i64, (ImageFormat, Vec<u8>)>;

/// Frames and paired wrenches (by frame) of a file.
fn contents(path: &Path) -> (Frames, BTreeMap<i64, Paired>) {
    let bytes = std::fs::read(path).unwrap();
    let (mut frames, mut paired) = (BTreeMap::new(), BTreeMap::new());
    for m in messages(&bytes).unwrap() {
        match m.unwrap() {
            Message::Frame {
                seq, format, data, ..
            } => {
                frames.insert(seq, (format, data));
            }
            Message::Paired(p) => {
                paired.insert(p.frame_seq, p);
            }
            _ => {}
        }
    }
    (frames, paired)
}

fn legacy_spec() -> SyntheticSpec {
    // What tests/data/legacy-json was recorded with (by the recorder before issue 16).
    SyntheticSpec {
        duration_ms: 150,
        truth: true,
        drop_frames: vec![2],
        ..Default::default()
    }
}

#[test]
fn an_old_json_recording_still_checks_loads_and_reads_as_the_new_format() {
    let old = tempfile::tempdir().unwrap();
    copy_dir(Path::new(LEGACY), old.path());
    let c = read_file(&old.path().join("legacy-a.mcap")).unwrap();
    assert_eq!(c.encodings["/camera/image"], "json");
    assert_eq!(c.chunks, 0);
    assert_eq!(
        (
            c.counts.frames,
            c.counts.wrench,
            c.counts.poses,
            c.counts.truth
        ),
        (4, 151, 76, 4)
    );

    // `rig dataset check` passes it with its counts.
    let out = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check", "--json"])
        .arg(old.path())
        .output()
        .unwrap();
    let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(out.status.success(), "{j:#}");
    assert_eq!(j["complete"], 2);
    assert_eq!(j["trajectories"][0]["counts"]["frames"], 4);
    assert_eq!(j["trajectories"][0]["counts"]["wrench"], 151);
    assert_eq!(j["trajectories"][0]["frames_dropped"], 1);

    // The same synthetic trajectories recorded today: chunked protobuf, and the same frames
    // (PNG bytes) and paired wrenches, value for value.
    let new = tempfile::tempdir().unwrap();
    let ids = vec!["legacy-a".to_owned(), "legacy-b".to_owned()];
    tokio::runtime::Runtime::new()
        .unwrap()
        .block_on(record_dataset(new.path(), &ids, &legacy_spec()))
        .unwrap();
    let n = read_file(&new.path().join("legacy-a.mcap")).unwrap();
    assert_eq!(n.encodings["/camera/image"], "protobuf");
    assert!(n.chunks >= 1);
    assert_eq!(n.counts, c.counts);
    let (old_frames, old_paired) = contents(&old.path().join("legacy-a.mcap"));
    let (new_frames, new_paired) = contents(&new.path().join("legacy-a.mcap"));
    assert_eq!(old_frames.keys().copied().collect::<Vec<_>>(), [0, 1, 3, 4]);
    assert_eq!(old_frames, new_frames);
    assert_eq!(old_paired.len(), 4);
    // JSON numbers came back within an ulp of what was written (serde_json's float parsing);
    // protobuf doubles are the values themselves.
    let close = |a: &[f64], b: &[f64]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-12 * x.abs().max(1.0))
    };
    for (seq, p) in &old_paired {
        let q = &new_paired[seq];
        assert!(
            close(&p.force_n.unwrap(), &q.force_n.unwrap()),
            "{p:?} {q:?}"
        );
        assert!(close(&p.torque_nmm.unwrap(), &q.torque_nmm.unwrap()));
        assert!(close(&p.tcp_pose.unwrap(), &q.tcp_pose.unwrap()));
        assert_eq!(
            (&p.status, &p.stage, p.sync_error_ns, p.t_ns),
            (&q.status, &q.stage, q.sync_error_ns, q.t_ns)
        );
    }

    // The trainer's loader reads the old files: every frame with a force, with that force.
    let spec = rig::train::data::ImageSpec {
        width: 16,
        height: 12,
        modality: rig::train::modality::Modality::RgbMarker,
    };
    let set = rig::train::data::load_labelled(old.path(), &spec, false).unwrap();
    assert_eq!(set.trajectories.len(), 2);
    let with_force: Vec<[f32; 3]> = old_paired
        .values()
        .filter_map(|p| p.force_n)
        .map(|f| [f[0] as f32, f[1] as f32, f[2] as f32])
        .collect();
    assert!(!with_force.is_empty());
    assert_eq!(set.trajectories[0].frames, with_force.len());
    assert_eq!(set.forces(0), &with_force[..]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_chunk_write_failure_mid_trajectory_fails_it_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ids: Vec<String> = vec!["t-small".into(), "t-big".into(), "t-after".into()];
    let manifest = Manifest::new(
        "synthetic",
        SensorInfo {
            id: "sim-source".into(),
            role: "source".into(),
        },
        serde_json::json!({}),
        serde_json::json!({}),
        &ids,
    );
    // Every file fails once it would pass 200 kB: the small trajectories fit, the big one
    // (6 s of 320×240 frames) does not.
    let rec = Recorder::start(
        dir.path(),
        manifest,
        RecorderConfig {
            fail_after_bytes: Some(200_000),
            ..RecorderConfig::default()
        },
    )
    .unwrap();
    record_one(&rec, &ids[0], &SyntheticSpec::default())
        .await
        .unwrap();
    let big = SyntheticSpec {
        duration_ms: 6000,
        width: 320,
        height: 240,
        ..Default::default()
    };
    let err = record_one(&rec, &ids[1], &big)
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("t-big"), "{err}");
    assert!(err.contains("simulated write failure"), "{err}");
    // It failed while messages were still coming: the later ones were discarded.
    let discarded = rec
        .stats()
        .discarded
        .load(std::sync::atomic::Ordering::Relaxed);
    assert!(discarded > 100, "discarded {discarded}");
    // The recorder goes on: the next trajectory completes.
    record_one(&rec, &ids[2], &SyntheticSpec::default())
        .await
        .unwrap();
    // No panic took the writer thread down: close returns the manifest.
    let m = rec.close().await.unwrap();
    let e = m.entry("t-big").unwrap();
    assert_eq!(e.status, Status::Failed);
    assert!(
        e.reason
            .as_deref()
            .unwrap()
            .contains("simulated write failure"),
        "{e:?}"
    );
    assert!(!dir.path().join(final_name("t-big")).exists());
    assert!(!dir.path().join(partial_name("t-big")).exists());
    for id in ["t-small", "t-after"] {
        assert_eq!(m.entry(id).unwrap().status, Status::Complete);
        let c = read_file(&dir.path().join(final_name(id))).unwrap();
        assert_eq!(c.counts.wrench, 401);
    }
}

/// A 320×240 JPEG whose content depends on `k`, as a UVC camera would send it.
fn jpeg(k: u8) -> Vec<u8> {
    let img = image::RgbImage::from_fn(320, 240, |x, y| {
        image::Rgb([
            (x / 2) as u8 ^ k,
            (y + u32::from(k)) as u8,
            k.wrapping_mul(37),
        ])
    });
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .encode_image(&img)
        .unwrap();
    out
}

#[tokio::test]
async fn mjpeg_frames_are_recorded_byte_for_byte() {
    let jpegs: Vec<Vec<u8>> = (0..3).map(jpeg).collect();
    let mut frames: VecDeque<std::io::Result<Option<RawFrame>>> = jpegs
        .iter()
        .enumerate()
        .map(|(k, j)| {
            Ok(Some(RawFrame {
                data: j.clone(),
                sequence: 7 + k as u32,
                timestamp_ns: (100 + 33 * k as u64) * 1_000_000,
                error: false,
            }))
        })
        .collect();
    // A corrupt JPEG is skipped, as before: it is not recorded.
    frames.push_back(Ok(Some(RawFrame {
        data: vec![0xff, 0xd8, 1, 2, 3],
        sequence: 10,
        timestamp_ns: 200_000_000,
        error: false,
    })));
    let dev = FakeDevice {
        modes: vec![OfferedMode {
            pixel: PixelFormat::Mjpeg,
            width: 320,
            height: 240,
            fps: vec![30.0],
        }],
        force_pixel: None,
        frames,
        log: Arc::new(Mutex::new(Vec::new())),
    };
    let (clock, _handle) = Clock::manual();
    let mut src = V4l2Source::open(
        dev,
        "/dev/fake0",
        clock,
        &Request::new(320, 240, 30.0),
        &V4l2Options::default(),
    )
    .unwrap();
    assert_eq!(src.format().pixel, PixelFormat::Mjpeg);
    let dir = tempfile::tempdir().unwrap();
    let mut w = TrajectoryWriter::create(dir.path(), "mjpeg").unwrap();
    for _ in 0..4 {
        let f = src.next_frame().await.unwrap();
        match stored_image(&f) {
            Ok((format, data)) => w
                .write(&rig::record::Record::Frame {
                    seq: f.sequence as i64,
                    t_ns: f.received_t_ns,
                    format,
                    data,
                })
                .unwrap(),
            Err(e) => {
                assert_eq!(f.sequence, 10, "{e}");
                assert!(e.contains("MJPEG"), "{e}");
            }
        }
    }
    w.finish().unwrap();
    let (got, _) = contents(&dir.path().join(final_name("mjpeg")));
    assert_eq!(got.keys().copied().collect::<Vec<_>>(), [7, 8, 9]);
    for (k, (format, data)) in got.values().enumerate() {
        assert_eq!(*format, ImageFormat::Jpeg);
        assert_eq!(data, &jpegs[k], "frame {k}: the camera's JPEG, untouched");
        let img = rig::record::png::decode_as(*format, data).unwrap();
        assert_eq!(img.dimensions(), (320, 240));
    }
}

#[test]
fn export_folder_writes_frames_and_a_force_csv_per_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("run");
    let ids = vec!["p0-d0-a0".to_owned(), "p0-d0-a30".to_owned()];
    let spec = SyntheticSpec {
        drop_frames: vec![3],
        ..Default::default()
    };
    let m = tokio::runtime::Runtime::new()
        .unwrap()
        .block_on(record_dataset(&data, &ids, &spec))
        .unwrap();
    let out = dir.path().join("exported");
    let run = |out: &Path| {
        Command::new(env!("CARGO_BIN_EXE_rig"))
            .args(["dataset", "export", "--format", "folder", "--out"])
            .arg(out)
            .arg(&data)
            .output()
            .unwrap()
    };
    let o = run(&out);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let total: u64 = m.trajectories.iter().map(|t| t.counts.frames).sum();
    assert_eq!(total, 24);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        stdout.contains("exported 2 trajectories (24 frames)"),
        "{stdout}"
    );
    for id in &ids {
        let (frames, paired) = contents(&data.join(final_name(id)));
        assert_eq!(frames.len() as u64, m.entry(id).unwrap().counts.frames);
        assert_eq!(frames.len(), 12);
        let t = out.join(id);
        let mut images: Vec<_> = std::fs::read_dir(t.join("images"))
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        images.sort();
        assert_eq!(images.len(), frames.len());
        let csv = std::fs::read_to_string(t.join("force.csv")).unwrap();
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some(rig::dataset::export::CSV_HEADER));
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), frames.len(), "one row per frame");
        for (row, ((seq, (_, bytes)), name)) in rows.iter().zip(frames.iter().zip(&images)) {
            assert_eq!(row[0], seq.to_string());
            assert_eq!(row[1], name);
            assert!(name.ends_with(".png"));
            assert_eq!(&std::fs::read(t.join("images").join(name)).unwrap(), bytes);
            let p = &paired[seq];
            let num = |k: usize| row[k].parse::<f64>().ok();
            assert_eq!(
                [num(3), num(4), num(5)],
                p.force_n.map_or([None; 3], |f| f.map(Some))
            );
            assert_eq!(
                [num(6), num(7), num(8)],
                p.torque_nmm.map_or([None; 3], |f| f.map(Some))
            );
            assert_eq!(row[9], p.stage.as_deref().unwrap_or(""));
            assert_eq!(row[10], p.status);
            assert_eq!(row[2], p.t_ns.to_string());
            let pose: Vec<Option<f64>> = (11..17).map(num).collect();
            assert_eq!(
                pose,
                p.tcp_pose.map_or(vec![None; 6], |q| q.map(Some).to_vec())
            );
        }
        // Real values: the synthetic wrench is non-zero in the middle of the press.
        assert!(
            rows.iter()
                .any(|r| r[5].parse::<f64>().is_ok_and(|fz| fz < -1.0))
        );
    }
    // An export never mixes with an older one.
    let again = run(&out);
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("is not empty"));
}

/// The Python snippet of docs/recording-format.md, run as it stands against a recording: it
/// decodes a frame and its paired wrench with the PyPI `mcap` + `mcap-protobuf-support` packages.
#[test]
fn the_documented_python_snippet_reads_a_frame_and_its_paired_wrench() {
    let page = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/docs/recording-format.md"
    ))
    .unwrap();
    let start = page
        .find("<!-- python-snippet -->")
        .expect("docs/recording-format.md has the python-snippet marker");
    let code = page[start..]
        .split("```python\n")
        .nth(1)
        .and_then(|s| s.split("```").next())
        .expect("a ```python block after the marker");
    let dir = tempfile::tempdir().unwrap();
    let ids = vec!["p0-d0-a0".to_owned()];
    tokio::runtime::Runtime::new()
        .unwrap()
        .block_on(record_dataset(dir.path(), &ids, &SyntheticSpec::default()))
        .unwrap();
    let script = dir.path().join("snippet.py");
    std::fs::write(&script, code).unwrap();
    let file = dir.path().join(final_name("p0-d0-a0"));
    let python = std::env::var("RIG_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = Command::new(&python)
        .arg(&script)
        .arg(&file)
        .output()
        .unwrap_or_else(|e| panic!("cannot run {python}: {e}; run `bash scripts/test`"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "the docs/recording-format.md snippet failed (interpreter {python}; `bash scripts/test` installs \
         tests/python/requirements.txt into .venv):\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Its last line: frames, the frame's seq, format, bytes, then Fx Fy Fz Mx My Mz.
    let last: Vec<&str> = stdout.lines().last().unwrap().split_whitespace().collect();
    let (frames, paired) = contents(&file);
    assert_eq!(last[0], frames.len().to_string());
    let seq: i64 = last[1].parse().unwrap();
    assert_eq!(last[2], "png");
    assert_eq!(last[3], frames[&seq].1.len().to_string());
    let p = &paired[&seq];
    let got: Vec<f64> = last[4..10].iter().map(|v| v.parse().unwrap()).collect();
    let want: Vec<f64> = p
        .force_n
        .unwrap()
        .into_iter()
        .chain(p.torque_nmm.unwrap())
        .collect();
    assert_eq!(got, want);
}
