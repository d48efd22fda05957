//! Calibration files, tool transform and bias estimation (rig_core::ft).

use nalgebra::Matrix6;
use rig_core::ft::bias::BiasEstimator;
use rig_core::ft::cal::{CalError, Calibration, MatrixSource};
use rig_core::ft::transform::{ToolTransform, TransformError};

const USER: &str = include_str!("../../../tests/data/nano17_useraxis.cal");
const AXIS: &str = include_str!("../../../tests/data/nano17_axis_only.cal");

fn max_rel(a: &Matrix6<f64>, b: &Matrix6<f64>) -> f64 {
    let mut worst: f64 = 0.0;
    for i in 0..6 {
        let row_max = (0..6).map(|j| a[(i, j)].abs()).fold(0.0, f64::max);
        for j in 0..6 {
            worst = worst.max((a[(i, j)] - b[(i, j)]).abs() / row_max);
        }
    }
    worst
}

#[test]
fn ft_useraxis_file_agrees_with_its_axis_derivation() {
    let cal = Calibration::parse(USER).unwrap();
    assert_eq!(cal.source, MatrixSource::UserAxis);
    assert_eq!(cal.serial, "FT90017");
    assert_eq!(cal.max_loads, [25.0, 25.0, 35.0, 250.0, 250.0, 250.0]);
    let mismatch = cal.derivation_mismatch().unwrap();
    assert!(
        mismatch < 1e-4,
        "UserAxis vs Axis/scale+BasicTransform: {mismatch:e}"
    );
    // A value straight from the file: UserAxis Fx, gauge 3.
    assert!((cal.matrix[(0, 3)] - -3.04125).abs() < 1e-12);
    let c = cal.conditioning();
    assert!(!c.ill_conditioned, "{c:?}");
    assert!(
        c.condition_number > 1.0 && c.condition_number < 100.0,
        "{c:?}"
    );
    assert!(cal.temperature.is_some());
}

#[test]
fn ft_axis_only_file_in_us_units_matches_the_same_sensor_in_si() {
    // Both files describe one gauge matrix B (at the gauge origin). The UserAxis file moves it
    // by Dz = 1.6 mm; the Axis-only file (lbf, lbf-in, inches) by Dz = 0.063 in and Rz = -90°.
    let user = Calibration::parse(USER).unwrap();
    let axis = Calibration::parse(AXIS).unwrap();
    assert_eq!(axis.source, MatrixSource::AxisBasicTransform);
    assert!(axis.derivation_mismatch().is_none());
    let t_user = ToolTransform::from_angles([0.0, 0.0, 1.6], [0.0; 3]).unwrap();
    let b = t_user.matrix().try_inverse().unwrap() * user.derived_matrix;
    let t_axis =
        ToolTransform::from_angles([0.0, 0.0, 0.063 * 25.4], [0.0, 0.0, -90f64.to_radians()])
            .unwrap();
    let expected = t_axis.matrix() * b;
    let d = max_rel(&expected, &axis.matrix);
    assert!(d < 1e-4, "relative difference {d:e}");
    // Max loads converted back to N and N·mm (the file has 6 significant digits).
    for (got, want) in axis
        .max_loads
        .iter()
        .zip([25.0, 25.0, 35.0, 250.0, 250.0, 250.0])
    {
        assert!((got - want).abs() / want < 1e-5, "{got} vs {want}");
    }
}

