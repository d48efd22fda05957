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

use gemm::Parallelism;

/// The fewest input and output channels a layer needs to go through Winograd: below it the
/// products over the channels are too short for the saved multiplications to pay for the
/// transforms (measured: `rig bench train --speed`).
pub(super) const MIN_CHANNELS: usize = 32;

/// Whether a 3 × 3 same layer of `c → o` channels on `h × w` images takes this path: even
/// sizes (whole 2 × 2 blocks) and [`MIN_CHANNELS`] each way.
pub(super) fn fits(c: usize, o: usize, h: usize, w: usize) -> bool {
    h % 2 == 0 && w % 2 == 0 && h > 0 && w > 0 && c >= MIN_CHANNELS && o >= MIN_CHANNELS
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
        for o in 0..n {
            let g = |ky: usize, kx: usize| wk[((ky * 3 + kx) * c + ci) * n + o];
            // G g: 4 × 3, column by column.
            let cols: [[f32; 4]; 3] =
                std::array::from_fn(|kx| g_rows([g(0, kx), g(1, kx), g(2, kx)]));
            for a in 0..4 {
                // (G g) Gᵀ: row a of G g through G again.
                let row = g_rows([cols[0][a], cols[1][a], cols[2][a]]);
                for (b, v) in row.into_iter().enumerate() {
                    u[((a * 4 + b) * c + ci) * n + o] = v;
                }
            }
        }
    }
    u
}

/// Buffers reused from group to group: the transformed patches, the products, and one
/// image's output channels-last.
#[derive(Default)]
pub(super) struct Scratch {
    v: Vec<f32>,
    m: Vec<f32>,
    y: Vec<f32>,
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
/// [`kernels`] (`n` outputs), no bias: `put(image, channel, index, value)` for every index
/// `(channel · h + y) · w + x` of each image's `n × h × w` output. `h` and `w` must be even.
pub(super) fn convolve(
    pads: &[&[f32]],
    [c, h, w]: [usize; 3],
    u: &[f32],
    n: usize,
    scratch: &mut Scratch,
    mut put: impl FnMut(usize, usize, usize, f32),
) {
    assert!(h % 2 == 0 && w % 2 == 0, "winograd: odd image {h} × {w}");
    assert_eq!(u.len(), 16 * c * n, "winograd: kernels of another shape");
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
        let (v, m) = (&scratch.v[k * c..], &mut scratch.m[k * n..]);
        assert!(v.len() >= (t - 1) * 16 * c + c && m.len() >= (t - 1) * 16 * n + n);
        // SAFETY: `m` holds rows `0..t` of `n` floats, `16n` apart (asserted); `v` rows of `c`
        // floats `16c` apart (asserted); `u`'s position `k` is a row-major `[c, n]` slice
        // (its length asserted above); `m` is a buffer of its own, aliasing neither.
        unsafe {
            gemm::gemm(
                t,
                n,
                c,
                m.as_mut_ptr(),
                1,
                (16 * n) as isize,
                false,
                v.as_ptr(),
                1,
                (16 * c) as isize,
                u[k * c * n..].as_ptr(),
                1,
                n as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                Parallelism::None,
            );
        }
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
        for o in 0..n {
            for p in 0..h * w {
                put(j, o, o * h * w + p, scratch.y[p * n + o]);
            }
        }
    }
}
