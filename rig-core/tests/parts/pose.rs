//! Integration tests of `rig_core::pose`.
//!
//! Tolerances: conversions are compared by the angle of `R_aᵀ R_b` ([`rotation_distance`]), with
//! `ROT_TOL = 1e-12` rad. The arithmetic itself is accurate to a few ulps (~1e-15 rad); the margin
//! covers rotation vectors of norm up to 4π, whose Rodrigues terms are ~10× larger. Values quoted
//! from the URScript manual are printed to 5 decimals (rotations of 3.14 to 2), so they are
//! compared to 1e-5 m / 1e-5 rad, or to the printed precision.

// The manual's examples use 1.57 and 3.14 for π/2 and π; they are kept as printed.
#![allow(clippy::approx_constant)]

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use nalgebra::{Rotation3, Unit, UnitQuaternion, Vector3};
use proptest::prelude::*;
use rig_core::pose::{
    Pose, interpolate, pose_add, pose_dist, pose_inv, pose_trans, rotation_distance,
    rotation_to_rotvec, rotvec_to_rotation, translation_distance,
};

const ROT_TOL: f64 = 1e-12;

/// π up to the rounding of `|k · θ|` (a unit axis has norm 1 ± 1 ulp).
const PI_ROUNDED: f64 = PI * (1.0 + 4.0 * f64::EPSILON);

/// Angle between two rotation matrices, computed independently of the code under test: through
/// nalgebra's quaternion of `aᵀb` and `2·atan2(|q_v|, |q_w|)`. (nalgebra's own `angle()` uses
/// `acos` and returns NaN or loses half the digits near 0.)
fn angle_between(a: &Rotation3<f64>, b: &Rotation3<f64>) -> f64 {
    let q = UnitQuaternion::from_rotation_matrix(&a.rotation_to(b));
    2.0 * q.imag().norm().atan2(q.w.abs())
}

fn rot_pose(v: Vector3<f64>) -> Pose {
    Pose::new(0.0, 0.0, 0.0, v.x, v.y, v.z)
}

/// Rotation about `axis` by `angle`, built by nalgebra (not by the code under test).
fn reference_rotation(axis: &Vector3<f64>, angle: f64) -> Rotation3<f64> {
    Rotation3::from_axis_angle(&Unit::new_normalize(*axis), angle)
}

fn axes() -> Vec<Vector3<f64>> {
    [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [1.0, 1.0, 1.0],
        [1.0, -2.0, 3.0],
        [-0.3, 0.8, -0.52],
        [0.001, -1.0, 0.002],
        [1.0, 1.0, 1e-9],
        [-5.0, 0.1, 0.2],
    ]
    .iter()
    .map(|a| Vector3::from_column_slice(a).normalize())
    .collect()
}

const ANGLES: [f64; 9] = [
    0.0,
    1e-12,
    1e-8,
    1e-3,
    FRAC_PI_2,
    PI - 1e-6,
    PI - 1e-9,
    PI - 1e-12,
    PI,
];

#[test]
fn rotvec_to_rotation_matches_axis_angle_reference() {
    for axis in axes() {
        for &angle in &ANGLES {
            let r = rotvec_to_rotation(&(axis * angle));
            let d = angle_between(&r, &reference_rotation(&axis, angle));
            assert!(d < ROT_TOL, "axis {axis:?} angle {angle}: {d}");
            // Entry-wise as well, which also checks orthonormality to rounding.
            let e = (r.matrix() - reference_rotation(&axis, angle).matrix()).amax();
            assert!(e < 1e-15, "axis {axis:?} angle {angle}: entry error {e}");
        }
    }
}

#[test]
fn zero_and_tiny_rotvecs_are_exact() {
    assert_eq!(rotvec_to_rotation(&Vector3::zeros()), Rotation3::identity());
    assert_eq!(rotation_to_rotvec(&Rotation3::identity()), Vector3::zeros());
    for axis in axes() {
        for &angle in &[1e-12, 1e-8, 1e-5] {
            let v = axis * angle;
            let back = rotation_to_rotvec(&rotvec_to_rotation(&v));
            // Relative error at machine precision, i.e. far below the angle itself.
            assert!(
                (back - v).norm() <= 4.0 * f64::EPSILON * angle,
                "{v:?} -> {back:?}"
            );
        }
    }
}

