//! The contact step's geometry and material: the elastomer's constants, the grid over the gel,
//! the indenter's overlap with the gel per cell, and the sphere of the Hertz model.

use rig_core::config::ElastomerConfig;
use rig_core::indenter::{Geometry, Indenter, Primitive};

use crate::sim::scene::SimError;

/// Most cells a contact grid may have (a typo in a cell size must not exhaust memory).
pub const MAX_GRID_CELLS: usize = 1 << 20;

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

/// Mean spacing of the sub-samples the overlap of a cell is taken from, mm: features down to
/// this size (a sharp ridge, a thin bar) touch the grid whatever the cell, and a slide moves the
/// overlap smoothly from cell to cell.
pub const OVERLAP_SAMPLE_MM: f64 = 0.1;

/// Geometric overlap of the indenter (axis at `axis_mm`) with the gel, per cell. The gel's
/// material point of cell `k` sits at its centre plus `shift` (the surface's tangential
/// displacement, when the contact drags the gel along; `None`: undeformed).
///
/// The cell is sampled at `n = s²` sub-samples (`s = ⌈cell / OVERLAP_SAMPLE_MM⌉`): where some
/// sub-sample penetrates, the overlap is the mean penetration `max(0, d − g)` over all of them
/// (the interference volume per area, so it follows a feature sliding across the cell); where
/// none does, it is the largest `d − g` (≤ 0: the smallest gap, so the cell enters contact when
/// its nearest point is reached). `−∞` where the indenter has no material over the whole cell.
///
/// The sub-samples are not an `s × s` grid but a lattice with one sample in each of `n` columns
/// and each of `n` rows of the cell ([`sub_samples`]), shifted differently in each cell
/// ([`cell_offset`]). A flat face's straight edge (a bar, a hexagon's side) has no depth
/// gradient to follow, so the overlap steps each time the edge passes a sub-sample. On an
/// `s × s` grid an edge along a grid axis passed a whole row of sub-samples in every cell of its
/// length at once: paralines sliding across its ridges kept the same Fz for 20 µm, then stepped
/// by about 0.16 N, every 0.1 mm. On the lattice the edge passes one sample at a time, at other
/// places in each cell. On the simulated rig (16 trajectories per indenter: 2 contact points,
/// 0.4 and 0.8 mm, 4 directions; two runs each), the largest |F/T label − frame's true force|
/// went from 0.14 / 0.14 to 0.12 / 0.15 N (hexagon), 0.35 / 0.40 to 0.34 / 0.19 (paralines),
/// 0.20 / 0.18 to 0.14 / 0.14 (triangle), 0.14 / 0.09 to 0.08 / 0.10 (cylinder) and 0.17 / 0.16
/// to 0.10 / 0.21 N (torus): smaller in 8 of 10 runs, within the runs' spread in the rest.
///
/// **Walls are filtered.** A point sample is in or out of a flat face, so a wall (the face's
/// edge) passing a sub-sample stepped the cell's overlap by a sixteenth of the depth at once,
/// and a sliding flat face's force moved in steps. A sub-sample `distance` outside the
/// footprint's edge (signed distance, [`Indenter::edge_mm`]) now counts its penetration of the
/// face at the edge with the weight `clamp(1 + distance / w, 0, 1)`, `w = cell / s` the
/// sub-samples' spacing: a linear ramp one spacing wide outside the wall, so the overlap moves
/// continuously. The ramp lies outside the edge because a rigid face's load is carried where
/// it is fully pressed: a ramp centred on the edge made the flat punch 3.6 % soft at the 0.1 mm
/// cell against `2 a E* d`; this one gives −0.05 % (`contact_convergence.rs`), and the bonded
/// layer's punch within 0.3 % at 0.05 and 0.025 mm cells (`contact_physics.rs`; −1.8 and
/// −0.8 % before). A mesh has no edge distance and is sampled at points.
///
/// Sliding at 300°, 0.6 mm deep, with friction, the largest change of force from one 0.5 ms
/// probe to the next (1 µm of slide) fell from 0.070 to 0.045 N on paralines, from 0.025 to
/// 0.003 N on the hexagon, from 0.051 to 0.010 N on dotin and from 0.039 to 0.008 N on pacman
/// (`docs/experiments.md`, *Walls filtered across the sub-samples*).
pub(super) fn overlap(
    indenter: &Indenter,
    grid: &Grid,
    axis_mm: [f64; 2],
    depth_mm: f64,
    shift: Option<(&[f64], &[f64])>,
) -> Vec<f64> {
    let s = ((grid.cell_mm / OVERLAP_SAMPLE_MM) - 1e-9).ceil().max(1.0) as usize;
    let n = s * s;
    let count = n as f64;
    let pattern = sub_samples(s);
    let w = grid.cell_mm / s as f64;
    (0..grid.len())
        .map(|k| {
            let [mut x, mut y] = grid.centre_mm(k);
            if let Some((ux, uy)) = shift {
                x += ux[k];
                y += uy[k];
            }
            let offset = if n > 1 { cell_offset(k) } else { [0.0, 0.0] };
            let (mut sum, mut best) = (0.0, f64::NEG_INFINITY);
            for [a, b] in &pattern {
                let sx = x + grid.cell_mm * (wrap_unit(a + offset[0]) - 0.5);
                let sy = y + grid.cell_mm * (wrap_unit(b + offset[1]) - 0.5);
                if let Some((g, distance)) = indenter.edge_mm(sx - axis_mm[0], sy - axis_mm[1]) {
                    let c = (1.0 + distance / w).clamp(0.0, 1.0);
                    if c > 0.0 {
                        let v = depth_mm - g;
                        best = best.max(v);
                        sum += c * v.max(0.0);
                    }
                    continue;
                }
                let g = indenter.gap_mm(sx - axis_mm[0], sy - axis_mm[1]);
                if g.is_finite() {
                    let v = depth_mm - g;
                    best = best.max(v);
                    sum += v.max(0.0);
                }
            }
            if best > 0.0 { sum / count } else { best }
        })
        .collect()
}

