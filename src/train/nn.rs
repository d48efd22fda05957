//! The networks of the TransForce trainer, in burn 0.22 (the backend is chosen at run time by the
//! [`Device`]: flex on the CPU, CUDA with the `gpu` feature).
//!
//! - CycleGAN generator: ResNet blocks with instance norm and reflection padding (Zhu et al.,
//!   "Unpaired Image-to-Image Translation using Cycle-Consistent Adversarial Networks", 2017:
//!   c7s1-k, d2k, d4k, R4k × n, u2k, uk, c7s1-3).
//! - PatchGAN discriminator (the same paper's 70×70 design: C64-C128-C256-C512, 4×4 kernels,
//!   LeakyReLU 0.2, no norm on the first layer).
//! - The force model: a ResNet encoder (He et al. 2016; depth 18, 34 or 50) → 64-d embedding per
//!   frame → LSTM(64) → MLP with a sigmoid (TransForce), or the MLP straight on the embedding
//!   (the `nolstm` control).

use burn::module::Module;
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig, MaxPool2d, MaxPool2dConfig};
use burn::nn::{
    BatchNorm, BatchNormConfig, InstanceNorm, InstanceNormConfig, Linear, LinearConfig, Lstm,
    LstmConfig, PaddingConfig2d,
};
use burn::tensor::activation::{relu, sigmoid, tanh};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};

mod act;
mod adam;
mod conv;
mod deconv;
mod fast;
mod kernels;
mod lanes;
mod norm;
mod pad;
mod simd;
mod unroll;
mod wino;
pub use act::leaky_relu;
pub use adam::FusedAdam;
pub use conv::conv2d;
pub use deconv::conv_transpose2d;
pub use fast::FastEncoder;
pub use norm::{batch_norm, batch_norm_relu, instance_norm};
pub use pad::reflect_pad;

/// Runs `work` on a worker thread of rayon's pool, the calling thread waiting for it: for
/// training loops. A training step is a chain of operations, most shared out over the pool and
/// joined. Run from outside the pool, each one wakes the sleeping workers and waits for them,
/// and between them the calling thread is one more runnable thread than there are cores (the
/// workers yield a while before they sleep). Run on a worker, the step starts each operation
/// where it already is and shares it with one fewer wake-up. On 2 cores (2026-11-30, AMD EPYC)
/// a CycleGAN step of the protocol's shape ran 20 % faster so, and at 1 thread the protocol's
/// force models 6-24 % faster (docs/experiments.md).
pub fn on_pool<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| work())
}

fn conv(c_in: usize, c_out: usize, k: usize, stride: usize, pad: usize, dev: &Device) -> Conv2d {
    Conv2dConfig::new([c_in, c_out], [k, k])
        .with_stride([stride, stride])
        .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
        .init(dev)
}

/// Instance norm without affine parameters, as in the reference CycleGAN.
fn inorm(c: usize, dev: &Device) -> InstanceNorm {
    InstanceNormConfig::new(c).with_affine(false).init(dev)
}

// ---------------------------------------------------------------------------------------------
// CycleGAN

/// Size of a CycleGAN. The paper's defaults are `ngf = ndf = 64`, 9 residual blocks at 256 px
/// and 3 discriminator layers; small images on a CPU want far less.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GanShape {
    pub ngf: usize,
    pub ndf: usize,
    pub res_blocks: usize,
    pub disc_layers: usize,
    /// The generator's stride-2 downsamplings before its residual blocks (and as many
    /// upsamplings after them). The reference has 2, made for 256 px images, whose residual
    /// blocks then work on 64 × 64 maps. On a 32 × 24 image two leave an 8 × 6 map, coarser than
    /// the markers' 3 px pitch, so the generator has to redraw every marker from a summary; one
    /// keeps a 16 × 12 map. Image sides must be multiples of 2^down. Translators saved before
    /// the field existed had 2.
    #[serde(default = "reference_downsamplings")]
    pub down: usize,
}

