//! `rig train translate`: CycleGAN from the source sensor's images to the target sensor's style
//! (Zhu et al. 2017), with the paper's settings as defaults: LSGAN, λ_cyc = 10, λ_idt = 0.5
//! (of λ_cyc, as in the reference implementation), Adam lr 2e-4 with β1 = 0.5, an image pool of
//! 50, and the learning rate decayed linearly to zero over the second half of training.

use std::fs;
use std::path::Path;

use anyhow::{Context, bail};
use burn::module::Module;
use burn::optim::{GradientsParams, ModuleOptimizer};
use burn::store::{ModuleSnapshot, SafetensorsStore};
use burn::tensor::{Device, Tensor};
use rig_nn::{
    Discriminator, FusedAdam, GanShape, Generator, build_networks, device, init_params, l1, lsgan,
    on_pool,
};
use serde::{Deserialize, Serialize};

use super::Progress;
use super::batch::{Rng, images_to_tensor, tensor_to_images};
use super::data::{ImageSpec, LabelledSet, Trajectory, UnlabelledSet};
use super::pitch::pitch_zoom;

const INFO: &str = "translator.json";

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TranslateConfig {
    pub shape: GanShape,
    pub lambda_adv: f64,
    pub lambda_cyc: f64,
    pub lambda_idt: f64,
    pub lr: f64,
    pub beta1: f32,
    pub pool: usize,
    pub batch: usize,
    /// Paper: 30 epochs over the source images.
    pub epochs: usize,
    /// Iterations per epoch; by default one pass over the larger image set.
    pub steps_per_epoch: Option<usize>,
    pub seed: u64,
    /// Magnify the source's frames by the ratio of the two sensors' marker pitches before
    /// translating them ([`super::pitch`]), so that the translated markers can move with the
    /// gel; the recordings' rig configs must give both pitches. Off by default.
    pub match_marker_pitch: bool,
}

impl Default for TranslateConfig {
    fn default() -> Self {
        Self {
            shape: GanShape {
                ngf: 16,
                ndf: 16,
                res_blocks: 6,
                disc_layers: 3,
                down: 2,
            },
            lambda_adv: 1.0,
            lambda_cyc: 10.0,
            lambda_idt: 0.5,
            lr: 2e-4,
            beta1: 0.5,
            pool: 50,
            batch: 1,
            epochs: 30,
            steps_per_epoch: None,
            seed: 1,
            match_marker_pitch: false,
        }
    }
}

/// The zoom the translator's source frames take under `cfg`: 1 unless
/// [`TranslateConfig::match_marker_pitch`], else [`pitch_zoom`] (said on stderr).
pub fn source_zoom(cfg: &TranslateConfig, source: &Path, target: &Path) -> anyhow::Result<f64> {
    if !cfg.match_marker_pitch {
        return Ok(1.0);
    }
    let z = pitch_zoom(source, target)?;
    eprintln!(
        "      marker pitches matched: the source's frames magnified {z:.3} × for translation"
    );
    Ok(z)
}

#[derive(Module, Debug)]
pub struct Generators {
    /// G_s: source → target style.
    pub s2t: Generator,
    /// G_t: target → source style.
    pub t2s: Generator,
}

#[derive(Module, Debug)]
pub struct Discriminators {
    /// D_t judges target-style images, D_s source-style ones.
    pub t: Discriminator,
    pub s: Discriminator,
}

/// The reference CycleGAN's history of generated images: with probability ½ the discriminator
/// sees an older fake instead of the newest one, which steadies training.
pub struct ImagePool {
    cap: usize,
    images: Vec<Tensor<4>>,
}

impl ImagePool {
    pub fn new(cap: usize) -> Self {
        Self {
            cap,
            images: Vec::new(),
        }
    }
    /// Images `[N, 3, H, W]` (detached) in, as many out.
    pub fn query(&mut self, fakes: Tensor<4>, rng: &mut Rng) -> Tensor<4> {
        if self.cap == 0 {
            return fakes;
        }
        let n = fakes.dims()[0];
        let mut out = Vec::with_capacity(n);
        for i in 0..n {
            let img = fakes.clone().slice(i..i + 1);
            if self.images.len() < self.cap {
                self.images.push(img.clone());
                out.push(img);
            } else if rng.unit() < 0.5 {
                let j = rng.below(self.cap);
                out.push(std::mem::replace(&mut self.images[j], img));
            } else {
                out.push(img);
            }
        }
        Tensor::cat(out, 0)
    }
    pub fn len(&self) -> usize {
        self.images.len()
    }
    pub fn is_empty(&self) -> bool {
        self.images.is_empty()
    }
}

