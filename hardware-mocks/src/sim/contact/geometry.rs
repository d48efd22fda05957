//! The contact step's geometry and material: the elastomer's constants, the grid over the gel,
//! the indenter's overlap with the gel per cell, and the sphere of the Hertz model.

use rig_core::config::ElastomerConfig;
use rig_core::indenter::{Geometry, Indenter, Primitive};

use super::MAX_GRID_CELLS;
use crate::sim::scene::SimError;

/// Material constants derived from the elastomer configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    pub youngs_mpa: f64,
    pub poisson: f64,
    /// Plane-strain modulus `E* = E / (1 − ν²)`.
    pub e_star_mpa: f64,
    /// Shear modulus `G = E / (2(1 + ν))`.
    pub shear_mpa: f64,
    /// Oedometric modulus `M = E(1−ν)/((1+ν)(1−2ν))`.
    pub oedometric_mpa: f64,
    pub thickness_mm: f64,
    pub friction: f64,
}

impl Material {
    /// Checks the elastomer's values: `E > 0`, `0 ≤ ν < 0.5`, `h > 0`, `μ ≥ 0`, size > 0.
    pub fn from_config(c: &ElastomerConfig) -> Result<Self, SimError> {
        // Each value must hold `ok`, else the error names it and says what it must be.
        let check = |name, value: f64, ok: bool, reason: &str| {
            if ok {
                Ok(value)
            } else {
                Err(SimError::InvalidParameter {
                    name,
                    value,
                    reason: reason.to_owned(),
                })
            }
        };
        let positive = |name, v: f64| {
            check(
                name,
                v,
                v.is_finite() && v > 0.0,
                "must be a finite number > 0",
            )
        };
        let e = positive("elastomer.youngs_modulus_mpa", c.youngs_modulus_mpa)?;
        let nu = c.poisson_ratio;
        check(
            "elastomer.poisson_ratio",
            nu,
            nu.is_finite() && (0.0..0.5).contains(&nu),
            "must be in [0, 0.5) (0.5 is incompressible: use 0.49)",
        )?;
        let h = positive("elastomer.thickness_mm", c.thickness_mm)?;
        let mu = c.friction_coefficient;
        check(
            "elastomer.friction_coefficient",
            mu,
            mu.is_finite() && mu >= 0.0,
            "must be a finite number ≥ 0",
        )?;
        positive("elastomer.size_x_mm", c.size_x_mm)?;
        positive("elastomer.size_y_mm", c.size_y_mm)?;
        Ok(Self {
            youngs_mpa: e,
            poisson: nu,
            e_star_mpa: e / (1.0 - nu * nu),
            shear_mpa: e / (2.0 * (1.0 + nu)),
            oedometric_mpa: e * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu)),
            thickness_mm: h,
            friction: mu,
        })
    }
}

/// The contact grid over the gel: `nx × ny` square cells of `cell_mm`, centred on the gel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    pub nx: usize,
    pub ny: usize,
    pub cell_mm: f64,
    pub origin_mm: [f64; 2],
}

impl Grid {
    /// The grid over a gel of `size_mm` at `cell_mm` (cell count rounded, at least 1).
    pub fn for_gel(size_mm: [f64; 2], cell_mm: f64) -> Result<Self, SimError> {
        if !(cell_mm.is_finite() && cell_mm > 0.0) {
            return Err(SimError::InvalidParameter {
                name: "effects.cell_mm",
                value: cell_mm,
                reason: "must be a finite number > 0".into(),
            });
        }
        let n = |s: f64| (s / cell_mm).round().max(1.0);
        let (fx, fy) = (n(size_mm[0]), n(size_mm[1]));
        if fx * fy > MAX_GRID_CELLS as f64 {
            return Err(SimError::Grid(format!(
                "{fx} × {fy} cells of {cell_mm} mm exceed {MAX_GRID_CELLS}; use a larger cell_mm"
            )));
        }
        let (nx, ny) = (fx as usize, fy as usize);
        Ok(Self {
            nx,
            ny,
            cell_mm,
            origin_mm: [
                -(nx as f64 - 1.0) / 2.0 * cell_mm,
                -(ny as f64 - 1.0) / 2.0 * cell_mm,
            ],
        })
    }

    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn centre_mm(&self, k: usize) -> [f64; 2] {
        [
            self.origin_mm[0] + (k % self.nx) as f64 * self.cell_mm,
            self.origin_mm[1] + (k / self.nx) as f64 * self.cell_mm,
        ]
    }
}