#[test]
fn rotvec_round_trip_over_angles_zero_to_pi() {
    for axis in axes() {
        for &angle in &ANGLES {
            let v = axis * angle;
            let r = rotvec_to_rotation(&v);
            let back = rotation_to_rotvec(&r);
            assert!(back.iter().all(|c| c.is_finite()));
            let d = angle_between(&r, &rotvec_to_rotation(&back));
            assert!(
                d < ROT_TOL,
                "axis {axis:?} angle {angle}: rotation distance {d}"
            );
            assert!(back.norm() <= PI_ROUNDED, "angle {} above π", back.norm());
            // Below π the rotation vector itself is unique and must come back, also at π − 1e-12
            // (the axis comes from the symmetric part there, only its sign from sin θ · k).
            if angle < PI {
                assert!(
                    (back - v).norm() < 1e-14,
                    "axis {axis:?} angle {angle}: {v:?} -> {back:?}"
                );
            } else {
                // At exactly π both signs of the axis are the same rotation.
                assert!(
                    (back - v).norm() < 1e-14 || (back + v).norm() < 1e-14,
                    "axis {axis:?}: {v:?} -> {back:?}"
                );
            }
        }
    }
}

#[test]
fn angle_near_pi_is_accurate_to_machine_precision() {
    for axis in axes() {
        for &delta in &[1e-6, 1e-9, 1e-12, 0.0] {
            let r = reference_rotation(&axis, PI - delta);
            let back = rotation_to_rotvec(&r);
            assert!(
                (back.norm() - (PI - delta)).abs() < 1e-15,
                "delta {delta}: angle {}",
                back.norm()
            );
            assert!(angle_between(&r, &rotvec_to_rotation(&back)) < ROT_TOL);
        }
    }
}

#[test]
fn norms_above_pi_map_to_the_equivalent_rotation() {
    // (norm, expected angle in [0, π], expected axis sign)
    let cases = [
        (PI + 0.1, PI - 0.1, -1.0),
        (1.5 * PI, 0.5 * PI, -1.0),
        (2.0 * PI - 0.1, 0.1, -1.0),
        (2.0 * PI, 0.0, 1.0),
        (2.0 * PI + 0.1, 0.1, 1.0),
        (3.0 * PI, PI, 1.0),
        (4.0 * PI - 0.2, 0.2, -1.0),
    ];
    for axis in axes() {
        for &(norm, angle, sign) in &cases {
            let r = rotvec_to_rotation(&(axis * norm));
            let d = angle_between(&r, &reference_rotation(&axis, norm));
            assert!(d < ROT_TOL, "norm {norm}: {d}");
            let back = rotation_to_rotvec(&r);
            assert!((back.norm() - angle).abs() < 1e-13, "norm {norm}: {back:?}");
            let expected = axis * (sign * angle);
            if angle == PI {
                assert!((back - expected).norm() < 1e-13 || (back + expected).norm() < 1e-13);
            } else {
                assert!((back - expected).norm() < 1e-13, "norm {norm}: {back:?}");
            }
        }
    }
}

#[test]
fn canonical_keeps_the_rotation() {
    let p = Pose::new(0.1, 0.2, 0.3, 0.0, PI + 0.05, 0.0);
    let c = p.canonical();
    assert!((c.ry + (PI - 0.05)).abs() < 1e-14, "{c:?}");
    assert!(rotation_distance(&p, &c) < ROT_TOL);
    assert_eq!(translation_distance(&p, &c), 0.0);
}

#[test]
fn isometry_round_trip() {
    let p = Pose::new(0.3, -0.2, 0.45, 2.2, -2.2, 0.1);
    let iso = p.to_isometry();
    assert!((iso.translation.vector - p.position()).norm() == 0.0);
    let r = iso.rotation.to_rotation_matrix();
    assert!(angle_between(&r, &p.rotation()) < ROT_TOL);
    let q = Pose::from_isometry(&iso);
    let (dp, dr) = pose_dist(&p, &q);
    assert!(dp == 0.0 && dr < ROT_TOL);
    // Below π the rotation vector is returned as given.
    assert!((q.rotvec() - p.rotvec()).norm() < 1e-14);
    // Identity.
    assert_eq!(
        Pose::from_isometry(&Pose::identity().to_isometry()),
        Pose::identity()
    );
}

