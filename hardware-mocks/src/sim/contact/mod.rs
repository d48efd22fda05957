//! Contact mechanics of an indenter pressed into the gel.
//!
//! # Normal models ([`ContactModel`])
//!
//! All models take the material from [`ElastomerConfig`](rig_core::config::ElastomerConfig) (`E`, `ν`, thickness `h`, `μ`) with
//! `E* = E / (1 − ν²)`, and the indenter's face as a gap field sampled at the cell centres of a
//! regular grid over the gel (cell size [`Effects::cell_mm`](super::Effects::cell_mm), default
//! [`DEFAULT_CELL_MM`]). Contact is displacement-controlled: the depth is given, the force
//! follows.
//!
//! - **Hertz** (analytic; Johnson, *Contact Mechanics*, §4.2): `a = √(R d)`,
//!   `F = 4/3 E* √R d^{3/2}`, elliptical pressure `p0 √(1 − r²/a²)`. Only for an indenter made of
//!   one spherical cap (its `radius_mm` is R); anything else is an error. Limits: a half-space
//!   (no thickness effect), parabolic profile (`a ≪ R`), `a` within the cap's rim. Needs no grid
//!   unless a field or friction is asked for.
//! - **Winkler** (fast): `p = k · max(0, d − g)`, `k = M / h`, with the oedometric (confined)
//!   modulus `M = E(1−ν)/((1+ν)(1−2ν))`. Cells are independent springs, so there is no spreading
//!   of displacement around the contact. Limit: for a nearly incompressible gel `M` is huge
//!   (ν = 0.49: `M ≈ 17 E`, `M/E* ≈ 13`), so a Winkler layer is far stiffer than the real gel
//!   under a small indenter (it is the right limit only for a thin layer under a contact much
//!   wider than `h` and a compressible material). Use it for speed, not for force accuracy.
//! - **HalfSpace** (FFT boundary elements): uniform pressure per square cell; the normal
//!   displacement is `K ∗ p` with Love's closed-form influence coefficients of a uniformly loaded
//!   rectangle (spectrally `ũ_z = 2 p̃ / (E* |k|)`), evaluated by zero-padded FFT convolution
//!   (DC-FFT, so the problem is not periodic). The contact area and pressure come from the
//!   Polonsky–Keer constrained conjugate gradient (Polonsky & Keer 1999): `p ≥ 0`, gap `≥ 0`,
//!   `p · gap = 0`. Limits: contact is confined to the gel's extent (cells beyond the gel's
//!   edge do not exist), the thickness is ignored, small strain, frictionless normal problem.
//! - **Layer** (default; FFT boundary elements for a layer of thickness `h` bonded to a rigid
//!   base, frictionless on top): the half-space kernel plus a smooth correction
//!   `u_z = (1/r + f(r)) P/(π E*)`, `f(r) = ∫₀^∞ (C(kh) − 1) J0(kr) dk`, with the layer factor
//!   `C(kh) = [(3−4ν) sinh 2kh − 2kh] / [(3−4ν) cosh 2kh + 2(kh)² + ((3−4ν)²+1)/2]` (the
//!   standard layer Green's function, as in Carbone & Mangialardi 2008, JMPS 56). It tends to
//!   the half-space for `h → ∞` and to the oedometric `h/M` for long waves. The bonded layer is
//!   stiffer than the half-space, so at the same depth it gives more force than Hertz.
//!
//! # The grid: sub-sampled overlap
//!
//! Each cell's overlap is taken from sub-samples about [`OVERLAP_SAMPLE_MM`] apart (16 in a 0.4
//! mm cell, on a lattice with one sample per row and column of the cell, shifted from cell to
//! cell, so a straight edge passes them one at a time): the mean penetration where some
//! sub-sample penetrates, else the nearest approach. A ridge or bar narrower than a cell still
//! touches, and a slide moves the overlap continuously from cell to cell (centre sampling on
//! 0.4 mm cells gave the prism zero force at 0.2 mm whenever its ridge fell between cell
//! centres, and made the line's Fz jump as it slid). A wall (a flat face's edge) covers a
//! sub-sample gradually as it passes: each sub-sample's penetration is weighted by a box filter
//! across the edge, from the face's signed distance to its edge
//! ([`Indenter::edge_mm`](rig_core::indenter::Indenter::edge_mm)), so the overlap of a sliding
//! flat face moves continuously rather than in steps of a sixteenth of the depth. The sensor physics
//! ([`Effects::sensor`](super::Effects::sensor), what `rig run`, `rig sim render|forces` and
//! the demo use) runs the layer model on 0.4 mm cells
//! ([`SENSOR_CELL_MM`](super::scene::SENSOR_CELL_MM)). Its |Fz| against the 0.1 mm grid, from
//! static presses at the gel centre:
//!
//! | indenter | 0.2 mm deep: 0.4 mm / 0.1 mm grid | 0.8 mm deep: 0.4 mm / 0.1 mm grid |
//! |---|---|---|
//! | sphere | 0.091 / 0.093 N (−2 %) | 1.169 / 1.176 N (−0.6 %) |
//! | cone | 0.011 / 0.013 N | 0.280 / 0.282 N (−0.7 %) |
//! | hexagon (flat) | 2.46 / 2.57 N (−4 %) | 9.84 / 10.28 N (−4 %) |
//! | line (bar) | 0.43 / 0.52 N (−18 %) | 1.70 / 2.07 N (−18 %) |
//! | prism (90° ridge) | 0.11–0.15 / 0.19 N | 1.27 / 1.29 N (−1 %) |
//!
//! (E = 0.2 MPa; measured with the 4 × 4 sub-sample grid the lattice replaced, which moved `rig
//! sim forces`' calibration by under 0.1 %.) Features narrower than a cell (the line's bars,
//! the prism's ridge at shallow depth) are underestimated, and a ridge sliding across a cell
//! swings its force by about ±17 % (continuously); everything else is within a few percent. A
//! 0.2 mm grid would cost about 4× per step.
//!
//! # Tangential models ([`FrictionModel`])
//!
//! Coulomb friction with stick and slip (see `tangential.rs`): tractions `|q| ≤ μ p`, cells
//! inside the Coulomb disc stick to the indenter, cells on its rim slip. The tangential
//! compliance is the half-space Cerruti solution per cell (closed form; the (1−2ν) coupling to
//! the normal problem is neglected, i.e. Goodman's approximation, exact at ν = ½); the Layer
//! model uses the same half-space tangential compliance (a limit: a thin layer is stiffer in
//! shear). Winkler uses an independent shear spring `G/h` per cell. [`FrictionModel::Monotonic`]
//! solves each frame as one shear step from the unloaded state (Cattaneo–Mindlin; no history:
//! loading and unloading give identical results); [`FrictionModel::Incremental`] carries the
//! tractions from frame to frame in the [`Simulator`](super::Simulator), so loading, shear,
//! reverse and unloading differ (the first frame in contact starts with zero traction, and
//! losing contact resets the history).
//!
//! With history, stick is tracked on the gel's material points: the overlap of a step is
//! taken where the last step left the gel surface (cell centre plus its tangential
//! displacement), so stuck material travels with the indenter and keeps its traction until
//! the Coulomb limit lets it slip. Shear then saturates by friction (gross slip,
//! `|F_t| = μ|F_n|`), not by the contact sweeping over fresh cells. This is a large-slide
//! extension of the small-strain model (one step of lag, micrometres at the run's rates); the
//! contact's cells keep their undeformed areas, so a long slide that piles the gel up in front
//! of a bar raises its Fz (the line across its length: up to about +30 % after 2 mm).
//!
//! Both iterative solvers run on a window of the grid around the contact, with the full
//! surface displacement computed once per step from the solved loads (`window.rs`): the cone's
//! step on the 0.4 mm grid costs a quarter of what the whole grid did, with the same solution
//! (to the solvers' tolerance).
//!
//! The tangential solve starts from the last step's traction change, scaled by how far this
//! step moves along the last one (a steady slide repeats its increments), and each
//! application of the Cerruti operator is one forward and one inverse FFT: both traction
//! components travel as one complex field, both displacements come back as one.
//!
//! # Viscoelastic relaxation ([`Viscoelastic`])
//!
//! A standard linear solid on the total normal force: the elastic solution (with the scene's
//! `E` as the relaxed modulus) gives `F∞(t)`; the force is `F = F∞ + (r − 1) h`, with
//! `h(t) = ∫ e^{−(t−t')/τ} dF∞(t')` updated exactly for a piecewise-linear `F∞`, and `r` the
//! ratio of instantaneous to relaxed modulus. Pressure, tractions and wrench are scaled by
//! `F / F∞`; the displacement field stays the elastic one (displacement control). Exact for a
//! contact area that only grows (Lee & Radok 1960); an approximation otherwise.
//!
//! # Accuracy: sphere against Hertz
//!
//! Sphere R = 4 mm pressed 0.5 mm into the half-space (E = 0.2 MPa, ν = 0.49), force relative
//! to Hertz; the exact sphere (not a paraboloid) is pressed, so part of the remaining
//! difference is Hertz's own parabolic approximation. From `contact_convergence.rs`:
//!
//! | cell (mm) | cells per contact radius | F (N)   | vs Hertz | vs exact sphere (Segedin 1957) |
//! |-----------|--------------------------|---------|----------|--------------------------------|
//! | 0.4       | 3.5                      | 0.24622 | −0.77%   | +0.485%                        |
//! | 0.2       | 7.1                      | 0.24540 | −1.11%   | +0.148%                        |
//! | **0.1**   | 14.1                     | 0.24514 | −1.21%   | +0.045%                        |
//! | 0.05      | 28.3                     | 0.24506 | −1.24%   | +0.009%                        |
//! | 0.025     | 56.6                     | 0.24504 | −1.25%   | +0.002%                        |
//!
//! (Hertz F = 0.24814 N, exact sphere 0.24503 N.) The grid converges to the exact sphere at
//! about first order in the cell; Hertz's paraboloid itself is 1.25% stiffer at a/R = 0.35.
//! Cone (60°, d = 1 mm, a = 1.1 mm) against `(2/π) E* tan α d²`: +0.71%, +0.02%, +0.05%,
//! +0.01% for cells 0.4 … 0.05 mm. Flat punch (a = 1.5 mm, d = 0.2 mm) against `2 a E* d`:
//! −9.3%, −4.3%, −0.05%, −0.17% (its wall filtered across the sub-samples; as a staircase of
//! point samples the 0.1 and 0.05 mm rows were −0.13% and −0.38%, the 0.4 mm row −11.8%).
//!
//! The default cell ([`DEFAULT_CELL_MM`] = 0.1 mm, 100 × 80 cells on the 10 × 8 mm gel) is within
//! 2% for all three and keeps a frame to tens of milliseconds (see `rig bench sim`). (Cells
//! larger than [`OVERLAP_SAMPLE_MM`] sub-sample their overlap, so the coarse rows above moved
//! slightly when sub-sampling came in.)
//!
//! Against a published finite-thickness solution: a sphere (R = 4 mm) on the 3 mm layer at
//! 0.1 mm cells gives 0.0571 N at 0.15 mm and 0.1898 N at 0.3 mm, against 0.0563 and 0.1849 N
//! from Dimitriadis et al. 2002 (bonded layer, their ν-dependent series): +1.4 % and +2.6 %,
//! where the half-space gives 0.041 and 0.115 N (`contact_physics.rs`).

