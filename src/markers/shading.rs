//! How much the gel's shading has changed since the reference frame, on the same grid as the
//! displacement field: the press the markers' in-plane motion does not show.
//!
//! A nearly incompressible gel pressed straight down hardly moves its surface sideways, so the
//! displacement field carries little of the normal force; the shading of the pressed region
//! does. Each cell holds the relative change of the image's mean colour over a square window of
//! [`WINDOW_HALF_MM`] about the cell, against the reference frame's:
//! `Σ_c |m_c − m0_c| / Σ_c m0_c` over the three colour channels. The window is two millimetres
//! wide, wider than any sensor's marker pitch in use (0.6–1.2 mm), so the dots inside it are
//! about as many whether the gel has moved or not: their motion cancels and the shading stays.
//! Relative to the reference, the value does not depend on the LEDs' brightness; how strongly a
//! sensor's LEDs shade a given slope still does, which a sensor-independent input cannot know.

use image::RgbImage;

use super::{GridSpec, SensorGeometry};

/// How far from its cell the tent weight reaches, mm (it falls to zero there).
pub const WINDOW_HALF_MM: f64 = 1.0;

/// Boxes per side whose mean makes the tent.
const STEPS: usize = 4;

/// The reference frame's window means, and the windows, of one sensor and grid.
#[derive(Debug, Clone)]
pub struct Shading {
    width: usize,
    height: usize,
    /// Each cell's [`STEPS`]² boxes, pixels: `[x0, y0, x1, y1)`, clipped to the image (empty
    /// where a box lies outside it).
    windows: Vec<[usize; 4]>,
    /// The reference frame's mean colour over each window.
    reference: Vec<[f64; 3]>,
    /// Summed-area table of the frame being measured (reused).
    sums: Vec<[u32; 3]>,
}

impl Shading {
    /// The reference (no-contact) frame's window means on `spec`'s grid, centred on the image
    /// centre like [`super::Tracker::grid`].
    pub fn new(
        reference: &RgbImage,
        geom: &SensorGeometry,
        spec: &GridSpec,
    ) -> Result<Self, String> {
        geom.check()?;
        spec.check()?;
        if reference.dimensions() != (geom.width_px, geom.height_px) {
            return Err(format!(
                "the reference frame is {} × {} pixels; the sensor's optics say {} × {}",
                reference.width(),
                reference.height(),
                geom.width_px,
                geom.height_px
            ));
        }
        let (w, h) = (geom.width_px as usize, geom.height_px as usize);
        // Boxes of side w = WINDOW_HALF_MM centred at offsets spread evenly over ±w/2.
        let side = WINDOW_HALF_MM / geom.mm_per_px;
        let offsets: Vec<f64> = (0..STEPS)
            .map(|k| ((k as f64 + 0.5) / STEPS as f64 - 0.5) * side)
            .collect();
        let mut windows = Vec::with_capacity(spec.len() * STEPS * STEPS);
        let lo = |c: f64, n: usize| ((c - side / 2.0).round().max(0.0) as usize).min(n);
        let hi = |c: f64, n: usize| ((c + side / 2.0).round().max(0.0) as usize).min(n);
        for j in 0..spec.ny {
            for i in 0..spec.nx {
                let [cx, cy] = geom.mm_to_px(spec.cell_mm(i, j));
                for oy in &offsets {
                    for ox in &offsets {
                        let (x, y) = (cx + ox, cy + oy);
                        let (x0, x1, y0, y1) = (lo(x, w), hi(x, w), lo(y, h), hi(y, h));
                        windows.push(if x0 < x1 && y0 < y1 {
                            [x0, y0, x1, y1]
                        } else {
                            [0; 4]
                        });
                    }
                }
            }
        }
        let mut s = Self {
            width: w,
            height: h,
            windows,
            reference: Vec::new(),
            sums: vec![[0; 3]; (w + 1) * (h + 1)],
        };
        s.reference = s.means(reference);
        Ok(s)
    }

    /// The relative shading change of `frame` in each cell (row-major, as the grid); zero in a
    /// cell outside the image.
    pub fn field(&mut self, frame: &RgbImage) -> Result<Vec<f32>, String> {
        if frame.dimensions() != (self.width as u32, self.height as u32) {
            return Err(format!(
                "a frame of {} × {} pixels; the reference was {} × {}",
                frame.width(),
                frame.height(),
                self.width,
                self.height
            ));
        }
        let now = self.means(frame);
        Ok(now
            .iter()
            .zip(&self.reference)
            .map(|(m, r)| {
                let base = r[0] + r[1] + r[2];
                if base <= 0.0 {
                    return 0.0;
                }
                let d: f64 = (0..3).map(|c| (m[c] - r[c]).abs()).sum();
                (d / base) as f32
            })
            .collect())
    }

