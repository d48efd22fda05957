//! Tangential contact: Coulomb friction with stick and slip, solved incrementally.
//!
//! One step takes the shear tractions `q₀` of the previous step and the indenter's tangential
//! displacement increment `Δs`, and finds the new tractions `q` with `|q| ≤ μ p` in every cell
//! such that cells whose traction is inside the Coulomb disc *stick* (the gel surface there moves
//! with the indenter: `Δu = Δs`) and cells on the disc's rim *slip* opposite to their traction.
//! With the pressure held at this step's value this is Kalker's incremental principle of
//! maximum dissipation, the convex problem
//!
//! `min ½ (q − q₀)ᵀ C (q − q₀) − Δs · Σ(q − q₀)  subject to  |q_i| ≤ μ p_i`,
//!
//! whose optimality conditions are exactly stick/slip above (`C`: tangential compliance).
//! Cattaneo–Mindlin partial slip is its solution for one monotonic shear step of a Hertz
//! contact. Loading, shear, reverse and unloading then differ because `q₀` carries the
//! history.

use rustfft::num_complex::Complex64;

use super::fft::Conv2;
use super::kernels::TangentialKernel;

/// Relative change of the tractions at which the iteration stops.
const TOL: f64 = 3e-5;
const MAX_ITER: u32 = 3000;

pub(crate) struct Tangential {
    pub qx: Vec<f64>,
    pub qy: Vec<f64>,
    /// Tangential surface displacement of the gel, mm.
    pub ux: Vec<f64>,
    pub uy: Vec<f64>,
    pub iterations: u32,
    pub converged: bool,
}

fn project(qx: &mut [f64], qy: &mut [f64], limit: &[f64]) {
    for i in 0..qx.len() {
        let m = qx[i].hypot(qy[i]);
        if m > limit[i] {
            let s = if m > 0.0 { limit[i] / m } else { 0.0 };
            qx[i] *= s;
            qy[i] *= s;
        }
    }
}

struct Apply<'a> {
    conv: &'a mut Conv2,
    k: &'a TangentialKernel,
    inv_e: f64,
    z: Vec<Complex64>,
    w: Vec<Complex64>,
}

impl Apply<'_> {
    /// `(ux, uy) = C (qx, qy)`: both tractions in one forward transform (`qx + i·qy`), both
    /// displacements out of one inverse (`ux + i·uy`), as all four fields are real.
    fn apply(&mut self, qx: &[f64], qy: &[f64], ux: &mut [f64], uy: &mut [f64]) {
        self.conv.forward_pair(qx, qy, &mut self.z);
        self.w.clear();
        self.w.resize(self.z.len(), Complex64::default());
        let k = self.k;
        for (((w, z), (p, q)), &m) in self
            .w
            .iter_mut()
            .zip(&self.z)
            .zip(k.packed_p.iter().zip(&k.packed_q))
            .zip(&k.mirror)
        {
            *w = p * z + q * self.z[m as usize].conj();
        }
        self.conv.inverse_pair(&mut self.w, self.inv_e, ux, uy);
    }
}

/// The surface displacements `(ux, uy) = C (qx, qy)` of the tractions on `conv`'s grid, mm.
pub(crate) fn apply(
    conv: &mut Conv2,
    k: &TangentialKernel,
    inv_e: f64,
    qx: &[f64],
    qy: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let mut op = Apply {
        conv,
        k,
        inv_e,
        z: Vec::new(),
        w: Vec::new(),
    };
    let (mut ux, mut uy) = (vec![0.0; qx.len()], vec![0.0; qx.len()]);
    op.apply(qx, qy, &mut ux, &mut uy);
    (ux, uy)
}

