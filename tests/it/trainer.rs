//! The trainer on tiny CPU configurations: translation learns, the force model fits, variants
//! share one code path, checkpoints round-trip, non-finite losses stop training safely, and
//! seeds make runs repeatable.

use burn::tensor::Tensor;
use rig::train::Progress;
use rig::train::batch::{Rng, images_to_tensor};
use rig::train::cyclegan::{CycleGan, TranslateConfig};
use rig::train::data::{ImageSpec, LabelledSet, Trajectory};
use rig::train::eval::eval_windows;
use rig::train::force::{self, ForceConfig, ForceModel};
use rig::train::modality::Modality;
use rig_nn::{Depth, GanShape};

const W: u32 = 16;

/// burn seeds one random generator per device for the whole process: two trainings running at
/// once in one process draw from it in turn. Tests that train take this lock so that each run's
/// initial weights come from its own seed alone.
static TRAINING: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    TRAINING.lock().unwrap_or_else(|e| e.into_inner())
}
const H: u32 = 16;

fn spec() -> ImageSpec {
    ImageSpec {
        width: W,
        height: H,
        modality: Modality::RgbMarker,
    }
}

/// A frame whose content encodes the force: a disc whose brightness grows with |Fz| and whose
/// centre moves with (Fx, Fy), on a grey background.
fn frame(f: [f32; 3]) -> Vec<u8> {
    let (cx, cy) = (7.5 + 3.0 * f[0], 7.5 + 3.0 * f[1]);
    let mut px = Vec::with_capacity((W * H * 3) as usize);
    for y in 0..H {
        for x in 0..W {
            let d2 = (x as f32 - cx).powi(2) + (y as f32 - cy).powi(2);
            let v = if d2 < 16.0 {
                80.0 + 170.0 * (-f[2]).clamp(0.0, 1.0)
            } else {
                60.0
            };
            px.extend_from_slice(&[v as u8, (v * 0.8) as u8, 40]);
        }
    }
    px
}

/// Four trajectories of 12 frames: press (Fz 0 → −1), shear along one direction, release.
fn tiny_set() -> LabelledSet {
    four_presses(spec(), frame, |k, i, s| {
        let dir = [[1.0f32, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]][k];
        let shear = if (3..9).contains(&i) { 0.8 * s } else { 0.0 };
        [shear * dir[0], shear * dir[1], -s]
    })
}

/// Four presses of a sphere, 12 frames each: frame `i` of trajectory `k` carries
/// `force(k, i, s)`, `s` the press's profile sin(π i / 11), and shows `image(force)`.
fn four_presses(
    spec: ImageSpec,
    image: impl Fn([f32; 3]) -> Vec<u8>,
    force: impl Fn(usize, usize, f32) -> [f32; 3],
) -> LabelledSet {
    let mut trajs = Vec::new();
    let mut forces = Vec::new();
    for k in 0..4 {
        let f: Vec<[f32; 3]> = (0..12)
            .map(|i| force(k, i, (i as f32 / 11.0 * std::f32::consts::PI).sin()))
            .collect();
        let pixels = f.iter().flat_map(|f| image(*f)).collect();
        trajs.push(Trajectory {
            id: format!("t{k}"),
            indenter: "sphere".into(),
            pixels,
            frames: 12,
        });
        forces.push(f);
    }
    LabelledSet::from_parts(spec, trajs, forces).unwrap()
}

fn small_force(lstm: bool, epochs: usize) -> ForceConfig {
    ForceConfig {
        depth: Depth::R18,
        width: 4,
        embed: 16,
        lstm,
        seq_len: 4,
        // As many draws per epoch as a 12-frame trajectory has 4-frame windows.
        per_trajectory: 9,
        epochs,
        batch: 4,
        lr: 3e-3,
        ..ForceConfig::default()
    }
}

/// Every frame's prediction and truth.
fn predict_all(model: &ForceModel, set: &LabelledSet) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let lengths: Vec<usize> = set.trajectories.iter().map(|t| t.frames).collect();
    let windows = eval_windows(&lengths, model.info.config.seq_len);
    let seqs: Vec<_> = windows.iter().map(|(s, _)| s.clone()).collect();
    let out = model.predict(&set.trajectories, &seqs, 8);
    let mut pred = Vec::new();
    let mut truth = Vec::new();
    for ((s, skip), p) in windows.iter().zip(out) {
        for (k, &i) in s.frames.iter().enumerate().skip(*skip) {
            pred.push(p[k]);
            truth.push(set.forces(s.traj)[i]);
        }
    }
    (pred, truth)
}

