//! The force model's encoder compiled for CPU inference: what `rig predict` and `rig eval` run
//! per frame on the CPU.
//!
//! Same function as [`Encoder::forward`] in inference mode (batch norms on their running
//! statistics), computed differently:
//!
//! - **Batch norm folded into the convolution before it.** In inference a batch norm is an
//!   affine map per channel, `y = γ (x − μ) / √(σ² + ε) + β`, so with `x = W * v + b` it is the
//!   convolution with weights `W · s` and bias `(b − μ) s + β`, `s = γ / √(σ² + ε)` (Ioffe and
//!   Szegedy 2015, eq. in Alg. 2). One pass over the activations instead of three.
//! - **Channels-last activations throughout.** A convolution is then a matrix product
//!   `[pixels, k·k·c_in] × [k·k·c_in, c_out]` whose left side (im2col) is built from runs of
//!   `c_in` contiguous floats; a 1 × 1 convolution of stride 1 multiplies the activation
//!   itself, and a 3 × 3 one of stride 1 needs no im2col at all (three products straight on a
//!   zero-bordered copy of the input, see `Conv::run_3x3`). The weights are laid out for that
//!   product once, at load.
//! - **Fused epilogue.** Bias, residual and ReLU in the pass that reads the product.
//! - **Buffers reused** across layers and frames of one call.
//!
//! The products run on the `gemm` crate (the kernels burn's flex backend uses too), on one
//! thread for a single frame so that latency is not spent waking a pool, on all of them for a
//! batch. A test checks the result against burn's forward on several shapes.

use burn::module::Param;
use burn::nn::BatchNorm;
use burn::nn::conv::Conv2d;
use burn::tensor::Tensor;
use gemm::Parallelism;

use super::{Encoder, ForceNet, ResUnit};
use crate::cpu::{matmul, symmetric, taps_major, three_rows};

impl ForceNet {
    /// The encoder compiled for CPU inference (see [`FastEncoder`]), `None` if it has a layer
    /// that form does not cover.
    pub fn fast_encoder(&self) -> Option<FastEncoder> {
        FastEncoder::new(&self.encoder)
    }
}

/// One convolution with its batch norm folded in.
#[derive(Debug, Clone)]
struct Conv {
    k: usize,
    stride: usize,
    pad: usize,
    c_in: usize,
    c_out: usize,
    /// `[k·k·c_in, c_out]`, row-major, rows in (ky, kx, ci) order.
    w: Vec<f32>,
    b: Vec<f32>,
}

#[derive(Debug, Clone)]
struct Unit {
    conv1: Conv,
    conv2: Conv,
    conv3: Option<Conv>,
    short: Option<Conv>,
}

/// A 3 × 3 (or any) max pool, padding excluded from the maximum.
#[derive(Debug, Clone, Copy)]
struct MaxPool {
    k: usize,
    stride: usize,
    pad: usize,
}

/// [`Encoder`] for CPU inference; see the module docs.
#[derive(Debug, Clone)]
pub struct FastEncoder {
    stem: Conv,
    pool: Option<MaxPool>,
    units: Vec<Unit>,
    /// The adaptive average pool's output, `[h, w]`.
    cells: [usize; 2],
    /// `[d_in, d_out]`, row-major (burn's `Linear` layout).
    embed_w: Vec<f32>,
    embed_b: Vec<f32>,
    d_out: usize,
}

/// An activation map, NHWC.
struct Map {
    n: usize,
    h: usize,
    w: usize,
    c: usize,
    v: Vec<f32>,
}

fn values<const D: usize>(t: Tensor<D>) -> Option<Vec<f32>> {
    t.into_data().convert::<f32>().try_to_vec::<f32>().ok()
}

fn param<const D: usize>(p: &Param<Tensor<D>>) -> Option<Vec<f32>> {
    values(p.val())
}

