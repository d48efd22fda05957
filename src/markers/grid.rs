//! The displacement field on a fixed grid in millimetres, whatever the marker pitch.

use super::TrackedMarker;

/// Most cells a grid may have (a typo must not allocate gigabytes).
pub const MAX_GRID_CELLS: usize = 1 << 20;

/// A cell is "covered" when its markers' total Gaussian weight reaches this: the weight of one
/// marker 1.5 σ away (`exp(−1.5²/2)`). Cells below it hold zero.
pub const MIN_WEIGHT: f64 = 0.324_652_467_358_349_9;

/// A grid of cells in sensor millimetres, centred on the image centre: `ny` rows of `nx`
/// cells, `spacing_mm` apart, row 0 at the top (`+y`), column 0 at the left (`−x`). Cell
/// `(i, j)` is at `x = (i − (nx − 1)/2) · spacing`, `y = ((ny − 1)/2 − j) · spacing`.
///
/// The field in a cell is the normalised Gaussian-weighted mean of the tracked markers'
/// displacements around it, `Σ wₖ dₖ / Σ wₖ` with `wₖ = exp(−|xₖ − c|² / 2σ²)` at the markers'
/// reference positions `xₖ`, and zero where `Σ wₖ` < [`MIN_WEIGHT`].
///
/// # The default: 16 × 12 cells at 0.5 mm, σ = 1 mm
///
/// - **σ is the same for every sensor**, not each sensor's own pitch: a kernel that grew with
///   the pitch would smooth a coarse lattice's field more than a fine one's, which is the very
///   pitch dependence this grid exists to remove. 1 mm is about the pitch of the sensors in use
///   (0.8–1.2 mm): at least 0.8 × the pitch, so a cell always averages several markers (the
///   normalised mean then shows no trace of where the lattice's dots fall), and small enough to
///   keep a contact's field (a sphere's stick zone is 1–3 mm across) from being flattened.
/// - **The extent, 8 × 6 mm** (cell centres within ±3.75 mm in x, ±2.75 mm in y), is what every
///   such sensor covers with markers on a 10 × 7.5 mm field of view: the outermost dots a
///   detector keeps (whole dots, clear of the border) lie within `pitch + dot radius` ≤ 1.3 mm
///   of each image edge for a pitch up to 1.1 mm (1.4 mm at 1.2 mm), i.e. out to at least ±3.6
///   mm and ±2.35 mm; a cell up to 0.67 σ beyond the last row of markers still has the weight of
///   a quarter of a full lattice (a corner cell, beyond two edges, over twice [`MIN_WEIGHT`]),
///   so all 192 cells are covered on both a 0.9 mm and a 1.1–1.2 mm sensor, turned by a few
///   degrees or not (`tests/it/markers.rs` checks every cell on 0.8, 0.9 and 1.1 mm sensors).
/// - **0.5 mm cells** sample a field smoothed by σ = 1 mm at twice its Nyquist rate; finer cells
///   would add numbers, not information.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSpec {
    /// Cells along x (columns).
    pub nx: usize,
    /// Cells along y (rows).
    pub ny: usize,
    /// Distance between cell centres, mm.
    pub spacing_mm: f64,
    /// Width of the Gaussian weight, mm.
    pub sigma_mm: f64,
}

impl Default for GridSpec {
    fn default() -> Self {
        Self {
            nx: 16,
            ny: 12,
            spacing_mm: 0.5,
            sigma_mm: 1.0,
        }
    }
}

impl GridSpec {
    /// Number of cells, `nx · ny`.
    pub fn len(&self) -> usize {
        self.nx.saturating_mul(self.ny)
    }

    /// Whether the grid has no cells.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Centre of cell `(i, j)` (column, row), sensor mm.
    pub fn cell_mm(&self, i: usize, j: usize) -> [f64; 2] {
        [
            (i as f64 - (self.nx as f64 - 1.0) / 2.0) * self.spacing_mm,
            ((self.ny as f64 - 1.0) / 2.0 - j as f64) * self.spacing_mm,
        ]
    }

    /// Every value usable: 1 to [`MAX_GRID_CELLS`] cells, finite positive spacing and σ.
    pub fn check(&self) -> Result<(), String> {
        if self.is_empty() || self.len() > MAX_GRID_CELLS {
            return Err(format!(
                "grid of {} × {} cells: it must have 1 to {MAX_GRID_CELLS} cells",
                self.nx, self.ny
            ));
        }
        for (name, v) in [("spacing_mm", self.spacing_mm), ("sigma_mm", self.sigma_mm)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("grid {name} = {v:?} must be a finite number > 0"));
            }
        }
        Ok(())
    }
}

/// The displacement field of the markers that are tracked in the current frame (lost ones are
/// left out: their displacement is stale) on `spec`'s grid: `ny` rows of `nx` `[dx, dy]`, mm,
/// sensor axes (see [`GridSpec`]). The markers' reference positions are taken as they are, so
/// the grid is centred on the image centre; shift them (say by
/// [`SensorGeometry::gel_centre_mm`](super::SensorGeometry::gel_centre_mm)) and call
/// [`resample_points`] to centre it elsewhere.
///
/// An unusable `spec` ([`GridSpec::check`]) gives all zeros (none when it has too many cells).
pub fn resample(markers: &[TrackedMarker], spec: &GridSpec) -> Vec<[f32; 2]> {
    let (points, disp): (Vec<[f64; 2]>, Vec<[f64; 2]>) = markers
        .iter()
        .filter(|m| !m.lost)
        .map(|m| (m.reference_mm, m.displacement_mm))
        .unzip();
    resample_points(&points, &disp, spec)
}