mod fft;
mod geometry;
mod kernels;
mod normal;
mod tangential;
mod window;

use rig_core::wrench::Wrench;

pub use super::scene::{ContactModel, FrictionModel, Viscoelastic};
use super::scene::{Scene, SimError, SimStats};
use geometry::overlap;
pub use geometry::{Grid, MAX_GRID_CELLS, Material, OVERLAP_SAMPLE_MM, sphere_of};
use window::GridCache;

/// Closed-form reference forces (N) for the benchmark and tests; `e_star_mpa` is `E/(1−ν²)`.
pub mod analytic {
    /// Hertz sphere: `F = 4/3 E* √R d^{3/2}` (Johnson §4.2).
    pub fn hertz_sphere_n(e_star_mpa: f64, radius_mm: f64, depth_mm: f64) -> f64 {
        4.0 / 3.0 * e_star_mpa * radius_mm.sqrt() * depth_mm.max(0.0).powf(1.5)
    }

    /// Rigid cone of semi-angle α: `F = (2/π) E* tan α d²` (Johnson §5.2; Sneddon 1965).
    pub fn cone_n(e_star_mpa: f64, semi_angle_deg: f64, depth_mm: f64) -> f64 {
        2.0 / std::f64::consts::PI
            * e_star_mpa
            * semi_angle_deg.to_radians().tan()
            * depth_mm.max(0.0).powi(2)
    }

