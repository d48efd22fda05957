//! Solving where the contact is: the BEM solvers iterate on a window of the grid around the
//! contact instead of the whole gel.
//!
//! Both iterative solvers only ever change cells that can carry load: the normal solver the
//! cells the indenter penetrates (and any its deformed gel brings into contact), the
//! tangential solver the cells in contact (`μp > 0`) and those still holding last step's
//! traction. Every other cell's load stays zero, and the linear convolution on a window is
//! exactly the full grid's convolution restricted to it (both are zero-padded, DC-FFT), so an
//! iteration on the window does what the same iteration does on the whole grid. A cone's
//! contact at 0.8 mm covers about 8 × 8 of the 25 × 20 cells of the 0.4 mm grid: its
//! transforms are 16 × 16 instead of 50 × 40 points.
//!
//! What stays on the whole grid: the overlap (it finds the window), and once per step the
//! displacement of the whole surface from the solved loads (the camera sees all of it, and the
//! next step's stick tracking needs it). That full displacement also checks the window: a
//! cell outside it that the indenter penetrates through the deformed gel (gap < 0, which the
//! window could not see) grows the window to take it in, and the normal solve is repeated;
//! a window that would cover most of the grid is the whole grid.
//!
//! The tangential solver's step size is the window's own Lipschitz bound (the largest
//! eigenvalue of its circulant operator, which bounds the restricted operator by interlacing):
//! a small window's is smaller than the grid's (the Cerruti kernel's sum over a window grows
//! with its size), so it takes longer steps and fewer iterations to the same tolerance.

use std::collections::HashMap;

use rustfft::num_complex::Complex64;

use super::fft::Conv2;
use super::geometry::Grid;
use super::kernels::{self, OffsetTable, TangentialKernel, TangentialOffsets};
use super::normal::{self, NormalGrid};
use super::tangential::{self, Tangential};
use crate::sim::scene::SimStats;

/// Cells added around the penetrated cells for the normal window (the gel around a contact
/// sinks with it, so contact rarely spreads past the geometric overlap; the check catches it
/// when it does).
const NORMAL_PAD: usize = 2;
/// Cells added around the loaded cells for the tangential window.
const TANGENTIAL_PAD: usize = 1;
/// Window sides are multiples of this (their padded transforms are then multiples of 8, which
/// FFTs well, and few distinct sizes need kernels).
const SIDE_STEP: usize = 4;
/// A window with more than this share of the grid's cells solves on the whole grid.
const MOST_OF_GRID: f64 = 0.6;
/// A gap below this (mm) outside the window is a contact the window missed.
const MISSED_GAP_MM: f64 = -1e-9;
/// Window sizes whose kernels are kept; more are dropped (and rebuilt on demand).
const MAX_WINDOWS: usize = 64;

/// A box of cells `[i0, i0 + nx) × [j0, j0 + ny)` of a grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Window {
    pub i0: usize,
    pub j0: usize,
    pub nx: usize,
    pub ny: usize,
}

impl Window {
    /// The smallest box holding `cells` (indices of the `grid_nx × grid_ny` grid), grown by
    /// `pad` cells on each side, with sides rounded up to multiples of [`SIDE_STEP`] and kept
    /// within the grid. `None` when there are no cells.
    pub fn around(
        grid_nx: usize,
        grid_ny: usize,
        pad: usize,
        cells: impl IntoIterator<Item = usize>,
    ) -> Option<Self> {
        let (mut i_lo, mut i_hi, mut j_lo, mut j_hi) = (usize::MAX, 0, usize::MAX, 0);
        for k in cells {
            let (i, j) = (k % grid_nx, k / grid_nx);
            i_lo = i_lo.min(i);
            i_hi = i_hi.max(i);
            j_lo = j_lo.min(j);
            j_hi = j_hi.max(j);
        }
        if i_lo == usize::MAX {
            return None;
        }
        let side = |lo: usize, hi: usize, n: usize| {
            let (lo, hi) = (lo.saturating_sub(pad), (hi + pad).min(n - 1));
            let len = (hi - lo + 1).div_ceil(SIDE_STEP) * SIDE_STEP;
            let len = len.min(n);
            (lo.min(n - len), len)
        };
        let (i0, nx) = side(i_lo, i_hi, grid_nx);
        let (j0, ny) = side(j_lo, j_hi, grid_ny);
        Some(Self { i0, j0, nx, ny })
    }

    fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// Whether grid cell `k` lies in the window.
    pub fn contains(&self, k: usize, grid_nx: usize) -> bool {
        let (i, j) = (k % grid_nx, k / grid_nx);
        (self.i0..self.i0 + self.nx).contains(&i) && (self.j0..self.j0 + self.ny).contains(&j)
    }

    /// The grid indices of the window's cells, row by row.
    pub fn cells(&self, grid_nx: usize) -> impl Iterator<Item = usize> + '_ {
        (self.j0..self.j0 + self.ny)
            .flat_map(move |j| (self.i0..self.i0 + self.nx).map(move |i| j * grid_nx + i))
    }

    /// The window's part of a grid field.
    pub fn gather(&self, full: &[f64], grid_nx: usize) -> Vec<f64> {
        self.cells(grid_nx).map(|k| full[k]).collect()
    }

    /// A grid field that is `part` in the window and zero elsewhere.
    pub fn scatter(&self, part: &[f64], grid_nx: usize, grid_len: usize) -> Vec<f64> {
        let mut full = vec![0.0; grid_len];
        for (k, v) in self.cells(grid_nx).zip(part) {
            full[k] = *v;
        }
        full
    }
}

/// (layer thickness bits or `None` for the half-space, ν bits).
pub(crate) type NormalKey = (Option<u64>, u64);

/// FFT plans and kernel spectra of one window size.
struct WindowOps {
    conv: Conv2,
    normal: Option<(NormalKey, Vec<Complex64>)>,
    tangential: Option<(u64, TangentialKernel)>,
}

/// Kernels and FFT plans of one grid and of the windows solved on it.
pub(crate) struct GridCache {
    pub grid: Grid,
    conv: Conv2,
    /// Normal kernel at every offset, its spectrum on the whole grid (units 1/E*), and what
    /// it was built for.
    normal: Option<(NormalKey, OffsetTable, Vec<Complex64>)>,
    /// Tangential kernels (units 1/E), keyed by ν's bits.
    tangential: Option<(u64, TangentialOffsets, TangentialKernel)>,
    windows: HashMap<(usize, usize), WindowOps>,
}

/// The plans and spectra of `w`'s size (made empty when new).
fn ops_for<'a>(
    windows: &'a mut HashMap<(usize, usize), WindowOps>,
    w: &Window,
) -> &'a mut WindowOps {
    if windows.len() >= MAX_WINDOWS && !windows.contains_key(&(w.nx, w.ny)) {
        windows.clear();
    }
    windows.entry((w.nx, w.ny)).or_insert_with(|| WindowOps {
        conv: Conv2::new(w.nx, w.ny),
        normal: None,
        tangential: None,
    })
}

/// Whether a window is worth solving on rather than the whole grid.
fn worth_it(w: &Window, grid: &Grid) -> bool {
    (w.len() as f64) <= MOST_OF_GRID * grid.len() as f64
}

impl GridCache {
    pub fn new(grid: Grid) -> Self {
        Self {
            grid,
            conv: Conv2::new(grid.nx, grid.ny),
            normal: None,
            tangential: None,
            windows: HashMap::new(),
        }
    }

    fn ffts(&self) -> u32 {
        self.conv.ffts + self.windows.values().map(|o| o.conv.ffts).sum::<u32>()
    }

