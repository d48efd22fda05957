//! Marker displacement (`rig::markers`) against the simulator's own truth.
//!
//! The simulator's renderer (`hardware_mocks::sim::optics`) prints each dot at its undeformed
//! centre `c` on the gel (`marker_centres_mm`, jitter included) and draws it at `c + u(c)`, `u`
//! the surface field's tangential displacement sampled bilinearly at `c`, the disc mapped by
//! the local deformation (an affine map, which keeps its centroid). So a dot's true displacement
//! is `u(c)`, in the gel's axes: what the tracker reports in sensor axes, camera rotation undone.
//!
//! One press is simulated once (the contact physics of a run: finite layer, Coulomb friction
//! with history; a 4 mm sphere 0.6 mm deep, then slid 0.6 mm at 30°, 0.1 mm a frame) and
//! rendered by every sensor's renderer: the same gel motion seen by different cameras and
//! lattices.

use std::sync::{Arc, OnceLock};

use hardware_mocks::sim::contact::SurfaceField;
use hardware_mocks::sim::optics::{ImageEffects, Renderer, marker_centres_mm, mm_to_px};
use hardware_mocks::sim::{Effects, IndenterPose, Scene, Simulator};
use rig::markers::{GridSpec, SensorGeometry, TrackedMarker, Tracker, detect, resample_points};
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;

/// Where the sphere touches the gel, mm (off the lattice's symmetry on purpose).
const CONTACT_MM: [f64; 2] = [0.35, -0.2];
/// Depth of the press, mm, reached in 0.1 mm steps.
const DEPTH_MM: f64 = 0.6;
/// The slide: direction and length, in 0.1 mm steps.
const SLIDE_DEG: f64 = 30.0;
const SLIDE_MM: f64 = 0.6;

fn shipped(name: &str) -> RigConfig {
    let path = format!("{}/rig-configs/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    RigConfig::load(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn optics_of(name: &str) -> OpticsConfig {
    shipped(name)
        .optics
        .expect("the shipped sim configs have [optics]")
}

/// The press's surface fields, one a frame (the reference frame before them is the untouched
/// gel): six steps down, six along the slide. Simulated once for every test.
fn press() -> &'static [SurfaceField] {
    static FIELDS: OnceLock<Vec<SurfaceField>> = OnceLock::new();
    FIELDS.get_or_init(|| {
        let config = RigConfig::sim_source();
        let sphere = Arc::new(Indenter::builtin("sphere").unwrap());
        let mut scene = Scene::new(
            config.elastomer.clone(),
            sphere,
            IndenterPose {
                contact_mm: CONTACT_MM,
                depth_mm: 0.0,
                shear_mm: [0.0, 0.0],
            },
        );
        scene.effects = Effects {
            surface_field: true,
            viscoelastic: None,
            ..Effects::sensor(&config.elastomer)
        };
        let mut sim = Simulator::new();
        let (c, s) = (SLIDE_DEG.to_radians().cos(), SLIDE_DEG.to_radians().sin());
        let steps = (DEPTH_MM / 0.1).round() as usize;
        let slides = (SLIDE_MM / 0.1).round() as usize;
        let mut out = Vec::new();
        for k in 1..=steps + slides {
            scene.pose.depth_mm = DEPTH_MM * (k.min(steps) as f64 / steps as f64);
            let along = 0.1 * k.saturating_sub(steps) as f64;
            scene.pose.shear_mm = [along * c, along * s];
            let frame = sim.step(&scene, 0.04 * k as f64).unwrap();
            out.push(frame.field.expect("asked for the surface field"));
        }
        out
    })
}