    /// Rigid flat circular punch of radius a: `F = 2 a E* d` (Johnson §3.8, Boussinesq).
    pub fn flat_punch_n(e_star_mpa: f64, radius_mm: f64, depth_mm: f64) -> f64 {
        2.0 * radius_mm * e_star_mpa * depth_mm.max(0.0)
    }

    /// Winkler layer under an exact sphere: `k` times the overlapping cap volume,
    /// `F = k π d² (R − d/3)`.
    pub fn winkler_sphere_n(k_n_mm3: f64, radius_mm: f64, depth_mm: f64) -> f64 {
        let d = depth_mm.max(0.0);
        k_n_mm3 * std::f64::consts::PI * d * d * (radius_mm - d / 3.0)
    }
}

/// Default grid cell, mm: the sphere converges to Hertz within 2% (see the module docs).
pub const DEFAULT_CELL_MM: f64 = 0.1;

/// Surface fields on a regular grid over the gel, in the sensor surface frame.
///
/// Cell `(i, j)` (x index `i` fastest: `k = j * nx + i`) has its centre at
/// `origin_mm + (i, j) · cell_mm`. Every vector has `nx * ny` entries.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SurfaceField {
    pub nx: usize,
    pub ny: usize,
    pub cell_mm: f64,
    /// Centre of cell (0, 0), mm.
    pub origin_mm: [f64; 2],
    /// Normal displacement of the gel surface, mm; negative where it is pressed in.
    pub uz_mm: Vec<f64>,
    /// Tangential displacement of the gel surface, mm (all zero without friction).
    pub ux_mm: Vec<f64>,
    pub uy_mm: Vec<f64>,
    /// Contact pressure, MPa (N/mm²), ≥ 0.
    pub pressure_mpa: Vec<f64>,
    /// Shear traction on the gel, MPa.
    pub traction_x_mpa: Vec<f64>,
    pub traction_y_mpa: Vec<f64>,
}

