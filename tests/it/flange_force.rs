//! A target sensor recorded without an F/T sensor (no `[force_sensor]`) on the simulated rig:
//! its run records images, TCP poses and stage labels along the same plan, and its force watch
//! is the UR5e's flange sensor (`actual_TCP_force`, from the twin's contact physics with the
//! data sheet's accuracy), tripping the stop first as the Nano17 does.

use std::path::{Path, PathBuf};
use std::process::Command;

use rig::record::{Manifest, Status, TOPIC_IMAGE, TOPIC_POSE, final_name, read_file};
use rig::run::events::Trip;
use rig::run::{RunOptions, run};
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;
use rig_core::pose;

use crate::common;

/// The shipped simulated target's `[force_sensor]`, removed by [`no_ft_target`].
const FT_SECTION: &str =
    "[force_sensor]\nkind = \"sim\"                # the simulated Nano17\nrate_hz = 1000.0\n";

/// The shipped simulated target config without its `[force_sensor]`, with `edits` (exact
/// line replacements) applied, written as `dir/name`.
fn no_ft_target(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let shipped = concat!(env!("CARGO_MANIFEST_DIR"), "/rig-configs/sim-target.toml");
    let mut text = std::fs::read_to_string(shipped).unwrap();
    assert!(
        text.contains(FT_SECTION),
        "the shipped target config changed"
    );
    text = text.replace(FT_SECTION, "");
    for (from, to) in edits {
        assert!(
            text.contains(from),
            "the shipped target config has no {from:?}"
        );
        text = text.replace(from, to);
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Log times of a trajectory file's frames and of its TCP poses, ns, in file order.
fn log_times(path: &Path) -> (Vec<u64>, Vec<u64>) {
    let bytes = std::fs::read(path).unwrap();
    let (mut frames, mut poses) = (Vec::new(), Vec::new());
    for m in mcap::read::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        match m.channel.topic.as_str() {
            TOPIC_IMAGE => frames.push(m.log_time),
            TOPIC_POSE => poses.push(m.log_time),
            _ => {}
        }
    }
    (frames, poses)
}

#[test]
fn a_target_without_an_ft_sensor_records_images_poses_and_stages_along_the_plan() {
    let _rig = common::one_rig_at_a_time();
    let tmp = tempfile::tempdir().unwrap();
    let cfg = no_ft_target(tmp.path(), "target.toml", &[]);
    let out = tmp.path().join("rec");
    let run = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["run", "--indenter", "cone", "--config"])
        .arg(&cfg)
        .arg("--out")
        .arg(&out)
        .args(["--limit", "2", "--speed-factor", "5"])
        .output()
        .unwrap();
    let text = common::output_text(&run);
    assert!(run.status.success(), "{text}");
    assert!(text.contains("dataset check: OK, 2 complete"), "{text}");
    assert!(text.contains("flange sensor"), "{text}");

    // The same plan as the source's, recorded without forces.
    let config = RigConfig::load(&cfg).unwrap();
    let plan = rig::plan::Plan::build(&config, &Indenter::load("cone").unwrap()).unwrap();
    let m = Manifest::load(&out).unwrap();
    assert_eq!(m.sensor.role, "target");
    assert!(m.calibration.is_null(), "{}", m.calibration);
    for t in &plan.trajectories[..2] {
        let e = m.entry(&t.id).unwrap();
        assert_eq!(e.status, Status::Complete, "{e:?}");
        let c = read_file(&out.join(final_name(&t.id))).unwrap();
        assert_eq!(c.counts, e.counts);
        assert!(c.counts.frames > 100, "{:?}", c.counts);
        assert_eq!((c.counts.wrench, c.counts.paired), (0, 0), "{:?}", c.counts);
        assert_eq!(c.counts.stages, 4, "{:?}", c.counts);
        // TCP poses cover every frame, so each frame's contact pose is known (what pairs it
        // with the source's frames).
        assert!(c.counts.poses > 2 * c.counts.frames, "{:?}", c.counts);
        let (frames, poses) = log_times(&out.join(final_name(&t.id)));
        let (first_pose, last_pose) = (poses[0], *poses.last().unwrap());
        let inside = frames
            .iter()
            .filter(|t| (first_pose..=last_pose).contains(*t))
            .count();
        assert!(
            inside as f64 >= 0.95 * c.counts.frames as f64,
            "{inside} of {} frames within the poses' span",
            c.counts.frames
        );
    }

    // `rig dataset check` accepts it as it is.
    let check = Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["dataset", "check"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(check.status.success(), "{}", common::output_text(&check));
}

#[test]
fn pressing_past_the_force_limit_with_no_nano17_trips_the_stop_on_the_flange_force_first() {
    let _rig = common::one_rig_at_a_time();
    let tmp = tempfile::tempdir().unwrap();
    // A gel forty times as stiff as the target's, pressed to 0.8 mm: the cone pushes far past
    // a 15 N limit there (about 0.5 N on the shipped gel: `rig sim forces --indenter cone`),
    // well within the flange sensor's reach (it trips at 15 − 6.9 N read).
    let cfg = no_ft_target(
        tmp.path(),
        "stiff.toml",
        &[
            ("youngs_modulus_mpa = 0.29", "youngs_modulus_mpa = 11.6"),
            ("depths_mm = [0.2, 0.4, 0.6, 0.8]", "depths_mm = [0.8]"),
            ("max_force_n = 20.0", "max_force_n = 15.0"),
        ],
    );
    let config = RigConfig::load(&cfg).unwrap();
    assert!(config.force_sensor.is_none());
    let indenter = Indenter::load("cone").unwrap();
    let out = tmp.path().join("rec");
    let opts = RunOptions {
        limit: Some(1),
        // The stop's latency is real time (the host's own latencies would count ten times
        // over on a ×10 clock): simulated time runs at real speed here.
        speed_factor: 1.0,
        ..RunOptions::new(&out)
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    let summary = rt.block_on(run(&config, &indenter, &opts)).unwrap();

    let stop = summary
        .safety_stops
        .first()
        .unwrap_or_else(|| panic!("no safety stop: {}", summary.report()));
    let Trip::FlangeForceLimit {
        force_n,
        threshold_n,
        limit_n,
    } = stop.trip
    else {
        panic!("the first stop was not the flange force's: {stop:?}");
    };
    assert_eq!(limit_n, 15.0);
    assert!((threshold_n - (15.0 - rig::run::flange::MARGIN_N)).abs() < 1e-9);
    assert!(force_n > threshold_n, "{stop:?}");
    // Stop first: the request went out on the crossing, and reached the controller.
    let commanded = stop.commanded_ns.expect("the stop request was not written");
    assert!(commanded >= stop.detected_ns);
    let latency_s = stop.reached_controller_ns.map_or(f64::NAN, |r| {
        r.saturating_sub(stop.detected_ns) as f64 * 1e-9
    });
    let (id, why) = summary.failure.clone().unwrap();
    assert!(why.contains("UR5e flange sensor"), "{id}: {why}");

    // The arm comes to rest within what the stop's deceleration allows from the speed it
    // pressed at.
    let v = config.plan.down.speed_mm_s * 1e-3;
    let (travel, from_crossing, allowed) = common::assert_stop_travel(stop, &summary, v);
    eprintln!(
        "flange |F| {force_n:.2} N read at the crossing (trips above {threshold_n:.2} N); the \
         stop reached the controller {:.2} ms later; travel after it {:.4} mm, after the \
         crossing {:.4} mm (allowed {:.4} mm)",
        latency_s * 1e3,
        travel * 1e3,
        from_crossing * 1e3,
        allowed * 1e3
    );
    let rest = summary.retracts[0].from;
    // It was pressing, not yet at the planned depth, and is left clear of the gel.
    let surface_inv = pose::pose_inv(&config.sensor.surface_frame);
    let depth_mm = -pose::pose_trans(&surface_inv, &rest).z * 1e3;
    eprintln!("stopped {depth_mm:.3} mm deep: {}", summary.report());
    assert!(
        depth_mm > 0.0 && depth_mm < 0.8,
        "stopped {depth_mm:.3} mm deep"
    );
    let end = summary.retracts.first().unwrap().to;
    let height_mm = pose::pose_trans(&surface_inv, &end).z * 1e3;
    assert!(
        (height_mm - config.plan.approach_height_mm).abs() < 1e-3,
        "retracted to {height_mm:.3} mm"
    );
    let m = Manifest::load(&out).unwrap();
    assert_eq!(m.entry(&id).unwrap().status, Status::Failed);
}

/// A target recorded without an F/T sensor, as `rig run` writes one (frames, TCP poses, stage
/// labels; the config's `force_sensor` null), through the real recorder: `trajectories` of
/// `frames` frames each.
async fn forceless_target(dir: &Path, trajectories: usize, frames: u64) {
    use rig::record::{Recorder, RecorderConfig, SensorInfo, synthetic::png_frame};
    let mut config = RigConfig::sim_target();
    config.force_sensor = None;
    let ids: Vec<String> = (0..trajectories)
        .map(|k| format!("p0-d0.4-a{k:03}"))
        .collect();
    let manifest = Manifest::new(
        "sphere",
        SensorInfo {
            id: config.sensor.id.clone(),
            role: "target".into(),
        },
        serde_json::to_value(&config).unwrap(),
        serde_json::Value::Null,
        &ids,
    );
    let rec = Recorder::start(dir, manifest, RecorderConfig::default()).unwrap();
    for id in &ids {
        rec.begin(id).await.unwrap();
        for (k, stage) in rig::plan::StageName::ALL.iter().enumerate() {
            rec.send(rig::record::Record::Stage {
                t_ns: k as u64 * 100_000_000,
                stage: *stage,
            })
            .await
            .unwrap();
        }
        for k in 0..frames {
            let t_ns = k * 40_000_000;
            rec.send(rig::record::Record::Pose {
                t_ns,
                pose: rig_core::pose::Pose::new(
                    0.4,
                    0.0,
                    0.2 - k as f64 * 1e-5,
                    std::f64::consts::PI,
                    0.0,
                    0.0,
                ),
            })
            .await
            .unwrap();
            rec.send(rig::record::Record::Frame {
                seq: k as i64,
                t_ns,
                format: rig::record::ImageFormat::Png,
                data: png_frame(40, 30, k),
            })
            .await
            .unwrap();
        }
        rec.finish(0).await.unwrap();
    }
    rec.close().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_target_recorded_without_forces_serves_the_translator_and_eval_asks_for_labels() {
    use rig::train::data::{self, ImageSpec};
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("target");
    forceless_target(&dir, 2, 12).await;
    // `rig dataset check` accepts it as it is.
    let report = rig::dataset::check(&dir);
    assert!(report.ok(), "{report:?}");
    assert_eq!((report.complete, report.frames), (2, 24));
    assert!(!Manifest::load(&dir).unwrap().records_forces());
    assert!(!data::has_forces(&dir).unwrap());
    assert_eq!(data::role_of(&dir).unwrap(), "target");

    // The translator's target images: every frame (nothing is paired, nothing is dropped),
    // the same through the decode cache.
    let spec = ImageSpec {
        width: 16,
        height: 12,
        modality: rig::train::modality::Modality::RgbMarker,
    };
    for pass in ["decoded", "cached"] {
        let set = data::load_unlabelled(&dir, &spec, false).unwrap();
        let frames: Vec<usize> = set.trajectories.iter().map(|t| t.frames).collect();
        assert_eq!(frames, [12, 12], "{pass}");
    }
    // Evaluating a force model needs forces, and says where they come from.
    let e = data::load_eval(&dir, &spec, false).unwrap_err();
    let msg = format!("{e:#}");
    assert!(
        msg.contains("without an F/T sensor") && msg.contains("needs a labelled target"),
        "{msg}"
    );
    // Training on it is refused as for any target.
    assert!(data::load_labelled(&dir, &spec, false).is_err());
}
