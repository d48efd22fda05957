//! The tool transform: a wrench at the sensor's reference point, moved to another point (the
//! indenter tip) and expressed in another orientation.
//!
//! Convention (the same as the ATI software's "tool transform", written out here so there is
//! no doubt): the tool frame has its origin at `d` (mm, in sensor coordinates) and its axes are
//! the columns of `R` (a rotation, sensor ← tool). A wrench `(F, T)` measured at the sensor
//! origin is, at the tool origin and in tool axes,
//!
//! ```text
//! F_tool = Rᵀ F
//! T_tool = Rᵀ (T − d × F)
//! ```
//!
//! so the 6×6 matrix is `[[Rᵀ, 0], [−Rᵀ [d]×, Rᵀ]]`; the torque rows pick up `d × F`. Angles
//! `(rx, ry, rz)` are fixed-axis rotations applied about x, then y, then z: `R = Rz Ry Rx`.
//!
//! A proper rotation makes this matrix invertible, so a transform goes wrong in two ways, both
//! detected by [`ToolTransform::from_matrix`]: a "rotation" that is not one (a typo in a matrix,
//! determinant near 0: near-singular), and a displacement so large that the torque rows swamp
//! the forces (condition number above [`MAX_TOOL_CONDITION`]).

use nalgebra::{Matrix3, Matrix6, Rotation3, Vector3, Vector6};

/// Largest accepted condition number of the 6×6 tool transform. Its condition number grows
/// roughly like `|d|²` in mm; 1e6 allows a 1 m lever arm, far beyond any indenter.
pub const MAX_TOOL_CONDITION: f64 = 1e6;
/// A 3×3 "rotation" whose |determinant| is below this is near-singular.
pub const MIN_ROTATION_DET: f64 = 1e-3;
/// Largest accepted deviation of `RᵀR` from the identity (max abs element).
pub const MAX_ORTHONORMALITY_ERROR: f64 = 1e-4;

/// Why a tool transform was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TransformError {
    #[error(
        "tool transform is near-singular: its rotation has determinant {det:.3e}; give a proper rotation (angles, or an orthonormal matrix)"
    )]
    NearSingular { det: f64 },
    #[error(
        "tool transform rotation is not orthonormal (max |RᵀR − I| = {error:.3e}, det {det:.4}); check the matrix rows"
    )]
    NotRotation { error: f64, det: f64 },
    #[error(
        "tool transform is ill-conditioned: condition number {condition:.3e} exceeds {limit:.0e} (displacement {d_mm:?} mm); check the units (mm)"
    )]
    IllConditioned {
        condition: f64,
        limit: f64,
        d_mm: [f64; 3],
    },
    #[error("tool transform has a non-finite value")]
    NotFinite,
}

/// A checked tool transform. See the module docs for the convention.
#[derive(Debug, Clone, PartialEq)]
pub struct ToolTransform {
    rotation: Matrix3<f64>,
    d_mm: Vector3<f64>,
    matrix: Matrix6<f64>,
    inverse: Matrix6<f64>,
    condition: f64,
}

impl Default for ToolTransform {
    fn default() -> Self {
        Self::identity()
    }
}

impl ToolTransform {
    /// No displacement, no rotation.
    pub fn identity() -> Self {
        Self {
            rotation: Matrix3::identity(),
            d_mm: Vector3::zeros(),
            matrix: Matrix6::identity(),
            inverse: Matrix6::identity(),
            condition: 1.0,
        }
    }

    /// From a displacement (mm) and fixed-axis angles `(rx, ry, rz)` in radians.
    pub fn from_angles(d_mm: [f64; 3], r_rad: [f64; 3]) -> Result<Self, TransformError> {
        if d_mm.iter().chain(&r_rad).any(|v| !v.is_finite()) {
            return Err(TransformError::NotFinite);
        }
        let r = Rotation3::from_axis_angle(&Vector3::z_axis(), r_rad[2])
            * Rotation3::from_axis_angle(&Vector3::y_axis(), r_rad[1])
            * Rotation3::from_axis_angle(&Vector3::x_axis(), r_rad[0]);
        Self::from_matrix(*r.matrix(), d_mm)
    }

    /// From a displacement (mm) and a rotation matrix (sensor ← tool), checked.
    pub fn from_matrix(rotation: Matrix3<f64>, d_mm: [f64; 3]) -> Result<Self, TransformError> {
        if rotation.iter().chain(&d_mm).any(|v| !v.is_finite()) {
            return Err(TransformError::NotFinite);
        }
        let det = rotation.determinant();
        if det.abs() < MIN_ROTATION_DET {
            return Err(TransformError::NearSingular { det });
        }
        let ortho = (rotation.transpose() * rotation - Matrix3::identity())
            .abs()
            .max();
        if ortho > MAX_ORTHONORMALITY_ERROR || det < 0.0 {
            return Err(TransformError::NotRotation { error: ortho, det });
        }
        let d = Vector3::from(d_mm);
        let rt = rotation.transpose();
        let mut m = Matrix6::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&rt);
        m.fixed_view_mut::<3, 3>(3, 3).copy_from(&rt);
        m.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(-rt * d.cross_matrix()));
        let condition = condition_number(&m);
        if condition.is_nan() || condition > MAX_TOOL_CONDITION {
            return Err(TransformError::IllConditioned {
                condition,
                limit: MAX_TOOL_CONDITION,
                d_mm,
            });
        }
        // Exact inverse: F = R F_tool, T = R T_tool + d × F.
        let mut inv = Matrix6::zeros();
        inv.fixed_view_mut::<3, 3>(0, 0).copy_from(&rotation);
        inv.fixed_view_mut::<3, 3>(3, 3).copy_from(&rotation);
        inv.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&(d.cross_matrix() * rotation));
        Ok(Self {
            rotation,
            d_mm: d,
            matrix: m,
            inverse: inv,
            condition,
        })
    }

    /// The 6×6 matrix (tool ← sensor).
    pub fn matrix(&self) -> &Matrix6<f64> {
        &self.matrix
    }

    /// The displacement of the tool origin, mm (sensor coordinates).
    pub fn displacement_mm(&self) -> [f64; 3] {
        self.d_mm.into()
    }

    /// The rotation, sensor ← tool.
    pub fn rotation(&self) -> &Matrix3<f64> {
        &self.rotation
    }

    /// 2-norm condition number of [`Self::matrix`].
    pub fn condition_number(&self) -> f64 {
        self.condition
    }

    /// Whether this is (numerically) the identity.
    pub fn is_identity(&self) -> bool {
        self.matrix == Matrix6::identity()
    }

    /// Sensor-frame wrench → tool-frame wrench.
    pub fn apply(&self, w: &[f64; 6]) -> [f64; 6] {
        if self.is_identity() {
            return *w;
        }
        (self.matrix * Vector6::from_column_slice(w)).into()
    }

    /// Tool-frame wrench → sensor-frame wrench (what the simulated sensor must feel).
    pub fn invert(&self, w: &[f64; 6]) -> [f64; 6] {
        if self.is_identity() {
            return *w;
        }
        (self.inverse * Vector6::from_column_slice(w)).into()
    }
}

/// 2-norm condition number (σ_max / σ_min) of a 6×6 matrix; infinity when singular.
pub fn condition_number(m: &Matrix6<f64>) -> f64 {
    let sv = m.singular_values();
    let max = sv.max();
    let min = sv.min();
    if min > 0.0 && max.is_finite() {
        max / min
    } else {
        f64::INFINITY
    }
}
