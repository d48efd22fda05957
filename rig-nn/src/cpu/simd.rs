//! Direct AVX-512 kernels for the products of the 3 × 3 path ([`super::kernels::three_rows`]
//! and [`super::kernels::three_rows_grad`]) when the channels of the product's output come in
//! sixteens, as in a ResNet's narrow first stage.
//!
//! `gemm` computes such a product on its 16 × 6 micro-kernel: six accumulators, fewer than the
//! eight that two FMA units of latency four keep busy, after packing both sides. Here the
//! bordered channels-last image is read in place and each output pixel's channels stay in
//! registers (the register blocking of direct convolutions on SIMD CPUs, as in Georganas et al.
//! 2018, "Anatomy of high-performance deep learning convolutions on SIMD architectures"):
//!
//! - **forward** (and the input gradient, the same product on the turned kernel): a tile of `P`
//!   output pixels × `16·NB` channels, `P·NB = 24` registers; for every tap one load of the
//!   kernel's row and one broadcast of each pixel's input, summed over the three kernel rows
//!   before one store;
//! - **weight gradient:** a tile of `T` taps × `16·NB` channels, `T·NB = 24` registers, summed
//!   over all the image's pixels (one load of `dy` a pixel, one broadcast of each tap).
//!
//! On an AVX-512 Xeon with 2 threads the ResNet-18 training step (64 × 48, width 16, batch 8)
//! went from 19.9–20.6 to 22.4–22.6 seq/s and inference from 1.16–1.18 to 1.02–1.07 ms a
//! frame (`rig bench train --speed`; docs/experiments.md). The kernels run where the CPU reports
//! AVX-512F at run time; elsewhere, and for channel counts that are not a multiple of 16, the
//! callers keep `gemm`.
//!
//! The same tile kernel ([`x86::product_rows`]) computes the input gradient of the 3 × 3
//! stride-2 layers by phases ([`stride2_input_grad`]), which had gone through `gemm` into an
//! unrolled matrix and a fold back onto the image. Over 12 steps of the ResNet-18 above, those
//! three layers' input gradients went from 0.109 / 0.075 / 0.057 s of thread time to 0.064 /
//! 0.048 / 0.057 s (16, 32 and 64 channels in; per-layer timers, not committed): about 1 % of
//! the step.

use std::mem::MaybeUninit;

use gemm::Parallelism;
use rayon::prelude::*;

/// Output channels a register holds.
const LANES: usize = 16;

/// Accumulator registers a tile uses (of AVX-512's 32).
const TILE: usize = 24;

/// Whether the direct kernels compute a product with `n` output channels here.
pub(super) fn covers(n: usize) -> bool {
    n > 0 && n.is_multiple_of(LANES) && has_avx512()
}

#[cfg(target_arch = "x86_64")]
fn has_avx512() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

#[cfg(not(target_arch = "x86_64"))]
fn has_avx512() -> bool {
    false
}

/// Floats of `pad` that the products of `m` output rows read (three kernel rows `wp` pixels
/// apart, `3c` floats each).
fn reach([wp, c, m]: [usize; 3]) -> usize {
    if m == 0 {
        0
    } else {
        (m - 1 + 2 * wp) * c + 3 * c
    }
}

/// `dst = Σ_ky L_ky · W_ky` as [`super::kernels::three_rows`] defines it, for `n` a multiple of
/// 16 ([`covers`]). Every element of `dst`'s first `m` rows is written.
pub(super) fn three_rows(
    pad: &[f32],
    [wp, c, m]: [usize; 3],
    w: &[f32],
    n: usize,
    dst: &mut [f32],
    par: Parallelism,
) {
    assert!(
        covers(n),
        "simd::three_rows: {n} channels, or no AVX-512 here"
    );
    assert!(
        reach([wp, c, m]) <= pad.len(),
        "simd::three_rows: the image is too short"
    );
    assert_eq!(
        w.len(),
        9 * c * n,
        "simd::three_rows: weights of another shape"
    );
    let dst = &mut dst[..m * n];
    // Rows a task computes when the product is shared out (a multiple of every tile height).
    let rows = 8 * TILE;
    let run = |first: usize, part: &mut [f32]| {
        // SAFETY: AVX-512F is present (`covers`); `pad` holds every float the rows
        // `first..first + part.len() / n` read (`reach` of all `m` rows, asserted), `w` is
        // `9c × n` (asserted) and `part` holds those rows of `n` floats.
        #[cfg(target_arch = "x86_64")]
        unsafe {
            x86::forward_rows(pad, [wp, c], [first * c, c], w, n, part)
        };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("{first} {}", part.len());
    };
    match par {
        Parallelism::None => run(0, dst),
        _ => dst
            .par_chunks_mut(rows * n)
            .enumerate()
            .for_each(|(i, part)| run(i * rows, part)),
    }
}