/// The true tangential displacement at gel point `p`, mm: the field sampled as the renderer
/// samples it (bilinear between cell centres; zero more than half a cell outside the grid).
fn truth_at(f: &SurfaceField, p: [f64; 2]) -> [f64; 2] {
    let bracket = |x: f64, n: usize| -> Option<(usize, usize, f64)> {
        if n == 0 || x < -0.5 || x > n as f64 - 0.5 {
            return None;
        }
        let x = x.clamp(0.0, (n - 1) as f64);
        let i0 = (x.floor() as usize).min(n.saturating_sub(2));
        let t = if n < 2 { 0.0 } else { x - i0 as f64 };
        Some((i0, (i0 + 1).min(n - 1), t))
    };
    let (Some((i0, i1, tx)), Some((j0, j1, ty))) = (
        bracket((p[0] - f.origin_mm[0]) / f.cell_mm, f.nx),
        bracket((p[1] - f.origin_mm[1]) / f.cell_mm, f.ny),
    ) else {
        return [0.0, 0.0];
    };
    let lerp = |v: &[f64]| {
        let at = |i: usize, j: usize| v[j * f.nx + i];
        let top = at(i0, j0) + (at(i1, j0) - at(i0, j0)) * tx;
        let bottom = at(i0, j1) + (at(i1, j1) - at(i0, j1)) * tx;
        top + (bottom - top) * ty
    };
    [lerp(&f.ux_mm), lerp(&f.uy_mm)]
}

/// Contact pressure at gel point `p` (nearest cell), MPa.
fn pressure_at(f: &SurfaceField, p: [f64; 2]) -> f64 {
    let i = ((p[0] - f.origin_mm[0]) / f.cell_mm).round();
    let j = ((p[1] - f.origin_mm[1]) / f.cell_mm).round();
    if i < 0.0 || j < 0.0 || i >= f.nx as f64 || j >= f.ny as f64 {
        return 0.0;
    }
    f.pressure_mpa[j as usize * f.nx + i as usize]
}

/// A sensor's dots on the untouched gel: undeformed gel centre (mm) and pixel position.
fn lattice(optics: &OpticsConfig) -> Vec<([f64; 2], [f64; 2])> {
    marker_centres_mm(optics)
        .into_iter()
        .map(|c| (c, mm_to_px(optics, c)))
        .collect()
}

/// The printed dot a tracked marker is (its reference centroid within 1 px of the dot's
/// undeformed position), as its gel centre.
fn gel_centre_of(m: &TrackedMarker, lattice: &[([f64; 2], [f64; 2])]) -> [f64; 2] {
    let (c, px) = lattice
        .iter()
        .min_by(|a, b| dist(a.1, m.reference_px).total_cmp(&dist(b.1, m.reference_px)))
        .expect("a lattice");
    assert!(
        dist(*px, m.reference_px) < 1.0,
        "reference marker at {:?} is no printed dot",
        m.reference_px
    );
    *c
}

fn dist(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The renderer of a sensor with the image effects its config records.
fn renderer(optics: &OpticsConfig) -> Renderer {
    Renderer::new(optics, &ImageEffects::from_optics(optics))
}

/// The press seen by a sensor: its tracker after the last frame, and that frame.
fn track_press(
    optics: &OpticsConfig,
    effects: &ImageEffects,
    seed: u64,
) -> (Tracker, image::RgbImage) {
    let r = Renderer::new(optics, effects);
    let geom = SensorGeometry::from_optics(optics).unwrap();
    let mut tracker = Tracker::new(&r.render(&SurfaceField::default(), seed), &geom).unwrap();
    let mut last = None;
    for (k, f) in press().iter().enumerate() {
        let img = r.render(f, seed + 1 + k as u64);
        let s = tracker.update(&img).unwrap();
        assert!(s.matched > s.lost, "frame {k}: {s:?}");
        last = Some(img);
    }
    (tracker, last.unwrap())
}

/// Tracked displacement against the truth, over the markers tracked in the last frame:
/// `(truth, measured, in contact)`, mm (in contact: the gel under the marker carries pressure).
fn against_truth(optics: &OpticsConfig, tracker: &Tracker) -> Vec<([f64; 2], [f64; 2], bool)> {
    let lattice = lattice(optics);
    let field = press().last().unwrap();
    tracker
        .markers()
        .iter()
        .filter(|m| !m.lost)
        .map(|m| {
            let c = gel_centre_of(m, &lattice);
            (
                truth_at(field, c),
                m.displacement_mm,
                pressure_at(field, c) > 0.0,
            )
        })
        .collect()
}

/// RMS of the per-cell vector difference of two grids.
fn rms_diff(a: &[[f32; 2]], b: &[[f32; 2]]) -> f64 {
    assert_eq!(a.len(), b.len());
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| f64::from(p[0] - q[0]).powi(2) + f64::from(p[1] - q[1]).powi(2))
        .sum();
    (s / a.len() as f64).sqrt()
}

