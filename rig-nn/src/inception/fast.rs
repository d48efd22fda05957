//! The FID Inception compiled for CPU inference: what [`super::Inception::features`] runs on
//! the CPU (burn's forward stays for the GPU backends and as the reference the tests check this
//! against).
//!
//! The same function as [`super::Inception::forward`], computed as the force model's
//! `FastEncoder` computes its encoder (`force_net/fast.rs`):
//! - **Channels last, one image at a time.** A convolution is one matrix product
//!   `[pixels, kh·kw·c_in] × [kh·kw·c_in, c_out]`, its left side (im2col) built from runs of
//!   `c_in` contiguous floats; a 1 × 1 convolution of stride 1 multiplies the activation
//!   itself. The weights (batch norm already folded in at load) are laid out for it once.
//! - **Bias and ReLU** in the pass that reads the product.
//! - **Images in parallel,** each on one thread with its own scratch: no pool wake-ups inside
//!   a layer, and a block's branches concatenate by copying channel runs.

use gemm::Parallelism;
use rayon::prelude::*;

use crate::cpu::matmul;

/// An activation map of one image, channels last (`[h][w][c]`).
#[derive(Debug, Clone)]
pub(super) struct Map {
    pub(super) h: usize,
    pub(super) w: usize,
    pub(super) c: usize,
    pub(super) v: Vec<f32>,
}

/// A convolution with its batch norm folded in, then a ReLU.
#[derive(Debug, Clone)]
pub(super) struct Conv {
    kh: usize,
    kw: usize,
    stride: usize,
    /// Rows, columns.
    pad: [usize; 2],
    c_in: usize,
    c_out: usize,
    /// `[kh·kw·c_in, c_out]`, row-major, rows in (ky, kx, ci) order.
    w: Vec<f32>,
    b: Vec<f32>,
}

impl Conv {
    /// The convolution of weights `w` in burn's layout (`[c_out][c_in][kh][kw]`, batch norm
    /// folded in) and bias `b`, with `stride` and padding `pad` (rows, columns).
    pub(super) fn new(
        w: &[f32],
        [c_out, c_in, kh, kw]: [usize; 4],
        b: Vec<f32>,
        stride: usize,
        pad: [usize; 2],
    ) -> Self {
        assert!(
            w.len() == c_out * c_in * kh * kw && b.len() == c_out,
            "weights of another shape"
        );
        // Rows (ky, kx, ci) of c_out columns.
        let mut t = vec![0f32; w.len()];
        for (i, &v) in w.iter().enumerate() {
            let (kx, rest) = (i % kw, i / kw);
            let (ky, rest) = (rest % kh, rest / kh);
            let (ci, o) = (rest % c_in, rest / c_in);
            t[((ky * kw + kx) * c_in + ci) * c_out + o] = v;
        }
        Self {
            kh,
            kw,
            stride,
            pad,
            c_in,
            c_out,
            w: t,
            b,
        }
    }

    fn out_size(&self, h: usize, w: usize) -> (usize, usize) {
        (
            (h + 2 * self.pad[0] - self.kh) / self.stride + 1,
            (w + 2 * self.pad[1] - self.kw) / self.stride + 1,
        )
    }

    /// `relu(conv(x) + bias)`. `col` is scratch for the im2col matrix.
    pub(super) fn run(&self, x: &Map, col: &mut Vec<f32>) -> Map {
        assert_eq!(x.c, self.c_in, "a map of another depth");
        let (oh, ow) = self.out_size(x.h, x.w);
        let (m, kk, n) = (oh * ow, self.kh * self.kw * self.c_in, self.c_out);
        let direct = self.kh == 1 && self.kw == 1 && self.stride == 1 && self.pad == [0, 0];
        if !direct {
            im2col(x, self, oh, ow, col);
        }
        let lhs: &[f32] = if direct { &x.v } else { col };
        let mut out = vec![0f32; m * n];
        matmul(&mut out, [m, n, kk], lhs, &self.w, Parallelism::None);
        for row in out.chunks_exact_mut(n) {
            for (v, b) in row.iter_mut().zip(&self.b) {
                *v = (*v + b).max(0.0);
            }
        }
        Map {
            h: oh,
            w: ow,
            c: n,
            v: out,
        }
    }
}

