//! `rig predict`: the trained model on the simulated target sensor's camera, frame by frame.
//!
//! - A replay of a recorded target dataset gives, frame for frame, the forces `rig eval`
//!   scores (the same windows), so its MAE is eval's.
//! - Live on the simulated rig (camera at its configured rate, clock ×1), every frame is
//!   estimated: none skipped; the estimates are scored against the simulator's truth.
//! - The live view advertises `/predict/wrench` and a Foxglove client receives the estimates.
//! - Bad input is refused with a message: no model, a model of another format version, frames
//!   of another aspect ratio.
//!
//! All at the quick demo's scale: a target dataset of a few trajectories (160 × 120 at 10 fps),
//! a tiny model (32 × 24 input, width 4, one epoch on synthetic frames: its accuracy does not
//! matter here, only that predict computes what eval computes).

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use std::time::Duration;

use futures_util::{SinkExt, StreamExt};
use rig::predict::output::{Format, Output, TOPIC_PREDICTED, predicted_channel};
use rig::predict::session::{self, Feed};
use rig::predict::source::{Replay, SimRun, marker_of};
use rig::predict::{Predictor, PredictorOptions};
use rig::train::Progress;
use rig::train::data::{self, ImageSpec, LabelledSet, Trajectory};
use rig::train::eval;
use rig::train::force::{self, ForceConfig, ForceModel};
use rig::train::modality::Modality;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;
use rig_nn::Depth;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

use crate::common;

const SPEC: ImageSpec = ImageSpec {
    width: 32,
    height: 24,
    modality: Modality::RgbMarker,
};

/// The quick demo's target sensor: 160 × 120 at 10 fps, the centre contact point.
fn target_config() -> RigConfig {
    let plan = rig::train::demo::DemoPlan::new(true);
    rig::train::demo::demo_config(RigConfig::sim_target(), &plan)
}

struct Fixture {
    data: PathBuf,
    model: PathBuf,
}

/// A recorded target dataset (3 trajectories) and a tiny model, made once for the module.
fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let root = Path::new(env!("CARGO_TARGET_TMPDIR")).join("predict-fixture");
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&root).unwrap();
        let data = root.join("target");
        {
            let _rig = common::one_rig_at_a_time();
            let opts = rig::run::RunOptions {
                limit: Some(3),
                ..rig::run::RunOptions::new(&data)
            };
            let rt = tokio::runtime::Runtime::new().unwrap();
            let s = rt
                .block_on(rig::run::run(
                    &target_config(),
                    &Indenter::load("sphere").unwrap(),
                    &opts,
                ))
                .unwrap();
            assert!(s.failure.is_none(), "{}", s.report());
        }
        let model = root.join("model");
        force::train(
            &synthetic_set(),
            &tiny_config(),
            "tiny",
            &model,
            false,
            Progress::Silent,
        )
        .unwrap();
        Fixture { data, model }
    })
}

fn tiny_config() -> ForceConfig {
    ForceConfig {
        depth: Depth::R18,
        width: 4,
        embed: 16,
        seq_len: 8,
        per_trajectory: 2,
        epochs: 1,
        batch: 4,
        ..ForceConfig::default()
    }
}

/// Frames with a bright disc whose size follows the force, 40 frames per trajectory.
fn synthetic_set() -> LabelledSet {
    let (w, h) = (SPEC.width, SPEC.height);
    let mut trajs = Vec::new();
    let mut forces = Vec::new();
    for k in 0..3 {
        let f: Vec<[f32; 3]> = (0..40)
            .map(|i| {
                let s = (i as f32 / 39.0 * std::f32::consts::PI).sin();
                [0.2 * s * (k as f32 - 1.0), 0.1 * s, -2.0 * s]
            })
            .collect();
        let mut px = Vec::new();
        for fi in &f {
            let r2 = 4.0 + 20.0 * -fi[2];
            for y in 0..h {
                for x in 0..w {
                    let d2 = (x as f32 - 16.0).powi(2) + (y as f32 - 12.0).powi(2);
                    let v = if d2 < r2 { 220 } else { 90 };
                    px.extend_from_slice(&[v, v / 2, 60]);
                }
            }
        }
        trajs.push(Trajectory {
            id: format!("s{k}"),
            indenter: "sphere".into(),
            pixels: px,
            frames: 40,
        });
        forces.push(f);
    }
    LabelledSet::from_parts(SPEC, trajs, forces).unwrap()
}