/// Losses of one iteration.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Losses {
    pub adv: f64,
    pub cycle: f64,
    pub identity: f64,
    pub disc: f64,
}

/// A CycleGAN in training.
pub struct CycleGan {
    pub cfg: TranslateConfig,
    pub gens: Generators,
    pub discs: Discriminators,
    opt_g: ModuleOptimizer,
    opt_d: ModuleOptimizer,
    pool_t: ImagePool,
    pool_s: ImagePool,
    rng: Rng,
    pub dev: Device,
}

impl CycleGan {
    pub fn new(cfg: &TranslateConfig) -> Self {
        let dev = device();
        let adam = || FusedAdam::init(cfg.beta1, 0.999);
        let (gens, discs, adev) = build_networks(&dev, Some(cfg.seed), || {
            let adev = dev.clone().autodiff();
            let gens = Generators {
                s2t: Generator::new(&cfg.shape, &adev),
                t2s: Generator::new(&cfg.shape, &adev),
            };
            let discs = Discriminators {
                t: Discriminator::new(&cfg.shape, &adev),
                s: Discriminator::new(&cfg.shape, &adev),
            };
            init_params(&gens);
            init_params(&discs);
            (gens, discs, adev)
        });
        Self {
            gens,
            discs,
            opt_g: adam(),
            opt_d: adam(),
            pool_t: ImagePool::new(cfg.pool),
            pool_s: ImagePool::new(cfg.pool),
            rng: Rng(cfg.seed ^ 0xC7C1E),
            cfg: cfg.clone(),
            dev: adev,
        }
    }

    /// One generator step then one discriminator step on a batch of real source and target
    /// images (NCHW in [-1, 1], on `self.dev`).
    pub fn step(
        &mut self,
        real_s: Tensor<4>,
        real_t: Tensor<4>,
        lr: f64,
    ) -> anyhow::Result<Losses> {
        let c = &self.cfg;
        // Generators: fool both discriminators, reconstruct both ways, leave the target alone.
        let fake_t = self.gens.s2t.forward(real_s.clone());
        let rec_s = self.gens.t2s.forward(fake_t.clone());
        let fake_s = self.gens.t2s.forward(real_t.clone());
        let rec_t = self.gens.s2t.forward(fake_s.clone());
        let adv = lsgan(self.discs.t.forward(fake_t.clone()), 1.0)
            + lsgan(self.discs.s.forward(fake_s.clone()), 1.0);
        let cycle = l1(rec_s, real_s.clone()) + l1(rec_t, real_t.clone());
        let mut loss_g =
            adv.clone().mul_scalar(c.lambda_adv) + cycle.clone().mul_scalar(c.lambda_cyc);
        let mut identity = 0.0;
        if c.lambda_idt > 0.0 {
            let idt = l1(self.gens.s2t.forward(real_t.clone()), real_t.clone())
                + l1(self.gens.t2s.forward(real_s.clone()), real_s.clone());
            identity = idt.clone().into_scalar::<f32>() as f64;
            loss_g = loss_g + idt.mul_scalar(c.lambda_cyc * c.lambda_idt);
        }
        let adv_v = adv.into_scalar::<f32>() as f64;
        let cycle_v = cycle.into_scalar::<f32>() as f64;
        let g_v = loss_g.clone().into_scalar::<f32>() as f64;
        if !g_v.is_finite() {
            bail!("the generator loss became {g_v}");
        }
        // Only the generators' parameters are stepped here; the discriminators' gradients from
        // this graph are dropped.
        let grads = GradientsParams::from_grads(loss_g.backward(), &self.gens);
        self.gens = self.opt_g.step(lr, self.gens.clone(), grads);

        // Discriminators: real → 1, (pooled) fake → 0, halved as in the reference.
        let fake_t = self.pool_t.query(fake_t.detach(), &mut self.rng);
        let fake_s = self.pool_s.query(fake_s.detach(), &mut self.rng);
        let loss_d = (lsgan(self.discs.t.forward(real_t), 1.0)
            + lsgan(self.discs.t.forward(fake_t), 0.0))
        .mul_scalar(0.5)
            + (lsgan(self.discs.s.forward(real_s), 1.0) + lsgan(self.discs.s.forward(fake_s), 0.0))
                .mul_scalar(0.5);
        let d_v = loss_d.clone().into_scalar::<f32>() as f64;
        if !d_v.is_finite() {
            bail!("the discriminator loss became {d_v}");
        }
        let grads = GradientsParams::from_grads(loss_d.backward(), &self.discs);
        self.discs = self.opt_d.step(lr, self.discs.clone(), grads);
        Ok(Losses {
            adv: adv_v,
            cycle: cycle_v,
            identity,
            disc: d_v,
        })
    }

