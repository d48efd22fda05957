//! Winograd's minimal filtering, F(2 × 2, 3 × 3), for the training convolution's 3 × 3,
//! stride-1, padding-1 layers with many channels (Lavin and Gray 2016, "Fast Algorithms for
//! Convolutional Neural Networks", CVPR; the transforms are their F(2, 3)).
//!
//! Each 2 × 2 block of output pixels comes from a 4 × 4 patch of the bordered input: the patch
//! is transformed (`V = Bᵀ d B`), each of the 16 transformed positions is one matrix product
//! over the channels with the transformed kernels (`M = V · U`, `U = G g Gᵀ`), and the block is
//! transformed back (`Y = Aᵀ M A`). That is 16 multiplications a channel pair for four outputs
//! instead of 36: 2.25× fewer than the direct products of [`super::kernels::three_rows`], for
//! three extra passes over memory (the two transforms and the products' larger operands). It
//! pays where the channels are many and the image small, the deep stages of a ResNet; the
//! first stage (16 channels at full size) stays direct ([`fits`]).
//!
//! The input gradient is the same convolution of the bordered `dy` with the turned kernel, so
//! one routine serves both. Rounding differs from the direct sum (the transforms add and
//! subtract before multiplying), within f32's precision for these magnitudes; the conv tests
//! compare both paths with burn's.
//!
//! [`fits`]: fits

use std::mem::MaybeUninit;

use gemm::Parallelism;

use super::kernels::{Mat, product_into, to_planes};
use super::simd;

/// The fewest input and output channels a layer needs to go through Winograd when its direct
/// products would run on `gemm`: below it the products over the channels are too short for the
/// saved multiplications to pay for the transforms (measured: `rig bench train --speed`).
pub(super) const MIN_CHANNELS: usize = 32;

/// The same when the direct products run on the AVX-512 kernels of [`super::simd`] (outputs in
/// sixteens), about twice `gemm`'s rate on these shapes: the 32-channel layers stay direct. On
/// an AVX-512 Xeon, 2 threads, 64 × 48, width 16, batch 8, their taking Winograd made the
/// ResNet-18 / -34 training step 2–3 % slower than this threshold (3 rounds, each faster here);
/// from 128 channels instead sat between the two.
pub(super) const MIN_CHANNELS_DIRECT: usize = 64;

/// Whether a 3 × 3 same layer of `c → o` channels on `h × w` images takes this path: even
/// sizes (whole 2 × 2 blocks) and [`MIN_CHANNELS`] each way, or [`MIN_CHANNELS_DIRECT`] where
/// the direct kernels cover `o` outputs.
pub(super) fn fits(c: usize, o: usize, h: usize, w: usize) -> bool {
    let least = if simd::covers(o) {
        MIN_CHANNELS_DIRECT
    } else {
        MIN_CHANNELS
    };
    h.is_multiple_of(2) && w.is_multiple_of(2) && h > 0 && w > 0 && c >= least && o >= least
}

/// Images transformed together, so each of the 16 products has about 512 rows (blocks).
pub(super) fn group(h: usize, w: usize) -> usize {
    (512 / ((h / 2) * (w / 2)).max(1)).max(1)
}

/// The transformed kernels `U = G g Gᵀ`, `[16, c, n]`, from taps-major weights `[9c, n]` with
/// rows in (ky, kx, ci) order (what [`super::kernels::taps_major`] gives). `G` is F(2, 3)'s
/// `[[1, 0, 0], [½, ½, ½], [½, −½, ½], [0, 0, 1]]`.
pub(super) fn kernels(wk: &[f32], c: usize, n: usize) -> Vec<f32> {
    assert_eq!(wk.len(), 9 * c * n, "winograd: weights of another shape");
    // Sixteen output channels at a time in fixed-size arrays, so the arithmetic vectorises
    // across them (the nine taps of a channel pair are 9 rows `c·n` apart, and the 16 results
    // 16 rows apart: element by element, the loads and stores did not). It runs on the calling
    // thread, with the workers idle, once per layer in each pass.
    const L: usize = 16;
    let mut u = vec![0.0f32; 16 * c * n];
    let g_rows = |f: [f32; 3]| {
        [
            f[0],
            0.5 * (f[0] + f[1] + f[2]),
            0.5 * (f[0] - f[1] + f[2]),
            f[2],
        ]
    };
    for ci in 0..c {
        for o0 in (0..n).step_by(L) {
            let len = L.min(n - o0);
            let mut g = [[0.0f32; L]; 9];
            for (t, gt) in g.iter_mut().enumerate() {
                gt[..len].copy_from_slice(&wk[(t * c + ci) * n + o0..][..len]);
            }
            let mut out = [[0.0f32; L]; 16];
            for l in 0..L {
                // G g: 4 × 3, column by column.
                let cols: [[f32; 4]; 3] =
                    std::array::from_fn(|kx| g_rows([g[kx][l], g[3 + kx][l], g[6 + kx][l]]));
                for a in 0..4 {
                    // (G g) Gᵀ: row a of G g through G again.
                    let row = g_rows([cols[0][a], cols[1][a], cols[2][a]]);
                    for (b, v) in row.into_iter().enumerate() {
                        out[a * 4 + b][l] = v;
                    }
                }
            }
            for (ab, vals) in out.iter().enumerate() {
                u[(ab * c + ci) * n + o0..][..len].copy_from_slice(&vals[..len]);
            }
        }
    }
    u
}