/// `dw += Σ_ky L_kyᵀ · dy`: the weight gradient of [`three_rows`]'s product, `dw` as its
/// weights `[9c, n]` (rows in (ky, kx, ci) order), `dy` `[m, n]` on the padded width, for `n` a
/// multiple of 16 ([`covers`]).
pub(super) fn three_rows_grad(
    pad: &[f32],
    [wp, c, m]: [usize; 3],
    dy: &[f32],
    n: usize,
    dw: &mut [f32],
    par: Parallelism,
) {
    assert!(
        covers(n),
        "simd::three_rows_grad: {n} channels, or no AVX-512 here"
    );
    assert!(
        reach([wp, c, m]) <= pad.len(),
        "simd::three_rows_grad: the image is too short"
    );
    assert!(dy.len() >= m * n, "simd::three_rows_grad: dy is too short");
    assert_eq!(
        dw.len(),
        9 * c * n,
        "simd::three_rows_grad: weights of another shape"
    );
    let kr = 3 * c;
    let run = |ky: usize, part: &mut [f32]| {
        // SAFETY: AVX-512F is present (`covers`); the rows of kernel row `ky` read `m` pixels
        // from `ky · wp`, inside `reach` (asserted); `dy` holds `m × n` floats and `part` is
        // that kernel row's `3c × n` of `dw` (asserted).
        #[cfg(target_arch = "x86_64")]
        unsafe {
            x86::grad_rows(&pad[ky * wp * c..], [c, m, c], dy, n, part)
        };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("{ky} {}", part.len());
    };
    let parts = dw.chunks_mut(kr * n).enumerate();
    match par {
        Parallelism::None => parts.for_each(|(ky, part)| run(ky, part)),
        _ => parts
            .collect::<Vec<_>>()
            .into_par_iter()
            .for_each(|(ky, part)| run(ky, part)),
    }
}

/// The 3 × 3 convolution of stride 2 of the [`super::kernels::border`]ed channels-last image
/// `pad` (`wp` pixels a row, `c` floats a pixel; padding 1), `[ho, wo]` output pixels, into
/// `dst` channels-last `[ho·wo, n]`: output `(oy, ox)` of kernel row `ky` reads the `3c` floats
/// from padded pixel `(2oy + ky, 2ox)`, so each output row is the forward product on pixels two
/// apart. `w` is `[9c, n]` as for [`three_rows`]; `n` a multiple of 16 ([`covers`]).
pub(super) fn stride2_rows(
    pad: &[f32],
    [wp, c]: [usize; 2],
    [ho, wo]: [usize; 2],
    w: &[f32],
    n: usize,
    dst: &mut [f32],
) {
    assert!(
        covers(n),
        "simd::stride2_rows: {n} channels, or no AVX-512 here"
    );
    assert!(
        ho == 0 || wo == 0 || stride2_reach([wp, c], [ho, wo]) <= pad.len(),
        "simd::stride2_rows: the image is too short"
    );
    assert_eq!(
        w.len(),
        9 * c * n,
        "simd::stride2_rows: weights of another shape"
    );
    assert!(
        dst.len() >= ho * wo * n,
        "simd::stride2_rows: the output is too short"
    );
    if wo == 0 {
        return;
    }
    for (oy, part) in dst[..ho * wo * n].chunks_mut(wo * n).enumerate() {
        // SAFETY: AVX-512F is present (`covers`); the `wo` outputs of row `oy` read from
        // padded row `2oy`, `(wo − 1)·2c + 2wp·c + 3c` floats, within `stride2_reach`
        // (asserted); `w` is `9c × n` and `part` one output row of `n` floats a pixel.
        #[cfg(target_arch = "x86_64")]
        unsafe {
            x86::forward_rows(pad, [wp, c], [2 * oy * wp * c, 2 * c], w, n, part)
        };
        #[cfg(not(target_arch = "x86_64"))]
        unreachable!("{oy} {}", part.len());
    }
}