    /// Iterations a second of [`Self::step`] on random `width × height` images (the values do
    /// not change the work), timed over `steps` after one untimed warm-up: for
    /// `rig bench train --speed` and its side-by-side with PyTorch.
    pub fn step_speed(cfg: &TranslateConfig, width: usize, height: usize, steps: usize) -> f64 {
        let mut gan = Self::new(cfg);
        let b = cfg.batch.max(1);
        let img = |gan: &Self| {
            Tensor::<4>::random(
                [b, 3, height, width],
                burn::tensor::Distribution::Uniform(-1.0, 1.0),
                &gan.dev,
            )
        };
        let steps = steps.max(1);
        let mut timed = 0.0;
        for i in 0..=steps {
            let (s, t) = (img(&gan), img(&gan));
            let t0 = std::time::Instant::now();
            // On the pool, as `translate` runs its steps.
            let _ = on_pool(|| gan.step(s, t, cfg.lr));
            if i >= 1 {
                timed += t0.elapsed().as_secs_f64();
            }
        }
        steps as f64 / timed.max(1e-9)
    }

    /// Cycle loss of a batch without training (for tests and logs).
    pub fn cycle_loss(&self, real_s: Tensor<4>, real_t: Tensor<4>) -> f64 {
        let g = self.gens.valid();
        let rs = g.t2s.forward(g.s2t.forward(real_s.clone()));
        let rt = g.s2t.forward(g.t2s.forward(real_t.clone()));
        (l1(rs, real_s) + l1(rt, real_t)).into_scalar::<f32>() as f64
    }
}

/// The translator's record of itself.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TranslatorInfo {
    pub format: String,
    pub spec: ImageSpec,
    pub config: TranslateConfig,
    pub iterations: usize,
    pub last: Losses,
}

/// What `translate` produced.
pub struct Translated {
    pub set: LabelledSet,
    pub info: TranslatorInfo,
}

/// Pick `n` frames at random across a set's trajectories.
fn pick<'a>(trajs: &'a [Trajectory], spec: &ImageSpec, n: usize, rng: &mut Rng) -> Vec<&'a [u8]> {
    let total: usize = trajs.iter().map(|t| t.frames).sum();
    (0..n)
        .map(|_| {
            let mut k = rng.below(total);
            for t in trajs {
                if k < t.frames {
                    return t.frame(k, spec);
                }
                k -= t.frames;
            }
            unreachable!("k < total")
        })
        .collect()
}

/// Train the translator on source and target images, then translate every source image.
/// Writes into `out`: `translator/` (weights and `translator.json`), `translated/` (the
/// translated source dataset with the source forces, a prepared dataset) and `samples/`
/// (I_s | Î_t | I_t grids as PNG).
pub fn translate(
    source: &LabelledSet,
    target: &UnlabelledSet,
    cfg: &TranslateConfig,
    out: &Path,
    progress: Progress,
) -> anyhow::Result<Translated> {
    on_pool(|| translate_here(source, target, cfg, out, progress))
}

