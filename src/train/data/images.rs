//! Images as the networks see them: their size and modality ([`ImageSpec`]), the steps every
//! recorded or live frame takes to get there ([`prepare_image`]), and the zoom the
//! translator's source frames take when two sensors' marker pitches are matched
//! ([`zoom_about_centre`]).

use image::{Rgb, RgbImage};
use serde::{Deserialize, Serialize};

use crate::train::modality::{MarkerParams, Modality};

/// Images as the networks see them: RGB, `width × height`, one modality.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ImageSpec {
    pub width: u32,
    pub height: u32,
    pub modality: Modality,
}

impl ImageSpec {
    pub fn frame_bytes(&self) -> usize {
        self.width as usize * self.height as usize * 3
    }
}

/// The network's size first (triangle filter), then the modality, with `params` (marker sizes
/// in pixels of `img`) scaled to that size. Every image a force model sees, recorded, translated
/// or live, takes these same steps: a translated set is written at the network's size, so
/// deriving R and M there is the one way its images and the target's are made alike (deriving
/// them from the full frame before resizing made the target's M and R images differ from the
/// translated ones the TransForce models learnt from).
pub fn prepare_image(img: &image::RgbImage, spec: &ImageSpec, params: &MarkerParams) -> Vec<u8> {
    let resized;
    let small = if img.width() == spec.width && img.height() == spec.height {
        img
    } else {
        resized = image::imageops::resize(
            img,
            spec.width,
            spec.height,
            image::imageops::FilterType::Triangle,
        );
        &resized
    };
    let scale = spec.width as f32 / img.width().max(1) as f32;
    spec.modality.apply(small, &params.scaled(scale)).into_raw()
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
}
