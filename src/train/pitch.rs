//! Matching two sensors' marker pitches before translation.
//!
//! A CycleGAN translator carries the source's marker motion (shear) to the target's style only
//! when the two lattices are about as far apart in pixels: with sim-target's markers 22 % coarser
//! than the source's, the generator redraws the target's lattice as a fixed texture and no shear
//! crosses (docs/experiments.md, *The protocol's runs*). A lab knows both gels' marker spacing and
//! both cameras' scale, so the source's frames can be magnified by the ratio of the pitches before
//! the translator sees them. The price is geometry: a contact then looks that much larger in the
//! translated images than the same contact does on the target.

use std::path::Path;

use anyhow::Context;
use image::{Rgb, RgbImage};

use super::cyclegan::TranslateConfig;
use crate::record::manifest::Manifest;

/// The marker pitch of the recordings in `dir` as a fraction of the frame's width (spacing,
/// mm, over the width the camera sees, mm), from the rig config in the first run's manifest;
/// `None` when it does not say (a lab rig without `[optics.markers]`, or markers off).
pub fn marker_pitch(dir: &Path) -> anyhow::Result<Option<f64>> {
    let runs = super::data::find_runs(dir)?;
    let Some(run) = runs.first() else {
        return Ok(None);
    };
    let m = Manifest::load(run).map_err(anyhow::Error::msg)?;
    Ok(pitch_of(&m.config))
}

fn pitch_of(config: &serde_json::Value) -> Option<f64> {
    let optics = &config["optics"];
    if optics["effects"]["markers"].as_bool() == Some(false) {
        return None;
    }
    let spacing = optics["markers"]["spacing_mm"].as_f64()?;
    let mm_px = optics["mm_per_px"].as_f64()?;
    let width = optics["width_px"].as_f64()?;
    let pitch = spacing / (mm_px * width);
    (pitch.is_finite() && pitch > 0.0).then_some(pitch)
}

/// How many times the source's frames are magnified so that its markers lie as far apart in
/// the frame as the target's: the target's pitch over the source's.
pub fn pitch_zoom(source: &Path, target: &Path) -> anyhow::Result<f64> {
    let pitch = |dir: &Path, which: &str| {
        marker_pitch(dir)?.with_context(|| {
            format!(
                "matching marker pitches needs the {which} recordings' marker spacing and camera \
                 scale ([optics] mm_per_px, width_px and [optics.markers] spacing_mm in the rig \
                 config their manifest holds), and {} does not say them",
                dir.display()
            )
        })
    };
    let z = pitch(target, "target")? / pitch(source, "source")?;
    anyhow::ensure!(
        (0.25..=4.0).contains(&z),
        "the target's marker pitch is {z:.2} × the source's: too far apart to match by zooming"
    );
    Ok(z)
}

/// The zoom the translator's source frames take under `cfg`: 1 unless
/// [`TranslateConfig::match_marker_pitch`], else [`pitch_zoom`] (said on stderr).
pub fn source_zoom(cfg: &TranslateConfig, source: &Path, target: &Path) -> anyhow::Result<f64> {
    if !cfg.match_marker_pitch {
        return Ok(1.0);
    }
    let z = pitch_zoom(source, target)?;
    eprintln!(
        "      marker pitches matched: the source's frames magnified {z:.3} × for translation"
    );
    Ok(z)
}