fn translate_here(
    source: &LabelledSet,
    target: &UnlabelledSet,
    cfg: &TranslateConfig,
    out: &Path,
    progress: Progress,
) -> anyhow::Result<Translated> {
    let spec = source.spec;
    if target.spec != spec {
        bail!("source and target images must share one size and modality");
    }
    fits_generator(&cfg.shape, &spec)?;
    let n_s: usize = source.trajectories.iter().map(|t| t.frames).sum();
    let n_t: usize = target.trajectories.iter().map(|t| t.frames).sum();
    if n_s == 0 || n_t == 0 {
        bail!("translation needs images of both sensors ({n_s} source, {n_t} target)");
    }
    let batch = cfg.batch.max(1);
    let per_epoch = cfg
        .steps_per_epoch
        .unwrap_or(n_s.max(n_t).div_ceil(batch))
        .max(1);
    let iterations = per_epoch * cfg.epochs;
    let mut gan = CycleGan::new(cfg);
    let mut rng = Rng(cfg.seed);
    let samples_dir = out.join("samples");
    fs::create_dir_all(&samples_dir)?;
    let bar = super::progress_bar(progress == Progress::Bar, iterations as u64, "translate");
    let t0 = std::time::Instant::now();
    let mut last = Losses::default();
    let mut log = String::from("iteration,adv,cycle,identity,disc\n");
    for it in 0..iterations {
        // Constant for the first half, then linearly to zero (reference schedule).
        let half = iterations / 2;
        let lr = if it < half {
            cfg.lr
        } else {
            cfg.lr * (1.0 - (it - half) as f64 / (iterations - half).max(1) as f64)
        };
        let s = images_to_tensor(
            &pick(&source.trajectories, &spec, batch, &mut rng),
            &spec,
            &gan.dev,
        );
        let t = images_to_tensor(
            &pick(&target.trajectories, &spec, batch, &mut rng),
            &spec,
            &gan.dev,
        );
        last = gan
            .step(s, t, lr)
            .with_context(|| format!("translation stopped at iteration {}", it + 1))?;
        log.push_str(&format!(
            "{},{:.5},{:.5},{:.5},{:.5}\n",
            it + 1,
            last.adv,
            last.cycle,
            last.identity,
            last.disc
        ));
        let secs = t0.elapsed().as_secs_f64().max(1e-9);
        let status = format!(
            "cycle {:.3} adv {:.3} D {:.3} · {:.1} img/s",
            last.cycle,
            last.adv,
            last.disc,
            ((it + 1) * batch * 2) as f64 / secs
        );
        bar.set_message(status.clone());
        bar.inc(1);
        if (it + 1) % per_epoch == 0 {
            let epoch = (it + 1) / per_epoch;
            let grid = sample_grid(&gan, source, target, &mut Rng(cfg.seed ^ 77))?;
            grid.save(samples_dir.join(format!("epoch-{epoch:03}.png")))?;
            if progress == Progress::Lines {
                eprintln!(
                    "translate: epoch {epoch}/{} (iteration {}/{iterations}) {status}",
                    cfg.epochs,
                    it + 1
                );
            }
        }
    }
    bar.finish_and_clear();
    let info = TranslatorInfo {
        format: "rig-translator-1".into(),
        spec,
        config: cfg.clone(),
        iterations,
        last,
    };
    save_translator(&out.join("translator"), &gan, &info)?;
    fs::write(out.join("translate-log.csv"), log)?;

    // Î_t: every source frame through G_s, with its source force.
    let set = through(&gan.gens.s2t.valid(), source, &g_device(&gan.dev))?;
    super::data::write_prepared(&out.join("translated"), &set, "translated")?;
    Ok(Translated { set, info })
}

/// Every frame of `source` through the generator `g`, with its source force.
fn through(g: &Generator, source: &LabelledSet, dev: &Device) -> anyhow::Result<LabelledSet> {
    let spec = source.spec;
    let mut trajs = Vec::with_capacity(source.trajectories.len());
    for t in &source.trajectories {
        let mut pixels = Vec::with_capacity(t.pixels.len());
        let frames: Vec<&[u8]> = (0..t.frames).map(|i| t.frame(i, &spec)).collect();
        for chunk in frames.chunks(16) {
            for img in tensor_to_images(g.forward(images_to_tensor(chunk, &spec, dev))) {
                pixels.extend_from_slice(&img);
            }
        }
        trajs.push(Trajectory {
            id: t.id.clone(),
            indenter: t.indenter.clone(),
            pixels,
            frames: t.frames,
        });
    }
    source.with_images(spec, trajs)
}

