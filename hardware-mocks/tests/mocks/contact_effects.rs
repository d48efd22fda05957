//! Effects are opt-in stages, and friction history is what makes loading, shear, reverse and
//! unloading differ.

use std::sync::Arc;

use hardware_mocks::sim::{
    ContactModel, FrictionModel, IndenterPose, Scene, SimOutput, Simulator, Viscoelastic, simulate,
};
use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;

fn scene(name: &str, model: ContactModel, depth: f64) -> Scene {
    let mut s = Scene::new(
        ElastomerConfig::default(),
        Arc::new(Indenter::builtin(name).unwrap()),
        IndenterPose {
            depth_mm: depth,
            ..IndenterPose::default()
        },
    );
    s.effects.contact = model;
    s.effects.cell_mm = Some(0.2);
    s
}

#[test]
fn a_force_only_scene_renders_nothing_and_builds_no_field() {
    let out = simulate(&scene("cone", ContactModel::Layer, 0.6)).unwrap();
    assert!(out.wrench.force_n[2] < 0.0);
    assert!(out.image.is_none() && out.field.is_none());
    assert_eq!(out.stats.images_rendered, 0);
    assert_eq!(out.stats.fields_built, 0);
    assert_eq!(
        out.stats.tangential_solves, 0,
        "no friction asked, no tangential solve"
    );
    assert_eq!(out.stats.tangential_iterations, 0);
    assert_eq!(out.stats.normal_solves, 1);
    assert_eq!(out.wrench.force_n[0], 0.0);

    // Hertz without field or friction needs no grid at all.
    let out = simulate(&scene("sphere", ContactModel::Hertz, 0.6)).unwrap();
    assert_eq!(out.stats.ffts, 0);
    assert_eq!(out.stats.kernels_built, 0);
    assert!(out.field.is_none());
}

/// The image stage does exactly the work the sensor's `[optics.effects]` asks for: every
/// effect that is off counts zero, every one that is on counts its work.
#[test]
fn image_effects_run_only_when_the_sensor_config_enables_them() {
    use hardware_mocks::sim::ImageEffects;
    use rig_core::config::RigConfig;
    use rig_core::optics::{EffectsConfig, MarkerPattern};

    let stats_for = |effects: EffectsConfig, pattern: MarkerPattern, depth: f64| {
        let mut optics = RigConfig::sim_source().optics.unwrap();
        optics.effects = effects;
        optics.markers.pattern = pattern;
        let mut s = scene("sphere", ContactModel::Winkler, depth);
        s.effects.image = Some(ImageEffects::from_optics(&optics));
        s.optics = Some(optics);
        let out = Simulator::new().step(&s, 0.0).unwrap();
        assert_eq!(out.stats.images_rendered, 1);
        out.stats
    };
    let none = EffectsConfig {
        markers: false,
        shadows: false,
        blur_sigma_px: 0.0,
        vignetting: 0.0,
        noise_sigma: 0.0,
    };
    let st = stats_for(none, MarkerPattern::Grid, 0.6);
    assert!(st.shaded_pixels > 1000, "{st:?}");
    let idle = [
        st.markers_drawn,
        st.shadow_sweeps,
        st.blur_passes,
        st.vignette_frames,
        st.noise_samples,
    ];
    assert_eq!(idle, [0; 5], "{st:?}");

    let all = EffectsConfig::default();
    let st = stats_for(all, MarkerPattern::Grid, 0.6);
    assert!(st.markers_drawn > 100, "{st:?}");
    assert_eq!(st.shadow_sweeps, 3, "one per LED: {st:?}");
    assert_eq!(st.blur_passes, 6, "two per colour plane: {st:?}");
    assert_eq!(st.vignette_frames, 1);
    assert_eq!(st.noise_samples, 320 * 240 * 3);

    // A sensor without printed markers draws none even with the effect on.
    let st = stats_for(all, MarkerPattern::None, 0.6);
    assert_eq!(st.markers_drawn, 0, "{st:?}");
    // An untouched gel is the cached image: nothing shaded, only the noise is new.
    let st = stats_for(all, MarkerPattern::Grid, 0.0);
    assert_eq!(
        (st.shaded_pixels, st.shadow_sweeps, st.blur_passes),
        (0, 0, 0)
    );
    assert_eq!(st.noise_samples, 320 * 240 * 3);
}

