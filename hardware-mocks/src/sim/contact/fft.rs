//! Zero-padded 2-D FFT convolution on the contact grid (DC-FFT: Liu, Wang & Liu 2000).
//!
//! A field on the `nx × ny` grid is padded to `2nx × 2ny` with zeros, and the influence kernel is
//! laid out for offsets `−(n−1)..=(n−1)` (wrapped), so the circular convolution of the padded
//! arrays equals the linear (non-periodic) convolution on the grid: the gel has no periodic
//! images.

use std::sync::Arc;

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

/// FFT plans and scratch buffers for one grid size.
pub(crate) struct Conv2 {
    pub nx: usize,
    pub ny: usize,
    pub px: usize,
    pub py: usize,
    row_f: Arc<dyn Fft<f64>>,
    row_i: Arc<dyn Fft<f64>>,
    col_f: Arc<dyn Fft<f64>>,
    col_i: Arc<dyn Fft<f64>>,
    col: Vec<Complex64>,
    scratch: Vec<Complex64>,
    /// Forward and inverse 2-D transforms executed (for `SimStats`).
    pub ffts: u32,
}

impl Conv2 {
    pub fn new(nx: usize, ny: usize) -> Self {
        let (px, py) = (2 * nx, 2 * ny);
        let mut planner = FftPlanner::new();
        let row_f = planner.plan_fft_forward(px);
        let row_i = planner.plan_fft_inverse(px);
        let col_f = planner.plan_fft_forward(py);
        let col_i = planner.plan_fft_inverse(py);
        let scratch_len = [&row_f, &row_i, &col_f, &col_i]
            .iter()
            .map(|f| f.get_inplace_scratch_len())
            .max()
            .unwrap_or(0);
        Self {
            nx,
            ny,
            px,
            py,
            row_f,
            row_i,
            col_f,
            col_i,
            col: vec![Complex64::default(); py],
            scratch: vec![Complex64::default(); scratch_len],
            ffts: 0,
        }
    }

    /// Transforms a padded `px × py` array (row-major, x fastest) in place. Forward: only the
    /// first `rows_live` rows may be non-zero (the zero rows are skipped). Inverse: only the
    /// first `rows_live` rows are completed (the cropped result).
    fn fft2(&mut self, data: &mut [Complex64], inverse: bool, rows_live: usize) {
        self.ffts += 1;
        let (row, col) = if inverse {
            (self.row_i.clone(), self.col_i.clone())
        } else {
            (self.row_f.clone(), self.col_f.clone())
        };
        if !inverse {
            row.process_with_scratch(&mut data[..rows_live * self.px], &mut self.scratch);
        }
        for i in 0..self.px {
            for j in 0..self.py {
                self.col[j] = data[j * self.px + i];
            }
            col.process_with_scratch(&mut self.col, &mut self.scratch);
            for j in 0..self.py {
                data[j * self.px + i] = self.col[j];
            }
        }
        if inverse {
            row.process_with_scratch(&mut data[..rows_live * self.px], &mut self.scratch);
        }
    }

    /// Spectrum of a kernel given by its value at each cell offset `(di, dj)`.
    pub fn kernel_hat(&mut self, mut k: impl FnMut(isize, isize) -> f64) -> Vec<Complex64> {
        let (nx, ny, px, py) = (self.nx as isize, self.ny as isize, self.px, self.py);
        let mut data = vec![Complex64::default(); px * py];
        for dj in -(ny - 1)..ny {
            let j = dj.rem_euclid(py as isize) as usize;
            for di in -(nx - 1)..nx {
                let i = di.rem_euclid(px as isize) as usize;
                data[j * px + i] = Complex64::new(k(di, dj), 0.0);
            }
        }
        self.fft2(&mut data, false, py);
        data
    }

    /// Spectrum of a grid field (zero-padded).
    pub fn forward(&mut self, field: &[f64], out: &mut Vec<Complex64>) {
        out.clear();
        out.resize(self.px * self.py, Complex64::default());
        for j in 0..self.ny {
            for i in 0..self.nx {
                out[j * self.px + i] = Complex64::new(field[j * self.nx + i], 0.0);
            }
        }
        self.fft2(out, false, self.ny);
    }

    /// Inverse transform of a spectrum, cropped to the grid, times `scale`.
    pub fn inverse(&mut self, spec: &mut [Complex64], scale: f64, out: &mut [f64]) {
        self.fft2(spec, true, self.ny);
        let norm = scale / (self.px * self.py) as f64;
        for j in 0..self.ny {
            for i in 0..self.nx {
                out[j * self.nx + i] = spec[j * self.px + i].re * norm;
            }
        }
    }

    /// Spectrum of the complex grid field `re + i·im` (zero-padded): two real fields in one
    /// transform. Their own spectra are `(Z[k] + conj Z[−k])/2` and `(Z[k] − conj Z[−k])/2i`.
    pub fn forward_pair(&mut self, re: &[f64], im: &[f64], out: &mut Vec<Complex64>) {
        out.clear();
        out.resize(self.px * self.py, Complex64::default());
        for j in 0..self.ny {
            for i in 0..self.nx {
                let k = j * self.nx + i;
                out[j * self.px + i] = Complex64::new(re[k], im[k]);
            }
        }
        self.fft2(out, false, self.ny);
    }

    /// Inverse transform of the spectrum of `a + i·b` (two real fields), cropped to the grid,
    /// times `scale`: `a` into `re`, `b` into `im`.
    pub fn inverse_pair(
        &mut self,
        spec: &mut [Complex64],
        scale: f64,
        re: &mut [f64],
        im: &mut [f64],
    ) {
        self.fft2(spec, true, self.ny);
        let norm = scale / (self.px * self.py) as f64;
        for j in 0..self.ny {
            for i in 0..self.nx {
                let z = spec[j * self.px + i];
                re[j * self.nx + i] = z.re * norm;
                im[j * self.nx + i] = z.im * norm;
            }
        }
    }

    /// `out = scale · (K ∗ field)` on the grid.
    pub fn convolve(
        &mut self,
        hat: &[Complex64],
        field: &[f64],
        scale: f64,
        work: &mut Vec<Complex64>,
        out: &mut [f64],
    ) {
        self.forward(field, work);
        for (w, k) in work.iter_mut().zip(hat) {
            *w *= *k;
        }
        self.inverse(work, scale, out);
    }
}