/// The im2col matrix of `x` for `conv`: row `(oy, ox)` holds the `kh × kw × c_in` inputs under
/// the kernel there, zeros where it hangs over the border. Every element is written (the buffer
/// is reused without clearing).
fn im2col(x: &Map, conv: &Conv, oh: usize, ow: usize, col: &mut Vec<f32>) {
    let (kh, kw, s, c) = (conv.kh, conv.kw, conv.stride, x.c);
    let kk = kh * kw * c;
    col.resize(oh * ow * kk, 0.0);
    for oy in 0..oh {
        for ox in 0..ow {
            let row = &mut col[(oy * ow + ox) * kk..][..kk];
            for ky in 0..kh {
                let taps = &mut row[ky * kw * c..][..kw * c];
                let Some(iy) = (oy * s + ky).checked_sub(conv.pad[0]).filter(|&y| y < x.h) else {
                    taps.fill(0.0);
                    continue;
                };
                for kx in 0..kw {
                    let dst = &mut taps[kx * c..][..c];
                    match (ox * s + kx).checked_sub(conv.pad[1]).filter(|&v| v < x.w) {
                        Some(ix) => dst.copy_from_slice(&x.v[(iy * x.w + ix) * c..][..c]),
                        None => dst.fill(0.0),
                    }
                }
            }
        }
    }
}

/// What a branch does to the block's input before its convolutions.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Pool {
    None,
    /// 3 × 3, stride 1, padding 1, dividing by the real (not padded) inputs.
    Avg,
    /// 3 × 3 maximum of stride and padding, padding never the maximum.
    Max {
        stride: usize,
        pad: usize,
    },
}

/// A 3 × 3 pool of `x`: the mean of the inputs inside the map (`Pool::Avg`), or their maximum.
pub(super) fn pool(x: &Map, p: Pool) -> Map {
    let (stride, pad, avg) = match p {
        Pool::None => return x.clone(),
        Pool::Avg => (1, 1, true),
        Pool::Max { stride, pad } => (stride, pad, false),
    };
    let oh = (x.h + 2 * pad - 3) / stride + 1;
    let ow = (x.w + 2 * pad - 3) / stride + 1;
    let c = x.c;
    let mut v = vec![0f32; oh * ow * c];
    let within =
        |o: usize, k: usize, len: usize| (o * stride + k).checked_sub(pad).filter(|&i| i < len);
    for oy in 0..oh {
        for ox in 0..ow {
            let dst = &mut v[(oy * ow + ox) * c..][..c];
            dst.fill(if avg { 0.0 } else { f32::NEG_INFINITY });
            let mut count = 0usize;
            for ky in 0..3 {
                let Some(iy) = within(oy, ky, x.h) else {
                    continue;
                };
                for kx in 0..3 {
                    let Some(ix) = within(ox, kx, x.w) else {
                        continue;
                    };
                    count += 1;
                    let src = &x.v[(iy * x.w + ix) * c..][..c];
                    if avg {
                        dst.iter_mut().zip(src).for_each(|(d, &a)| *d += a);
                    } else {
                        dst.iter_mut().zip(src).for_each(|(d, &a)| *d = d.max(a));
                    }
                }
            }
            if avg {
                let inv = 1.0 / count as f32;
                dst.iter_mut().for_each(|d| *d *= inv);
            }
        }
    }
    Map { h: oh, w: ow, c, v }
}

/// One branch of a block: a pool, a chain of convolutions, and, for the E blocks' towers, the
/// pair of convolutions the chain's output splits into (each one an output of the branch).
#[derive(Debug, Clone)]
pub(super) struct Branch {
    pool: Pool,
    chain: Vec<Conv>,
    split: Vec<Conv>,
}

impl Branch {
    pub(super) fn new(pool: Pool, chain: Vec<Conv>, split: Vec<Conv>) -> Self {
        Self { pool, chain, split }
    }