#[test]
fn a_requested_field_is_consistent_with_the_wrench() {
    let mut s = scene("sphere", ContactModel::HalfSpace, 0.5);
    s.effects.surface_field = true;
    let out = simulate(&s).unwrap();
    assert_eq!(out.stats.fields_built, 1);
    assert_eq!(out.stats.images_rendered, 0);
    let f = out.field.unwrap();
    assert_eq!(f.pressure_mpa.len(), f.nx * f.ny);
    let a = f.cell_mm * f.cell_mm;
    let total: f64 = f.pressure_mpa.iter().sum::<f64>() * a;
    assert!((total + out.wrench.force_n[2]).abs() < 1e-9);
    assert!(f.pressure_mpa.iter().all(|&p| p >= 0.0));
    // The centre is pressed in by the depth; the surface far away barely moves.
    let centre = f.uz_mm.iter().copied().fold(f64::INFINITY, f64::min);
    assert!((centre + 0.5).abs() < 0.01, "{centre}");
    assert!(f.uz_mm[0].abs() < 0.05);
    // No friction: no tangential displacement.
    assert!(f.ux_mm.iter().chain(&f.uy_mm).all(|&u| u == 0.0));
}

fn run(sim: &mut Simulator, s: &mut Scene, poses: &[(f64, f64)]) -> Vec<SimOutput> {
    poses
        .iter()
        .enumerate()
        .map(|(i, &(depth, shear))| {
            s.pose.depth_mm = depth;
            s.pose.shear_mm = [shear, 0.0];
            sim.step(s, i as f64 * 0.1).unwrap()
        })
        .collect()
}

/// Down to 0.5 mm, shear to +0.3 mm, back to 0, up.
const PATH: [(f64, f64); 9] = [
    (0.25, 0.0),
    (0.5, 0.0),
    (0.5, 0.15),
    (0.5, 0.3),
    (0.5, 0.15),
    (0.5, 0.0),
    (0.25, 0.0),
    (0.5, 0.0),
    (0.0, 0.0),
];

#[test]
fn without_friction_history_loading_and_unloading_are_identical() {
    for friction in [FrictionModel::None, FrictionModel::Monotonic] {
        let mut s = scene("sphere", ContactModel::HalfSpace, 0.0);
        s.effects.friction = friction;
        let mut sim = Simulator::new();
        let out = run(&mut sim, &mut s, &PATH);
        // Same pose, same result, whatever came before.
        assert_eq!(out[0].wrench, out[6].wrench, "{friction:?}");
        assert_eq!(out[1].wrench, out[5].wrench, "{friction:?}");
        assert_eq!(out[1].wrench, out[7].wrench, "{friction:?}");
        assert_eq!(out[2].wrench, out[4].wrench, "{friction:?}");
    }
}

#[test]
fn with_friction_history_shear_reverse_and_unloading_differ() {
    let mut s = scene("sphere", ContactModel::HalfSpace, 0.0);
    s.effects.friction = FrictionModel::Incremental;
    let mut sim = Simulator::new();
    let out = run(&mut sim, &mut s, &PATH);
    let fx: Vec<f64> = out.iter().map(|o| o.wrench.force_n[0]).collect();
    let fz: Vec<f64> = out.iter().map(|o| o.wrench.force_n[2]).collect();
    println!("Fx along the path: {fx:?}");
    assert!(out.iter().all(|o| o.stats.converged));
    // Pure loading: no tangential force.
    assert!(fx[0].abs() < 1e-9 && fx[1].abs() < 1e-9);
    // Shearing +x drags the gel along +x.
    assert!(fx[2] > 0.0 && fx[3] > fx[2]);
    // Coulomb: never more than μ |Fz|.
    for (x, z) in fx.iter().zip(&fz) {
        assert!(x.abs() <= 1.0 * z.abs() * (1.0 + 1e-6));
    }
    // Reverse: at the same pose the force is lower on the way back (hysteresis) ...
    assert!(fx[4] < fx[2] - 0.1 * fx[2].abs(), "{} vs {}", fx[4], fx[2]);
    // ... and back at the start the gel is left sheared the other way.
    assert!(fx[5] < -1e-4, "{}", fx[5]);
    // Unloading after shear keeps a locked-in traction; loading did not.
    assert!(fx[6].abs() > 1e-7 && fx[6] != fx[0], "{}", fx[6]);
    // Losing contact resets the history.
    assert_eq!(out[8].wrench.force_n, [0.0; 3]);
}

