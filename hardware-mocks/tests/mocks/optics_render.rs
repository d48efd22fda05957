//! The GelSight renderer against what its model says: a flat gel is the background, slopes take
//! the colour of the LED they face, markers ride on the tangential displacement, effects are
//! opt-in and seeded, and bad input never panics.

use hardware_mocks::sim::contact::SurfaceField;
use hardware_mocks::sim::optics::{
    ImageEffects, background, geometric_field, marker_centres_mm, mm_to_px, render,
};
use rig_core::config::{ElastomerConfig, RigConfig};
use rig_core::indenter::Indenter;
use rig_core::optics::{MarkerPattern, OpticsConfig};

fn source_optics() -> OpticsConfig {
    RigConfig::sim_source()
        .optics
        .expect("sim-source has [optics]")
}

fn sphere_field(depth_mm: f64, shear_mm: [f64; 2]) -> SurfaceField {
    field_of("sphere", depth_mm, shear_mm)
}

fn field_of(indenter: &str, depth_mm: f64, shear_mm: [f64; 2]) -> SurfaceField {
    let indenter = Indenter::builtin(indenter).unwrap();
    geometric_field(
        &indenter,
        &ElastomerConfig::default(),
        [0.0, 0.0],
        depth_mm,
        shear_mm,
        0.05,
    )
}

fn px(img: &image::RgbImage, p_mm: [f64; 2], optics: &OpticsConfig) -> [f64; 3] {
    let [u, v] = mm_to_px(optics, p_mm);
    img.get_pixel(u.round() as u32, v.round() as u32)
        .0
        .map(f64::from)
}

fn diff(a: &image::RgbImage, b: &image::RgbImage) -> Vec<u32> {
    a.pixels()
        .zip(b.pixels())
        .map(|(p, q)| (0..3).map(|k| p.0[k].abs_diff(q.0[k]) as u32).sum())
        .collect()
}

#[test]
fn an_untouched_gel_renders_exactly_as_the_background() {
    let optics = source_optics();
    let fx = ImageEffects::realistic();
    let flat = sphere_field(0.0, [0.0, 0.0]);
    assert!(flat.uz_mm.iter().all(|&u| u == 0.0));
    let img = render(&optics, &fx, &flat, 9);
    assert_eq!(img, background(&optics, &fx, 9));
    assert_eq!(img.dimensions(), (320, 240));
}

#[test]
fn a_press_changes_the_image_only_around_the_contact() {
    let optics = source_optics();
    let fx = ImageEffects::shading_only();
    let img = render(&optics, &fx, &sphere_field(0.6, [0.0, 0.0]), 0);
    let bg = background(&optics, &fx, 0);
    let d = diff(&img, &bg);
    let w = img.width() as usize;
    // Sphere (R = 4 mm, see indenters/sphere.toml) at 0.6 mm: contact radius about √(R d) ≈ 1.5 mm;
    // with the 0.25 mm skirt nothing changes beyond about 2.8 mm from the centre.
    let mut changed_inside = 0;
    for (k, &dk) in d.iter().enumerate() {
        let (u, v) = ((k % w) as f64, (k / w) as f64);
        let r_mm = ((u + 0.5 - 160.0).hypot(v + 0.5 - 120.0)) * optics.mm_per_px;
        if r_mm > 3.2 {
            assert_eq!(dk, 0, "pixel {u},{v} at {r_mm:.2} mm changed");
        } else if r_mm < 1.4 && dk > 6 {
            changed_inside += 1;
        }
    }
    assert!(
        changed_inside > 2000,
        "{changed_inside} pixels changed in the contact"
    );
}

