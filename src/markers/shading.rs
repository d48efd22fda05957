//! How much the gel's shading has changed since the reference frame, on a grid of cells (the
//! trainer's D+S puts as many cells as the displacement field's over the whole view,
//! `train::data::SHADING_VIEW_MM`): the press the markers' in-plane motion does not show.
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
    /// Each cell's boxes (up to [`STEPS`]², those inside the image): its corners as offsets
    /// into the summed-area table, and the box's weight `1 / (area · boxes)`, so that a cell's
    /// tent mean is `Σ weight · (d + a − b − c)`.
    boxes: Vec<Tile>,
    /// Where each cell's boxes start in `boxes` (`cells + 1` entries).
    starts: Vec<usize>,
    /// The reference frame's mean colour over each window.
    reference: Vec<[f32; 3]>,
    /// Summed-area table of the frame being measured (reused): `(width + 1) · (height + 1)`
    /// entries of three channels, interleaved.
    sums: Vec<u32>,
}

/// One box of a cell's tent: its corners' offsets in the summed-area table (first channel)
/// and its weight.
#[derive(Debug, Clone, Copy)]
struct Tile {
    corners: [u32; 4],
    weight: f32,
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
        let lo = |c: f64, n: usize| ((c - side / 2.0).round().max(0.0) as usize).min(n);
        let hi = |c: f64, n: usize| ((c + side / 2.0).round().max(0.0) as usize).min(n);
        let stride = w + 1;
        let offset = |x: usize, y: usize| ((y * stride + x) * 3) as u32;
        let (mut boxes, mut starts) = (Vec::new(), vec![0]);
        for j in 0..spec.ny {
            for i in 0..spec.nx {
                let [cx, cy] = geom.mm_to_px(spec.cell_mm(i, j));
                let first = boxes.len();
                for oy in &offsets {
                    for ox in &offsets {
                        let (x, y) = (cx + ox, cy + oy);
                        let (x0, x1, y0, y1) = (lo(x, w), hi(x, w), lo(y, h), hi(y, h));
                        if x0 < x1 && y0 < y1 {
                            boxes.push(Tile {
                                corners: [
                                    offset(x0, y0),
                                    offset(x1, y0),
                                    offset(x0, y1),
                                    offset(x1, y1),
                                ],
                                weight: ((x1 - x0) * (y1 - y0)) as f32,
                            });
                        }
                    }
                }
                // Each box's weight: the mean over its area, then over the cell's boxes.
                let n = (boxes.len() - first) as f32;
                for b in &mut boxes[first..] {
                    b.weight = 1.0 / (b.weight * n);
                }
                starts.push(boxes.len());
            }
        }
        let mut s = Self {
            width: w,
            height: h,
            boxes,
            starts,
            reference: Vec::new(),
            sums: vec![0; stride * (h + 1) * 3],
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
                let d: f32 = (0..3).map(|c| (m[c] - r[c]).abs()).sum();
                d / base
            })
            .collect())
    }

    /// The tent-weighted mean colour about each cell: the mean of its boxes' means, boxes
    /// outside the image left out (a summed-area table: O(pixels + cells)). The table is
    /// exact in `u32` (at most 255 · 640 · 480 per channel); the weighting is in `f32`, whose
    /// rounding (about 1e-7 of a mean) is far below the 1/500 a level of the image holds.
    fn means(&mut self, img: &RgbImage) -> Vec<[f32; 3]> {
        let w = self.width;
        let row_len = (w + 1) * 3;
        let raw = img.as_raw();
        for (y, pixels) in raw.chunks_exact(w * 3).enumerate().take(self.height) {
            let (above, below) = self.sums[y * row_len..(y + 2) * row_len].split_at_mut(row_len);
            let mut run = [0u32; 3];
            for ((p, a), b) in pixels
                .chunks_exact(3)
                .zip(above[3..].chunks_exact(3))
                .zip(below[3..].chunks_exact_mut(3))
            {
                for c in 0..3 {
                    run[c] += u32::from(p[c]);
                    b[c] = a[c] + run[c];
                }
            }
        }
        let s = &self.sums;
        self.starts
            .windows(2)
            .map(|r| {
                let mut sum = [0.0f32; 3];
                for b in &self.boxes[r[0]..r[1]] {
                    let [a, bb, c, d] = b.corners.map(|o| o as usize);
                    for k in 0..3 {
                        // d + a − b − c ≥ 0: the box's sum (wrapping arithmetic, exact).
                        let v = s[d + k]
                            .wrapping_add(s[a + k])
                            .wrapping_sub(s[bb + k])
                            .wrapping_sub(s[c + k]);
                        sum[k] += v as f32 * b.weight;
                    }
                }
                sum
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
    fn a_uniform_change_reads_the_same_in_every_cell_of_a_large_frame() {
        // 640 × 480 (the largest frames, whose box sums are the largest): every level up by
        // 10 of 100 is a relative change of exactly 0.1, in the cells at the image's edge too
        // (their boxes clipped), to f32's rounding.
        let optics = OpticsConfig {
            width_px: 640,
            height_px: 480,
            mm_per_px: 0.015625,
            ..OpticsConfig::default()
        };
        let g = SensorGeometry::from_optics(&optics).unwrap();
        let spec = GridSpec::default();
        let reference = RgbImage::from_pixel(640, 480, image::Rgb([100, 100, 100]));
        let mut s = Shading::new(&reference, &g, &spec).unwrap();
        let f = s
            .field(&RgbImage::from_pixel(640, 480, image::Rgb([110, 90, 110])))
            .unwrap();
        assert_eq!(f.len(), spec.len());
        for v in f {
            assert!((v - 0.1).abs() < 1e-6, "{v}");
        }
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
