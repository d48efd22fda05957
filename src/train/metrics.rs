//! Scores: MAE and R² per force axis, the total-force MAE, and FID/KID between image-feature
//! sets (Heusel et al. 2017; Bińkowski et al. 2018), in f64.

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
    /// MAE per axis over the shear-loaded frames only ([`ShearLoad`]): most frames carry little
    /// shear, so a model that predicts no shear at all still scores a small MAE over every
    /// frame; over these frames it cannot. NaN when no frame is loaded.
    pub loaded_mae: [f64; 3],
    /// How many frames are shear-loaded.
    pub loaded_n: usize,
}

/// Which frames count as shear-loaded: true |F_shear| = √(Fx² + Fy²) above `fraction` of its
/// range over a reference set. One threshold for every group and model scored on the same
/// data, so their loaded MAEs are over the same frames.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ShearLoad {
    pub threshold_n: f64,
}

impl ShearLoad {
    /// The fraction of the shear range above which a frame is loaded.
    pub const FRACTION: f64 = 0.1;

    /// [`Self::FRACTION`] of the range (max − min) of |F_shear| over `truth`.
    pub fn of(truth: &[[f64; 3]]) -> Self {
        let (lo, hi) = truth
            .iter()
            .map(shear_n)
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
                (lo.min(v), hi.max(v))
            });
        let range = if hi >= lo { hi - lo } else { 0.0 };
        Self {
            threshold_n: Self::FRACTION * range,
        }
    }

    /// Whether a frame whose true force is `f` is loaded. A set without shear (range 0) has
    /// no loaded frame.
    pub fn loaded(&self, f: &[f64; 3]) -> bool {
        shear_n(f) > self.threshold_n
    }
}

/// |F_shear| = √(Fx² + Fy²), N.
pub fn shear_n(f: &[f64; 3]) -> f64 {
    f[0].hypot(f[1])
}

/// [`score_at`] with the shear-loaded frames taken from `truth` itself.
pub fn score(pred: &[[f64; 3]], truth: &[[f64; 3]]) -> AxisScores {
    score_at(pred, truth, ShearLoad::of(truth))
}