    /// The Polonsky–Keer normal solve for `overlap` (see [`normal::polonsky_keer`]) on a
    /// window around the penetrated cells, grown until no cell outside it is penetrated.
    pub fn solve_normal(
        &mut self,
        key: NormalKey,
        nu: f64,
        inv_e_star: f64,
        overlap: &[f64],
        stats: &mut SimStats,
    ) -> NormalGrid {
        let before = self.ffts();
        let grid = self.grid;
        if self.normal.as_ref().is_none_or(|(k, ..)| *k != key) {
            let thick = key.0.map(f64::from_bits);
            let table = kernels::normal_offsets(grid.nx, grid.ny, grid.cell_mm, nu, thick);
            let hat = table.hat(&mut self.conv);
            self.normal = Some((key, table, hat));
            self.windows.values_mut().for_each(|o| o.normal = None);
            stats.kernels_built += 1;
        }
        let n = grid.len();
        let mut window = Window::around(
            grid.nx,
            grid.ny,
            NORMAL_PAD,
            (0..n).filter(|&k| overlap[k] > 0.0),
        );
        let mut iterations = 0;
        let sol = loop {
            let Some(w) = window.filter(|w| worth_it(w, &grid)) else {
                let (_, _, hat) = self.normal.as_ref().expect("built above");
                let mut sol = normal::polonsky_keer(&mut self.conv, hat, inv_e_star, overlap);
                sol.iterations += iterations;
                break sol;
            };
            let ops = self.windows_with_normal(&w, key);
            let (conv, hat) = (&mut ops.conv, &ops.normal.as_ref().expect("just built").1);
            let part = normal::polonsky_keer(conv, hat, inv_e_star, &w.gather(overlap, grid.nx));
            iterations += part.iterations;
            let p = w.scatter(&part.p, grid.nx, n);
            let (_, _, hat) = self.normal.as_ref().expect("built above");
            let mut u = vec![0.0; n];
            self.conv
                .convolve(hat, &p, inv_e_star, &mut Vec::new(), &mut u);
            let missed: Vec<usize> = (0..n)
                .filter(|&k| {
                    !w.contains(k, grid.nx)
                        && overlap[k].is_finite()
                        && u[k] - overlap[k] < MISSED_GAP_MM
                })
                .collect();
            if missed.is_empty() {
                break NormalGrid {
                    p,
                    w: u,
                    iterations,
                    converged: part.converged,
                };
            }
            stats.windows_grown += 1;
            window = Window::around(
                grid.nx,
                grid.ny,
                NORMAL_PAD,
                missed.into_iter().chain(w.cells(grid.nx)),
            );
        };
        stats.ffts += self.ffts() - before;
        sol
    }

    fn windows_with_normal(&mut self, w: &Window, key: NormalKey) -> &mut WindowOps {
        let (_, table, _) = self.normal.as_ref().expect("built by the caller");
        let ops = ops_for(&mut self.windows, w);
        if ops.normal.as_ref().is_none_or(|(k, _)| *k != key) {
            ops.normal = Some((key, table.hat(&mut ops.conv)));
        }
        ops
    }