fn reference_downsamplings() -> usize {
    2
}

#[derive(Module, Debug)]
pub struct ResBlock {
    conv1: Conv2d,
    norm1: InstanceNorm,
    conv2: Conv2d,
    norm2: InstanceNorm,
}

impl ResBlock {
    fn new(c: usize, dev: &Device) -> Self {
        Self {
            conv1: conv(c, c, 3, 1, 0, dev),
            norm1: inorm(c, dev),
            conv2: conv(c, c, 3, 1, 0, dev),
            norm2: inorm(c, dev),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let y = conv2d(&self.conv1, reflect_pad(x.clone(), 1));
        let y = instance_norm(&self.norm1, y, None, true);
        let y = conv2d(&self.conv2, reflect_pad(y, 1));
        instance_norm(&self.norm2, y, Some(x), false)
    }
}

#[derive(Module, Debug)]
pub struct DownBlock {
    conv: Conv2d,
    norm: InstanceNorm,
}

#[derive(Module, Debug)]
pub struct UpBlock {
    conv: ConvTranspose2d,
    norm: InstanceNorm,
}

/// ResNet-block generator: RGB in [-1, 1] to RGB in [-1, 1], same size (height and width must be
/// multiples of 2^[`GanShape::down`]).
#[derive(Module, Debug)]
pub struct Generator {
    stem: Conv2d,
    stem_norm: InstanceNorm,
    down: Vec<DownBlock>,
    blocks: Vec<ResBlock>,
    up: Vec<UpBlock>,
    head: Conv2d,
}

impl Generator {
    pub fn new(shape: &GanShape, dev: &Device) -> Self {
        let k = shape.ngf.max(1);
        // Channels double at each downsampling and halve again on the way up.
        let widths: Vec<usize> = (0..=shape.down).map(|i| k << i).collect();
        let down = widths
            .windows(2)
            .map(|w| DownBlock {
                conv: conv(w[0], w[1], 3, 2, 1, dev),
                norm: inorm(w[1], dev),
            })
            .collect();
        let up = widths
            .windows(2)
            .rev()
            .map(|w| (w[1], w[0]))
            .map(|(a, b)| UpBlock {
                conv: ConvTranspose2dConfig::new([a, b], [3, 3])
                    .with_stride([2, 2])
                    .with_padding([1, 1])
                    .with_padding_out([1, 1])
                    .init(dev),
                norm: inorm(b, dev),
            })
            .collect();
        Self {
            stem: conv(3, k, 7, 1, 0, dev),
            stem_norm: inorm(k, dev),
            down,
            blocks: (0..shape.res_blocks)
                .map(|_| ResBlock::new(widths[shape.down], dev))
                .collect(),
            up,
            head: conv(k, 3, 7, 1, 0, dev),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut x = instance_norm(
            &self.stem_norm,
            conv2d(&self.stem, reflect_pad(x, 3)),
            None,
            true,
        );
        for d in &self.down {
            x = instance_norm(&d.norm, conv2d(&d.conv, x), None, true);
        }
        for b in &self.blocks {
            x = b.forward(x);
        }
        for u in &self.up {
            x = instance_norm(&u.norm, conv_transpose2d(&u.conv, x), None, true);
        }
        tanh(conv2d(&self.head, reflect_pad(x, 3)))
    }
}

#[derive(Module, Debug)]
pub struct DiscLayer {
    conv: Conv2d,
    norm: Option<InstanceNorm>,
}

/// PatchGAN discriminator: one real/fake score per overlapping patch (no sigmoid: LSGAN).
#[derive(Module, Debug)]
pub struct Discriminator {
    layers: Vec<DiscLayer>,
    head: Conv2d,
}

impl Discriminator {
    pub fn new(shape: &GanShape, dev: &Device) -> Self {
        let ndf = shape.ndf.max(1);
        let n = shape.disc_layers.max(1);
        let mut layers = vec![DiscLayer {
            conv: conv(3, ndf, 4, 2, 1, dev),
            norm: None,
        }];
        let mut c = ndf;
        for i in 1..=n {
            let next = ndf * (1 << i.min(3));
            let stride = if i == n { 1 } else { 2 };
            layers.push(DiscLayer {
                conv: conv(c, next, 4, stride, 1, dev),
                norm: Some(inorm(next, dev)),
            });
            c = next;
        }
        Self {
            layers,
            head: conv(c, 1, 4, 1, 1, dev),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let mut x = x;
        for l in &self.layers {
            x = conv2d(&l.conv, x);
            if let Some(n) = &l.norm {
                x = instance_norm(n, x, None, false);
            }
            x = leaky_relu(x, 0.2);
        }
        conv2d(&self.head, x)
    }
}

// ---------------------------------------------------------------------------------------------
// Force model

/// The encoder's ResNet depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Depth {
    #[serde(rename = "18")]
    R18,
    #[serde(rename = "34")]
    R34,
    #[serde(rename = "50")]
    R50,
}

impl Depth {
    pub const ALL: [Depth; 3] = [Depth::R18, Depth::R34, Depth::R50];

