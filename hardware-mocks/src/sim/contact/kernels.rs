//! Influence coefficients: surface displacement at a cell centre caused by a uniform traction
//! on one square cell, in closed form for the half-space and with a numerically integrated
//! correction for a finite layer bonded to a rigid base.

use rustfft::num_complex::Complex64;

use super::fft::Conv2;

/// `a · asinh(b / |a|)`, continuous at `a = 0` (where it is 0).
fn xasinh(a: f64, b: f64) -> f64 {
    if a == 0.0 {
        0.0
    } else {
        a * (b / a.abs()).asinh()
    }
}

/// `Σ ±Φ(X, Y)` over the corners of the cell of half-width `c` seen from offset `(x, y)`:
/// the integral of `φ` over the cell when `∂²Φ/∂X∂Y = φ`.
fn corners(phi: impl Fn(f64, f64) -> f64, x: f64, y: f64, c: f64) -> f64 {
    phi(x + c, y + c) - phi(x + c, y - c) - phi(x - c, y + c) + phi(x - c, y - c)
}

/// `∫∫_cell dA / ρ` (Love 1929; Johnson, Contact Mechanics, §3.4): `Φ = X asinh(Y/|X|) + Y
/// asinh(X/|Y|)`.
pub(crate) fn cell_inv_r(x: f64, y: f64, c: f64) -> f64 {
    corners(|a, b| xasinh(a, b) + xasinh(b, a), x, y, c)
}

/// `∫∫_cell X² / ρ³ dA`: `Φ = Y asinh(X/|Y|)`.
fn cell_xx_r3(x: f64, y: f64, c: f64) -> f64 {
    corners(|a, b| xasinh(b, a), x, y, c)
}

/// `∫∫_cell X Y / ρ³ dA`: `Φ = −ρ`.
fn cell_xy_r3(x: f64, y: f64, c: f64) -> f64 {
    corners(|a, b| -a.hypot(b), x, y, c)
}

/// Bessel function J0 (Abramowitz & Stegun 9.4.1 and 9.4.3; |error| < 5e-8).
pub(crate) fn bessel_j0(x: f64) -> f64 {
    let x = x.abs();
    if x <= 3.0 {
        let t = (x / 3.0).powi(2);
        1.0 + t
            * (-2.249_999_7
                + t * (1.265_620_8
                    + t * (-0.316_386_6 + t * (0.044_447_9 + t * (-0.003_944_4 + t * 0.000_21)))))
    } else {
        let t = 3.0 / x;
        let f0 = 0.797_884_56
            + t * (-0.000_000_77
                + t * (-0.005_527_40
                    + t * (-0.000_095_12
                        + t * (0.001_372_37 + t * (-0.000_728_05 + t * 0.000_144_76)))));
        let theta = x - std::f64::consts::FRAC_PI_4
            + t * (-0.041_663_97
                + t * (-0.000_039_54
                    + t * (0.002_625_73
                        + t * (-0.000_541_25 + t * (-0.000_293_33 + t * 0.000_135_58)))));
        f0 * theta.cos() / x.sqrt()
    }
}

/// Compliance of a layer of thickness h bonded to a rigid base relative to the half-space, for
/// a surface pressure wave of wavenumber k, as a function of `x = k h` (frictionless top):
///
/// `C(x) = [(3−4ν) sinh 2x − 2x] / [(3−4ν) cosh 2x + 2x² + ((3−4ν)² + 1)/2]`,
///
/// so that `ũ_z = 2 C(kh) p̃ / (E* k)` (the standard layer Green's function, as used by Carbone
/// & Mangialardi 2008). Checks: `C → 1` for `kh → ∞` (half-space); `2C/(E*k) → h/M` for
/// `kh → 0` (the oedometric, Winkler limit); for ν = ½ and small kh, `ũ_z = k² h³ p̃ / E`
/// (thin-film lubrication flow of an incompressible layer).
pub(crate) fn layer_factor(x: f64, nu: f64) -> f64 {
    let k = 3.0 - 4.0 * nu;
    if x > 40.0 {
        return 1.0;
    }
    let num = k * (2.0 * x).sinh() - 2.0 * x;
    let den = k * (2.0 * x).cosh() + 2.0 * x * x + (k * k + 1.0) / 2.0;
    num / den
}

/// `f(r) = ∫₀^∞ (C(kh) − 1) J0(k r) dk` (1/mm): the smooth difference between the layer's and the
/// half-space's point-load responses, `u_z = (1/r + f(r)) P / (π E*)`. Tabulated in r.
pub(crate) struct LayerCorrection {
    dr: f64,
    values: Vec<f64>,
}