impl Conv {
    /// `conv` followed by `bn`, folded. `None` for layouts this path does not cover (groups,
    /// dilation, non-square kernels or strides, asymmetric padding): the caller keeps burn's.
    fn fold(conv: &Conv2d, bn: &BatchNorm) -> Option<Self> {
        let [c_out, c_in, kh, kw] = conv.weight.val().dims();
        if conv.groups != 1
            || conv.dilation != [1, 1]
            || kh != kw
            || conv.stride[0] != conv.stride[1]
        {
            return None;
        }
        let k = kh;
        let pad = symmetric(&conv.padding)?;
        let w = param(&conv.weight)?;
        let bias = match &conv.bias {
            Some(b) => param(b)?,
            None => vec![0.0; c_out],
        };
        let gamma = param(&bn.gamma)?;
        let beta = param(&bn.beta)?;
        let mean = values(bn.running_mean.value())?;
        let var = values(bn.running_var.value())?;
        if [gamma.len(), beta.len(), mean.len(), var.len()] != [c_out; 4] {
            return None;
        }
        let scale: Vec<f32> = (0..c_out)
            .map(|o| (gamma[o] as f64 / (var[o] as f64 + bn.epsilon).sqrt()) as f32)
            .collect();
        let mut folded = taps_major(&w, [c_out, c_in, k], false);
        for (i, v) in folded.iter_mut().enumerate() {
            *v *= scale[i % c_out];
        }
        let b = (0..c_out)
            .map(|o| (bias[o] - mean[o]) * scale[o] + beta[o])
            .collect();
        Some(Self {
            k,
            stride: conv.stride[0],
            pad,
            c_in,
            c_out,
            w: folded,
            b,
        })
    }

    /// A 3 × 3 convolution of stride 1 and padding 1 on one frame, without im2col. The input
    /// is copied once into a zero-bordered buffer `(h + 2) × (w + 2)`; the output is computed on
    /// the same padded width, `h × (w + 2)` (two columns a row are discarded). Then for kernel
    /// row `ky` the three taps of output pixel `m` are the `3 · c_in` floats starting at padded
    /// pixel `m + ky (w + 2)`, so each kernel row is one product whose left side is the padded
    /// buffer itself read with a row stride of `c_in` (rows overlap), accumulated over `ky`.
    fn run_3x3(&self, x: &Map, residual: Option<&Map>, relu: bool, pad: &mut Vec<f32>) -> Map {
        let (h, w, c) = (x.h, x.w, x.c);
        let wp = w + 2;
        // Two spare pixels: the discarded columns of the last row read past the border.
        let len = ((h + 2) * wp + 2) * c;
        pad.clear();
        pad.resize(len, 0.0);
        for y in 0..h {
            let dst = ((y + 1) * wp + 1) * c;
            pad[dst..dst + w * c].copy_from_slice(&x.v[y * w * c..(y + 1) * w * c]);
        }
        let n = self.c_out;
        let m = h * wp;
        let mut wide = vec![0f32; m * n];
        three_rows(pad, [wp, c, m], &self.w, n, &mut wide, Parallelism::None);
        // The valid columns of each row, then the epilogue.
        let mut out = Vec::with_capacity(h * w * n);
        for y in 0..h {
            out.extend_from_slice(&wide[y * wp * n..(y * wp + w) * n]);
        }
        self.finish(&mut out, residual.map(|r| r.v.as_slice()), relu);
        Map {
            n: 1,
            h,
            w,
            c: n,
            v: out,
        }
    }

    /// The epilogue of a product, row by row of `c_out`: `v ← relu?(v + bias + residual?)`.
    fn finish(&self, v: &mut [f32], residual: Option<&[f32]>, relu: bool) {
        if let Some(r) = residual {
            assert_eq!(r.len(), v.len(), "residual of another shape");
        }
        let n = self.c_out;
        let act = |s: f32| if relu { s.max(0.0) } else { s };
        match residual {
            Some(r) => {
                for (row, rrow) in v.chunks_exact_mut(n).zip(r.chunks_exact(n)) {
                    for ((v, b), r) in row.iter_mut().zip(&self.b).zip(rrow) {
                        *v = act(*v + b + r);
                    }
                }
            }
            None => {
                for row in v.chunks_exact_mut(n) {
                    for (v, b) in row.iter_mut().zip(&self.b) {
                        *v = act(*v + b);
                    }
                }
            }
        }
    }