#[test]
fn ft_matrix_times_gauges_minus_bias_reproduces_known_loads() {
    let cal = Calibration::parse(USER).unwrap();
    let bias = [0.12, -0.08, 0.2, -0.15, 0.06, -0.03];
    // One gauge at +1 V above its bias reads the matrix column: Fx = -3.04125 N etc.
    let mut v = bias;
    v[3] += 1.0;
    let w = cal.wrench(&v, &bias);
    assert!((w[0] - -3.04125).abs() < 1e-12 && (w[2] - -0.08221).abs() < 1e-12);
    assert!((w[5] - -12.81302).abs() < 1e-12);
    // Known loads through the inverse and back.
    for load in [
        [0.0, 0.0, -10.0, 0.0, 0.0, 0.0],
        [2.5, -1.0, -16.0, 12.0, -30.0, 4.0],
        [0.0, 0.0, 34.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, -240.0, 0.0],
        [24.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    ] {
        let g = cal.gauges_for(&load);
        let mut v = [0.0; 6];
        for i in 0..6 {
            v[i] = g[i] + bias[i];
            assert!(
                v[i].abs() < 10.0,
                "load {load:?} needs {} V on gauge {i}",
                v[i]
            );
        }
        let w = cal.wrench(&v, &bias);
        for i in 0..6 {
            assert!((w[i] - load[i]).abs() < 1e-9, "{w:?} vs {load:?}");
        }
    }
    // Temperature compensation is the exact inverse of the model's uncompensation.
    let tc = cal.temperature.as_ref().unwrap();
    let g = [1.0, -2.0, 0.5, 3.0, -0.25, 0.1];
    let raw = tc.uncompensate(&g, 1.30);
    let back = tc.compensate(&raw, 1.30).unwrap();
    for i in 0..6 {
        assert!((back[i] - g[i]).abs() < 1e-12);
        assert!(
            (raw[i] - g[i]).abs() > 1e-6,
            "compensation should change gauge {i}"
        );
    }
}

fn err(xml: &str) -> String {
    Calibration::parse(xml).unwrap_err().to_string()
}

#[test]
fn ft_malformed_cal_files_name_the_element() {
    let short = USER.replacen(
        "values=\"3.60214 -0.05531 3.57842 -0.08221 3.63561 -0.04673\"",
        "values=\"3.60214 -0.05531 3.57842 -0.08221 3.63561\"",
        1,
    );
    let e = err(&short);
    assert!(
        e.contains("<UserAxis Name=\"Fz\">") && e.contains("5 numbers"),
        "{e}"
    );
    let e = err(&USER.replacen("max=\"35\" scale", "max=\"lots\" scale", 1));
    assert!(
        e.contains("<Axis Name=\"Fz\">") && e.contains("`max`"),
        "{e}"
    );
    let e = err(&USER.replace("ForceUnits=\"N\"", "ForceUnits=\"furlong\""));
    assert!(e.contains("ForceUnits") && e.contains("furlong"), "{e}");
    let e = err(&USER.replace("<Axis Name=\"Ty\"", "<Axis Name=\"Tq\""));
    assert!(e.contains("Tq"), "{e}");
    let e = err(&USER.replace("<Thermistor value=\"1.2234\"/>", ""));
    assert!(e.contains("<Thermistor>"), "{e}");
    let e = err("<FTSensor><Calibration ForceUnits=\"N\" TorqueUnits=\"N-mm\"></FTSensor>");
    assert!(e.contains("not well-formed"), "{e}");
    let e = err("<FTSensor NumGages=\"6\"/>");
    assert!(e.contains("<Calibration>"), "{e}");
    let e = err(&USER.replace("NumGages=\"6\"", "NumGages=\"8\""));
    assert!(e.contains("NumGages"), "{e}");
}

#[test]
fn ft_singular_cal_is_refused_and_ill_conditioned_cal_is_reported() {
    // Tz row equal to the Fz row scaled: rank 5.
    let fz = "3.60214 -0.05531 3.57842 -0.08221 3.63561 -0.04673";
    let tz_line = USER
        .lines()
        .find(|l| l.contains("<UserAxis Name=\"Tz\""))
        .unwrap();
    let singular = USER.replace(
        tz_line,
        &format!("    <UserAxis Name=\"Tz\" values=\"{fz}\" max=\"250\"/>"),
    );
    let e = Calibration::parse(&singular).unwrap_err();
    assert!(matches!(e, CalError::Singular { .. }), "{e}");
    assert!(e.to_string().contains("<UserAxis> rows"), "{e}");
    // Nearly dependent: Tz = 10 × Fz plus a 1e-4 perturbation.
    let near: Vec<String> = fz
        .split(' ')
        .enumerate()
        .map(|(j, v)| {
            format!(
                "{}",
                v.parse::<f64>().unwrap() * 10.0 + if j == 0 { 1e-4 } else { 0.0 }
            )
        })
        .collect();
    let ill = USER.replace(
        tz_line,
        &format!(
            "    <UserAxis Name=\"Tz\" values=\"{}\" max=\"250\"/>",
            near.join(" ")
        ),
    );
    let cal = Calibration::parse(&ill).unwrap();
    let c = cal.conditioning();
    assert!(c.ill_conditioned, "{c:?}");
    assert!(c.scaled_condition_number > 1e4, "{c:?}");
}

#[test]
fn ft_tool_transform_moves_the_wrench_and_refuses_near_singular() {
    // 1 N along z at the sensor; the tool 10 mm along x: T_tool = -d × F = (0, 10, 0) N·mm.
    let t = ToolTransform::from_angles([10.0, 0.0, 0.0], [0.0; 3]).unwrap();
    let w = t.apply(&[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]);
    assert_eq!(w, [0.0, 0.0, 1.0, 0.0, 10.0, 0.0]);
    let t = ToolTransform::from_angles([1.0, -2.0, 30.0], [0.1, -0.2, 0.3]).unwrap();
    let w0 = [1.0, -2.0, -12.0, 30.0, -4.0, 5.0];
    let back = t.invert(&t.apply(&w0));
    for i in 0..6 {
        assert!((back[i] - w0[i]).abs() < 1e-12);
    }
    let mut r = nalgebra::Matrix3::identity();
    r[(2, 2)] = 1e-5; // a typo'd "rotation"
    match ToolTransform::from_matrix(r, [0.0; 3]) {
        Err(TransformError::NearSingular { det }) => assert!((det - 1e-5).abs() < 1e-12),
        other => panic!("{other:?}"),
    }
    match ToolTransform::from_angles([0.0, 0.0, 5e6], [0.0; 3]) {
        Err(TransformError::IllConditioned { condition, .. }) => assert!(condition > 1e6),
        other => panic!("{other:?}"),
    }
    assert!(ToolTransform::from_angles([f64::NAN, 0.0, 0.0], [0.0; 3]).is_err());
}

#[test]
fn ft_bias_on_a_noisy_stream_converges_within_its_standard_error() {
    let mut rng = hardware_free_rng(42);
    let sigma = [
        1.0 / 160.0,
        1.0 / 160.0,
        1.0 / 160.0,
        1.0 / 32.0,
        1.0 / 32.0,
        1.0 / 64.0,
    ];
    let truth = [0.376, 0.008, 1.417, 2.95, -2.58, 3.64];
    let trials = 200;
    let n = 1000;
    let mut within_2se = 0;
    for _ in 0..trials {
        let mut est = BiasEstimator::new();
        for _ in 0..n {
            let mut x = [0.0; 6];
            for i in 0..6 {
                x[i] = truth[i] + sigma[i] * rng.gaussian();
            }
            est.push(&x);
        }
        let e = est.estimate().unwrap();
        for i in 0..6 {
            let se = sigma[i] / (n as f64).sqrt();
            assert!(
                (e.std_error[i] - se).abs() / se < 0.1,
                "reported SE {} vs {se}",
                e.std_error[i]
            );
            assert!((e.mean[i] - truth[i]).abs() < 5.0 * se, "axis {i}");
            if (e.mean[i] - truth[i]).abs() < 2.0 * e.std_error[i] {
                within_2se += 1;
            }
        }
    }
    // About 95 % of estimates lie within 2 standard errors.
    let frac = within_2se as f64 / (trials * 6) as f64;
    assert!((0.92..0.98).contains(&frac), "{frac}");
    // Non-finite samples are ignored.
    let mut est = BiasEstimator::new();
    est.push(&[f64::NAN; 6]);
    assert_eq!(est.count(), 0);
}

/// A tiny Gaussian generator (SplitMix64 + Box-Muller) so this test needs no mock crate.
struct Rng(u64);
fn hardware_free_rng(seed: u64) -> Rng {
    Rng(seed)
}
impl Rng {
    fn u(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (((z ^ (z >> 31)) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn gaussian(&mut self) -> f64 {
        let (a, b) = (self.u(), self.u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

#[test]
fn ft_output_range_sets_the_channel_span_and_the_saturation_threshold() {
    let c = Calibration::parse(USER).unwrap();
    // OutputRange="20", OutputBipolar="True": ±10 V.
    assert_eq!((c.output_range.min_v, c.output_range.max_v), (-10.0, 10.0));
    let five =
        Calibration::parse(&USER.replace("OutputRange=\"20\"", "OutputRange=\"10\"")).unwrap();
    assert_eq!(
        (five.output_range.min_v, five.output_range.max_v),
        (-5.0, 5.0)
    );
    let unipolar =
        Calibration::parse(&USER.replace("OutputBipolar=\"True\"", "OutputBipolar=\"False\""))
            .unwrap();
    assert_eq!(
        (unipolar.output_range.min_v, unipolar.output_range.max_v),
        (0.0, 20.0)
    );
    // ATI: saturated at 99.5 % of the range (±4.975 V on a ±5 V sensor).
    let r = five.output_range;
    assert_eq!(r.saturated_gauges(&[4.97, -4.97, 0.0, 0.0, 0.0, 0.0]), 0);
    assert_eq!(
        r.saturated_gauges(&[4.98, -4.98, 0.0, 0.0, f64::NAN, 0.0]),
        0b1_0011
    );
    let e = err(&USER.replace("OutputRange=\"20\"", "OutputRange=\"-3\""));
    assert!(e.contains("OutputRange"), "{e}");
    let e = err(&USER.replace("OutputBipolar=\"True\"", "OutputBipolar=\"maybe\""));
    assert!(e.contains("OutputBipolar"), "{e}");
}