    /// One incremental Coulomb step (see [`tangential::bem_step`]) on a window around the
    /// cells that carry traction now or did last step; the returned displacements cover the
    /// whole grid.
    #[allow(clippy::too_many_arguments)]
    pub fn solve_tangential(
        &mut self,
        nu: f64,
        inv_e: f64,
        limit: &[f64],
        q0x: &[f64],
        q0y: &[f64],
        ds: [f64; 2],
        guess: Option<(&[f64], &[f64])>,
        stats: &mut SimStats,
    ) -> Tangential {
        let before = self.ffts();
        let grid = self.grid;
        let key = nu.to_bits();
        if self.tangential.as_ref().is_none_or(|(k, ..)| *k != key) {
            let offsets = kernels::tangential_offsets(grid.nx, grid.ny, grid.cell_mm, nu);
            let kern = kernels::tangential_kernel(&mut self.conv, &offsets);
            self.tangential = Some((key, offsets, kern));
            self.windows.values_mut().for_each(|o| o.tangential = None);
            stats.kernels_built += 1;
        }
        let n = grid.len();
        let window = Window::around(
            grid.nx,
            grid.ny,
            TANGENTIAL_PAD,
            (0..n).filter(|&k| limit[k] > 0.0 || q0x[k] != 0.0 || q0y[k] != 0.0),
        )
        .filter(|w| worth_it(w, &grid));
        let sol = match window {
            None => {
                let (_, _, kern) = self.tangential.as_ref().expect("built above");
                tangential::bem_step(&mut self.conv, kern, inv_e, limit, q0x, q0y, ds, guess)
            }
            Some(w) => {
                let (_, offsets, _) = self.tangential.as_ref().expect("built above");
                let ops = ops_for(&mut self.windows, &w);
                if ops.tangential.as_ref().is_none_or(|(k, _)| *k != key) {
                    ops.tangential =
                        Some((key, kernels::tangential_kernel(&mut ops.conv, offsets)));
                }
                let kern = &ops.tangential.as_ref().expect("just built").1;
                let at = |f: &[f64]| w.gather(f, grid.nx);
                let guess = guess.map(|(gx, gy)| (at(gx), at(gy)));
                let part = tangential::bem_step(
                    &mut ops.conv,
                    kern,
                    inv_e,
                    &at(limit),
                    &at(q0x),
                    &at(q0y),
                    ds,
                    guess.as_ref().map(|(x, y)| (x.as_slice(), y.as_slice())),
                );
                let qx = w.scatter(&part.qx, grid.nx, n);
                let qy = w.scatter(&part.qy, grid.nx, n);
                let (_, _, kern) = self.tangential.as_ref().expect("built above");
                let (ux, uy) = tangential::apply(&mut self.conv, kern, inv_e, &qx, &qy);
                Tangential {
                    qx,
                    qy,
                    ux,
                    uy,
                    iterations: part.iterations,
                    converged: part.converged,
                }
            }
        };
        stats.ffts += self.ffts() - before;
        sol
    }
}

#[cfg(test)]
mod tests {
    use rig_core::config::ElastomerConfig;
    use rig_core::indenter::Indenter;

    use super::*;

    /// The 0.4 mm grid over the default 10 × 8 mm gel (25 × 20 cells).
    fn sensor_grid() -> Grid {
        Grid::for_gel([10.0, 8.0], 0.4).expect("grid")
    }

    fn key(gel: &ElastomerConfig) -> NormalKey {
        (
            Some(gel.thickness_mm.to_bits()),
            gel.poisson_ratio.to_bits(),
        )
    }

    #[test]
    fn a_window_boxes_its_cells_with_padding_and_rounded_sides_inside_the_grid() {
        // Cells (3..=5, 4..=6) of a 25 × 20 grid, padded by 2: 1..=7 × 2..=8 (7 × 7), sides
        // rounded up to 8.
        let cells = [4 * 25 + 3, 6 * 25 + 5, 5 * 25 + 4];
        let w = Window::around(25, 20, 2, cells).expect("cells");
        assert_eq!(
            w,
            Window {
                i0: 1,
                j0: 2,
                nx: 8,
                ny: 8
            }
        );
        assert!(cells.iter().all(|&k| w.contains(k, 25)));
        assert!(!w.contains(2 * 25 + 9, 25) && !w.contains(25 * 10, 25));
        // At the far corner the rounded box slides back inside the grid.
        let w = Window::around(25, 20, 2, [19 * 25 + 24]).expect("cell");
        assert_eq!(
            w,
            Window {
                i0: 21,
                j0: 16,
                nx: 4,
                ny: 4
            }
        );
        // A box wider than the grid is the grid.
        let w = Window::around(25, 20, 2, [0, 19 * 25 + 24]).expect("cells");
        assert_eq!(
            w,
            Window {
                i0: 0,
                j0: 0,
                nx: 25,
                ny: 20
            }
        );
        assert_eq!(Window::around(25, 20, 2, []), None);
        // gather and scatter are inverse on the window and zero outside it.
        let w = Window {
            i0: 1,
            j0: 2,
            nx: 4,
            ny: 4,
        };
        let full: Vec<f64> = (0..500).map(f64::from).collect();
        let part = w.gather(&full, 25);
        assert_eq!(part[0], 51.0);
        assert_eq!(part[5], 77.0);
        let back = w.scatter(&part, 25, 500);
        for (k, (a, b)) in back.iter().zip(&full).enumerate() {
            assert_eq!(*a, if w.contains(k, 25) { *b } else { 0.0 }, "cell {k}");
        }
    }

