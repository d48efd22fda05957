//! The building blocks of the CPU training kernels ([`super::conv`], [`super::norm`] and
//! the inference path [`crate::FastEncoder`]): tensors in and out of flat `f32` vectors, buffers that
//! are written before they are read, parallel sums and maps, the strided matrix product on
//! `gemm`, and the channels-last bordered layout of the 3 × 3 convolutions with its products.

use std::borrow::Cow;
use std::mem::MaybeUninit;

use burn::backend::flex::FlexTensor;
use burn::tensor::TensorData;
use gemm::Parallelism;
use rayon::prelude::*;

use super::simd;

pub(super) fn dense(t: &FlexTensor) -> Cow<'_, [f32]> {
    match t.as_slice::<f32>() {
        Some(s) => Cow::Borrowed(s),
        None => Cow::Owned(t.to_contiguous().storage::<f32>().to_vec()),
    }
}

pub(super) fn flex<const D: usize>(v: Vec<f32>, shape: [usize; D]) -> FlexTensor {
    FlexTensor::from_data(TensorData::new(v, shape))
}

/// `Σ f(v_i)` in f64, as eight independent partial sums. One running sum is a chain of
/// dependent additions that the compiler must keep in order (float addition is not
/// associative), one addition per latency; eight chains let the loop vectorise.
#[inline]
pub(super) fn sum_of(v: &[f32], f: impl Fn(f32) -> f64) -> f64 {
    let mut acc = [0.0f64; 8];
    let mut chunks = v.chunks_exact(8);
    for c in &mut chunks {
        for (a, &x) in acc.iter_mut().zip(c) {
            *a += f(x);
        }
    }
    let tail: f64 = chunks.remainder().iter().map(|&x| f(x)).sum();
    acc.iter().sum::<f64>() + tail
}

/// `n` floats for a kernel that writes every one of them before anything reads it: the
/// allocation without the zero fill of `vec![0.0; n]`, a pass over memory that would be
/// overwritten anyway. [`written`] turns it into the vector.
pub(super) fn unwritten(n: usize) -> Vec<MaybeUninit<f32>> {
    let mut v = Vec::with_capacity(n);
    // SAFETY: `MaybeUninit<f32>` is valid uninitialised, and the capacity is `n`.
    unsafe { v.set_len(n) };
    v
}

/// The vector of [`unwritten`], once every element has been written.
///
/// # Safety
/// Every element of `v` must have been initialised.
pub(super) unsafe fn written(v: Vec<MaybeUninit<f32>>) -> Vec<f32> {
    let mut v = std::mem::ManuallyDrop::new(v);
    // SAFETY: `MaybeUninit<f32>` has the layout of `f32`; the caller vouches for the values;
    // pointer, length and capacity come from a vector whose ownership moves here.
    unsafe { Vec::from_raw_parts(v.as_mut_ptr().cast::<f32>(), v.len(), v.capacity()) }
}

/// `v` filled with zeros, as the floats it now holds.
pub(super) fn zeroed(v: &mut [MaybeUninit<f32>]) -> &mut [f32] {
    v.fill(MaybeUninit::new(0.0));
    // SAFETY: every element was initialised just above; `MaybeUninit<f32>` has the layout of
    // `f32`.
    unsafe { &mut *(v as *mut [MaybeUninit<f32>] as *mut [f32]) }
}

/// Floats a task of [`map2`] and [`add_into`].
pub(super) const BLOCK: usize = 1 << 14;

/// `dst_i += src_i`, shared out over the rayon pool in blocks.
pub(super) fn add_into(dst: &mut [f32], src: &[f32]) {
    assert_eq!(
        dst.len(),
        src.len(),
        "add_into: {} against {} values",
        dst.len(),
        src.len()
    );
    dst.par_chunks_mut(BLOCK)
        .zip(src.par_chunks(BLOCK))
        .for_each(|(d, s)| d.iter_mut().zip(s).for_each(|(d, s)| *d += s));
}

/// `out_i = f(a_i, b_i)`, shared out over the rayon pool in blocks.
pub(super) fn map2(a: &[f32], b: &[f32], f: impl Fn(f32, f32) -> f32 + Sync) -> Vec<f32> {
    assert_eq!(
        a.len(),
        b.len(),
        "map2: {} against {} values",
        a.len(),
        b.len()
    );
    let mut out = unwritten(a.len());
    out.par_chunks_mut(BLOCK)
        .zip(a.par_chunks(BLOCK).zip(b.par_chunks(BLOCK)))
        .for_each(|(o, (a, b))| {
            for ((o, &a), &b) in o.iter_mut().zip(a).zip(b) {
                o.write(f(a, b));
            }
        });
    // SAFETY: the blocks of `out` match those of `a` one to one, each written in full.
    unsafe { written(out) }
}