/// Buffers reused from group to group: the transformed patches, the products, and one
/// image's output channels-last. [`convolve`] writes every element it then reads, so a reused
/// buffer's old contents never show.
#[derive(Default)]
pub(super) struct Scratch {
    v: Vec<f32>,
    m: Vec<f32>,
    y: Vec<f32>,
}

thread_local! {
    /// Each thread's [`Scratch`] between layers ([`Scratch::kept`]).
    static KEPT: std::cell::Cell<Scratch> = std::cell::Cell::new(Scratch::default());
}

impl Scratch {
    /// This thread's scratch, handed back when the guard drops. A fresh one per layer was
    /// grown and zero-filled each time (with a ResNet-34's 64-channel layers at 64 × 48, about
    /// 4 MB per layer and worker, 1 % of the step in `memset`); kept, it is sized once. A
    /// nested take on the same thread (a rayon steal) gets an empty one and allocates.
    pub(super) fn kept() -> KeptScratch {
        KeptScratch(KEPT.with(std::cell::Cell::take))
    }
}

/// [`Scratch::kept`]'s guard.
pub(super) struct KeptScratch(Scratch);

impl std::ops::Deref for KeptScratch {
    type Target = Scratch;
    fn deref(&self) -> &Scratch {
        &self.0
    }
}

impl std::ops::DerefMut for KeptScratch {
    fn deref_mut(&mut self) -> &mut Scratch {
        &mut self.0
    }
}

impl Drop for KeptScratch {
    fn drop(&mut self) {
        let s = std::mem::take(&mut self.0);
        KEPT.with(|k| k.set(s));
    }
}

/// `V = Bᵀ d B` of one 4 × 4 patch, `Bᵀ = [[1, 0, −1, 0], [0, 1, 1, 0], [0, −1, 1, 0],
/// [0, 1, 0, −1]]`, for `c` channels at once: `r0..r3` are the patch's rows (4 pixels of `c`
/// floats each), `out` the 16 transformed positions of `c` floats. Separate arguments so the
/// compiler knows they do not overlap and vectorises over the channels.
#[inline(never)]
fn patch(c: usize, r0: &[f32], r1: &[f32], r2: &[f32], r3: &[f32], out: &mut [f32]) {
    let (r0, r1, r2, r3) = (&r0[..4 * c], &r1[..4 * c], &r2[..4 * c], &r3[..4 * c]);
    let out = &mut out[..16 * c];
    for ci in 0..c {
        // Bᵀ d, column by column (jj), then each row of it through B.
        let mut t = [[0.0f32; 4]; 4];
        for jj in 0..4 {
            let (d0, d1, d2, d3) = (
                r0[jj * c + ci],
                r1[jj * c + ci],
                r2[jj * c + ci],
                r3[jj * c + ci],
            );
            t[0][jj] = d0 - d2;
            t[1][jj] = d1 + d2;
            t[2][jj] = d2 - d1;
            t[3][jj] = d1 - d3;
        }
        for (a, [e0, e1, e2, e3]) in t.into_iter().enumerate() {
            out[(a * 4) * c + ci] = e0 - e2;
            out[(a * 4 + 1) * c + ci] = e1 + e2;
            out[(a * 4 + 2) * c + ci] = e2 - e1;
            out[(a * 4 + 3) * c + ci] = e1 - e3;
        }
    }
}

