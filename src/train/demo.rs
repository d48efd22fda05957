//! `rig demo [--quick]`: the whole TransForce story on the simulated rig, at a small scale.
//!
//! 1. Collect a source dataset (images + forces) and a target dataset (a second simulated sensor
//!    with other LEDs and markers) for a few seen and unseen indenters.
//! 2. Translate the source images into the target's style (CycleGAN).
//! 3. Train the force model on the translated sequences with the source forces (TransForce), its
//!    no-LSTM control, and the source-only baseline (trained on the raw source images). Two
//!    train at a time: source-only beside the translator, TransForce beside its control.
//! 4. Evaluate all of them on the target sensor and print the paper-shaped table.
//!
//! Re-running with the same `--out` reuses the recorded data (`rig run --resume`) and retrains.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use anyhow::Context;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use super::Progress;
use super::cyclegan::TranslateConfig;
use super::data::{self, ImageSpec, Split};
use super::eval::{self, FidConfig};
use super::force::{self, ForceConfig};
use super::modality::Modality;
use super::report::{Row, Table};
use rig_nn::{Depth, GanShape};

/// The demo's scale.
#[derive(Debug, Clone)]
pub struct DemoPlan {
    pub seen: Vec<&'static str>,
    pub unseen: Vec<&'static str>,
    pub directions_deg: Vec<f64>,
    /// How far each trajectory slides at depth, mm (the rig configs' 2 mm: gross slip at the
    /// end of the slide for most indenters).
    pub shear_distance_mm: f64,
    pub camera: (u32, u32),
    pub fps: f64,
    pub spec: (u32, u32),
    pub modalities: Vec<Modality>,
    pub translate: TranslateConfig,
    pub force: ForceConfig,
    /// FID/KID: how many images of each set and group go through Inception.
    pub fid: FidConfig,
}

impl DemoPlan {
    pub fn new(quick: bool) -> Self {
        if quick {
            Self {
                seen: vec!["sphere", "hemisphere", "prism"],
                // Two of the paper's six unseen indenters, as in the full demo: the cone alone
                // (|Fz| under 0.47 N) leaves the unseen R² Fz at the mercy of a small offset.
                unseen: vec!["cone", "sphere_s"],
                directions_deg: vec![0.0, 90.0, 180.0, 270.0],
                shear_distance_mm: 2.0,
                camera: (160, 120),
                fps: 10.0,
                spec: (32, 24),
                // R+M, the image as captured (the paper's main modality), which carries normal
                // force across better than R. No image modality carries shear to sim-target
                // here: the small translator cannot redraw the source's marker lattice at the
                // target's pitch (marker flow does carry it). The full demo and `rig reproduce`
                // run all three. Evidence: docs/experiments.md, *The quick demo's settings*.
                modalities: vec![Modality::RgbMarker],
                translate: TranslateConfig {
                    shape: GanShape {
                        ngf: 8,
                        ndf: 8,
                        res_blocks: 2,
                        disc_layers: 2,
                        // One downsampling, not the reference's two: at 32 × 24 two leave an
                        // 8 × 6 map, coarser than the markers' 3 px pitch (see `GanShape::down`),
                        // at the same cost. It gave the best Fz and FID of 0, 1 and 2
                        // (docs/experiments.md, *The quick demo's settings*).
                        down: 1,
                    },
                    // Five times the paper's rate: these tiny networks get a few hundred
                    // iterations, not 30 epochs.
                    lr: 1e-3,
                    batch: 4,
                    // 2400 iterations: at 600 the translated contact patches were still
                    // smeared, and at 1200 the unseen Fz varied widely from run to run (same
                    // section of docs/experiments.md).
                    epochs: 12,
                    steps_per_epoch: Some(200),
                    ..TranslateConfig::default()
                },
                // 30 epochs, about 360 Adam steps, settled by a cosine decay: what CI asserts
                // (normal force, |F|, marker flow's shear) is learnt by then; 60 epochs cost
                // half as much time again for little (same section of docs/experiments.md).
                // The full demo and `rig reproduce` train longer.
                force: ForceConfig {
                    depth: Depth::R18,
                    width: 8,
                    epochs: 30,
                    batch: 16,
                    lr: 2e-3,
                    lr_final: Some(2e-4),
                    ..ForceConfig::default()
                },
                // 64 images of each set and group: 5 samples (I_s and I_t seen and unseen, Î_t
                // seen), 320 Inception passes, about 1.5 minutes on 2 cores. KID uses subsets of
                // 64 (the reference 1000 needs more images than the quick demo has time for).
                fid: FidConfig {
                    max_images: 64,
                    ..FidConfig::default()
                },
            }
        } else {
            Self {
                seen: vec!["sphere", "hemisphere", "prism", "dots", "line", "random"],
                unseen: vec!["cone", "sphere_s"],
                directions_deg: (0..12).map(|k| k as f64 * 30.0).collect(),
                shear_distance_mm: 2.0,
                camera: (320, 240),
                fps: 25.0,
                spec: (64, 48),
                modalities: Modality::ALL.to_vec(),
                translate: TranslateConfig {
                    epochs: 5,
                    steps_per_epoch: Some(1000),
                    batch: 2,
                    ..TranslateConfig::default()
                },
                force: ForceConfig {
                    epochs: 20,
                    ..ForceConfig::default()
                },
                fid: FidConfig::default(),
            }
        }
    }
}