/// A row-major matrix as `gemm` takes it: pointer, column stride, row stride.
#[derive(Clone, Copy)]
pub(super) struct Mat(*const f32, isize, isize);

impl Mat {
    pub(super) fn rows(v: &[f32], cols: usize) -> Self {
        Self(v.as_ptr(), 1, cols as isize)
    }

    /// The transpose of the row-major `[rows, cols]` matrix in `v`.
    pub(super) fn transposed(v: &[f32], cols: usize) -> Self {
        Self(v.as_ptr(), cols as isize, 1)
    }

    /// `[rows, cols]` with contiguous rows that start `stride` floats apart, which may be
    /// fewer than `cols`: the rows then overlap (read only). Checks that `v` holds them all.
    pub(super) fn overlapping(v: &[f32], [rows, cols]: [usize; 2], stride: usize) -> Self {
        assert!(
            rows == 0 || (rows - 1) * stride + cols <= v.len(),
            "{rows} rows of {cols} floats {stride} apart do not fit in {}",
            v.len()
        );
        Self(v.as_ptr(), 1, stride as isize)
    }

    /// This matrix transposed (the same memory).
    pub(super) fn t(self) -> Self {
        Self(self.0, self.2, self.1)
    }
}

/// `dst = (accumulate ? dst : 0) + lhs · rhs`, `dst` row-major `[m, n]`.
pub(super) fn product(
    dst: &mut [f32],
    [m, n, k]: [usize; 3],
    accumulate: bool,
    lhs: Mat,
    rhs: Mat,
    par: Parallelism,
) {
    product_into(dst, n, [m, n, k], accumulate, lhs, rhs, par);
}

/// `dst = lhs · rhs` for row-major slices: `lhs` `[m, k]` (at least that many floats, read as
/// such), `rhs` `[k, n]`, `dst` `[m, n]`. The inference forms' convolutions
/// (`force_net/fast.rs`, `inception/fast.rs`).
pub(crate) fn matmul(
    dst: &mut [f32],
    [m, n, k]: [usize; 3],
    lhs: &[f32],
    rhs: &[f32],
    par: Parallelism,
) {
    assert!(lhs.len() >= m * k && rhs.len() == k * n && dst.len() == m * n);
    product(
        dst,
        [m, n, k],
        false,
        Mat::rows(lhs, k),
        Mat::rows(rhs, n),
        par,
    );
}

/// [`product`] into `m` rows of `n` floats that start `stride` floats apart in `dst`.
pub(super) fn product_into(
    dst: &mut [f32],
    stride: usize,
    [m, n, k]: [usize; 3],
    accumulate: bool,
    lhs: Mat,
    rhs: Mat,
    par: Parallelism,
) {
    assert!(stride >= n && (m == 0 || (m - 1) * stride + n <= dst.len()));
    // SAFETY: `dst` holds the `m` rows of `n` floats `stride` apart (asserted); every caller
    // builds `lhs` (`m × k`) and `rhs` (`k × n`) from slices that hold every element their
    // strides reach for that shape (row-major or transposed slices of at least that many
    // elements, or `Mat::overlapping`, which checks it), and none of them aliases `dst`.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            stride as isize,
            accumulate,
            lhs.0,
            lhs.1,
            lhs.2,
            rhs.0,
            rhs.1,
            rhs.2,
            1.0,
            1.0,
            false,
            false,
            false,
            par,
        );
    }
}

/// Pixels of one row that [`border_into`] and [`unborder_into`] move together between the planar
/// and the channels-last layouts: at most 16 × 128 floats (8 KiB) for a ResNet's widest layer.
const PIXEL_BLOCK: usize = 16;

/// Floats of an image `c × h × w` once [`border`]ed: `(h + 2) × (w + 2)` pixels and two spare.
pub(super) fn bordered_len([c, h, w]: [usize; 3]) -> usize {
    ((h + 2) * (w + 2) + 2) * c
}

/// Writes the NCHW image `src` (`c × h × w`) into `dst` channels-last with a zero border of
/// one pixel, `(h + 2) × (w + 2)` pixels of `c` floats, and two spare zero pixels after them
/// (the last output row of [`three_rows`] reads them). Only the border is zeroed: the buffer is
/// reused from image to image.
pub(super) fn border(src: &[f32], dims: [usize; 3], dst: &mut Vec<f32>) {
    dst.resize(bordered_len(dims), 0.0);
    border_into(src, dims, as_slots(dst));
}

