//! `rig train force`: the sequential force model (encoder + LSTM, or the `nolstm` control),
//! trained with the γ-weighted L1 loss on labelled sequences; checkpoints in safetensors.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use burn::module::Module;
use burn::optim::{GradientsParams, ModuleOptimizer, SgdConfig};
use burn::store::{BurnpackStore, ModuleSnapshot, SafetensorsStore};
use burn::tensor::{Device, Tensor, TensorData};
use rig_nn::{
    Depth, FastEncoder, ForceNet, ForceShape, FusedAdam, build_networks, device, gamma_l1,
    init_params, on_pool,
};
use serde::{Deserialize, Serialize};

use super::Progress;
use super::batch::{Rng, Sequence, images_to_tensor, sample_sequences};
use super::data::{ImageSpec, LabelledSet, Trajectory};

pub mod speed;

pub const MODEL_INFO: &str = "model.json";
/// The format of a model directory this rig reads and writes ([`ModelInfo::format`]). A model
/// of another format is refused by [`read_info`] with a message saying what to do, instead of
/// being misread. Fields added later with a default (such as
/// [`ModelInfo::frames_per_trajectory`]) keep the format; a change that older readers would
/// misread bumps it.
pub const MODEL_FORMAT: &str = "rig-force-model-2";
/// Formats this version reads: its own, and format 1 (before the residual LSTM, which format 1
/// models lack: [`ForceShape::residual`] defaults to `false`).
const READS_FORMATS: [&str; 2] = [MODEL_FORMAT, "rig-force-model-1"];
const WEIGHTS: &str = "model.safetensors";
/// The same weights in burn's own format, which also keeps each parameter's id: the optimiser
/// state is keyed by those ids, so resuming needs them.
const RESUME_WEIGHTS: &str = "resume.bpk";
const OPTIM: &str = "optim.bin";
const LOG: &str = "train-log.csv";

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Optimizer {
    Adam,
    Sgd,
}

/// Force-model training settings. Paper values: ResNet-50, 64-d embedding and LSTM, T = 8,
/// K = 4, γ = 0.8, 20 epochs, lr 0.1 (our default optimiser is Adam at 1e-3, which trains these
/// small models reliably; `optimizer = "sgd"`, `lr = 0.1` gives the paper's setting).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ForceConfig {
    pub depth: Depth,
    pub width: usize,
    pub embed: usize,
    pub lstm: bool,
    /// The LSTM's output added to its input (see [`ForceShape::residual`]); `false` is the
    /// paper's plain LSTM.
    pub lstm_residual: bool,
    pub seq_len: usize,
    pub per_trajectory: usize,
    pub gamma: f64,
    pub epochs: usize,
    pub batch: usize,
    pub lr: f64,
    /// With a value: the learning rate decays from `lr` to this on a cosine, step by step
    /// (step k of K trains at `lr_final + (lr − lr_final) · ½ (1 + cos(π k / (K − 1)))`), so the
    /// last steps settle instead of jumping about at the full rate. None: constant `lr`.
    pub lr_final: Option<f64>,
    pub optimizer: Optimizer,
    pub seed: u64,
    /// Force range of the sigmoid output, N per axis; from the training labels (with a 5 %
    /// margin) when absent.
    pub range: Option<ForceRange>,
    /// Marker modalities (D, D+S) only: train on mirror images too. Each sequence is drawn
    /// as it is, mirrored left-right, top-bottom or both (one of the four at random, the same
    /// for all its frames), with the force's x or y component negated to match
    /// ([`super::data::mirror_flow_image`]): new contact shapes from the same recordings.
    /// The paper's image modalities are never mirrored (their LEDs light from one side).
    pub mirror: bool,
    /// The encoder's head pools its last feature map to one vector (ResNet's global average
    /// pool) even on small inputs, which otherwise flatten the map ([`ForceShape::spatial`]).
    /// The pool reads a contact the same wherever its shading falls, and so reads shapes it
    /// was not trained on better; the flattened map keeps where the contact sits, the cue for
    /// shear in the paper's image modalities.
    pub global_pool: bool,
}

impl Default for ForceConfig {
    fn default() -> Self {
        Self {
            depth: Depth::R18,
            width: 16,
            embed: 64,
            lstm: true,
            lstm_residual: true,
            seq_len: 8,
            per_trajectory: 4,
            gamma: 0.8,
            epochs: 20,
            batch: 8,
            lr: 1e-3,
            lr_final: None,
            optimizer: Optimizer::Adam,
            seed: 1,
            range: None,
            mirror: false,
            global_pool: false,
        }
    }
}