    fn run(&self, x: &Map, col: &mut Vec<f32>, outs: &mut Vec<Map>) {
        let mut y = (self.pool != Pool::None).then(|| pool(x, self.pool));
        for conv in &self.chain {
            y = Some(conv.run(y.as_ref().unwrap_or(x), col));
        }
        if self.split.is_empty() {
            outs.push(y.unwrap_or_else(|| x.clone()));
        } else {
            let y = y.as_ref().unwrap_or(x);
            outs.extend(self.split.iter().map(|conv| conv.run(y, col)));
        }
    }
}

/// The maps of a block's branches, concatenated along the channels in order.
fn concat(parts: &[Map]) -> Map {
    let (h, w) = (parts[0].h, parts[0].w);
    assert!(
        parts.iter().all(|m| m.h == h && m.w == w),
        "branches of other sizes"
    );
    let c = parts.iter().map(|m| m.c).sum();
    let mut v = Vec::with_capacity(h * w * c);
    for p in 0..h * w {
        for m in parts {
            v.extend_from_slice(&m.v[p * m.c..][..m.c]);
        }
    }
    Map { h, w, c, v }
}

/// [`super::Inception`] for CPU inference; see the module docs.
#[derive(Debug, Clone)]
pub struct FastInception {
    /// The stem's convolutions; a 3/2 max pool follows the third and the fifth.
    stem: Vec<Conv>,
    blocks: Vec<Vec<Branch>>,
}

impl FastInception {
    /// The network of `stem` (a 3/2 max pool after its third and fifth convolution) and
    /// `blocks` (each the branches whose outputs it concatenates).
    pub(super) fn new(stem: Vec<Conv>, blocks: Vec<Vec<Branch>>) -> Self {
        Self { stem, blocks }
    }

    /// The features of `frames`, each made into the network's square input by `prepare`
    /// (planar, `3 × n × n`), the frames in parallel.
    pub(super) fn features(
        &self,
        frames: &[&[u8]],
        prepare: impl Fn(&[u8]) -> Vec<f32> + Sync,
    ) -> Vec<Vec<f32>> {
        frames
            .par_iter()
            .map_init(Vec::new, |col, f| self.one(&prepare(f), col))
            .collect()
    }

    fn one(&self, chw: &[f32], col: &mut Vec<f32>) -> Vec<f32> {
        let n = (chw.len() / 3).isqrt();
        assert_eq!(chw.len(), 3 * n * n, "the input is not 3 square planes");
        let mut v = vec![0f32; n * n * 3];
        for (c, plane) in chw.chunks_exact(n * n).enumerate() {
            for (p, &x) in plane.iter().enumerate() {
                v[p * 3 + c] = x;
            }
        }
        let mut x = Map {
            h: n,
            w: n,
            c: 3,
            v,
        };
        let max = Pool::Max { stride: 2, pad: 0 };
        for (i, conv) in self.stem.iter().enumerate() {
            x = conv.run(&x, col);
            if i == 2 || i == 4 {
                x = pool(&x, max);
            }
        }
        let mut outs = Vec::new();
        for block in &self.blocks {
            outs.clear();
            for branch in block {
                branch.run(&x, col, &mut outs);
            }
            x = concat(&outs);
        }
        // The average over the final map (8 × 8 for a 299 input).
        let mut f = vec![0f32; x.c];
        for px in x.v.chunks_exact(x.c) {
            f.iter_mut().zip(px).for_each(|(a, &b)| *a += b);
        }
        let inv = 1.0 / (x.h * x.w) as f32;
        f.iter_mut().for_each(|a| *a *= inv);
        f
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn branches_concatenate_in_order_pixel_by_pixel() {
        let a = Map {
            h: 1,
            w: 2,
            c: 1,
            v: vec![1.0, 2.0],
        };
        let b = Map {
            h: 1,
            w: 2,
            c: 2,
            v: vec![10.0, 11.0, 20.0, 21.0],
        };
        let m = concat(&[a, b]);
        assert_eq!(m.c, 3);
        assert_eq!(m.v, [1.0, 10.0, 11.0, 2.0, 20.0, 21.0]);
    }
}