fn mae(pred: &[[f32; 3]], truth: &[[f32; 3]]) -> [f32; 3] {
    std::array::from_fn(|a| {
        pred.iter()
            .zip(truth)
            .map(|(p, t)| (p[a] - t[a]).abs())
            .sum::<f32>()
            / pred.len() as f32
    })
}

#[test]
fn a_cyclegan_step_lowers_the_cycle_loss_on_a_fixed_batch() {
    let _serial = serial();
    let cfg = TranslateConfig {
        shape: GanShape {
            ngf: 4,
            ndf: 4,
            res_blocks: 1,
            disc_layers: 2,
            down: 2,
        },
        lr: 2e-3,
        pool: 4,
        ..TranslateConfig::default()
    };
    let mut gan = CycleGan::new(&cfg);
    let s: Vec<Vec<u8>> = [[0.0, 0.0, -0.5], [0.5, 0.0, -1.0]]
        .iter()
        .map(|f| frame(*f))
        .collect();
    // The "target sensor": the same scenes with the colour channels swapped.
    let t: Vec<Vec<u8>> = s
        .iter()
        .map(|px| px.chunks(3).flat_map(|c| [c[2], c[0], c[1]]).collect())
        .collect();
    let rs: Vec<&[u8]> = s.iter().map(|x| x.as_slice()).collect();
    let rt: Vec<&[u8]> = t.iter().map(|x| x.as_slice()).collect();
    let dev = gan.dev.clone();
    let (bs, bt) = (
        images_to_tensor(&rs, &spec(), &dev),
        images_to_tensor(&rt, &spec(), &dev),
    );
    let before = gan.cycle_loss(bs.clone(), bt.clone());
    for _ in 0..25 {
        let l = gan.step(bs.clone(), bt.clone(), cfg.lr).unwrap();
        assert!(l.cycle.is_finite() && l.adv.is_finite() && l.disc.is_finite());
    }
    let after = gan.cycle_loss(bs, bt);
    assert!(after < 0.7 * before, "cycle loss {before:.4} → {after:.4}");
}

#[test]
fn the_force_model_overfits_a_tiny_dataset_and_round_trips_through_its_checkpoint() {
    let _serial = serial();
    let set = tiny_set();
    let dir = tempfile::tempdir().unwrap();
    // 120 epochs of 9 steps, the rate decaying on a cosine to a tenth. Measured over seeds
    // 1–8, which stand in for the rounding differences between CPUs (they change the course of
    // training the same way), with the weights drawn when the network is built
    // (`rig_nn::init_params`): seeds 2–8 worst axis MAE 0.0072 N, median 0.0046 N; seed 1 stalls
    // on Fx at 0.178 N (a local minimum of this 4-wide network; Fy and Fz 0.007 and 0.005 N),
    // so the test trains with seed 2. (With weights drawn lazily at the first forward pass,
    // seeds 1–8 gave worst 0.024 N.) At a constant rate the last epochs jump about (worst
    // 0.054 N); with 3 draws per trajectory and 100 epochs training had not converged.
    let cfg = ForceConfig {
        lr_final: Some(3e-4),
        seed: 2,
        ..small_force(true, 120)
    };
    let r = force::train(
        &set,
        &cfg,
        "TransForce",
        dir.path(),
        false,
        Progress::Silent,
    )
    .unwrap();
    assert_eq!(r.epochs_done, 120);
    let model = ForceModel::load(dir.path()).unwrap();
    let (pred, truth) = predict_all(&model, &set);
    assert_eq!(pred.len(), 48, "every frame scored once");
    let e = mae(&pred, &truth);
    // Forces span 1.6 N in x/y and 1 N in z; "near zero" here is below 5 % of that span, far
    // under the 0.3–0.5 N a constant (mean) predictor scores on this data.
    for (a, v) in e.iter().enumerate() {
        assert!(*v < 0.05, "axis {a}: MAE {v:.4} N (all {e:?})");
    }
    // Loaded twice: bit-identical predictions.
    let again = ForceModel::load(dir.path()).unwrap();
    assert_eq!(predict_all(&again, &set).0, pred);
}

#[test]
fn no_lstm_and_source_only_run_through_the_same_code_path() {
    let _serial = serial();
    let set = tiny_set();
    for (lstm, method) in [(false, "TransForce (no LSTM)"), (true, "source-only")] {
        let dir = tempfile::tempdir().unwrap();
        force::train(
            &set,
            &small_force(lstm, 2),
            method,
            dir.path(),
            false,
            Progress::Silent,
        )
        .unwrap();
        let model = ForceModel::load(dir.path()).unwrap();
        assert_eq!(model.info.shape.lstm, lstm);
        assert_eq!(model.info.method, method);
        let (pred, _) = predict_all(&model, &set);
        assert_eq!(pred.len(), 48);
        assert!(pred.iter().flatten().all(|v| v.is_finite()));
    }
}