fn peak(a: &[[f32; 2]]) -> f64 {
    a.iter()
        .map(|v| f64::from(v[0]).hypot(f64::from(v[1])))
        .fold(0.0, f64::max)
}

/// The true field on the default grid, smoothed as the grid smooths markers: the truth on a
/// dense 0.05 mm lattice over the part of the gel every sensor's camera sees (±4.6 × ±3.4 mm,
/// the field of view less the dot radius and the cameras' offsets), then resampled. What a
/// sensor with an infinitely fine lattice would give.
fn ideal_grid() -> Vec<[f32; 2]> {
    let field = press().last().unwrap();
    let (mut p, mut d) = (Vec::new(), Vec::new());
    for j in -68..=68 {
        for i in -92..=92 {
            let x = [f64::from(i) * 0.05, f64::from(j) * 0.05];
            p.push(x);
            d.push(truth_at(field, x));
        }
    }
    resample_points(&p, &d, &GridSpec::default())
}

#[test]
fn every_visible_dot_of_an_untouched_gel_is_found_once_at_its_printed_centre() {
    // Dots whose disc, anti-aliased rim included, keeps a clear pixel from the border are
    // "fully visible"; the detector drops dots whose ink reaches the outermost pixels (it
    // cannot tell them from dots cut by the border), so dots nearer the border may go either
    // way, but must be right when found.
    for name in ["sim-source", "sim-target", "sim-third"] {
        let optics = optics_of(name);
        let geom = SensorGeometry::from_optics(&optics).unwrap();
        let img = renderer(&optics).render(&SurfaceField::default(), 11);
        let found = detect(&img, &geom);
        let r = geom.dot_px() / 2.0;
        let (w, h) = (f64::from(geom.width_px), f64::from(geom.height_px));
        let lattice = lattice(&optics);
        let visible = |p: [f64; 2]| {
            p[0] >= r + 1.0 && p[0] <= w - 2.0 - r && p[1] >= r + 1.0 && p[1] <= h - 2.0 - r
        };
        let mut errors = Vec::new();
        for (_, px) in lattice.iter().filter(|(_, px)| visible(*px)) {
            let near: Vec<f64> = found
                .iter()
                .map(|m| dist(m.px, *px))
                .filter(|d| *d < geom.spacing_px() / 3.0)
                .collect();
            assert_eq!(
                near.len(),
                1,
                "{name}: dot at {px:?} found {} times",
                near.len()
            );
            errors.push(near[0]);
        }
        // No spurious detection: each one is a printed dot.
        for m in &found {
            let d = lattice
                .iter()
                .map(|(_, px)| dist(*px, m.px))
                .fold(f64::INFINITY, f64::min);
            assert!(
                d < 0.5,
                "{name}: detection at {:?} is {d:.3} px from any dot",
                m.px
            );
            errors.push(d);
        }
        let max = errors.iter().copied().fold(0.0, f64::max);
        let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
        println!(
            "{name}: {} dots found, {} fully visible; centroid error rms {rms:.4} px, max {max:.4} px",
            found.len(),
            lattice.iter().filter(|(_, px)| visible(*px)).count()
        );
        // What moves a centroid off the printed centre: the renderer's one-pixel linear edge
        // ramp (not a disc's exact coverage) and 8-bit rounding of the rim, up to about 0.02 px
        // on a disc of 4–6 px radius; camera noise (1–2 levels against a contrast of 100–220
        // levels, over 50–130 pixels) about 0.003 px. Measured: max 0.018 / 0.020 / 0.025 px
        // (source / target / third). 0.05 px (1.6 µm) leaves room for the noise seed and no
        // more: a dot's centroid pulled by a clipped background window at the border (before
        // the background left dots out) was 0.10 px off.
        assert!(max < 0.05, "{name}: max centroid error {max:.4} px");
    }
}