/// URScript manual, `pose_trans` entry (Script Manual e-Series, e.g. SW 10.6):
/// `pose_trans(p[.2,.5,.1,1.57,0,0], p[.2,.5,.6,1.57,0,0])` returns
/// `p[0.4,-0.0996,0.60048,3.14,0.0,0.0]`.
#[test]
fn pose_trans_manual_example() {
    let got = pose_trans(
        &Pose::new(0.2, 0.5, 0.1, 1.57, 0.0, 0.0),
        &Pose::new(0.2, 0.5, 0.6, 1.57, 0.0, 0.0),
    );
    let ur = Pose::new(0.4, -0.0996, 0.60048, 3.14, 0.0, 0.0);
    // Printed to 5 decimals (0.600478 → 0.60048; −0.099602 → −0.0996).
    assert!(translation_distance(&got, &ur) < 1e-5, "{got:?}");
    assert!(rotation_distance(&got, &ur) < 1e-12, "{got:?}");
    assert!(
        (got.rx - 3.14).abs() < 1e-12 && got.ry == 0.0 && got.rz == 0.0,
        "{got:?}"
    );
}

/// URScript manual, `pose_add` entry (Script Manual e-Series, e.g. SW 10.6):
/// `pose_add(p[.2,.5,.1,1.57,0,0], p[.2,.5,.6,1.57,0,0])` returns `p[0.4,1.0,0.7,3.14,0,0]`.
#[test]
fn pose_add_manual_example() {
    let got = pose_add(
        &Pose::new(0.2, 0.5, 0.1, 1.57, 0.0, 0.0),
        &Pose::new(0.2, 0.5, 0.6, 1.57, 0.0, 0.0),
    );
    let ur = Pose::new(0.4, 1.0, 0.7, 3.14, 0.0, 0.0);
    assert!(translation_distance(&got, &ur) < 1e-15, "{got:?}");
    assert!(rotation_distance(&got, &ur) < 1e-12, "{got:?}");
}

/// URScript manual, `inv` entry (Script Manual e-Series SW 10.9, the pose inverse that
/// `pose_inv` computes): `inv(p[.2,.5,.1,1.57,0,3.14])` returns
/// `p[0.19324,0.41794,-0.29662,1.23993,0.0,2.47985]`. The input's rotation vector has norm
/// 3.51 > π; UR's answer has norm 2.77 = 2π − 3.51, the representative in [0, π].
#[test]
fn pose_inv_manual_example() {
    let got = pose_inv(&Pose::new(0.2, 0.5, 0.1, 1.57, 0.0, 3.14));
    let ur = Pose::new(0.19324, 0.41794, -0.29662, 1.23993, 0.0, 2.47985);
    for (g, u) in got.to_array().iter().zip(ur.to_array()) {
        assert!((g - u).abs() < 1e-5, "{got:?}");
    }
    assert!(rotation_distance(&got, &ur) < 1e-5);
}

/// Not from the manual: a UR forum thread ("Math behind Pose_inv & Pose_trans",
/// forum.universal-robots.com/t/39279) quotes a controller's result for
/// `pose_trans(pose_inv(display), tcp)` with display = p[0.53916, 0.25017, 0.33852, 0.72307,
/// -0.77053, -1.38234], tcp = p[0.45311, 0.30546, 0.47648, 4.071, -0.539, -2.517]:
/// p[-0.05104, 0.0677, 0.14934, 1.727, -0.221, -2.762]. The inputs are rounded (rotations to 3
/// decimals), hence the loose tolerances. UR's rotation vector has norm 3.265 > π; ours is the
/// equivalent one with norm 2π − 3.265 and every sign flipped, the same orientation: the case
/// for comparing by rotation distance.
#[test]
fn pose_trans_of_pose_inv_forum_example() {
    let display = Pose::new(0.53916, 0.25017, 0.33852, 0.72307, -0.77053, -1.38234);
    let tcp = Pose::new(0.45311, 0.30546, 0.47648, 4.071, -0.539, -2.517);
    let got = pose_trans(&pose_inv(&display), &tcp);
    let ur = Pose::new(-0.05104, 0.0677, 0.14934, 1.727, -0.221, -2.762);
    assert!(translation_distance(&got, &ur) < 1e-4, "{got:?}");
    assert!(rotation_distance(&got, &ur) < 1e-3, "{got:?}");
    // Component-wise the rotation vectors are nowhere near each other.
    assert!((got.rotvec() - ur.rotvec()).norm() > 6.0);
}