#[test]
fn without_an_lstm_each_frame_is_predicted_alone() {
    let _serial = serial();
    // The no-LSTM control sees one frame at a time: the same frame in two different sequences
    // gets the same force; with the LSTM its context changes the prediction.
    let set = tiny_set();
    for lstm in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        force::train(
            &set,
            &small_force(lstm, 1),
            "x",
            dir.path(),
            false,
            Progress::Silent,
        )
        .unwrap();
        let m = ForceModel::load(dir.path()).unwrap();
        let a = rig::train::batch::Sequence {
            traj: 0,
            frames: vec![0, 1, 2, 6],
        };
        let b = rig::train::batch::Sequence {
            traj: 0,
            frames: vec![3, 4, 5, 6],
        };
        let p = m.predict(&set.trajectories, &[a, b], 2);
        if lstm {
            assert_ne!(p[0][3], p[1][3]);
        } else {
            assert_eq!(p[0][3], p[1][3]);
        }
    }
}

#[test]
fn seeds_make_training_repeatable_and_resume_continues_the_same_run() {
    let _serial = serial();
    let set = tiny_set();
    let run = |epochs: usize, seed: u64, dir: &std::path::Path, resume: bool| {
        let cfg = ForceConfig {
            seed,
            ..small_force(true, epochs)
        };
        force::train(&set, &cfg, "x", dir, resume, Progress::Silent).unwrap();
        predict_all(&ForceModel::load(dir).unwrap(), &set).0
    };
    let (a, b, c, d) = (
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
        tempfile::tempdir().unwrap(),
    );
    let straight = run(3, 5, a.path(), false);
    assert_eq!(
        run(3, 5, b.path(), false),
        straight,
        "same seed, same model"
    );
    assert_ne!(
        run(3, 6, c.path(), false),
        straight,
        "another seed, another model"
    );
    // Two epochs, then resumed to three: the same weights as three epochs straight.
    run(2, 5, d.path(), false);
    assert_eq!(force::read_info(d.path()).unwrap().epochs_done, 2);
    assert_eq!(run(3, 5, d.path(), true), straight);
}

#[test]
fn a_non_finite_loss_stops_training_and_keeps_the_last_good_checkpoint() {
    let _serial = serial();
    let set = tiny_set();
    let dir = tempfile::tempdir().unwrap();
    force::train(
        &set,
        &small_force(true, 2),
        "x",
        dir.path(),
        false,
        Progress::Silent,
    )
    .unwrap();
    let good = predict_all(&ForceModel::load(dir.path()).unwrap(), &set).0;
    // An absurd learning rate blows the weights up within the next epoch.
    let cfg = ForceConfig {
        lr: 1e30,
        ..small_force(true, 6)
    };
    let err = force::train(&set, &cfg, "x", dir.path(), true, Progress::Silent)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("loss became") || err.contains("no longer finite"),
        "unexpected error: {err}"
    );
    assert!(err.contains("epoch 2"), "names the kept checkpoint: {err}");
    let info = force::read_info(dir.path()).unwrap();
    assert_eq!(info.epochs_done, 2);
    let kept = predict_all(&ForceModel::load(dir.path()).unwrap(), &set).0;
    assert_eq!(kept, good);
}

#[test]
fn the_image_pool_returns_as_many_images_as_it_gets() {
    let _serial = serial();
    let dev = burn::tensor::Device::flex();
    let mut pool = rig::train::cyclegan::ImagePool::new(3);
    let mut rng = Rng(1);
    for i in 0..10 {
        let x = Tensor::<4>::full([2, 3, 4, 4], i as f32, &dev);
        let y = pool.query(x, &mut rng);
        assert_eq!(y.dims(), [2, 3, 4, 4]);
        assert!(pool.len() <= 3);
    }
    assert_eq!(pool.len(), 3);
}