/// [`resample`] for any scattered displacements: `displacements_mm[k]` at `points_mm[k]` (sensor
/// mm; pairs with a non-finite value, and any beyond the shorter list, are ignored).
pub fn resample_points(
    points_mm: &[[f64; 2]],
    displacements_mm: &[[f64; 2]],
    spec: &GridSpec,
) -> Vec<[f32; 2]> {
    if spec.len() > MAX_GRID_CELLS {
        return Vec::new();
    }
    let mut out = vec![[0f32; 2]; spec.len()];
    if spec.check().is_err() {
        return out;
    }
    let samples: Vec<([f64; 2], [f64; 2])> = points_mm
        .iter()
        .zip(displacements_mm)
        .filter(|(p, d)| p.iter().chain(d.iter()).all(|v| v.is_finite()))
        .map(|(p, d)| (*p, *d))
        .collect();
    let inv = 1.0 / (2.0 * spec.sigma_mm * spec.sigma_mm);
    // Beyond 3.5 σ a marker's weight (< 0.0022) is below what the sums can notice.
    let reach2 = (3.5 * spec.sigma_mm).powi(2);
    for j in 0..spec.ny {
        for i in 0..spec.nx {
            let c = spec.cell_mm(i, j);
            let (mut sw, mut sx, mut sy) = (0f64, 0f64, 0f64);
            for (p, d) in &samples {
                let r2 = (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2);
                if r2 < reach2 {
                    let w = (-r2 * inv).exp();
                    sw += w;
                    sx += w * d[0];
                    sy += w * d[1];
                }
            }
            if sw >= MIN_WEIGHT {
                out[j * spec.nx + i] = [(sx / sw) as f32, (sy / sw) as f32];
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A square lattice of `pitch` over `[-hx, hx] × [-hy, hy]`.
    fn lattice(pitch: f64, hx: f64, hy: f64) -> Vec<[f64; 2]> {
        let (nx, ny) = ((hx / pitch) as i64, (hy / pitch) as i64);
        (-ny..=ny)
            .flat_map(|j| (-nx..=nx).map(move |i| [i as f64 * pitch, j as f64 * pitch]))
            .collect()
    }

    #[test]
    fn the_weight_floor_is_one_marker_at_one_and_a_half_sigma() {
        assert!((MIN_WEIGHT - (-1.125f64).exp()).abs() < 1e-15);
    }

    #[test]
    fn a_uniform_displacement_comes_back_everywhere_covered() {
        let spec = GridSpec::default();
        for pitch in [0.8, 0.9, 1.1, 1.2] {
            let points = lattice(pitch, 4.6, 3.4);
            let disp = vec![[0.123, -0.045]; points.len()];
            let grid = resample_points(&points, &disp, &spec);
            assert_eq!(grid.len(), 16 * 12);
            for v in &grid {
                assert!(
                    (v[0] - 0.123).abs() < 1e-6 && (v[1] + 0.045).abs() < 1e-6,
                    "pitch {pitch}: {v:?}"
                );
            }
        }
    }

    #[test]
    fn cells_without_markers_in_reach_are_zero() {
        let spec = GridSpec::default();
        // Markers only on the left half (x < −0.5 mm).
        let points: Vec<[f64; 2]> = lattice(0.9, 4.6, 3.4)
            .into_iter()
            .filter(|p| p[0] < -0.5)
            .collect();
        let disp = vec![[0.2, 0.1]; points.len()];
        let grid = resample_points(&points, &disp, &spec);
        for j in 0..spec.ny {
            for i in 0..spec.nx {
                let x = spec.cell_mm(i, j)[0];
                let v = grid[j * spec.nx + i];
                // The last column of markers is at x = −0.9. A column of pitch p at dx weighs
                // about √(2π)·σ/p · exp(−dx²/2σ²): under MIN_WEIGHT beyond dx ≈ 2.1 σ (the
                // columns behind it add under 10 %). Zero beyond 2.5 σ; the value within 1 σ.
                if x > -0.9 + 2.5 {
                    assert_eq!(v, [0.0, 0.0], "cell at x = {x}");
                } else if x < -0.9 + 1.0 {
                    assert!((v[0] - 0.2).abs() < 1e-6 && (v[1] - 0.1).abs() < 1e-6);
                }
            }
        }
        // No markers: all zero.
        assert!(
            resample_points(&[], &[], &spec)
                .iter()
                .all(|v| *v == [0.0, 0.0])
        );
    }

    #[test]
    fn bad_specs_and_values_do_not_panic() {
        let points = lattice(0.9, 4.6, 3.4);
        let disp = vec![[0.1, 0.1]; points.len()];
        for spec in [
            GridSpec {
                nx: 0,
                ..GridSpec::default()
            },
            GridSpec {
                spacing_mm: f64::NAN,
                ..GridSpec::default()
            },
            GridSpec {
                sigma_mm: 0.0,
                ..GridSpec::default()
            },
        ] {
            assert!(spec.check().is_err());
            let g = resample_points(&points, &disp, &spec);
            assert_eq!(g.len(), spec.len());
            assert!(g.iter().all(|v| *v == [0.0, 0.0]));
        }
        let huge = GridSpec {
            nx: usize::MAX,
            ny: 3,
            ..GridSpec::default()
        };
        assert!(huge.check().is_err());
        assert!(resample_points(&points, &disp, &huge).is_empty());
        // A non-finite sample is ignored, the rest used.
        let mut bad = disp.clone();
        bad[0] = [f64::NAN, 0.0];
        let g = resample_points(&points, &bad, &GridSpec::default());
        assert!(g.iter().all(|v| (v[0] - 0.1).abs() < 1e-6));
    }
}
