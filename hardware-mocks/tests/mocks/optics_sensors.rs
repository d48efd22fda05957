//! The two shipped simulated sensors (rig-configs/sim-source.toml, sim-target.toml) image the
//! same contact differently — colours, marker layout and (here) camera placement — while the
//! contact region coincides once the cameras' offsets are taken into account: the domain gap
//! the TransForce translator is meant to close.

use hardware_mocks::sim::contact::SurfaceField;
use hardware_mocks::sim::optics::{
    ImageEffects, background, geometric_field, marker_centres_mm, mm_to_px, render,
};
use rig_core::config::{ElastomerConfig, RigConfig};
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;

/// The shipped sensors, the target's camera mounted 0.3 mm off the gel centre (as a real
/// sensor's may be: `optics.camera_offset_mm`) and not turned, so the two images of a contact
/// differ by a shift (the turn is tested in `optics_render`).
fn sensors() -> (OpticsConfig, OpticsConfig) {
    let mut target = RigConfig::sim_target().optics.unwrap();
    target.camera_offset_mm = [0.25, -0.15];
    target.camera_rotation_deg = 0.0;
    (RigConfig::sim_source().optics.unwrap(), target)
}

fn contact() -> SurfaceField {
    geometric_field(
        &Indenter::builtin("sphere").unwrap(),
        &ElastomerConfig::default(),
        [0.5, -0.3],
        0.6,
        [0.0, 0.0],
        0.05,
    )
}

/// Pixels that differ from the background by more than `threshold` (sum over channels).
fn changed(img: &image::RgbImage, bg: &image::RgbImage, threshold: u32) -> Vec<bool> {
    img.pixels()
        .zip(bg.pixels())
        .map(|(p, q)| {
            (0..3)
                .map(|k| u32::from(p.0[k].abs_diff(q.0[k])))
                .sum::<u32>()
                > threshold
        })
        .collect()
}

/// Where the target's camera sees what the source's sees at pixel (0, 0), rounded: the
/// cameras' offsets on the gel, in pixels.
fn camera_shift_px(s: &OpticsConfig, t: &OpticsConfig) -> [i64; 2] {
    let (a, b) = (mm_to_px(s, [0.0, 0.0]), mm_to_px(t, [0.0, 0.0]));
    [(b[0] - a[0]).round() as i64, (b[1] - a[1]).round() as i64]
}

/// `mask` moved by `d` pixels (what was at (u, v) is at (u + d0, v + d1)); 320 × 240.
fn shifted(mask: &[bool], d: [i64; 2]) -> Vec<bool> {
    let (w, h) = (320i64, 240i64);
    (0..w * h)
        .map(|p| {
            let (u, v) = (p % w - d[0], p / w - d[1]);
            (0..w).contains(&u) && (0..h).contains(&v) && mask[(v * w + u) as usize]
        })
        .collect()
}

fn iou(a: &[bool], b: &[bool]) -> f64 {
    let inter = a.iter().zip(b).filter(|(x, y)| **x && **y).count();
    let union = a.iter().zip(b).filter(|(x, y)| **x || **y).count();
    inter as f64 / union.max(1) as f64
}

fn mean_rgb(img: &image::RgbImage) -> [f64; 3] {
    let n = f64::from(img.width() * img.height());
    let mut m = [0.0; 3];
    for p in img.pixels() {
        for (mk, pk) in m.iter_mut().zip(p.0) {
            *mk += f64::from(pk) / n;
        }
    }
    m
}

#[test]
fn both_sensors_share_the_geometry() {
    let (s, t) = sensors();
    assert_eq!((s.width_px, s.height_px), (t.width_px, t.height_px));
    assert_eq!(s.mm_per_px, t.mm_per_px);
    // The target's camera sits a fraction of a mm off the gel centre: 8 and 5 pixels.
    assert_eq!(camera_shift_px(&s, &t), [-8, -5]);
    assert_ne!(s.leds, t.leds);
    assert_ne!(s.markers, t.markers);
    assert_ne!(s.background, t.background);
}

#[test]
fn the_same_contact_differs_in_colour_but_not_in_where_it_is() {
    let (s, t) = sensors();
    let fx = ImageEffects::shading_only();
    let field = contact();
    let (img_s, img_t) = (render(&s, &fx, &field, 0), render(&t, &fx, &field, 0));
    let (bg_s, bg_t) = (background(&s, &fx, 0), background(&t, &fx, 0));

    // Colour statistics: the mean colours differ by well over the noise of a camera.
    let (ms, mt) = (mean_rgb(&img_s), mean_rgb(&img_t));
    let dist = ((0..3).map(|k| (ms[k] - mt[k]).powi(2)).sum::<f64>()).sqrt();
    assert!(dist > 15.0, "mean colours {ms:?} vs {mt:?}");

    // The contact region (difference from each sensor's own background) coincides once moved
    // by the cameras' offset, and only then.
    let (cs, ct) = (changed(&img_s, &bg_s, 24), changed(&img_t, &bg_t, 24));
    let n = cs.iter().filter(|&&c| c).count();
    assert!(n > 3000, "{n} contact pixels");
    let moved = shifted(&cs, camera_shift_px(&s, &t));
    let overlap = iou(&moved, &ct);
    assert!(overlap > 0.75, "contact masks overlap only {overlap:.2}");
    let unmoved = iou(&cs, &ct);
    assert!(
        unmoved < overlap - 0.1,
        "{unmoved:.2} without the offset, {overlap:.2} with"
    );
}

#[test]
fn the_marker_layouts_differ_and_the_contact_still_coincides_with_markers_on() {
    let (s, t) = sensors();
    let fx = ImageEffects {
        markers: true,
        ..ImageEffects::shading_only()
    };
    // Marker masks of the untouched gel: dark pixels.
    let dark = |img: &image::RgbImage| -> Vec<bool> {
        img.pixels()
            .map(|p| p.0.iter().map(|&c| u32::from(c)).sum::<u32>() < 120)
            .collect()
    };
    let (bg_s, bg_t) = (background(&s, &fx, 0), background(&t, &fx, 0));
    let (ds, dt) = (dark(&bg_s), dark(&bg_t));
    assert!(ds.iter().filter(|&&d| d).count() > 3000);
    assert!(dt.iter().filter(|&&d| d).count() > 3000);
    let overlap = iou(&ds, &dt);
    assert!(overlap < 0.2, "marker masks overlap {overlap:.2}");
    // Different counts of dots: grid 0.9 mm vs hex 1.1 mm.
    let (ns, nt) = (marker_centres_mm(&s).len(), marker_centres_mm(&t).len());
    assert!(ns > nt + 20, "{ns} vs {nt} dots");

    // With markers drawn, the difference-from-background masks still coincide: markers change
    // the image only inside the contact (where the surface tilts), on both sensors.
    let field = contact();
    let (cs, ct) = (
        changed(&render(&s, &fx, &field, 0), &bg_s, 24),
        changed(&render(&t, &fx, &field, 0), &bg_t, 24),
    );
    let overlap = iou(&shifted(&cs, camera_shift_px(&s, &t)), &ct);
    assert!(overlap > 0.7, "contact masks overlap only {overlap:.2}");
}