    fn out_size(&self, h: usize, w: usize) -> (usize, usize) {
        (
            (h + 2 * self.pad - self.k) / self.stride + 1,
            (w + 2 * self.pad - self.k) / self.stride + 1,
        )
    }

    /// `relu?(conv(x) + residual?)`. `col` is scratch for the im2col matrix.
    fn run(&self, x: &Map, residual: Option<&Map>, relu: bool, col: &mut Vec<f32>) -> Map {
        debug_assert_eq!(x.c, self.c_in);
        if self.k == 3 && self.stride == 1 && self.pad == 1 && x.n == 1 {
            return self.run_3x3(x, residual, relu, col);
        }
        let (oh, ow) = self.out_size(x.h, x.w);
        let m = x.n * oh * ow;
        let kk = self.k * self.k * self.c_in;
        let direct = self.k == 1 && self.stride == 1 && self.pad == 0;
        if !direct {
            im2col(x, self, oh, ow, col);
        }
        let lhs: &[f32] = if direct { &x.v } else { col };
        let mut out = vec![0f32; m * self.c_out];
        let n = self.c_out;
        // One thread: the frames of a batch run in parallel instead.
        matmul(&mut out, [m, n, kk], lhs, &self.w, Parallelism::None);
        self.finish(&mut out, residual.map(|r| r.v.as_slice()), relu);
        Map {
            n: x.n,
            h: oh,
            w: ow,
            c: n,
            v: out,
        }
    }
}

/// The im2col matrix of `x` for `conv`: row `(n, oy, ox)` holds the `k × k × c_in` inputs under
/// the kernel at that output, zeros where it hangs over the border. Every element is written
/// (the buffer is reused without clearing).
fn im2col(x: &Map, conv: &Conv, oh: usize, ow: usize, col: &mut Vec<f32>) {
    let (k, s, p, c) = (conv.k, conv.stride, conv.pad, x.c);
    let kk = k * k * c;
    let len = x.n * oh * ow * kk;
    if col.len() < len {
        col.resize(len, 0.0);
    }
    col.truncate(len);
    for n in 0..x.n {
        for oy in 0..oh {
            for ox in 0..ow {
                let row = &mut col[((n * oh + oy) * ow + ox) * kk..][..kk];
                for ky in 0..k {
                    let iy = (oy * s + ky) as isize - p as isize;
                    let taps = &mut row[ky * k * c..(ky + 1) * k * c];
                    if iy < 0 || iy >= x.h as isize {
                        taps.fill(0.0);
                        continue;
                    }
                    for kx in 0..k {
                        let ix = (ox * s + kx) as isize - p as isize;
                        let dst = &mut taps[kx * c..(kx + 1) * c];
                        if ix < 0 || ix >= x.w as isize {
                            dst.fill(0.0);
                        } else {
                            let src = ((n * x.h + iy as usize) * x.w + ix as usize) * c;
                            dst.copy_from_slice(&x.v[src..src + c]);
                        }
                    }
                }
            }
        }
    }
}