/// The simulated rig of one sensor at the demo's scale: the centre contact point, all depths,
/// the demo's shear directions and distance, the demo's camera size.
pub fn demo_config(base: RigConfig, plan: &DemoPlan) -> RigConfig {
    let mut c = sized_camera(base, plan.camera, plan.fps);
    c.plan.contact_points_mm = vec![[0.0, 0.0]];
    c.plan.directions_deg = plan.directions_deg.clone();
    c.plan.shear_distance_mm = plan.shear_distance_mm;
    c
}

/// A simulated sensor's config with its camera at `(w, h)` pixels and `fps`, seeing the same
/// field of view (the optics' mm per pixel scaled with it).
pub(super) fn sized_camera(base: RigConfig, (w, h): (u32, u32), fps: f64) -> RigConfig {
    let mut c = base;
    if let Some(cam) = c.camera.as_mut() {
        let scale = cam.width_px as f64 / w as f64;
        cam.width_px = w;
        cam.height_px = h;
        cam.fps = fps;
        if let Some(o) = c.optics.as_mut() {
            o.width_px = w;
            o.height_px = h;
            o.mm_per_px *= scale;
        }
    }
    c
}

/// Records `indenter`'s plan on `config` into `out`, or resumes it there; `false` when `out`
/// already held a complete recording.
pub(super) fn collect(
    config: &RigConfig,
    indenter: &str,
    out: &Path,
    progress: bool,
) -> anyhow::Result<bool> {
    let ind = Indenter::load(indenter)?;
    let resume = out.join("manifest.json").is_file();
    if resume && crate::dataset::check(out).ok() {
        return Ok(false);
    }
    let opts = crate::run::RunOptions {
        resume,
        progress,
        ..crate::run::RunOptions::new(out)
    };
    let rt = tokio::runtime::Runtime::new()?;
    let summary = rt
        .block_on(crate::run::run(config, &ind, &opts))
        .with_context(|| format!("collecting {indenter} on {}", config.sensor.id))?;
    let report = crate::dataset::check(out);
    if !report.ok() {
        anyhow::bail!(
            "the {indenter} dataset of {} is not complete:\n{}{}",
            config.sensor.id,
            summary.report(),
            crate::dataset::render(&report)
        );
    }
    Ok(true)
}

