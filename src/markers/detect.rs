//! Finding the marker dots of one image, with sub-pixel centroids ([`Detector`]).

use image::RgbImage;

use super::{Polarity, SensorGeometry};

/// Smallest response that can be a marker, in luminance units of `R + G + B` (0..765): 40 is
/// 5 % of full scale, 13 8-bit levels a channel; about 12 σ of a camera with 2 levels of noise
/// (the response's noise is the sum of three channels', √3 · σ).
pub const FLOOR_LEVELS: f32 = 40.0;
/// The threshold's share of the dots' typical response.
const REL: f32 = 0.35;

/// One marker dot found in an image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    /// Centroid, pixels, `[column, row]` (pixel centres at whole numbers).
    pub px: [f64; 2],
    /// Pixels over the threshold.
    pub area_px: u32,
    /// Largest response in the dot, luminance units of `R + G + B` (0..765): its contrast.
    pub peak: f32,
}

/// A marker detector for one sensor, with its working buffers kept between frames (a frame then
/// allocates only its result).
///
/// # Method (O(pixels), a handful of operations per pixel)
///
/// 1. **Luminance** `Y = R + G + B` (0..765, integers: the box sums below are exact).
/// 2. **Local background** `B`: the mean of `Y` over a square window of half-width `k` around
///    each pixel, from integral images (a few lookups per pixel; windows clipped at the
///    border). `k` is half the marker spacing but at least the dot diameter: the window of any
///    pixel of a dot holds the whole dot and, on an undeformed lattice, no other. It is taken
///    twice: first over every pixel of the window, then over the window's *background* pixels
///    only (those whose first-pass response stays under half the first pass's threshold,
///    step 4), so the dots themselves do not darken it. Without the second pass a dot near the
///    border, whose clipped window holds a larger share of its own ink on the border side, had
///    its centroid pulled by up to 0.1 px. Smooth shading (the LEDs' ramp, a contact's slopes,
///    vignetting) is followed to first order: a box mean reproduces a linear ramp.
/// 3. **Response** `r = B − Y` for dark dots (`Y − B` for light ones): the dot's contrast
///    inside a dot, about zero on smooth gel.
/// 4. **Threshold** `t = max(FLOOR, REL · strength)`, `strength` the response that the top
///    `½ · fill` of the pixels reach (`fill` the share of the image the dots cover, from the
///    geometry): relative, so a dim camera's dots are found, with an absolute floor of
///    [`FLOOR_LEVELS`] so that a dot-free image (blank, black, flat gel) yields nothing rather
///    than its noise.
/// 5. **Connected components** (8-connected) of `r > t`, one flood fill over the image.
/// 6. **Centroid**: response-weighted (`max(r, 0)`) over the component and the pixels that
///    border it (its anti-aliased rim, below the threshold), so the weights follow each pixel's
///    dot coverage and the centroid is that of the dot's ink, to a few hundredths of a pixel.
/// 7. **Rejection**: a component that touches the image's outermost rows or columns (a dot cut
///    by the border: its centroid would be pulled inwards), whose area is outside
///    `[0.3, 3]` × the dot's expected area, or whose extent exceeds twice the dot's diameter
///    (plus 3 px) is not a marker.
#[derive(Debug, Clone)]
pub struct Detector {
    polarity: Polarity,
    /// Half-width of the background window, pixels.
    half: usize,
    /// Expected dot area, pixels.
    area_px: f64,
    /// Largest bounding-box side of a dot, pixels.
    max_extent: usize,
    /// Share of the image the dots cover.
    fill: f64,
    lum: Vec<u16>,
    /// Y where the first pass saw background (0 elsewhere), then 1 there (0 elsewhere).
    bg: Vec<u16>,
    /// Integral images (see [`integrate`]) of Y, of Y over the background pixels, and of the
    /// background pixels' count.
    integral: Vec<u32>,
    integral_bg: Vec<u32>,
    integral_n: Vec<u32>,
    response: Vec<f32>,
    label: Vec<u32>,
    stack: Vec<u32>,
}