impl LayerCorrection {
    pub fn new(h: f64, nu: f64, r_max: f64, cell: f64) -> Self {
        let dr = (h / 40.0).min(cell / 2.0).max(r_max / 4000.0);
        let n_r = (r_max / dr).ceil() as usize + 2;
        // Integrate in x = k h up to 30 (C − 1 ~ x² e^{−2x} beyond), ≥ 20 points per period of
        // J0(x r / h).
        let x_max = 30.0;
        let rho_max = r_max / h;
        let dx = (0.02_f64).min(std::f64::consts::TAU / (20.0 * rho_max.max(1e-9)));
        let mut n_x = (x_max / dx).ceil() as usize;
        n_x += n_x % 2; // Simpson needs an even count
        let dx = x_max / n_x as f64;
        let weights: Vec<f64> = (0..=n_x)
            .map(|i| {
                let x = i as f64 * dx;
                let w = if i == 0 || i == n_x {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                w * dx / 3.0 * (layer_factor(x, nu) - 1.0)
            })
            .collect();
        let values = (0..n_r)
            .map(|ir| {
                let rho = ir as f64 * dr / h;
                let s: f64 = weights
                    .iter()
                    .enumerate()
                    .map(|(i, w)| w * bessel_j0(i as f64 * dx * rho))
                    .sum();
                s / h
            })
            .collect();
        Self { dr, values }
    }

    pub fn at(&self, r: f64) -> f64 {
        let t = r / self.dr;
        let i = (t.floor() as usize).min(self.values.len() - 2);
        let f = t - i as f64;
        self.values[i] * (1.0 - f) + self.values[i + 1] * f
    }
}

/// A kernel's values at the cell offsets of a grid of `nx × ny` cells: `(di, dj)` with
/// `|di| < nx`, `|dj| < ny`. Evaluated once per grid; the spectrum of any window of the grid
/// (see `window.rs`) is transformed from it.
pub(crate) struct OffsetTable {
    nx: usize,
    ny: usize,
    values: Vec<f64>,
}

impl OffsetTable {
    pub fn new(nx: usize, ny: usize, f: impl Fn(isize, isize) -> f64) -> Self {
        let (sx, sy) = (nx as isize, ny as isize);
        let mut values = Vec::with_capacity((2 * nx - 1) * (2 * ny - 1));
        for dj in -(sy - 1)..sy {
            for di in -(sx - 1)..sx {
                values.push(f(di, dj));
            }
        }
        Self { nx, ny, values }
    }

    /// The value at offset `(di, dj)`; panics outside the table (a window is never larger
    /// than its grid).
    pub fn at(&self, di: isize, dj: isize) -> f64 {
        let (sx, sy) = (self.nx as isize, self.ny as isize);
        assert!(
            di.abs() < sx && dj.abs() < sy,
            "offset ({di}, {dj}) outside the table"
        );
        self.values[((dj + sy - 1) * (2 * sx - 1) + di + sx - 1) as usize]
    }