/// Hand-computed: pure translations add in `pose_trans` and `pose_add` alike.
#[test]
fn pure_translations() {
    let a = Pose::new(0.1, -0.2, 0.3, 0.0, 0.0, 0.0);
    let b = Pose::new(0.05, 0.4, -0.1, 0.0, 0.0, 0.0);
    let sum = Pose::new(0.15000000000000002, 0.2, 0.19999999999999998, 0.0, 0.0, 0.0);
    assert_eq!(pose_trans(&a, &b), sum);
    assert_eq!(pose_add(&a, &b), sum);
    assert_eq!(pose_inv(&a), Pose::new(-0.1, 0.2, -0.3, 0.0, 0.0, 0.0));
}

/// Hand-computed: a frame rotated 90° about z at (1, 0, 0). Moving (0.1, 0, 0) in that frame goes
/// along the base y axis: pose_trans gives (1, 0.1, 0). pose_add moves along base x instead:
/// (1.1, 0, 0). Rotating the frame by a further 90° about z gives 180° about z in both.
#[test]
fn quarter_turn_about_z() {
    let frame = Pose::new(1.0, 0.0, 0.0, 0.0, 0.0, FRAC_PI_2);
    let step = Pose::new(0.1, 0.0, 0.0, 0.0, 0.0, 0.0);
    let t = pose_trans(&frame, &step);
    assert!(translation_distance(&t, &Pose::new(1.0, 0.1, 0.0, 0.0, 0.0, 0.0)) < 1e-15);
    assert!(rotation_distance(&t, &frame) < ROT_TOL);
    let a = pose_add(&frame, &step);
    assert!(translation_distance(&a, &Pose::new(1.1, 0.0, 0.0, 0.0, 0.0, 0.0)) < 1e-15);
    assert!(rotation_distance(&a, &frame) < ROT_TOL);

    let turn = Pose::new(0.0, 0.0, 0.0, 0.0, 0.0, FRAC_PI_2);
    let half = Pose::new(1.0, 0.0, 0.0, 0.0, 0.0, PI);
    assert!(rotation_distance(&pose_trans(&frame, &turn), &half) < ROT_TOL);
    assert!(translation_distance(&pose_trans(&frame, &turn), &half) < 1e-15);
    assert!(rotation_distance(&pose_add(&frame, &turn), &half) < ROT_TOL);

    // The inverse of the frame: position −Rᵀ·(1, 0, 0) = (0, 1, 0), rotation −90° about z.
    let inv = pose_inv(&frame);
    assert!(translation_distance(&inv, &Pose::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)) < 1e-15);
    assert!((inv.rz + FRAC_PI_2).abs() < 1e-15 && inv.rx == 0.0 && inv.ry == 0.0);
}

/// pose_add applies the second rotation about the base axes (R₂·R₁): a tool pointing down
/// (π about x) turned by 90° about base z.
#[test]
fn pose_add_composes_rotations_as_the_manual_writes() {
    // URScript manual, pose_add: "p_3.P = p_1.P + p_2.P, p_3.R = p_1.R * p_2.R". The
    // positions are added in the base frame; the rotation is the same product pose_trans uses.
    let down = Pose::new(0.01, 0.0, 0.0, PI, 0.0, 0.0);
    let yaw = Pose::new(0.0, 0.02, 0.0, 0.0, 0.0, FRAC_PI_2);
    let got = pose_add(&down, &yaw);
    let expected =
        reference_rotation(&Vector3::x(), PI) * reference_rotation(&Vector3::z(), FRAC_PI_2);
    assert!(angle_between(&got.rotation(), &expected) < ROT_TOL);
    assert!((got.position() - Vector3::new(0.01, 0.02, 0.0)).norm() < 1e-15);
    // pose_trans gives the same rotation but moves along the rotated frame's axes: y flips.
    let tool = pose_trans(&down, &yaw);
    assert!(angle_between(&tool.rotation(), &expected) < ROT_TOL);
    assert!((tool.position() - Vector3::new(0.01, -0.02, 0.0)).norm() < 1e-15);
}

fn sample_poses() -> Vec<Pose> {
    vec![
        Pose::identity(),
        Pose::new(0.3, -0.2, 0.45, 0.0, 0.0, 0.0),
        Pose::new(0.3, -0.2, 0.45, PI, 0.0, 0.0),
        Pose::new(0.3, -0.2, 0.45, 2.2214, -2.2214, 0.0),
        Pose::new(-0.1, 0.5, 0.2, PI + 1e-7, 1e-8, -1e-8),
        Pose::new(0.0, 0.0, 0.1, 1e-12, -1e-12, 2e-12),
        Pose::new(0.2, 0.5, 0.1, 1.57, 0.0, 3.14),
        Pose::new(1.0, 2.0, 3.0, -4.0, 5.0, -6.0),
    ]
}