/// The components' running sums.
#[derive(Debug, Clone, Copy)]
struct Blob {
    count: u32,
    peak: f32,
    u0: usize,
    u1: usize,
    v0: usize,
    v1: usize,
}

impl Detector {
    /// A detector for the sensor's dots. `geom` should pass [`SensorGeometry::check`]; values
    /// that do not are clamped to something harmless (the detector then finds little).
    pub fn new(geom: &SensorGeometry) -> Self {
        let finite = |v: f64, fallback: f64| if v.is_finite() { v } else { fallback };
        let dot = finite(geom.dot_px(), 2.0).clamp(1.0, 1024.0);
        let pitch = finite(geom.spacing_px(), 3.0 * dot).clamp(dot, 4096.0);
        let half = (0.5 * pitch).round().max(dot.ceil()).max(2.0) as usize;
        let r = dot / 2.0;
        let area_px = std::f64::consts::PI * r * r;
        Self {
            polarity: geom.polarity,
            half,
            area_px,
            max_extent: (2.0 * dot + 3.0).ceil() as usize,
            fill: (area_px / (pitch * pitch)).clamp(0.0, 1.0),
            lum: Vec::new(),
            bg: Vec::new(),
            integral: Vec::new(),
            integral_bg: Vec::new(),
            integral_n: Vec::new(),
            response: Vec::new(),
            label: Vec::new(),
            stack: Vec::new(),
        }
    }

    /// The marker dots of `img`, in the order of their top-left pixel (row by row). An image
    /// smaller than 3 × 3 px, or without dots, gives none.
    pub fn detect(&mut self, img: &RgbImage) -> Vec<Marker> {
        let (w, h) = (img.width() as usize, img.height() as usize);
        if w < 3 || h < 3 {
            return Vec::new();
        }
        self.respond(img, w, h);
        let t = self.threshold(w * h);
        let blobs = self.label(w, h, t);
        let mut out = Vec::new();
        for (k, b) in blobs.iter().enumerate() {
            let touches = b.u0 == 0 || b.v0 == 0 || b.u1 == w - 1 || b.v1 == h - 1;
            let count = f64::from(b.count);
            let sized = count >= (0.3 * self.area_px).max(3.0) && count <= 3.0 * self.area_px + 4.0;
            let compact = b.u1 - b.u0 < self.max_extent && b.v1 - b.v0 < self.max_extent;
            if touches || !sized || !compact {
                continue;
            }
            if let Some(px) = self.centroid(b, k as u32 + 1, w, h) {
                out.push(Marker {
                    px,
                    area_px: b.count,
                    peak: b.peak,
                });
            }
        }
        out
    }

    /// Steps 1–3: luminance, integral images, response (two passes: the second one's
    /// background leaves out the pixels the first found to be dots).
    fn respond(&mut self, img: &RgbImage, w: usize, h: usize) {
        let n = w * h;
        self.lum.clear();
        self.lum.extend(
            img.as_raw()
                .chunks_exact(3)
                .map(|p| u16::from(p[0]) + u16::from(p[1]) + u16::from(p[2])),
        );
        integrate(&mut self.integral, &self.lum, w, h);
        self.response.clear();
        self.response.resize(n, 0.0);
        self.box_response(w, h, false);
        // Dots of the first pass (and their rims, at half its threshold) are not background.
        let cut = 0.5 * self.threshold(n);
        self.bg.clear();
        self.bg.extend(
            self.lum
                .iter()
                .zip(&self.response)
                .map(|(&l, &r)| if r > cut { 0 } else { l }),
        );
        integrate(&mut self.integral_bg, &self.bg, w, h);
        self.bg.clear();
        self.bg
            .extend(self.response.iter().map(|&r| u16::from(r <= cut)));
        integrate(&mut self.integral_n, &self.bg, w, h);
        self.box_response(w, h, true);
    }