/// RMS and largest distance between truth and measurement, pixels of `mm_per_px`.
fn error_px<'a>(
    pairs: impl IntoIterator<Item = &'a ([f64; 2], [f64; 2], bool)>,
    mm_per_px: f64,
) -> (f64, f64, usize) {
    let e: Vec<f64> = pairs
        .into_iter()
        .map(|(t, m, _)| dist(*t, *m) / mm_per_px)
        .collect();
    let rms = (e.iter().map(|e| e * e).sum::<f64>() / e.len().max(1) as f64).sqrt();
    (rms, e.iter().copied().fold(0.0, f64::max), e.len())
}

#[test]
fn a_sheared_press_moves_the_tracked_markers_as_the_simulated_gel() {
    let last = press().last().unwrap();
    let truth_peak = (0..last.ux_mm.len())
        .map(|k| last.ux_mm[k].hypot(last.uy_mm[k]))
        .fold(0.0, f64::max);
    println!("press: peak true tangential displacement {truth_peak:.3} mm");
    // The slide sticks in the middle of the contact: the gel there moves with the sphere.
    assert!((truth_peak - SLIDE_MM).abs() < 0.05, "{truth_peak}");
    let slide = [SLIDE_DEG.to_radians().cos(), SLIDE_DEG.to_radians().sin()];
    for (name, full_look) in [
        ("sim-source", false),
        ("sim-target", false),
        ("sim-third", false),
        ("sim-source", true),
    ] {
        let optics = optics_of(name);
        // A GelSight Mini's whole look on top of the sensor's own: shadows of the raised gel,
        // 0.8 px of defocus blur, 25 % vignetting, noise 1.5 levels.
        let effects = ImageEffects {
            shadows: full_look,
            blur_sigma_px: if full_look { 0.8 } else { 0.0 },
            vignetting: if full_look { 0.25 } else { 0.0 },
            noise_sigma: if full_look {
                1.5
            } else {
                optics.effects.noise_sigma
            },
            ..ImageEffects::from_optics(&optics)
        };
        let label = format!("{name}{}", if full_look { " (full look)" } else { "" });
        let (tracker, _) = track_press(&optics, &effects, 21);
        let pairs = against_truth(&optics, &tracker);
        let (rms, max, n) = error_px(&pairs, optics.mm_per_px);
        let (rms_c, max_c, n_c) = error_px(pairs.iter().filter(|p| p.2), optics.mm_per_px);
        let lost = tracker.markers().iter().filter(|m| m.lost).count();
        println!(
            "{label}: {n} of {} markers tracked: error rms {rms:.3} px, max {max:.3} px; \
             {n_c} in contact: rms {rms_c:.3} px, max {max_c:.3} px",
            tracker.markers().len()
        );
        // Markers are lost only where the slide carries them out of the image (the slide
        // points up and right): within a dot's radius and a pixel of the top or right edge.
        let r = optics.markers.dot_diameter_mm / 2.0 / optics.mm_per_px;
        for m in tracker.markers().iter().filter(|m| m.lost) {
            let edge = (f64::from(optics.width_px) - 1.0 - m.position_px[0]).min(m.position_px[1]);
            assert!(edge < r + 2.0, "{label}: lost inside the image: {m:?}");
        }
        assert!(lost * 20 < tracker.markers().len(), "{label}: {lost} lost");
        // The contact is covered: a 1.5 mm contact radius holds 8–16 dots of these lattices.
        assert!(
            n_c >= 8,
            "{label}: only {n_c} tracked markers in the contact"
        );
        // Per marker, the error of a displacement is that of two centroids (reference, now),
        // each within 0.025 px on the untouched gel. In the contact a dot is also stretched
        // and foreshortened (its centroid stays, to first order) and sits on shaded gel whose
        // curvature the background window follows only to first order; blur and shadows add
        // their own. Measured: rms 0.014–0.032 px, max 0.036–0.107 px (the light dots of
        // sim-third on its strongly specular gel are the worst). Bounds: rms 0.08 px, max
        // 0.25 px = 7.8 µm, 1.3 % of the 0.6 mm slide (an error of a pixel would be 5 %).
        assert!(
            rms < 0.08 && max < 0.25,
            "{label}: rms {rms:.3} px, max {max:.3} px"
        );
        // In the contact the markers moved with the sphere: along the slide, most of its length.
        let mean = pairs.iter().filter(|p| p.2).fold([0.0, 0.0], |a, p| {
            [a[0] + p.1[0] / n_c as f64, a[1] + p.1[1] / n_c as f64]
        });
        let along = mean[0] * slide[0] + mean[1] * slide[1];
        let across = mean[0] * slide[1] - mean[1] * slide[0];
        println!(
            "   contact's mean displacement {along:.3} mm along the slide, {across:.4} across"
        );
        assert!(
            along > 0.5 * SLIDE_MM && across.abs() < 0.1 * along,
            "{label}: {mean:?}"
        );
    }
}