#[test]
fn monotonic_shear_matches_cattaneo_mindlin() {
    // Hertz pressure on the grid plus the tangential BEM against Mindlin's
    // Q/μP = 1 − (1 − 16 G a δ / (3 μ P (2 − ν)))^{3/2}.
    let mut s = scene("sphere", ContactModel::Hertz, 0.5);
    s.effects.friction = FrictionModel::Monotonic;
    let g = &s.elastomer;
    let (e, nu, mu) = (
        g.youngs_modulus_mpa,
        g.poisson_ratio,
        g.friction_coefficient,
    );
    let shear = e / (2.0 * (1.0 + nu));
    let a = (4.0f64 * 0.5).sqrt();
    for delta in [0.02, 0.05, 0.1] {
        s.pose.shear_mm = [delta, 0.0];
        let out = simulate(&s).unwrap();
        let p = -out.wrench.force_n[2];
        let x = 16.0 * shear * a * delta / (3.0 * mu * p * (2.0 - nu));
        let want = mu * p * (1.0 - (1.0 - x).max(0.0).powf(1.5));
        let got = out.wrench.force_n[0];
        println!("δ = {delta}: Q = {got:.5} N, Mindlin {want:.5} N");
        assert!(
            (got - want).abs() / want < 0.05,
            "δ = {delta}: {got} vs {want}"
        );
        assert!(out.wrench.force_n[1].abs() < 1e-6 * p);
    }
    // Beyond full slip: Q = μ P.
    s.pose.shear_mm = [1.0, 0.0];
    let out = simulate(&s).unwrap();
    let ratio = out.wrench.force_n[0] / (-out.wrench.force_n[2]);
    assert!((ratio - mu).abs() < 1e-3, "{ratio}");
}

#[test]
fn winkler_friction_uses_springs_per_cell() {
    let mut s = scene("sphere", ContactModel::Winkler, 0.5);
    s.effects.friction = FrictionModel::Monotonic;
    s.pose.shear_mm = [0.01, 0.0];
    let out = simulate(&s).unwrap();
    assert_eq!(out.stats.ffts, 0);
    assert_eq!(out.stats.tangential_solves, 1);
    assert!(out.wrench.force_n[0] > 0.0);
    assert!(out.wrench.force_n[0] <= -out.wrench.force_n[2]);
}

#[test]
fn viscoelastic_force_relaxes_to_the_elastic_one() {
    let mut s = scene("sphere", ContactModel::HalfSpace, 0.5);
    s.effects.viscoelastic = Some(Viscoelastic {
        instant_ratio: 2.0,
        tau_s: 1.0,
    });
    let elastic = {
        let mut e = s.clone();
        e.effects.viscoelastic = None;
        simulate(&e).unwrap().wrench.force_n[2]
    };
    let mut sim = Simulator::new();
    let first = sim.step(&s, 0.0).unwrap().wrench.force_n[2];
    assert!((first - 2.0 * elastic).abs() < 1e-9 * elastic.abs());
    let later = sim.step(&s, 1.0).unwrap().wrench.force_n[2];
    assert!((later - elastic * (1.0 + (-1.0f64).exp())).abs() < 1e-9 * elastic.abs());
    let relaxed = sim.step(&s, 20.0).unwrap().wrench.force_n[2];
    assert!((relaxed - elastic).abs() < 1e-6 * elastic.abs());
}

#[test]
fn an_image_without_optics_is_an_error() {
    let mut s = scene("sphere", ContactModel::Hertz, 0.5);
    s.effects.image = Some(Default::default());
    assert!(simulate(&s).is_err());
}
