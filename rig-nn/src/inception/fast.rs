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

use burn::tensor::Tensor;
use gemm::Parallelism;
use rayon::prelude::*;

use super::{Block, ConvBn, FEATURE_DIM, INPUT_SIZE, prepare};
use crate::cpu::matmul;

/// An activation map of one image, channels last (`[h][w][c]`).
#[derive(Debug, Clone)]
struct Map {
    h: usize,
    w: usize,
    c: usize,
    v: Vec<f32>,
}

/// A convolution with its batch norm folded in, then a ReLU.
#[derive(Debug, Clone)]
struct Conv {
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

fn values<const D: usize>(t: &Tensor<D>) -> Option<Vec<f32>> {
    t.clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .ok()
}

impl Conv {
    fn new(c: &ConvBn) -> Option<Self> {
        let [c_out, c_in, kh, kw] = c.weight.dims();
        let w = values(&c.weight)?;
        let b = values(&c.bias)?;
        if w.len() != c_out * c_in * kh * kw || b.len() != c_out {
            return None;
        }
        // burn's [c_out][c_in][ky][kx] to rows (ky, kx, ci) of c_out columns.
        let mut t = vec![0f32; w.len()];
        for (i, &v) in w.iter().enumerate() {
            let (kx, rest) = (i % kw, i / kw);
            let (ky, rest) = (rest % kh, rest / kh);
            let (ci, o) = (rest % c_in, rest / c_in);
            t[((ky * kw + kx) * c_in + ci) * c_out + o] = v;
        }
        Some(Self {
            kh,
            kw,
            stride: c.stride,
            pad: c.padding,
            c_in,
            c_out,
            w: t,
            b,
        })
    }

    fn out_size(&self, h: usize, w: usize) -> (usize, usize) {
        (
            (h + 2 * self.pad[0] - self.kh) / self.stride + 1,
            (w + 2 * self.pad[1] - self.kw) / self.stride + 1,
        )
    }