#[test]
fn two_sensors_of_different_pitch_give_the_same_grid_field() {
    // The same gel motion through three cameras and lattices: 0.9 mm square (sim-source),
    // 1.1 mm jittered hexagonal, other colours, a camera 0.25 mm off centre and turned 1.5°
    // (sim-target), 0.8 mm light dots on a dark gel turned −1° (sim-third).
    let ideal = ideal_grid();
    let p = peak(&ideal);
    let mut grids = Vec::new();
    let mut frames = Vec::new();
    for name in ["sim-source", "sim-target", "sim-third"] {
        let optics = optics_of(name);
        let (tracker, img) = track_press(&optics, &ImageEffects::from_optics(&optics), 31);
        // Each sensor's camera offset is known here: grids centred on the gel sample the same gel.
        let g = tracker.grid_on_gel(&GridSpec::default());
        let centred = tracker.grid(&GridSpec::default());
        println!(
            "{name} ({} mm pitch): grid vs ideal rms {:.4} mm ({:.1} % of the peak, {p:.3} mm); \
             centred on the image instead of the gel: {:.4} mm",
            optics.markers.spacing_mm,
            rms_diff(&g, &ideal),
            100.0 * rms_diff(&g, &ideal) / p,
            rms_diff(&centred, &ideal),
        );
        // Each grid is the ideal one to within the sampling of the field by its lattice (a
        // normalised Gaussian mean over dots ~1 mm apart instead of over every point: a few
        // tenths of a percent to 2 % of the peak for a contact 3 mm across) plus the
        // tracking error (under 0.05 px, 1.5 µm, 0.3 % of the peak). Measured: 1.1 / 1.4 /
        // 0.8 %. Bound: 3 %.
        assert!(rms_diff(&g, &ideal) < 0.03 * p, "{name}");
        grids.push(g);
        frames.push(img);
    }
    // Pairwise, two such errors: measured 2.3 % (0.9 vs 1.1 mm), 1.7 % and 1.2 %. Bound: 4 %
    // of the peak, 21 µm, under a pixel. (Without the camera offset taken out, sim-target's
    // field sits 0.25 mm off and is 4.3 % from the ideal.)
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        let d = rms_diff(&grids[a], &grids[b]);
        println!(
            "grid {a} vs {b}: rms {d:.4} mm = {:.1} % of the peak",
            100.0 * d / p
        );
        assert!(d < 0.04 * p, "grids {a} and {b}: rms {d:.4} mm");
    }
    // While the images are nothing alike.
    let pixel_diff = frames[0]
        .as_raw()
        .iter()
        .zip(frames[1].as_raw())
        .map(|(a, b)| f64::from(a.abs_diff(*b)))
        .sum::<f64>()
        / frames[0].as_raw().len() as f64;
    println!("source vs target last frame: mean |difference| {pixel_diff:.1} levels");
    assert!(pixel_diff > 20.0, "{pixel_diff}");
}

