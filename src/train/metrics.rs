//! Scores: MAE and R² per force axis, the total-force MAE, and FID/KID between image-feature
//! sets.

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use serde::Serialize;

pub const AXES: [&str; 3] = ["Fx", "Fy", "Fz"];

/// Mean absolute error; NaN for empty input.
pub fn mae(pred: &[f64], truth: &[f64]) -> f64 {
    let n = pred.len().min(truth.len());
    if n == 0 {
        return f64::NAN;
    }
    pred.iter()
        .zip(truth)
        .map(|(p, t)| (p - t).abs())
        .sum::<f64>()
        / n as f64
}

/// Coefficient of determination, 1 − SS_res / SS_tot, with the mean taken first (two passes),
/// so a large common offset does not cancel the variance away.
///
/// When the truth has no variance (SS_tot = 0, e.g. an axis that never sees force) the ratio is
/// undefined; we define R² = 1 for a prediction that matches exactly and 0 otherwise: there is
/// no variance to explain, so an imperfect model explains none of it. NaN only for empty input.
pub fn r2(pred: &[f64], truth: &[f64]) -> f64 {
    let n = pred.len().min(truth.len());
    if n == 0 {
        return f64::NAN;
    }
    let mean = truth[..n].iter().sum::<f64>() / n as f64;
    let ss_tot: f64 = truth[..n].iter().map(|t| (t - mean).powi(2)).sum();
    let ss_res: f64 = pred.iter().zip(truth).map(|(p, t)| (t - p).powi(2)).sum();
    let scale = truth[..n]
        .iter()
        .map(|t| t.abs())
        .fold(0.0, f64::max)
        .max(1e-300);
    // "Zero" relative to the data's magnitude: n · (1e-12 · scale)².
    let tiny = n as f64 * (1e-12 * scale).powi(2);
    if ss_tot <= tiny {
        return if ss_res <= tiny { 1.0 } else { 0.0 };
    }
    1.0 - ss_res / ss_tot
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct AxisScores {
    pub mae: [f64; 3],
    pub r2: [f64; 3],
    /// Mean | |F̂| − |F| |: the error of the force magnitude.
    pub total_mae: f64,
    pub n: usize,
}

pub fn score(pred: &[[f64; 3]], truth: &[[f64; 3]]) -> AxisScores {
    let axis = |v: &[[f64; 3]], a: usize| v.iter().map(|x| x[a]).collect::<Vec<_>>();
    let norm = |x: &[f64; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    let mags_p: Vec<f64> = pred.iter().map(norm).collect();
    let mags_t: Vec<f64> = truth.iter().map(norm).collect();
    AxisScores {
        mae: std::array::from_fn(|a| mae(&axis(pred, a), &axis(truth, a))),
        r2: std::array::from_fn(|a| r2(&axis(pred, a), &axis(truth, a))),
        total_mae: mae(&mags_p, &mags_t),
        n: pred.len().min(truth.len()),
    }
}

/// A Gaussian fitted to feature vectors (unbiased covariance).
#[derive(Debug, Clone)]
pub struct Gaussian {
    pub mean: DVector<f64>,
    pub cov: DMatrix<f64>,
    pub n: usize,
}

impl Gaussian {
    pub fn fit(features: &[Vec<f64>]) -> Result<Self, String> {
        let n = features.len();
        if n < 2 {
            return Err(format!("need at least 2 feature vectors, got {n}"));
        }
        let d = features[0].len();
        if d == 0 || features.iter().any(|f| f.len() != d) {
            return Err("feature vectors must share one non-zero dimension".into());
        }
        if features.iter().flatten().any(|v| !v.is_finite()) {
            return Err("a feature is not finite".into());
        }
        let x = DMatrix::from_fn(n, d, |i, j| features[i][j]);
        let mean = DVector::from_fn(d, |j, _| x.column(j).mean());
        let centred = DMatrix::from_fn(n, d, |i, j| x[(i, j)] - mean[j]);
        let cov = centred.transpose() * &centred / (n - 1) as f64;
        Ok(Self { mean, cov, n })
    }
}

/// Square root of a symmetric positive semi-definite matrix by eigendecomposition. Eigenvalues
/// below zero can only be round-off (the matrix is PSD in exact arithmetic) and are clamped.
fn psd_sqrt(m: &DMatrix<f64>) -> DMatrix<f64> {
    let sym = (m + m.transpose()) * 0.5;
    let e = SymmetricEigen::new(sym);
    let vals = e.eigenvalues.map(|v| v.max(0.0).sqrt());
    &e.eigenvectors * DMatrix::from_diagonal(&vals) * e.eigenvectors.transpose()
}

/// Fréchet distance between two Gaussians (Heusel et al. 2017, the FID):
/// |μ1 − μ2|² + tr(Σ1 + Σ2 − 2 (Σ1^½ Σ2 Σ1^½)^½). The product is computed in the symmetric form
/// so that singular covariances (fewer samples than dimensions) stay well defined.
pub fn frechet_distance(a: &Gaussian, b: &Gaussian) -> f64 {
    let dm = (&a.mean - &b.mean).norm_squared();
    let s1 = psd_sqrt(&a.cov);
    let inner = &s1 * &b.cov * &s1;
    let cross = psd_sqrt(&inner).trace();
    (dm + a.cov.trace() + b.cov.trace() - 2.0 * cross).max(0.0)
}

pub fn fid(a: &[Vec<f64>], b: &[Vec<f64>]) -> Result<f64, String> {
    let (ga, gb) = (Gaussian::fit(a)?, Gaussian::fit(b)?);
    if ga.mean.len() != gb.mean.len() {
        return Err("the two feature sets differ in dimension".into());
    }
    Ok(frechet_distance(&ga, &gb))
}

/// Kernel Inception Distance (Bińkowski et al. 2018): the unbiased MMD² with the cubic kernel
/// k(x, y) = (x·y / d + 1)³, averaged over `subsets` random subsets of `subset_size` from each
/// set. Returns (mean, standard deviation over subsets).
pub fn kid(
    a: &[Vec<f64>],
    b: &[Vec<f64>],
    subsets: usize,
    subset_size: usize,
    seed: u64,
) -> Result<(f64, f64), String> {
    let m = subset_size.min(a.len()).min(b.len());
    if m < 2 {
        return Err(format!(
            "KID needs subsets of at least 2 (sets of {} and {})",
            a.len(),
            b.len()
        ));
    }
    let d = a[0].len();
    if d == 0 || a.iter().chain(b).any(|f| f.len() != d) {
        return Err("feature vectors must share one non-zero dimension".into());
    }
    if a.iter().chain(b).flatten().any(|v| !v.is_finite()) {
        return Err("a feature is not finite".into());
    }
    let k = |x: &[f64], y: &[f64]| {
        (x.iter().zip(y).map(|(p, q)| p * q).sum::<f64>() / d as f64 + 1.0).powi(3)
    };
    let mut rng = super::batch::Rng(seed);
    let mut pick = |n: usize| {
        let mut idx: Vec<usize> = (0..n).collect();
        rng.shuffle(&mut idx);
        idx.truncate(m);
        idx
    };
    let mut vals = Vec::with_capacity(subsets.max(1));
    for _ in 0..subsets.max(1) {
        let (ia, ib) = (pick(a.len()), pick(b.len()));
        let (mut kxx, mut kyy, mut kxy) = (0.0, 0.0, 0.0);
        for i in 0..m {
            for j in 0..m {
                if i != j {
                    kxx += k(&a[ia[i]], &a[ia[j]]);
                    kyy += k(&b[ib[i]], &b[ib[j]]);
                }
                kxy += k(&a[ia[i]], &b[ib[j]]);
            }
        }
        let mf = m as f64;
        vals.push(kxx / (mf * (mf - 1.0)) + kyy / (mf * (mf - 1.0)) - 2.0 * kxy / (mf * mf));
    }
    let mean = vals.iter().sum::<f64>() / vals.len() as f64;
    let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64;
    Ok((mean, var.sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mae_and_r2_on_hand_computed_values() {
        let t = [1.0, 2.0, 3.0, 4.0];
        let p = [1.5, 2.0, 2.0, 5.0];
        // |0.5| + 0 + 1 + 1 = 2.5 over 4.
        assert!((mae(&p, &t) - 0.625).abs() < 1e-15);
        // mean 2.5, SS_tot = 2.25 + 0.25 + 0.25 + 2.25 = 5; SS_res = 0.25 + 0 + 1 + 1 = 2.25.
        assert!((r2(&p, &t) - (1.0 - 2.25 / 5.0)).abs() < 1e-15);
        assert_eq!(r2(&t, &t), 1.0);
        assert!(r2(&[2.5; 4], &t).abs() < 1e-15, "the mean explains nothing");
        // Reversed: SS_res = 9 + 1 + 1 + 9 = 20 → R² = 1 − 20/5 = −3.
        assert!((r2(&[4.0, 3.0, 2.0, 1.0], &t) + 3.0).abs() < 1e-12);
        assert!(mae(&[], &[]).is_nan() && r2(&[], &[]).is_nan());
    }

    #[test]
    fn r2_is_defined_without_variance_and_stable_under_offsets() {
        assert_eq!(r2(&[0.0; 5], &[0.0; 5]), 1.0);
        assert_eq!(r2(&[0.1, 0.0, 0.0], &[0.0; 3]), 0.0);
        assert_eq!(r2(&[3.0], &[3.0]), 1.0);
        assert_eq!(r2(&[2.0], &[3.0]), 0.0);
        let t: Vec<f64> = [1.0, 2.0, 3.0, 4.0].iter().map(|v| v + 1e8).collect();
        let p: Vec<f64> = [1.5, 2.0, 2.0, 5.0].iter().map(|v| v + 1e8).collect();
        assert!((r2(&p, &t) - 0.55).abs() < 1e-6, "{}", r2(&p, &t));
    }

    #[test]
    fn total_mae_is_the_error_of_the_magnitude() {
        // |(3, 4, 0)| = 5 against |(0, 0, -2)| = 2 → 3; |(1, 0, 0)| = 1 against itself → 0.
        let s = score(
            &[[3.0, 4.0, 0.0], [1.0, 0.0, 0.0]],
            &[[0.0, 0.0, -2.0], [1.0, 0.0, 0.0]],
        );
        assert!((s.total_mae - 1.5).abs() < 1e-15);
        assert_eq!(s.mae, [1.5, 2.0, 1.0]);
        assert_eq!(s.n, 2);
    }

    fn one_d(values: &[f64]) -> Vec<Vec<f64>> {
        values.iter().map(|v| vec![*v]).collect()
    }

    #[test]
    fn fid_matches_the_closed_form() {
        // Sample means 0 and 3; unbiased variances 1 and 4 ({−1, 0, 1}: 2/2; {1, 3, 5}: 8/2).
        let a = one_d(&[-1.0, 0.0, 1.0]);
        let b = one_d(&[1.0, 3.0, 5.0]);
        // (0 − 3)² + (1 − 2)² = 10.
        assert!((fid(&a, &b).unwrap() - 10.0).abs() < 1e-9);
        assert!(fid(&a, &a).unwrap() < 1e-9);
        assert!((fid(&a, &b).unwrap() - fid(&b, &a).unwrap()).abs() < 1e-9);
        // Diagonal 2-D: independent axes add.
        let a2: Vec<Vec<f64>> = vec![
            vec![-1.0, 0.0],
            vec![1.0, 0.0],
            vec![0.0, -2.0],
            vec![0.0, 2.0],
        ];
        let b2: Vec<Vec<f64>> = a2.iter().map(|v| vec![v[0] * 3.0 + 1.0, v[1]]).collect();
        // var x: 2/3 → 6; var y: 8/3 both; means (0,0) vs (1,0).
        let want = 1.0 + ((2.0f64 / 3.0).sqrt() - 6.0f64.sqrt()).powi(2);
        assert!((fid(&a2, &b2).unwrap() - want).abs() < 1e-9);
    }

    #[test]
    fn fid_is_stable_for_singular_covariances() {
        // 8-D features on a 2-D subspace, 5 samples (fewer than dimensions): rank-deficient.
        let basis = |s: f64, t: f64| -> Vec<f64> {
            (0..8)
                .map(|k| s * (k as f64 + 1.0) / 8.0 + t * if k % 2 == 0 { 1.0 } else { -1.0 })
                .collect()
        };
        let a: Vec<Vec<f64>> = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (0.5, 0.5)]
            .iter()
            .map(|&(s, t)| basis(s, t))
            .collect();
        let shift: Vec<f64> = (0..8).map(|k| k as f64 * 0.1).collect();
        let b: Vec<Vec<f64>> = a
            .iter()
            .map(|v| v.iter().zip(&shift).map(|(x, s)| x + s).collect())
            .collect();
        let f = fid(&a, &b).unwrap();
        // A pure shift: equal covariances cancel, leaving |Δμ|² = Σ (0.1 k)².
        let want: f64 = shift.iter().map(|s| s * s).sum();
        assert!(f.is_finite() && (f - want).abs() < 1e-6, "{f} vs {want}");
        // A constant feature and duplicated samples.
        let c = vec![vec![1.0, 5.0], vec![1.0, 5.0], vec![2.0, 5.0]];
        assert!(fid(&c, &c).unwrap().abs() < 1e-9);
        assert!(fid(&[vec![f64::NAN]], &c).is_err());
        assert!(fid(&one_d(&[1.0]), &c).is_err());
    }

    #[test]
    fn kid_is_near_zero_for_one_distribution_and_grows_with_a_shift() {
        let mut rng = super::super::batch::Rng(3);
        let mut gauss = |shift: f64| -> Vec<Vec<f64>> {
            (0..200)
                .map(|_| {
                    (0..4)
                        .map(|_| {
                            // Box–Muller.
                            let (u, v) = (rng.unit().max(1e-12), rng.unit());
                            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos() + shift
                        })
                        .collect()
                })
                .collect()
        };
        let (a, b, c, d) = (gauss(0.0), gauss(0.0), gauss(0.5), gauss(1.0));
        let same = kid(&a, &b, 10, 100, 1).unwrap().0;
        let half = kid(&a, &c, 10, 100, 1).unwrap().0;
        let one = kid(&a, &d, 10, 100, 1).unwrap().0;
        assert!(same.abs() < 0.1 * half, "{same} vs {half}");
        assert!(half > 0.0 && one > half);
        assert_eq!(
            kid(&a, &c, 10, 100, 1).unwrap(),
            kid(&a, &c, 10, 100, 1).unwrap()
        );
        assert!(kid(&a[..1], &b, 10, 100, 1).is_err());
    }
}