/// Whether `spec`'s images fit a generator of `shape`: each side a multiple of 2^down (a
/// saved translator's description is read from a file, so `down` is checked, not trusted).
fn fits_generator(shape: &GanShape, spec: &ImageSpec) -> anyhow::Result<()> {
    let m = u32::try_from(shape.down)
        .ok()
        .filter(|&d| d <= 8)
        .map(|d| 1u32 << d)
        .with_context(|| {
            format!(
                "a generator with {} downsamplings: at most 8 are supported",
                shape.down
            )
        })?;
    if !spec.width.is_multiple_of(m) || !spec.height.is_multiple_of(m) {
        bail!(
            "image width and height must be multiples of {m} for the generator's {} \
             downsamplings (got {}×{})",
            shape.down,
            spec.width,
            spec.height
        );
    }
    Ok(())
}

/// The source images of `source` in the target's style, through the translator that
/// [`translate`] saved in `tdir` (its `translator/` directory): for source frames it was not
/// trained on, e.g. the unseen indenters'. The set must have the translator's image spec.
pub fn apply_translator(tdir: &Path, source: &LabelledSet) -> anyhow::Result<LabelledSet> {
    let info: TranslatorInfo =
        serde_json::from_slice(&fs::read(tdir.join(INFO)).with_context(|| {
            format!(
                "no translator in {} (run the translation first)",
                tdir.display()
            )
        })?)
        .with_context(|| format!("{} is damaged", tdir.join(INFO).display()))?;
    if info.spec != source.spec {
        bail!(
            "the translator in {} takes {}x{} {} images, the data are {}x{} {}",
            tdir.display(),
            info.spec.width,
            info.spec.height,
            info.spec.modality.name(),
            source.spec.width,
            source.spec.height,
            source.spec.modality.name()
        );
    }
    fits_generator(&info.config.shape, &info.spec)?;
    let dev = g_device(&device());
    let mut g = Generator::new(&info.config.shape, &dev);
    g.load_from(&mut SafetensorsStore::from_file(
        tdir.join("g_s2t.safetensors"),
    ))
    .map_err(|e| {
        anyhow::anyhow!(
            "cannot read {}: {e:?}",
            tdir.join("g_s2t.safetensors").display()
        )
    })?;
    through(&g, source, &dev)
}

/// Writes the translator into `tdir`: its four networks and description, replaced as one
/// set, so a crash leaves the previous translator whole, never networks of two trainings.
fn save_translator(tdir: &Path, gan: &CycleGan, info: &TranslatorInfo) -> anyhow::Result<()> {
    fn save(dir: &Path, name: &str, net: &impl ModuleSnapshot) -> anyhow::Result<()> {
        let path = dir.join(format!("{name}.safetensors"));
        net.save_into(&mut SafetensorsStore::from_file(path))
            .map_err(|e| anyhow::anyhow!("cannot write {name}: {e:?}"))
    }
    fs::create_dir_all(tdir)?;
    crate::durable::FileSet::new(tdir, INFO)
        .replace(|dir| {
            save(dir, "g_s2t", &gan.gens.s2t)?;
            save(dir, "g_t2s", &gan.gens.t2s)?;
            save(dir, "d_t", &gan.discs.t)?;
            save(dir, "d_s", &gan.discs.s)?;
            fs::write(dir.join(INFO), serde_json::to_vec_pretty(info)?)?;
            Ok(())
        })
        .with_context(|| format!("cannot write the translator into {}", tdir.display()))
}

/// The device without autodiff, for inference.
fn g_device(dev: &Device) -> Device {
    dev.clone().inner()
}

/// Pastes the `w × h` RGB frame `px` into `grid` at column `col`, row `row` of frames.
pub(super) fn paste_frame(
    grid: &mut image::RgbImage,
    px: &[u8],
    (w, h): (u32, u32),
    col: usize,
    row: usize,
) -> anyhow::Result<()> {
    let img = image::RgbImage::from_raw(w, h, px.to_vec()).context("frame size")?;
    image::imageops::replace(grid, &img, (col as u32 * w) as i64, (row as u32 * h) as i64);
    Ok(())
}