/// `g` turned by `deg` (each cell's vector, not the cells).
fn turn(g: &[[f32; 2]], deg: f64) -> Vec<[f32; 2]> {
    let (s, c) = (deg.to_radians().sin() as f32, deg.to_radians().cos() as f32);
    g.iter()
        .map(|v| [c * v[0] - s * v[1], s * v[0] + c * v[1]])
        .collect()
}

#[test]
fn a_turned_camera_gives_the_same_field_in_sensor_axes() {
    let ideal = ideal_grid();
    let p = peak(&ideal);
    let straight = optics_of("sim-source");
    let (t0, _) = track_press(&straight, &ImageEffects::from_optics(&straight), 41);
    let g0 = t0.grid(&GridSpec::default());
    for deg in [3.0, -4.0] {
        let turned = OpticsConfig {
            camera_rotation_deg: deg,
            ..straight.clone()
        };
        let (t, _) = track_press(&turned, &ImageEffects::from_optics(&turned), 41);
        let g = t.grid(&GridSpec::default());
        let pairs = against_truth(&turned, &t);
        let (rms, max, _) = error_px(&pairs, turned.mm_per_px);
        let d = rms_diff(&g, &g0);
        // Had the turn not been undone, the vectors would be off by the angle.
        let not_undone = rms_diff(&turn(&g, -deg), &g0);
        println!(
            "{deg}°: markers vs truth rms {rms:.3} px, max {max:.3} px; grid vs straight rms \
             {d:.4} mm ({:.1} % of the peak; {:.1} % with the turn not undone), vs ideal {:.4} mm",
            100.0 * d / p,
            100.0 * not_undone / p,
            rms_diff(&g, &ideal)
        );
        // Per marker, as on the straight camera (bounds of the sheared press test); the turn
        // left in would put a 0.6 mm displacement 31–42 µm (1.0–1.3 px) off.
        assert!(
            rms < 0.08 && max < 0.25,
            "{deg}°: rms {rms:.3} px, max {max:.3} px"
        );
        // The grids sample the same gel through differently placed dots: measured 1.2 % and
        // 1.5 % of the peak. Leaving the turn in gives 3.3 % and 4.6 % (an rms over all cells,
        // most of which move less than the peak): bounds 3 %, and under half of that.
        assert!(
            d < 0.03 * p && not_undone > 2.0 * d,
            "{deg}°: {d:.4} vs {not_undone:.4}"
        );
    }
}

/// A gel whose whole surface has moved by `shift_mm` (no normal displacement): every dot
/// moves by exactly that.
fn shifted(shift_mm: [f64; 2]) -> SurfaceField {
    let mut f = SurfaceField::unloaded(41, 33, 0.5, [-10.0, -8.0]);
    f.ux_mm.fill(shift_mm[0]);
    f.uy_mm.fill(shift_mm[1]);
    f
}