/// Records every indenter's plan on each sensor, `workers` recordings at a time: a simulated
/// rig runs on its clock (×10), not flat out, so one keeps about half a core busy (measured)
/// and leaves the rest of two cores idle. The jobs are (indenter, sensor) pairs, both sensors
/// of an indenter next to each other; only the first worker shows a progress bar (two bars
/// would overwrite each other), and every finished recording is announced on one line. `true`
/// when anything was recorded. When one recording fails, the other workers stop after their
/// current one (what they recorded is kept, and a rerun resumes it).
///
/// Before anything is recorded, the disk budget of every recording still to do is summed and
/// refused when the disk cannot hold it ([`crate::run::budget::check_collection`]; `command`
/// names the command in the message, `smaller` says how to ask it for less).
pub(super) fn collect_parallel<S: AsRef<str> + Sync>(
    sensors: &[(&RigConfig, &Path)],
    indenters: &[S],
    workers: usize,
    progress: bool,
    (command, smaller): (&str, Option<&str>),
) -> anyhow::Result<bool> {
    use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
    let jobs: Vec<(&RigConfig, &Path, &str)> = indenters
        .iter()
        .flat_map(|i| sensors.iter().map(move |(c, d)| (*c, *d, i.as_ref())))
        .collect();
    let runs: Vec<(&RigConfig, PathBuf, &str)> =
        jobs.iter().map(|&(c, d, i)| (c, d.join(i), i)).collect();
    crate::run::budget::check_collection(&runs, command, smaller)?;
    let (failed, next, finished) = (
        AtomicBool::new(false),
        AtomicUsize::new(0),
        AtomicUsize::new(0),
    );
    let (failed, next, finished, jobs) = (&failed, &next, &finished, &jobs);
    let worker = move |bar: bool| -> anyhow::Result<bool> {
        let mut recorded = false;
        while !failed.load(Ordering::Relaxed) {
            let Some(&(cfg, dir, ind)) = jobs.get(next.fetch_add(1, Ordering::Relaxed)) else {
                break;
            };
            match collect(cfg, ind, &dir.join(ind), bar) {
                Ok(r) => {
                    recorded |= r;
                    let k = finished.fetch_add(1, Ordering::Relaxed) + 1;
                    if r {
                        eprintln!(
                            "      {ind} on {}: recorded ({k}/{})",
                            cfg.sensor.id,
                            jobs.len()
                        );
                    }
                }
                Err(e) => {
                    failed.store(true, Ordering::Relaxed);
                    return Err(e);
                }
            }
        }
        Ok(recorded)
    };
    std::thread::scope(|s| {
        let others: Vec<_> = (1..workers.max(1))
            .map(|_| s.spawn(move || worker(false)))
            .collect();
        let mut result = worker(progress);
        for o in others {
            let r = o
                .join()
                .map_err(|_| anyhow::anyhow!("a collecting thread panicked"))
                .and_then(|r| r);
            result = match (result, r) {
                (Ok(a), Ok(b)) => Ok(a | b),
                (Err(e), _) | (_, Err(e)) => Err(e),
            };
        }
        result
    })
}

/// How many recordings run at once: a simulated rig at ×10 keeps about half a core busy
/// (measured at 160 × 120 and 10 fps), so two per core fill the machine; its clock governor
/// slows a rig whose camera cannot follow, so a busier machine costs time, not frames. At most
/// 8 (each rig is a UR5e, a Nano17 and a camera on loopback).
pub(super) fn collect_workers() -> usize {
    let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
    (2 * cores).clamp(2, 8)
}

