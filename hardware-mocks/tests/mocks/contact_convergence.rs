//! Accuracy of the contact models against analytic solutions, with convergence tables over grid
//! resolutions (run with `--nocapture` to see them; the sphere table is in the `contact` module
//! docs).

use std::sync::Arc;

use hardware_mocks::sim::contact::{DEFAULT_CELL_MM, analytic};
use hardware_mocks::sim::{ContactModel, IndenterPose, Scene, simulate};
use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;

fn e_star(g: &ElastomerConfig) -> f64 {
    g.youngs_modulus_mpa / (1.0 - g.poisson_ratio.powi(2))
}

/// The normal force (N, pushing into the gel) of `indenter` at `depth` mm on `gel`, with one
/// contact model and cell size; the solver must converge to a finite wrench. Also used by
/// `contact_physics`.
pub(crate) fn force(
    indenter: &Indenter,
    gel: &ElastomerConfig,
    model: ContactModel,
    cell: f64,
    depth: f64,
) -> f64 {
    let mut scene = Scene::new(
        gel.clone(),
        Arc::new(indenter.clone()),
        IndenterPose {
            depth_mm: depth,
            ..IndenterPose::default()
        },
    );
    scene.effects.contact = model;
    scene.effects.cell_mm = Some(cell);
    let out = simulate(&scene).expect("simulates");
    assert!(out.stats.converged, "solver converged");
    assert!(out.wrench.is_finite());
    -out.wrench.force_n[2]
}

/// Exact (non-parabolic) rigid sphere on a half-space (Segedin 1957): with the contact radius a,
/// `d = (a/2) ln((R+a)/(R−a))`, `F = (E*/2)[(a² + R²) ln((R+a)/(R−a)) − 2aR]`.
fn segedin_sphere_n(e_star: f64, r: f64, depth: f64) -> f64 {
    let (mut lo, mut hi) = (0.0, r * (1.0 - 1e-12));
    for _ in 0..200 {
        let a = (lo + hi) / 2.0;
        if a / 2.0 * ((r + a) / (r - a)).ln() < depth {
            lo = a;
        } else {
            hi = a;
        }
    }
    let a = lo;
    e_star / 2.0 * ((a * a + r * r) * ((r + a) / (r - a)).ln() - 2.0 * a * r)
}

const CELLS: [f64; 4] = [0.4, 0.2, 0.1, 0.05];

fn table(
    title: &str,
    indenter: &Indenter,
    gel: &ElastomerConfig,
    model: ContactModel,
    depth: f64,
    reference_n: f64,
    second: Option<(&str, f64)>,
) -> Vec<(f64, f64)> {
    println!("{title}: reference F = {reference_n:.5} N");
    match second {
        Some((name, _)) => {
            println!("| cell (mm) | F (N) | error vs analytic | error vs {name} |");
            println!("|---|---|---|---|");
        }
        None => {
            println!("| cell (mm) | F (N) | error vs analytic |");
            println!("|---|---|---|");
        }
    }
    CELLS
        .iter()
        .map(|&cell| {
            let f = force(indenter, gel, model, cell, depth);
            let err = (f - reference_n) / reference_n;
            match second {
                Some((_, s)) => println!(
                    "| {cell} | {f:.5} | {:+.2}% | {:+.3}% |",
                    err * 100.0,
                    (f - s) / s * 100.0
                ),
                None => println!("| {cell} | {f:.5} | {:+.2}% |", err * 100.0),
            }
            (cell, err)
        })
        .collect()
}

fn at_default(errors: &[(f64, f64)]) -> f64 {
    errors
        .iter()
        .find(|(c, _)| *c == DEFAULT_CELL_MM)
        .expect("default cell in the table")
        .1
}

#[test]
fn sphere_half_space_converges_to_hertz() {
    let g = ElastomerConfig::default();
    let sphere = Indenter::builtin("sphere").unwrap();
    let depth = 0.5;
    let hertz = analytic::hertz_sphere_n(e_star(&g), 4.0, depth);
    let exact = segedin_sphere_n(e_star(&g), 4.0, depth);
    let errors = table(
        "sphere R = 4 mm, d = 0.5 mm, half-space",
        &sphere,
        &g,
        ContactModel::HalfSpace,
        depth,
        hertz,
        Some(("exact sphere (Segedin)", exact)),
    );
    assert!(at_default(&errors).abs() < 0.02, "{errors:?}");
    // Converging: the finest grid is within 0.1% of the exact sphere, and errors against it
    // shrink with the cell.
    let f_fine = hertz * (1.0 + errors.last().unwrap().1);
    assert!((f_fine - exact).abs() / exact < 1e-3);
    // Hertz's paraboloid differs from the exact sphere by about (a/R)²-order: 1.25% here.
    assert!(((exact - hertz) / hertz + 0.0125).abs() < 5e-4);
}