    /// Residual blocks per stage (He et al. 2016, Table 1).
    pub fn blocks(self) -> [usize; 4] {
        match self {
            Depth::R18 => [2, 2, 2, 2],
            Depth::R34 | Depth::R50 => [3, 4, 6, 3],
        }
    }

    /// ResNet-50 uses bottleneck blocks (1×1, 3×3, 1×1 with ×4 expansion).
    pub fn bottleneck(self) -> bool {
        self == Depth::R50
    }

    pub fn number(self) -> u32 {
        match self {
            Depth::R18 => 18,
            Depth::R34 => 34,
            Depth::R50 => 50,
        }
    }
}

impl std::str::FromStr for Depth {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim().trim_start_matches("resnet") {
            "18" => Ok(Depth::R18),
            "34" => Ok(Depth::R34),
            "50" => Ok(Depth::R50),
            other => Err(format!("encoder depth {other:?}: use 18, 34 or 50")),
        }
    }
}

impl std::fmt::Display for Depth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.number())
    }
}

/// Shape of the force model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForceShape {
    pub depth: Depth,
    /// Channels of the first stage (64 in the paper's ResNet; stages double it).
    pub width: usize,
    /// Per-frame embedding and LSTM hidden size (64 in the paper).
    pub embed: usize,
    /// `false`: the `nolstm` control, embedding straight into the MLP.
    pub lstm: bool,
    /// ImageNet stem (7×7 stride 2 + max pool) when the images are large enough; a 3×3 stride-1
    /// stem for small images, which would otherwise shrink to nothing.
    pub imagenet_stem: bool,
    /// The LSTM's output is added to its input (a residual connection), so the MLP sees each
    /// frame's own embedding from the first step and the LSTM learns what history adds to it.
    /// Without it the plain LSTM (the paper's) starts from a small, gated signal and trained
    /// about half as fast as its no-LSTM control (quick demo: loss 0.10 against 0.06 after
    /// 60 epochs, where the residual one reached 0.06). `false` in models of format 1.
    #[serde(default)]
    pub residual: bool,
    /// The encoder's head: `None` is ResNet's global average pool; `Some([h, w])` flattens the
    /// last `h × w` feature map instead. Global pooling discards where things are, and on small
    /// images where the contact sits (how far the indenter has slid) is the visible cue for
    /// shear; so small inputs keep the map.
    #[serde(default)]
    pub spatial: Option<[usize; 2]>,
}

impl ForceShape {
    /// The last feature map's size for an input of `h × w`.
    pub fn final_map(imagenet_stem: bool, h: usize, w: usize) -> [usize; 2] {
        let half = |v: usize| v.div_ceil(2);
        let (mut h, mut w) = if imagenet_stem {
            (half(half(h)), half(half(w)))
        } else {
            (h, w)
        };
        for _ in 0..3 {
            h = half(h);
            w = half(w);
        }
        [h, w]
    }
}