impl ForceConfig {
    /// The learning rate of step `step` (0-based) of the `steps` in epoch `epoch`: `lr`, or the
    /// cosine decay to `lr_final` over the whole training, step by step, so that the last step
    /// trains at `lr_final` however few the epochs (decayed per epoch, two epochs ended at half
    /// the rate: docs/experiments.md, *A learning rate that settles*). A function of where
    /// the step is and `epochs` alone, so a run resumed with the same config continues the
    /// same schedule (resumed with more epochs, the rest of it stretches).
    pub fn lr_at(&self, epoch: usize, step: usize, steps: usize) -> f64 {
        match self.lr_final {
            None => self.lr,
            Some(end) => {
                let steps = steps.max(1);
                let last = (self.epochs.max(1) * steps).saturating_sub(1).max(1);
                let x = ((epoch * steps + step.min(steps - 1)) as f64 / last as f64).min(1.0);
                end + (self.lr - end) * 0.5 * (1.0 + (std::f64::consts::PI * x).cos())
            }
        }
    }
}

/// The work range the sigmoid output is scaled to: F = lo + (hi − lo) · σ(z).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForceRange {
    pub lo: [f32; 3],
    pub hi: [f32; 3],
}

impl ForceRange {
    /// The labels' bounds with a 5 % margin; an axis without variation gets ±0.5 N so the
    /// scale stays finite.
    pub fn from_bounds(b: [(f32, f32); 3]) -> Self {
        let mut lo = [0.0; 3];
        let mut hi = [0.0; 3];
        for a in 0..3 {
            let (mn, mx) = if b[a].0.is_finite() && b[a].1.is_finite() {
                b[a]
            } else {
                (0.0, 0.0)
            };
            let span = mx - mn;
            if span <= 1e-6 {
                lo[a] = mn - 0.5;
                hi[a] = mx + 0.5;
            } else {
                lo[a] = mn - 0.05 * span;
                hi[a] = mx + 0.05 * span;
            }
        }
        Self { lo, hi }
    }
    pub fn normalise(&self, f: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|a| ((f[a] - self.lo[a]) / (self.hi[a] - self.lo[a])).clamp(0.0, 1.0))
    }
    pub fn denormalise(&self, u: [f32; 3]) -> [f32; 3] {
        std::array::from_fn(|a| self.lo[a] + u[a] * (self.hi[a] - self.lo[a]))
    }
}

/// What a model directory says about its model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    pub format: String,
    /// A label for tables: `TransForce`, `TransForce (no LSTM)`, `source-only`, …
    pub method: String,
    pub spec: ImageSpec,
    pub shape: ForceShape,
    pub range: ForceRange,
    pub config: ForceConfig,
    /// Epochs completed (the checkpoint holds the weights after this many).
    pub epochs_done: usize,
    pub trained_on: String,
    pub last_loss: f64,
    /// The median length, in frames, of the training trajectories: `rig predict` derives its
    /// default window stride from it (⌊n/T⌋, the stride `rig eval` reads a trajectory of n
    /// frames at). Absent in models trained before it was recorded.
    #[serde(default)]
    pub frames_per_trajectory: Option<usize>,
    /// D+S models: the mean shading change of their training frames
    /// ([`super::data::mean_shading`]), the scale another sensor's shading is brought to
    /// ([`super::data::shading_gain`]). Absent for other modalities and older models.
    #[serde(default)]
    pub shading_mean: Option<f64>,
}

/// A trained model, ready to predict (no autodiff).
pub struct ForceModel {
    pub info: ModelInfo,
    net: ForceNet,
    dev: Device,
    /// The encoder's CPU inference form, used by [`Self::encode`] and [`Self::predict`] on the
    /// CPU (same numbers as burn's forward to float rounding; about twice as fast).
    fast: Option<FastEncoder>,
}

/// The encoder's CPU inference form on the CPU backend; `None` on the GPU, where burn's
/// kernels run.
fn fast_form(net: &ForceNet) -> Option<FastEncoder> {
    if rig_nn::GPU {
        None
    } else {
        net.fast_encoder()
    }
}

pub fn shape_for(cfg: &ForceConfig, spec: &ImageSpec) -> ForceShape {
    let imagenet_stem = spec.width.min(spec.height) >= 96;
    let map = ForceShape::final_map(imagenet_stem, spec.height as usize, spec.width as usize);
    let cells = map[0] * map[1];
    ForceShape {
        depth: cfg.depth,
        width: cfg.width,
        embed: cfg.embed,
        lstm: cfg.lstm,
        residual: cfg.lstm && cfg.lstm_residual,
        imagenet_stem,
        spatial: (cells <= 64 && !cfg.global_pool).then_some(map),
    }
}

/// The network a training starts from, on `dev` with autodiff: its weights from `seed` alone.
fn initial_network(shape: &ForceShape, dev: &Device, seed: u64) -> (Device, ForceNet) {
    build_networks(dev, Some(seed), || {
        let adev = dev.clone().autodiff();
        let net = ForceNet::new(shape, &adev);
        init_params(&net);
        (adev, net)
    })
}

