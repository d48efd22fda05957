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
//!    `data/target/<indenter>`), two recordings per core at a time (a simulated rig at ×10
//!    keeps about half a core busy);
//! 2. **translate**: one CycleGAN on the seen indenters' source and target images; then the
//!    seen and the unseen source images through it (`translate/translated`,
//!    `translate/translated-unseen`). One translator serves every seed: the seeds vary the
//!    force models (initial weights and batch order), not the translation;
//! 3. **fid**: FID and KID (Inception-v3) of I_s–I_t, Î_t–I_t and I_s–Î_t, seen and unseen;
//! 4. **train**: methods × modalities × seeds force models, two at a time. The source-only
//!    baselines need no translation: one of them trains beside phases 2 and 3 from their
//!    start, and the phases' wall times stay consecutive (phase 4's counts from the end of 3);
//! 5. **evaluate** on the target sensor (two models at a time), and **report**: `results/reproduce.md` (tables with
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
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::Instant;

use anyhow::Context;
use rig_core::config::RigConfig;
use serde::{Deserialize, Serialize};

use super::Progress;
use super::cyclegan;
use super::data::{self, ImageSpec, LabelledSet, Split};
use super::demo::{collect_parallel, collect_workers, train_force};
use super::eval;
use super::force::{ForceConfig, ForceModel};
use super::modality::Modality;
use super::report::{FidRow, Row};

mod figures;
mod findings;
mod methods;
mod protocol;
pub use findings::{Aggregate, Reproduction, Verdict, aggregate, markdown, verdicts};
pub use methods::{
    METHODS, Method, PAPER_FID_AFTER, PAPER_FID_BEFORE, PAPER_MAE_N, PAPER_R2, PAPER_RANGE_N,
};
pub use protocol::{Protocol, Scale};

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

/// Whether phase 3 computes FID and KID, and with which Inception weights.
#[derive(Debug, Clone, Copy)]
pub enum Fid<'a> {
    /// With the weights in this file (`None`: `$RIG_INCEPTION_WEIGHTS`, else the default file).
    /// Missing weights stop the run before it records anything, except at `--scale tiny`,
    /// which leaves FID and KID out with a note ([`eval::load_inception`]).
    Inception(Option<&'a Path>),
    /// Not at all (`--no-fid`): the FID table keeps only the colour-statistics distance.
    Skip,
}