fn quiet() -> Output {
    Output::new(Format::Quiet, Box::new(std::io::sink()))
}

#[test]
fn a_replay_gives_eval_s_forces_frame_for_frame() {
    let f = fixture();
    // What `rig eval` computes: its windows, its per-frame predictions and truths.
    let model = ForceModel::load(&f.model).unwrap();
    let set = data::load_eval(&f.data, &model.spec(), false).unwrap();
    let lengths: Vec<usize> = set.trajectories.iter().map(|t| t.frames).collect();
    assert_eq!(lengths.len(), 3);
    let windows = eval::eval_windows(&lengths, 8);
    let seqs: Vec<_> = windows.iter().map(|(s, _)| s.clone()).collect();
    let out = model.predict(&set.trajectories, &seqs, 16);
    let mut by_frame = std::collections::BTreeMap::new();
    for ((s, skip), pred) in windows.iter().zip(&out) {
        for (k, &i) in s.frames.iter().enumerate().skip(*skip) {
            by_frame.insert((s.traj, i), pred[k]);
        }
    }
    let p = eval::predict(&model, &set);
    let eval_scores = rig::train::metrics::score(&p.pred, &p.truth);

    // The replay, as fast as possible (lossless), without a tare.
    let predictor = Predictor::load(
        &f.model,
        PredictorOptions {
            stride: Some(1),
            ..PredictorOptions::default()
        },
    )
    .unwrap();
    let feed = Arc::new(Feed::new(true));
    let replay = Replay {
        dir: f.data.clone(),
        speed: None,
        seq_len: 8,
        live: None,
    };
    let s = session::run(predictor, feed, move |f| replay.run(f), &mut quiet()).unwrap();
    assert_eq!(s.skipped, 0);
    assert_eq!(s.frames as usize, lengths.iter().sum::<usize>());
    assert_eq!(s.estimates.len(), by_frame.len());

    // Frame for frame: the i-th estimate of trajectory t is eval's prediction of frame i.
    let mut worst = 0f64;
    let mut index = [0usize; 3];
    for (traj, _seq, est) in &s.estimates {
        let i = index[*traj];
        index[*traj] += 1;
        let want = by_frame[&(*traj, i)];
        for (got, want) in est.force_n.iter().zip(want) {
            worst = worst.max((got - want as f64).abs());
        }
    }
    assert!(worst < 1e-4, "replay differs from eval by up to {worst} N");

    // And so the MAE against the paired force: eval's, within 1 %.
    let r = s
        .vs_paired
        .as_ref()
        .expect("the replay knows the paired forces");
    assert_eq!(r.n, eval_scores.n);
    for a in 0..3 {
        let rel = (r.mae[a] - eval_scores.mae[a]).abs() / eval_scores.mae[a].max(1e-9);
        assert!(
            rel < 0.01,
            "axis {a}: replay MAE {} vs eval {}",
            r.mae[a],
            eval_scores.mae[a]
        );
    }
    let rel = (r.total_mae - eval_scores.total_mae).abs() / eval_scores.total_mae.max(1e-9);
    assert!(rel < 0.01, "{} vs {}", r.total_mae, eval_scores.total_mae);
    // The simulator's truth was recorded too, and is reported beside it.
    assert_eq!(s.vs_sim.as_ref().map(|v| v.n), Some(r.n));
}

/// A marker-displacement model (`flow`, and `flow+shading` with the shading change in blue):
/// the replay tracks each trajectory's markers from its first frame with the recording's
/// optics, as the trainer's loader does, so it gives eval's forces frame for frame too. (An
/// untrained model: only the inputs' agreement matters.)
#[test]
fn a_replay_of_a_flow_model_gives_eval_s_forces_frame_for_frame() {
    let f = fixture();
    for modality in Modality::MARKERS {
        replay_equals_eval(f, modality, &tiny_config());
    }
    // Marker flow as `rig reproduce` trains it: the encoder pools its last map.
    let pooled = ForceConfig {
        global_pool: true,
        ..tiny_config()
    };
    replay_equals_eval(f, Modality::FlowShading, &pooled);
}

