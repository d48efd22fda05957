//! The batch norm's per-plane loops ([`super::norm`]), compiled for the widest vector unit the
//! CPU reports at run time.
//!
//! The crate builds for baseline x86-64, so a plain loop vectorises to SSE's four lanes. The
//! batch norm's passes are elementwise loops and sums with independent partial sums, which the
//! compiler vectorises to whatever width it is allowed: [`widest!`] compiles a loop three
//! times, for AVX-512F (16 lanes), for AVX2 with FMA (8) and for the baseline, and picks one
//! per call. The arithmetic is the same Rust in every copy (Rust never contracts `a·b + c`
//! into a fused multiply-add, and every sum keeps its order), so the copies give the same bits;
//! the tests run every copy the CPU has (a thread-local cap on the dispatch) against the
//! baseline's bits.
//!
//! On the Intel VM (AVX-512, 2 threads) the batch norm is about a fifth of the ResNet-18
//! training step (64 × 48, width 16, batch 8) and bound by memory more than by arithmetic:
//! the wide copies and the channel-by-channel passes of [`super::norm`] together took its
//! forward from 0.32 to 0.29 s over 12 steps, the whole step about 2 % (`rig bench train
//! --speed`, per-layer timers not committed). [`grad_sums`] stays on the baseline: the wide
//! copy of its sixteen partial sums shuffled lanes at every step and was slower.

use std::mem::MaybeUninit;

use super::kernels::sum_of;

/// A float of an output buffer, written once.
pub(super) type Slot = MaybeUninit<f32>;

#[cfg(test)]
thread_local! {
    /// The widest copy [`widest!`] may take on this thread: 2 AVX-512F, 1 AVX2 + FMA, 0 the
    /// baseline. The tests lower it to run every copy this CPU has.
    static CAP: std::cell::Cell<u8> = const { std::cell::Cell::new(2) };
}

/// Whether [`widest!`] may take the copy of `level` (see `CAP`; always outside the tests).
#[inline(always)]
fn allowed(level: u8) -> bool {
    #[cfg(test)]
    return CAP.with(|c| c.get()) >= level;
    #[cfg(not(test))]
    {
        let _ = level;
        true
    }
}