/// Runs (or resumes) the protocol into `out`. See the module docs.
pub fn run(
    protocol: &Protocol,
    out: &Path,
    fid: Fid<'_>,
    target: Option<&RigConfig>,
) -> anyhow::Result<Reproduction> {
    let progress = std::io::stderr().is_terminal();
    // Before anything is recorded: a two-hour run should not find out at its third phase that
    // it cannot say what the translation did (only `tiny`, a smoke test, goes on without).
    let net = match fid {
        Fid::Inception(file) => {
            eval::load_inception(file, protocol.fid.batch, protocol.scale != Scale::Tiny)
                .map_err(|e| anyhow::anyhow!("{e}; or pass --no-fid to run without FID and KID"))?
        }
        Fid::Skip => Err("--no-fid was given".to_owned()),
    };
    std::fs::create_dir_all(out)?;
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
    let recorded = collect_parallel(
        &[(&source_cfg, &src_dir), (&target_cfg, &tgt_dir)],
        &indenters,
        match protocol.scale {
            // The test's scale, beside other tests: the two sensors side by side.
            Scale::Tiny => 2,
            Scale::Cpu | Scale::Paper => collect_workers(),
        },
        progress,
        (
            "rig reproduce",
            match protocol.scale {
                Scale::Paper => Some("choose a smaller --scale (cpu or tiny)"),
                Scale::Cpu => Some("choose the smaller --scale tiny"),
                Scale::Tiny => None,
            },
        ),
    )?;
    phases.done(out, "collect", t, recorded)?;

    // The force models: methods × modalities × seeds, the source-only baselines first. They
    // need no translation, so they train beside it (phases 2 and 3 keep one core of two busy
    // at most part of the time); the others wait for the translated images.
    let mut jobs: Vec<Job> = Vec::new();
    for method in METHODS {
        for &seed in &protocol.seeds {
            for &m in protocol.modalities_of(&method) {
                let dir = out.join(format!(
                    "models/{}-{}-s{seed}",
                    eval::slug(method.name),
                    eval::slug(m.name())
                ));
                jobs.push(Job {
                    method: method.name.to_owned(),
                    modality: m,
                    seed,
                    dir,
                    translated: method.translated,
                    lstm: method.lstm,
                    markers: method.markers,
                });
            }
        }
    }
    // The queue's order: those on the source's own recordings first (they train beside the
    // translation), the report's order within each.
    jobs.sort_by_key(|j| j.translated);
    let rgbm = ImageSpec {
        width: protocol.spec.0,
        height: protocol.spec.1,
        modality: Modality::RgbMarker,
    };
    let tdir = out.join("translate");
    let trainer = Trainer {
        protocol,
        jobs: &jobs,
        split: &split,
        rgbm,
        src_dir: &src_dir,
        translated_dir: tdir.join("translated"),
        next: AtomicUsize::new(0),
        gate: Default::default(),
        trained: AtomicBool::new(false),
        sets: Default::default(),
    };
    let (fid, fid_notes) = std::thread::scope(|s| -> anyhow::Result<_> {
        let early = s.spawn(|| trainer.work());
        let main = (|| -> anyhow::Result<_> {
            let r = translate_and_fid(protocol, out, &net, &mut phases, progress)?;
            trainer.gate.set(|g| g.translation_ready = true);
            // 4. Train the rest, two at a time (the early worker goes on beside this one).
            let t = Instant::now();
            eprintln!(
                "[4/5] training {} force models ({} methods × their modalities × {} seeds; \
                 those on the source's own recordings began during translation)",
                jobs.len(),
                METHODS.len(),
                protocol.seeds.len()
            );
            trainer.work()?;
            Ok((r, t))
        })();
        if main.is_err() {
            trainer.gate.set(|g| g.stop = true);
        }
        let early = early
            .join()
            .map_err(|_| anyhow::anyhow!("a training thread panicked"));
        let (r, t) = main?;
        early??;
        phases.done(out, "train", t, trainer.trained.load(Ordering::Relaxed))?;
        Ok(r)
    })?;
    // The training sets' memory, before the target's are read.
    drop(trainer);

    // 5. Evaluate on the target sensor, and report.
    let t = Instant::now();
    eprintln!("[5/5] evaluating on the target sensor");
    let mut rows = Vec::new();
    let mut predictions = Vec::new();
    let mut ids: Vec<(String, String)> = Vec::new();
    // The target set is read once per modality, not once per model.
    for &m in protocol
        .modalities
        .iter()
        .chain(&protocol.marker_modalities)
    {
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
        // Two models at a time: a prediction keeps two cores busy only part of the time,
        // and each model's plot is drawn on one.
        let mine: Vec<(usize, &Job)> = jobs
            .iter()
            .enumerate()
            .filter(|(_, j)| j.modality == m)
            .collect();
        let done = std::sync::Mutex::new(Vec::new());
        let next = AtomicUsize::new(0);
        let evaluate_one = |job: &Job| -> anyhow::Result<(Vec<Row>, eval::Predictions)> {
            let name = job
                .dir
                .file_name()
                .map(|n| n.to_string_lossy().into_owned());
            let plots = out.join("results/models").join(name.unwrap_or_default());
            let model = ForceModel::load(&job.dir)
                .with_context(|| format!("loading the model in {}", job.dir.display()))?;
            anyhow::ensure!(
                model.spec() == spec,
                "{} was trained on other images ({:?}) than this protocol's ({spec:?}); \
                 use a fresh --out",
                job.dir.display(),
                model.spec()
            );
            eval::evaluate_on(&model, &set, &tgt_dir, &plots, &split)
        };
        std::thread::scope(|s| -> anyhow::Result<()> {
            let work = || -> anyhow::Result<()> {
                while let Some(&(i, job)) = mine.get(next.fetch_add(1, Ordering::Relaxed)) {
                    let r = evaluate_one(job)?;
                    done.lock()
                        .map_err(|_| anyhow::anyhow!("poisoned"))?
                        .push((i, job, r));
                }
                Ok(())
            };
            let other = s.spawn(work);
            let a = work();
            let b = other
                .join()
                .map_err(|_| anyhow::anyhow!("an evaluation thread panicked"))?;
            a.and(b)
        })?;
        let mut done = done.into_inner().map_err(|_| anyhow::anyhow!("poisoned"))?;
        // The jobs' order (the paper's methods, then seeds), whichever model finished first.
        done.sort_by_key(|(i, _, _)| *i);
        for (_, job, (model_rows, p)) in done {
            for mut r in model_rows {
                r.method = format!("{}#{}", r.method, job.seed);
                rows.push(r);
            }
            predictions.push(figures::ModelPredictions {
                method: job.method.clone(),
                modality: m.paper_name().to_owned(),
                seed: job.seed,
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
    let shown = figures::figure_modalities(&agg);
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
    let range_n = eval::force_range(&data::load_eval(&tgt_dir, &rgbm, false)?);
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

/// What the training workers wait on: the translated images, or a failure elsewhere.
#[derive(Debug, Default, Clone, Copy)]
struct GateState {
    /// The translated images are written: the TransForce models may start.
    translation_ready: bool,
    /// Something failed: take no more jobs, stop waiting.
    stop: bool,
}

#[derive(Default)]
struct Gate {
    state: std::sync::Mutex<GateState>,
    changed: std::sync::Condvar,
}

impl Gate {
    fn get(&self) -> GateState {
        *self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Changes the state and wakes every waiting worker.
    fn set(&self, f: impl FnOnce(&mut GateState)) {
        f(&mut self.state.lock().unwrap_or_else(|p| p.into_inner()));
        self.changed.notify_all();
    }

    /// Blocks until `done` holds, and returns the state then.
    fn wait_until(&self, done: impl Fn(&GateState) -> bool) -> GateState {
        let g = self.state.lock().unwrap_or_else(|p| p.into_inner());
        *self
            .changed
            .wait_while(g, |s| !done(s))
            .unwrap_or_else(|p| p.into_inner())
    }
}

/// One force model to train.
struct Job {
    method: String,
    modality: Modality,
    seed: u64,
    dir: PathBuf,
    /// Trained on the translated images (else on the source sensor's own).
    translated: bool,
    lstm: bool,
    /// A marker-flow method's (trained with `Protocol::marker_force`).
    markers: bool,
}

/// The force models' shared queue, taken in order by each worker.
struct Trainer<'a> {
    protocol: &'a Protocol,
    jobs: &'a [Job],
    split: &'a Split,
    rgbm: ImageSpec,
    src_dir: &'a Path,
    translated_dir: PathBuf,
    next: AtomicUsize,
    /// Whether the translated images are ready (the TransForce models may start), or
    /// something failed.
    gate: Gate,
    /// Some model was trained (not only found done).
    trained: AtomicBool,
    /// The training sets loaded so far, by (translated, modality): 27 models train on 6 sets,
    /// and reading one from its recordings takes longer than a few epochs' batches.
    sets: std::sync::Mutex<BTreeMap<(bool, &'static str), std::sync::Arc<LabelledSet>>>,
}

impl Trainer<'_> {
    /// Trains jobs off the queue until it is empty; a job on translated images waits until
    /// they are ready. A failure stops every worker after its current model.
    fn work(&self) -> anyhow::Result<()> {
        let r = self.work_inner();
        if r.is_err() {
            self.gate.set(|g| g.stop = true);
        }
        r
    }

    fn work_inner(&self) -> anyhow::Result<()> {
        while !self.gate.get().stop {
            let Some(job) = self.jobs.get(self.next.fetch_add(1, Ordering::Relaxed)) else {
                return Ok(());
            };
            if job.translated && self.gate.wait_until(|g| g.translation_ready || g.stop).stop {
                return Ok(());
            }
            self.train(job)
                .with_context(|| format!("training {}", job.dir.display()))?;
        }
        Ok(())
    }

    fn train(&self, job: &Job) -> anyhow::Result<()> {
        if job.dir.join("DONE").is_file() {
            return Ok(());
        }
        let spec = ImageSpec {
            modality: job.modality,
            ..self.rgbm
        };
        let dir = if job.translated {
            &self.translated_dir
        } else {
            self.src_dir
        };
        let key = (job.translated, job.modality.name());
        let cached = self.sets.lock().ok().and_then(|m| m.get(&key).cloned());
        let set = match cached {
            Some(set) => set,
            None => {
                let set = std::sync::Arc::new(
                    data::load_labelled(dir, &spec, false)?.seen_only(self.split),
                );
                if let Ok(mut m) = self.sets.lock() {
                    m.insert(key, set.clone());
                }
                set
            }
        };
        let base = if job.markers {
            &self.protocol.marker_force
        } else {
            &self.protocol.force
        };
        let cfg = ForceConfig {
            lstm: job.lstm,
            seed: job.seed,
            ..base.clone()
        };
        train_force(&set, &cfg, &job.method, job.modality, &job.dir)?;
        std::fs::write(job.dir.join("DONE"), b"")?;
        self.trained.store(true, Ordering::Relaxed);
        Ok(())
    }
}

/// Phases 2 and 3: the translator (seen indenters), the seen and unseen source images through
/// it, the sample grids; then FID and KID. Returns the FID rows and their notes.
fn translate_and_fid(
    protocol: &Protocol,
    out: &Path,
    net: &Result<rig_nn::Inception, String>,
    phases: &mut Phases,
    progress: bool,
) -> anyhow::Result<(Vec<FidRow>, Vec<String>)> {
    let split = protocol.split();
    let (src_dir, tgt_dir) = (out.join("data/source"), out.join("data/target"));
    // 2. Translate (seen indenters), then the unseen source images through the translator.
    let t = Instant::now();
    let rgbm = ImageSpec {
        width: protocol.spec.0,
        height: protocol.spec.1,
        modality: Modality::RgbMarker,
    };
    let tdir = out.join("translate");
    let done = tdir.join("DONE");
    let zoom = super::cyclegan::source_zoom(&protocol.translate, &src_dir, &tgt_dir)?;
    let source_all = data::load_labelled_zoomed(&src_dir, &rgbm, zoom, progress)?;
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
            Progress::bar_or_lines(progress),
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
            // I_s is the source sensor's own frames, also when the translator saw them magnified
            // (`--match-marker-pitch`), as in `rig demo`.
            let source_images = if zoom == 1.0 {
                images_of(&source_seen, &source_unseen)
            } else {
                data::load_unlabelled(&src_dir, &rgbm, progress)?
            };
            let translated_images = images_of(&translated_seen, &translated_unseen);
            let rows = eval::translation_fid(
                [&source_images, &target_images, &translated_images],
                &split,
                &protocol.fid,
                net.as_ref().ok(),
                progress,
            )?;
            let notes = eval::fid_notes(net, &rows, &protocol.fid);
            std::fs::create_dir_all(out.join("results"))?;
            crate::durable::write_atomic(&fid_file, &serde_json::to_vec_pretty(&(&rows, &notes))?)?;
            (rows, notes, true)
        }
    };
    phases.done(out, "fid", t, fid_work)?;
    Ok((fid, fid_notes))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_worker_waiting_for_the_translation_wakes_when_it_is_ready_or_when_a_failure_stops_it() {
        for (what, set) in [
            (
                "ready",
                (|g: &mut GateState| g.translation_ready = true) as fn(&mut GateState),
            ),
            ("stop", |g: &mut GateState| g.stop = true),
        ] {
            let gate = Gate::default();
            let seen = std::thread::scope(|s| {
                let waiter = s.spawn(|| gate.wait_until(|g| g.translation_ready || g.stop));
                // The waiter blocks until the state changes (it has nothing to see before).
                std::thread::sleep(std::time::Duration::from_millis(50));
                assert!(
                    !waiter.is_finished(),
                    "{what}: returned before the gate changed"
                );
                gate.set(set);
                waiter.join().unwrap()
            });
            assert_eq!(
                (seen.translation_ready, seen.stop),
                (what == "ready", what == "stop"),
                "{what}"
            );
            // A later wait on a state that already holds returns at once.
            let again = gate.wait_until(|g| g.translation_ready || g.stop);
            assert_eq!(again.stop, what == "stop");
        }
    }
}