fn replay_equals_eval(f: &Fixture, modality: Modality, cfg: &ForceConfig) {
    let spec = ImageSpec { modality, ..SPEC };
    // Two copies of one untrained model (the same seed): one for eval, one to replay with.
    let model = ForceModel::untrained(cfg, spec, 40);
    assert_eq!(model.info.shape.spatial.is_none(), cfg.global_pool);
    let set = data::load_eval(&f.data, &spec, false).unwrap();
    // The flow images move: the markers were tracked through the presses.
    let moved = set
        .trajectories
        .iter()
        .flat_map(|t| {
            t.pixels
                .chunks_exact(3)
                .map(|p| p[0].abs_diff(128).max(p[1].abs_diff(128)))
        })
        .max()
        .unwrap();
    assert!(
        moved >= 10,
        "{modality}: the largest displacement is {moved} levels (0.01 mm each)"
    );
    // Blue: mid-grey for D; for D+S the shading change, none at a trajectory's first frame and
    // some in its presses.
    let blue: Vec<u8> = set
        .trajectories
        .iter()
        .flat_map(|t| t.pixels.chunks_exact(3).map(|p| p[2]))
        .collect();
    if modality == Modality::Flow {
        assert!(blue.iter().all(|&b| b == 128));
    } else {
        let first = &set.trajectories[0].pixels[..spec.frame_bytes()];
        assert!(first.chunks_exact(3).all(|p| p[2] == 0), "{modality}");
        let most = blue.iter().max().copied().unwrap_or(0);
        assert!(
            most >= 20,
            "{modality}: the largest shading change is {most} levels"
        );
    }
    // D+S read on a sensor whose shading is weaker than the training sensor's: the model's
    // training mean is 1.5 times this set's, so eval and the replay both scale blue ×1.5.
    let gain = if modality == Modality::FlowShading {
        let m = data::mean_shading(set.trajectories.iter().map(|t| t.pixels.as_slice())).unwrap();
        // The fixture's indenters, seen or not: the mean over all of them is the set's.
        let split = data::Split {
            unseen: Vec::new(),
            excluded: Vec::new(),
        };
        let g = set.shading_gain_for(Some(1.5 * m), &split);
        assert!((g - 1.5).abs() < 1e-9, "{g}");
        g
    } else {
        1.0
    };
    let set = set.with_shading_gain(gain);
    let p = eval::predict(&model, &set);
    // Its outputs follow its input, so agreeing frame for frame means the same inputs.
    let (lo, hi) = p.pred.iter().fold((f64::MAX, f64::MIN), |(lo, hi), f| {
        (lo.min(f[0]), hi.max(f[0]))
    });
    assert!(
        hi - lo > 1e-3,
        "the untrained model's Fx spans only {} N",
        hi - lo
    );

    let mut predictor = Predictor::new(
        ForceModel::untrained(cfg, spec, 40),
        PredictorOptions {
            stride: Some(1),
            ..PredictorOptions::default()
        },
    )
    .unwrap();
    predictor.set_shading_gain(gain).unwrap();
    let replay = Replay {
        dir: f.data.clone(),
        speed: None,
        seq_len: 8,
        live: None,
    };
    let s = session::run(
        predictor,
        Arc::new(Feed::new(true)),
        move |f| replay.run(f),
        &mut quiet(),
    )
    .unwrap();
    assert_eq!(s.estimates.len(), p.pred.len());
    // `eval::predict` lists frames trajectory by trajectory in frame order, as the replay
    // estimates them.
    let mut want: Vec<(usize, usize, [f64; 3])> = (0..p.pred.len())
        .map(|k| (p.traj[k], p.frame[k], p.pred[k]))
        .collect();
    want.sort_by_key(|w| (w.0, w.1));
    let mut worst = 0f64;
    for ((traj, _seq, est), (t, _i, pred)) in s.estimates.iter().zip(&want) {
        assert_eq!(traj, t);
        for (a, b) in est.force_n.iter().zip(pred) {
            worst = worst.max((a - b).abs());
        }
    }
    assert!(
        worst < 1e-4,
        "{modality}: replay differs from eval by up to {worst} N"
    );
}