/// Rows of I_s | Î_t | I_t (a random source frame, its translation, a random target frame).
fn sample_grid(
    gan: &CycleGan,
    source: &LabelledSet,
    target: &UnlabelledSet,
    rng: &mut Rng,
) -> anyhow::Result<image::RgbImage> {
    let spec = source.spec;
    let rows = 4;
    let s = pick(&source.trajectories, &spec, rows, rng);
    let t = pick(&target.trajectories, &spec, rows, rng);
    let plain = g_device(&gan.dev);
    let g = gan.gens.s2t.valid();
    let fake = tensor_to_images(g.forward(images_to_tensor(&s, &spec, &plain)));
    let (w, h) = (spec.width, spec.height);
    let mut grid = image::RgbImage::new(w * 3, h * rows as u32);
    for r in 0..rows {
        for (col, px) in [s[r], fake[r].as_slice(), t[r]].into_iter().enumerate() {
            paste_frame(&mut grid, px, (w, h), col, r)?;
        }
    }
    // Small network inputs are enlarged (nearest neighbour) so the grid can be looked at.
    let k = (96 / h.max(1)).max(1);
    if k > 1 {
        grid = image::imageops::resize(
            &grid,
            grid.width() * k,
            grid.height() * k,
            image::imageops::FilterType::Nearest,
        );
    }
    Ok(grid)
}

#[cfg(test)]
mod tests {
    use burn::module::{ModuleVisitor, Param};

    use super::*;

    fn params<M: Module>(m: &M) -> Vec<f32> {
        struct Collect(Vec<f32>);
        impl ModuleVisitor for Collect {
            fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
                self.0.extend(
                    p.val()
                        .into_data()
                        .convert::<f32>()
                        .try_to_vec::<f32>()
                        .unwrap(),
                );
            }
        }
        let mut c = Collect(Vec::new());
        m.visit(&mut c);
        c.0
    }

    #[test]
    fn image_sides_must_divide_by_the_generators_downsamplings_and_a_bad_count_is_an_error() {
        let spec = |width, height| ImageSpec {
            width,
            height,
            modality: crate::train::modality::Modality::RgbMarker,
        };
        let shape = |down| GanShape {
            ngf: 4,
            ndf: 4,
            res_blocks: 1,
            disc_layers: 2,
            down,
        };
        assert!(fits_generator(&shape(3), &spec(32, 24)).is_ok());
        assert!(fits_generator(&shape(0), &spec(33, 25)).is_ok());
        let e = fits_generator(&shape(4), &spec(32, 24)).unwrap_err();
        assert!(e.to_string().contains("multiples of 16"), "{e}");
        // A description read from a damaged file: an error, not an overflowing shift.
        for down in [9, 64, usize::MAX] {
            let e = fits_generator(&shape(down), &spec(32, 24)).unwrap_err();
            assert!(e.to_string().contains("at most 8"), "{e}");
        }
    }

    #[test]
    fn the_translator_is_written_whole_over_a_crashed_write() {
        let cfg = TranslateConfig {
            shape: GanShape {
                ngf: 4,
                ndf: 4,
                res_blocks: 1,
                disc_layers: 2,
                down: 2,
            },
            ..TranslateConfig::default()
        };
        let gan = CycleGan::new(&cfg);
        let info = TranslatorInfo {
            format: "rig-translator-1".into(),
            spec: ImageSpec {
                width: 16,
                height: 16,
                modality: crate::train::modality::Modality::RgbMarker,
            },
            config: cfg.clone(),
            iterations: 3,
            last: Losses::default(),
        };
        let tmp = tempfile::tempdir().unwrap();
        let tdir = tmp.path().join("translator");
        // A write a crash cut short: a staging directory with a torn generator.
        let staging = tdir.join(crate::durable::FileSet::STAGING);
        fs::create_dir_all(&staging).unwrap();
        fs::write(staging.join("g_s2t.safetensors"), b"torn").unwrap();

        save_translator(&tdir, &gan, &info).unwrap();
        let mut names: Vec<String> = fs::read_dir(&tdir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        names.sort();
        assert_eq!(
            names,
            [
                "d_s.safetensors",
                "d_t.safetensors",
                "g_s2t.safetensors",
                "g_t2s.safetensors",
                INFO
            ]
        );
        let read: TranslatorInfo =
            serde_json::from_slice(&fs::read(tdir.join(INFO)).unwrap()).unwrap();
        assert_eq!(read, info);
        let mut g = Generator::new(&cfg.shape, &gan.dev);
        g.load_from(&mut SafetensorsStore::from_file(
            tdir.join("g_s2t.safetensors"),
        ))
        .unwrap();
        let want = params(&gan.gens.s2t);
        assert!(!want.is_empty());
        assert_eq!(params(&g), want);
        assert_ne!(
            params(&gan.gens.t2s),
            want,
            "two generators with the same weights"
        );
    }
}