#[test]
fn a_slope_facing_an_led_takes_its_colour() {
    // Source sensor: red LED from +y (azimuth 90°), blue from 330°, green from 210°.
    let optics = source_optics();
    let fx = ImageEffects::shading_only();
    let img = render(&optics, &fx, &sphere_field(0.6, [0.0, 0.0]), 0);
    let bg = background(&optics, &fx, 0);
    let at = |p| {
        let (a, b) = (px(&img, p, &optics), px(&bg, p, &optics));
        [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
    };
    // The raised gel's +y flank faces the +y LED: redder; the −y flank turns away: less red.
    let north = at([0.0, 1.0]);
    let south = at([0.0, -1.0]);
    assert!(north[0] > 15.0, "north {north:?}");
    assert!(south[0] < -15.0, "south {south:?}");
    // The flank towards 330° faces the blue LED.
    let (s, c) = 330f64.to_radians().sin_cos();
    let blue_side = at([c, s]);
    assert!(
        blue_side[2] > 15.0 && blue_side[2] > blue_side[0],
        "{blue_side:?}"
    );
    // The top of the cap is nearly flat: nearly background.
    let top = at([0.0, 0.0]);
    assert!(top.iter().all(|d| d.abs() < 8.0), "top {top:?}");
}

/// Intensity-weighted centre of the dark pixels within `r_px` of `(u, v)`.
fn dark_centroid(img: &image::RgbImage, u: f64, v: f64, r_px: f64) -> Option<[f64; 2]> {
    let (mut su, mut sv, mut sw) = (0.0, 0.0, 0.0);
    for (x, y, p) in img.enumerate_pixels() {
        let (x, y) = (f64::from(x), f64::from(y));
        if (x - u).hypot(y - v) > r_px {
            continue;
        }
        let lum = f64::from(p.0[0]) + f64::from(p.0[1]) + f64::from(p.0[2]);
        let dark = (200.0 - lum).max(0.0);
        su += dark * x;
        sv += dark * y;
        sw += dark;
    }
    (sw > 0.0).then(|| [su / sw, sv / sw])
}

#[test]
fn markers_move_with_the_tangential_displacement() {
    let optics = source_optics();
    let fx = ImageEffects {
        markers: true,
        ..ImageEffects::shading_only()
    };
    // A gel sheared uniformly by (0.3, −0.2) mm, no normal displacement.
    let mut field = sphere_field(0.0, [0.0, 0.0]);
    field.ux_mm.iter_mut().for_each(|u| *u = 0.3);
    field.uy_mm.iter_mut().for_each(|u| *u = -0.2);
    let still = render(&optics, &fx, &sphere_field(0.0, [0.0, 0.0]), 0);
    let moved = render(&optics, &fx, &field, 0);
    let dot = [0.9, 0.0]; // a grid dot (spacing 0.9 mm, no offset)
    let [u0, v0] = mm_to_px(&optics, dot);
    let [u1, v1] = mm_to_px(&optics, [dot[0] + 0.3, dot[1] - 0.2]);
    let c0 = dark_centroid(&still, u0, v0, 6.0).unwrap();
    let c1 = dark_centroid(&moved, u1, v1, 6.0).unwrap();
    assert!(
        (c0[0] - u0).abs() < 0.3 && (c0[1] - v0).abs() < 0.3,
        "{c0:?}"
    );
    assert!(
        (c1[0] - u1).abs() < 0.3 && (c1[1] - v1).abs() < 0.3,
        "{c1:?} vs {u1},{v1}"
    );
    // 0.3 mm at 0.03125 mm/px is 9.6 px right; −0.2 mm in y is 6.4 px down.
    assert!((c1[0] - c0[0] - 9.6).abs() < 0.4 && (c1[1] - c0[1] - 6.4).abs() < 0.4);
}

/// A camera turned on its axis (`optics.camera_rotation_deg`) sees the gel turned: each dot lies
/// where the turned pixel grid puts it. Its LEDs turn with it, so a contact whose shape does not
/// change under the turn (a sphere pressed at the image centre) looks the same as from the
/// unturned camera: the surface's slopes are shaded in the camera's frame.
#[test]
fn a_turned_camera_sees_the_gel_turned_and_shades_in_its_own_frame() {
    let straight = source_optics();
    let turned = OpticsConfig {
        camera_rotation_deg: 10.0,
        ..straight.clone()
    };
    let with = ImageEffects {
        markers: true,
        ..ImageEffects::shading_only()
    };
    let flat = sphere_field(0.0, [0.0, 0.0]);
    let img = render(&turned, &with, &flat, 0);
    // A grid dot 2.7 mm right of and 1.8 mm above the centre: turned by 10°, it lands about
    // 11 px away from where the straight camera sees it.
    let dot = [2.7, 1.8];
    let [u, v] = mm_to_px(&turned, dot);
    let [us, vs] = mm_to_px(&straight, dot);
    assert!((u - us).hypot(v - vs) > 10.0, "{u},{v} vs {us},{vs}");
    // x' = 2.7 cos 10° + 1.8 sin 10° = 2.9716 mm, y' = −2.7 sin 10° + 1.8 cos 10° = 1.3038 mm.
    assert!((u - (159.5 + 2.9716 / 0.03125)).abs() < 0.01, "{u}");
    assert!((v - (119.5 - 1.3038 / 0.03125)).abs() < 0.01, "{v}");
    let c = dark_centroid(&img, u, v, 6.0).unwrap();
    assert!((c[0] - u).hypot(c[1] - v) < 0.3, "{c:?} vs {u},{v}");
    // Every dot the turned camera lists lies inside its image.
    for centre in marker_centres_mm(&turned) {
        let [u, v] = mm_to_px(&turned, centre);
        assert!((-0.5..319.5).contains(&u) && (-0.5..239.5).contains(&v));
    }

    // A sphere pressed at the centre, shading only: the same image from both cameras, up to
    // the resampling (a few levels on a handful of pixels).
    let fx = ImageEffects::shading_only();
    let pressed = sphere_field(0.6, [0.0, 0.0]);
    let (a, b) = (
        render(&straight, &fx, &pressed, 0),
        render(&turned, &fx, &pressed, 0),
    );
    let d = diff(&a, &b);
    let contact = diff(&a, &background(&straight, &fx, 0))
        .iter()
        .filter(|&&x| x > 24)
        .count();
    assert!(contact > 2000, "{contact} contact pixels");
    let off = d.iter().filter(|&&x| x > 6).count();
    assert!(
        off < contact / 50,
        "{off} of {contact} contact pixels differ"
    );
    // (Shaded with the gel's slopes, not turned into the camera's frame, the colours would be
    // turned 10° against the LEDs and the two would differ.) Pressed 1.5 mm off centre, the
    // contact is seen elsewhere by the turned camera: the turn is really there.
    let off_centre = field_of("sphere", 0.6, [1.5, 0.0]);
    let moved = diff(
        &render(&straight, &fx, &off_centre, 0),
        &render(&turned, &fx, &off_centre, 0),
    );
    assert!(moved.iter().filter(|&&x| x > 24).count() > 1000);
}

#[test]
fn markers_are_opt_in_and_follow_the_configured_pattern() {
    let mut optics = source_optics();
    let flat = sphere_field(0.0, [0.0, 0.0]);
    let dark = |img: &image::RgbImage| {
        img.pixels()
            .filter(|p| p.0.iter().map(|&c| u32::from(c)).sum::<u32>() < 100)
            .count()
    };
    let plain = render(&optics, &ImageEffects::shading_only(), &flat, 0);
    assert_eq!(dark(&plain), 0);
    let with = ImageEffects {
        markers: true,
        ..ImageEffects::shading_only()
    };
    let dotted = render(&optics, &with, &flat, 0);
    // Grid 0.9 mm over 10 × 7.5 mm: 11 × 9 dots (x from −4.5 to 4.5, y from −3.6 to 3.6) of
    // π·0.15²/0.03125² ≈ 72 px each.
    let centres = marker_centres_mm(&optics);
    assert_eq!(centres.len(), 11 * 9);
    let n = dark(&dotted) as f64;
    assert!(
        (n / centres.len() as f64 - 72.0).abs() < 12.0,
        "{n} dark pixels"
    );
    optics.markers.pattern = MarkerPattern::None;
    assert_eq!(dark(&render(&optics, &with, &flat, 0)), 0);
    assert!(marker_centres_mm(&optics).is_empty());
}

#[test]
fn noise_is_seeded_and_effects_change_the_image() {
    let optics = source_optics();
    // A 1 mm wide ridge along x: steep flanks, so every effect shows.
    let field = field_of("line", 0.6, [0.3, 0.0]);
    let fx = ImageEffects::realistic();
    let a = render(&optics, &fx, &field, 1);
    assert_eq!(a, render(&optics, &fx, &field, 1));
    assert_ne!(a, render(&optics, &fx, &field, 2));
    let base = render(&optics, &ImageEffects::shading_only(), &field, 1);
    for (name, one) in [
        (
            "markers",
            ImageEffects {
                markers: true,
                ..ImageEffects::shading_only()
            },
        ),
        (
            "shadows",
            ImageEffects {
                shadows: true,
                ..ImageEffects::shading_only()
            },
        ),
        (
            "blur",
            ImageEffects {
                blur_sigma_px: 1.5,
                ..ImageEffects::shading_only()
            },
        ),
        (
            "vignetting",
            ImageEffects {
                vignetting: 0.3,
                ..ImageEffects::shading_only()
            },
        ),
        (
            "noise",
            ImageEffects {
                noise_sigma: 2.0,
                ..ImageEffects::shading_only()
            },
        ),
    ] {
        let img = render(&optics, &one, &field, 1);
        let changed = diff(&img, &base).iter().filter(|&&d| d > 0).count();
        assert!(changed > 500, "{name} changed only {changed} pixels");
    }
    // Vignetting darkens the corners, not the centre.
    let vig = render(
        &optics,
        &ImageEffects {
            vignetting: 0.3,
            ..ImageEffects::shading_only()
        },
        &sphere_field(0.0, [0.0, 0.0]),
        0,
    );
    let bg = background(&optics, &ImageEffects::shading_only(), 0);
    let sum = |p: &image::Rgb<u8>| p.0.iter().map(|&c| u32::from(c)).sum::<u32>();
    assert!(sum(vig.get_pixel(0, 0)) < sum(bg.get_pixel(0, 0)) * 8 / 10);
    assert!(sum(vig.get_pixel(160, 120)).abs_diff(sum(bg.get_pixel(160, 120))) <= 3);
}

#[test]
fn shadows_darken_the_side_away_from_each_led() {
    let optics = source_optics();
    // A 1 mm wide flat ridge along x pressed 0.8 mm: the raised band |y| < 0.5 mm.
    let field = field_of("line", 0.8, [0.0, 0.0]);
    let on = render(
        &optics,
        &ImageEffects {
            shadows: true,
            ..ImageEffects::shading_only()
        },
        &field,
        0,
    );
    let off = render(&optics, &ImageEffects::shading_only(), &field, 0);
    // The red LED shines from +y at 30° elevation: the band's shadow on the −y side reaches
    // 0.8 / tan 30° ≈ 1.4 mm beyond its edge.
    let (a, b) = (
        px(&on, [0.0, -1.5], &optics),
        px(&off, [0.0, -1.5], &optics),
    );
    assert!(a[0] < b[0] - 20.0, "shadowed red {a:?} vs lit {b:?}");
    // The +y side is not in the red LED's shadow.
    let (a, b) = (px(&on, [0.0, 1.5], &optics), px(&off, [0.0, 1.5], &optics));
    assert!((a[0] - b[0]).abs() < 2.0, "{a:?} vs {b:?}");
}

#[test]
fn malformed_fields_and_optics_do_not_panic() {
    let optics = source_optics();
    let fx = ImageEffects::realistic();
    let bg = background(&optics, &fx, 0);
    // Vectors of the wrong length: treated as an untouched gel.
    let mut bad = sphere_field(0.5, [0.0, 0.0]);
    bad.uz_mm.pop();
    assert_eq!(render(&optics, &fx, &bad, 0), bg);
    // Non-finite values read as zero.
    let mut nan = sphere_field(0.0, [0.0, 0.0]);
    nan.uz_mm.iter_mut().for_each(|u| *u = f64::NAN);
    nan.ux_mm[0] = f64::INFINITY;
    assert_eq!(render(&optics, &fx, &nan, 0), bg);
    // A one-cell field and a zero cell size.
    let one = SurfaceField {
        nx: 1,
        ny: 1,
        cell_mm: 0.0,
        uz_mm: vec![-0.3],
        ux_mm: vec![0.0],
        uy_mm: vec![0.0],
        ..SurfaceField::default()
    };
    assert_eq!(render(&optics, &fx, &one, 0), bg);
    // Degenerate optics.
    let mut o = optics.clone();
    o.width_px = 0;
    assert_eq!(render(&o, &fx, &bad, 0).dimensions(), (0, 240));
    let mut o = optics;
    o.mm_per_px = f64::NAN;
    o.leds[0].elevation_deg = f64::NAN;
    o.markers.spacing_mm = -1.0;
    let img = render(&o, &fx, &sphere_field(0.5, [0.0, 0.0]), 0);
    assert_eq!(img.dimensions(), (320, 240));
}
