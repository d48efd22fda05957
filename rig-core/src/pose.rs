//! UR pose maths: `p[x, y, z, rx, ry, rz]` with the rotation as an axis × angle vector.
//!
//! A UR pose is a position in metres and a *rotation vector*: the unit rotation axis scaled by the
//! rotation angle in radians. This module converts rotation vectors to and from rotation
//! matrices, unit quaternions and [`Isometry3`], and reproduces the URScript pose functions.
//!
//! # URScript semantics
//!
//! The URScript manual (Universal Robots, *Script Manual*, e-Series; `pose_trans`, `pose_add`,
//! `pose_inv`/`inv` entries) defines:
//!
//! - `pose_trans(p_from, p_from_to)`: "starting at the coordinate system of `p_from`, and then in
//!   that coordinate system moving `p_from_to`", i.e. `T_world→to = T_world→from · T_from→to`.
//! - `pose_add(p_1, p_2)`: "p_3.P = p_1.P + p_2.P, p_3.R = p_1.R * p_2.R": the positions are
//!   added in the base frame and the rotation matrices multiplied in the order written. (The
//!   manual's own example, two rotations about `x`, cannot tell the orders apart; we follow the
//!   formula as written.)
//! - `pose_inv(p)`: the inverse transform.
//!
//! # Numerics
//!
//! Rotation vectors are singular in two places, and this module treats both explicitly:
//!
//! - **Near angle 0** the factors `sin θ / θ`, `(1 − cos θ) / θ²` and `θ / sin θ` are 0/0 at
//!   θ = 0 and `1 − cos θ` cancels catastrophically just above it; below a small threshold they
//!   are replaced by their Taylor series (above it `1 − cos θ` is computed as `2 sin²(θ/2)`), so
//!   that angles of `0` and `1e-12` convert exactly to machine precision.
//! - **Near angle π** the antisymmetric part of the rotation matrix, `sin θ · [k]ₓ`, vanishes and
//!   no longer determines the axis. There the axis is recovered from the symmetric part,
//!   `(R + Rᵀ)/2 = cos θ · I + (1 − cos θ) · k kᵀ` (which at θ = π is `(R + I)/2 = k kᵀ`), from
//!   its column with the largest diagonal entry, and the small antisymmetric part is used only to
//!   pick the sign of the axis. Angles are always computed with `atan2(sin θ, cos θ)`, never with
//!   `acos`, whose derivative is infinite at both ends.
//!
//! # Comparing poses
//!
//! Compare poses by [`translation_distance`] and [`rotation_distance`], never component by
//! component. A downward-pointing tool sits near angle π, where `k · π` and `−k · π` are the
//! same rotation: a tiny change in orientation can flip every sign of `(rx, ry, rz)`. UR also
//! reports rotation vectors whose norm is slightly above π (an angle of `π + ε` about `k` is the
//! rotation `π − ε` about `−k`), and any multiple of 2π may be added to the norm without changing
//! the rotation. Two rotation vectors whose difference has a norm of up to 2π can therefore
//! describe the same orientation; only the angle of `R_aᵀ R_b` is meaningful.
//! [`rotation_to_rotvec`] always returns the representative with angle in `[0, π]` (up to one
//! rounding of the norm), and so do the pose functions below; they may thus return a rotation
//! vector that differs component-wise from the one the controller prints for the same pose.

use nalgebra::{Isometry3, Matrix3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// Below this angle (radians) the Rodrigues / half-angle factors use their Taylor series.
///
/// At 1e-3 the first omitted terms are below θ⁶/5040 ≈ 2e-22, far under machine epsilon.
const SERIES_ANGLE: f64 = 1e-3;

/// A TCP pose as UR reports it: position in metres, rotation vector (axis × angle) in radians.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub struct Pose {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub rx: f64,
    pub ry: f64,
    pub rz: f64,
}