/// The optimiser `train` steps with (its state starts empty).
fn new_optimizer(kind: Optimizer) -> ModuleOptimizer {
    match kind {
        Optimizer::Adam => FusedAdam::init(0.9, 0.999),
        Optimizer::Sgd => SgdConfig::new().init(),
    }
}

/// A batch of sequences: images `[B, T, 3, H, W]` and normalised forces `[B, T, 3]`. Sequence
/// `i` is mirrored as `flips[i]` says (see [`ForceConfig::mirror`]; none where `flips` is short).
fn batch_tensors(
    trajs: &[Trajectory],
    forces: &dyn Fn(usize) -> Vec<[f32; 3]>,
    seqs: &[&Sequence],
    flips: &[u8],
    spec: &ImageSpec,
    range: &ForceRange,
    dev: &Device,
) -> (Tensor<5>, Tensor<3>) {
    let t = seqs.first().map_or(0, |s| s.frames.len());
    let mut frames: Vec<std::borrow::Cow<[u8]>> = Vec::with_capacity(seqs.len() * t);
    let mut y = Vec::with_capacity(seqs.len() * t * 3);
    for (k, s) in seqs.iter().enumerate() {
        let f = forces(s.traj);
        let flip = flips.get(k).copied().unwrap_or(0);
        for &i in &s.frames {
            let img = trajs[s.traj].frame(i, spec);
            let mut fi = f[i];
            if flip == 0 {
                frames.push(img.into());
            } else {
                let (w, h) = (spec.width as usize, spec.height as usize);
                frames.push(super::data::mirror_flow_image(img, w, h, flip).into());
                if flip & 1 != 0 {
                    fi[0] = -fi[0];
                }
                if flip & 2 != 0 {
                    fi[1] = -fi[1];
                }
            }
            y.extend_from_slice(&range.normalise(fi));
        }
    }
    let refs: Vec<&[u8]> = frames.iter().map(|f| f.as_ref()).collect();
    let x = images_to_tensor(&refs, spec, dev);
    let [_, c, h, w] = x.dims();
    let b = seqs.len();
    (
        x.reshape([b, t, c, h, w]),
        Tensor::from_data(TensorData::new(y, [b, t, 3]), dev),
    )
}

/// Progress of one training run (returned for tests and the benchmark).
#[derive(Debug, Clone, PartialEq)]
pub struct TrainReport {
    pub epochs_done: usize,
    pub last_loss: f64,
    pub sequences_per_s: f64,
    pub images_per_s: f64,
    pub seconds: f64,
}

/// Training throughput for the progress bar and the per-epoch line.
fn rates(sequences: usize, seq_len: usize, secs: f64) -> String {
    format!(
        "{:.1} seq/s {:.0} img/s",
        sequences as f64 / secs,
        (sequences * seq_len) as f64 / secs
    )
}

/// Train (or resume training of) a force model on `set`, writing checkpoints into `out`; on a
/// worker of rayon's pool ([`on_pool`]).
pub fn train(
    set: &LabelledSet,
    cfg: &ForceConfig,
    method: &str,
    out: &Path,
    resume: bool,
    progress: Progress,
) -> anyhow::Result<TrainReport> {
    on_pool(|| train_here(set, cfg, method, out, resume, progress))
}