#[test]
fn dots_leaving_the_image_are_lost_not_matched_to_a_neighbour() {
    // The whole gel slides 0.1 mm (3.2 px) a frame along +x, 1.4 mm in all: more than any of
    // these pitches, so each dot of the right-hand columns leaves the image and its left
    // neighbour later passes over where it was last seen. Also: the default grid is covered
    // everywhere on every sensor, and a turned camera reports the slide along the gel's x.
    let mut source_turned = optics_of("sim-source");
    source_turned.camera_rotation_deg = 3.0;
    for (name, optics) in [
        ("sim-source", optics_of("sim-source")),
        ("sim-target", optics_of("sim-target")),
        ("sim-third", optics_of("sim-third")),
        ("sim-source turned 3°", source_turned),
    ] {
        let r = renderer(&optics);
        let geom = SensorGeometry::from_optics(&optics).unwrap();
        let mut tracker = Tracker::new(&r.render(&SurfaceField::default(), 5), &geom).unwrap();
        let rad = geom.dot_px() / 2.0;
        let (w, h) = (f64::from(geom.width_px), f64::from(geom.height_px));
        let (mut lost_total, mut passed_over) = (0, 0);
        for k in 1..=14 {
            let s = 0.1 * f64::from(k);
            let summary = tracker
                .update(&r.render(&shifted([s, 0.0]), 5 + k as u64))
                .unwrap();
            let truth_px = |m: &TrackedMarker| {
                let gel = geom.px_to_mm(m.reference_px);
                geom.mm_to_px([gel[0] + s, gel[1]])
            };
            for m in tracker.markers() {
                let now = truth_px(m);
                let margin = now[0]
                    .min(now[1])
                    .min(w - 1.0 - now[0])
                    .min(h - 1.0 - now[1]);
                if m.lost {
                    // Only a dot at the border (cut, or gone) is lost.
                    assert!(margin < rad + 1.5, "{name}, frame {k}: lost at {now:?}");
                } else {
                    // A tracked dot is this dot, not a neighbour a pitch (26–35 px) away: both
                    // centroids within 0.025 px on the flat gel (see the untouched-gel test),
                    // so 0.1 px (3 µm).
                    let err = dist(m.position_px, now);
                    assert!(
                        err < 0.1,
                        "{name}, frame {k}: {m:?} is {err:.2} px from {now:?}"
                    );
                    assert!(
                        margin > rad - 0.5,
                        "{name}, frame {k}: tracked outside: {m:?}"
                    );
                    let d = m.displacement_mm;
                    assert!(
                        (d[0] - s).abs() < 0.003 && d[1].abs() < 0.003,
                        "{name}: {d:?}"
                    );
                }
            }
            // Count the frames where a tracked dot is inside a lost marker's gate (the lost
            // one, not being matched, did not take it).
            for l in tracker.markers().iter().filter(|m| m.lost) {
                passed_over += tracker
                    .markers()
                    .iter()
                    .filter(|m| !m.lost && dist(m.position_px, l.position_px) < tracker.gate_px())
                    .count();
            }
            lost_total = summary.lost;
            // The grid: the slide in every cell (all 192 covered).
            for v in tracker.grid(&GridSpec::default()) {
                assert!(
                    (f64::from(v[0]) - s).abs() < 0.003 && v[1].abs() < 0.003,
                    "{name}, frame {k}: cell {v:?}"
                );
            }
        }
        println!(
            "{name}: {} reference markers, {lost_total} lost after the 1.4 mm slide; a tracked \
             dot inside a lost marker's gate {passed_over} times",
            tracker.markers().len()
        );
        assert!(
            lost_total > 0 && passed_over > 0,
            "{name}: the case did not arise"
        );
    }
}