impl SurfaceField {
    /// A flat, unloaded field on `grid`.
    fn flat(grid: &Grid) -> Self {
        Self::unloaded(grid.nx, grid.ny, grid.cell_mm, grid.origin_mm)
    }

    /// A flat, unloaded field of `nx × ny` cells of `cell_mm`, cell (0, 0) centred at
    /// `origin_mm`.
    pub fn unloaded(nx: usize, ny: usize, cell_mm: f64, origin_mm: [f64; 2]) -> Self {
        let n = nx * ny;
        Self {
            nx,
            ny,
            cell_mm,
            origin_mm,
            uz_mm: vec![0.0; n],
            ux_mm: vec![0.0; n],
            uy_mm: vec![0.0; n],
            pressure_mpa: vec![0.0; n],
            traction_x_mpa: vec![0.0; n],
            traction_y_mpa: vec![0.0; n],
        }
    }

    /// Centre of cell `k`, mm.
    pub fn cell_centre_mm(&self, k: usize) -> [f64; 2] {
        let (i, j) = (k % self.nx.max(1), k / self.nx.max(1));
        [
            self.origin_mm[0] + i as f64 * self.cell_mm,
            self.origin_mm[1] + j as f64 * self.cell_mm,
        ]
    }
}

/// What the contact stage hands back to the simulator.
pub(crate) struct Solved {
    pub wrench: Wrench,
    pub contact_area_mm2: f64,
    pub field: Option<SurfaceField>,
}

#[derive(Clone)]
struct TangentialHistory {
    grid: Grid,
    model: ContactModel,
    indenter_mm: [f64; 2],
    qx: Vec<f64>,
    qy: Vec<f64>,
    /// The gel surface's tangential displacement at the end of the step, mm.
    ux: Vec<f64>,
    uy: Vec<f64>,
    /// The step's traction change and indenter displacement (the next solve's start).
    last_step: Option<(Vec<f64>, Vec<f64>, [f64; 2])>,
}

#[derive(Debug, Clone, Copy)]
struct ViscoHistory {
    time_s: f64,
    f_relaxed: f64,
    memory: f64,
}

/// The contact's history (stick and slip, relaxation) as a step leaves it, saved to be put
/// back ([`Simulator::history`](super::Simulator::history)).
#[derive(Clone)]
pub struct History {
    friction: Option<TangentialHistory>,
    visco: Option<ViscoHistory>,
}