#[derive(Module, Debug)]
pub struct ResUnit {
    conv1: Conv2d,
    bn1: BatchNorm,
    conv2: Conv2d,
    bn2: BatchNorm,
    conv3: Option<Conv2d>,
    bn3: Option<BatchNorm>,
    short_conv: Option<Conv2d>,
    short_bn: Option<BatchNorm>,
}

fn bn(c: usize, dev: &Device) -> BatchNorm {
    BatchNormConfig::new(c).init(dev)
}

impl ResUnit {
    fn new(c_in: usize, planes: usize, stride: usize, bottleneck: bool, dev: &Device) -> Self {
        let expansion = if bottleneck { 4 } else { 1 };
        let c_out = planes * expansion;
        let (conv1, conv2, conv3) = if bottleneck {
            (
                conv(c_in, planes, 1, 1, 0, dev),
                conv(planes, planes, 3, stride, 1, dev),
                Some(conv(planes, c_out, 1, 1, 0, dev)),
            )
        } else {
            (
                conv(c_in, planes, 3, stride, 1, dev),
                conv(planes, planes, 3, 1, 1, dev),
                None,
            )
        };
        let projection = stride != 1 || c_in != c_out;
        Self {
            conv1,
            bn1: bn(planes, dev),
            conv2,
            bn2: bn(planes, dev),
            bn3: conv3.as_ref().map(|_| bn(c_out, dev)),
            conv3,
            short_conv: projection.then(|| conv(c_in, c_out, 1, stride, 0, dev)),
            short_bn: projection.then(|| bn(c_out, dev)),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<4> {
        let shortcut = match (&self.short_conv, &self.short_bn) {
            (Some(c), Some(b)) => batch_norm(b, conv2d(c, x.clone())),
            _ => x.clone(),
        };
        let y = batch_norm_relu(&self.bn1, conv2d(&self.conv1, x), None);
        let y = conv2d(&self.conv2, y);
        match (&self.conv3, &self.bn3) {
            (Some(c3), Some(b3)) => {
                let y = batch_norm_relu(&self.bn2, y, None);
                batch_norm_relu(b3, conv2d(c3, y), Some(shortcut))
            }
            _ => batch_norm_relu(&self.bn2, y, Some(shortcut)),
        }
    }
}

/// ResNet encoder: image → `embed`-d vector.
#[derive(Module, Debug)]
pub struct Encoder {
    stem: Conv2d,
    stem_bn: BatchNorm,
    pool: Option<MaxPool2d>,
    units: Vec<ResUnit>,
    gap: AdaptiveAvgPool2d,
    embed: Linear,
}

impl Encoder {
    pub fn new(shape: &ForceShape, dev: &Device) -> Self {
        let w = shape.width.max(1);
        let (stem, pool) = if shape.imagenet_stem {
            (
                conv(3, w, 7, 2, 3, dev),
                Some(
                    MaxPool2dConfig::new([3, 3])
                        .with_strides([2, 2])
                        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                        .init(),
                ),
            )
        } else {
            (conv(3, w, 3, 1, 1, dev), None)
        };
        let bottleneck = shape.depth.bottleneck();
        let expansion = if bottleneck { 4 } else { 1 };
        let mut units = Vec::new();
        let mut c_in = w;
        for (stage, &n) in shape.depth.blocks().iter().enumerate() {
            let planes = w << stage;
            for i in 0..n {
                let stride = if stage > 0 && i == 0 { 2 } else { 1 };
                units.push(ResUnit::new(c_in, planes, stride, bottleneck, dev));
                c_in = planes * expansion;
            }
        }
        let cells = shape.spatial.map_or(1, |[h, w]| h * w);
        Self {
            stem,
            stem_bn: bn(w, dev),
            pool,
            units,
            gap: AdaptiveAvgPool2dConfig::new(shape.spatial.unwrap_or([1, 1])).init(),
            embed: LinearConfig::new(c_in * cells, shape.embed).init(dev),
        }
    }

    /// `[N, 3, H, W]` → `[N, embed]`.
    pub fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        let mut x = batch_norm_relu(&self.stem_bn, conv2d(&self.stem, x), None);
        if let Some(p) = &self.pool {
            x = p.forward(x);
        }
        for u in &self.units {
            x = u.forward(x);
        }
        let pooled = self.gap.forward(x);
        let [n, c, h, w] = pooled.dims();
        self.embed.forward(pooled.reshape([n, c * h * w]))
    }
}

/// Encoder + LSTM (or not) + MLP with a sigmoid: a force per frame, in 0..1 of the force range.
#[derive(Module, Debug)]
pub struct ForceNet {
    encoder: Encoder,
    lstm: Option<Lstm>,
    fc1: Linear,
    fc2: Linear,
    /// [`ForceShape::residual`].
    residual: bool,
}

impl ForceNet {
    pub fn new(shape: &ForceShape, dev: &Device) -> Self {
        Self {
            encoder: Encoder::new(shape, dev),
            lstm: shape
                .lstm
                .then(|| LstmConfig::new(shape.embed, shape.embed, true).init(dev)),
            fc1: LinearConfig::new(shape.embed, shape.embed).init(dev),
            fc2: LinearConfig::new(shape.embed, 3).init(dev),
            residual: shape.residual,
        }
    }