#[test]
fn inverse_composes_to_identity() {
    for p in sample_poses() {
        let inv = pose_inv(&p);
        for id in [pose_trans(&p, &inv), pose_trans(&inv, &p)] {
            let (dp, dr) = pose_dist(&id, &Pose::identity());
            assert!(dp < 1e-14 && dr < ROT_TOL, "{p:?}: {id:?}");
        }
        // Involution.
        let (dp, dr) = pose_dist(&pose_inv(&inv), &p);
        assert!(dp < 1e-14 && dr < ROT_TOL, "{p:?}");
    }
}

#[test]
fn interpolation_endpoints_and_midpoint_of_quarter_turn() {
    let a = Pose::new(0.0, 0.0, 0.2, 0.0, 0.0, 0.0);
    let b = Pose::new(0.1, -0.2, 0.4, 0.0, 0.0, FRAC_PI_2);
    let (dp, dr) = pose_dist(&interpolate(&a, &b, 0.0), &a);
    assert!(dp == 0.0 && dr < ROT_TOL);
    let (dp, dr) = pose_dist(&interpolate(&a, &b, 1.0), &b);
    assert!(dp < 1e-16 && dr < ROT_TOL);
    let mid = interpolate(&a, &b, 0.5);
    let expected = Pose::new(0.05, -0.1, 0.30000000000000004, 0.0, 0.0, FRAC_PI_4);
    let (dp, dr) = pose_dist(&mid, &expected);
    assert!(dp < 1e-16 && dr < ROT_TOL, "{mid:?}");
    assert!((mid.rz - FRAC_PI_4).abs() < 1e-15);

    // Same for a quarter turn about a tilted axis starting from a tool pointing down.
    let down = Pose::new(0.0, 0.0, 0.0, PI, 0.0, 0.0);
    let turned = pose_trans(&down, &Pose::new(0.0, 0.0, 0.0, 0.0, FRAC_PI_2, 0.0));
    let mid = interpolate(&down, &turned, 0.5);
    let expected = pose_trans(&down, &Pose::new(0.0, 0.0, 0.0, 0.0, FRAC_PI_4, 0.0));
    assert!(rotation_distance(&mid, &expected) < ROT_TOL);
    assert!((rotation_distance(&down, &mid) - FRAC_PI_4).abs() < 1e-14);
}

#[test]
fn interpolation_near_pi_apart_is_finite_and_geodesic() {
    let a = Pose::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &delta in &[1e-6, 1e-12, 0.0] {
        for axis in axes() {
            let b = rot_pose(axis * (PI - delta));
            for i in 0..=10 {
                let s = f64::from(i) / 10.0;
                let p = interpolate(&a, &b, s);
                assert!(p.to_array().iter().all(|c| c.is_finite()), "{p:?}");
                // Along the geodesic: distance from a is s times the total.
                let d = rotation_distance(&a, &p);
                assert!((d - s * (PI - delta)).abs() < 1e-12, "s {s}: {d}");
            }
        }
    }
    // Two downward tools, π apart about z (π about x vs π about y): relative angle exactly π.
    let a = Pose::new(0.0, 0.0, 0.0, PI, 0.0, 0.0);
    let b = Pose::new(0.0, 0.0, 0.0, 0.0, PI, 0.0);
    let mid = interpolate(&a, &b, 0.5);
    assert!(mid.to_array().iter().all(|c| c.is_finite()));
    assert!((rotation_distance(&a, &mid) - FRAC_PI_2).abs() < 1e-12);
    assert!((rotation_distance(&b, &mid) - FRAC_PI_2).abs() < 1e-12);
}

/// A downward tool reported with norm slightly above π on one side and slightly below π with the
/// opposite sign on the other: the same orientation (up to 2e-9 rad). Component-wise lerp would
/// swing through the zero rotation vector; slerp stays put.
#[test]
fn interpolation_across_rotvec_sign_flip_stays_put() {
    let a = Pose::new(0.0, 0.0, 0.0, PI + 1e-9, 0.0, 0.0);
    let b = Pose::new(0.0, 0.0, 0.0, -(PI - 1e-9), 0.0, 0.0);
    assert!(rotation_distance(&a, &b) < 1e-14);
    assert!(rotation_distance(&a, &b) < 1e-14);
    for i in 0..=10 {
        let p = interpolate(&a, &b, f64::from(i) / 10.0);
        assert!(rotation_distance(&a, &p) < 1e-14, "{p:?}");
    }
}