/// The contact stage with its caches and history (owned by a `Simulator`).
#[derive(Default)]
pub(crate) struct ContactEngine {
    cache: Option<GridCache>,
    friction: Option<TangentialHistory>,
    visco: Option<ViscoHistory>,
}

/// The grid cache in `slot`, made anew for `grid` when it holds another grid's (or none).
fn grid_cache(slot: &mut Option<GridCache>, grid: Grid) -> &mut GridCache {
    if slot.as_ref().is_none_or(|c| c.grid != grid) {
        *slot = Some(GridCache::new(grid));
    }
    slot.as_mut().expect("just set")
}

impl ContactEngine {
    pub fn reset_history(&mut self) {
        self.friction = None;
        self.visco = None;
    }

    /// A copy of the history (the caches are not part of it).
    pub(crate) fn history(&self) -> History {
        History {
            friction: self.friction.clone(),
            visco: self.visco,
        }
    }

    /// Puts `h` (saved by [`Self::history`]) in place of the history, and gives the one it
    /// replaced.
    pub(crate) fn replace_history(&mut self, h: History) -> History {
        History {
            friction: std::mem::replace(&mut self.friction, h.friction),
            visco: std::mem::replace(&mut self.visco, h.visco),
        }
    }

    fn cache_for(&mut self, grid: Grid) -> &mut GridCache {
        grid_cache(&mut self.cache, grid)
    }

    /// The boundary-element normal solve (half-space or layer) of `scene`'s indenter at
    /// `depth_mm` on `grid`, the gel's material points moved by `shift` where given; counts its
    /// iterations and convergence into `stats`. (On the engine's grid cache alone, so that
    /// `shift` may borrow its friction history.)
    #[allow(clippy::too_many_arguments)]
    fn solve_bem_normal(
        cache: &mut Option<GridCache>,
        scene: &Scene,
        mat: &Material,
        model: ContactModel,
        grid: Grid,
        axis: [f64; 2],
        depth_mm: f64,
        shift: Option<(&[f64], &[f64])>,
        stats: &mut SimStats,
    ) -> normal::NormalGrid {
        let overlap = overlap(&scene.indenter, &grid, axis, depth_mm, shift);
        let thick = (model == ContactModel::Layer).then_some(mat.thickness_mm);
        let key = (thick.map(f64::to_bits), mat.poisson.to_bits());
        let sol = grid_cache(cache, grid).solve_normal(
            key,
            mat.poisson,
            1.0 / mat.e_star_mpa,
            &overlap,
            stats,
        );
        stats.normal_iterations += sol.iterations;
        stats.converged &= sol.converged;
        sol
    }

    pub fn solve(
        &mut self,
        scene: &Scene,
        time_s: f64,
        want_field: bool,
        stats: &mut SimStats,
    ) -> Result<Solved, SimError> {
        let mat = Material::from_config(&scene.elastomer)?;
        let pose = scene.pose;
        let e = &scene.effects;
        for (name, v) in [
            ("pose.depth_mm", pose.depth_mm),
            ("pose.contact_mm[0]", pose.contact_mm[0]),
            ("pose.contact_mm[1]", pose.contact_mm[1]),
            ("pose.shear_mm[0]", pose.shear_mm[0]),
            ("pose.shear_mm[1]", pose.shear_mm[1]),
            ("time_s", time_s),
        ] {
            if !v.is_finite() {
                return Err(SimError::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be a finite number".into(),
                });
            }
        }
        if pose.depth_mm > mat.thickness_mm {
            return Err(SimError::DepthBeyondThickness {
                depth_mm: pose.depth_mm,
                thickness_mm: mat.thickness_mm,
            });
        }
        if let Some(v) = e.viscoelastic {
            if !(v.instant_ratio.is_finite() && v.instant_ratio >= 1.0) {
                return Err(SimError::InvalidParameter {
                    name: "effects.viscoelastic.instant_ratio",
                    value: v.instant_ratio,
                    reason: "must be a finite number ≥ 1".into(),
                });
            }
            if !(v.tau_s.is_finite() && v.tau_s > 0.0) {
                return Err(SimError::InvalidParameter {
                    name: "effects.viscoelastic.tau_s",
                    value: v.tau_s,
                    reason: "must be a finite number > 0".into(),
                });
            }
        }
        let model = e.contact;
        let sphere = match model {
            ContactModel::Hertz => Some(sphere_of(&scene.indenter)?),
            _ => None,
        };
        let friction = if mat.friction > 0.0 {
            e.friction
        } else {
            FrictionModel::None
        };
        let cell = e.cell_mm.unwrap_or(DEFAULT_CELL_MM);
        let needs_grid =
            model != ContactModel::Hertz || want_field || friction != FrictionModel::None;
        let grid = if needs_grid {
            Some(Grid::for_gel(
                [scene.elastomer.size_x_mm, scene.elastomer.size_y_mm],
                cell,
            )?)
        } else {
            None
        };
        let axis = [
            pose.contact_mm[0] + pose.shear_mm[0],
            pose.contact_mm[1] + pose.shear_mm[1],
        ];
        let centre = pose.contact_mm;