fn train_here(
    set: &LabelledSet,
    cfg: &ForceConfig,
    method: &str,
    out: &Path,
    resume: bool,
    progress: Progress,
) -> anyhow::Result<TrainReport> {
    if cfg.seq_len == 0 || cfg.batch == 0 || cfg.per_trajectory == 0 {
        bail!("seq_len, batch and per_trajectory must be at least 1");
    }
    if !(cfg.gamma > 0.0 && cfg.gamma.is_finite() && cfg.lr > 0.0 && cfg.lr.is_finite()) {
        bail!("gamma and lr must be positive and finite");
    }
    if cfg
        .lr_final
        .is_some_and(|l| !(l > 0.0 && l.is_finite() && l <= cfg.lr))
    {
        bail!("lr_final must be positive, finite and at most lr");
    }
    let spec = set.spec;
    // Only marker displacement is mirrored (`ForceConfig::mirror`).
    let mirror = cfg.mirror && !spec.modality.per_frame();
    let lengths: Vec<usize> = set.trajectories.iter().map(|t| t.frames).collect();
    if sample_sequences(&lengths, cfg.seq_len, 1, &mut Rng(0)).is_empty() {
        bail!(
            "no trajectory has {} frames: nothing to train on ({} trajectories)",
            cfg.seq_len,
            lengths.len()
        );
    }
    fs::create_dir_all(out)?;
    let dev = device();
    let shape = shape_for(cfg, &spec);
    let (adev, mut net) = initial_network(&shape, &dev, cfg.seed);
    let mut optim = new_optimizer(cfg.optimizer);
    let mut info = ModelInfo {
        format: MODEL_FORMAT.into(),
        method: method.into(),
        spec,
        shape,
        range: cfg.range.unwrap_or_else(|| {
            let mut b = set.force_bounds();
            if mirror {
                // Mirrored labels negate x and y: the range must hold both signs.
                for (lo, hi) in &mut b[..2] {
                    let m = lo.abs().max(hi.abs());
                    (*lo, *hi) = (-m, m);
                }
            }
            ForceRange::from_bounds(b)
        }),
        config: cfg.clone(),
        epochs_done: 0,
        trained_on: String::new(),
        last_loss: f64::NAN,
        frames_per_trajectory: median(&lengths),
        shading_mean: if spec.modality == super::modality::Modality::FlowShading {
            super::data::mean_shading(set.trajectories.iter().map(|t| t.pixels.as_slice()))
        } else {
            None
        },
    };
    // A checkpoint a crash interrupted: an incomplete one is dropped, a complete one installed.
    checkpoint_set(out).recover()?;
    if resume && out.join(MODEL_INFO).is_file() {
        let old = read_info(out)?;
        if old.shape != shape || old.spec != spec {
            bail!(
                "{} holds a model of another shape or image size; train into a new --out",
                out.display()
            );
        }
        net.load_from(&mut BurnpackStore::from_file(out.join(RESUME_WEIGHTS)))
            .map_err(|e| {
                anyhow::anyhow!("cannot load {}: {e:?}", out.join(RESUME_WEIGHTS).display())
            })?;
        net = net.fork(&adev);
        if out.join(OPTIM).is_file() {
            optim = optim
                .load(out.join(OPTIM))
                .map_err(|e| anyhow::anyhow!("cannot load the optimiser state: {e:?}"))?;
        }
        info.range = old.range;
        info.epochs_done = old.epochs_done;
        info.last_loss = old.last_loss;
        if progress != Progress::Silent {
            eprintln!("resuming {} after epoch {}", out.display(), old.epochs_done);
        }
    }
    let forces = |i: usize| set.forces(i).to_vec();
    let steps_per_epoch = sample_sequences(&lengths, cfg.seq_len, cfg.per_trajectory, &mut Rng(0))
        .len()
        .div_ceil(cfg.batch);
    let total = (cfg.epochs.saturating_sub(info.epochs_done) * steps_per_epoch) as u64;
    let bar = super::progress_bar(progress == Progress::Bar, total, "force");
    let t0 = std::time::Instant::now();
    let mut seqs_done = 0usize;
    let mut log = fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(out.join(LOG))?;
    for epoch in info.epochs_done..cfg.epochs {
        let mut rng = Rng(cfg.seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9));
        let mut seqs = sample_sequences(&lengths, cfg.seq_len, cfg.per_trajectory, &mut rng);
        rng.shuffle(&mut seqs);
        // Drawn after the sequences, so that mirroring leaves which sequences are drawn as
        // they were.
        let flips: Vec<u8> = if mirror {
            seqs.iter().map(|_| rng.below(4) as u8).collect()
        } else {
            Vec::new()
        };
        let mut sum = 0.0;
        let mut lr = cfg.lr;
        for (n, chunk) in seqs.chunks(cfg.batch).enumerate() {
            lr = cfg.lr_at(epoch, n, steps_per_epoch);
            let refs: Vec<&Sequence> = chunk.iter().collect();
            let flips = flips.get(n * cfg.batch..).unwrap_or(&[]);
            let (x, y) = batch_tensors(
                &set.trajectories,
                &forces,
                &refs,
                flips,
                &spec,
                &info.range,
                &adev,
            );
            let loss = gamma_l1(net.forward(x), y, cfg.gamma);
            let value = loss.clone().into_scalar::<f32>() as f64;
            if !value.is_finite() {
                bar.abandon();
                bail!(
                    "the loss became {value} in epoch {} (learning rate {} too high, or bad \
                     data); training stopped. {}",
                    epoch + 1,
                    lr,
                    if info.epochs_done > 0 {
                        format!(
                            "The last good checkpoint (epoch {}) is kept in {}",
                            info.epochs_done,
                            out.display()
                        )
                    } else {
                        "No checkpoint was written.".to_string()
                    }
                );
            }
            let grads = GradientsParams::from_grads(loss.backward(), &net);
            net = optim.step(lr, net, grads);
            sum += value * chunk.len() as f64;
            seqs_done += chunk.len();
            let secs = t0.elapsed().as_secs_f64().max(1e-9);
            bar.set_message(format!(
                "epoch {}/{} loss {value:.4} · {}",
                epoch + 1,
                cfg.epochs,
                rates(seqs_done, cfg.seq_len, secs)
            ));
            bar.inc(1);
        }
        let mean = sum / seqs.len().max(1) as f64;
        // A step can leave weights that are not finite while this epoch's losses were: check
        // before the checkpoint is replaced, so the last good one survives.
        let probe: Vec<&Sequence> = seqs.iter().take(cfg.batch).collect();
        let (x, _) = batch_tensors(
            &set.trajectories,
            &forces,
            &probe,
            &[],
            &spec,
            &info.range,
            &dev,
        );
        let check = net
            .valid()
            .forward(x)
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>();
        if !check.is_ok_and(|v| v.iter().all(|x| x.is_finite())) {
            bar.abandon();
            bail!(
                "the weights are no longer finite after epoch {} (learning rate {} too high?); \
                 training stopped, the checkpoint of epoch {} is kept",
                epoch + 1,
                lr,
                info.epochs_done
            );
        }
        info.epochs_done = epoch + 1;
        info.last_loss = mean;
        save_checkpoint(out, &net, &optim, &info)?;
        if progress == Progress::Lines {
            eprintln!(
                "force: epoch {}/{} loss {mean:.4} · {}",
                epoch + 1,
                cfg.epochs,
                rates(seqs_done, cfg.seq_len, t0.elapsed().as_secs_f64().max(1e-9))
            );
        }
        use std::io::Write as _;
        writeln!(
            log,
            "{},{mean:.6},{:.3}",
            epoch + 1,
            t0.elapsed().as_secs_f64()
        )?;
    }
    bar.finish_and_clear();
    let secs = t0.elapsed().as_secs_f64();
    Ok(TrainReport {
        epochs_done: info.epochs_done,
        last_loss: info.last_loss,
        sequences_per_s: seqs_done as f64 / secs.max(1e-9),
        images_per_s: (seqs_done * cfg.seq_len) as f64 / secs.max(1e-9),
        seconds: secs,
    })
}