/// MAE and R² per axis over every frame, the magnitude's MAE, and the MAE per axis over the
/// frames that `load` calls shear-loaded.
pub fn score_at(pred: &[[f64; 3]], truth: &[[f64; 3]], load: ShearLoad) -> AxisScores {
    let axis = |v: &[[f64; 3]], a: usize| v.iter().map(|x| x[a]).collect::<Vec<_>>();
    let norm = |x: &[f64; 3]| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
    let mags_p: Vec<f64> = pred.iter().map(norm).collect();
    let mags_t: Vec<f64> = truth.iter().map(norm).collect();
    let (lp, lt): (Vec<[f64; 3]>, Vec<[f64; 3]>) = pred
        .iter()
        .zip(truth)
        .filter(|(_, t)| load.loaded(t))
        .map(|(p, t)| (*p, *t))
        .unzip();
    AxisScores {
        mae: std::array::from_fn(|a| mae(&axis(pred, a), &axis(truth, a))),
        r2: std::array::from_fn(|a| r2(&axis(pred, a), &axis(truth, a))),
        total_mae: mae(&mags_p, &mags_t),
        n: pred.len().min(truth.len()),
        loaded_mae: std::array::from_fn(|a| mae(&axis(&lp, a), &axis(&lt, a))),
        loaded_n: lp.len(),
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

/// The Fréchet distance between Gaussians fitted to two feature sets (the FID when the features
/// are Inception's). With fewer samples than dimensions (the usual case for 2048-d features) it is
/// computed from the samples instead of the d × d covariances, exactly and far faster: with A and
/// B the centred samples (rows), Σ₁ = AᵀA/(n₁−1) and Σ₂ = BᵀB/(n₂−1), the non-zero eigenvalues of
/// Σ₁Σ₂ are the squared singular values of A Bᵀ/√((n₁−1)(n₂−1)), so tr((Σ₁Σ₂)^½) is the sum of
/// those singular values, and tr Σ₁ = ‖A‖²_F/(n₁−1).
pub fn fid(a: &[Vec<f64>], b: &[Vec<f64>]) -> Result<f64, String> {
    let (ga, gb) = (Gaussian::fit(a)?, Gaussian::fit(b)?);
    let d = ga.mean.len();
    if d != gb.mean.len() {
        return Err("the two feature sets differ in dimension".into());
    }
    if a.len().min(b.len()) > d {
        return Ok(frechet_distance(&ga, &gb));
    }
    let centred =
        |x: &[Vec<f64>], g: &Gaussian| DMatrix::from_fn(x.len(), d, |i, j| x[i][j] - g.mean[j]);
    let (ca, cb) = (centred(a, &ga), centred(b, &gb));
    let (na, nb) = ((a.len() - 1) as f64, (b.len() - 1) as f64);
    let cross = (&ca * cb.transpose()).singular_values().sum() / (na * nb).sqrt();
    let dm = (&ga.mean - &gb.mean).norm_squared();
    Ok((dm + ca.norm_squared() / na + cb.norm_squared() / nb - 2.0 * cross).max(0.0))
}

/// A KID estimate: the mean and standard deviation over `subsets` subsets of `subset_size`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Kid {
    pub mean: f64,
    pub std: f64,
    pub subset_size: usize,
    pub subsets: usize,
}

/// Kernel Inception Distance (Bińkowski et al. 2018): the unbiased estimate of MMD² with the
/// cubic polynomial kernel k(x, y) = (x·y / d + 1)³,
/// 1/(m(m−1)) Σ_{i≠j} k(xᵢ, xⱼ) + 1/(m(m−1)) Σ_{i≠j} k(yᵢ, yⱼ) − 2/m² Σ_{i,j} k(xᵢ, yⱼ),
/// averaged over `subsets` random subsets of m = min(`subset_size`, |a|, |b|) from each set
/// (drawn without replacement within a subset). The reference practice is 100 subsets of 1000;
/// the returned [`Kid`] says which size was used. The kernel matrices of the whole sets are
/// computed once (matrix products), so each subset costs only look-ups.
pub fn kid(
    a: &[Vec<f64>],
    b: &[Vec<f64>],
    subsets: usize,
    subset_size: usize,
    seed: u64,
) -> Result<Kid, String> {
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
    let rows = |x: &[Vec<f64>]| DMatrix::from_fn(x.len(), d, |i, j| x[i][j]);
    let (xa, xb) = (rows(a), rows(b));
    let kernel = |p: &DMatrix<f64>, q: &DMatrix<f64>| {
        (p * q.transpose()).map(|v| (v / d as f64 + 1.0).powi(3))
    };
    let (kaa, kbb, kab) = (kernel(&xa, &xa), kernel(&xb, &xb), kernel(&xa, &xb));
    let mut rng = super::batch::Rng(seed);
    let mut pick = |n: usize| {
        let mut idx: Vec<usize> = (0..n).collect();
        rng.shuffle(&mut idx);
        idx.truncate(m);
        idx
    };
    let subsets = subsets.max(1);
    let mut vals = Vec::with_capacity(subsets);
    for _ in 0..subsets {
        let (ia, ib) = (pick(a.len()), pick(b.len()));
        let (mut kxx, mut kyy, mut kxy) = (0.0, 0.0, 0.0);
        for i in 0..m {
            for j in 0..m {
                if i != j {
                    kxx += kaa[(ia[i], ia[j])];
                    kyy += kbb[(ib[i], ib[j])];
                }
                kxy += kab[(ia[i], ib[j])];
            }
        }
        let mf = m as f64;
        vals.push(kxx / (mf * (mf - 1.0)) + kyy / (mf * (mf - 1.0)) - 2.0 * kxy / (mf * mf));
    }
    let mean = vals.iter().sum::<f64>() / vals.len() as f64;
    let var = vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64;
    Ok(Kid {
        mean,
        std: var.sqrt(),
        subset_size: m,
        subsets,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A model that predicts no shear scores a small MAE over every frame when few frames
    /// carry shear, but its loaded MAE is the loaded frames' whole shear; R² shows it too.
    #[test]
    fn predicting_no_shear_shows_in_the_loaded_mae_and_r2() {
        // 90 frames of pure normal force, 10 with 1 N of shear along x.
        let truth: Vec<[f64; 3]> = (0..100)
            .map(|i| {
                if i < 90 {
                    [0.0, 0.0, -2.0]
                } else {
                    [1.0, 0.0, -2.0]
                }
            })
            .collect();
        let zero_shear: Vec<[f64; 3]> = truth.iter().map(|t| [0.0, 0.0, t[2]]).collect();
        let s = score(&zero_shear, &truth);
        assert!((s.mae[0] - 0.1).abs() < 1e-12, "{:?}", s.mae);
        assert_eq!(s.loaded_n, 10);
        assert!((s.loaded_mae[0] - 1.0).abs() < 1e-12, "{:?}", s.loaded_mae);
        assert_eq!(s.loaded_mae[2], 0.0);
        assert!(s.r2[0] < 0.0, "{:?}", s.r2);
        // A model that reads the shear: loaded MAE 0.
        let s = score(&truth, &truth);
        assert_eq!(s.loaded_mae, [0.0; 3]);
        // The threshold is 10 % of the |F_shear| range (0..1 N): 0.1 N; a frame at exactly
        // the threshold is not loaded.
        let load = ShearLoad::of(&truth);
        assert!((load.threshold_n - 0.1).abs() < 1e-12);
        assert!(!load.loaded(&[0.1, 0.0, 0.0]) && load.loaded(&[0.0, -0.11, 0.0]));
    }

    /// No shear anywhere: no loaded frame, and a NaN loaded MAE rather than a flattering 0.
    #[test]
    fn a_set_without_shear_has_no_loaded_frames() {
        let truth = vec![[0.0, 0.0, -1.0]; 5];
        let s = score(&truth, &truth);
        assert_eq!(s.loaded_n, 0);
        assert!(s.loaded_mae.iter().all(|v| v.is_nan()));
        assert!(score(&[], &[]).loaded_mae[0].is_nan());
    }

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
        let same = kid(&a, &b, 10, 100, 1).unwrap().mean;
        let half = kid(&a, &c, 10, 100, 1).unwrap().mean;
        let one = kid(&a, &d, 10, 100, 1).unwrap().mean;
        assert!(same.abs() < 0.1 * half, "{same} vs {half}");
        assert!(half > 0.0 && one > half);
        assert_eq!(
            kid(&a, &c, 10, 100, 1).unwrap(),
            kid(&a, &c, 10, 100, 1).unwrap()
        );
        assert!(kid(&a[..1], &b, 10, 100, 1).is_err());
        // Subsets shrink to the smaller set, and the estimate says so.
        let k = kid(&a[..50], &b, 100, 1000, 1).unwrap();
        assert_eq!((k.subset_size, k.subsets), (50, 100));
    }

    #[test]
    fn kid_matches_the_estimator_computed_by_hand() {
        // d = 1, subsets of 2 from sets of 2 (every subset is the whole set, so every estimate
        // is the same): x = {0, 1}, y = {1, 2}, k(p, q) = (pq + 1)³.
        let k = |p: f64, q: f64| (p * q + 1.0).powi(3);
        let (x, y) = ([0.0, 1.0], [1.0, 2.0]);
        let kxx = 2.0 * k(x[0], x[1]) / 2.0;
        let kyy = 2.0 * k(y[0], y[1]) / 2.0;
        let kxy: f64 = x
            .iter()
            .flat_map(|&p| y.iter().map(move |&q| k(p, q)))
            .sum::<f64>()
            / 4.0;
        let want = kxx + kyy - 2.0 * kxy;
        let got = kid(&one_d(&x), &one_d(&y), 3, 1000, 7).unwrap();
        assert!(
            (got.mean - want).abs() < 1e-9 && got.std < 1e-12,
            "{got:?} vs {want}"
        );
    }

    #[test]
    fn fid_from_samples_equals_fid_from_covariances() {
        // 6 and 9 samples of 12-d features: fewer samples than dimensions (the sample form);
        // against the d × d covariance form on the same Gaussians.
        let mut rng = super::super::batch::Rng(11);
        let mut set = |n: usize, shift: f64, scale: f64| -> Vec<Vec<f64>> {
            (0..n)
                .map(|_| {
                    (0..12)
                        .map(|k| (rng.unit() - 0.5) * scale * (1.0 + k as f64 / 6.0) + shift)
                        .collect()
                })
                .collect()
        };
        let (a, b) = (set(6, 0.0, 1.0), set(9, 0.3, 2.0));
        let want = frechet_distance(&Gaussian::fit(&a).unwrap(), &Gaussian::fit(&b).unwrap());
        let got = fid(&a, &b).unwrap();
        // (The covariance form takes square roots of eigenvalues that are zero up to round-off,
        // about 1e-16, each adding about 1e-8: agreement to 1e-6 relative is what it can give.)
        assert!(
            want > 1.0 && (got - want).abs() < 1e-6 * want,
            "{got} vs {want}"
        );
        // And with more samples than dimensions (the covariance form) it is the same function.
        let (c, e) = (set(40, 0.0, 1.0), set(30, 0.3, 2.0));
        let want = frechet_distance(&Gaussian::fit(&c).unwrap(), &Gaussian::fit(&e).unwrap());
        assert!((fid(&c, &e).unwrap() - want).abs() < 1e-12 * want);
    }
}