    /// The normal solve on a window matches the same solve on the whole grid (the same
    /// iteration on a restriction of the same linear operator) for a small and a wide contact.
    #[test]
    fn the_windowed_normal_solve_is_the_whole_grids() {
        let gel = ElastomerConfig::default();
        let grid = sensor_grid();
        let inv_e_star = (1.0 - gel.poisson_ratio.powi(2)) / gel.youngs_modulus_mpa;
        for (name, axis, depth, windowed) in [
            ("cone", [0.0, 0.0], 0.8, true),
            ("sphere", [-2.5, 1.5], 0.3, true),
            ("prism", [1.0, -0.6], 0.5, true),
            ("hexagon", [0.0, 0.0], 0.5, false),
        ] {
            let ind = Indenter::builtin(name).expect("built-in");
            let ov = super::super::geometry::overlap(&ind, &grid, axis, depth, None);
            let mut stats = SimStats::default();
            let mut cache = GridCache::new(grid);
            let got = cache.solve_normal(key(&gel), gel.poisson_ratio, inv_e_star, &ov, &mut stats);
            assert!(got.converged, "{name}");
            let (_, _, hat) = cache.normal.as_ref().expect("built");
            let want = normal::polonsky_keer(&mut cache.conv, hat, inv_e_star, &ov);
            let a = grid.cell_mm * grid.cell_mm;
            let (fg, fw) = (
                got.p.iter().sum::<f64>() * a,
                want.p.iter().sum::<f64>() * a,
            );
            assert!(fw > 0.01, "{name}: {fw} N");
            assert!(
                (fg - fw).abs() <= 1e-6 * fw,
                "{name}: {fg} N against {fw} N"
            );
            let w_max = want.w.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
            for (k, (g, w)) in got.w.iter().zip(&want.w).enumerate() {
                assert!(
                    (g - w).abs() <= 1e-6 * w_max,
                    "{name}: cell {k}: {g} against {w}"
                );
            }
            // The narrow contacts ran on windows: fewer, smaller transforms than the grid's
            // (its solve above ran 2 per iteration plus 3).
            let full_ffts = 2 * want.iterations + 3;
            assert_eq!(
                cache.windows.is_empty(),
                !windowed,
                "{name}: windows {:?}",
                cache.windows.keys().collect::<Vec<_>>()
            );
            if windowed {
                assert_eq!(stats.windows_grown, 0, "{name}");
                assert!(stats.ffts >= full_ffts, "{name}: {} transforms", stats.ffts);
            }
        }
    }