/// `Y = Aᵀ M A`, `Aᵀ = [[1, 1, 1, 0], [0, 1, −1, −1]]`, of one block for `n` channels at once:
/// `m` holds the 16 positions of `n` floats, `top` and `bottom` the block's two output rows
/// (two pixels of `n` floats each), channels last.
#[inline(never)]
fn unpatch(n: usize, m: &[f32], top: &mut [f32], bottom: &mut [f32]) {
    let m = &m[..16 * n];
    let (top, bottom) = (&mut top[..2 * n], &mut bottom[..2 * n]);
    for o in 0..n {
        let e = |k: usize| m[k * n + o];
        let s0: [f32; 4] = std::array::from_fn(|q| e(q) + e(4 + q) + e(8 + q));
        let s1: [f32; 4] = std::array::from_fn(|q| e(4 + q) - e(8 + q) - e(12 + q));
        top[o] = s0[0] + s0[1] + s0[2];
        top[n + o] = s0[1] - s0[2] - s0[3];
        bottom[o] = s1[0] + s1[1] + s1[2];
        bottom[n + o] = s1[1] - s1[2] - s1[3];
    }
}

/// The 3 × 3 same convolution of `pads` (images bordered as [`super::kernels::border`] lays them
/// out: `(h + 2) × (w + 2)` pixels of `c` floats, channels last) with the kernels `u` of
/// [`kernels`] (`n` outputs), plus `bias[o]` on channel `o` if given, into `out`: image `j`'s
/// `n × h × w` (NCHW) from `j · n·h·w`, every element written. `h` and `w` must be even.
/// `par`: the products' threads (one, when the caller shares images out over the pool).
#[allow(clippy::too_many_arguments)]
pub(super) fn convolve(
    pads: &[&[f32]],
    [c, h, w]: [usize; 3],
    u: &[f32],
    n: usize,
    bias: Option<&[f32]>,
    par: Parallelism,
    scratch: &mut Scratch,
    out: &mut [MaybeUninit<f32>],
) {
    assert!(h % 2 == 0 && w % 2 == 0, "winograd: odd image {h} × {w}");
    assert_eq!(u.len(), 16 * c * n, "winograd: kernels of another shape");
    assert!(
        out.len() >= pads.len() * n * h * w,
        "winograd: an output too short"
    );
    let (th, tw, wp) = (h / 2, w / 2, w + 2);
    let per = th * tw;
    let t = pads.len() * per;
    if t == 0 || c == 0 || n == 0 {
        return;
    }
    // `v` is [t, 16, c] and `m` [t, 16, n]: each block's positions together, so the
    // transforms read and write contiguous memory; the products see position `k` as the rows
    // `k · c ..` (and `k · n ..`) with a row stride of 16 positions.
    scratch.v.resize(16 * t * c, 0.0);
    scratch.m.resize(16 * t * n, 0.0);
    scratch.y.resize(h * w * n, 0.0);
    for (j, pad) in pads.iter().enumerate() {
        assert!(
            pad.len() >= (h + 2) * wp * c,
            "winograd: a bordered image too short"
        );
        for by in 0..th {
            let row = |i: usize| &pad[(2 * by + i) * wp * c..];
            for bx in 0..tw {
                let block = j * per + by * tw + bx;
                let at = 2 * bx * c;
                patch(
                    c,
                    &row(0)[at..],
                    &row(1)[at..],
                    &row(2)[at..],
                    &row(3)[at..],
                    &mut scratch.v[block * 16 * c..],
                );
            }
        }
    }
    for k in 0..16 {
        product_into(
            &mut scratch.m[k * n..],
            16 * n,
            [t, n, c],
            false,
            Mat::overlapping(&scratch.v[k * c..], [t, c], 16 * c),
            Mat::rows(&u[k * c * n..][..c * n], n),
            par,
        );
    }
    for j in 0..pads.len() {
        for by in 0..th {
            let (top, bottom) = scratch.y[2 * by * w * n..][..2 * w * n].split_at_mut(w * n);
            for bx in 0..tw {
                let block = j * per + by * tw + bx;
                unpatch(
                    n,
                    &scratch.m[block * 16 * n..],
                    &mut top[2 * bx * n..],
                    &mut bottom[2 * bx * n..],
                );
            }
        }
        let image = n * h * w;
        let y = &scratch.y[..h * w * n];
        to_planes(y, [n, h * w], bias, h * w, &mut out[j * image..][..image]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::kernels::{as_slots, border, taps_major};

    /// Uniform in `[-1, 1)` from a fixed linear congruential sequence.
    fn uniform(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }

    /// The largest error of Winograd's output over `Σ|w||x|` of the same output (the scale of
    /// any summation's rounding), against the exact sum in f64: one image `c × h × w` with
    /// entries `offset + U(-1, 1)`, weights `U(-1, 1)`.
    fn relative_error(c: usize, o: usize, [h, w]: [usize; 2], offset: f32) -> f64 {
        let mut s = 7u64;
        let x: Vec<f32> = (0..c * h * w).map(|_| offset + uniform(&mut s)).collect();
        let wt: Vec<f32> = (0..o * c * 9).map(|_| uniform(&mut s)).collect();
        let u = kernels(&taps_major(&wt, [o, c, 3], false), c, o);
        let mut pad = Vec::new();
        border(&x, [c, h, w], &mut pad);
        let mut got = vec![f32::NAN; o * h * w];
        let mut scratch = Scratch::default();
        convolve(
            &[&pad],
            [c, h, w],
            &u,
            o,
            None,
            Parallelism::None,
            &mut scratch,
            as_slots(&mut got),
        );
        let mut worst = 0.0f64;
        for oo in 0..o {
            for y in 0..h {
                for xx in 0..w {
                    let (mut exact, mut scale) = (0.0f64, 0.0f64);
                    for ci in 0..c {
                        for ky in 0..3 {
                            for kx in 0..3 {
                                let (yy, xi) = (y + ky, xx + kx);
                                if yy < 1 || yy > h || xi < 1 || xi > w {
                                    continue;
                                }
                                let a = x[(ci * h + yy - 1) * w + xi - 1] as f64;
                                let b = wt[((oo * c + ci) * 3 + ky) * 3 + kx] as f64;
                                exact += a * b;
                                scale += (a * b).abs();
                            }
                        }
                    }
                    let v = got[(oo * h + y) * w + xx] as f64;
                    assert!(v.is_finite(), "output {oo} {y} {xx} not written");
                    worst = worst.max((v - exact).abs() / scale);
                }
            }
        }
        worst
    }

    #[test]
    fn winograd_stays_within_f32_rounding_of_the_exact_sum_even_under_a_large_offset() {
        // The transforms' row sums are at most 2 (Bᵀ), 1.5 (G) and 3 (Aᵀ), so a value can grow
        // by at most 2² · 1.5² · 3² = 81 between its rounding and the output: errors of order
        // 81 ε ≈ 1e-5 of Σ|w||x|, whatever the channels' count (each product adds a term's
        // worth). A common offset of 1000 (inputs far from zero, where the patch transform's
        // differences cancel) must not break that.
        for (offset, what) in [(0.0f32, "centred"), (1000.0, "offset by 1000")] {
            for (c, o, hw) in [(32, 32, [6, 8]), (64, 40, [4, 4]), (32, 48, [2, 10])] {
                let e = relative_error(c, o, hw, offset);
                assert!(
                    e < 81.0 * f32::EPSILON as f64,
                    "{what}, {c} → {o} at {hw:?}: error {e:e} of Σ|w||x|"
                );
            }
        }
    }

    #[test]
    fn the_kernel_transform_is_g_g_g_transposed() {
        // One channel pair, g = [[1, 2, 3], [4, 5, 6], [7, 8, 9]] (ky, kx): G g Gᵀ by hand.
        let wk: Vec<f32> = (1..=9).map(|v| v as f32).collect();
        let u = kernels(&wk, 1, 1);
        // G g (4 × 3): rows g0, (g0 + g1 + g2)/2, (g0 − g1 + g2)/2, g2.
        let gg = [
            [1.0, 2.0, 3.0],
            [6.0, 7.5, 9.0],
            [2.0, 2.5, 3.0],
            [7.0, 8.0, 9.0],
        ];
        for a in 0..4 {
            let r = gg[a];
            let want = [
                r[0],
                (r[0] + r[1] + r[2]) / 2.0,
                (r[0] - r[1] + r[2]) / 2.0,
                r[2],
            ];
            for b in 0..4 {
                assert_eq!(u[a * 4 + b], want[b], "U[{a}][{b}]");
            }
        }
    }
}