    /// `response = sign · (box mean − Y)`: the mean over the whole window, or (`masked`) over
    /// its background pixels (the whole window's where it has none).
    fn box_response(&mut self, w: usize, h: usize, masked: bool) {
        let w1 = w + 1;
        // (2k + 1)² · 765 < 2³² ⇔ 2k + 1 ≤ 2369: a window's sum fits in a u32.
        let k = self.half.min(1183);
        let sign = match self.polarity {
            Polarity::Dark => 1.0f32,
            Polarity::Light => -1.0,
        };
        // Each column's window bounds and the reciprocal of its width, once.
        let c0: Vec<usize> = (0..w).map(|u| u.saturating_sub(k)).collect();
        let c1: Vec<usize> = (0..w).map(|u| (u + k + 1).min(w)).collect();
        let inv_cols: Vec<f32> = c0
            .iter()
            .zip(&c1)
            .map(|(a, b)| 1.0 / (b - a) as f32)
            .collect();
        // Per row: the window's column sums, `bottom − top` of each integral image; a window's
        // sum is then the difference of two of them.
        let (mut all, mut bg, mut count) = (vec![0u32; w1], vec![0u32; w1], vec![0u32; w1]);
        for v in 0..h {
            let (a, b) = (v.saturating_sub(k), (v + k + 1).min(h));
            let inv_rows = 1.0 / (b - a) as f32;
            column_sums(&self.integral, a, b, w1, &mut all);
            let lum = &self.lum[v * w..(v + 1) * w];
            let out = &mut self.response[v * w..(v + 1) * w];
            let cols = c0.iter().zip(&c1).zip(&inv_cols);
            if masked {
                column_sums(&self.integral_bg, a, b, w1, &mut bg);
                column_sums(&self.integral_n, a, b, w1, &mut count);
                for ((o, &l), ((&c0, &c1), &inv)) in out.iter_mut().zip(lum).zip(cols) {
                    let n = count[c1].wrapping_sub(count[c0]);
                    let mean = if n > 0 {
                        bg[c1].wrapping_sub(bg[c0]) as f32 / n as f32
                    } else {
                        all[c1].wrapping_sub(all[c0]) as f32 * inv_rows * inv
                    };
                    *o = sign * (mean - f32::from(l));
                }
            } else {
                for ((o, &l), ((&c0, &c1), &inv)) in out.iter_mut().zip(lum).zip(cols) {
                    let mean = all[c1].wrapping_sub(all[c0]) as f32 * inv_rows * inv;
                    *o = sign * (mean - f32::from(l));
                }
            }
        }
    }

    /// Step 4: the threshold, from a histogram of the positive responses.
    fn threshold(&self, n: usize) -> f32 {
        let mut hist = [0u32; 766];
        for &r in &self.response {
            if r > 0.0 {
                hist[(r as usize).min(765)] += 1;
            }
        }
        let want = ((0.5 * self.fill).clamp(0.002, 0.1) * n as f64).ceil() as u64;
        let mut seen = 0u64;
        let mut strength = 0f32;
        for (level, &count) in hist.iter().enumerate().rev() {
            seen += u64::from(count);
            if seen >= want {
                strength = level as f32;
                break;
            }
        }
        (REL * strength).max(FLOOR_LEVELS)
    }