        // --- normal stage -----------------------------------------------------------------
        // Either analytic (Hertz without a grid) or a pressure field on the grid.
        let mut hertz_total: Option<(normal::Hertz, [f64; 2])> = None;
        let mut p: Option<Vec<f64>> = None;
        let mut w: Option<Vec<f64>> = None;
        // With friction history, the gel's surface is where the last step left it: stuck
        // material has moved with the indenter, so the contact is found at the displaced
        // material points (stick is tracked in the gel's material coordinates). This first
        // search lags one step; after the tangential stage the contact is found again on the
        // surface the step leaves (see "the contact at the end of the step" below).
        // Only for the continuum (BEM) models: Winkler's independent shear springs are 51×
        // softer than its normal ones at ν = 0.49, so their stick displacements are not a
        // surface that moves (they reach tens of mm).
        let continuum = matches!(model, ContactModel::HalfSpace | ContactModel::Layer);
        let shift = match (&self.friction, friction) {
            (Some(h), FrictionModel::Incremental)
                if continuum && grid == Some(h.grid) && h.model == model =>
            {
                Some((h.ux.as_slice(), h.uy.as_slice()))
            }
            _ => None,
        };
        if pose.depth_mm > 0.0 {
            stats.normal_solves += 1;
            match model {
                ContactModel::Hertz => {
                    let (r, offset, rim) = sphere.expect("checked above");
                    let h = normal::Hertz::new(r, pose.depth_mm, mat.e_star_mpa);
                    if h.a_mm > rim {
                        return Err(SimError::NotASphere {
                            indenter: scene.indenter.name().to_owned(),
                            reason: format!(
                                "pressed {} mm deep, beyond its spherical cap (contact radius {:.3} mm > rim {rim} mm)",
                                pose.depth_mm, h.a_mm
                            ),
                        });
                    }
                    let c = [axis[0] + offset[0], axis[1] + offset[1]];
                    if let Some(grid) = grid {
                        let n = grid.len();
                        let (mut pp, mut ww) = (vec![0.0; n], vec![0.0; n]);
                        for k in 0..n {
                            let [x, y] = grid.centre_mm(k);
                            let rr = (x - c[0]).hypot(y - c[1]);
                            pp[k] = h.pressure(rr);
                            ww[k] = h.displacement(rr);
                        }
                        p = Some(pp);
                        w = Some(ww);
                    }
                    hertz_total = Some((h, c));
                }
                ContactModel::Winkler => {
                    let grid = grid.expect("gridded model");
                    let k = mat.oedometric_mpa / mat.thickness_mm;
                    let overlap = overlap(&scene.indenter, &grid, axis, pose.depth_mm, shift);
                    let ov: Vec<f64> = overlap.iter().map(|d| d.max(0.0)).collect();
                    p = Some(ov.iter().map(|d| k * d).collect());
                    w = Some(ov);
                }
                ContactModel::HalfSpace | ContactModel::Layer => {
                    let grid = grid.expect("gridded model");
                    let sol = Self::solve_bem_normal(
                        &mut self.cache,
                        scene,
                        &mat,
                        model,
                        grid,
                        axis,
                        pose.depth_mm,
                        shift,
                        stats,
                    );
                    p = Some(sol.p);
                    w = Some(sol.w);
                }
            }
        }
        let in_contact = pose.depth_mm > 0.0
            && (hertz_total.is_some() || p.as_ref().is_some_and(|p| p.iter().any(|&x| x > 0.0)));