    /// Spectrum of the kernel on `conv`'s (padded) grid, which must not exceed the table's.
    pub fn hat(&self, conv: &mut Conv2) -> Vec<Complex64> {
        conv.kernel_hat(|di, dj| self.at(di, dj))
    }
}

/// The normal influence kernel in units of 1/E* (multiply by 1/E*): displacement into the gel
/// at a cell centre per unit pressure on a cell, at every offset of an `nx × ny` grid.
/// `thickness_mm`: `None` for the half-space, `Some(h)` for the bonded layer.
pub(crate) fn normal_offsets(
    nx: usize,
    ny: usize,
    cell: f64,
    nu: f64,
    thickness_mm: Option<f64>,
) -> OffsetTable {
    let c = cell / 2.0;
    let r_max = cell * ((nx as f64).hypot(ny as f64) + 1.0);
    let corr = thickness_mm.map(|h| LayerCorrection::new(h, nu, r_max, cell));
    OffsetTable::new(nx, ny, |di, dj| {
        let (x, y) = (di as f64 * cell, dj as f64 * cell);
        let mut v = cell_inv_r(x, y, c);
        if let Some(corr) = &corr {
            // f is smooth on the scale of h: midpoint rule over the cell.
            v += cell * cell * corr.at(x.hypot(y));
        }
        v / std::f64::consts::PI
    })
}

/// Tangential (Cerruti) influence spectra in units of 1/E: `u_x = Kxx q_x + Kxy q_y`,
/// `u_y = Kxy q_x + Kyy q_y` (Johnson, Contact Mechanics, eq. 2.19; the normal-tangential
/// coupling through (1−2ν) is neglected, which is exact for ν = ½ and within 2% of it for the
/// gel's ν = 0.49). Also returns the largest eigenvalue of the circulant operator (for the
/// solver's step), in units of 1/E.
pub(crate) struct TangentialKernel {
    /// The operator on the packed traction spectrum `Z` of `q_x + i·q_y`: the spectrum of
    /// `u_x + i·u_y` is `W[k] = P[k] Z[k] + Q[k] conj(Z[−k])`, with `P = (Kxx + Kyy)/2` and
    /// `Q = (Kxx − Kyy)/2 + i Kxy` (from `Q_x = (Z + conj Z[−k])/2`, `Q_y = (Z − conj Z[−k])/2i`
    /// for real tractions). One forward and one inverse transform per application.
    pub packed_p: Vec<Complex64>,
    pub packed_q: Vec<Complex64>,
    /// Padded index of `−k` for each padded index `k`.
    pub mirror: Vec<u32>,
    pub lambda_max: f64,
}

/// The Cerruti compliances `Kxx`, `Kyy`, `Kxy` (units 1/E) at every offset of a grid.
pub(crate) struct TangentialOffsets {
    xx: OffsetTable,
    yy: OffsetTable,
    xy: OffsetTable,
}

pub(crate) fn tangential_offsets(nx: usize, ny: usize, cell: f64, nu: f64) -> TangentialOffsets {
    let c = cell / 2.0;
    let pre = (1.0 + nu) / std::f64::consts::PI;
    let at = |di: isize, dj: isize| (di as f64 * cell, dj as f64 * cell);
    TangentialOffsets {
        xx: OffsetTable::new(nx, ny, |di, dj| {
            let (x, y) = at(di, dj);
            pre * ((1.0 - nu) * cell_inv_r(x, y, c) + nu * cell_xx_r3(x, y, c))
        }),
        yy: OffsetTable::new(nx, ny, |di, dj| {
            let (x, y) = at(di, dj);
            pre * ((1.0 - nu) * cell_inv_r(x, y, c) + nu * cell_xx_r3(y, x, c))
        }),
        xy: OffsetTable::new(nx, ny, |di, dj| {
            let (x, y) = at(di, dj);
            pre * nu * cell_xy_r3(x, y, c)
        }),
    }
}

/// The packed Cerruti operator on `conv`'s grid (a window of the tables' grid, or all of it).
pub(crate) fn tangential_kernel(conv: &mut Conv2, offsets: &TangentialOffsets) -> TangentialKernel {
    let xx = offsets.xx.hat(conv);
    let yy = offsets.yy.hat(conv);
    let xy = offsets.xy.hat(conv);
    let lambda_max = xx
        .iter()
        .zip(&yy)
        .zip(&xy)
        .map(|((a, d), b)| {
            let (a, d, b) = (a.re, d.re, b.norm());
            (a + d) / 2.0 + (((a - d) / 2.0).powi(2) + b * b).sqrt()
        })
        .fold(0.0, f64::max);
    let packed_p = xx.iter().zip(&yy).map(|(a, d)| (a + d) * 0.5).collect();
    let packed_q = xx
        .iter()
        .zip(&yy)
        .zip(&xy)
        .map(|((a, d), b)| (a - d) * 0.5 + Complex64::new(0.0, 1.0) * b)
        .collect();
    let (px, py) = (conv.px, conv.py);
    let mirror = (0..px * py)
        .map(|k| {
            let (i, j) = (k % px, k / px);
            (((py - j) % py) * px + (px - i) % px) as u32
        })
        .collect();
    TangentialKernel {
        packed_p,
        packed_q,
        mirror,
        lambda_max,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn j0_matches_known_values() {
        assert!((bessel_j0(0.0) - 1.0).abs() < 1e-7);
        assert!((bessel_j0(1.0) - 0.765_197_686_6).abs() < 1e-7);
        assert!((bessel_j0(2.404_825_557_7)).abs() < 1e-7);
        assert!((bessel_j0(10.0) + 0.245_935_764_5).abs() < 1e-7);
    }

    #[test]
    fn square_centre_influence_is_loves() {
        // Centre of a uniformly loaded square of side s: 4 s ln(1 + √2) (Love 1929).
        let s = 0.3;
        let v = cell_inv_r(0.0, 0.0, s / 2.0);
        assert!((v - 4.0 * s * (1.0 + 2f64.sqrt()).ln()).abs() < 1e-12);
        // Far away it tends to area / distance.
        let far = cell_inv_r(30.0, 40.0, s / 2.0);
        assert!((far - s * s / 50.0).abs() / (s * s / 50.0) < 1e-4);
    }

    #[test]
    fn layer_factor_limits() {
        let nu = 0.3;
        assert!((layer_factor(50.0, nu) - 1.0).abs() < 1e-12);
        // k → 0: 2 C / k → h (1+ν)(1−2ν) / (1−ν) · 2/(E*·...) i.e. C/x → (1−2ν)/(2(1−ν)²).
        let x = 1e-4;
        let want = (1.0 - 2.0 * nu) / (2.0 * (1.0 - nu).powi(2));
        assert!((layer_factor(x, nu) / x - want).abs() / want < 1e-3);
    }
}
