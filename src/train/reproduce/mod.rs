//! `rig reproduce`: the TransForce paper's experiment on the simulated rig, with the paper's
//! numbers beside ours.
//!
//! The protocol (Chen et al., TransForce; see the design references): the 18 indenters with
//! the paper's split (unseen: sphere_s, triangle, pacman, wave, torus, cone; seen: the other
//! 12; `paralines`, the paper's failure case of translation, is left out), a source and a
//! target sensor, every contact point and depth of the plan, the three modalities (R, M, R+M)
//! and the three methods (source-only with the LSTM, TransForce without the LSTM, TransForce),
//! each force model over several seeds.
//!
//! Phases, each resumable: a killed run continues where it stopped (recording with
//! `rig run --resume`'s logic, the translator once complete, each force model from its last
//! checkpoint; the evaluation and the report are recomputed, they take seconds).
//!
//! 1. **collect**: each indenter's plan on both sensors (`data/source/<indenter>`,
//!    `data/target/<indenter>`);
//! 2. **translate**: one CycleGAN on the seen indenters' source and target images; then the
//!    seen and the unseen source images through it (`translate/translated`,
//!    `translate/translated-unseen`). One translator serves every seed: the seeds vary the
//!    force models (initial weights and batch order), not the translation;
//! 3. **fid**: FID and KID (Inception-v3) of I_s–I_t, Î_t–I_t and I_s–Î_t, seen and unseen;
//! 4. **train**: methods × modalities × seeds force models, two at a time;
//! 5. **evaluate** on the target sensor, and **report**: `results/reproduce.md` (tables with
//!    the paper's numbers, verdicts per claim, wall time per phase), `results/rows.json`,
//!    `figures/samples-{seen,unseen}.png` (I_s | Î_t | I_t).
//!
//! Scales: `tiny` (the tests: 3 indenters, a few trajectories, tiny networks), `cpu` (the whole
//! split at a size 2 cores can run: 4 of the 12 directions, 160 × 120 frames at 10 fps,
//! 32 × 24 network input), `paper` (the full plan, 320 × 240 frames at 25 fps, ResNet-50: for
//! a GPU machine).

use std::collections::BTreeMap;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use rig_core::config::RigConfig;
use serde::{Deserialize, Serialize};

use super::cyclegan::{self, TranslateConfig};
use super::data::{self, ImageSpec, LabelledSet, PAPER_EXCLUDED, PAPER_UNSEEN, Split};
use super::demo::{collect_both, sized_camera, train_force};
use super::eval::{self, FidConfig};
use super::force::{ForceConfig, ForceModel};
use super::modality::Modality;
use super::nn::Depth;
use super::report::{FidRow, Row};

mod figures;
mod findings;
pub use findings::{Aggregate, Verdict, aggregate, markdown, verdicts};

/// How big a reproduction to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
pub enum Scale {
    /// Three indenters and a few trajectories, tiny networks: minutes (the tests).
    Tiny,
    /// The whole split at a size 2 CPU cores run in a little over two hours (133 min measured).
    Cpu,
    /// The paper's protocol: every trajectory, 320 × 240 frames, ResNet-50 (a GPU machine).
    Paper,
}

/// The methods, in the paper's order: (name, trained on translated images, LSTM).
const METHODS: [(&str, bool, bool); 3] = [
    ("source-only", false, true),
    ("TransForce (no LSTM)", true, false),
    ("TransForce", true, true),
];

/// The paper's reported results on its real sensors (seen group, LSTM): MAE Fx and Fy with
/// the marker modality, Fz with R+M (N), their work range (N: Fx, Fy ±6, Fz −16..0), the best
/// R² per axis, and FID before (I_s–I_t) and after (Î_t–I_t) translation, seen and unseen.
pub const PAPER_MAE_N: [f64; 3] = [0.695, 0.701, 1.112];
pub const PAPER_RANGE_N: [f64; 3] = [12.0, 12.0, 16.0];
pub const PAPER_R2: [f64; 3] = [0.69, 0.66, 0.79];
pub const PAPER_FID_BEFORE: [f64; 2] = [81.1, 87.9];
pub const PAPER_FID_AFTER: [f64; 2] = [18.3, 21.3];