        // --- tangential stage -------------------------------------------------------------
        let mut tang: Option<tangential::Tangential> = None;
        if friction != FrictionModel::None {
            let grid = grid.expect("friction needs a grid");
            let pp = p.as_ref();
            if in_contact {
                let pp = pp.expect("grid pressure");
                let limit: Vec<f64> = pp.iter().map(|x| mat.friction * x).collect();
                let n = grid.len();
                let (q0x, q0y, ds, last) = match friction {
                    FrictionModel::Monotonic => (vec![0.0; n], vec![0.0; n], pose.shear_mm, None),
                    _ => match self.friction.take() {
                        Some(hist) if hist.grid == grid && hist.model == model => (
                            hist.qx,
                            hist.qy,
                            [axis[0] - hist.indenter_mm[0], axis[1] - hist.indenter_mm[1]],
                            hist.last_step,
                        ),
                        _ => (vec![0.0; n], vec![0.0; n], [0.0, 0.0], None),
                    },
                };
                // Where the solver starts: the last step's traction change, scaled by how far
                // this step moves along the last one (a steady slide repeats its increments).
                let guess = last.and_then(|(dqx, dqy, last_ds)| {
                    let len2 = last_ds[0] * last_ds[0] + last_ds[1] * last_ds[1];
                    let along = (ds[0] * last_ds[0] + ds[1] * last_ds[1]) / len2;
                    (len2 > 0.0 && along > 0.0).then(|| {
                        let gx: Vec<f64> =
                            q0x.iter().zip(&dqx).map(|(q, d)| q + along * d).collect();
                        let gy: Vec<f64> =
                            q0y.iter().zip(&dqy).map(|(q, d)| q + along * d).collect();
                        (gx, gy)
                    })
                });
                stats.tangential_solves += 1;
                let sol = if model == ContactModel::Winkler {
                    let k_t = mat.shear_mpa / mat.thickness_mm;
                    tangential::spring_step(k_t, &limit, &q0x, &q0y, ds)
                } else {
                    self.cache_for(grid).solve_tangential(
                        mat.poisson,
                        1.0 / mat.youngs_mpa,
                        &limit,
                        &q0x,
                        &q0y,
                        ds,
                        guess.as_ref().map(|(x, y)| (x.as_slice(), y.as_slice())),
                        stats,
                    )
                };
                stats.tangential_iterations += sol.iterations;
                stats.converged &= sol.converged;
                if friction == FrictionModel::Incremental {
                    self.friction = Some(TangentialHistory {
                        grid,
                        model,
                        indenter_mm: axis,
                        qx: sol.qx.clone(),
                        qy: sol.qy.clone(),
                        ux: sol.ux.clone(),
                        uy: sol.uy.clone(),
                        last_step: Some((
                            sol.qx.iter().zip(&q0x).map(|(a, b)| a - b).collect(),
                            sol.qy.iter().zip(&q0y).map(|(a, b)| a - b).collect(),
                            ds,
                        )),
                    });
                }
                tang = Some(sol);
            } else {
                self.friction = None;
            }
        }

        // --- the contact at the end of the step -------------------------------------------
        // The normal stage found the contact on the surface as the last step left it; the
        // stuck material has since moved with the indenter. One fixed-point pass finds it again
        // on the surface this step leaves. On the simulated rig's runs (physics ticks, frame
        // steps and F/T steps interleaved) this made a sliding flat face's Fz less jumpy from
        // step to step: the largest |F/T label − frame's true force| over 16 trajectories fell
        // from 0.48–0.55 N to 0.14 N for the hexagon, 0.76–0.91 to 0.35–0.40 N for paralines,
        // 0.23–0.25 to 0.09–0.14 N for the cylinder. It costs a second normal solve per contact
        // step (the cone's full plan: 158 → 169 s). It is not a full coupling: the tangential
        // solve still used the lagged contact's friction limits, and a slide split into other
        // step lengths still changes Fz (paralines across its ridges, 40 µm steps against
        // 38 + 2 µm: up to 0.52 N, 0.14 N without this pass, on the sub-sample lattice). What
        // the pass buys is a contact that holds still: without it each step re-runs the search ↔
        // friction loop once more, which does not settle where the contact has edges, so 20
        // steps at rest after a 2 mm slide spread Fz over 1.45 N (paralines; hexagon 0.30 N),
        // against 0.16 N (0.07 N) with it. Iterating the pass further does not converge either
        // (paralines' |Fz| max 9.84, 8.83 and 10.0 N after 2, 3 and 8 passes).
        // (A tangential solution exists only in contact, so the depth is positive here.)
        if continuum
            && friction == FrictionModel::Incremental
            && let (Some(t), Some(grid)) = (&tang, grid)
        {
            let sol = Self::solve_bem_normal(
                &mut self.cache,
                scene,
                &mat,
                model,
                grid,
                axis,
                pose.depth_mm,
                Some((t.ux.as_slice(), t.uy.as_slice())),
                stats,
            );
            p = Some(sol.p);
            w = Some(sol.w);
        }