impl Pose {
    pub const fn new(x: f64, y: f64, z: f64, rx: f64, ry: f64, rz: f64) -> Self {
        Self {
            x,
            y,
            z,
            rx,
            ry,
            rz,
        }
    }
    pub const fn from_array(a: [f64; 6]) -> Self {
        Self::new(a[0], a[1], a[2], a[3], a[4], a[5])
    }
    pub const fn to_array(&self) -> [f64; 6] {
        [self.x, self.y, self.z, self.rx, self.ry, self.rz]
    }
    /// The identity pose `p[0, 0, 0, 0, 0, 0]`.
    pub const fn identity() -> Self {
        Self::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    }
    /// A pose from a position and a rotation vector.
    pub fn from_parts(position: &Vector3<f64>, rotvec: &Vector3<f64>) -> Self {
        Self::new(
            position.x, position.y, position.z, rotvec.x, rotvec.y, rotvec.z,
        )
    }
    pub fn position(&self) -> Vector3<f64> {
        Vector3::new(self.x, self.y, self.z)
    }
    pub fn rotvec(&self) -> Vector3<f64> {
        Vector3::new(self.rx, self.ry, self.rz)
    }
    pub fn rotation(&self) -> Rotation3<f64> {
        rotvec_to_rotation(&self.rotvec())
    }
    /// The orientation as a unit quaternion (computed directly from the rotation vector).
    pub fn quaternion(&self) -> UnitQuaternion<f64> {
        rotvec_to_quaternion(&self.rotvec())
    }
    pub fn to_isometry(&self) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(self.x, self.y, self.z), self.quaternion())
    }
    /// The pose of an isometry; the rotation vector has angle in `[0, π]`.
    pub fn from_isometry(iso: &Isometry3<f64>) -> Self {
        Self::from_parts(
            &iso.translation.vector,
            &quaternion_to_rotvec(&iso.rotation),
        )
    }
    /// The same pose with its rotation vector brought to angle `[0, π]`.
    pub fn canonical(&self) -> Self {
        Self::from_parts(&self.position(), &rotation_to_rotvec(&self.rotation()))
    }
}

/// `sin θ / θ` and `(1 − cos θ) / θ²`, with Taylor series near θ = 0.
fn rodrigues_factors(theta: f64) -> (f64, f64) {
    let t2 = theta * theta;
    if theta < SERIES_ANGLE {
        // sin θ/θ = 1 − θ²/6 + θ⁴/120 − …; (1 − cos θ)/θ² = 1/2 − θ²/24 + θ⁴/720 − …
        (
            1.0 - t2 / 6.0 * (1.0 - t2 / 20.0),
            0.5 - t2 / 24.0 * (1.0 - t2 / 30.0),
        )
    } else {
        // 1 − cos θ = 2 sin²(θ/2) avoids cancellation.
        let h = (0.5 * theta).sin();
        (theta.sin() / theta, 2.0 * h * h / t2)
    }
}

fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `vee((M − Mᵀ)/2)`: for a rotation matrix, `sin θ · k`.
fn antisym_vee(m: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(
        m[(2, 1)] - m[(1, 2)],
        m[(0, 2)] - m[(2, 0)],
        m[(1, 0)] - m[(0, 1)],
    ) * 0.5
}

/// Angle in `[0, π]` of a rotation matrix, via `atan2(|sin θ|, cos θ)`.
fn rotation_angle(m: &Matrix3<f64>) -> f64 {
    let s = antisym_vee(m).norm();
    let c = (m.trace() - 1.0) * 0.5;
    s.atan2(c)
}

/// Rotation matrix of a rotation vector (any norm, including 0 and above π).
pub fn rotvec_to_rotation(v: &Vector3<f64>) -> Rotation3<f64> {
    let (a, b) = rodrigues_factors(v.norm());
    let k = hat(v);
    // R = I + (sin θ/θ)[v]ₓ + ((1 − cos θ)/θ²)[v]ₓ²
    Rotation3::from_matrix_unchecked(Matrix3::identity() + k * a + k * k * b)
}