    /// Step 5: labels the 8-connected components of `response > t` (1, 2, …) and returns each
    /// one's bounds, count and peak.
    fn label(&mut self, w: usize, h: usize, t: f32) -> Vec<Blob> {
        let n = w * h;
        self.label.clear();
        self.label.resize(n, 0);
        let mut blobs = Vec::new();
        for start in 0..n {
            if self.label[start] != 0 || self.response[start] <= t {
                continue;
            }
            let id = blobs.len() as u32 + 1;
            let mut b = Blob {
                count: 0,
                peak: 0.0,
                u0: usize::MAX,
                u1: 0,
                v0: usize::MAX,
                v1: 0,
            };
            self.label[start] = id;
            self.stack.clear();
            self.stack.push(start as u32);
            while let Some(p) = self.stack.pop() {
                let p = p as usize;
                let (u, v) = (p % w, p / w);
                b.count += 1;
                b.peak = b.peak.max(self.response[p]);
                b.u0 = b.u0.min(u);
                b.u1 = b.u1.max(u);
                b.v0 = b.v0.min(v);
                b.v1 = b.v1.max(v);
                for vv in v.saturating_sub(1)..(v + 2).min(h) {
                    for uu in u.saturating_sub(1)..(u + 2).min(w) {
                        let q = vv * w + uu;
                        if self.label[q] == 0 && self.response[q] > t {
                            self.label[q] = id;
                            self.stack.push(q as u32);
                        }
                    }
                }
            }
            blobs.push(b);
        }
        blobs
    }

    /// Step 6: the response-weighted centroid over component `id` and its one-pixel rim.
    fn centroid(&self, b: &Blob, id: u32, w: usize, h: usize) -> Option<[f64; 2]> {
        let (u0, u1) = (b.u0.saturating_sub(1), (b.u1 + 1).min(w - 1));
        let (v0, v1) = (b.v0.saturating_sub(1), (b.v1 + 1).min(h - 1));
        let (mut sw, mut su, mut sv) = (0f64, 0f64, 0f64);
        for v in v0..=v1 {
            for u in u0..=u1 {
                let p = v * w + u;
                let own = match self.label[p] {
                    l if l == id => true,
                    0 => (v.saturating_sub(1)..(v + 2).min(h)).any(|vv| {
                        (u.saturating_sub(1)..(u + 2).min(w))
                            .any(|uu| self.label[vv * w + uu] == id)
                    }),
                    _ => false,
                };
                if own {
                    let r = f64::from(self.response[p].max(0.0));
                    sw += r;
                    su += r * u as f64;
                    sv += r * v as f64;
                }
            }
        }
        (sw > 0.0).then(|| [su / sw, sv / sw])
    }
}

/// Integral image of `values` (a `w × h` image), with a zero first row and column:
/// `out[v·(w+1) + u]` = Σ values over the rows above `v` and the columns left of `u`. It may
/// exceed 2³² on a large image (765 · 4096²), so it is kept modulo 2³² (wrapping): a box sum, a
/// difference of four entries, is still exact while the box's own sum is below 2³².
fn integrate(out: &mut Vec<u32>, values: &[u16], w: usize, h: usize) {
    let w1 = w + 1;
    out.clear();
    out.resize(w1 * (h + 1), 0);
    for (v, src) in values.chunks_exact(w).take(h).enumerate() {
        let (above, below) = out.split_at_mut((v + 1) * w1);
        let prev = &above[v * w1 + 1..(v + 1) * w1];
        let cur = &mut below[1..w1];
        let mut row = 0u32;
        for ((c, &p), &x) in cur.iter_mut().zip(prev).zip(src) {
            row = row.wrapping_add(u32::from(x));
            *c = p.wrapping_add(row);
        }
    }
}

/// Row `b` minus row `a` of an integral image with rows of `w1` entries: the sums of the rows
/// `a..b` over the columns left of each column.
fn column_sums(ii: &[u32], a: usize, b: usize, w1: usize, out: &mut [u32]) {
    let (top, bottom) = (&ii[a * w1..(a + 1) * w1], &ii[b * w1..(b + 1) * w1]);
    for ((o, &t), &bt) in out.iter_mut().zip(top).zip(bottom) {
        *o = bt.wrapping_sub(t);
    }
}