#[test]
fn sphere_thick_layer_tends_to_hertz() {
    // The finite layer with h ≫ a is the half-space: within 2% of Hertz at the default grid.
    let g = ElastomerConfig {
        thickness_mm: 500.0,
        ..ElastomerConfig::default()
    };
    let sphere = Indenter::builtin("sphere").unwrap();
    let hertz = analytic::hertz_sphere_n(e_star(&g), 4.0, 0.5);
    let f = force(&sphere, &g, ContactModel::Layer, DEFAULT_CELL_MM, 0.5);
    let err = (f - hertz) / hertz;
    println!(
        "layer h = 500 mm: F = {f:.5} N, {:+.2}% vs Hertz",
        err * 100.0
    );
    assert!(err.abs() < 0.02, "{err}");
}

#[test]
fn finite_layer_is_stiffer_the_thinner_it_is() {
    let sphere = Indenter::builtin("sphere").unwrap();
    let mut last = 0.0;
    for h in [100.0, 10.0, 3.0, 1.0] {
        let g = ElastomerConfig {
            thickness_mm: h,
            ..ElastomerConfig::default()
        };
        let f = force(&sphere, &g, ContactModel::Layer, 0.2, 0.5);
        println!("layer h = {h} mm: F = {f:.4} N");
        assert!(f > last, "h = {h}: {f} ≤ {last}");
        last = f;
    }
    // A thin layer stays below the Winkler (confined) bound for the same gel.
    let g = ElastomerConfig {
        thickness_mm: 1.0,
        ..ElastomerConfig::default()
    };
    let winkler = force(&sphere, &g, ContactModel::Winkler, 0.2, 0.5);
    assert!(last < winkler, "{last} vs Winkler {winkler}");
}

#[test]
fn cone_converges_to_its_formula() {
    let g = ElastomerConfig::default();
    let cone = Indenter::builtin("cone").unwrap(); // 60° semi-angle
    let depth = 1.0;
    let want = analytic::cone_n(e_star(&g), 60.0, depth);
    let errors = table(
        "cone 60°, d = 1.0 mm, half-space",
        &cone,
        &g,
        ContactModel::HalfSpace,
        depth,
        want,
        None,
    );
    assert!(at_default(&errors).abs() < 0.02, "{errors:?}");
    assert!(errors.last().unwrap().1.abs() < 0.01, "{errors:?}");
}

#[test]
fn flat_punch_converges_to_its_formula() {
    let g = ElastomerConfig::default();
    let punch = Indenter::from_toml_str(
        "name = \"punch\"\n[[shape]]\nkind = \"flat_punch\"\nradius_mm = 1.5\n",
    )
    .unwrap();
    let depth = 0.2;
    let want = analytic::flat_punch_n(e_star(&g), 1.5, depth);
    let errors = table(
        "flat punch a = 1.5 mm, d = 0.2 mm, half-space",
        &punch,
        &g,
        ContactModel::HalfSpace,
        depth,
        want,
        None,
    );
    assert!(at_default(&errors).abs() < 0.02, "{errors:?}");
}

#[test]
fn winkler_matches_the_cap_volume() {
    let g = ElastomerConfig::default();
    let sphere = Indenter::builtin("sphere").unwrap();
    let m = g.youngs_modulus_mpa * (1.0 - g.poisson_ratio)
        / ((1.0 + g.poisson_ratio) * (1.0 - 2.0 * g.poisson_ratio));
    let k = m / g.thickness_mm;
    let want = analytic::winkler_sphere_n(k, 4.0, 0.5);
    let f = force(&sphere, &g, ContactModel::Winkler, DEFAULT_CELL_MM, 0.5);
    assert!((f - want).abs() / want < 0.01, "{f} vs {want}");
    // ν = 0.49 makes the confined modulus large: Winkler is an order of magnitude stiffer
    // than Hertz here.
    let hertz = analytic::hertz_sphere_n(e_star(&g), 4.0, 0.5);
    assert!(f > 10.0 * hertz);
}

#[test]
fn hertz_model_is_the_formula_and_needs_a_sphere() {
    let g = ElastomerConfig::default();
    let sphere = Indenter::builtin("sphere_s").unwrap();
    let f = force(&sphere, &g, ContactModel::Hertz, DEFAULT_CELL_MM, 0.3);
    let want = analytic::hertz_sphere_n(e_star(&g), 2.0, 0.3);
    assert!((f - want).abs() < 1e-12);
    let cone = Indenter::builtin("cone").unwrap();
    let mut scene = Scene::new(
        g,
        Arc::new(cone),
        IndenterPose {
            depth_mm: 0.3,
            ..IndenterPose::default()
        },
    );
    scene.effects.contact = ContactModel::Hertz;
    let err = simulate(&scene).unwrap_err();
    assert!(err.to_string().contains("cone"), "{err}");
}