    /// `[B, T, 3, H, W]` → `[B, T, 3]` in 0..1: [`Self::encode`] every frame, then
    /// [`Self::head`] over each sequence.
    pub fn forward(&self, x: Tensor<5>) -> Tensor<3> {
        let [b, t, c, h, w] = x.dims();
        let e = self.encode(x.reshape([b * t, c, h, w]));
        let d = e.dims()[1];
        self.head(e.reshape([b, t, d]))
    }

    /// The encoder alone: `[N, 3, H, W]` → `[N, embed]`, each frame on its own (in inference
    /// the batch norms use their running statistics, so a frame's embedding does not depend on
    /// the others in the batch). `rig predict` computes it once per frame and caches it.
    pub fn encode(&self, x: Tensor<4>) -> Tensor<2> {
        self.encoder.forward(x)
    }

    /// The encoder compiled for CPU inference (see [`FastEncoder`]), `None` if it has a layer
    /// that form does not cover.
    pub fn fast_encoder(&self) -> Option<FastEncoder> {
        FastEncoder::new(&self.encoder)
    }

    /// Everything after the encoder: embeddings `[B, T, embed]` → forces `[B, T, 3]` in 0..1.
    /// The LSTM starts from a zero state at the sequence's first frame and is causal: position
    /// k depends on positions 0..=k only.
    pub fn head(&self, mut s: Tensor<3>) -> Tensor<3> {
        if let Some(lstm) = &self.lstm {
            s = if self.residual {
                lstm.forward(s.clone(), None).0 + s
            } else {
                lstm.forward(s, None).0
            };
        }
        let y = self.fc2.forward(relu(self.fc1.forward(s)));
        sigmoid(y)
    }
}

/// The γ-weighted L1 loss of TransForce: Σ_i γ^(T−i) · |F^i − F̂^i|_1 over the T frames of a
/// sequence (i = 1..T, so the last frame weighs 1), averaged over the batch.
/// `pred` and `truth` are `[B, T, 3]`.
pub fn gamma_l1(pred: Tensor<3>, truth: Tensor<3>, gamma: f64) -> Tensor<1> {
    let [b, t, _] = pred.dims();
    let weights: Vec<f32> = (1..=t).map(|i| gamma.powi((t - i) as i32) as f32).collect();
    let w = Tensor::<1>::from_floats(weights.as_slice(), &pred.device()).reshape([1, t, 1]);
    let per = (pred - truth).abs() * w;
    per.sum().div_scalar(b.max(1) as f64).reshape([1])
}

/// Least-squares GAN loss: mean (D(x) − target)².
pub fn lsgan(scores: Tensor<4>, target: f32) -> Tensor<1> {
    (scores - target).powi_scalar(2).mean().reshape([1])
}

/// Mean absolute difference.
pub fn l1(a: Tensor<4>, b: Tensor<4>) -> Tensor<1> {
    (a - b).abs().mean().reshape([1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::module::Param;
    use burn::tensor::TensorData;

    fn dev() -> Device {
        Device::flex()
    }

    pub(super) fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap()
    }

    /// `|a − b| ≤ 1e-4 · max|b|` elementwise, for our kernels (`a`) against burn's (`b`): both
    /// compute the same sums of at most a few hundred O(1) terms in another order (ours partly
    /// in f64), so they differ by f32 rounding of terms of the size of the largest entry; an
    /// error in indexing (a misplaced convolution tap, a wrong channel) moves whole entries.
    pub(super) fn close_to_largest(what: &str, a: &[f32], b: &[f32]) {
        assert_eq!(a.len(), b.len(), "{what}: lengths");
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-6);
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-4 * scale,
                "{what}[{i}]: {x} against burn's {y} (largest {scale})"
            );
        }
    }

    fn close(a: &[f32], b: &[f32], tol: f32) {
        assert_eq!(a.len(), b.len());
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= tol, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn reflection_padding_mirrors_without_repeating_the_edge() {
        let x = Tensor::<4>::from_data(
            TensorData::new(vec![1f32, 2., 3., 4., 5., 6.], [1, 1, 2, 3]),
            &dev(),
        );
        let y = reflect_pad(x, 1);
        assert_eq!(y.dims(), [1, 1, 4, 5]);
        // Row −1 mirrors row 1, row 2 mirrors row 0; column −1 mirrors column 1, column 3
        // mirrors column 1.
        #[rustfmt::skip]
        let want = [
            5., 4., 5., 6., 5.,
            2., 1., 2., 3., 2.,
            5., 4., 5., 6., 5.,
            2., 1., 2., 3., 2.,
        ];
        close(&values(y), &want, 0.0);
    }

    #[test]
    fn instance_norm_normalises_each_channel_of_each_image() {
        let norm = inorm(2, &dev());
        // Channel 0: 1, 2, 3, 4 (mean 2.5, biased variance 1.25); channel 1: constant 7.
        let x = Tensor::<4>::from_data(
            TensorData::new(vec![1f32, 2., 3., 4., 7., 7., 7., 7.], [1, 2, 2, 2]),
            &dev(),
        );
        let y = values(norm.forward(x));
        // (x − 2.5) / sqrt(1.25 + 1e-5)
        close(
            &y[..4],
            &[-1.341_635_4, -0.447_211_8, 0.447_211_8, 1.341_635_4],
            1e-5,
        );
        // A constant channel normalises to 0 (variance 0, kept finite by ε).
        close(&y[4..], &[0.0; 4], 1e-6);
    }

    fn set_linear(l: &mut Linear, w: f32, b: f32) {
        l.weight = Param::from_tensor(Tensor::from_data(TensorData::new(vec![w], [1, 1]), &dev()));
        l.bias = Some(Param::from_tensor(Tensor::from_data(
            TensorData::new(vec![b], [1]),
            &dev(),
        )));
    }

    #[test]
    fn lstm_matches_the_hand_computed_recurrence() {
        let mut lstm = LstmConfig::new(1, 1, true).init(&dev());
        let mut gates = vec![
            &mut lstm.input_gate,
            &mut lstm.output_gate,
            &mut lstm.cell_gate,
        ];
        gates.push(lstm.forget_gate.as_mut().expect("uncoupled forget gate"));
        for g in gates {
            set_linear(&mut g.input_transform, 0.5, 0.1);
            set_linear(&mut g.hidden_transform, -0.25, 0.0);
        }
        // Every gate's pre-activation is a = 0.5 x + 0.1 − 0.25 h; i = f = o = σ(a), g = tanh(a),
        // c' = f c + i g, h' = o tanh(c'). From h = c = 0 with x = 1 then −2 (computed by hand
        // in double precision):
        //   step 1: c = 0.346749440, h = 0.215319686
        //   step 2: c = -0.109789495, h = -0.030412038
        let x = Tensor::<3>::from_data(TensorData::new(vec![1f32, -2.0], [1, 2, 1]), &dev());
        let (out, state) = lstm.forward(x, None);
        close(&values(out), &[0.215_319_7, -0.030_412_04], 1e-6);
        close(&values(state.cell), &[-0.109_789_5], 1e-6);
    }

    #[test]
    fn gamma_weighted_l1_weighs_the_last_frame_most() {
        let pred = Tensor::<3>::zeros([2, 3, 3], &dev());
        let one = [1f32, 0., 0., 0., 2., 0., 0., 0., -3.];
        let truth = Tensor::<3>::from_data(TensorData::new([one, one].concat(), [2, 3, 3]), &dev());
        // γ = 0.8, T = 3: weights 0.64, 0.8, 1 → 0.64·1 + 0.8·2 + 1·3 = 5.24 per sequence; the
        // batch mean of two equal sequences is the same.
        let l = values(gamma_l1(pred.clone(), truth.clone(), 0.8));
        close(&l, &[5.24], 1e-5);
        // γ = 1 is the plain summed L1: 1 + 2 + 3.
        close(&values(gamma_l1(pred, truth, 1.0)), &[6.0], 1e-5);
    }

    #[test]
    fn a_gan_shape_saved_before_down_existed_reads_as_the_reference_two() {
        let old = r#"{"ngf":8,"ndf":8,"res_blocks":2,"disc_layers":2}"#;
        let shape: GanShape = serde_json::from_str(old).unwrap();
        assert_eq!(shape.down, 2);
        let new: GanShape =
            serde_json::from_str(&serde_json::to_string(&GanShape { down: 1, ..shape }).unwrap())
                .unwrap();
        assert_eq!(new.down, 1);
    }

    #[test]
    fn networks_keep_their_shapes() {
        let d = dev();
        let gan = GanShape {
            ngf: 4,
            ndf: 4,
            res_blocks: 1,
            disc_layers: 2,
            down: 2,
        };
        let x = Tensor::<4>::zeros([2, 3, 24, 32], &d);
        for down in 0..=3 {
            let g = Generator::new(&GanShape { down, ..gan }, &d);
            assert_eq!(g.forward(x.clone()).dims(), [2, 3, 24, 32], "down {down}");
            // The residual blocks work at 1/2^down of the image, on ngf · 2^down channels.
            let c = 4 << down;
            assert_eq!(g.blocks[0].conv1.weight.dims(), [c, c, 3, 3], "down {down}");
            assert_eq!((g.down.len(), g.up.len()), (down, down));
        }
        let score = Discriminator::new(&gan, &d).forward(x).dims();
        assert_eq!(score[..2], [2, 1]);
        for depth in Depth::ALL {
            for lstm in [true, false] {
                let shape = ForceShape {
                    depth,
                    width: 4,
                    embed: 8,
                    lstm,
                    residual: lstm,
                    imagenet_stem: false,
                    // Both heads: the flattened map and the global pool.
                    spatial: lstm.then(|| ForceShape::final_map(false, 24, 32)),
                };
                let y = ForceNet::new(&shape, &d).forward(Tensor::zeros([2, 3, 3, 24, 32], &d));
                assert_eq!(y.dims(), [2, 3, 3]);
                assert!(values(y).iter().all(|v| (0.0..=1.0).contains(v)));
            }
        }
    }
}