/// The checkpoint files of `dir` as one set: replaced whole after each epoch, the
/// description ([`MODEL_INFO`]) last, so a crash never leaves files of two epochs (see
/// [`crate::durable::FileSet`]).
fn checkpoint_set(dir: &Path) -> crate::durable::FileSet<'_> {
    crate::durable::FileSet::new(dir, MODEL_INFO)
}

/// Replaces the checkpoint in `out` by this one: weights (safetensors and burn's format),
/// optimiser state and description, written, fsynced and installed as one set.
fn save_checkpoint(
    out: &Path,
    net: &ForceNet,
    optim: &ModuleOptimizer,
    info: &ModelInfo,
) -> anyhow::Result<()> {
    checkpoint_set(out)
        .replace(|dir| write_checkpoint(dir, net, optim, info))
        .with_context(|| format!("cannot write the checkpoint of epoch {}", info.epochs_done))
}

/// The checkpoint's files, written into `dir` (a staging directory).
fn write_checkpoint(
    dir: &Path,
    net: &ForceNet,
    optim: &ModuleOptimizer,
    info: &ModelInfo,
) -> anyhow::Result<()> {
    net.save_into(&mut SafetensorsStore::from_file(dir.join(WEIGHTS)))
        .map_err(|e| anyhow::anyhow!("cannot write the weights: {e:?}"))?;
    net.save_into(&mut BurnpackStore::from_file(dir.join(RESUME_WEIGHTS)))
        .map_err(|e| anyhow::anyhow!("cannot write the resume weights: {e:?}"))?;
    optim
        .save(dir.join(OPTIM))
        .map_err(|e| anyhow::anyhow!("cannot write the optimiser state: {e:?}"))?;
    fs::write(dir.join(MODEL_INFO), serde_json::to_vec_pretty(info)?)?;
    Ok(())
}

/// The description of the model in `dir` (of the checkpoint a crash left half installed, if
/// one did: the one whose files are read).
pub fn read_info(dir: &Path) -> anyhow::Result<ModelInfo> {
    if !dir.is_dir() {
        bail!(
            "no model at {}: give the directory `rig train force --out` wrote (it holds \
             {MODEL_INFO} and {WEIGHTS})",
            dir.display()
        );
    }
    let p = checkpoint_set(dir).path(MODEL_INFO);
    let text = fs::read(&p).with_context(|| {
        format!(
            "{} is not a model directory (no {MODEL_INFO}): give the directory `rig train \
             force --out` wrote",
            dir.display()
        )
    })?;
    // The format first, so a model of another version is named as such rather than reported
    // as a field this version does not know.
    let raw: serde_json::Value = serde_json::from_slice(&text)
        .with_context(|| format!("{} is not a model description (not JSON)", p.display()))?;
    match raw.get("format").and_then(|f| f.as_str()) {
        Some(f) if READS_FORMATS.contains(&f) => {}
        Some(other) => bail!(
            "{} is a model of format {other:?}; this rig ({}) reads {MODEL_FORMAT:?}. Use the \
             rig version that trained it, or retrain the model with this one (`rig train force`)",
            dir.display(),
            env!("CARGO_PKG_VERSION")
        ),
        None => bail!(
            "{} has no format field: it is not a model description this rig wrote",
            p.display()
        ),
    }
    serde_json::from_value(raw)
        .with_context(|| format!("{} is not a model description", p.display()))
}