impl MaxPool {
    fn run(&self, x: &Map) -> Map {
        let (k, s, p) = (self.k, self.stride, self.pad);
        let oh = (x.h + 2 * p - k) / s + 1;
        let ow = (x.w + 2 * p - k) / s + 1;
        let c = x.c;
        let mut v = vec![f32::NEG_INFINITY; x.n * oh * ow * c];
        for n in 0..x.n {
            for oy in 0..oh {
                for ox in 0..ow {
                    let dst = &mut v[((n * oh + oy) * ow + ox) * c..][..c];
                    for ky in 0..k {
                        let iy = (oy * s + ky) as isize - p as isize;
                        if iy < 0 || iy >= x.h as isize {
                            continue;
                        }
                        for kx in 0..k {
                            let ix = (ox * s + kx) as isize - p as isize;
                            if ix < 0 || ix >= x.w as isize {
                                continue;
                            }
                            let src = ((n * x.h + iy as usize) * x.w + ix as usize) * c;
                            for (d, &a) in dst.iter_mut().zip(&x.v[src..src + c]) {
                                *d = d.max(a);
                            }
                        }
                    }
                }
            }
        }
        Map {
            n: x.n,
            h: oh,
            w: ow,
            c,
            v,
        }
    }
}

/// Adaptive average pooling to `[oh, ow]` (cell i spans rows ⌊i·H/oh⌋ .. ⌈(i+1)·H/oh⌉), then
/// flattened per image in burn's NCHW order: `[n][c · oh · ow]`.
fn adaptive_avg_flat(x: &Map, [oh, ow]: [usize; 2]) -> Vec<f32> {
    let c = x.c;
    let d = c * oh * ow;
    let mut out = vec![0f32; x.n * d];
    for n in 0..x.n {
        for cy in 0..oh {
            let (y0, y1) = (cy * x.h / oh, ((cy + 1) * x.h).div_ceil(oh));
            for cx in 0..ow {
                let (x0, x1) = (cx * x.w / ow, ((cx + 1) * x.w).div_ceil(ow));
                let mut acc = vec![0f32; c];
                for y in y0..y1 {
                    for xx in x0..x1 {
                        let src = ((n * x.h + y) * x.w + xx) * c;
                        for (a, &v) in acc.iter_mut().zip(&x.v[src..src + c]) {
                            *a += v;
                        }
                    }
                }
                let cnt = ((y1 - y0) * (x1 - x0)) as f32;
                for (ch, a) in acc.iter().enumerate() {
                    out[n * d + (ch * oh + cy) * ow + cx] = a / cnt;
                }
            }
        }
    }
    out
}

impl FastEncoder {
    /// The inference form of `enc`, or `None` when it has a layer this path does not cover.
    pub fn new(enc: &Encoder) -> Option<Self> {
        let stem = Conv::fold(&enc.stem, &enc.stem_bn)?;
        let pool = match &enc.pool {
            Some(p) => {
                if p.kernel_size[0] != p.kernel_size[1]
                    || p.stride[0] != p.stride[1]
                    || p.dilation != [1, 1]
                    || p.ceil_mode
                {
                    return None;
                }
                Some(MaxPool {
                    k: p.kernel_size[0],
                    stride: p.stride[0],
                    pad: symmetric(&p.padding)?,
                })
            }
            None => None,
        };
        let units = enc
            .units
            .iter()
            .map(Unit::fold)
            .collect::<Option<Vec<_>>>()?;
        let embed_w = param(&enc.embed.weight)?;
        let [d_in, d_out] = enc.embed.weight.val().dims();
        let embed_b = match &enc.embed.bias {
            Some(b) => param(b)?,
            None => vec![0.0; d_out],
        };
        let cells = enc.gap.output_size;
        let c_last = units.last().map_or(stem.c_out, Unit::c_out);
        if c_last * cells[0] * cells[1] != d_in || embed_w.len() != d_in * d_out {
            return None;
        }
        Some(Self {
            stem,
            pool,
            units,
            cells,
            embed_w,
            embed_b,
            d_out,
        })
    }

    /// Embeddings of `frames`, each an RGB image of `width × height` (HWC, u8), scaled to
    /// [-1, 1] as the trainer feeds them: one `d_out`-vector per frame. The frames of a batch
    /// are encoded in parallel, each on one thread (a frame's products are too small to split
    /// well, and a batch-sized im2col matrix would not stay in cache).
    pub fn encode(&self, frames: &[&[u8]], width: usize, height: usize) -> Vec<Vec<f32>> {
        use rayon::prelude::*;
        if frames.len() > 1 && rayon::current_num_threads() > 1 {
            frames
                .par_iter()
                .map_init(Vec::new, |col, f| self.encode_one(f, width, height, col))
                .collect()
        } else {
            let mut col = Vec::new();
            frames
                .iter()
                .map(|f| self.encode_one(f, width, height, &mut col))
                .collect()
        }
    }

