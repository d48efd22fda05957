//! Normal contact solvers: the Polonsky–Keer constrained conjugate gradient on the BEM grid,
//! the Winkler layer and the Hertz solution.

use rustfft::num_complex::Complex64;

use super::fft::Conv2;

/// Relative change of the pressure field at which the CG stops.
const CG_TOL: f64 = 1e-7;
/// Iteration cap of the CG (it typically needs 20–200).
const CG_MAX_ITER: u32 = 2000;

/// Result of a gridded normal solve.
pub(crate) struct NormalGrid {
    /// Pressure per cell, MPa.
    pub p: Vec<f64>,
    /// Displacement into the gel per cell, mm (≥ 0 where pressed in).
    pub w: Vec<f64>,
    pub iterations: u32,
    pub converged: bool,
}

/// Displacement-controlled frictionless contact (Polonsky & Keer 1999, Wear 231, without their
/// load constraint since the depth is given): find `p ≥ 0` with gap `g = K p − δ ≥ 0` and
/// `p · g = 0`, where `δ` is the geometric overlap of the indenter with the undeformed gel
/// (`−∞` for cells under no indenter material) and `K = kernel / E*`.
pub(crate) fn polonsky_keer(
    conv: &mut Conv2,
    hat: &[Complex64],
    inv_e_star: f64,
    overlap: &[f64],
) -> NormalGrid {
    let n = overlap.len();
    let candidate: Vec<bool> = overlap.iter().map(|d| d.is_finite()).collect();
    let mut work = Vec::new();
    let mut u = vec![0.0; n];
    let mut r = vec![0.0; n];
    // Start from the overlap, scaled by the best single factor (one steepest-descent step).
    let mut p: Vec<f64> = overlap.iter().map(|&d| d.max(0.0)).collect();
    conv.convolve(hat, &p, inv_e_star, &mut work, &mut u);
    let num: f64 = p.iter().map(|x| x * x).sum();
    let den: f64 = p.iter().zip(&u).map(|(a, b)| a * b).sum();
    if num == 0.0 || den.is_nan() || den <= 0.0 {
        return NormalGrid {
            p: vec![0.0; n],
            w: vec![0.0; n],
            iterations: 0,
            converged: true,
        };
    }
    let s = num / den;
    p.iter_mut().for_each(|x| *x *= s);

    let mut t = vec![0.0; n];
    let mut g = vec![0.0; n];
    let mut g_old = 1.0;
    let mut conjugate = false;
    let mut iterations = 0;
    let mut converged = false;
    while iterations < CG_MAX_ITER {
        iterations += 1;
        conv.convolve(hat, &p, inv_e_star, &mut work, &mut u);
        for i in 0..n {
            g[i] = if candidate[i] {
                u[i] - overlap[i]
            } else {
                f64::INFINITY
            };
        }
        let gg: f64 = (0..n).filter(|&i| p[i] > 0.0).map(|i| g[i] * g[i]).sum();
        let beta = if conjugate { gg / g_old } else { 0.0 };
        for i in 0..n {
            t[i] = if p[i] > 0.0 { g[i] + beta * t[i] } else { 0.0 };
        }
        g_old = gg;
        conv.convolve(hat, &t, inv_e_star, &mut work, &mut r);
        let (mut gt, mut rt) = (0.0, 0.0);
        for i in 0..n {
            if p[i] > 0.0 {
                gt += g[i] * t[i];
                rt += r[i] * t[i];
            }
        }
        let tau = if rt > 0.0 { gt / rt } else { 0.0 };
        let mut changed = 0.0;
        let mut total = 0.0;
        let mut overlap_added = false;
        for i in 0..n {
            let old = p[i];
            if old > 0.0 {
                p[i] = (old - tau * t[i]).max(0.0);
            } else if candidate[i] && g[i] < 0.0 {
                // Penetration outside the current contact: let pressure in there.
                p[i] = -tau * g[i];
                overlap_added = true;
            }
            changed += (p[i] - old).abs();
            total += p[i];
        }
        conjugate = !overlap_added;
        if total == 0.0 {
            break;
        }
        if changed <= CG_TOL * total {
            converged = true;
            break;
        }
    }
    conv.convolve(hat, &p, inv_e_star, &mut work, &mut u);
    NormalGrid {
        p,
        w: u,
        iterations,
        converged,
    }
}

/// Hertz contact of a sphere of radius `r_mm` pressed `depth_mm` into a half-space (Johnson,
/// Contact Mechanics, §4.2): `a = √(R d)`, `F = 4/3 E* √R d^{3/2}`, `p0 = 2 E* a / (π R)`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Hertz {
    pub a_mm: f64,
    pub force_n: f64,
    pub p0_mpa: f64,
    pub e_star: f64,
}

impl Hertz {
    pub fn new(r_mm: f64, depth_mm: f64, e_star: f64) -> Self {
        let a = (r_mm * depth_mm).sqrt();
        Self {
            a_mm: a,
            force_n: 4.0 / 3.0 * e_star * r_mm.sqrt() * depth_mm.powf(1.5),
            p0_mpa: 2.0 * e_star * a / (std::f64::consts::PI * r_mm),
            e_star,
        }
    }

    pub fn pressure(&self, r: f64) -> f64 {
        if r < self.a_mm {
            self.p0_mpa * (1.0 - (r / self.a_mm).powi(2)).sqrt()
        } else {
            0.0
        }
    }

    /// Displacement into the gel at radius r (Johnson eq. 3.41a/b).
    pub fn displacement(&self, r: f64) -> f64 {
        let a = self.a_mm;
        let k = std::f64::consts::PI * self.p0_mpa / (4.0 * a * self.e_star);
        if r <= a {
            k * (2.0 * a * a - r * r)
        } else {
            let s = a / r;
            self.p0_mpa / (2.0 * a * self.e_star)
                * ((2.0 * a * a - r * r) * s.asin() + r * a * (1.0 - s * s).sqrt())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hertz_displacement_is_continuous_at_the_edge_and_equals_depth_at_centre() {
        let h = Hertz::new(4.0, 0.5, 0.26);
        assert!((h.displacement(0.0) - 0.5).abs() < 1e-12);
        let inside = h.displacement(h.a_mm * (1.0 - 1e-9));
        let outside = h.displacement(h.a_mm * (1.0 + 1e-9));
        assert!((inside - outside).abs() < 1e-6, "{inside} vs {outside}");
        // Far field of a point load: F / (π E* r).
        let r = 200.0;
        let want = h.force_n / (std::f64::consts::PI * 0.26 * r);
        assert!((h.displacement(r) - want).abs() / want < 1e-3);
    }
}