/// The protocol at one scale.
#[derive(Debug, Clone)]
pub struct Protocol {
    pub scale: Scale,
    pub seen: Vec<String>,
    pub unseen: Vec<String>,
    pub contact_points_mm: Vec<[f64; 2]>,
    pub depths_mm: Vec<f64>,
    pub directions_deg: Vec<f64>,
    pub camera: (u32, u32),
    pub fps: f64,
    pub spec: (u32, u32),
    pub modalities: Vec<Modality>,
    pub seeds: Vec<u64>,
    pub translate: TranslateConfig,
    pub force: ForceConfig,
    pub fid: FidConfig,
}

impl Protocol {
    pub fn new(scale: Scale) -> Self {
        // The built-in set is the paper's 18 and `paralines`.
        let paper_seen: Vec<String> = rig_core::indenter::Indenter::list_builtin()
            .iter()
            .filter(|i| !PAPER_UNSEEN.contains(i) && !PAPER_EXCLUDED.contains(i))
            .map(|s| s.to_string())
            .collect();
        let paper_unseen: Vec<String> = PAPER_UNSEEN.iter().map(|s| s.to_string()).collect();
        let all_points = vec![
            [0.0, 0.0],
            [-3.0, -2.0],
            [3.0, -2.0],
            [-3.0, 2.0],
            [3.0, 2.0],
        ];
        // The quick demo's small networks and training settings; each scale sets its own
        // length of training.
        let quick = super::demo::DemoPlan::new(true);
        let (small_gan, small_force) = (quick.translate, quick.force);
        match scale {
            Scale::Tiny => Self {
                scale,
                seen: vec!["sphere".into(), "hemisphere".into()],
                unseen: vec!["cone".into()],
                contact_points_mm: vec![[0.0, 0.0]],
                depths_mm: vec![0.8],
                directions_deg: vec![0.0, 90.0],
                camera: (160, 120),
                fps: 10.0,
                spec: (32, 24),
                modalities: Modality::ALL.to_vec(),
                seeds: vec![1],
                translate: TranslateConfig {
                    epochs: 1,
                    steps_per_epoch: Some(20),
                    ..small_gan
                },
                force: ForceConfig {
                    epochs: 2,
                    ..small_force
                },
                fid: FidConfig {
                    max_images: 16,
                    ..FidConfig::default()
                },
            },
            Scale::Cpu => Self {
                scale,
                seen: paper_seen,
                unseen: paper_unseen,
                contact_points_mm: all_points,
                depths_mm: vec![0.2, 0.4, 0.6, 0.8],
                // Four of the twelve: both shear axes, both ways.
                directions_deg: vec![0.0, 90.0, 180.0, 270.0],
                camera: (160, 120),
                fps: 10.0,
                spec: (32, 24),
                modalities: Modality::ALL.to_vec(),
                seeds: vec![1, 2, 3],
                translate: TranslateConfig {
                    epochs: 6,
                    steps_per_epoch: Some(250),
                    ..small_gan
                },
                // 480 Adam steps of 16 sequences (960 training trajectories, 4 sequences
                // each, 2 epochs): 27 models of ResNet-18 width 8 train at about 55 sequences/s
                // on 2 cores (two at a time; 41/s one alone, `rig bench train --speed --width 8
                // --batch 16`), so this is an hour of the two. The quick demo's models learn
                // normal force in 360 steps; they learnt shear on their own sensor in 720.
                force: ForceConfig {
                    epochs: 2,
                    ..small_force
                },
                fid: FidConfig {
                    max_images: 256,
                    ..FidConfig::default()
                },
            },
            Scale::Paper => Self {
                scale,
                seen: paper_seen,
                unseen: paper_unseen,
                contact_points_mm: all_points,
                depths_mm: vec![0.2, 0.4, 0.6, 0.8],
                directions_deg: (0..12).map(|k| k as f64 * 30.0).collect(),
                camera: (320, 240),
                fps: 25.0,
                spec: (128, 96),
                modalities: Modality::ALL.to_vec(),
                seeds: vec![1, 2, 3],
                // The paper's: 30 epochs at 2e-4 (its defaults).
                translate: TranslateConfig {
                    epochs: 30,
                    steps_per_epoch: Some(1000),
                    ..TranslateConfig::default()
                },
                force: ForceConfig {
                    depth: Depth::R50,
                    width: 64,
                    epochs: 20,
                    ..ForceConfig::default()
                },
                fid: FidConfig::default(),
            },
        }
    }

