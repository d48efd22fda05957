//! The sizes of one convolution ([`Geom`]) and the classic unrolled layout of its input
//! (`im2col`, and its adjoint `col2im`) that [`super::conv`]'s general path multiplies.

use burn::backend::flex::FlexTensor;

use super::simd;

/// The sizes of one convolution.
#[derive(Debug, Clone, Copy)]
pub(super) struct Geom {
    pub(super) n: usize,
    pub(super) c: usize,
    pub(super) h: usize,
    pub(super) w: usize,
    pub(super) o: usize,
    pub(super) k: usize,
    pub(super) s: usize,
    pub(super) p: usize,
    pub(super) ho: usize,
    pub(super) wo: usize,
}

impl Geom {
    pub(super) fn of(x: &FlexTensor, weight: &FlexTensor, s: usize, p: usize) -> Self {
        let [n, c, h, w]: [usize; 4] = x.layout().shape().dims();
        let [o, ci, k, kw]: [usize; 4] = weight.layout().shape().dims();
        assert!(
            ci == c && kw == k,
            "train_conv2d: input {:?} and weight {:?} do not fit",
            [n, c, h, w],
            [o, ci, k, kw]
        );
        Self::new([n, c, h, w], o, k, s, p)
    }

    /// `n` images of `c × h × w` into `o` channels by a `k × k` kernel of stride `s` and
    /// padding `p`.
    pub(super) fn new([n, c, h, w]: [usize; 4], o: usize, k: usize, s: usize, p: usize) -> Self {
        assert!(
            s > 0 && h + 2 * p >= k && w + 2 * p >= k,
            "train_conv2d: {k} × {k} kernel, stride {s}, padding {p} on {h} × {w}"
        );
        Self {
            n,
            c,
            h,
            w,
            o,
            k,
            s,
            p,
            ho: (h + 2 * p - k) / s + 1,
            wo: (w + 2 * p - k) / s + 1,
        }
    }

    pub(super) fn pixels(&self) -> usize {
        self.ho * self.wo
    }

    /// Rows of the unrolled input, `c_in·k·k`.
    pub(super) fn taps(&self) -> usize {
        self.c * self.k * self.k
    }

    pub(super) fn image(&self) -> usize {
        self.c * self.h * self.w
    }

    /// The 1 × 1, stride 1, unpadded case: the image is its own unrolling.
    pub(super) fn direct(&self) -> bool {
        self.k == 1 && self.s == 1 && self.p == 0
    }

    /// The 3 × 3, stride 1, padding 1 case: three products on a [`border`]ed copy of the
    /// image, without im2col ([`three_rows`]).
    pub(super) fn three(&self) -> bool {
        self.k == 3 && self.s == 1 && self.p == 1
    }

    /// The 3 × 3 case of stride 2 and padding 1 with outputs in sixteens on AVX-512: the
    /// forward and the weight gradient on the direct kernels over the bordered image
    /// ([`simd::stride2_rows`]), without im2col; the input gradient by phases where the input
    /// channels come in sixteens as well ([`simd::stride2_input_grad`]).
    pub(super) fn stride2(&self) -> bool {
        self.k == 3 && self.s == 2 && self.p == 1 && simd::covers(self.o)
    }

    /// Whether the forward borders the image (and keeps it for the weight gradient).
    pub(super) fn bordered(&self) -> bool {
        self.three() || self.stride2()
    }
}

/// Output positions `lo..hi` along one axis whose input position `o·s + kx − p` lies inside
/// `0..len` (`out` positions in all).
pub(super) fn inside(kx: usize, s: usize, p: usize, len: usize, out: usize) -> (usize, usize) {
    let lo = if p > kx { (p - kx).div_ceil(s) } else { 0 };
    let hi = if len + p > kx {
        ((len - 1 + p - kx) / s + 1).min(out)
    } else {
        0
    };
    (lo.min(hi), hi)
}

/// `col[(ci, ky, kx), (oy, ox)] = x[ci, oy·s + ky − p, ox·s + kx − p]`, zero outside the image.
pub(super) fn im2col(g: &Geom, x: &[f32], col: &mut [f32]) {
    let (k, s, p, wo) = (g.k, g.s, g.p, g.wo);
    let pix = g.pixels();
    for ci in 0..g.c {
        let plane = &x[ci * g.h * g.w..][..g.h * g.w];
        for ky in 0..k {
            let (ylo, yhi) = inside(ky, s, p, g.h, g.ho);
            for kx in 0..k {
                let (xlo, xhi) = inside(kx, s, p, g.w, wo);
                let row = &mut col[((ci * k + ky) * k + kx) * pix..][..pix];
                row[..ylo * wo].fill(0.0);
                row[yhi * wo..].fill(0.0);
                for oy in ylo..yhi {
                    let dst = &mut row[oy * wo..][..wo];
                    dst[..xlo].fill(0.0);
                    dst[xhi..].fill(0.0);
                    if xhi == xlo {
                        continue;
                    }
                    let src = &plane[(oy * s + ky - p) * g.w..][..g.w];
                    if s == 1 {
                        let from = xlo + kx - p;
                        dst[xlo..xhi].copy_from_slice(&src[from..from + xhi - xlo]);
                    } else {
                        for (ox, d) in dst[xlo..xhi].iter_mut().enumerate() {
                            *d = src[(xlo + ox) * s + kx - p];
                        }
                    }
                }
            }
        }
    }
}

/// The adjoint of [`im2col`]: every entry of `col` is added into the pixel it was read from.
pub(super) fn col2im(g: &Geom, col: &[f32], x: &mut [f32]) {
    let (k, s, p, wo) = (g.k, g.s, g.p, g.wo);
    let pix = g.pixels();
    for ci in 0..g.c {
        let plane = &mut x[ci * g.h * g.w..][..g.h * g.w];
        for ky in 0..k {
            let (ylo, yhi) = inside(ky, s, p, g.h, g.ho);
            for kx in 0..k {
                let (xlo, xhi) = inside(kx, s, p, g.w, wo);
                if xhi == xlo {
                    continue;
                }
                let row = &col[((ci * k + ky) * k + kx) * pix..][..pix];
                for oy in ylo..yhi {
                    let src = &row[oy * wo + xlo..oy * wo + xhi];
                    let dst = &mut plane[(oy * s + ky - p) * g.w..][..g.w];
                    if s == 1 {
                        let from = xlo + kx - p;
                        for (d, v) in dst[from..from + src.len()].iter_mut().zip(src) {
                            *d += v;
                        }
                    } else {
                        for (ox, v) in src.iter().enumerate() {
                            dst[(xlo + ox) * s + kx - p] += v;
                        }
                    }
                }
            }
        }
    }
}

/// The unrolled image `x_n` as `[k·k·c_in, pixels]`: the image itself for a direct
/// convolution, else [`im2col`] into `col`.
pub(super) fn unrolled<'a>(g: &Geom, x_n: &'a [f32], col: &'a mut Vec<f32>) -> &'a [f32] {
    if g.direct() {
        return x_n;
    }
    col.resize(g.taps() * g.pixels(), 0.0);
    im2col(g, x_n, col);
    col
}