    /// The bonded, nearly incompressible layer heaves around a contact (its kernel turns
    /// negative beyond about 2.4 mm). A cell outside the first window that the indenter
    /// almost touches is lifted into it: the window grows to take it in, and the solve agrees
    /// with the whole grid's, which sees every cell.
    #[test]
    fn contact_outside_the_window_grows_it() {
        let gel = ElastomerConfig::default();
        let grid = sensor_grid();
        let inv_e_star = (1.0 - gel.poisson_ratio.powi(2)) / gel.youngs_modulus_mpa;
        let ind = Indenter::builtin("sphere").expect("built-in");
        // The sphere touches about 3 cells around cell (6, 10) (x = −2.4 mm); cell (19, 10) is
        // 5.2 mm away, outside its window, where the gel rises.
        let mut ov = super::super::geometry::overlap(&ind, &grid, [-2.4, 0.0], 0.3, None);
        let far = 10 * 25 + 19;
        let first = Window::around(25, 20, NORMAL_PAD, (0..500).filter(|&k| ov[k] > 0.0));
        assert!(!first.expect("contact").contains(far, 25));
        ov[far] = -1e-7;
        let mut stats = SimStats::default();
        let mut cache = GridCache::new(grid);
        let got = cache.solve_normal(key(&gel), gel.poisson_ratio, inv_e_star, &ov, &mut stats);
        let (_, _, hat) = cache.normal.as_ref().expect("built");
        let want = normal::polonsky_keer(&mut cache.conv, hat, inv_e_star, &ov);
        assert!(
            want.p[far] > 0.0,
            "the heave lifts the far cell into contact"
        );
        assert_eq!(stats.windows_grown, 1);
        assert!(got.p[far] > 0.0);
        let (fg, fw): (f64, f64) = (got.p.iter().sum(), want.p.iter().sum());
        assert!((fg - fw).abs() <= 1e-6 * fw, "{fg} against {fw}");
        // Without the near-touch the first window holds it all.
        ov[far] = -0.01;
        let mut stats = SimStats::default();
        cache.solve_normal(key(&gel), gel.poisson_ratio, inv_e_star, &ov, &mut stats);
        assert_eq!(stats.windows_grown, 0);
    }

    /// The windowed Coulomb step (own step size, so its own iterates) reaches the whole grid's
    /// solution within the solvers' tolerance, in stick, partial slip and with history.
    #[test]
    fn the_windowed_tangential_step_is_the_whole_grids() {
        let gel = ElastomerConfig::default();
        let grid = sensor_grid();
        let n = grid.len();
        let inv_e_star = (1.0 - gel.poisson_ratio.powi(2)) / gel.youngs_modulus_mpa;
        let inv_e = 1.0 / gel.youngs_modulus_mpa;
        let ind = Indenter::builtin("sphere").expect("built-in");
        let ov = super::super::geometry::overlap(&ind, &grid, [1.0, 0.5], 0.5, None);
        let mut stats = SimStats::default();
        let mut cache = GridCache::new(grid);
        let normal = cache.solve_normal(key(&gel), gel.poisson_ratio, inv_e_star, &ov, &mut stats);
        let limit: Vec<f64> = normal
            .p
            .iter()
            .map(|p| gel.friction_coefficient * p)
            .collect();
        let zero = vec![0.0; n];
        // Partial slip from rest, then a second step with that history (a reversal).
        let (mut q0x, mut q0y) = (zero.clone(), zero.clone());
        for ds in [[0.05, 0.02], [-0.08, 0.0]] {
            let got = cache.solve_tangential(
                gel.poisson_ratio,
                inv_e,
                &limit,
                &q0x,
                &q0y,
                ds,
                None,
                &mut stats,
            );
            assert!(got.converged);
            let (_, _, kern) = cache.tangential.as_ref().expect("built");
            let want =
                tangential::bem_step(&mut cache.conv, kern, inv_e, &limit, &q0x, &q0y, ds, None);
            let a = grid.cell_mm * grid.cell_mm;
            let force = |q: &[f64]| q.iter().sum::<f64>() * a;
            let scale = force(&limit);
            for (g, w) in [(&got.qx, &want.qx), (&got.qy, &want.qy)] {
                let (fg, fw) = (force(g), force(w));
                assert!(
                    (fg - fw).abs() <= 1e-3 * scale,
                    "{ds:?}: {fg} N against {fw} N"
                );
            }
            let u_max = want
                .ux
                .iter()
                .chain(&want.uy)
                .fold(0.0_f64, |m, x| m.max(x.abs()));
            for (g, w) in got
                .ux
                .iter()
                .chain(&got.uy)
                .zip(want.ux.iter().chain(&want.uy))
            {
                assert!(
                    (g - w).abs() <= 1e-3 * u_max,
                    "{ds:?}: {g} mm against {w} mm"
                );
            }
            q0x = got.qx;
            q0y = got.qy;
        }
        assert!(
            !cache.windows.is_empty(),
            "the sphere's contact is small enough for a window"
        );
    }
}