/// Rotation vector of a rotation matrix, with angle in [0, π]; robust near 0 and π.
pub fn rotation_to_rotvec(r: &Rotation3<f64>) -> Vector3<f64> {
    let m = r.matrix();
    let w = antisym_vee(m); // sin θ · k
    let s = w.norm();
    let c = (m.trace() - 1.0) * 0.5; // cos θ
    let theta = s.atan2(c);
    if c >= 0.0 {
        // θ ≤ π/2: the antisymmetric part determines the axis well (error ≈ ε / sin θ).
        let factor = if theta < SERIES_ANGLE {
            // θ / sin θ = 1 + θ²/6 + 7θ⁴/360 + …
            let t2 = theta * theta;
            1.0 + t2 / 6.0 * (1.0 + 7.0 * t2 / 60.0)
        } else {
            theta / s
        };
        return w * factor;
    }
    // θ > π/2: k kᵀ = ((R + Rᵀ)/2 − cos θ · I) / (1 − cos θ), with 1 − cos θ in (1, 2].
    let sym = (m + m.transpose()) * 0.5;
    let kkt = (sym - Matrix3::identity() * c) / (1.0 - c);
    let mut j = 0;
    for i in 1..3 {
        if kkt[(i, i)] > kkt[(j, j)] {
            j = i;
        }
    }
    // Column j is k_j · k with k_j² ≥ 1/3, so its norm is at least 1/√3.
    let col = kkt.column(j).into_owned();
    let mut k = col / col.norm();
    // The sign: sin θ · k = w. At θ = π exactly, w is rounding noise and either sign is right.
    if k.dot(&w) < 0.0 {
        k = -k;
    }
    k * theta
}

/// Unit quaternion of a rotation vector (any norm), with a series for `sin(θ/2)/θ` near 0.
pub fn rotvec_to_quaternion(v: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta = v.norm();
    let half_sinc = if theta < SERIES_ANGLE {
        // sin(θ/2)/θ = 1/2 − θ²/48 + θ⁴/3840 − …
        let t2 = theta * theta;
        0.5 - t2 / 48.0 * (1.0 - t2 / 80.0)
    } else {
        (0.5 * theta).sin() / theta
    };
    let q = Quaternion::new(
        (0.5 * theta).cos(),
        v.x * half_sinc,
        v.y * half_sinc,
        v.z * half_sinc,
    );
    // Unit to rounding already; renormalise so nalgebra's invariant holds exactly.
    UnitQuaternion::from_quaternion(q)
}

/// Rotation vector (angle in `[0, π]`) of a unit quaternion.
///
/// `θ = 2·atan2(|q_v|, |q_w|)` is well conditioned everywhere, including near π where `q_w → 0`
/// and the axis is simply `q_v / |q_v|`.
pub fn quaternion_to_rotvec(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (mut w, mut v) = (q.w, q.imag());
    if w < 0.0 {
        // q and −q are the same rotation; w ≥ 0 selects the angle in [0, π].
        w = -w;
        v = -v;
    }
    let n = v.norm();
    let factor = if n < SERIES_ANGLE {
        // 2·atan(n/w)/n = (2/w)(1 − (n/w)²/3 + (n/w)⁴/5 − …), w ≈ 1 here.
        let r2 = (n / w) * (n / w);
        2.0 / w * (1.0 - r2 / 3.0 * (1.0 - 0.6 * r2))
    } else {
        2.0 * n.atan2(w) / n
    };
    v * factor
}

/// URScript `pose_trans(p_from, p_from_to)`: `p_from_to` expressed in the frame `p_from`.
pub fn pose_trans(p_from: &Pose, p_from_to: &Pose) -> Pose {
    Pose::from_isometry(&(p_from.to_isometry() * p_from_to.to_isometry()))
}

/// URScript `pose_add(p_1, p_2)`: positions added, rotations composed as `R_1 · R_2`.
pub fn pose_add(p1: &Pose, p2: &Pose) -> Pose {
    let q = p1.quaternion() * p2.quaternion();
    Pose::from_parts(&(p1.position() + p2.position()), &quaternion_to_rotvec(&q))
}