/// `dw += ` the weight gradient of [`stride2_rows`]' product: `dw` `[9c, n]` as its weights,
/// `dy` channels-last, `ho` rows of `wo` pixels of `n` floats, the rows `dy_row` floats apart
/// (`wo·n` when packed, more when `dy` is bordered).
pub(super) fn stride2_rows_grad(
    pad: &[f32],
    [wp, c]: [usize; 2],
    [ho, wo]: [usize; 2],
    dy: &[f32],
    dy_row: usize,
    n: usize,
    dw: &mut [f32],
) {
    assert!(
        covers(n),
        "simd::stride2_rows_grad: {n} channels, or no AVX-512 here"
    );
    assert!(
        ho == 0 || wo == 0 || stride2_reach([wp, c], [ho, wo]) <= pad.len(),
        "simd::stride2_rows_grad: the image is too short"
    );
    assert!(
        ho == 0 || (dy_row >= wo * n && dy.len() >= (ho - 1) * dy_row + wo * n),
        "simd::stride2_rows_grad: dy is too short"
    );
    assert_eq!(
        dw.len(),
        9 * c * n,
        "simd::stride2_rows_grad: weights of another shape"
    );
    if wo == 0 {
        return;
    }
    for (ky, part) in dw.chunks_mut(3 * c * n).enumerate() {
        for oy in 0..ho {
            // SAFETY: AVX-512F is present (`covers`); row `oy` of kernel row `ky` reads
            // `(wo − 1)·2c + 3c` floats from padded row `2oy + ky`, within `stride2_reach`
            // (asserted); `dy` holds that output row's `wo × n` floats from `oy·dy_row`
            // (asserted), `part` is kernel row `ky`'s `3c × n` of `dw`.
            #[cfg(target_arch = "x86_64")]
            unsafe {
                let rows = &pad[(2 * oy + ky) * wp * c..];
                x86::grad_rows(rows, [c, wo, 2 * c], &dy[oy * dy_row..], n, part)
            };
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("{ky} {oy} {}", part.len());
        }
    }
}

/// Floats of `pad` that the stride-2 products of `[ho, wo]` outputs (both above zero) read.
fn stride2_reach([wp, c]: [usize; 2], [ho, wo]: [usize; 2]) -> usize {
    2 * (ho - 1) * wp * c + (wo - 1) * 2 * c + 2 * wp * c + 3 * c
}

/// Whether [`to_pixels`] and [`to_planes`] take the 16 × 16 register transpose for `c`
/// channels here: `c` a multiple of 16 and AVX-512F present.
pub(super) fn transposes(c: usize) -> bool {
    c > 0 && c.is_multiple_of(LANES) && has_avx512()
}

/// Sixteen pixels of `c` planes `stride` floats apart into channels-last order:
/// `dst[px·c + ci] = src[ci·stride + px]` for `px < 16`, `ci < c` ([`transposes`] must hold).
/// The NCHW to channels-last copy of [`super::kernels::border_into`], a block of 16 × 16 floats
/// at a time in registers instead of one float at a time.
pub(super) fn to_pixels(src: &[f32], stride: usize, c: usize, dst: &mut [MaybeUninit<f32>]) {
    assert!(
        transposes(c),
        "simd::to_pixels: {c} channels, or no AVX-512 here"
    );
    assert!(
        src.len() >= (c - 1) * stride + LANES && dst.len() >= LANES * c,
        "simd::to_pixels: {} and {} floats for 16 pixels of {c} planes {stride} apart",
        src.len(),
        dst.len()
    );
    // SAFETY: AVX-512F is present (`transposes`); the reads and writes stay within the lengths
    // asserted above.
    #[cfg(target_arch = "x86_64")]
    unsafe {
        x86::to_pixels(src.as_ptr(), stride, c, dst.as_mut_ptr().cast())
    };
}

/// The other way: sixteen channels-last pixels of `c` floats (`src`) into `c` planes `stride`
/// floats apart, `dst[ci·stride + px] = src[px·c + ci] (+ bias[ci])` ([`transposes`] must
/// hold). [`super::kernels::unborder_into`]'s copy.
pub(super) fn to_planes(
    src: &[f32],
    c: usize,
    bias: Option<&[f32]>,
    stride: usize,
    dst: &mut [MaybeUninit<f32>],
) {
    assert!(
        transposes(c),
        "simd::to_planes: {c} channels, or no AVX-512 here"
    );
    assert!(
        src.len() >= LANES * c && dst.len() >= (c - 1) * stride + LANES,
        "simd::to_planes: {} and {} floats for 16 pixels of {c} planes {stride} apart",
        src.len(),
        dst.len()
    );
    assert!(
        bias.is_none_or(|b| b.len() >= c),
        "simd::to_planes: a bias per channel"
    );
    // SAFETY: as in `to_pixels`; `bias`, when given, holds `c` floats (asserted).
    #[cfg(target_arch = "x86_64")]
    unsafe {
        x86::to_planes(src.as_ptr(), c, bias, stride, dst.as_mut_ptr().cast())
    };
}

/// The shape of a direct product's rows ([`x86::product_rows`]): each output row sums `rows`
/// kernel rows of `kr` taps, the kernel rows `row_step` floats apart in the source;
/// consecutive output rows read the source `step` floats apart and are stored `dstep` apart.
#[derive(Debug, Clone, Copy)]
struct Reach {
    rows: usize,
    row_step: usize,
    kr: usize,
    step: usize,
    dstep: usize,
}