    /// One frame's embedding; `col` is scratch.
    fn encode_one(
        &self,
        frame: &[u8],
        width: usize,
        height: usize,
        col: &mut Vec<f32>,
    ) -> Vec<f32> {
        assert_eq!(
            frame.len(),
            width * height * 3,
            "frame of another size than the model's input"
        );
        let x = Map {
            n: 1,
            h: height,
            w: width,
            c: 3,
            v: frame.iter().map(|&b| b as f32 / 127.5 - 1.0).collect(),
        };
        let mut x = self.stem.run(&x, None, true, col);
        if let Some(p) = &self.pool {
            x = p.run(&x);
        }
        for u in &self.units {
            x = u.run(&x, col);
        }
        let flat = adaptive_avg_flat(&x, self.cells);
        let d = self.d_out;
        assert_eq!(self.embed_w.len(), flat.len() * d);
        // One row: a plain dot product per output, in the order of burn's matmul rows.
        let mut out = self.embed_b.clone();
        for (i, &v) in flat.iter().enumerate() {
            if v != 0.0 {
                for (o, &w) in out.iter_mut().zip(&self.embed_w[i * d..(i + 1) * d]) {
                    *o += v * w;
                }
            }
        }
        out
    }
}

impl Unit {
    fn fold(u: &ResUnit) -> Option<Self> {
        let conv3 = match (&u.conv3, &u.bn3) {
            (Some(c), Some(b)) => Some(Conv::fold(c, b)?),
            (None, None) => None,
            _ => return None,
        };
        let short = match (&u.short_conv, &u.short_bn) {
            (Some(c), Some(b)) => Some(Conv::fold(c, b)?),
            (None, None) => None,
            _ => return None,
        };
        Some(Self {
            conv1: Conv::fold(&u.conv1, &u.bn1)?,
            conv2: Conv::fold(&u.conv2, &u.bn2)?,
            conv3,
            short,
        })
    }

    fn c_out(&self) -> usize {
        self.conv3.as_ref().unwrap_or(&self.conv2).c_out
    }