#[test]
fn live_on_the_simulated_rig_every_frame_is_estimated_and_the_live_view_shows_it() {
    let f = fixture();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let live = Arc::new(
        rt.block_on(rig::live::LiveView::start_with_channels(
            "127.0.0.1:0".parse().unwrap(),
            rig::live::LiveLimits::default(),
            vec![predicted_channel()],
        ))
        .unwrap(),
    );
    // A Foxglove client subscribed to the estimates before the run starts.
    let addr = live.addr();
    let mut ws = rt.block_on(async {
        let req = format!("ws://{addr}/").into_client_request().unwrap();
        let tcp = tokio::net::TcpStream::connect(addr).await.unwrap();
        let (mut ws, _) = tokio_tungstenite::client_async(req, tcp).await.unwrap();
        let _info = next_text(&mut ws).await;
        let adv = next_text(&mut ws).await;
        let ch = adv["channels"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["topic"] == TOPIC_PREDICTED)
            .unwrap_or_else(|| panic!("{TOPIC_PREDICTED} not advertised: {adv}"))
            .clone();
        assert_eq!(ch["schemaName"], "rig.PredictedWrench");
        assert!(
            adv["channels"]
                .as_array()
                .unwrap()
                .iter()
                .any(|c| c["topic"] == "/camera/image"),
            "the image is advertised beside it"
        );
        let sub = serde_json::json!({"op": "subscribe",
            "subscriptions": [{"id": 7, "channelId": ch["id"]}]});
        ws.send(Message::Text(sub.to_string().into()))
            .await
            .unwrap();
        ws
    });
    // Let the subscription land before the first estimate.
    std::thread::sleep(Duration::from_millis(200));

    let config = target_config();
    let predictor = Predictor::load(
        &f.model,
        PredictorOptions {
            tare_frames: 4,
            marker: marker_of(&config),
            ..PredictorOptions::default()
        },
    )
    .unwrap();
    // The model's default stride: eval's for its 40-frame training trajectories.
    assert_eq!(predictor.stride(), 5);
    let feed = Arc::new(Feed::new(false));
    let sim = SimRun {
        config,
        indenter: Indenter::load("sphere").unwrap(),
        limit: 1,
        speed_factor: 1.0,
        live: Some(live.clone()),
    };
    let mut out = quiet().with_live(live.clone());
    let s = {
        let _rig = common::one_rig_at_a_time();
        session::run(predictor, feed, move |f| sim.run(f), &mut out).unwrap()
    };
    eprintln!("{}", s.report());
    assert!(s.frames >= 20, "{}", s.report());
    assert_eq!(s.skipped, 0, "{}", s.report());
    assert_eq!(s.processed, s.frames);
    assert_eq!(s.tare_frames, 4);
    assert_eq!(s.estimates.len() as u64, s.frames - 4);
    let truth = s.vs_sim.as_ref().expect("the simulator's truth");
    assert_eq!(truth.n, s.estimates.len());
    assert!(s.latency_ms_p99.is_finite() && s.latency_ms_p99 > 0.0);

    // The client got the estimates, with the frames' timestamps and the same forces.
    let (sub, t_ns, body) = rt.block_on(async {
        loop {
            match tokio::time::timeout(Duration::from_secs(5), ws.next())
                .await
                .expect("an estimate within 5 s")
                .unwrap()
                .unwrap()
            {
                Message::Binary(b) => {
                    break (
                        u32::from_le_bytes(b[1..5].try_into().unwrap()),
                        u64::from_le_bytes(b[5..13].try_into().unwrap()),
                        serde_json::from_slice::<serde_json::Value>(&b[13..]).unwrap(),
                    );
                }
                _ => continue,
            }
        }
    });
    assert_eq!(sub, 7);
    let first = &s.estimates[0].2;
    assert_eq!(t_ns, first.t_ns);
    assert_eq!(body["frame_seq"], s.estimates[0].1);
    for a in 0..3 {
        let v = body["force_n"][a].as_f64().unwrap();
        assert!((v - first.force_n[a]).abs() < 1e-9, "{body}");
    }
}

async fn next_text(
    ws: &mut tokio_tungstenite::WebSocketStream<tokio::net::TcpStream>,
) -> serde_json::Value {
    match tokio::time::timeout(Duration::from_secs(5), ws.next())
        .await
        .unwrap()
        .unwrap()
        .unwrap()
    {
        Message::Text(t) => serde_json::from_str(&t).unwrap(),
        other => panic!("expected text, got {other:?}"),
    }
}