#[test]
fn bad_input_is_an_error_that_says_what_is_wrong_and_never_a_panic() {
    let optics = optics_of("sim-source");
    let geom = SensorGeometry::from_optics(&optics).unwrap();
    let reference = renderer(&optics).render(&SurfaceField::default(), 3);
    let grey = image::RgbImage::from_pixel(320, 240, image::Rgb([115, 115, 122]));
    for (what, img) in [
        ("black", image::RgbImage::new(320, 240)),
        ("blank", grey.clone()),
        (
            "white",
            image::RgbImage::from_pixel(320, 240, image::Rgb([255; 3])),
        ),
    ] {
        assert!(detect(&img, &geom).is_empty(), "{what}");
        let e = Tracker::new(&img, &geom).unwrap_err();
        assert!(e.contains("0 marker dots found"), "{what}: {e}");
    }
    for (w, h) in [(640, 480), (0, 0), (1, 1), (320, 239)] {
        let e = Tracker::new(&image::RgbImage::new(w, h), &geom).unwrap_err();
        assert!(
            e.contains(&format!("{w}×{h} px")) && e.contains("320×240"),
            "{e}"
        );
        assert!(detect(&image::RgbImage::new(w, h), &geom).is_empty());
    }
    // Only the middle 100 × 80 px show dots (12 of them): too few for a reference.
    let mut few = grey.clone();
    for (u, v, px) in reference.enumerate_pixels() {
        if (110..210).contains(&u) && (80..160).contains(&v) {
            few.put_pixel(u, v, *px);
        }
    }
    let e = Tracker::new(&few, &geom).unwrap_err();
    assert!(
        e.contains("marker dots found") && e.contains("needed"),
        "{e}"
    );
    println!("too few markers: {e}");
    // A sensor without markers, unusable geometry.
    let mut bare = optics.clone();
    bare.effects.markers = false;
    assert!(
        SensorGeometry::from_optics(&bare)
            .unwrap_err()
            .contains("no markers")
    );
    let bad = SensorGeometry {
        mm_per_px: 0.0,
        ..geom.clone()
    };
    assert!(
        Tracker::new(&reference, &bad)
            .unwrap_err()
            .contains("mm_per_px")
    );
    // A tracker takes a wrong-sized frame as an error and a blank one as every marker lost.
    let mut t = Tracker::new(&reference, &geom).unwrap();
    assert!(
        t.update(&image::RgbImage::new(10, 10))
            .unwrap_err()
            .contains("10×10")
    );
    let s = t.update(&grey).unwrap();
    assert_eq!((s.detected, s.matched, s.lost), (0, 0, t.markers().len()));
    let s = t.update(&reference).unwrap();
    assert_eq!(s.matched, t.markers().len());
}

#[test]
fn detection_time_per_frame() {
    // Measured, not asserted (a debug build on a shared machine, beside the other tests): the
    // fastest of 50 calls, the one least disturbed. The release target is well under 2 ms for
    // 320 × 240.
    let optics = optics_of("sim-source");
    let geom = SensorGeometry::from_optics(&optics).unwrap();
    let r = renderer(&optics);
    let frame = r.render(press().last().unwrap(), 9);
    let mut detector = rig::markers::Detector::new(&geom);
    let mut tracker = Tracker::new(&r.render(&SurfaceField::default(), 9), &geom).unwrap();
    let fastest_ms = |f: &mut dyn FnMut()| {
        (0..50)
            .map(|_| {
                let t0 = std::time::Instant::now();
                f();
                t0.elapsed().as_secs_f64() * 1e3
            })
            .fold(f64::INFINITY, f64::min)
    };
    let detect_ms = fastest_ms(&mut || {
        std::hint::black_box(detector.detect(std::hint::black_box(&frame)));
    });
    let track_ms = fastest_ms(&mut || {
        std::hint::black_box(tracker.update(&frame).unwrap());
    });
    let grid_ms = fastest_ms(&mut || {
        std::hint::black_box(tracker.grid(&GridSpec::default()));
    });
    println!(
        "detect {detect_ms:.2} ms, detect + track {track_ms:.2} ms, grid {grid_ms:.2} ms a frame \
         (this build)"
    );
}