/// The marker dots of `img` for a sensor of geometry `geom` (see [`Detector`] for the method). Never panics: an empty, blank or black image gives
/// no markers. A [`Detector`] kept between frames saves the allocations.
pub fn detect(img: &RgbImage, geom: &SensorGeometry) -> Vec<Marker> {
    Detector::new(geom).detect(img)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rig_core::optics::OpticsConfig;

    fn geom() -> SensorGeometry {
        SensorGeometry::from_optics(&OpticsConfig::default()).unwrap()
    }

    /// A gel of `bg` with a ramp, and dots of radius `r` px drawn at `centres` with exact
    /// coverage (16 × 16 supersampling per pixel).
    fn draw(w: u32, h: u32, centres: &[[f64; 2]], r: f64, bg: f64, dot: f64) -> RgbImage {
        RgbImage::from_fn(w, h, |u, v| {
            let mut cov = 0.0;
            for cell in centres {
                for i in 0..16 {
                    for j in 0..16 {
                        let x = f64::from(u) - 0.5 + (i as f64 + 0.5) / 16.0;
                        let y = f64::from(v) - 0.5 + (j as f64 + 0.5) / 16.0;
                        if (x - cell[0]).hypot(y - cell[1]) <= r {
                            cov += 1.0 / 256.0;
                        }
                    }
                }
            }
            let base = bg + 0.0004 * f64::from(u) - 0.0003 * f64::from(v);
            let c = base + (dot - base) * cov;
            let q = (c * 255.0).round().clamp(0.0, 255.0) as u8;
            image::Rgb([q, q, q])
        })
    }

    #[test]
    fn a_drawn_dot_is_found_at_its_sub_pixel_centre() {
        let g = geom();
        let r = g.dot_px() / 2.0;
        let centres = [[40.3, 30.7], [70.55, 31.2], [41.0, 60.05], [69.81, 59.49]];
        let img = draw(110, 90, &centres, r, 0.45, 0.06);
        let found = detect(&img, &g);
        assert_eq!(found.len(), centres.len(), "{found:?}");
        for c in centres {
            let best = found
                .iter()
                .map(|m| (m.px[0] - c[0]).hypot(m.px[1] - c[1]))
                .fold(f64::INFINITY, f64::min);
            // 8-bit quantisation of the rim and the ramp under the dot: a few hundredths.
            assert!(
                best < 0.03,
                "dot at {c:?}: nearest centroid {best:.4} px away"
            );
        }
    }

    #[test]
    fn light_dots_are_found_with_light_polarity_only() {
        let g = SensorGeometry {
            polarity: Polarity::Light,
            ..geom()
        };
        let img = draw(80, 80, &[[39.4, 40.6]], g.dot_px() / 2.0, 0.25, 0.9);
        let found = detect(&img, &g);
        assert_eq!(found.len(), 1);
        assert!((found[0].px[0] - 39.4).abs() < 0.03 && (found[0].px[1] - 40.6).abs() < 0.03);
        assert!(detect(&img, &geom()).is_empty());
    }

    #[test]
    fn blank_black_tiny_and_cut_dots_give_nothing() {
        let g = geom();
        for img in [
            RgbImage::new(320, 240),
            RgbImage::from_pixel(320, 240, image::Rgb([120, 118, 125])),
            RgbImage::new(0, 0),
            RgbImage::new(2, 200),
        ] {
            assert!(detect(&img, &g).is_empty());
        }
        // A dot cut by the left border, a blob far too big, a speck far too small.
        let img = draw(100, 80, &[[1.0, 40.0]], 4.8, 0.45, 0.06);
        assert!(detect(&img, &g).is_empty());
        let img = draw(100, 80, &[[50.0, 40.0]], 15.0, 0.45, 0.06);
        assert!(detect(&img, &g).is_empty());
        let img = draw(100, 80, &[[50.0, 40.0]], 0.8, 0.45, 0.06);
        assert!(detect(&img, &g).is_empty());
    }
}