/// The `s²` sub-sample positions of a cell, in cell units (`[0, 1)²`): a rank-1 lattice, one
/// sample in each of the `s²` columns and each of the `s²` rows (`s = 1`: the centre).
fn sub_samples(s: usize) -> Vec<[f64; 2]> {
    let n = s * s;
    if n == 1 {
        return vec![[0.5, 0.5]];
    }
    // A generator coprime with n, near n / φ² (φ the golden ratio), spreads the samples over
    // the cell rather than along its diagonal.
    let g = (1..n)
        .rev()
        .filter(|&g| gcd(g, n) == 1)
        .min_by(|&a, &b| {
            let t = n as f64 * 0.381_966;
            (a as f64 - t).abs().total_cmp(&(b as f64 - t).abs())
        })
        .unwrap_or(1);
    (0..n)
        .map(|i| {
            [
                (i as f64 + 0.5) / n as f64,
                ((i * g % n) as f64 + 0.5) / n as f64,
            ]
        })
        .collect()
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 { a } else { gcd(b, a % b) }
}

/// A per-cell shift of the sub-sample lattice (cell units, wrapped in the cell), from the
/// cell's index by the golden-ratio sequence: neighbouring cells sample at other offsets.
fn cell_offset(k: usize) -> [f64; 2] {
    const PHI: f64 = 0.618_033_988_749_895;
    const PSI: f64 = 0.754_877_666_246_693; // 1 / plastic number
    let frac = |x: f64| x - x.trunc();
    [frac(k as f64 * PHI), frac(k as f64 * PSI)]
}

/// `x % 1.0` for `x` in `[0, 2)`, bit for bit (the subtraction is exact there), without a call
/// to libm's `fmod` or `trunc` per sub-sample: they were 7 % of a simulated run's CPU.
fn wrap_unit(x: f64) -> f64 {
    if x >= 1.0 { x - 1.0 } else { x }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A straight edge along either axis passes the sub-samples one at a time: every column and
    /// every row of the `n × n` subdivision of the cell holds exactly one sample, and the
    /// samples are spread over the cell (not along its diagonal).
    #[test]
    fn sub_samples_fill_every_row_and_column_once() {
        for s in 1..=6 {
            let n = s * s;
            let pts = sub_samples(s);
            assert_eq!(pts.len(), n);
            for axis in 0..2 {
                let mut idx: Vec<usize> = pts
                    .iter()
                    .map(|p| (p[axis] * n as f64).floor() as usize)
                    .collect();
                idx.sort_unstable();
                assert_eq!(idx, (0..n).collect::<Vec<_>>(), "s = {s}, axis {axis}");
            }
            if n >= 4 {
                // Every quadrant of the cell holds a quarter of the samples, give or take one.
                for (qx, qy) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                    let inside = pts
                        .iter()
                        .filter(|p| (p[0] >= 0.5) == (qx == 1) && (p[1] >= 0.5) == (qy == 1))
                        .count();
                    assert!(
                        inside.abs_diff(n / 4) <= 1,
                        "s = {s}: {inside} of {n} in one quadrant"
                    );
                }
            }
        }
    }

    /// Neighbouring cells (along a row, and along a column of the sensor's 25-cell rows) place
    /// their samples at other positions within the columns and rows of the subdivision, so an
    /// edge crossing a row of cells passes their samples at different places.
    #[test]
    fn neighbouring_cells_are_offset_differently() {
        let n = 16.0;
        // Distance on the circle of positions within one column (or row) of the subdivision.
        let apart = |a: f64, b: f64| {
            let d = ((a * n).fract() - (b * n).fract()).abs();
            d.min(1.0 - d)
        };
        for k in 0..1000 {
            for other in [k + 1, k + 25] {
                let (a, b) = (cell_offset(k), cell_offset(other));
                for axis in 0..2 {
                    assert!(
                        apart(a[axis], b[axis]) > 0.02,
                        "cells {k} and {other}, axis {axis}: {a:?} {b:?}"
                    );
                }
            }
        }
    }
}