    /// The split: the protocol's unseen group, `paralines` excluded.
    pub fn split(&self) -> Split {
        Split {
            unseen: self.unseen.clone(),
            ..Split::default()
        }
    }

    /// A sensor's rig config at this protocol's plan and camera.
    pub fn rig_config(&self, base: RigConfig) -> RigConfig {
        let mut c = sized_camera(base, self.camera, self.fps);
        c.plan.contact_points_mm = self.contact_points_mm.clone();
        c.plan.depths_mm = self.depths_mm.clone();
        c.plan.directions_deg = self.directions_deg.clone();
        c
    }

    fn trajectories_per_sensor(&self) -> usize {
        self.contact_points_mm.len() * self.depths_mm.len() * self.directions_deg.len()
    }
}

/// Wall time per phase, s, kept in `<out>/phases.json` across resumed runs (a phase done by an
/// earlier run keeps that run's time).
#[derive(Debug, Default, Serialize, Deserialize)]
struct Phases(BTreeMap<String, f64>);

impl Phases {
    fn load(out: &Path) -> Self {
        std::fs::read(out.join("phases.json"))
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
            .unwrap_or_default()
    }
    fn done(&mut self, out: &Path, phase: &str, t0: Instant, did_work: bool) -> anyhow::Result<()> {
        let s = t0.elapsed().as_secs_f64();
        if did_work || !self.0.contains_key(phase) {
            self.0.insert(phase.to_owned(), s);
        }
        crate::durable::write_atomic(&out.join("phases.json"), &serde_json::to_vec_pretty(self)?)?;
        eprintln!("      {phase}: {s:.0} s");
        Ok(())
    }
}

/// Everything `rig reproduce` found.
#[derive(Debug, Serialize)]
pub struct Reproduction {
    pub scale: Scale,
    pub rows: Vec<Row>,
    pub aggregate: Vec<Aggregate>,
    pub fid: Vec<FidRow>,
    pub fid_notes: Vec<String>,
    /// The target labels' range per axis, N (max − min over every frame).
    pub range_n: [f64; 3],
    pub verdicts: Vec<Verdict>,
    pub phases_s: BTreeMap<String, f64>,
}