/// Run the demo; returns the table (also written to `<out>/results.*`). `inception` names the
/// Inception weights for FID/KID (default: [`super::inception::weights_path`]); without them at
/// the default location the table says so and leaves FID/KID empty. `target` replaces the
/// built-in simulated target sensor (its plan is set to the demo's like the built-in one's).
/// `match_marker_pitch` sets [`TranslateConfig::match_marker_pitch`].
pub fn run(
    quick: bool,
    out: &Path,
    inception: Option<&Path>,
    target: Option<&RigConfig>,
    match_marker_pitch: bool,
) -> anyhow::Result<Table> {
    let progress = std::io::stderr().is_terminal();
    let mut plan = DemoPlan::new(quick);
    plan.translate.match_marker_pitch = match_marker_pitch;
    // Before an hour of work: a damaged or missing explicitly named weights file stops here.
    let net = eval::load_inception(inception, plan.fid.batch, false)?;
    let t0 = std::time::Instant::now();
    let split = Split {
        unseen: plan.unseen.iter().map(|s| s.to_string()).collect(),
        ..Split::default()
    };
    let source_cfg = demo_config(RigConfig::sim_source(), &plan);
    let target_cfg = demo_config(target.cloned().unwrap_or_else(RigConfig::sim_target), &plan);
    let (src_dir, tgt_dir) = (out.join("data/source"), out.join("data/target"));
    let indenters: Vec<&str> = plan.seen.iter().chain(&plan.unseen).copied().collect();
    eprintln!(
        "[1/4] collecting on the simulated rig: {} indenters × {} trajectories × 2 sensors",
        indenters.len(),
        4 * plan.directions_deg.len()
    );
    collect_parallel(
        &[(&source_cfg, &src_dir), (&target_cfg, &tgt_dir)],
        &indenters,
        // The two sensors side by side, about a core: the quick demo runs in CI beside
        // timing-sensitive protocol tests, which a full machine starves (ur_rtde's 500 Hz
        // stream check failed with four recordings at a time).
        2,
        progress,
        (
            "rig demo",
            (!quick).then_some("run the smaller `rig demo --quick`"),
        ),
    )?;
    eprintln!("      done in {:.0} s", t0.elapsed().as_secs_f64());

    let rgbm = ImageSpec {
        width: plan.spec.0,
        height: plan.spec.1,
        modality: Modality::RgbMarker,
    };
    let zoom = super::cyclegan::source_zoom(&plan.translate, &src_dir, &tgt_dir)?;
    let source = data::load_labelled_zoomed(&src_dir, &rgbm, zoom, progress)?.seen_only(&split);
    let target_images = data::load_unlabelled(&tgt_dir, &rgbm, progress)?;
    // The translator sees target images of the seen indenters only.
    let mut target_seen = target_images.clone();
    target_seen
        .trajectories
        .retain(|t| split.trains_on(&t.indenter));

    // Two trainings at a time, on the cores one leaves idle (a small network does not keep
    // two cores busy): the source-only baselines need no translation and train beside the
    // translator; TransForce trains beside its no-LSTM control. Each network's initial
    // weights still come from its seed alone (`rig_nn::build_networks`).
    let mut table = Table::default();
    let models = std::thread::scope(|s| -> anyhow::Result<Vec<(String, PathBuf)>> {
        let baselines = s.spawn(|| -> anyhow::Result<Vec<(String, PathBuf)>> {
            let mut models = Vec::new();
            for &m in &plan.modalities {
                let spec = ImageSpec {
                    modality: m,
                    ..rgbm
                };
                let src = data::load_labelled(&src_dir, &spec, false)?.seen_only(&split);
                let dir = out.join(format!("models/source-only-{}", eval::slug(m.name())));
                train_force(&src, &plan.force, "source-only", m, &dir)?;
                models.push(("source-only".to_owned(), dir));
            }
            // The marker-displacement method: the source's own recordings and labels, no
            // translation (the displacement in mm does not depend on the sensor's look).
            let flow = ImageSpec {
                modality: Modality::Flow,
                ..rgbm
            };
            let src = data::load_labelled(&src_dir, &flow, false)?.seen_only(&split);
            let dir = out.join("models/marker-flow");
            train_force(&src, &plan.force, METHOD_MARKER_FLOW, Modality::Flow, &dir)?;
            models.push((METHOD_MARKER_FLOW.to_owned(), dir));
            Ok(models)
        });

        eprintln!(
            "[2/4] translating source → target style (CycleGAN), training source-only beside it"
        );
        let t1 = std::time::Instant::now();
        let translated = super::cyclegan::translate(
            &source,
            &target_seen,
            &plan.translate,
            &out.join("translate"),
            Progress::bar_or_lines(progress),
        )?;
        eprintln!(
            "      {} iterations in {:.0} s, cycle loss {:.3}",
            translated.info.iterations,
            t1.elapsed().as_secs_f64(),
            translated.info.last.cycle
        );
        let tf = std::time::Instant::now();
        let source_images = data::load_unlabelled(&src_dir, &rgbm, false)?;
        let translated_images = translated.set.images();
        table.fid = eval::translation_fid(
            [&source_images, &target_images, &translated_images],
            &split,
            &plan.fid,
            net.as_ref().ok(),
            progress,
        )?;
        table.fid_notes = eval::fid_notes(&net, &table.fid, &plan.fid);
        eprintln!(
            "      FID/KID on at most {} images per set and group in {:.0} s",
            plan.fid.max_images,
            tf.elapsed().as_secs_f64()
        );

        eprintln!("[3/4] training force models on the translated images");
        let translated_dir = out.join("translate/translated");
        let mut models = Vec::new();
        for &m in &plan.modalities {
            let spec = ImageSpec {
                modality: m,
                ..rgbm
            };
            let tr = data::load_labelled(&translated_dir, &spec, progress)?;
            let [with, without] =
                [(true, "TransForce"), (false, "TransForce (no LSTM)")].map(|(lstm, name)| {
                    let dir = out.join(format!(
                        "models/{}-{}",
                        eval::slug(name),
                        eval::slug(m.name())
                    ));
                    let cfg = ForceConfig {
                        lstm,
                        ..plan.force.clone()
                    };
                    (name, cfg, dir)
                });
            std::thread::scope(|pair| -> anyhow::Result<()> {
                let control = pair.spawn(|| train_force(&tr, &without.1, without.0, m, &without.2));
                train_force(&tr, &with.1, with.0, m, &with.2)?;
                control
                    .join()
                    .map_err(|_| anyhow::anyhow!("training {} panicked", without.0))?
            })?;
            models.push((with.0.to_owned(), with.2));
            models.push((without.0.to_owned(), without.2));
        }
        let baselines = baselines
            .join()
            .map_err(|_| anyhow::anyhow!("training source-only panicked"))??;
        models.extend(baselines);
        Ok(models)
    })?;

    if data::has_forces(&tgt_dir)? {
        eprintln!("[4/4] evaluating on the target sensor");
        for (_, dir) in &models {
            table.rows.extend(eval::evaluate(
                dir,
                &tgt_dir,
                &out.join("results"),
                &split,
                progress,
            )?);
        }
        let rgbm_eval = data::load_eval(&tgt_dir, &rgbm, false)?;
        table.range_n = Some(eval::force_range(&rgbm_eval));
    } else {
        // A target recorded without an F/T sensor served the translator; its frames carry no
        // forces to score the models against.
        eprintln!(
            "[4/4] not evaluated: the target sensor was recorded without an F/T sensor (no \
             [force_sensor]), and evaluating against forces needs a labelled target. The \
             translated images and the trained models are in {}",
            out.display()
        );
    }
    table.write(&out.join("results"))?;
    eprintln!("      total {:.0} s", t0.elapsed().as_secs_f64());
    Ok(table)
}