/// Defines `fn $name` as a dispatcher over three compilations of `$body`: AVX-512F, AVX2 with
/// FMA, and the baseline, taken by the first the CPU has.
macro_rules! widest {
    ($(#[$meta:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?
        $body:block) => {
        $(#[$meta])*
        $vis fn $name($($arg: $ty),*) $(-> $ret)? {
            #[inline(always)]
            fn body($($arg: $ty),*) $(-> $ret)? $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                fn avx512($($arg: $ty),*) $(-> $ret)? {
                    body($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                fn avx2($($arg: $ty),*) $(-> $ret)? {
                    body($($arg),*)
                }
                if allowed(2) && std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU reports AVX-512F.
                    return unsafe { avx512($($arg),*) };
                }
                if allowed(1)
                    && std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: the CPU reports AVX2 and FMA.
                    return unsafe { avx2($($arg),*) };
                }
            }
            body($($arg),*)
        }
    };
}

widest! {
    /// `Σ v` in f64 ([`sum_of`]'s eight partial sums).
    pub(super) fn plane_sum(p: &[f32]) -> f64 {
        sum_of(p, f64::from)
    }
}

widest! {
    /// `Σ (v − mean)²` in f64.
    pub(super) fn plane_sq(p: &[f32], mean: f64) -> f64 {
        sum_of(p, |v| {
            let d = v as f64 - mean;
            d * d
        })
    }
}

widest! {
    /// One tap's weight gradient of a stride-1, unpadded convolution with at most four output
    /// channels: `out[o·c + ci] = Σ_images Σ_(y, x) dy[o, y, x] · x[y + ky, x + kx, ci]` for
    /// `dims = [c, w, ho, wo]` and `tap = [ky, kx]`, over `images`, each an input channels-last
    /// (`w` pixels a row, `c` floats a pixel, `c` in sixteens) and its four output-gradient
    /// planes (missing outputs as zero planes). Sixteen channels at a time, their four sums in
    /// registers while the pixels stream past.
    pub(super) fn tap_grad(
        images: &[(&[f32], [&[f32]; 4])],
        dims: [usize; 4],
        tap: [usize; 2],
        out: &mut [f32],
    ) {
        let ([c, w, ho, wo], [ky, kx]) = (dims, tap);
        let o = out.len() / c.max(1);
        out.fill(0.0);
        for (xcl, dy) in images {
            for c0 in (0..c).step_by(16) {
                let mut acc = [[0.0f32; 16]; 4];
                for y in 0..ho {
                    let row = &xcl[((y + ky) * w + kx) * c..][..wo * c];
                    let d = dy.map(|p| &p[y * wo..][..wo]);
                    for x in 0..wo {
                        let v: &[f32; 16] = row[x * c + c0..][..16].try_into().unwrap();
                        for (a, d) in acc.iter_mut().zip(&d) {
                            let g = d[x];
                            for j in 0..16 {
                                a[j] += g * v[j];
                            }
                        }
                    }
                }
                for (oi, a) in acc.iter().enumerate().take(o) {
                    for (t, v) in out[oi * c + c0..][..16].iter_mut().zip(a) {
                        *t += v;
                    }
                }
            }
        }
    }
}

/// The ReLU as burn's flex backend computes it: NaN goes through.
#[inline(always)]
pub(super) fn activation(z: f32, relu: bool) -> f32 {
    if relu && z <= 0.0 { 0.0 } else { z }
}

/// The ReLU's gradient as [`activation`] passes it: `d` where the output `y` was positive (or
/// NaN), else 0.
#[inline(always)]
pub(super) fn activation_grad(d: f32, y: f32, relu: bool) -> f32 {
    if relu && y <= 0.0 { 0.0 } else { d }
}

/// One channel's affine map of the normalisation: `z = (x − mu)·scale + shift`.
#[derive(Debug, Clone, Copy)]
pub(super) struct PlaneMap {
    pub mu: f32,
    pub scale: f32,
    pub shift: f32,
}

widest! {
    /// `yp = act((xp − μ)·scale + shift (+ rp))`, every slot written. `(x − μ)` first: exact
    /// for values near μ, where `x·s + (β − μ·s)` would cancel.
    pub(super) fn norm_plane(
        yp: &mut [Slot],
        xp: &[f32],
        rp: Option<&[f32]>,
        map: PlaneMap,
        relu: bool,
    ) {
        let PlaneMap { mu, scale, shift } = map;
        match (rp, relu) {
            (Some(rp), true) => {
                for ((o, &v), &r) in yp.iter_mut().zip(xp).zip(rp) {
                    o.write(activation((v - mu) * scale + shift + r, true));
                }
            }
            (Some(rp), false) => {
                for ((o, &v), &r) in yp.iter_mut().zip(xp).zip(rp) {
                    o.write((v - mu) * scale + shift + r);
                }
            }
            (None, true) => {
                for (o, &v) in yp.iter_mut().zip(xp) {
                    o.write(activation((v - mu) * scale + shift, true));
                }
            }
            (None, false) => {
                for (o, &v) in yp.iter_mut().zip(xp) {
                    o.write((v - mu) * scale + shift);
                }
            }
        }
    }
}

/// Values [`grad_sums`] adds in f32 before it carries their sums into f64.
const SUM_BLOCK: usize = 256;

/// [`grad_sums`] for one ReLU setting.
#[inline(always)]
fn grad_sums_of<const RELU: bool>(
    dy: &[f32],
    y: &[f32],
    x: &[f32],
    mean: f32,
    inv: f32,
) -> (f64, f64) {
    const LANES: usize = 16;
    let (mut tb, mut tg) = (0.0f64, 0.0f64);
    let blocks = dy
        .chunks(SUM_BLOCK)
        .zip(y.chunks(SUM_BLOCK))
        .zip(x.chunks(SUM_BLOCK));
    for ((db, yb), xb) in blocks {
        let (mut sb, mut sg) = ([0.0f32; LANES], [0.0f32; LANES]);
        let (dc, dr) = db.as_chunks::<LANES>();
        let (yc, yr) = yb.as_chunks::<LANES>();
        let (xc, xr) = xb.as_chunks::<LANES>();
        for ((d, yv), v) in dc.iter().zip(yc).zip(xc) {
            for j in 0..LANES {
                let dz = activation_grad(d[j], yv[j], RELU);
                sb[j] += dz;
                sg[j] += dz * ((v[j] - mean) * inv);
            }
        }
        for (j, ((&d, &yv), &v)) in dr.iter().zip(yr).zip(xr).enumerate() {
            let dz = activation_grad(d, yv, RELU);
            sb[j] += dz;
            sg[j] += dz * ((v - mean) * inv);
        }
        tb += sb.iter().map(|&v| f64::from(v)).sum::<f64>();
        tg += sg.iter().map(|&v| f64::from(v)).sum::<f64>();
    }
    (tb, tg)
}

/// Per channel `(Σ dz, Σ dz·x̂)` over one plane, `dz` from `dy` through the ReLU's gradient
/// (with `relu`, `y` the output; else `y` is not read), `x̂ = (x − mean)·inv`. Sixteen f32
/// partial sums of each a block of [`SUM_BLOCK`] values (the loop vectorises, and each f32
/// sum adds at most 16 terms), carried into f64 after each block: sums in f64 throughout
/// cost a ResNet-18 step several per cent.
pub(super) fn grad_sums(
    dy: &[f32],
    y: &[f32],
    x: &[f32],
    mean: f32,
    inv: f32,
    relu: bool,
) -> (f64, f64) {
    if relu {
        grad_sums_of::<true>(dy, y, x, mean, inv)
    } else {
        grad_sums_of::<false>(dy, y, x, mean, inv)
    }
}

/// One channel's input gradient: `dx = k·(dz − mdb − (x − mu)·inv·mdg)`, with `k = γ·inv`,
/// `mdb = Σdz / m` and `mdg = Σdz·x̂ / m`.
#[derive(Debug, Clone, Copy)]
pub(super) struct PlaneGrad {
    pub k: f32,
    pub mu: f32,
    pub inv: f32,
    pub mdb: f32,
    pub mdg: f32,
}

widest! {
    /// One plane of the input gradient ([`PlaneGrad`]), `dz` from `dyp` through the ReLU's
    /// gradient where `relu` (`yp` the output), and written to `dzp` too when given.
    pub(super) fn grad_plane(
        dxp: &mut [Slot],
        dzp: Option<&mut [Slot]>,
        dyp: &[f32],
        yp: &[f32],
        xp: &[f32],
        relu: bool,
        c: PlaneGrad,
    ) {
        let grad = |d: f32, v: f32| c.k * (d - c.mdb - (v - c.mu) * c.inv * c.mdg);
        match dzp {
            Some(dzp) => {
                let dzs = dyp.iter().zip(yp).map(|(&d, &y)| activation_grad(d, y, relu));
                for (((o, z), d), &v) in dxp.iter_mut().zip(dzp).zip(dzs).zip(xp) {
                    z.write(d);
                    o.write(grad(d, v));
                }
            }
            None if relu => {
                let dzs = dyp.iter().zip(yp).map(|(&d, &y)| activation_grad(d, y, true));
                for ((o, d), &v) in dxp.iter_mut().zip(dzs).zip(xp) {
                    o.write(grad(d, v));
                }
            }
            None => {
                for ((o, &d), &v) in dxp.iter_mut().zip(dyp).zip(xp) {
                    o.write(grad(d, v));
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values with a tail past every vector width, negative, zero and NaN among them.
    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| {
                let h = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed) >> 8;
                match i % 29 {
                    0 => f32::NAN,
                    1 => 0.0,
                    _ => (h % 20_000) as f32 / 1000.0 - 10.0,
                }
            })
            .collect()
    }

    fn bits(v: &[Slot]) -> Vec<u32> {
        // SAFETY: the callers read only slots the loops under test wrote in full.
        v.iter()
            .map(|s| unsafe { s.assume_init() }.to_bits())
            .collect()
    }

    #[test]
    fn the_wide_copies_give_the_baselines_bits() {
        // Every copy this CPU has (AVX-512, AVX2 + FMA, the baseline), through the dispatch;
        // the references are the same expressions written out here, compiled for the baseline.
        for cap in [2, 1, 0] {
            CAP.with(|c| c.set(cap));
            each_copy_matches(cap);
        }
        CAP.with(|c| c.set(2));
    }

    fn each_copy_matches(cap: u8) {
        for n in [0, 1, 15, 16, 37, 1000] {
            let (x, r, d) = (values(n, 1), values(n, 2), values(n, 3));
            let y: Vec<f32> = values(n, 4);
            let finite: Vec<f32> = x
                .iter()
                .map(|v| if v.is_nan() { 1.5 } else { *v })
                .collect();
            assert_eq!(
                plane_sum(&finite),
                sum_of(&finite, f64::from),
                "sum, {n} values, copy {cap}"
            );
            let sq = sum_of(&finite, |v| (v as f64 - 0.3) * (v as f64 - 0.3));
            assert_eq!(
                plane_sq(&finite, 0.3),
                sq,
                "squares, {n} values, copy {cap}"
            );

            let map = PlaneMap {
                mu: 0.25,
                scale: 1.7,
                shift: -0.4,
            };
            for (rp, relu) in [
                (None, false),
                (None, true),
                (Some(&r[..]), false),
                (Some(&r[..]), true),
            ] {
                let mut out = vec![Slot::uninit(); n];
                norm_plane(&mut out, &x, rp, map, relu);
                let want: Vec<u32> = (0..n)
                    .map(|i| {
                        let z = (x[i] - 0.25) * 1.7 + -0.4 + rp.map_or(0.0, |r| r[i]);
                        activation(z, relu).to_bits()
                    })
                    .collect();
                assert_eq!(
                    bits(&out),
                    want,
                    "normalised, {n} values, relu {relu}, copy {cap}"
                );
            }

            let c = PlaneGrad {
                k: 0.9,
                mu: 0.1,
                inv: 1.3,
                mdb: 0.05,
                mdg: -0.2,
            };
            for relu in [false, true] {
                let (mut dx, mut dz) = (vec![Slot::uninit(); n], vec![Slot::uninit(); n]);
                grad_plane(&mut dx, Some(&mut dz), &d, &y, &x, relu, c);
                let dz_want: Vec<f32> = (0..n).map(|i| activation_grad(d[i], y[i], relu)).collect();
                let dx_want: Vec<u32> = (0..n)
                    .map(|i| (0.9 * (dz_want[i] - 0.05 - (x[i] - 0.1) * 1.3 * -0.2)).to_bits())
                    .collect();
                let dz_bits: Vec<u32> = dz_want.iter().map(|v| v.to_bits()).collect();
                assert_eq!(
                    bits(&dx),
                    dx_want,
                    "dx, {n} values, relu {relu}, copy {cap}"
                );
                assert_eq!(
                    bits(&dz),
                    dz_bits,
                    "dz, {n} values, relu {relu}, copy {cap}"
                );
                let mut dx2 = vec![Slot::uninit(); n];
                grad_plane(&mut dx2, None, &d, &y, &x, relu, c);
                assert_eq!(
                    bits(&dx2),
                    dx_want,
                    "dx without dz, {n} values, relu {relu}, copy {cap}"
                );
            }
        }
    }
}