    /// He et al.'s residual unit, as [`ResUnit::forward`]: `relu(F(x) + shortcut(x))`.
    fn run(&self, x: &Map, col: &mut Vec<f32>) -> Map {
        let projected = self.short.as_ref().map(|s| s.run(x, None, false, col));
        let shortcut = projected.as_ref().unwrap_or(x);
        let y = self.conv1.run(x, None, true, col);
        match &self.conv3 {
            Some(c3) => {
                let y = self.conv2.run(&y, None, true, col);
                c3.run(&y, Some(shortcut), true, col)
            }
            None => self.conv2.run(&y, Some(shortcut), true, col),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Depth, ForceShape};
    use super::*;
    use burn::module::RunningState;
    use burn::tensor::{Device, Distribution, TensorData};

    fn dev() -> Device {
        Device::flex()
    }

    /// Batch norms with running statistics and affine parameters far from the identity, so
    /// that folding them is tested, not skipped.
    fn perturb(bn: &mut BatchNorm, dev: &Device) {
        let [c] = bn.gamma.val().dims();
        let r = |lo: f64, hi: f64| Tensor::<1>::random([c], Distribution::Uniform(lo, hi), dev);
        bn.gamma = Param::from_tensor(r(0.5, 1.5));
        bn.beta = Param::from_tensor(r(-0.3, 0.3));
        bn.running_mean = RunningState::new(r(-0.2, 0.2));
        bn.running_var = RunningState::new(r(0.3, 2.0));
    }

    fn perturbed(shape: &ForceShape) -> Encoder {
        let dev = dev();
        dev.seed(7);
        let mut e = Encoder::new(shape, &dev);
        perturb(&mut e.stem_bn, &dev);
        for u in &mut e.units {
            perturb(&mut u.bn1, &dev);
            perturb(&mut u.bn2, &dev);
            if let Some(b) = &mut u.bn3 {
                perturb(b, &dev);
            }
            if let Some(b) = &mut u.short_bn {
                perturb(b, &dev);
            }
        }
        e
    }

    fn frames(n: usize, w: usize, h: usize) -> Vec<Vec<u8>> {
        (0..n)
            .map(|i| {
                (0..w * h * 3)
                    .map(|j| ((j * 37 + i * 101 + (j / 7) * 13) % 256) as u8)
                    .collect()
            })
            .collect()
    }

    /// Burn's own forward on the same frames (NCHW, [-1, 1]).
    fn reference(e: &Encoder, frames: &[Vec<u8>], w: usize, h: usize) -> Vec<Vec<f32>> {
        let n = frames.len();
        let mut v = vec![0f32; n * 3 * h * w];
        for (i, f) in frames.iter().enumerate() {
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        v[((i * 3 + c) * h + y) * w + x] =
                            f[(y * w + x) * 3 + c] as f32 / 127.5 - 1.0;
                    }
                }
            }
        }
        let x = Tensor::<4>::from_data(TensorData::new(v, [n, 3, h, w]), &dev());
        let out = values(e.forward(x)).unwrap();
        let d = out.len() / n;
        out.chunks_exact(d).map(|c| c.to_vec()).collect()
    }

    fn check(shape: ForceShape, w: usize, h: usize, n: usize) {
        let e = perturbed(&shape);
        let fast = FastEncoder::new(&e).expect("every layer of the encoder is covered");
        let imgs = frames(n, w, h);
        let refs: Vec<&[u8]> = imgs.iter().map(|f| f.as_slice()).collect();
        let got = fast.encode(&refs, w, h);
        let want = reference(&e, &imgs, w, h);
        assert_eq!(got.len(), n);
        for (g, r) in got.iter().zip(&want) {
            assert_eq!(g.len(), shape.embed);
            // f32 sums of a few thousand terms in another order: relative error ~1e-6;
            // a wrong fold, layout or border is O(1).
            let scale = r.iter().fold(0f32, |m, v| m.max(v.abs())).max(1e-3);
            for (a, b) in g.iter().zip(r) {
                assert!(
                    (a - b).abs() <= 1e-4 * scale,
                    "{shape:?}: {a} vs {b} (scale {scale})"
                );
            }
        }
        // Frames in a batch are independent: the second alone gives its row of the batch.
        if n > 1 {
            let alone = fast.encode(&refs[1..2], w, h);
            for (a, b) in alone[0].iter().zip(&got[1]) {
                assert!((a - b).abs() <= 1e-5 * a.abs().max(1.0));
            }
        }
    }

    #[test]
    fn the_fast_encoder_computes_burns_forward() {
        // The trainer's default: small stem, ResNet-18, the final map kept.
        let mut shape = ForceShape {
            depth: Depth::R18,
            width: 4,
            embed: 8,
            lstm: true,
            residual: true,
            imagenet_stem: false,
            spatial: Some(ForceShape::final_map(false, 24, 32)),
        };
        check(shape, 32, 24, 2);
        // Odd sizes: borders and strides that do not divide evenly; global pooling.
        shape.spatial = None;
        check(shape, 19, 13, 2);
        // ImageNet stem (7 × 7 stride 2, max pool) and bottleneck units.
        let shape = ForceShape {
            depth: Depth::R50,
            width: 2,
            embed: 5,
            lstm: false,
            residual: false,
            imagenet_stem: true,
            spatial: Some([2, 3]),
        };
        check(shape, 96, 80, 1);
    }
}