/// A sphere cap's radius and centre offset, or why the indenter is not one.
pub fn sphere_of(indenter: &Indenter) -> Result<(f64, [f64; 2], f64), SimError> {
    let not = |reason: &str| SimError::NotASphere {
        indenter: indenter.name().to_owned(),
        reason: reason.to_owned(),
    };
    match indenter.geometry() {
        Geometry::Mesh(_) => Err(not("a mesh")),
        Geometry::Shapes(shapes) => match shapes.as_slice() {
            [shape] => match &shape.primitive {
                Primitive::SphereCap(cap) => Ok((
                    cap.radius_mm,
                    shape.center_mm,
                    cap.rim_radius_mm.unwrap_or(cap.radius_mm),
                )),
                other => Err(not(&format!("a {}", primitive_name(other)))),
            },
            _ => Err(not(&format!("a union of {} shapes", shapes.len()))),
        },
    }
}

fn primitive_name(p: &Primitive) -> &'static str {
    match p {
        Primitive::SphereCap(_) => "sphere cap",
        Primitive::Cone(_) => "cone",
        Primitive::FlatPunch(_) => "flat punch",
        Primitive::Ring(_) => "ring",
        Primitive::Torus(_) => "torus",
        Primitive::Polygon(_) => "polygon",
        Primitive::Bars(_) => "set of bars",
        Primitive::Wedge(_) => "wedge",
        Primitive::DotGrid(_) => "dot grid",
        Primitive::Wave(_) => "wave",
        Primitive::Moon(_) => "moon",
        Primitive::Pacman(_) => "pacman",
        Primitive::RandomBumps(_) => "set of random bumps",
    }
}

/// Spacing of the sub-samples the overlap of a cell is taken from, mm: features down to this
/// size (a sharp ridge, a thin bar) touch the grid whatever the cell, and a slide moves the
/// overlap smoothly from cell to cell.
pub const OVERLAP_SAMPLE_MM: f64 = 0.1;

/// Geometric overlap of the indenter (axis at `axis_mm`) with the gel, per cell. The gel's
/// material point of cell `k` sits at its centre plus `shift` (the surface's tangential
/// displacement, when the contact drags the gel along; `None`: undeformed).
///
/// The cell is sampled on an `s × s` grid of sub-cells (`s = ⌈cell / OVERLAP_SAMPLE_MM⌉`):
/// where some sub-sample penetrates, the overlap is the mean penetration `max(0, d − g)` over
/// all sub-samples (the interference volume per area, so it changes continuously as a feature
/// slides across the cell); where none does, it is the largest `d − g` (≤ 0: the smallest gap,
/// so the cell enters contact when its nearest point is reached). `−∞` where the indenter has
/// no material over the whole cell.
pub(super) fn overlap(
    indenter: &Indenter,
    grid: &Grid,
    axis_mm: [f64; 2],
    depth_mm: f64,
    shift: Option<(&[f64], &[f64])>,
) -> Vec<f64> {
    let s = ((grid.cell_mm / OVERLAP_SAMPLE_MM) - 1e-9).ceil().max(1.0) as usize;
    let sub = grid.cell_mm / s as f64;
    let first = -grid.cell_mm / 2.0 + sub / 2.0;
    let count = (s * s) as f64;
    (0..grid.len())
        .map(|k| {
            let [mut x, mut y] = grid.centre_mm(k);
            if let Some((ux, uy)) = shift {
                x += ux[k];
                y += uy[k];
            }
            let (mut sum, mut best) = (0.0, f64::NEG_INFINITY);
            for a in 0..s {
                for b in 0..s {
                    let (sx, sy) = (x + first + a as f64 * sub, y + first + b as f64 * sub);
                    let g = indenter.gap_mm(sx - axis_mm[0], sy - axis_mm[1]);
                    if g.is_finite() {
                        let v = depth_mm - g;
                        best = best.max(v);
                        sum += v.max(0.0);
                    }
                }
            }
            if best > 0.0 { sum / count } else { best }
        })
        .collect()
}