/// The kernel rows (or columns) of a 3 × 3 convolution of stride 2 and padding 1 that reach
/// the input rows of parity `p`, each with the offset of the output row it comes from: input
/// row `2a + p` is read by output row `a + off` through kernel row `k` where
/// `2(a + off) + k − 1 = 2a + p`.
fn phase_taps(p: usize) -> &'static [(usize, usize)] {
    if p == 0 { &[(1, 0)] } else { &[(2, 0), (0, 1)] }
}

/// The weights of [`stride2_input_grad`]: for each phase `(py, px)` (index `2py + px`) the
/// matrix of rows `(r, s, oi)` (the phase's kernel rows and columns in [`phase_taps`] order,
/// then the output channel) and columns `ci`, `w[oi, ci, ky_r, kx_s]`; `w` as `[o, c, 3, 3]`.
pub(super) fn stride2_phase_weights(w: &[f32], o: usize, c: usize) -> [Vec<f32>; 4] {
    assert_eq!(
        w.len(),
        o * c * 9,
        "simd::stride2_phase_weights: weights of another shape"
    );
    std::array::from_fn(|p| {
        let (rows, cols) = (phase_taps(p / 2), phase_taps(p % 2));
        let mut m = Vec::with_capacity(rows.len() * cols.len() * o * c);
        for &(ky, _) in rows {
            for &(kx, _) in cols {
                for oi in 0..o {
                    m.extend((0..c).map(|ci| w[((oi * c + ci) * 3 + ky) * 3 + kx]));
                }
            }
        }
        m
    })
}

/// The input gradient of [`stride2_rows`]' convolution, by phases: input pixel
/// `(2a + py, 2b + px)` gets the gradient only through the kernel taps of parities
/// `(py, px)` ([`phase_taps`]: 1, 2, 2 and 4 of the 9 taps), from output pixels `(a, b)` and
/// `(a + 1, b + 1)`'s neighbours. Each phase is a direct product (as the forward's) of `dy`
/// with that phase's weights ([`stride2_phase_weights`]) on pixels one apart, stored two
/// apart; no unrolled matrix and no fold back onto the image.
///
/// `dyb` is `dy` [`super::kernels::border`]ed channels-last (`o` floats a pixel, `wo + 2`
/// pixels a row; the bottom and right borders are the zeros beyond the last output), `dst`
/// the gradient channels-last `[h·w, c]`, every float of it written; `c` a multiple of 16
/// ([`covers`]).
pub(super) fn stride2_input_grad(
    dyb: &[f32],
    [ho, wo, o]: [usize; 3],
    phases: &[Vec<f32>; 4],
    [h, w, c]: [usize; 3],
    dst: &mut [f32],
) {
    assert!(
        covers(c),
        "simd::stride2_input_grad: {c} channels, or no AVX-512 here"
    );
    assert!(
        ho == h.div_ceil(2) && wo == w.div_ceil(2),
        "simd::stride2_input_grad: {h} × {w} in, {ho} × {wo} out is not stride 2, padding 1"
    );
    assert!(
        dyb.len() >= (ho + 2) * (wo + 2) * o,
        "simd::stride2_input_grad: dy is too short"
    );
    assert!(
        dst.len() >= h * w * c,
        "simd::stride2_input_grad: the output is too short"
    );
    for (p, wm) in phases.iter().enumerate() {
        let (py, px) = (p / 2, p % 2);
        let (nr, nc) = (phase_taps(py).len(), phase_taps(px).len());
        assert_eq!(
            wm.len(),
            nr * nc * o * c,
            "simd::stride2_input_grad: phase weights of another shape"
        );
        // Input rows `2a + py < h` and columns `2b + px < w` of this phase.
        let (rows, cols) = ((h + 1 - py.min(h + 1)) / 2, (w + 1 - px.min(w + 1)) / 2);
        if cols == 0 {
            continue;
        }
        let reach = Reach {
            rows: nr,
            row_step: (wo + 2) * o,
            kr: nc * o,
            step: o,
            dstep: 2 * c,
        };
        for a in 0..rows {
            // Output pixel `(a, 0)` in the bordered `dy`; input pixel `(2a + py, px)`.
            let origin = ((a + 1) * (wo + 2) + 1) * o;
            let at = ((2 * a + py) * w + px) * c;
            // SAFETY: AVX-512F is present (`covers`). The reads reach bordered row
            // `a + nr ≤ ho + 1` and column `cols + nc − 1 ≤ wo + 1` (`2a + py < h` gives
            // `a + py ≤ ho`, and likewise for columns), inside `dyb` (asserted); `wm` holds
            // `nr·nc·o` rows of `c` (asserted); the writes reach input pixel
            // `(2a + py)·w + px + 2(cols − 1) < h·w`, inside `dst` (asserted).
            #[cfg(target_arch = "x86_64")]
            unsafe {
                let d = dst.as_mut_ptr().add(at);
                x86::product_rows(dyb, origin, reach, wm, c, cols, d)
            };
            #[cfg(not(target_arch = "x86_64"))]
            unreachable!("{origin} {at}");
        }
    }
}