/// `v` seen as slots to write, for a kernel that writes only initialised values (such as
/// [`border_into`]).
pub(super) fn as_slots(v: &mut [f32]) -> &mut [MaybeUninit<f32>] {
    // SAFETY: `MaybeUninit<f32>` has the layout of `f32`; callers write only initialised
    // values through it, so `v` stays initialised.
    unsafe { &mut *(v as *mut [f32] as *mut [MaybeUninit<f32>]) }
}

/// [`border`] into `dst` of exactly [`bordered_len`] floats, every one of them written (the
/// border's zeros too); returns them.
pub(super) fn border_into<'a>(
    src: &[f32],
    [c, h, w]: [usize; 3],
    dst: &'a mut [MaybeUninit<f32>],
) -> &'a mut [f32] {
    assert_eq!(
        dst.len(),
        bordered_len([c, h, w]),
        "border: a buffer of another size"
    );
    let wp = w + 2;
    let zero = MaybeUninit::new(0.0);
    // The top row and the left pixel of the first image row.
    dst[..(wp + 1) * c].fill(zero);
    // Each image row's right pixel and the next row's left pixel.
    for y in 0..h {
        let right = ((y + 1) * wp + 1 + w) * c;
        dst[right..right + 2 * c].fill(zero);
    }
    // The bottom row after its left pixel, and the spare pixels.
    dst[((h + 1) * wp + 1) * c..].fill(zero);
    // The interior, row by row from the channel planes ([`to_pixels`]).
    let plane = h * w;
    assert!(
        src.len() >= c * plane,
        "border: {} floats for {c} × {h} × {w}",
        src.len()
    );
    for y in 0..h {
        let row = &mut dst[((y + 1) * wp + 1) * c..][..w * c];
        to_pixels(&src[y * w..], [c, w], plane, row);
    }
    // SAFETY: the fills cover the border pixels and the spare ones, the copy every interior
    // pixel's `c` floats: together every element of `dst`.
    unsafe { &mut *(dst as *mut [MaybeUninit<f32>] as *mut [f32]) }
}

/// `count` pixels of `c` planes `stride` floats apart (`src`) into channels-last order:
/// `dst[p·c + ci] = src[ci·stride + p]`, the inverse of [`to_planes`]. [`PIXEL_BLOCK`]
/// pixels at a time, so the block's floats stay in the L1 cache while the `c` planes are read
/// into them (writing a whole plane at a time instead, `c` floats apart, touched a new cache
/// line with every write and took 8 % of a ResNet-18 training step); with channels in sixteens
/// on AVX-512 each whole block is transposed in registers ([`simd::to_pixels`]).
pub(super) fn to_pixels(
    src: &[f32],
    [c, count]: [usize; 2],
    stride: usize,
    dst: &mut [MaybeUninit<f32>],
) {
    if c == 0 || count == 0 {
        return;
    }
    assert!(
        src.len() >= (c - 1) * stride + count && dst.len() >= count * c && count <= stride,
        "to_pixels: {} and {} floats for {count} pixels of {c} planes {stride} apart",
        src.len(),
        dst.len()
    );
    let in_registers = simd::transposes(c);
    for x0 in (0..count).step_by(PIXEL_BLOCK) {
        let xs = (count - x0).min(PIXEL_BLOCK);
        let block = &mut dst[x0 * c..][..xs * c];
        if in_registers && xs == PIXEL_BLOCK {
            simd::to_pixels(&src[x0..], stride, c, block);
            continue;
        }
        for ci in 0..c {
            let from = &src[ci * stride + x0..][..xs];
            for (px, &v) in block.chunks_exact_mut(c).zip(from) {
                px[ci].write(v);
            }
        }
    }
}

/// `dst = Σ_ky L_ky · W_ky`, `dst` row-major `[m, n]`: a 3 × 3, stride-1 convolution of the
/// [`border`]ed channels-last image `pad` (`wp` pixels a row, `c` floats a pixel), computed on
/// the padded width (`m = h · wp`; the last two columns of each row are discarded). The three
/// taps of output pixel `p` in kernel row `ky` are the `3c` floats from padded pixel
/// `p + ky · wp`, so `L_ky` is `pad` itself read with a row stride of `c` (rows overlap), and
/// `W_ky` is rows `ky · 3c ..` of `w`, `[9c, n]` with rows in (ky, kx, ci) order.
pub(crate) fn three_rows(
    pad: &[f32],
    [wp, c, m]: [usize; 3],
    w: &[f32],
    n: usize,
    dst: &mut [f32],
    par: Parallelism,
) {
    let kr = 3 * c;
    assert_eq!(w.len(), 3 * kr * n, "three_rows: weights of another shape");
    if simd::covers(n) {
        return simd::three_rows(pad, [wp, c, m], w, n, dst, par);
    }
    for ky in 0..3 {
        let lhs = Mat::overlapping(&pad[ky * wp * c..], [m, kr], c);
        let rhs = Mat::rows(&w[ky * kr * n..][..kr * n], n);
        product(dst, [m, n, kr], ky > 0, lhs, rhs, par);
    }
}