        // --- wrench -----------------------------------------------------------------------
        let mut f = [0.0; 3];
        let mut t = [0.0; 3];
        let mut area = 0.0;
        if let Some((h, c)) = hertz_total {
            f[2] = -h.force_n;
            let (rx, ry) = (c[0] - centre[0], c[1] - centre[1]);
            t[0] = ry * f[2];
            t[1] = -rx * f[2];
            area = std::f64::consts::PI * h.a_mm * h.a_mm;
        } else if let (Some(pp), Some(grid)) = (&p, grid) {
            let a = grid.cell_mm * grid.cell_mm;
            for (k, &pk) in pp.iter().enumerate() {
                if pk > 0.0 {
                    let [x, y] = grid.centre_mm(k);
                    let fz = -pk * a;
                    f[2] += fz;
                    t[0] += (y - centre[1]) * fz;
                    t[1] -= (x - centre[0]) * fz;
                    area += a;
                }
            }
        }
        if let (Some(tg), Some(grid)) = (&tang, grid) {
            let a = grid.cell_mm * grid.cell_mm;
            for k in 0..grid.len() {
                let (fx, fy) = (tg.qx[k] * a, tg.qy[k] * a);
                if fx != 0.0 || fy != 0.0 {
                    let [x, y] = grid.centre_mm(k);
                    f[0] += fx;
                    f[1] += fy;
                    t[2] += (x - centre[0]) * fy - (y - centre[1]) * fx;
                }
            }
        }

        // --- viscoelastic stage -----------------------------------------------------------
        let mut scale = 1.0;
        if let Some(v) = e.viscoelastic {
            let f_relaxed = -f[2];
            let prev = self.visco.unwrap_or(ViscoHistory {
                time_s,
                f_relaxed: 0.0,
                memory: 0.0,
            });
            let dt = (time_s - prev.time_s).max(0.0);
            let x = dt / v.tau_s;
            let decay = (-x).exp();
            let ramp = if x > 1e-12 { (1.0 - decay) / x } else { 1.0 };
            let memory = decay * prev.memory + (f_relaxed - prev.f_relaxed) * ramp;
            self.visco = Some(ViscoHistory {
                time_s,
                f_relaxed,
                memory,
            });
            let total = (f_relaxed + (v.instant_ratio - 1.0) * memory).max(0.0);
            scale = if f_relaxed > 0.0 {
                total / f_relaxed
            } else {
                0.0
            };
            f.iter_mut().chain(t.iter_mut()).for_each(|x| *x *= scale);
        }

        // --- surface field ----------------------------------------------------------------
        let field = if want_field {
            let grid = grid.expect("a field needs a grid");
            stats.fields_built += 1;
            let mut field = SurfaceField::flat(&grid);
            if let Some(w) = &w {
                field.uz_mm.iter_mut().zip(w).for_each(|(u, w)| *u = -w);
            }
            if let Some(pp) = &p {
                field
                    .pressure_mpa
                    .iter_mut()
                    .zip(pp)
                    .for_each(|(o, p)| *o = p * scale);
            }
            if let Some(tg) = tang {
                field.ux_mm = tg.ux;
                field.uy_mm = tg.uy;
                field.traction_x_mpa = tg.qx.iter().map(|q| q * scale).collect();
                field.traction_y_mpa = tg.qy.iter().map(|q| q * scale).collect();
            }
            Some(field)
        } else {
            None
        };

        Ok(Solved {
            wrench: Wrench {
                force_n: f,
                torque_nmm: t,
            },
            contact_area_mm2: area,
            field,
        })
    }
}