/// Runs (or resumes) the protocol into `out`. See the module docs.
pub fn run(
    protocol: &Protocol,
    out: &Path,
    inception: Option<&Path>,
    target: Option<&RigConfig>,
) -> anyhow::Result<Reproduction> {
    let progress = std::io::stderr().is_terminal();
    std::fs::create_dir_all(out)?;
    let net = eval::load_inception(inception, protocol.fid.batch)?;
    let mut phases = Phases::load(out);
    let split = protocol.split();
    let source_cfg = protocol.rig_config(RigConfig::sim_source());
    let target_cfg = protocol.rig_config(target.cloned().unwrap_or_else(RigConfig::sim_target));
    let (src_dir, tgt_dir) = (out.join("data/source"), out.join("data/target"));
    let indenters: Vec<&String> = protocol.seen.iter().chain(&protocol.unseen).collect();

    // 1. Collect.
    let t = Instant::now();
    eprintln!(
        "[1/5] collecting: {} indenters × {} trajectories × 2 sensors",
        indenters.len(),
        protocol.trajectories_per_sensor()
    );
    let recorded = collect_both(
        [(&source_cfg, &src_dir), (&target_cfg, &tgt_dir)],
        &indenters,
        progress,
    )?;
    phases.done(out, "collect", t, recorded)?;

    // 2. Translate (seen indenters), then the unseen source images through the translator.
    let t = Instant::now();
    let rgbm = ImageSpec {
        width: protocol.spec.0,
        height: protocol.spec.1,
        modality: Modality::RgbMarker,
    };
    let tdir = out.join("translate");
    let done = tdir.join("DONE");
    let source_all = data::load_labelled(&src_dir, &rgbm, progress)?;
    let (source_seen, source_unseen) = partition(source_all, &split);
    let target_images = data::load_unlabelled(&tgt_dir, &rgbm, progress)?;
    let translating = !done.is_file();
    if translating {
        eprintln!("[2/5] translating source → target style (CycleGAN, seen indenters)");
        let mut target_seen = target_images.clone();
        target_seen
            .trajectories
            .retain(|t| split.trains_on(&t.indenter));
        cyclegan::translate(
            &source_seen,
            &target_seen,
            &protocol.translate,
            &tdir,
            progress,
        )?;
        let unseen = cyclegan::apply_translator(&tdir.join("translator"), &source_unseen)?;
        data::write_prepared(&tdir.join("translated-unseen"), &unseen, "translated")?;
        std::fs::write(&done, b"")?;
    } else {
        eprintln!("[2/5] translation: done earlier");
    }
    phases.done(out, "translate", t, translating)?;
    let translated_seen = data::load_labelled(&tdir.join("translated"), &rgbm, false)?;
    let translated_unseen = data::load_labelled(&tdir.join("translated-unseen"), &rgbm, false)?;
    std::fs::create_dir_all(out.join("figures"))?;
    for (name, s, tr) in [
        ("seen", &source_seen, &translated_seen),
        ("unseen", &source_unseen, &translated_unseen),
    ] {
        sample_grid(s, tr, &target_images, 4)?
            .save(out.join(format!("figures/samples-{name}.png")))?;
    }

    // 3. FID and KID.
    let t = Instant::now();
    eprintln!("[3/5] FID and KID (Inception-v3)");
    let fid_file = out.join("results/fid.json");
    let (fid, fid_notes, fid_work) = match std::fs::read(&fid_file)
        .ok()
        .and_then(|b| serde_json::from_slice::<(Vec<FidRow>, Vec<String>)>(&b).ok())
    {
        Some((rows, notes)) if net.is_err() || rows.iter().all(|r| r.fid.is_some()) => {
            (rows, notes, false)
        }
        _ => {
            let source_images = images_of(&source_seen, &source_unseen);
            let translated_images = images_of(&translated_seen, &translated_unseen);
            let rows = eval::translation_fid(
                [&source_images, &target_images, &translated_images],
                &split,
                &protocol.fid,
                net.as_ref().ok(),
                progress,
            )?;
            let notes = eval::fid_notes(&net, &rows, &protocol.fid);
            std::fs::create_dir_all(out.join("results"))?;
            crate::durable::write_atomic(&fid_file, &serde_json::to_vec_pretty(&(&rows, &notes))?)?;
            (rows, notes, true)
        }
    };
    phases.done(out, "fid", t, fid_work)?;

    // 4. Train: methods × modalities × seeds, two at a time.
    let t = Instant::now();
    let mut jobs: Vec<(String, Modality, u64, PathBuf, bool, bool)> = Vec::new();
    for &seed in &protocol.seeds {
        for &m in &protocol.modalities {
            for (name, translated, lstm) in METHODS {
                let dir = out.join(format!(
                    "models/{}-{}-s{seed}",
                    eval::slug(name),
                    eval::slug(m.name())
                ));
                jobs.push((name.to_owned(), m, seed, dir, translated, lstm));
            }
        }
    }
    eprintln!(
        "[4/5] training {} force models ({} methods × {} modalities × {} seeds)",
        jobs.len(),
        METHODS.len(),
        protocol.modalities.len(),
        protocol.seeds.len()
    );
    let trained = std::sync::atomic::AtomicBool::new(false);
    let next = std::sync::atomic::AtomicUsize::new(0);
    let train_one = |(name, m, seed, dir, translated, lstm): &(
        String,
        Modality,
        u64,
        PathBuf,
        bool,
        bool,
    )|
     -> anyhow::Result<()> {
        if dir.join("DONE").is_file() {
            return Ok(());
        }
        let spec = ImageSpec {
            modality: *m,
            ..rgbm
        };
        let set = if *translated {
            data::load_labelled(&tdir.join("translated"), &spec, false)?
        } else {
            data::load_labelled(&src_dir, &spec, false)?
        }
        .seen_only(&split);
        let cfg = ForceConfig {
            lstm: *lstm,
            seed: *seed,
            ..protocol.force.clone()
        };
        train_force(&set, &cfg, name, *m, dir)?;
        std::fs::write(dir.join("DONE"), b"")?;
        trained.store(true, std::sync::atomic::Ordering::Relaxed);
        Ok(())
    };
    std::thread::scope(|s| -> anyhow::Result<()> {
        let worker = || -> anyhow::Result<()> {
            loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(job) = jobs.get(i) else {
                    return Ok(());
                };
                train_one(job).with_context(|| format!("training {}", job.3.display()))?;
            }
        };
        let other = s.spawn(worker);
        worker()?;
        other
            .join()
            .map_err(|_| anyhow::anyhow!("a training thread panicked"))?
    })?;
    phases.done(
        out,
        "train",
        t,
        trained.load(std::sync::atomic::Ordering::Relaxed),
    )?;

    // 5. Evaluate on the target sensor, and report.
    let t = Instant::now();
    eprintln!("[5/5] evaluating on the target sensor");
    let mut rows = Vec::new();
    let mut predictions = Vec::new();
    let mut ids: Vec<(String, String)> = Vec::new();
    // The target set is read once per modality, not once per model.
    for &m in &protocol.modalities {
        let spec = ImageSpec {
            modality: m,
            ..rgbm
        };
        let set = data::load_eval(&tgt_dir, &spec, progress)?;
        if ids.is_empty() {
            ids = set
                .trajectories
                .iter()
                .map(|t| (t.indenter.clone(), t.id.clone()))
                .collect();
        }
        for (method, _, seed, dir, _, _) in jobs.iter().filter(|j| j.1 == m) {
            let name = dir.file_name().map(|n| n.to_string_lossy().into_owned());
            let plots = out.join("results/models").join(name.unwrap_or_default());
            let model = ForceModel::load(dir)
                .with_context(|| format!("loading the model in {}", dir.display()))?;
            anyhow::ensure!(
                model.spec() == spec,
                "{} was trained on other images ({:?}) than this protocol's ({spec:?}); \
                 use a fresh --out",
                dir.display(),
                model.spec()
            );
            let (model_rows, p) = eval::evaluate_on(&model, &set, &tgt_dir, &plots, &split)?;
            for mut r in model_rows {
                r.method = format!("{}#{seed}", r.method);
                rows.push(r);
            }
            predictions.push(figures::ModelPredictions {
                method: method.clone(),
                modality: m.paper_name().to_owned(),
                seed: *seed,
                p,
            });
        }
    }
    let seedless: Vec<Row> = rows
        .iter()
        .map(|r| Row {
            method: r.method.split('#').next().unwrap_or_default().to_owned(),
            ..r.clone()
        })
        .collect();
    let agg = aggregate(&seedless);
    let shown = figures::figure_modalities(&agg, Modality::RgbMarker.paper_name());
    figures::error_violins(
        &out.join("figures/error-by-force-range.png"),
        &predictions,
        &shown,
        &split,
    )?;
    figures::force_over_time(
        &out.join("figures/force-over-time.png"),
        &predictions,
        &shown,
        &ids,
        &figures::pick_trajectories(&ids, &split, 2),
        protocol.fps,
    )?;
    drop(predictions);
    let target_eval = data::load_eval(&tgt_dir, &rgbm, false)?;
    let mut bounds = [(f32::INFINITY, f32::NEG_INFINITY); 3];
    for i in 0..target_eval.trajectories.len() {
        for f in target_eval.forces(i) {
            for a in 0..3 {
                bounds[a] = (bounds[a].0.min(f[a]), bounds[a].1.max(f[a]));
            }
        }
    }
    let range_n: [f64; 3] = std::array::from_fn(|a| (bounds[a].1 - bounds[a].0) as f64);
    let verdicts = verdicts(&agg, range_n, &fid);
    phases.done(out, "evaluate", t, true)?;
    let result = Reproduction {
        scale: protocol.scale,
        rows,
        aggregate: agg,
        fid,
        fid_notes,
        range_n,
        verdicts,
        phases_s: phases.0.clone(),
    };
    let results = out.join("results");
    std::fs::create_dir_all(&results)?;
    crate::durable::write_atomic(
        &results.join("rows.json"),
        &serde_json::to_vec_pretty(&result)?,
    )?;
    crate::durable::write_atomic(&results.join("reproduce.md"), markdown(&result).as_bytes())?;
    Ok(result)
}