/// URScript `pose_inv(p)`.
pub fn pose_inv(p: &Pose) -> Pose {
    Pose::from_isometry(&p.to_isometry().inverse())
}

/// Straight-line position interpolation and slerp of the rotation, `s` in [0, 1].
///
/// The rotation follows the shortest arc, `R_a · exp(s · log(R_aᵀ R_b))`. When the two
/// orientations are exactly π apart the shortest arc is not unique and one of them is taken;
/// the result is always finite.
pub fn interpolate(a: &Pose, b: &Pose, s: f64) -> Pose {
    let qa = a.quaternion();
    let rel = qa.inverse() * b.quaternion();
    let step = rotvec_to_quaternion(&(quaternion_to_rotvec(&rel) * s));
    let position = a.position() + (b.position() - a.position()) * s;
    Pose::from_parts(&position, &quaternion_to_rotvec(&(qa * step)))
}

/// Angle in [0, π] of the rotation taking `a`'s orientation to `b`'s.
pub fn rotation_distance(a: &Pose, b: &Pose) -> f64 {
    let m = a.rotation().transpose() * b.rotation();
    rotation_angle(m.matrix())
}

/// Euclidean distance between the positions, in metres.
pub fn translation_distance(a: &Pose, b: &Pose) -> f64 {
    (a.position() - b.position()).norm()
}

/// `(translation_distance, rotation_distance)`: metres and radians.
pub fn pose_dist(a: &Pose, b: &Pose) -> (f64, f64) {
    (translation_distance(a, b), rotation_distance(a, b))
}

/// Whether two poses are within `pos_tol` metres and `rot_tol` radians of each other.
pub fn poses_close(a: &Pose, b: &Pose, pos_tol: f64, rot_tol: f64) -> bool {
    let (dp, dr) = pose_dist(a, b);
    dp <= pos_tol && dr <= rot_tol
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The Taylor branches agree with the closed forms on both sides of the switch-over, so the
    /// functions are continuous to machine precision there.
    #[test]
    fn series_match_closed_forms_at_the_threshold() {
        for &t in &[
            SERIES_ANGLE * 0.999_999,
            SERIES_ANGLE,
            SERIES_ANGLE * 1.000_001,
            1e-4,
        ] {
            let (a, b) = rodrigues_factors(t);
            assert!((a - t.sin() / t).abs() < 4.0 * f64::EPSILON, "{t}");
            // The naive closed form loses ~ε/θ² to cancellation; that is why it is not used.
            let naive_err = f64::EPSILON / (t * t);
            assert!((b - (1.0 - t.cos()) / (t * t)).abs() < naive_err, "{t}");
            let h = (0.5 * t).sin();
            assert!(
                (b - 2.0 * h * h / (t * t)).abs() < 2.0 * f64::EPSILON,
                "{t}"
            );
            let q = rotvec_to_quaternion(&Vector3::new(t, 0.0, 0.0));
            let rel = 4.0 * f64::EPSILON;
            assert!((q.i / (0.5 * t).sin() - 1.0).abs() < rel, "{t}: {}", q.i);
            let v = quaternion_to_rotvec(&q);
            assert!((v.x / t - 1.0).abs() < rel, "{t}: {}", v.x);
        }
        assert_eq!(rodrigues_factors(0.0), (1.0, 0.5));
    }

    #[test]
    fn quaternion_path_near_pi_and_sign_of_w() {
        let v = Vector3::new(0.0, 0.0, std::f64::consts::PI - 1e-12);
        let back = quaternion_to_rotvec(&rotvec_to_quaternion(&v));
        assert!((back - v).norm() < 1e-15);
        // −q is the same rotation and must give the same rotation vector.
        let q = rotvec_to_quaternion(&Vector3::new(0.3, -0.2, 0.1));
        let neg = UnitQuaternion::new_unchecked(-q.into_inner());
        assert!((quaternion_to_rotvec(&neg) - quaternion_to_rotvec(&q)).norm() < 1e-16);
    }
}