#[test]
fn bad_input_is_refused_with_a_message_that_says_what_to_do() {
    let f = fixture();
    // No model there.
    let missing = Predictor::load(Path::new("/nonexistent/model"), PredictorOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(
        missing.contains("no model at /nonexistent/model"),
        "{missing}"
    );
    assert!(missing.contains("rig train force --out"), "{missing}");

    // A model of another format version.
    let tmp = tempfile::tempdir().unwrap();
    let other = tmp.path().join("model");
    std::fs::create_dir(&other).unwrap();
    for e in std::fs::read_dir(&f.model).unwrap() {
        let p = e.unwrap().path();
        if p.is_file() {
            std::fs::copy(&p, other.join(p.file_name().unwrap())).unwrap();
        }
    }
    let info = other.join("model.json");
    let text = std::fs::read_to_string(&info).unwrap();
    assert!(text.contains("\"rig-force-model-2\""));
    std::fs::write(
        &info,
        text.replace("rig-force-model-2", "rig-force-model-3"),
    )
    .unwrap();
    let version = Predictor::load(&other, PredictorOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(version.contains("\"rig-force-model-3\""), "{version}");
    assert!(version.contains("reads \"rig-force-model-2\""), "{version}");
    assert!(version.contains("retrain"), "{version}");

    // Frames of another aspect ratio, and frames smaller than the model's input.
    let mut p = Predictor::load(&f.model, PredictorOptions::default()).unwrap();
    let wide = p
        .push(&image::RgbImage::new(160, 90), 0)
        .unwrap_err()
        .to_string();
    assert!(wide.contains("160×90") && wide.contains("32×24"), "{wide}");
    assert!(wide.contains("aspect"), "{wide}");
    let small = p
        .push(&image::RgbImage::new(16, 12), 0)
        .unwrap_err()
        .to_string();
    assert!(small.contains("smaller than the model's 32×24"), "{small}");
    // The refused frames left the predictor as it was: a good frame is estimated.
    let est = p.push(&image::RgbImage::new(160, 120), 5).unwrap().unwrap();
    assert_eq!(est.t_ns, 5);
    assert!(est.force_n.iter().all(|v| v.is_finite()));

    // The command line: an error message and status 1, no panic.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["predict", "--model", "/nonexistent/model", "--replay"])
        .arg(&f.data)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{}", common::output_text(&o));
    assert!(err.contains("no model at"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// Frames of the fixture's dataset that `rig eval` (and so a replay) scores.
fn dataset_frames(f: &Fixture) -> usize {
    let model = ForceModel::load(&f.model).unwrap();
    let set = data::load_eval(&f.data, &model.spec(), false).unwrap();
    set.trajectories.iter().map(|t| t.frames).sum()
}

/// Splits a CSV line of `rig predict --csv` into its fields.
fn csv_fields(line: &str) -> Vec<&str> {
    line.split(',').collect()
}

#[test]
fn the_command_line_writes_the_same_estimates_as_csv_json_lines_and_mcap() {
    let f = fixture();
    let tmp = tempfile::tempdir().unwrap();
    let run = |extra: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_rig"))
            .args(["predict", "--model"])
            .arg(&f.model)
            .arg("--replay")
            .arg(&f.data)
            .args(["--replay-speed", "max"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", common::output_text(&o));
        String::from_utf8(o.stdout).unwrap()
    };
    let mcap_path = tmp.path().join("predicted.mcap");
    let csv = run(&["--csv", "--out", mcap_path.to_str().unwrap()]);
    let json = run(&[]);

    // CSV: the header, then one row per frame of the dataset (a replay estimates every frame
    // and takes no tare), with the paired force of the recording beside the estimate.
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(rig::predict::output::CSV_HEADER));
    let rows: Vec<Vec<&str>> = lines.map(csv_fields).collect();
    let frames = dataset_frames(f);
    assert_eq!(rows.len(), frames, "{csv}");
    let num = |s: &str| {
        s.parse::<f64>()
            .unwrap_or_else(|_| panic!("{s:?} in {csv}"))
    };
    for r in &rows {
        assert_eq!(r.len(), 12, "{r:?}");
        assert!(!r[1].is_empty(), "the trajectory is named: {r:?}");
        for v in &r[3..9] {
            assert!(num(v).is_finite(), "{r:?}");
        }
    }

    // JSON lines: the same estimates, in the same order, at full precision.
    let objs: Vec<serde_json::Value> = json
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(objs.len(), rows.len());
    for (o, r) in objs.iter().zip(&rows) {
        assert_eq!(o["t_ns"].as_u64().unwrap(), r[0].parse::<u64>().unwrap());
        assert_eq!(o["trajectory"].as_str().unwrap(), r[1]);
        assert_eq!(o["seq"].as_i64().unwrap(), r[2].parse::<i64>().unwrap());
        for a in 0..3 {
            let v = o["force_n"][a].as_f64().unwrap();
            // CSV carries 5 decimals.
            assert!((v - num(r[3 + a])).abs() <= 0.6e-5, "{o} vs {r:?}");
            let p = o["paired_force_n"][a].as_f64().unwrap();
            assert!((p - num(r[6 + a])).abs() <= 0.6e-5, "{o} vs {r:?}");
        }
    }

    // The MCAP file: complete (no .partial left), one /predict/wrench message per estimate,
    // stamped with its frame's time, holding the same forces.
    assert!(!tmp.path().join("predicted.mcap.partial").exists());
    let bytes = std::fs::read(&mcap_path).unwrap();
    let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(|m| m.unwrap())
        .collect();
    assert_eq!(msgs.len(), objs.len());
    for (m, o) in msgs.iter().zip(&objs) {
        assert_eq!(m.channel.topic, TOPIC_PREDICTED);
        assert_eq!(m.log_time, o["t_ns"].as_u64().unwrap());
        let body: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        assert_eq!(body["frame_seq"], o["seq"]);
        for a in 0..3 {
            let got = body["force_n"][a].as_f64().unwrap();
            let want = o["force_n"][a].as_f64().unwrap();
            assert!(
                (got - want).abs() <= 1e-9 * want.abs().max(1.0),
                "{body} vs {o}"
            );
        }
    }
}

#[test]
fn ctrl_c_ends_a_replay_with_its_summary_and_a_complete_mcap_file() {
    let f = fixture();
    let tmp = tempfile::tempdir().unwrap();
    let mcap_path = tmp.path().join("predicted.mcap");
    // At the recorded timing the dataset takes 12 s; interrupt it after 3.
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_rig"))
        .args(["predict", "--model"])
        .arg(&f.model)
        .arg("--replay")
        .arg(&f.data)
        .args(["--quiet", "--summary-json", "--out"])
        .arg(&mcap_path)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(3));
    let sent = std::process::Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(sent.success());
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{}", common::output_text(&o));
    assert!(err.contains("Ctrl-C: stopping"), "{err}");
    assert!(err.contains("latency"), "the summary is printed: {err}");
    let summary: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&o.stdout).trim()).unwrap();
    let processed = summary["processed"].as_u64().unwrap();
    let total = dataset_frames(f);
    assert!(
        (processed as usize) < total,
        "stopped early: {processed} of {total}"
    );
    // Every estimate made is in the file, and the file is whole.
    let bytes = std::fs::read(&mcap_path).expect("the MCAP file was completed");
    let msgs: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(msgs.len() as u64, processed);
}

/// A V4L2 device delivering scripted YUYV frames at a camera's pace (one every `period`).
struct PacedCamera {
    frames: std::collections::VecDeque<rig::camera::v4l2::RawFrame>,
    period: Duration,
    next: Option<std::time::Instant>,
}

impl rig::camera::v4l2::DeviceLayer for PacedCamera {
    fn modes(&mut self) -> std::io::Result<Vec<rig::camera::v4l2::OfferedMode>> {
        Ok(vec![rig::camera::v4l2::OfferedMode {
            pixel: rig::camera::PixelFormat::Yuyv,
            width: 320,
            height: 240,
            fps: vec![25.0],
        }])
    }
    fn configure(
        &mut self,
        f: &rig::camera::FrameFormat,
    ) -> std::io::Result<rig::camera::FrameFormat> {
        Ok(*f)
    }
    fn start(&mut self, _buffers: u32) -> std::io::Result<()> {
        Ok(())
    }
    fn dequeue(&mut self) -> std::io::Result<Option<rig::camera::v4l2::RawFrame>> {
        let due = *self.next.get_or_insert_with(std::time::Instant::now);
        if let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
            std::thread::sleep(wait);
        }
        self.next = Some(due + self.period);
        Ok(self.frames.pop_front())
    }
}

/// 320 × 240 YUYV frames of a smooth pattern that changes from frame to frame.
fn yuyv_frames(n: usize) -> Vec<rig::camera::v4l2::RawFrame> {
    (0..n)
        .map(|k| {
            let mut data = Vec::with_capacity(320 * 240 * 2);
            for y in 0..240usize {
                for x in (0..320usize).step_by(2) {
                    let luma = |x: usize| (16 + (x / 2 + y + 7 * k) % 200) as u8;
                    data.extend_from_slice(&[
                        luma(x),
                        (118 + (k % 20)) as u8,
                        luma(x + 1),
                        (140 - (x % 32)) as u8,
                    ]);
                }
            }
            rig::camera::v4l2::RawFrame {
                data,
                sequence: k as u32,
                timestamp_ns: 1_000_000_000_000 + k as u64 * 40_000_000,
                error: false,
            }
        })
        .collect()
}

#[test]
fn a_v4l2_camera_is_read_at_its_rate_and_every_frame_is_estimated_as_the_library_would() {
    let f = fixture();
    let n = 30;
    let raw = yuyv_frames(n);
    let opts = || PredictorOptions {
        tare_frames: 4,
        ..PredictorOptions::default()
    };
    let device = PacedCamera {
        frames: raw.clone().into(),
        period: Duration::from_millis(40),
        next: None,
    };
    let source = move |feed: Arc<Feed>| -> anyhow::Result<()> {
        let rt = tokio::runtime::Runtime::new()?;
        rt.block_on(async {
            let cam = rig::camera::v4l2::V4l2Source::open(
                device,
                "/dev/fake-gelsight",
                rig_core::clock::Clock::system(),
                &rig::camera::v4l2::Request::new(320, 240, 25.0),
                &rig::camera::v4l2::V4l2Options::default(),
            )?;
            rig::predict::source::read_camera(Box::new(cam), Some(n as u64), &feed).await
        })
    };
    let predictor = Predictor::load(&f.model, opts()).unwrap();
    let s = session::run(predictor, Arc::new(Feed::new(false)), source, &mut quiet()).unwrap();
    eprintln!("{}", s.report());
    // At the camera's rate nothing is skipped; the first 4 frames make the tare.
    assert_eq!(s.frames, n as u64, "{}", s.report());
    assert_eq!(s.skipped, 0, "{}", s.report());
    assert_eq!(s.tare_frames, 4);
    assert_eq!(s.estimates.len(), n - 4);
    // Each estimate carries its frame's sequence number and a capture time on the rig's clock,
    // in order.
    for (i, (_, seq, e)) in s.estimates.iter().enumerate() {
        assert_eq!(*seq, (i + 4) as i64);
        if i > 0 {
            assert!(e.t_ns > s.estimates[i - 1].2.t_ns);
        }
    }

    // The library fed the same frames, decoded from YUYV, gives the same forces.
    let mut p = Predictor::load(&f.model, opts()).unwrap();
    let format = rig::camera::FrameFormat {
        pixel: rig::camera::PixelFormat::Yuyv,
        width: 320,
        height: 240,
        fps: 25.0,
    };
    let mut want = Vec::new();
    for (k, r) in raw.iter().enumerate() {
        let frame = rig::camera::Frame {
            sequence: k as u64,
            device_ts_ns: r.timestamp_ns,
            capture_t_ns: None,
            received_t_ns: 0,
            dropped_before: 0,
            format,
            data: r.data.clone(),
            truth: None,
        };
        if let Some(e) = p.push(&frame.to_rgb().unwrap(), k as u64).unwrap() {
            want.push(e.force_n);
        }
    }
    assert_eq!(want.len(), s.estimates.len());
    for (w, (_, _, e)) in want.iter().zip(&s.estimates) {
        for a in 0..3 {
            assert!(
                (w[a] - e.force_n[a]).abs() < 1e-9,
                "{w:?} vs {:?}",
                e.force_n
            );
        }
    }
    // The pattern changes frame to frame, and so do the estimates.
    assert!(
        want.windows(2).any(|p| p[0] != p[1]),
        "every estimate the same: {want:?}"
    );
}