/// `dw += Σ_ky L_kyᵀ · dy`, the weight gradient of [`three_rows`]'s product: `dw` as its
/// weights, `[9c, n]` with rows in (ky, kx, ci) order, and `dy` `[m, n]` on the padded width
/// (its discarded columns zero, so that they add nothing).
pub(super) fn three_rows_grad(
    pad: &[f32],
    [wp, c, m]: [usize; 3],
    dy: &[f32],
    n: usize,
    dw: &mut [f32],
    par: Parallelism,
) {
    let kr = 3 * c;
    assert_eq!(
        dw.len(),
        3 * kr * n,
        "three_rows_grad: weights of another shape"
    );
    if simd::covers(n) {
        return simd::three_rows_grad(pad, [wp, c, m], dy, n, dw, par);
    }
    let dy = Mat::rows(&dy[..m * n], n);
    for ky in 0..3 {
        let lhs = Mat::overlapping(&pad[ky * wp * c..], [m, kr], c).t();
        product(
            &mut dw[ky * kr * n..][..kr * n],
            [kr, n, m],
            true,
            lhs,
            dy,
            par,
        );
    }
}

/// The valid columns of a channels-last product on the padded width (`h × (w + 2)` pixels of
/// `n` floats) back in NCHW order, with `bias[o]` added to channel `o` if given: every element
/// of `dst`'s `n × h × w` is written.
pub(super) fn unborder_into(
    wide: &[f32],
    [n, h, w]: [usize; 3],
    bias: Option<&[f32]>,
    dst: &mut [MaybeUninit<f32>],
) {
    let (wp, plane) = (w + 2, h * w);
    assert!(
        dst.len() >= n * plane,
        "unborder: {} floats for {n} × {h} × {w}",
        dst.len()
    );
    for y in 0..h {
        to_planes(&wide[y * wp * n..], [n, w], bias, plane, &mut dst[y * w..]);
    }
}

/// `count` channels-last pixels of `n` floats (`src`) into `n` planes `stride` floats apart:
/// `dst[o·stride + p] = src[p·n + o] (+ bias[o])`. [`PIXEL_BLOCK`] pixels at a time, so the
/// block's floats stay in the L1 cache while each channel's run is put; with channels in
/// sixteens on AVX-512 each whole block is transposed in registers ([`simd::to_planes`]).
pub(super) fn to_planes(
    src: &[f32],
    [n, count]: [usize; 2],
    bias: Option<&[f32]>,
    stride: usize,
    dst: &mut [MaybeUninit<f32>],
) {
    if n == 0 || count == 0 {
        return;
    }
    assert!(
        src.len() >= count * n && dst.len() >= (n - 1) * stride + count && count <= stride,
        "to_planes: {} and {} floats for {count} pixels of {n} channels, planes {stride} apart",
        src.len(),
        dst.len()
    );
    assert!(
        bias.is_none_or(|b| b.len() >= n),
        "to_planes: a bias per channel"
    );
    let in_registers = simd::transposes(n);
    for x0 in (0..count).step_by(PIXEL_BLOCK) {
        let xs = (count - x0).min(PIXEL_BLOCK);
        let block = &src[x0 * n..][..xs * n];
        if in_registers && xs == PIXEL_BLOCK {
            simd::to_planes(block, n, bias, stride, &mut dst[x0..]);
            continue;
        }
        for o in 0..n {
            let at = o * stride + x0;
            let run = dst[at..at + xs].iter_mut().zip(block.chunks_exact(n));
            match bias {
                Some(b) => run.for_each(|(d, px)| _ = d.write(px[o] + b[o])),
                None => run.for_each(|(d, px)| _ = d.write(px[o])),
            }
        }
    }
}

