//! Contact mechanics (skeleton; being written).

/// Which contact model a scene uses.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum ContactModel {
    #[default]
    Hertz,
}

/// Tangential behaviour.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum FrictionModel {
    /// No tangential traction.
    #[default]
    None,
}

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