/// The median of `v` (the upper one of an even count); `None` when empty.
fn median(v: &[usize]) -> Option<usize> {
    let mut s = v.to_vec();
    s.sort_unstable();
    s.get(s.len() / 2).copied()
}

impl ForceModel {
    /// The model of a model directory, ready to predict.
    pub fn load(dir: &Path) -> anyhow::Result<Self> {
        let info = read_info(dir)?;
        let dev = device();
        // The initial weights are overwritten, but building them draws from the shared
        // generator: under the lock, so a training seeding it in another thread is undisturbed.
        let mut net = build_networks(&dev, None, || ForceNet::new(&info.shape, &dev));
        // Read through the checkpoint set: whole even if a crash interrupted its installation.
        let weights = checkpoint_set(dir).path(WEIGHTS);
        net.load_from(&mut SafetensorsStore::from_file(&weights))
            .map_err(|e| anyhow::anyhow!("cannot load {}: {e:?}", weights.display()))?;
        let fast = fast_form(&net);
        Ok(Self {
            info,
            net,
            dev,
            fast,
        })
    }

    pub fn spec(&self) -> ImageSpec {
        self.info.spec
    }

    /// A model of `cfg`'s shape for `spec` images with the initial weights of `cfg.seed`,
    /// untrained: for benchmarks of inference time, where the weights' values do not matter.
    pub fn untrained(cfg: &ForceConfig, spec: ImageSpec, frames_per_trajectory: usize) -> Self {
        let dev = device();
        let shape = shape_for(cfg, &spec);
        let net = build_networks(&dev, Some(cfg.seed), || {
            let net = ForceNet::new(&shape, &dev);
            init_params(&net);
            net
        });
        let info = ModelInfo {
            format: MODEL_FORMAT.into(),
            method: "untrained".into(),
            spec,
            shape,
            range: cfg.range.unwrap_or_else(|| {
                ForceRange::from_bounds([(-1.0, 1.0), (-1.0, 1.0), (-5.0, 0.0)])
            }),
            config: cfg.clone(),
            epochs_done: 0,
            trained_on: String::new(),
            last_loss: f64::NAN,
            frames_per_trajectory: Some(frames_per_trajectory),
            shading_mean: None,
        };
        let fast = fast_form(&net);
        Self {
            info,
            net,
            dev,
            fast,
        }
    }

    /// Embeddings of `frames` (each `spec`-sized RGB), one per frame: the encoder alone.
    pub fn encode(&self, frames: &[&[u8]]) -> Vec<Vec<f32>> {
        if frames.is_empty() {
            return Vec::new();
        }
        if let Some(fast) = &self.fast {
            let spec = &self.info.spec;
            return fast.encode(frames, spec.width as usize, spec.height as usize);
        }
        let x = images_to_tensor(frames, &self.info.spec, &self.dev);
        let e = self.net.encode(x);
        let d = e.dims()[1];
        let v: Vec<f32> = e
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32 output");
        v.chunks_exact(d).map(|c| c.to_vec()).collect()
    }

    /// The force (N) at the last of a sequence of embeddings in time order (the LSTM runs
    /// over all of them from a zero state; without an LSTM only the last one counts).
    pub fn force_at_last(&self, embeddings: &[&[f32]]) -> [f32; 3] {
        let window: &[&[f32]] = if self.info.shape.lstm {
            embeddings
        } else {
            &embeddings[embeddings.len().saturating_sub(1)..]
        };
        let t = window.len();
        let d = self.info.shape.embed;
        let flat: Vec<f32> = window.iter().flat_map(|e| e.iter().copied()).collect();
        let s = Tensor::<3>::from_data(TensorData::new(flat, [1, t, d]), &self.dev);
        let y: Vec<f32> = self
            .net
            .head(s)
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32 output");
        let k = (t - 1) * 3;
        self.info.range.denormalise([y[k], y[k + 1], y[k + 2]])
    }

    /// Forces (N) at every position of `b` sequences of `t` frames each, given as `b · t`
    /// frames in sequence order: the encoder (its CPU form on the CPU), then the LSTM and MLP.
    pub fn sequence_forces(&self, frames: &[&[u8]], b: usize, t: usize) -> Vec<[f32; 3]> {
        assert_eq!(frames.len(), b * t, "b · t frames");
        let y = if self.fast.is_some() {
            let d = self.info.shape.embed;
            let flat: Vec<f32> = self.encode(frames).into_iter().flatten().collect();
            let s = Tensor::<3>::from_data(TensorData::new(flat, [b, t, d]), &self.dev);
            self.net.head(s)
        } else {
            let x = images_to_tensor(frames, &self.info.spec, &self.dev);
            let [_, c, h, w] = x.dims();
            self.net.forward(x.reshape([b, t, c, h, w]))
        };
        let v: Vec<f32> = y
            .into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32 output");
        v.chunks_exact(3)
            .map(|f| self.info.range.denormalise([f[0], f[1], f[2]]))
            .collect()
    }