/// The marker-displacement method's name in result tables: a force model on
/// [`Modality::Flow`], trained on the source sensor's recordings without translation.
pub const METHOD_MARKER_FLOW: &str = "marker flow";

/// Trains one force model into `dir` and says how it went (no progress bar: trainings run side
/// by side).
pub(super) fn train_force(
    set: &data::LabelledSet,
    cfg: &ForceConfig,
    name: &str,
    m: Modality,
    dir: &Path,
) -> anyhow::Result<()> {
    let t = std::time::Instant::now();
    let r = force::train(set, cfg, name, dir, false, Progress::Silent)?;
    eprintln!(
        "      {name} {}: loss {:.4}, {:.0} s",
        m.paper_name(),
        r.last_loss,
        t.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Does TransForce (LSTM) beat source-only on MAE on every axis, per modality and group?
pub fn beats_source_only(rows: &[Row]) -> Vec<(String, String, [bool; 3])> {
    let mut out = Vec::new();
    for r in rows.iter().filter(|r| r.method == "TransForce") {
        if let Some(b) = rows
            .iter()
            .find(|b| b.method == "source-only" && b.modality == r.modality && b.group == r.group)
        {
            out.push((
                r.modality.clone(),
                r.group.clone(),
                std::array::from_fn(|a| r.mae[a] < b.mae[a]),
            ));
        }
    }
    out
}