/// Boundary-element step (half-space Cerruti compliance), solved by accelerated projected
/// gradient (FISTA with adaptive restart; Beck & Teboulle 2009, O'Donoghue & Candès 2015).
#[allow(clippy::too_many_arguments)]
pub(crate) fn bem_step(
    conv: &mut Conv2,
    k: &TangentialKernel,
    inv_e: f64,
    limit: &[f64],
    q0x: &[f64],
    q0y: &[f64],
    ds: [f64; 2],
    guess: Option<(&[f64], &[f64])>,
) -> Tangential {
    let n = limit.len();
    let mut op = Apply {
        conv,
        k,
        inv_e,
        z: Vec::new(),
        w: Vec::new(),
    };
    let step = 1.0 / (k.lambda_max * inv_e);
    let (mut u0x, mut u0y) = (vec![0.0; n], vec![0.0; n]);
    op.apply(q0x, q0y, &mut u0x, &mut u0y);
    // Start from the guess (else the previous tractions), projected.
    let (mut qx, mut qy) = match guess {
        Some((gx, gy)) if gx.len() == n && gy.len() == n => (gx.to_vec(), gy.to_vec()),
        _ => (q0x.to_vec(), q0y.to_vec()),
    };
    project(&mut qx, &mut qy, limit);
    let (mut yx, mut yy) = (qx.clone(), qy.clone());
    let (mut ux, mut uy) = (vec![0.0; n], vec![0.0; n]);
    let mut t = 1.0_f64;
    let mut iterations = 0;
    let mut converged = limit.iter().all(|&l| l == 0.0);
    while !converged && iterations < MAX_ITER {
        iterations += 1;
        op.apply(&yx, &yy, &mut ux, &mut uy);
        // Gradient: slip increment Δu − Δs.
        let (mut zx, mut zy) = (vec![0.0; n], vec![0.0; n]);
        for i in 0..n {
            zx[i] = yx[i] - step * ((ux[i] - u0x[i]) - ds[0]);
            zy[i] = yy[i] - step * ((uy[i] - u0y[i]) - ds[1]);
        }
        project(&mut zx, &mut zy, limit);
        let (mut change, mut size, mut restart) = (0.0, 0.0, 0.0);
        for i in 0..n {
            let (dx, dy) = (zx[i] - qx[i], zy[i] - qy[i]);
            change += dx * dx + dy * dy;
            size += zx[i] * zx[i] + zy[i] * zy[i];
            restart += (yx[i] - zx[i]) * dx + (yy[i] - zy[i]) * dy;
        }
        let t_next = (1.0 + (1.0 + 4.0 * t * t).sqrt()) / 2.0;
        let momentum = if restart > 0.0 {
            0.0
        } else {
            (t - 1.0) / t_next
        };
        t = if restart > 0.0 { 1.0 } else { t_next };
        for i in 0..n {
            yx[i] = zx[i] + momentum * (zx[i] - qx[i]);
            yy[i] = zy[i] + momentum * (zy[i] - qy[i]);
        }
        qx = zx;
        qy = zy;
        if change <= TOL * TOL * size.max(f64::MIN_POSITIVE) {
            converged = true;
        }
    }
    op.apply(&qx, &qy, &mut ux, &mut uy);
    Tangential {
        qx,
        qy,
        ux,
        uy,
        iterations,
        converged,
    }
}

/// Winkler step: an independent shear spring `k_t = G / h` per cell (the tangential analogue of
/// the Winkler foundation), so the return mapping is exact in one pass.
pub(crate) fn spring_step(
    k_t: f64,
    limit: &[f64],
    q0x: &[f64],
    q0y: &[f64],
    ds: [f64; 2],
) -> Tangential {
    let mut qx: Vec<f64> = q0x.iter().map(|q| q + k_t * ds[0]).collect();
    let mut qy: Vec<f64> = q0y.iter().map(|q| q + k_t * ds[1]).collect();
    project(&mut qx, &mut qy, limit);
    let ux = qx.iter().map(|q| q / k_t).collect();
    let uy = qy.iter().map(|q| q / k_t).collect();
    Tangential {
        qx,
        qy,
        ux,
        uy,
        iterations: 1,
        converged: true,
    }
}