/// The seen and the unseen (and not excluded) trajectories of a labelled set.
fn partition(set: LabelledSet, split: &Split) -> (LabelledSet, LabelledSet) {
    let unseen = set
        .clone()
        .filtered(|t| split.group(&t.indenter) == "unseen");
    (set.seen_only(split), unseen)
}

/// The images of two labelled sets of the same spec, as one set.
fn images_of(a: &LabelledSet, b: &LabelledSet) -> data::UnlabelledSet {
    let mut m = a.images();
    m.trajectories.extend(b.images().trajectories);
    m
}

/// Rows of I_s | Î_t | I_t: the middle frame of `rows` trajectories spread over `source` (and
/// its translation, frame for frame), beside the same trajectory's middle frame on the target;
/// enlarged (nearest pixel) to at least 480 pixels across.
fn sample_grid(
    source: &LabelledSet,
    translated: &LabelledSet,
    target: &data::UnlabelledSet,
    rows: usize,
) -> anyhow::Result<image::RgbImage> {
    let spec = source.spec;
    let (w, h) = (spec.width, spec.height);
    let n = source.trajectories.len().min(translated.trajectories.len());
    anyhow::ensure!(n > 0, "no trajectories to show");
    let mut grid = image::RgbImage::new(w * 3, h * rows as u32);
    for r in 0..rows {
        let k = (r * n) / rows;
        let (s, tr) = (&source.trajectories[k], &translated.trajectories[k]);
        let tg = target
            .trajectories
            .iter()
            .find(|t| t.id == s.id && t.indenter == s.indenter);
        let mid = s.frames / 2;
        let mut cols: Vec<&[u8]> =
            vec![s.frame(mid, &spec), tr.frame(mid.min(tr.frames - 1), &spec)];
        if let Some(t) = tg {
            cols.push(t.frame((t.frames / 2).min(t.frames - 1), &spec));
        }
        for (c, px) in cols.into_iter().enumerate() {
            cyclegan::paste_frame(&mut grid, px, (w, h), c, r)?;
        }
    }
    // Pixels a person can see: at least 480 wide, whole pixels enlarged.
    let k = (480 / (3 * w)).max(1);
    Ok(image::imageops::resize(
        &grid,
        grid.width() * k,
        grid.height() * k,
        image::imageops::FilterType::Nearest,
    ))
}