/// `img` magnified `zoom` times about its centre, same size, bilinear. A zoom below 1 shrinks it,
/// and the border it leaves is filled with the mean colour of the image's edge pixels.
pub fn zoom_about_centre(img: &RgbImage, zoom: f64) -> RgbImage {
    let (w, h) = img.dimensions();
    if w == 0 || h == 0 || !(zoom.is_finite() && zoom > 0.0) {
        return img.clone();
    }
    let fill = edge_mean(img);
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    RgbImage::from_fn(w, h, |u, v| {
        // The output pixel's centre, back in the input's pixel coordinates.
        let x = (u as f64 + 0.5 - cx) / zoom + cx - 0.5;
        let y = (v as f64 + 0.5 - cy) / zoom + cy - 0.5;
        if x < -0.5 || y < -0.5 || x > w as f64 - 0.5 || y > h as f64 - 0.5 {
            return fill;
        }
        let (x, y) = (x.clamp(0.0, (w - 1) as f64), y.clamp(0.0, (h - 1) as f64));
        let (x0, y0) = (x.floor() as u32, y.floor() as u32);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let mut out = [0u8; 3];
        for (c, o) in out.iter_mut().enumerate() {
            let p = |a: u32, b: u32| img.get_pixel(a, b)[c] as f64;
            let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
            let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
            *o = (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8;
        }
        Rgb(out)
    })
}

fn edge_mean(img: &RgbImage) -> Rgb<u8> {
    let (w, h) = img.dimensions();
    let mut sum = [0f64; 3];
    let mut n = 0f64;
    for (u, v, p) in img.enumerate_pixels() {
        if u == 0 || v == 0 || u == w - 1 || v == h - 1 {
            for c in 0..3 {
                sum[c] += p[c] as f64;
            }
            n += 1.0;
        }
    }
    Rgb(sum.map(|s| (s / n.max(1.0)).round() as u8))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dark dot at `(x, y)` on a grey frame.
    fn dot(w: u32, h: u32, x: f64, y: f64) -> RgbImage {
        RgbImage::from_fn(w, h, |u, v| {
            let d = ((u as f64 + 0.5 - x).powi(2) + (v as f64 + 0.5 - y).powi(2)).sqrt();
            let g = if d < 3.0 { 20 } else { 200 };
            Rgb([g, g, g])
        })
    }

    /// Centroid of the dark pixels, in continuous pixel coordinates.
    fn dark_centroid(img: &RgbImage) -> (f64, f64) {
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for (u, v, p) in img.enumerate_pixels() {
            if p[0] < 110 {
                sx += u as f64 + 0.5;
                sy += v as f64 + 0.5;
                n += 1.0;
            }
        }
        (sx / n, sy / n)
    }

    #[test]
    fn zooming_moves_points_away_from_the_centre_by_the_factor() {
        // A dot 20 px right of and 10 px above the centre of 160 × 120 moves to 30 and 15 px
        // at a zoom of 1.5, and to 10 and 5 px at 0.5.
        let img = dot(160, 120, 100.0, 50.0);
        for (zoom, want) in [(1.5, (110.0, 45.0)), (0.5, (90.0, 55.0))] {
            let (x, y) = dark_centroid(&zoom_about_centre(&img, zoom));
            assert!(
                (x - want.0).abs() < 0.3 && (y - want.1).abs() < 0.3,
                "zoom {zoom}: dot at ({x:.2}, {y:.2}), want {want:?}"
            );
        }
    }

    #[test]
    fn a_zoom_of_one_leaves_the_image_as_it_is_and_a_shrunk_one_is_framed_in_the_edge_colour() {
        let img = dot(64, 48, 20.0, 30.0);
        assert_eq!(zoom_about_centre(&img, 1.0), img);
        let small = zoom_about_centre(&img, 0.5);
        // The outer quarter on each side lies outside the input: the edges' mean (grey).
        assert_eq!(*small.get_pixel(2, 2), Rgb([200, 200, 200]));
        assert_eq!(*small.get_pixel(61, 45), Rgb([200, 200, 200]));
        // Bad factors leave the image alone rather than panic.
        assert_eq!(zoom_about_centre(&img, 0.0), img);
        assert_eq!(zoom_about_centre(&img, f64::NAN), img);
    }

    #[test]
    fn the_pitch_is_the_spacing_over_the_width_the_camera_sees() {
        let config = |spacing: f64, mm_px: f64, markers: bool| {
            serde_json::json!({ "optics": {
                "mm_per_px": mm_px, "width_px": 320,
                "effects": { "markers": markers },
                "markers": { "spacing_mm": spacing },
            }})
        };
        // sim-source (0.9 mm over 10 mm) and sim-target (1.1 mm over 10 mm).
        let s = pitch_of(&config(0.9, 0.03125, true)).unwrap();
        let t = pitch_of(&config(1.1, 0.03125, true)).unwrap();
        assert!((s - 0.09).abs() < 1e-12 && (t / s - 1.1 / 0.9).abs() < 1e-12);
        // The same gel seen over a field 1.22 × wider: the pitch in the frame shrinks with it.
        let wide = pitch_of(&config(1.1, 0.03125 * 1.1 / 0.9, true)).unwrap();
        assert!((wide - s).abs() < 1e-12);
        assert_eq!(pitch_of(&config(0.9, 0.03125, false)), None);
        assert_eq!(pitch_of(&serde_json::json!({})), None);
    }
}