    /// Forces (N) for each frame of each sequence: `[sequence][position]`.
    pub fn predict(
        &self,
        trajs: &[Trajectory],
        seqs: &[Sequence],
        batch: usize,
    ) -> Vec<Vec<[f32; 3]>> {
        let spec = self.info.spec;
        let mut out = Vec::with_capacity(seqs.len());
        for chunk in seqs.chunks(batch.max(1)) {
            let refs: Vec<&Sequence> = chunk.iter().collect();
            let t = chunk[0].frames.len();
            let frames: Vec<&[u8]> = refs
                .iter()
                .flat_map(|s| s.frames.iter().map(|&i| trajs[s.traj].frame(i, &spec)))
                .collect();
            let v = self.sequence_forces(&frames, chunk.len(), t);
            out.extend(v.chunks_exact(t).map(|s| s.to_vec()));
        }
        out
    }
}

/// The checkpoint files of a model directory (for listings and tests).
pub fn checkpoint_files(dir: &Path) -> Vec<PathBuf> {
    [MODEL_INFO, WEIGHTS, RESUME_WEIGHTS, OPTIM]
        .iter()
        .map(|f| dir.join(f))
        .collect()
}

#[cfg(test)]
mod tests {
    use rig_nn::float_params as weights;

    use super::*;

    #[test]
    fn the_cosine_schedule_runs_from_lr_to_lr_final_step_by_step() {
        let cfg = ForceConfig {
            lr: 1e-2,
            lr_final: Some(1e-3),
            epochs: 3,
            ..ForceConfig::default()
        };
        // 3 epochs of 3 steps: x = k / 8 for the k-th step overall.
        let lrs: Vec<f64> = (0..3)
            .flat_map(|e| (0..3).map(move |n| (e, n)))
            .map(|(e, n)| cfg.lr_at(e, n, 3))
            .collect();
        // ½ (1 + cos(π k / 8)) at k = 0, 4 (epoch 1, step 1) and 8 (the last step).
        for (k, want) in [(0, 1e-2), (4, 5.5e-3), (8, 1e-3)] {
            assert!((lrs[k] - want).abs() < 1e-12, "step {k}: {lrs:?}");
        }
        assert!(lrs.windows(2).all(|w| w[1] < w[0]), "{lrs:?}");
        // Two epochs end at lr_final too (a schedule per epoch ended them at half the rate).
        let two = ForceConfig { epochs: 2, ..cfg };
        assert!((two.lr_at(1, 239, 240) - 1e-3).abs() < 1e-12);
        assert!((two.lr_at(1, 0, 240) - 1e-2).abs() > 4e-3);
        let flat = ForceConfig {
            lr_final: None,
            ..cfg
        };
        assert!((0..4).all(|e| flat.lr_at(e, 1, 3) == 1e-2));
    }

    #[test]
    fn a_pooled_head_drops_the_map_that_small_inputs_otherwise_keep() {
        let spec = ImageSpec {
            width: 32,
            height: 24,
            modality: super::super::modality::Modality::FlowShading,
        };
        let map = shape_for(&ForceConfig::default(), &spec);
        assert_eq!(map.spatial, Some(ForceShape::final_map(false, 24, 32)));
        let pooled = ForceConfig {
            global_pool: true,
            ..ForceConfig::default()
        };
        assert_eq!(shape_for(&pooled, &spec).spatial, None);
        // Older settings files, without the key, keep the map.
        let old: ForceConfig = toml::from_str("epochs = 2").unwrap();
        assert!(!old.global_pool);
    }

    /// `rig demo` trains two networks side by side. A network's initial weights must be drawn
    /// when it is built, under the build lock: if they were drawn at first use, another
    /// training's draws in between (here: a second network built and used first) would change
    /// them, and the same seed and data would give another model.
    #[test]
    fn initial_weights_depend_on_the_seed_alone_whatever_is_drawn_after_the_build() {
        let spec = ImageSpec {
            width: 32,
            height: 24,
            modality: crate::train::modality::Modality::RgbMarker,
        };
        let cfg = ForceConfig {
            width: 4,
            ..ForceConfig::default()
        };
        let shape = shape_for(&cfg, &spec);
        let dev = device();
        let (_, first) = initial_network(&shape, &dev, 7);
        // Another training builds its network (another seed) and uses it in between.
        let (_, other) = initial_network(&shape, &dev, 8);
        let w_other = weights(&other);
        let w_first = weights(&first);
        let (_, again) = initial_network(&shape, &dev, 7);
        assert_eq!(w_first.len(), w_other.len());
        assert!(
            w_first == weights(&again),
            "seed 7 gave other weights the second time"
        );
        assert!(w_first != w_other, "seeds 7 and 8 gave the same weights");
    }