/// Weights `[o, c, k, k]` with their taps first: `[k²c, o]`, rows in (ky, kx, ci) order, as
/// [`three_rows`] (for k = 3) and the channels-last products of [`crate::FastEncoder`] take them; or,
/// `flipped`, those of the input gradient, the convolution of `dy` with the kernel turned by
/// 180° and its channels swapped: `[k²o, c]`, `W'[(ky, kx, o), ci] = W[o, ci, k−1−ky, k−1−kx]`.
pub(crate) fn taps_major(w: &[f32], [o, c, k]: [usize; 3], flipped: bool) -> Vec<f32> {
    let kk = k * k;
    assert_eq!(w.len(), o * c * kk, "taps_major: weights of another shape");
    let mut out = unwritten(kk * c * o);
    if out.is_empty() {
        // SAFETY: empty.
        return unsafe { written(out) };
    }
    // One block of `c · o` floats a tap, written in order; the block of tap `t` (turned:
    // `kk − 1 − t`) reads tap `t` of every kernel.
    out.par_chunks_mut(c * o)
        .enumerate()
        .for_each(|(b, block)| {
            let t = if flipped { kk - 1 - b } else { b };
            if flipped {
                for (oo, row) in block.chunks_exact_mut(c).enumerate() {
                    for (ci, v) in row.iter_mut().enumerate() {
                        v.write(w[(oo * c + ci) * kk + t]);
                    }
                }
            } else {
                for (ci, row) in block.chunks_exact_mut(o).enumerate() {
                    for (oo, v) in row.iter_mut().enumerate() {
                        v.write(w[(oo * c + ci) * kk + t]);
                    }
                }
            }
        });
    // SAFETY: the `kk` blocks of `c · o` cover `out`, each written in full.
    unsafe { written(out) }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every float of a bordered image against its definition: pixel (y, x) of the padded
    /// `(h + 2) × (w + 2)` grid holds channel `ci` of image pixel (y − 1, x − 1) inside, zero
    /// on the border and in the two spare pixels; widths across and off the copy's blocks.
    #[test]
    fn a_bordered_image_holds_each_pixel_channels_last_inside_a_zero_border() {
        for [c, h, w] in [
            [1, 1, 1],
            [3, 5, 37],
            [16, 4, 16],
            [5, 3, 33],
            [2, 2, 15],
            [32, 3, 37],
            [48, 2, 16],
        ] {
            let src: Vec<f32> = (0..c * h * w).map(|i| i as f32 + 1.0).collect();
            // A reused buffer: stale values must not survive on the border.
            let mut dst = vec![f32::NAN; bordered_len([c, h, w])];
            border(&src, [c, h, w], &mut dst);
            let wp = w + 2;
            for (i, &v) in dst.iter().enumerate() {
                let (px, ci) = (i / c, i % c);
                let (y, x) = (px / wp, px % wp);
                let inside = (1..=h).contains(&y) && (1..=w).contains(&x);
                let want = if inside {
                    src[ci * h * w + (y - 1) * w + (x - 1)]
                } else {
                    0.0
                };
                assert_eq!(
                    v, want,
                    "c {c}, {h} × {w}: float {i} (pixel {y}, {x}, channel {ci})"
                );
            }
        }
    }

    /// [`unborder_into`] writes every valid column of a padded-width channels-last product at
    /// its NCHW index with its channel's bias (into a NaN-filled buffer, every index checked),
    /// and none of the two discarded columns a row; channel counts on and off the register
    /// transpose, widths across and off its blocks.
    #[test]
    fn unborder_writes_each_valid_pixel_at_its_planar_index() {
        for [n, h, w] in [
            [1, 1, 1],
            [3, 5, 37],
            [16, 4, 16],
            [4, 2, 17],
            [32, 3, 40],
            [48, 2, 16],
        ] {
            let wp = w + 2;
            let wide: Vec<f32> = (0..h * wp * n).map(|i| i as f32).collect();
            let bias: Vec<f32> = (0..n).map(|o| 0.5 + 1000.0 * o as f32).collect();
            for with_bias in [false, true] {
                let mut out = vec![f32::NAN; n * h * w];
                let b = with_bias.then_some(bias.as_slice());
                unborder_into(&wide, [n, h, w], b, as_slots(&mut out));
                for o in 0..n {
                    let add = if with_bias { bias[o] } else { 0.0 };
                    for y in 0..h {
                        for x in 0..w {
                            let want = wide[(y * wp + x) * n + o] + add;
                            assert_eq!(
                                out[(o * h + y) * w + x],
                                want,
                                "{n} × {h} × {w} at {o}, {y}, {x}"
                            );
                        }
                    }
                }
            }
        }
    }
}