#[test]
fn interpolation_between_equal_orientations() {
    let a = Pose::new(0.1, 0.2, 0.3, 0.5, -1.0, 2.0);
    let b = Pose::new(0.2, 0.2, 0.3, 0.5, -1.0, 2.0);
    let p = interpolate(&a, &b, 0.3);
    assert!(rotation_distance(&a, &p) < ROT_TOL);
    assert!((p.x - 0.13).abs() < 1e-16);
}

#[test]
fn rotation_distance_is_accurate_for_tiny_and_large_angles() {
    let a = Pose::new(0.0, 0.0, 0.0, PI, 0.0, 0.0);
    for &eps in &[1e-12, 1e-9, 1e-6, 0.5, PI - 1e-9] {
        let b = pose_trans(&a, &Pose::new(0.0, 0.0, 0.0, 0.0, eps, 0.0));
        let d = rotation_distance(&a, &b);
        assert!((d - eps).abs() <= 1e-15 + 1e-15 * eps, "eps {eps}: {d}");
        assert!((rotation_distance(&b, &a) - d).abs() < 1e-15);
    }
    assert_eq!(rotation_distance(&a, &a), 0.0);
    // Same rotation, different rotation vectors.
    let c = Pose::new(0.0, 0.0, 0.0, -PI, 0.0, 0.0);
    assert!(rotation_distance(&a, &c) < 1e-15);
    let d = Pose::new(0.0, 0.0, 0.0, 0.0, 0.0, 2.0 * PI);
    assert!(rotation_distance(&Pose::identity(), &d) < 1e-15);
}

fn rotvec_strategy(max_norm: f64) -> impl Strategy<Value = Vector3<f64>> {
    (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0, 0.0f64..max_norm)
        .prop_filter("non-degenerate axis", |(x, y, z, _)| {
            x * x + y * y + z * z > 1e-6
        })
        .prop_map(|(x, y, z, n)| Vector3::new(x, y, z).normalize() * n)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// rotation_to_rotvec ∘ rotvec_to_rotation is the identity on rotations, for |v| ≤ 4π.
    #[test]
    fn prop_rotvec_round_trip(v in rotvec_strategy(4.0 * PI)) {
        let r = rotvec_to_rotation(&v);
        prop_assert!(angle_between(&r, &Rotation3::from_scaled_axis(v)) < ROT_TOL);
        let back = rotation_to_rotvec(&r);
        prop_assert!(back.norm() <= PI_ROUNDED);
        prop_assert!(angle_between(&r, &rotvec_to_rotation(&back)) < ROT_TOL);
        // Also via the pose path (quaternions).
        let p = rot_pose(v);
        prop_assert!(rotation_distance(&p, &Pose::from_isometry(&p.to_isometry())) < ROT_TOL);
    }

    /// Same, concentrated near π where the axis sign is delicate.
    #[test]
    fn prop_rotvec_round_trip_near_pi(v in rotvec_strategy(1.0), d in -1e-6f64..1e-6) {
        let v = if v.norm() > 0.0 { v.normalize() * (PI + d) } else { Vector3::x() * PI };
        let r = rotvec_to_rotation(&v);
        let back = rotation_to_rotvec(&r);
        prop_assert!((back.norm() - (PI - d.abs())).abs() < 1e-14);
        prop_assert!(angle_between(&r, &rotvec_to_rotation(&back)) < ROT_TOL);
    }

    #[test]
    fn prop_pose_inv_and_trans(
        p in (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0, rotvec_strategy(4.0 * PI)),
        q in (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0, rotvec_strategy(4.0 * PI)),
    ) {
        let p = Pose::from_parts(&Vector3::new(p.0, p.1, p.2), &p.3);
        let q = Pose::from_parts(&Vector3::new(q.0, q.1, q.2), &q.3);
        let (dp, dr) = pose_dist(&pose_trans(&p, &pose_inv(&p)), &Pose::identity());
        prop_assert!(dp < 1e-14 && dr < ROT_TOL);
        // (p · q) · q⁻¹ = p
        let back = pose_trans(&pose_trans(&p, &q), &pose_inv(&q));
        let (dp, dr) = pose_dist(&back, &p);
        prop_assert!(dp < 1e-14 && dr < ROT_TOL);
    }
}