    /// A small network of `seed`, the optimiser and the description of its epoch `epoch`.
    fn checkpoint(seed: u64, epoch: usize) -> (ForceNet, ModuleOptimizer, ModelInfo) {
        let spec = ImageSpec {
            width: 32,
            height: 24,
            modality: crate::train::modality::Modality::RgbMarker,
        };
        let config = ForceConfig {
            width: 4,
            ..ForceConfig::default()
        };
        let shape = shape_for(&config, &spec);
        let (_, net) = initial_network(&shape, &device(), seed);
        let info = ModelInfo {
            format: MODEL_FORMAT.into(),
            method: "test".into(),
            spec,
            shape,
            range: ForceRange::from_bounds([(-1.0, 1.0); 3]),
            config,
            epochs_done: epoch,
            trained_on: String::new(),
            last_loss: 0.5,
            frames_per_trajectory: Some(60),
            shading_mean: None,
        };
        (net, FusedAdam::init(0.9, 0.999), info)
    }

    /// The weights burn's resume file in `dir` holds.
    fn resume_weights(dir: &Path, like: &ForceNet) -> Vec<f32> {
        let mut net = like.clone();
        net.load_from(&mut BurnpackStore::from_file(dir.join(RESUME_WEIGHTS)))
            .unwrap();
        weights(&net)
    }

    #[test]
    fn a_checkpoint_is_installed_whole_and_loads_back() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let (old, optim, info) = checkpoint(3, 1);
        save_checkpoint(dir, &old, &optim, &info).unwrap();
        let (net, optim, info) = checkpoint(4, 2);
        save_checkpoint(dir, &net, &optim, &info).unwrap();
        // The four files and nothing else (no staging left).
        let mut want: Vec<String> = checkpoint_files(dir)
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        want.sort();
        assert_eq!(crate::durable::entries(dir), want);

        let model = ForceModel::load(dir).unwrap();
        assert_eq!(model.info, info);
        let w = weights(&net);
        assert_ne!(w, weights(&old), "seeds 3 and 4 gave the same weights");
        assert_eq!(weights(&model.net), w);
        assert_eq!(resume_weights(dir, &net), w);
    }

    #[test]
    fn a_checkpoint_a_crash_left_half_written_is_ignored_and_removed() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let (net, optim, info) = checkpoint(3, 1);
        save_checkpoint(dir, &net, &optim, &info).unwrap();
        // The crash: epoch 2 half written into the staging directory (its description
        // already there, its weights cut short).
        let (newer, optim2, info2) = checkpoint(4, 2);
        let staging = dir.join(crate::durable::FileSet::STAGING);
        fs::create_dir(&staging).unwrap();
        write_checkpoint(&staging, &newer, &optim2, &info2).unwrap();
        let full = fs::read(staging.join(WEIGHTS)).unwrap();
        fs::write(staging.join(WEIGHTS), &full[..full.len() / 2]).unwrap();

        let model = ForceModel::load(dir).unwrap();
        assert_eq!(model.info.epochs_done, 1);
        assert_eq!(weights(&model.net), weights(&net));
        // What a training does first: the leftover goes, the checkpoint of epoch 1 stays.
        checkpoint_set(dir).recover().unwrap();
        assert!(!staging.exists());
        assert_eq!(read_info(dir).unwrap().epochs_done, 1);
        assert_eq!(resume_weights(dir, &net), weights(&net));
    }

    #[test]
    fn a_checkpoint_a_crash_left_half_installed_is_read_whole_and_completed() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let (old, optim, info) = checkpoint(3, 1);
        save_checkpoint(dir, &old, &optim, &info).unwrap();
        // The crash: epoch 2 complete and committed, only its weights moved into place.
        let (net, optim, info) = checkpoint(4, 2);
        let set = checkpoint_set(dir);
        set.stage(|d| write_checkpoint(d, &net, &optim, &info))
            .unwrap();
        let ready = dir.join(crate::durable::FileSet::READY);
        fs::rename(ready.join(WEIGHTS), dir.join(WEIGHTS)).unwrap();

        // Read as it is: epoch 2 throughout.
        let model = ForceModel::load(dir).unwrap();
        assert_eq!(model.info.epochs_done, 2);
        assert_eq!(weights(&model.net), weights(&net));
        // Recovered: epoch 2 installed, resume weights included.
        set.recover().unwrap();
        assert!(!ready.exists());
        assert_eq!(read_info(dir).unwrap(), info);
        assert_eq!(resume_weights(dir, &net), weights(&net));
        assert_ne!(weights(&net), weights(&old));
    }
}