    /// The tent-weighted mean colour about each cell: the mean of its boxes' means, boxes
    /// outside the image left out (a summed-area table: O(pixels + cells)).
    fn means(&mut self, img: &RgbImage) -> Vec<[f64; 3]> {
        let (w, h) = (self.width, self.height);
        let stride = w + 1;
        let raw = img.as_raw();
        for y in 0..h {
            let mut row = [0u32; 3];
            for x in 0..w {
                let p = &raw[(y * w + x) * 3..][..3];
                for c in 0..3 {
                    row[c] += u32::from(p[c]);
                }
                let above = self.sums[y * stride + x + 1];
                self.sums[(y + 1) * stride + x + 1] =
                    [above[0] + row[0], above[1] + row[1], above[2] + row[2]];
            }
        }
        let s = &self.sums;
        let at = |x: usize, y: usize| s[y * stride + x];
        self.windows
            .chunks_exact(STEPS * STEPS)
            .map(|boxes| {
                let (mut sum, mut n) = ([0.0; 3], 0usize);
                for &[x0, y0, x1, y1] in boxes {
                    let area = (x1 - x0) * (y1 - y0);
                    if area == 0 {
                        continue;
                    }
                    let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
                    for k in 0..3 {
                        let v =
                            f64::from(d[k]) + f64::from(a[k]) - f64::from(b[k]) - f64::from(c[k]);
                        sum[k] += v / area as f64;
                    }
                    n += 1;
                }
                if n == 0 {
                    [0.0; 3]
                } else {
                    sum.map(|v| v / n as f64)
                }
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rig_core::optics::OpticsConfig;

    /// The simulated source sensor: 320 × 240 at 0.03125 mm/px, dots 9.6 px across on a
    /// 28.8 px lattice.
    fn geom() -> SensorGeometry {
        SensorGeometry::from_optics(&OpticsConfig::default()).unwrap()
    }

    /// A grey gel (0.75) with dark dots (0.2) on the sensor's lattice moved by `shift` px,
    /// brightened by `gain` inside a disc of `disc_mm` about the centre. A dot's pixels are
    /// those whose centre lies inside it.
    fn frame(g: &SensorGeometry, shift: [f64; 2], gain: f64, disc_mm: f64) -> RgbImage {
        let (p, r) = (g.spacing_px(), g.dot_px() / 2.0);
        let centre = [f64::from(g.width_px) / 2.0, f64::from(g.height_px) / 2.0];
        RgbImage::from_fn(g.width_px, g.height_px, |u, v| {
            let (x, y) = (f64::from(u) - shift[0], f64::from(v) - shift[1]);
            let (dx, dy) = (x - (x / p).round() * p, y - (y / p).round() * p);
            let mut c = if dx.hypot(dy) <= r { 0.2 } else { 0.75 };
            let d = (f64::from(u) - centre[0]).hypot(f64::from(v) - centre[1]) * g.mm_per_px;
            if d <= disc_mm {
                c *= gain;
            }
            let q = (c * 255.0).round().clamp(0.0, 255.0) as u8;
            image::Rgb([q, q, q])
        })
    }

    #[test]
    fn moving_markers_barely_register_and_a_shading_change_does() {
        let g = geom();
        let spec = GridSpec::default();
        let reference = frame(&g, [0.0, 0.0], 1.0, 0.0);
        let mut s = Shading::new(&reference, &g, &spec).unwrap();
        assert!(s.field(&reference).unwrap().iter().all(|&v| v == 0.0));

        // The gel moved by about half a pitch, no shading: the windows (2 mm, over two
        // pitches) hold about as many dots as before.
        let moved = s.field(&frame(&g, [13.0, -9.0], 1.0, 0.0)).unwrap();
        let residue = moved.iter().fold(0.0f32, |m, &v| m.max(v));
        assert!(residue < 0.02, "marker motion alone reads {residue}");

        // The central 2 mm shaded 20 % brighter, the markers where they were: the centre's
        // cells read the 20 % (a window of 2 mm lies inside the disc there), the far ones
        // nothing.
        let pressed = s.field(&frame(&g, [0.0, 0.0], 1.2, 2.0)).unwrap();
        let at = |x_mm: f64, y_mm: f64| {
            let i = ((x_mm / spec.spacing_mm) + (spec.nx as f64 - 1.0) / 2.0).round() as usize;
            let j = ((spec.ny as f64 - 1.0) / 2.0 - y_mm / spec.spacing_mm).round() as usize;
            pressed[j * spec.nx + i]
        };
        let c = at(0.25, 0.25);
        assert!((c - 0.2).abs() < 0.03, "centre {c}");
        let far = at(-3.75, 2.75);
        assert!(far < 1e-6, "far corner {far}");
        assert!(c > 10.0 * residue, "{c} against {residue}");
    }

    #[test]
    fn a_frame_of_another_size_is_an_error_not_a_panic() {
        let g = geom();
        let reference = frame(&g, [0.0, 0.0], 1.0, 0.0);
        let mut s = Shading::new(&reference, &g, &GridSpec::default()).unwrap();
        let small = RgbImage::new(160, 120);
        assert!(s.field(&small).unwrap_err().contains("160 × 120"));
        assert!(Shading::new(&small, &g, &GridSpec::default()).is_err());
    }
}