#[test]
fn recorded_datasets_load_through_the_cache_and_target_forces_stay_out_of_training() {
    use rig::record::synthetic::{SyntheticSpec, record_dataset};
    use rig::train::data::{load_eval, load_labelled, load_unlabelled};
    let dir = tempfile::tempdir().unwrap();
    let ids: Vec<String> = (0..3).map(|i| format!("t{i}")).collect();
    let spec_rec = SyntheticSpec {
        width: 32,
        height: 24,
        ..SyntheticSpec::default()
    };
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(record_dataset(dir.path(), &ids, &spec_rec))
        .unwrap();
    let spec = ImageSpec {
        width: 16,
        height: 12,
        modality: Modality::RgbMarker,
    };

    let set = load_labelled(dir.path(), &spec, false).unwrap();
    assert_eq!(set.trajectories.len(), 3);
    let frames = set.trajectories[0].frames;
    // 400 ms at 33 ms per frame: 12 or 13 frames, each with its paired force.
    assert!((11..=13).contains(&frames), "{frames} frames");
    assert_eq!(set.forces(0).len(), frames);
    assert!(set.forces(0).iter().flatten().all(|v| v.is_finite()));
    // The decode cache is written beside the files and gives back the same data.
    assert!(
        dir.path()
            .join(".trainer-cache")
            .read_dir()
            .unwrap()
            .count()
            >= 3
    );
    let again = load_labelled(dir.path(), &spec, false).unwrap();
    assert_eq!(again.trajectories, set.trajectories);
    assert_eq!(again.forces(2), set.forces(2));

    // The same files as a target-sensor dataset: images for translation, forces for evaluation,
    // and a refusal for training.
    let m = dir.path().join("manifest.json");
    let text = std::fs::read_to_string(&m)
        .unwrap()
        .replace("\"role\": \"source\"", "\"role\": \"target\"");
    std::fs::write(&m, text).unwrap();
    let err = load_labelled(dir.path(), &spec, false)
        .unwrap_err()
        .to_string();
    assert!(err.contains("evaluation only"), "{err}");
    assert_eq!(
        load_unlabelled(dir.path(), &spec, false)
            .unwrap()
            .trajectories,
        set.trajectories
    );
    assert_eq!(
        load_eval(dir.path(), &spec, false).unwrap().forces(1),
        set.forces(1)
    );
}

/// A D set of four trajectories sheared along +x only: each frame's displacement is uniform,
/// 0.2 mm per N of shear.
fn flow_set_sheared_along_plus_x() -> LabelledSet {
    let spec = ImageSpec {
        width: W,
        height: H,
        modality: Modality::Flow,
    };
    let cells = (W * H) as usize;
    four_presses(
        spec,
        |f| rig::train::data::flow_image(&vec![[0.2 * f[0], 0.2 * f[1]]; cells], &[]),
        |_, _, s| [0.8 * s, 0.0, -s],
    )
}

#[test]
fn mirrored_training_holds_both_signs_of_shear_in_its_range_and_leaves_fz_alone() {
    let _serial = serial();
    let set = flow_set_sheared_along_plus_x();
    let mut ranges = Vec::new();
    for mirror in [false, true] {
        let dir = tempfile::tempdir().unwrap();
        let cfg = ForceConfig {
            mirror,
            ..small_force(true, 1)
        };
        force::train(
            &set,
            &cfg,
            "marker flow",
            dir.path(),
            false,
            Progress::Silent,
        )
        .unwrap();
        let model = ForceModel::load(dir.path()).unwrap();
        let (pred, _) = predict_all(&model, &set);
        assert!(
            pred.iter().flatten().all(|v| v.is_finite()),
            "mirror {mirror}"
        );
        ranges.push(model.info.range);
    }
    let (plain, mirrored) = (&ranges[0], &ranges[1]);
    // Labels Fx ∈ [0, m]: the plain range is theirs with a 5 % margin of the span; mirrored
    // labels reach −m, so the mirrored range is symmetric, with 5 % of 2m beyond each end.
    let m = set.force_bounds()[0].1;
    let near = |a: f32, b: f32| (a - b).abs() < 1e-5;
    assert!(near(set.force_bounds()[0].0, 0.0));
    assert!(
        near(plain.lo[0], -0.05 * m) && near(plain.hi[0], 1.05 * m),
        "{plain:?}"
    );
    assert_eq!(mirrored.lo[0], -mirrored.hi[0], "{mirrored:?}");
    assert!(near(mirrored.hi[0], 1.1 * m), "{mirrored:?}");
    // Fy is zero everywhere, its own negation: ±0.5 N either way. Fz is never mirrored.
    assert_eq!((plain.lo[1], plain.hi[1]), (-0.5, 0.5));
    assert_eq!((mirrored.lo[1], mirrored.hi[1]), (-0.5, 0.5));
    assert_eq!((plain.lo[2], plain.hi[2]), (mirrored.lo[2], mirrored.hi[2]));
}
