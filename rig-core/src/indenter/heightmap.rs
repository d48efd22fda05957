//! A sampled gap field of an indenter's contact face.

/// Gap of the contact face on a regular grid centred on the indenter axis.
///
/// `gap_mm[iy * nx + ix]` is the height of the indenter's contact face above its lowest point at
/// the cell centre `(x_mm(ix), y_mm(iy))`, in mm: 0 where the face reaches lowest, larger where
/// it is higher. [`f64::INFINITY`] marks "no material": the indenter has no downward surface above
/// that point, so the gel there can never be touched. No value is NaN.
///
/// Pressed `depth_mm` into the gel (tip at the undeformed surface = depth 0), the indenter overlaps
/// the undeformed gel by `max(0, depth_mm − gap)` at each cell: the input of contact models.
#[derive(Debug, Clone, PartialEq)]
pub struct Heightmap {
    /// Cell pitch (the same along x and y).
    pub resolution_mm: f64,
    /// Number of cells along x.
    pub nx: usize,
    /// Number of cells along y.
    pub ny: usize,
    /// Row-major gap values, `ny` rows of `nx`.
    pub gap_mm: Vec<f64>,
}

/// Largest grid [`Heightmap`] builds (cells), so a typo in a resolution cannot exhaust memory.
pub const MAX_CELLS: usize = 64 * 1024 * 1024;

/// A grid request that cannot be honoured.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    #[error("heightmap resolution {0} mm must be a finite number > 0")]
    Resolution(f64),
    #[error("heightmap extent [{0}, {1}] mm must be finite numbers > 0")]
    Extent(f64, f64),
    #[error(
        "heightmap of {nx} × {ny} cells is too large (at most {MAX_CELLS}); use a coarser resolution"
    )]
    TooLarge { nx: usize, ny: usize },
}

impl Heightmap {
    /// An all-"no material" grid of about `extent_mm` at `resolution_mm` (at least one cell per
    /// axis; the cell count is the extent divided by the resolution, rounded).
    pub fn empty(resolution_mm: f64, extent_mm: (f64, f64)) -> Result<Self, GridError> {
        if !(resolution_mm.is_finite() && resolution_mm > 0.0) {
            return Err(GridError::Resolution(resolution_mm));
        }
        let (ex, ey) = extent_mm;
        if !(ex.is_finite() && ex > 0.0 && ey.is_finite() && ey > 0.0) {
            return Err(GridError::Extent(ex, ey));
        }
        let cells = |e: f64| -> Option<usize> {
            let n = (e / resolution_mm).round().max(1.0);
            (n <= MAX_CELLS as f64).then_some(n as usize)
        };
        let too_large = GridError::TooLarge {
            nx: (ex / resolution_mm).round() as usize,
            ny: (ey / resolution_mm).round() as usize,
        };
        let (Some(nx), Some(ny)) = (cells(ex), cells(ey)) else {
            return Err(too_large);
        };
        if nx.saturating_mul(ny) > MAX_CELLS {
            return Err(too_large);
        }
        Ok(Self {
            resolution_mm,
            nx,
            ny,
            gap_mm: vec![f64::INFINITY; nx * ny],
        })
    }

    /// x of the centre of column `ix`, mm (the grid is symmetric about 0).
    pub fn x_mm(&self, ix: usize) -> f64 {
        (ix as f64 - (self.nx as f64 - 1.0) / 2.0) * self.resolution_mm
    }

    /// y of the centre of row `iy`, mm.
    pub fn y_mm(&self, iy: usize) -> f64 {
        (iy as f64 - (self.ny as f64 - 1.0) / 2.0) * self.resolution_mm
    }

    /// Gap at cell `(ix, iy)`; `None` outside the grid.
    pub fn get(&self, ix: usize, iy: usize) -> Option<f64> {
        (ix < self.nx && iy < self.ny).then(|| self.gap_mm[iy * self.nx + ix])
    }

    /// Number of cells with material (finite gap).
    pub fn material_cells(&self) -> usize {
        self.gap_mm.iter().filter(|g| g.is_finite()).count()
    }

    /// Smallest gap on the grid (`INFINITY` when no cell has material).
    pub fn min_gap_mm(&self) -> f64 {
        self.gap_mm.iter().copied().fold(f64::INFINITY, f64::min)
    }

    /// Largest finite gap on the grid (`None` when no cell has material).
    pub fn max_finite_gap_mm(&self) -> Option<f64> {
        self.gap_mm
            .iter()
            .copied()
            .filter(|g| g.is_finite())
            .reduce(f64::max)
    }

    /// Cells in contact at `depth_mm` of pressing: those whose gap is below the depth.
    pub fn contact_cells(&self, depth_mm: f64) -> usize {
        self.gap_mm.iter().filter(|&&g| g < depth_mm).count()
    }
}