/// `v`'s floats as slots, for [`x86`]'s stores.
fn slots(v: &mut [f32]) -> &mut [MaybeUninit<f32>] {
    // SAFETY: `MaybeUninit<f32>` has the layout of `f32`; only initialised values are written.
    unsafe { &mut *(v as *mut [f32] as *mut [MaybeUninit<f32>]) }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::{
        __m512, _mm512_add_ps, _mm512_castpd_ps, _mm512_castps_pd, _mm512_fmadd_ps,
        _mm512_loadu_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_shuffle_f32x4, _mm512_storeu_ps,
        _mm512_unpackhi_pd, _mm512_unpackhi_ps, _mm512_unpacklo_pd, _mm512_unpacklo_ps,
    };

    use super::{LANES, Reach, TILE, slots};

    /// Walks a product of `len` rows (output pixels, or taps) × `n` channels in tiles: column
    /// blocks of up to 64 channels, each in tiles of `TILE / NB` rows and smaller ones for the
    /// rest. `$tile!(P, NB, col, at)` computes the `P` rows from `at` of the `16·NB` columns
    /// from `col`, and evaluates to `P`.
    macro_rules! walk_tiles {
        ($n:expr, $len:expr, $tile:ident) => {{
            let (n, len): (usize, usize) = ($n, $len);
            let mut col = 0;
            while col < n {
                let blocks = ((n - col) / LANES).min(4);
                let mut at = 0;
                while at < len {
                    at += match (blocks, len - at) {
                        (4, l) if l >= TILE / 4 => $tile!(6, 4, col, at),
                        (4, l) if l >= 4 => $tile!(4, 4, col, at),
                        (4, l) if l >= 2 => $tile!(2, 4, col, at),
                        (4, _) => $tile!(1, 4, col, at),
                        (2 | 3, l) if l >= TILE / 2 => $tile!(12, 2, col, at),
                        (2 | 3, l) if l >= 8 => $tile!(8, 2, col, at),
                        (2 | 3, l) if l >= 4 => $tile!(4, 2, col, at),
                        (2 | 3, _) => $tile!(1, 2, col, at),
                        (_, l) if l >= TILE => $tile!(24, 1, col, at),
                        (_, l) if l >= 8 => $tile!(8, 1, col, at),
                        (_, l) if l >= 4 => $tile!(4, 1, col, at),
                        _ => $tile!(1, 1, col, at),
                    };
                }
                col += match blocks {
                    4 => 4,
                    2 | 3 => 2,
                    _ => 1,
                } * LANES;
            }
        }};
    }

    /// Output rows of the forward product into `part` (whole rows of `n` floats), in the tiles
    /// of `walk_tiles`: row `i` of `part` reads `pad` from float `origin + i·step` (`step = c`
    /// for stride 1, `2c` for stride 2).
    ///
    /// # Safety
    /// AVX-512F must be present; `pad` must hold the `(rows − 1)·step + 2wp·c + 3c` floats
    /// from `origin` that the rows of `part` read, and `w` `9c × n` floats.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn forward_rows(
        pad: &[f32],
        [wp, c]: [usize; 2],
        [origin, step]: [usize; 2],
        w: &[f32],
        n: usize,
        part: &mut [f32],
    ) {
        let rows = part.len() / n;
        let reach = Reach {
            rows: 3,
            row_step: wp * c,
            kr: 3 * c,
            step,
            dstep: n,
        };
        // SAFETY: `part` holds `rows` rows of `n` floats, and what the tiles read is what the
        // caller guarantees.
        unsafe {
            product_rows(
                pad,
                origin,
                reach,
                w,
                n,
                rows,
                slots(part).as_mut_ptr().cast(),
            )
        }
    }

    /// The rows of a direct product ([`Reach`]) into `dst`, in the tiles of `walk_tiles`: row
    /// `i` reads `src` from float `origin + i·step` and is written at `dst + i·dstep`.
    ///
    /// # Safety
    /// AVX-512F; `src` holds the `(rows − 1)·step + (r.rows − 1)·row_step + kr` floats from
    /// `origin`, `w` `r.rows·kr` rows of `n` floats, `dst` the `(rows − 1)·dstep + n` floats.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn product_rows(
        src: &[f32],
        origin: usize,
        r: Reach,
        w: &[f32],
        n: usize,
        rows: usize,
        dst: *mut f32,
    ) {
        // One tile: rows `row..row + P`, columns `col..col + 16·NB` (within `n`).
        macro_rules! tile {
            ($p:expr, $nb:expr, $col:expr, $row:expr) => {{
                // SAFETY: the tile's rows and columns are within `rows` and `n` (as
                // `walk_tiles` hands them out), and what it reads and writes is within what
                // the caller guarantees.
                unsafe {
                    let at = src.as_ptr().add(origin + $row * r.step);
                    let (wc, d) = (w.as_ptr().add($col), dst.add($row * r.dstep + $col));
                    forward_tile::<$p, $nb>(at, r, wc, n, d);
                }
                $p
            }};
        }
        walk_tiles!(n, rows, tile);
    }

    /// `P` output rows × `16·NB` channels:
    /// `Σ_ky Σ_t src[ky·row_step + i·step + t] · w[ky·kr + t]`, row `i` stored at `i·dstep`.
    ///
    /// # Safety
    /// AVX-512F; `src` holds `(P − 1)·step + (rows − 1)·row_step + kr` floats, `w` `rows·kr`
    /// rows of `n` floats (from the block's column), `dst` `(P − 1)·dstep + 16·NB` floats.
    #[target_feature(enable = "avx512f")]
    unsafe fn forward_tile<const P: usize, const NB: usize>(
        src: *const f32,
        r: Reach,
        w: *const f32,
        n: usize,
        dst: *mut f32,
    ) {
        let mut acc = [[_mm512_setzero_ps(); NB]; P];
        for ky in 0..r.rows {
            // SAFETY (the loads): within what the caller guarantees.
            unsafe {
                let base = src.add(ky * r.row_step);
                let wr = w.add(ky * r.kr * n);
                for t in 0..r.kr {
                    let mut wv = [_mm512_setzero_ps(); NB];
                    for (b, v) in wv.iter_mut().enumerate() {
                        *v = _mm512_loadu_ps(wr.add(t * n + b * LANES));
                    }
                    for (i, acc) in acc.iter_mut().enumerate() {
                        let x = _mm512_set1_ps(*base.add(i * r.step + t));
                        for (a, &v) in acc.iter_mut().zip(&wv) {
                            *a = _mm512_fmadd_ps(x, v, *a);
                        }
                    }
                }
            }
        }
        for (i, acc) in acc.iter().enumerate() {
            for (b, &a) in acc.iter().enumerate() {
                // SAFETY: row `i` < P, column block `b` < NB, as the caller guarantees.
                unsafe { _mm512_storeu_ps(dst.add(i * r.dstep + b * LANES), a) };
            }
        }
    }

    /// One kernel row's weight gradient: `part[t, :] += Σ_p rows[p·step + t] · dy[p, :]` for
    /// the `3c` taps `t`, in the tiles of `walk_tiles` (`step = c` for stride 1, `2c` for 2).
    ///
    /// # Safety
    /// AVX-512F; `rows` holds `(m − 1)·step + 3c` floats, `dy` `m × n`, `part` `3c × n`.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn grad_rows(
        rows: &[f32],
        [c, m, step]: [usize; 3],
        dy: &[f32],
        n: usize,
        part: &mut [f32],
    ) {
        let dst = slots(part).as_mut_ptr().cast::<f32>();
        // One tile: taps `t..t + T` (within `3c`), columns `col..col + 16·NB` (within `n`).
        macro_rules! tile {
            ($t:expr, $nb:expr, $col:expr, $at:expr) => {{
                // SAFETY: the tile's taps and columns are within `part` (as `walk_tiles` hands
                // them out), and what it reads of `rows` and `dy` is within what the caller
                // guarantees.
                unsafe {
                    let (src, dyc) = (rows.as_ptr().add($at), dy.as_ptr().add($col));
                    grad_tile::<$t, $nb>(src, [m, step], dyc, n, dst.add($at * n + $col));
                }
                $t
            }};
        }
        walk_tiles!(n, 3 * c, tile);
    }

    /// `T` taps × `16·NB` channels of one kernel row's weight gradient, added into `dst`.
    ///
    /// # Safety
    /// AVX-512F; `src` holds `(m − 1)·step + T` floats, `dy` `m` rows of `n` (from the block's
    /// column), `dst` `T` rows of `n` (from that column).
    #[target_feature(enable = "avx512f")]
    unsafe fn grad_tile<const T: usize, const NB: usize>(
        src: *const f32,
        [m, step]: [usize; 2],
        dy: *const f32,
        n: usize,
        dst: *mut f32,
    ) {
        let mut acc = [[_mm512_setzero_ps(); NB]; T];
        for p in 0..m {
            // SAFETY (the loads): within what the caller guarantees.
            unsafe {
                let mut dv = [_mm512_setzero_ps(); NB];
                for (b, v) in dv.iter_mut().enumerate() {
                    *v = _mm512_loadu_ps(dy.add(p * n + b * LANES));
                }
                let px = src.add(p * step);
                for (j, acc) in acc.iter_mut().enumerate() {
                    let x = _mm512_set1_ps(*px.add(j));
                    for (a, &v) in acc.iter_mut().zip(&dv) {
                        *a = _mm512_fmadd_ps(x, v, *a);
                    }
                }
            }
        }
        for (j, acc) in acc.iter().enumerate() {
            for (b, &a) in acc.iter().enumerate() {
                // SAFETY: tap `j` < T, column block `b` < NB, as the caller guarantees.
                unsafe {
                    let d = dst.add(j * n + b * LANES);
                    _mm512_storeu_ps(d, _mm512_add_ps(_mm512_loadu_ps(d), a));
                }
            }
        }
    }

    /// `t[j]` lane `i` = `r[i]` lane `j`: the 16 × 16 transpose in three rounds of shuffles.
    /// Interleaving pairs of rows by single floats, then by pairs of floats, leaves in 128-bit
    /// lane `L` of `u[4g + k]` rows `4g..4g + 4` at column `4L + k`; two rounds of 128-bit lane
    /// selection then gather each column's four lanes from `u[k]`, `u[4 + k]`, `u[8 + k]`
    /// and `u[12 + k]`.
    #[target_feature(enable = "avx512f")]
    fn transpose16(r: [__m512; 16]) -> [__m512; 16] {
        let mut t = [_mm512_setzero_ps(); 16];
        for i in (0..16).step_by(2) {
            t[i] = _mm512_unpacklo_ps(r[i], r[i + 1]);
            t[i + 1] = _mm512_unpackhi_ps(r[i], r[i + 1]);
        }
        let mut u = [_mm512_setzero_ps(); 16];
        for g in (0..16).step_by(4) {
            let pd = |a: usize, b: usize, hi: bool| {
                let (a, b) = (_mm512_castps_pd(t[a]), _mm512_castps_pd(t[b]));
                _mm512_castpd_ps(if hi {
                    _mm512_unpackhi_pd(a, b)
                } else {
                    _mm512_unpacklo_pd(a, b)
                })
            };
            u[g] = pd(g, g + 2, false);
            u[g + 1] = pd(g, g + 2, true);
            u[g + 2] = pd(g + 1, g + 3, false);
            u[g + 3] = pd(g + 1, g + 3, true);
        }
        // Lane selections: 0b10_00_10_00 takes lanes 0, 2 of each side, 0b11_01_11_01 lanes 1, 3.
        let mut out = [_mm512_setzero_ps(); 16];
        for k in 0..4 {
            let even_a = _mm512_shuffle_f32x4::<0b10_00_10_00>(u[k], u[4 + k]);
            let odd_a = _mm512_shuffle_f32x4::<0b11_01_11_01>(u[k], u[4 + k]);
            let even_b = _mm512_shuffle_f32x4::<0b10_00_10_00>(u[8 + k], u[12 + k]);
            let odd_b = _mm512_shuffle_f32x4::<0b11_01_11_01>(u[8 + k], u[12 + k]);
            out[k] = _mm512_shuffle_f32x4::<0b10_00_10_00>(even_a, even_b);
            out[8 + k] = _mm512_shuffle_f32x4::<0b11_01_11_01>(even_a, even_b);
            out[4 + k] = _mm512_shuffle_f32x4::<0b10_00_10_00>(odd_a, odd_b);
            out[12 + k] = _mm512_shuffle_f32x4::<0b11_01_11_01>(odd_a, odd_b);
        }
        out
    }

    /// [`super::to_pixels`], a group of 16 channels at a time.
    ///
    /// # Safety
    /// AVX-512F; `src` holds `(c − 1)·stride + 16` floats and `dst` `16c`; `c` a multiple of 16.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn to_pixels(src: *const f32, stride: usize, c: usize, dst: *mut f32) {
        for g in (0..c).step_by(LANES) {
            let mut r = [_mm512_setzero_ps(); 16];
            for (i, v) in r.iter_mut().enumerate() {
                // SAFETY: channel `g + i < c`, 16 floats from its plane's start (caller).
                *v = unsafe { _mm512_loadu_ps(src.add((g + i) * stride)) };
            }
            for (px, v) in transpose16(r).into_iter().enumerate() {
                // SAFETY: pixel `px < 16`, channels `g..g + 16` of `c` (caller).
                unsafe { _mm512_storeu_ps(dst.add(px * c + g), v) };
            }
        }
    }

    /// [`super::to_planes`], a group of 16 channels at a time.
    ///
    /// # Safety
    /// AVX-512F; `src` holds `16c` floats, `dst` `(c − 1)·stride + 16`, `bias` (if any) `c`;
    /// `c` a multiple of 16.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn to_planes(
        src: *const f32,
        c: usize,
        bias: Option<&[f32]>,
        stride: usize,
        dst: *mut f32,
    ) {
        for g in (0..c).step_by(LANES) {
            let mut r = [_mm512_setzero_ps(); 16];
            for (px, v) in r.iter_mut().enumerate() {
                // SAFETY: pixel `px < 16`, channels `g..g + 16` of `c` (caller).
                *v = unsafe { _mm512_loadu_ps(src.add(px * c + g)) };
            }
            for (i, mut v) in transpose16(r).into_iter().enumerate() {
                if let Some(b) = bias {
                    v = _mm512_add_ps(v, _mm512_set1_ps(b[g + i]));
                }
                // SAFETY: channel `g + i < c`, 16 floats from its plane's start (caller).
                unsafe { _mm512_storeu_ps(dst.add((g + i) * stride), v) };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Deterministic values in −1..1 (a linear congruential sequence).
    fn values(len: usize, seed: u32) -> Vec<f32> {
        let mut s = seed;
        (0..len)
            .map(|_| {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 8) as f32 / (1 << 23) as f32 - 1.0
            })
            .collect()
    }

    /// The shapes: channel counts of one to five column blocks (the 64-wide block, the 32-wide
    /// one and the single), input channels from 1 to 20, output rows below, at and across the
    /// tile heights (every tile of `walk_tiles` among them); each run single-threaded and shared
    /// out.
    fn shapes() -> Vec<[usize; 4]> {
        let mut out = Vec::new();
        for n in [16, 32, 48, 64, 80, 128] {
            for c in [1, 3, 16, 20] {
                for (wp, m) in [(3, 1), (5, 7), (4, 8), (6, 14), (10, 25), (11, 203)] {
                    out.push([n, c, wp, m]);
                }
            }
        }
        out
    }

    #[test]
    fn the_direct_products_match_their_definitions_in_f64() {
        if !has_avx512() {
            // Nothing here runs them: the callers keep `gemm` on this CPU.
            assert!(!covers(16));
            return;
        }
        assert!(covers(16) && covers(128) && !covers(8) && !covers(24) && !covers(0));
        for [n, c, wp, m] in shapes() {
            let kr = 3 * c;
            let pad = values(reach([wp, c, m]), (n * 31 + c * 7 + m) as u32);
            let w = values(9 * c * n, 5);
            let dy = values(m * n, 9);
            let at = |ky: usize, p: usize, t: usize| f64::from(pad[(p + ky * wp) * c + t]);
            let what = format!("n {n} c {c} wp {wp} m {m}");
            for par in [Parallelism::None, Parallelism::Rayon(2)] {
                // The forward: a NaN-filled destination, every element overwritten.
                let mut dst = vec![f32::NAN; m * n];
                three_rows(&pad, [wp, c, m], &w, n, &mut dst, par);
                for p in 0..m {
                    for o in 0..n {
                        let want: f64 = (0..3)
                            .flat_map(|ky| (0..kr).map(move |t| (ky, t)))
                            .map(|(ky, t)| at(ky, p, t) * f64::from(w[(ky * kr + t) * n + o]))
                            .sum();
                        let got = f64::from(dst[p * n + o]);
                        assert!(
                            (got - want).abs() < 1e-5 * (kr as f64),
                            "{what}: y {got} {want}"
                        );
                    }
                }
                // The weight gradient, added onto what `dw` held.
                let mut dw = vec![1.0f32; 9 * c * n];
                three_rows_grad(&pad, [wp, c, m], &dy, n, &mut dw, par);
                for ky in 0..3 {
                    for t in 0..kr {
                        for o in 0..n {
                            let want = 1.0
                                + (0..m)
                                    .map(|p| at(ky, p, t) * f64::from(dy[p * n + o]))
                                    .sum::<f64>();
                            let got = f64::from(dw[(ky * kr + t) * n + o]);
                            assert!(
                                (got - want).abs() < 1e-5 * m as f64,
                                "{what}: dw {got} {want}"
                            );
                        }
                    }
                }
            }
        }
    }
}