    /// `relu(conv(x) + bias)`. `col` is scratch for the im2col matrix.
    fn run(&self, x: &Map, col: &mut Vec<f32>) -> Map {
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
enum Pool {
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
fn pool(x: &Map, p: Pool) -> Map {
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
struct Branch {
    pool: Pool,
    chain: Vec<Conv>,
    split: Vec<Conv>,
}

impl Branch {
    fn new(pool: Pool, chain: &[ConvBn], split: &[ConvBn]) -> Option<Self> {
        Some(Self {
            pool,
            chain: chain.iter().map(Conv::new).collect::<Option<_>>()?,
            split: split.iter().map(Conv::new).collect::<Option<_>>()?,
        })
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
    /// The inference form of the network's layers (`None` if a weight cannot be read back).
    pub(super) fn new(stem: &[ConvBn], blocks: &[Block]) -> Option<Self> {
        let one = std::slice::from_ref;
        let plain = |chain: &[ConvBn]| Branch::new(Pool::None, chain, &[]);
        let max = Pool::Max { stride: 2, pad: 0 };
        let blocks = blocks
            .iter()
            .map(|b| match b {
                Block::A { b1, b5, b3, pool }
                | Block::C {
                    b1,
                    b7: b5,
                    b7dbl: b3,
                    pool,
                } => Some(vec![
                    plain(one(b1))?,
                    plain(b5)?,
                    plain(b3)?,
                    Branch::new(Pool::Avg, one(pool), &[])?,
                ]),
                Block::B { b3, b3dbl } => Some(vec![
                    plain(one(b3))?,
                    plain(b3dbl)?,
                    Branch::new(max, &[], &[])?,
                ]),
                Block::D { b3, b7 } => {
                    Some(vec![plain(b3)?, plain(b7)?, Branch::new(max, &[], &[])?])
                }
                Block::E(e) => {
                    let p = if e.max_pool {
                        Pool::Max { stride: 1, pad: 1 }
                    } else {
                        Pool::Avg
                    };
                    Some(vec![
                        plain(one(&e.b1))?,
                        Branch::new(Pool::None, one(&e.b3), &e.b3_split)?,
                        Branch::new(Pool::None, &e.dbl, &e.dbl_split)?,
                        Branch::new(p, one(&e.pool), &[])?,
                    ])
                }
            })
            .collect::<Option<_>>()?;
        Some(Self {
            stem: stem.iter().map(Conv::new).collect::<Option<_>>()?,
            blocks,
        })
    }

    /// The 2048-d features of RGB frames (HWC bytes, each `width × height × 3`, checked by the
    /// caller), the frames in parallel.
    pub(super) fn features(&self, frames: &[&[u8]], width: usize, height: usize) -> Vec<Vec<f32>> {
        frames
            .par_iter()
            .map_init(Vec::new, |col, f| self.one(f, width, height, col))
            .collect()
    }

    fn one(&self, rgb: &[u8], width: usize, height: usize, col: &mut Vec<f32>) -> Vec<f32> {
        let n = INPUT_SIZE;
        let chw = prepare(rgb, width, height);
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
        debug_assert_eq!(x.c, FEATURE_DIM);
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
    use burn::tensor::{Device, Distribution, TensorData};

    use super::super::{avg_pool_same, max_pool};
    use super::*;

    /// A map's values in burn's NCHW layout, as a one-image tensor.
    fn tensor(x: &Map, dev: &Device) -> Tensor<4> {
        let mut v = vec![0f32; x.v.len()];
        for (p, px) in x.v.chunks_exact(x.c).enumerate() {
            for (c, &a) in px.iter().enumerate() {
                v[c * x.h * x.w + p] = a;
            }
        }
        Tensor::from_data(TensorData::new(v, [1, x.c, x.h, x.w]), dev)
    }

    fn map_of(t: Tensor<4>) -> Map {
        let [_, c, h, w] = t.dims();
        let v = values(&t).unwrap();
        let mut out = vec![0f32; v.len()];
        for (i, &a) in v.iter().enumerate() {
            out[(i % (h * w)) * c + i / (h * w)] = a;
        }
        Map { h, w, c, v: out }
    }

    fn assert_close(ours: &Map, burn: &Map, what: &str) {
        assert_eq!((ours.h, ours.w, ours.c), (burn.h, burn.w, burn.c), "{what}");
        let scale = burn.v.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        for (i, (a, b)) in ours.v.iter().zip(&burn.v).enumerate() {
            assert!(
                (a - b).abs() <= 1e-5 * scale,
                "{what}: value {i}: {a} against {b}"
            );
        }
    }

    #[test]
    fn the_layers_compute_burns_convolutions_and_pools() {
        let dev = Device::flex();
        // The network's kernel shapes: 1 × 1, the factorised 1 × 7 and 7 × 1 (and 1 × 3, 3 × 1)
        // with their one-sided padding, 5 × 5, and 3 × 3 of stride 2 without padding.
        let layers = [
            ([1, 1], 1, [0, 0]),
            ([1, 7], 1, [0, 3]),
            ([7, 1], 1, [3, 0]),
            ([3, 1], 1, [1, 0]),
            ([5, 5], 1, [2, 2]),
            ([3, 3], 2, [0, 0]),
            ([3, 3], 1, [1, 1]),
        ];
        let x = map_of(Tensor::random(
            [1, 5, 11, 9],
            Distribution::Normal(0.0, 1.0),
            &dev,
        ));
        let mut col = Vec::new();
        for (k, stride, padding) in layers {
            let conv = ConvBn {
                weight: Tensor::random([4, 5, k[0], k[1]], Distribution::Normal(0.0, 0.5), &dev),
                bias: Tensor::random([4], Distribution::Normal(0.0, 0.5), &dev),
                stride,
                padding,
            };
            let ours = Conv::new(&conv).unwrap().run(&x, &mut col);
            let burn = map_of(conv.forward(tensor(&x, &dev)));
            assert_close(
                &ours,
                &burn,
                &format!("{k:?} stride {stride} padding {padding:?}"),
            );
            // The ReLU is applied: some outputs were negative before it.
            assert!(ours.v.contains(&0.0), "{k:?}");
        }
        assert_close(
            &pool(&x, Pool::Avg),
            &map_of(avg_pool_same(tensor(&x, &dev))),
            "avg",
        );
        for (stride, pad) in [(2, 0), (1, 1)] {
            let ours = pool(&x, Pool::Max { stride, pad });
            let burn = map_of(max_pool(tensor(&x, &dev), stride, pad));
            assert_close(&ours, &burn, &format!("max pool {stride}/{pad}"));
        }
        // The padding is never the maximum: an all-negative map stays negative at its border.
        let neg = Map {
            v: vec![-1.0; x.v.len()],
            ..x.clone()
        };
        assert!(
            pool(&neg, Pool::Max { stride: 1, pad: 1 })
                .v
                .iter()
                .all(|&v| v == -1.0)
        );
    }

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
