//! The image modalities of the TransForce paper:
//! - R+M (`rgb+marker`): the image as captured;
//! - R (`rgb`): markers removed — a marker mask from grey morphology, then inpainting with
//!   Telea's fast-marching method (A. Telea, "An Image Inpainting Technique Based on the Fast
//!   Marching Method", Journal of Graphics Tools 9(1), 2004);
//! - M (`marker`): the markers alone, as the black-hat response (closing − image), bright dots on
//!   black.
//!
//! And one of ours, not the paper's:
//! - D (`flow`): the markers' displacement from the trajectory's first, no-contact frame, in
//!   millimetres on a fixed grid ([`crate::markers`]), drawn as an image: red and green are the
//!   x and y displacement about mid-grey ([`FLOW_LEVELS_PER_MM`]), blue mid-grey. It does not
//!   depend on the marker pitch, the LEDs or the camera's turn, so it carries from one sensor to
//!   another without translation. It needs the trajectory's frames in order:
//!   `data::FramePrep` makes it.
//! - D+S (`flow+shading`): D with the blue channel carrying how much the gel's shading has
//!   changed since the first frame ([`crate::markers::Shading`], [`SHADING_LEVELS`]; its cells
//!   span the whole view, D's the central 8 × 6 mm): the normal press, which the markers'
//!   in-plane motion hardly shows. Unlike D it depends on how strongly
//!   a sensor's LEDs shade a slope (×0.6 to ×2.7 of the source's on the simulated targets), so
//!   it carries normal force between sensors whose shading is alike, and D carries shear.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use image::{GrayImage, Luma, RgbImage};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Modality {
    #[serde(rename = "rgb+marker")]
    RgbMarker,
    #[serde(rename = "rgb")]
    Rgb,
    #[serde(rename = "marker")]
    Marker,
    #[serde(rename = "flow")]
    Flow,
    #[serde(rename = "flow+shading")]
    FlowShading,
}

/// Image levels per millimetre of marker displacement in a [`Modality::Flow`] image: ±1.27 mm
/// about mid-grey (128), 0.01 mm a level (a third of a pixel of the simulated sensors).
pub const FLOW_LEVELS_PER_MM: f64 = 100.0;

/// Blue levels per unit of relative shading change in a [`Modality::FlowShading`] image
/// ([`crate::markers::Shading`]): 0 is none, 255 a change of 51 %. The simulated sensors' deepest
/// presses reach 0.2–0.35 (0.86 on sim-third, whose dark gel makes any change large).
pub const SHADING_LEVELS: f64 = 500.0;

impl Modality {
    /// The paper's three image modalities.
    pub const ALL: [Modality; 3] = [Modality::RgbMarker, Modality::Rgb, Modality::Marker];
    /// Every modality a force model can read.
    pub const ANY: [Modality; 5] = [
        Modality::RgbMarker,
        Modality::Rgb,
        Modality::Marker,
        Modality::Flow,
        Modality::FlowShading,
    ];
    /// The marker-displacement method's modalities.
    pub const MARKERS: [Modality; 2] = [Modality::Flow, Modality::FlowShading];

    pub fn name(self) -> &'static str {
        match self {
            Modality::RgbMarker => "rgb+marker",
            Modality::Rgb => "rgb",
            Modality::Marker => "marker",
            Modality::Flow => "flow",
            Modality::FlowShading => "flow+shading",
        }
    }

    pub fn paper_name(self) -> &'static str {
        match self {
            Modality::RgbMarker => "R+M",
            Modality::Rgb => "R",
            Modality::Marker => "M",
            Modality::Flow => "D",
            Modality::FlowShading => "D+S",
        }
    }

    /// Whether one frame alone makes the network's image (the paper's modalities); marker
    /// displacement needs the trajectory's reference frame (`data::FramePrep`).
    pub fn per_frame(self) -> bool {
        !Self::MARKERS.contains(&self)
    }

    /// The modality's image of one frame. [`Modality::Flow`] and [`Modality::FlowShading`]
    /// cannot be made from one frame: they give mid-grey (no displacement); use
    /// `data::FramePrep`.
    pub fn apply(self, img: &RgbImage, p: &MarkerParams) -> RgbImage {
        match self {
            Modality::RgbMarker => img.clone(),
            Modality::Rgb => inpaint_telea(img, &marker_mask(img, p), p.inpaint_radius_px),
            Modality::Marker => marker_image(img, p),
            Modality::Flow | Modality::FlowShading => {
                RgbImage::from_pixel(img.width(), img.height(), image::Rgb([128; 3]))
            }
        }
    }
}

impl std::str::FromStr for Modality {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let t = s.trim().to_ascii_lowercase();
        Modality::ANY
            .into_iter()
            .find(|m| m.name() == t || m.paper_name().to_ascii_lowercase() == t)
            .ok_or_else(|| {
                format!(
                    "unknown modality {s:?}: use rgb+marker (R+M), rgb (R), marker (M), flow (D, marker displacement) or flow+shading (D+S, with the shading change)"
                )
            })
    }
}

impl std::fmt::Display for Modality {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Marker detection and removal settings, in pixels of the image they apply to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerParams {
    /// Radius of a marker dot.
    pub dot_radius_px: f32,
    /// A pixel is a marker where its black-hat response exceeds this fraction of the image's
    /// strongest response (and at least [`MIN_CONTRAST`]).
    pub threshold: f32,
    /// Neighbourhood the inpainting averages over.
    pub inpaint_radius_px: f32,
}

/// Black-hat responses below this (luminance, 0..1) are never markers: a dot-free image yields
/// an empty mask instead of amplified noise.
pub const MIN_CONTRAST: f32 = 0.04;

impl MarkerParams {
    pub fn for_dot_radius(r: f32) -> Self {
        let r = if r.is_finite() { r.max(0.5) } else { 4.8 };
        Self {
            dot_radius_px: r,
            threshold: 0.3,
            inpaint_radius_px: (r * 0.75).max(2.0),
        }
    }

    /// The same settings for the image resized by `factor` (dot and inpainting radii scale, the
    /// threshold stays); a factor that is not a positive number leaves them as they are.
    pub fn scaled(self, factor: f32) -> Self {
        if !(factor.is_finite() && factor > 0.0) {
            return self;
        }
        Self {
            threshold: self.threshold,
            ..Self::for_dot_radius(self.dot_radius_px * factor)
        }
    }

    /// Radius of the closing's structuring element: wider than a dot, so closing fills it.
    fn closing_radius(&self) -> usize {
        (self.dot_radius_px * 1.5 + 1.0).ceil() as usize
    }
}

impl Default for MarkerParams {
    /// Dots of 0.3 mm at 0.03125 mm/px: the simulated source sensor at 320 × 240.
    fn default() -> Self {
        Self::for_dot_radius(4.8)
    }
}

/// Rec. 709 luminance in 0..1.
pub fn luminance(img: &RgbImage) -> Vec<f32> {
    img.pixels()
        .map(|p| (0.2126 * p[0] as f32 + 0.7152 * p[1] as f32 + 0.0722 * p[2] as f32) / 255.0)
        .collect()
}

/// Half-widths of a disc of `radius`, row by row: row `dy` (−r..=r) covers `dx` in
/// `−a..=a` with `a = half[dy + r]`, exactly the integer points `dx² + dy² ≤ r²`.
fn disc_rows(radius: usize) -> Vec<usize> {
    let r = radius as isize;
    (-r..=r)
        .map(|dy| {
            (0..=r)
                .rev()
                .find(|dx| dx * dx + dy * dy <= r * r)
                .unwrap_or(0) as usize
        })
        .collect()
}

/// The max (or min) of each window `x−a..=x+a` of `row`, positions outside the row ignored:
/// van Herk (1992) / Gil and Werman (1993), three comparisons a pixel whatever `a`.
fn window_extreme(row: &[f32], a: usize, max: bool, out: &mut [f32]) {
    let pick = |p: f32, q: f32| if max { p.max(q) } else { p.min(q) };
    let fill = if max {
        f32::NEG_INFINITY
    } else {
        f32::INFINITY
    };
    let k = 2 * a + 1;
    // The row padded by `a` neutral values on each side, so every window is whole.
    let n = row.len() + 2 * a;
    let padded = |i: usize| {
        if i < a || i >= a + row.len() {
            fill
        } else {
            row[i - a]
        }
    };
    // g: running extreme from each block's start; h: from each block's end.
    let mut g = vec![fill; n];
    let mut h = vec![fill; n];
    for i in 0..n {
        g[i] = if i % k == 0 {
            padded(i)
        } else {
            pick(g[i - 1], padded(i))
        };
    }
    for i in (0..n).rev() {
        h[i] = if i % k == k - 1 || i == n - 1 {
            padded(i)
        } else {
            pick(h[i + 1], padded(i))
        };
    }
    // The window of output x is padded[x ..= x + 2a]: h at its start, g at its end.
    for (x, o) in out.iter_mut().enumerate() {
        *o = pick(h[x], g[x + 2 * a]);
    }
}

/// Grey dilation (`max`) or erosion (`min`) with a disc of `radius`; pixels outside the image
/// are ignored. The disc is taken row by row: a 1-D window extreme per distinct half-width
/// (each in constant time a pixel), then the extreme over the disc's rows. For the dots of a
/// GelSight image (radius ≈ 9 px) that is about 6× fewer operations than visiting the 253
/// points of the disc at every pixel, with the same result (max and min are exact).
fn morph(v: &[f32], w: usize, h: usize, radius: usize, max: bool) -> Vec<f32> {
    let half = disc_rows(radius);
    let mut widths = half.clone();
    widths.sort_unstable();
    widths.dedup();
    // rows[j][y * w + x]: the window extreme of half-width widths[j] along row y.
    let mut rows = vec![vec![0f32; v.len()]; widths.len()];
    for (j, &a) in widths.iter().enumerate() {
        for y in 0..h {
            window_extreme(
                &v[y * w..(y + 1) * w],
                a,
                max,
                &mut rows[j][y * w..(y + 1) * w],
            );
        }
    }
    let pick = |p: f32, q: f32| if max { p.max(q) } else { p.min(q) };
    let mut out = vec![
        if max {
            f32::NEG_INFINITY
        } else {
            f32::INFINITY
        };
        v.len()
    ];
    let r = radius as isize;
    for (i, &a) in half.iter().enumerate() {
        let dy = i as isize - r;
        let src = &rows[widths.binary_search(&a).expect("listed")];
        for y in 0..h {
            let yy = y as isize + dy;
            if yy < 0 || yy >= h as isize {
                continue;
            }
            let (o, s) = (&mut out[y * w..(y + 1) * w], &src[yy as usize * w..][..w]);
            for (o, &s) in o.iter_mut().zip(s) {
                *o = pick(*o, s);
            }
        }
    }
    out
}

/// closing(lum) − lum with a disc of `radius`: large where a dark feature narrower than the disc
/// sits on a brighter surround, near zero on smooth shading.
pub fn black_hat(lum: &[f32], w: usize, h: usize, radius: usize) -> Vec<f32> {
    if w * h == 0 || lum.len() != w * h {
        return vec![0.0; lum.len()];
    }
    let closed = morph(&morph(lum, w, h, radius, true), w, h, radius, false);
    closed
        .iter()
        .zip(lum)
        .map(|(c, l)| (c - l).max(0.0))
        .collect()
}

/// 255 where a marker is, 0 elsewhere (grown by one pixel to take in the dots' soft rims).
pub fn marker_mask(img: &RgbImage, p: &MarkerParams) -> GrayImage {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mut mask = GrayImage::new(img.width(), img.height());
    if w * h == 0 {
        return mask;
    }
    let bh = black_hat(&luminance(img), w, h, p.closing_radius());
    let peak = bh.iter().copied().fold(0.0, f32::max);
    let cut = (p.threshold * peak).max(MIN_CONTRAST);
    let core: Vec<bool> = bh.iter().map(|v| *v > cut).collect();
    for y in 0..h {
        for x in 0..w {
            let near = (y.saturating_sub(1)..(y + 2).min(h))
                .any(|yy| (x.saturating_sub(1)..(x + 2).min(w)).any(|xx| core[yy * w + xx]));
            if near {
                mask.put_pixel(x as u32, y as u32, Luma([255]));
            }
        }
    }
    mask
}

/// The markers alone: the black-hat response as grey (bright dots on black).
pub fn marker_image(img: &RgbImage, p: &MarkerParams) -> RgbImage {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let bh = black_hat(&luminance(img), w, h, p.closing_radius());
    let peak = bh
        .iter()
        .copied()
        .fold(0.0, f32::max)
        .max(MIN_CONTRAST * 2.0);
    let mut out = RgbImage::new(img.width(), img.height());
    for (i, px) in out.pixels_mut().enumerate() {
        let v = (bh[i] / peak * 255.0).round().clamp(0.0, 255.0) as u8;
        *px = image::Rgb([v, v, v]);
    }
    out
}

/// A connected region of a mask.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Component {
    pub pixels: usize,
    pub centroid: (f32, f32),
}

/// 8-connected regions of the non-zero pixels.
pub fn connected_components(mask: &GrayImage) -> Vec<Component> {
    let (w, h) = (mask.width() as usize, mask.height() as usize);
    let on = |x: usize, y: usize| mask.get_pixel(x as u32, y as u32)[0] > 0;
    let mut seen = vec![false; w * h];
    let mut out = Vec::new();
    for y0 in 0..h {
        for x0 in 0..w {
            if seen[y0 * w + x0] || !on(x0, y0) {
                continue;
            }
            let mut stack = vec![(x0, y0)];
            seen[y0 * w + x0] = true;
            let (mut n, mut sx, mut sy) = (0usize, 0f64, 0f64);
            while let Some((x, y)) = stack.pop() {
                n += 1;
                sx += x as f64;
                sy += y as f64;
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        if !seen[yy * w + xx] && on(xx, yy) {
                            seen[yy * w + xx] = true;
                            stack.push((xx, yy));
                        }
                    }
                }
            }
            out.push(Component {
                pixels: n,
                centroid: ((sx / n as f64) as f32, (sy / n as f64) as f32),
            });
        }
    }
    out
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Flag {
    Known,
    Band,
    Inside,
}

/// Heap entry ordered by smallest arrival time first.
#[derive(PartialEq)]
struct Entry(f32, usize);
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        other
            .0
            .total_cmp(&self.0)
            .then_with(|| other.1.cmp(&self.1))
    }
}

/// Telea (2004) inpainting: march inwards from the mask's boundary in order of distance, and fill
/// each pixel from the known pixels within `radius`, each extrapolated along its image gradient
/// and weighted by direction (alignment with the marching normal), geometric distance and
/// level-set distance. Pixels outside the mask are returned unchanged.
pub fn inpaint_telea(img: &RgbImage, mask: &GrayImage, radius: f32) -> RgbImage {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w * h == 0 || mask.dimensions() != img.dimensions() {
        return img.clone();
    }
    let masked = |i: usize| mask.as_raw()[i] > 0;
    if (0..w * h).all(masked) {
        return img.clone();
    }
    let mut val: Vec<[f32; 3]> = img
        .pixels()
        .map(|p| [p[0] as f32, p[1] as f32, p[2] as f32])
        .collect();
    let mut flag: Vec<Flag> = (0..w * h)
        .map(|i| if masked(i) { Flag::Inside } else { Flag::Known })
        .collect();
    let mut t = vec![f32::INFINITY; w * h];
    let mut heap = BinaryHeap::new();
    let nb4 = |i: usize| -> [Option<usize>; 4] {
        let (x, y) = (i % w, i / w);
        [
            (x > 0).then(|| i - 1),
            (x + 1 < w).then(|| i + 1),
            (y > 0).then(|| i - w),
            (y + 1 < h).then(|| i + w),
        ]
    };
    // The initial band: known pixels touching the mask, at distance 0.
    for i in 0..w * h {
        if flag[i] == Flag::Known {
            t[i] = 0.0;
            if nb4(i).iter().flatten().any(|&j| flag[j] == Flag::Inside) {
                flag[i] = Flag::Band;
                heap.push(Entry(0.0, i));
            }
        }
    }
    let r = radius.max(1.0);
    let ri = r.ceil() as isize;
    while let Some(Entry(_, i)) = heap.pop() {
        if flag[i] == Flag::Known {
            continue;
        }
        flag[i] = Flag::Known;
        for j in nb4(i).into_iter().flatten() {
            if flag[j] != Flag::Inside {
                continue;
            }
            t[j] = eikonal(j, w, h, &t, &flag);
            val[j] = fill(j, w, h, &val, &t, &flag, r, ri);
            flag[j] = Flag::Band;
            heap.push(Entry(t[j], j));
        }
    }
    let mut out = img.clone();
    for (i, p) in out.pixels_mut().enumerate() {
        if masked(i) {
            *p = image::Rgb(val[i].map(|v| v.round().clamp(0.0, 255.0) as u8));
        }
    }
    out
}

/// Arrival time at `i` from its known (or band) neighbours: the upwind solution of |∇T| = 1.
fn eikonal(i: usize, w: usize, h: usize, t: &[f32], flag: &[Flag]) -> f32 {
    let (x, y) = (i % w, i / w);
    let get = |ok: bool, j: usize| {
        if ok && flag[j] != Flag::Inside {
            t[j]
        } else {
            f32::INFINITY
        }
    };
    let a = get(x > 0, i.wrapping_sub(1)).min(get(x + 1 < w, i + 1));
    let b = get(y > 0, i.wrapping_sub(w)).min(get(y + 1 < h, i + w));
    match (a.is_finite(), b.is_finite()) {
        (true, true) if (a - b).abs() < 1.0 => (a + b + (2.0 - (a - b) * (a - b)).sqrt()) / 2.0,
        (true, _) | (_, true) => a.min(b) + 1.0,
        _ => 1.0,
    }
}

/// Central (or one-sided) difference of `f` at `i` along x and y, over pixels `usable` says.
fn gradient(
    i: usize,
    w: usize,
    h: usize,
    usable: &dyn Fn(usize) -> bool,
    f: &dyn Fn(usize) -> f32,
) -> (f32, f32) {
    let (x, y) = (i % w, i / w);
    let d = |lo: Option<usize>, hi: Option<usize>| -> f32 {
        let lo = lo.filter(|&j| usable(j));
        let hi = hi.filter(|&j| usable(j));
        match (lo, hi) {
            (Some(l), Some(u)) => (f(u) - f(l)) / 2.0,
            (None, Some(u)) if usable(i) => f(u) - f(i),
            (Some(l), None) if usable(i) => f(i) - f(l),
            _ => 0.0,
        }
    };
    (
        d((x > 0).then(|| i - 1), (x + 1 < w).then(|| i + 1)),
        d((y > 0).then(|| i - w), (y + 1 < h).then(|| i + w)),
    )
}

#[allow(clippy::too_many_arguments)]
fn fill(
    i: usize,
    w: usize,
    h: usize,
    val: &[[f32; 3]],
    t: &[f32],
    flag: &[Flag],
    r: f32,
    ri: isize,
) -> [f32; 3] {
    let (px, py) = ((i % w) as isize, (i / w) as isize);
    let finite_t = |j: usize| flag[j] != Flag::Inside && t[j].is_finite();
    let (gtx, gty) = gradient(i, w, h, &finite_t, &|j| t[j]);
    let gt_norm = (gtx * gtx + gty * gty).sqrt();
    let known = |j: usize| flag[j] == Flag::Known;
    let mut acc = [0f32; 3];
    let mut wsum = 0f32;
    for dy in -ri..=ri {
        for dx in -ri..=ri {
            let (qx, qy) = (px + dx, py + dy);
            if qx < 0 || qy < 0 || qx >= w as isize || qy >= h as isize {
                continue;
            }
            let q = qy as usize * w + qx as usize;
            let d2 = (dx * dx + dy * dy) as f32;
            if q == i || !known(q) || d2 > r * r {
                continue;
            }
            // r = p − q; weights as in Telea's paper (d0 = T0 = 1 pixel).
            let (rx, ry) = (-dx as f32, -dy as f32);
            let len = d2.sqrt();
            let dir = if gt_norm > 0.0 {
                ((rx * gtx + ry * gty) / (len * gt_norm)).abs().max(1e-3)
            } else {
                1.0
            };
            let dst = 1.0 / d2;
            let lev = 1.0 / (1.0 + (t[q] - t[i]).abs());
            let wt = dir * dst * lev;
            for c in 0..3 {
                let (gx, gy) = gradient(q, w, h, &known, &|j| val[j][c]);
                acc[c] += wt * (val[q][c] + gx * rx + gy * ry);
            }
            wsum += wt;
        }
    }
    if wsum > 0.0 {
        acc.map(|a| a / wsum)
    } else {
        // No known pixel in reach (cannot happen for r ≥ 1, as the marching neighbour is known):
        // keep the pixel's own value.
        val[i]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 160;
    const H: u32 = 120;
    const R: f32 = 4.0;

    /// A smooth background: a colour gradient with a broad bump (second derivatives ≤ 0.02 grey
    /// levels per px²).
    fn background(x: f32, y: f32) -> [f32; 3] {
        let bump =
            30.0 * (-((x - 70.0).powi(2) + (y - 50.0).powi(2)) / (2.0 * 45.0f32.powi(2))).exp();
        [
            110.0 + 0.4 * x + bump,
            90.0 + 0.3 * y + 0.5 * bump,
            150.0 - 0.2 * x + 0.1 * y,
        ]
    }

    fn centres() -> Vec<(f32, f32)> {
        // 9 × 7 dots, 17 px apart; the first column and row sit 5 px from the border.
        (0..7)
            .flat_map(|j| (0..9).map(move |i| (5.0 + 17.5 * i as f32, 5.0 + 18.0 * j as f32)))
            .collect()
    }

    /// Antialiased dark discs of radius R on the background (4 × 4 supersampling).
    fn dotted() -> (RgbImage, RgbImage) {
        let mut img = RgbImage::new(W, H);
        let mut bg = RgbImage::new(W, H);
        let dark = [25.0f32, 22.0, 30.0];
        for y in 0..H {
            for x in 0..W {
                let b = background(x as f32, y as f32);
                let mut cover = 0.0;
                for sy in 0..4 {
                    for sx in 0..4 {
                        let (fx, fy) = (
                            x as f32 + (sx as f32 + 0.5) / 4.0 - 0.5,
                            y as f32 + (sy as f32 + 0.5) / 4.0 - 0.5,
                        );
                        if centres()
                            .iter()
                            .any(|(cx, cy)| (fx - cx).powi(2) + (fy - cy).powi(2) <= R * R)
                        {
                            cover += 1.0 / 16.0;
                        }
                    }
                }
                let px: [u8; 3] =
                    std::array::from_fn(|c| (b[c] * (1.0 - cover) + dark[c] * cover).round() as u8);
                img.put_pixel(x, y, image::Rgb(px));
                bg.put_pixel(x, y, image::Rgb(b.map(|v| v.round() as u8)));
            }
        }
        (img, bg)
    }

    #[test]
    fn the_mask_recovers_every_dot_and_nothing_else() {
        let (img, bg) = dotted();
        let p = MarkerParams::for_dot_radius(R);
        let comps = connected_components(&marker_mask(&img, &p));
        let dots = centres();
        assert_eq!(comps.len(), dots.len(), "one component per dot");
        for (cx, cy) in &dots {
            let hits = comps
                .iter()
                .filter(|c| (c.centroid.0 - cx).abs() < 1.5 && (c.centroid.1 - cy).abs() < 1.5)
                .count();
            assert_eq!(hits, 1, "dot at ({cx}, {cy})");
        }
        let mask = marker_mask(&img, &p);
        for (cx, cy) in &dots {
            assert_eq!(
                mask.get_pixel(*cx as u32, *cy as u32)[0],
                255,
                "centre of ({cx}, {cy}) masked"
            );
        }
        // No dots, no mask.
        assert!(marker_mask(&bg, &p).pixels().all(|v| v[0] == 0));
    }

    #[test]
    fn inpainting_restores_the_background_under_the_dots() {
        let (img, bg) = dotted();
        let p = MarkerParams::for_dot_radius(R);
        let mask = marker_mask(&img, &p);
        let out = inpaint_telea(&img, &mask, p.inpaint_radius_px);
        let (mut sum, mut max, mut n) = (0.0f64, 0.0f64, 0usize);
        for (i, ((o, b), m)) in out.pixels().zip(bg.pixels()).zip(mask.pixels()).enumerate() {
            if m[0] == 0 {
                assert_eq!(
                    o,
                    img.get_pixel(i as u32 % W, i as u32 / W),
                    "unmasked pixels unchanged"
                );
                continue;
            }
            for c in 0..3 {
                let e = (o[c] as f64 - b[c] as f64).abs();
                sum += e;
                max = max.max(e);
                n += 1;
            }
        }
        let mae = sum / n as f64;
        eprintln!("inpainting over {n} masked values: MAE {mae:.3}, max {max} grey levels");
        // The background is nearly linear over a dot (curvature ≤ 0.02 levels/px², so a
        // first-order extrapolation over ≤ 5 px errs by < 0.5 levels), plus rounding to whole
        // levels in the input and output and a trace of the dark rim just outside the mask:
        // allow 1 level on average and 6 at worst (measured: 0.33 and 3).
        assert!(mae < 1.0, "MAE {mae:.2} grey levels");
        assert!(max <= 6.0, "max error {max} grey levels");
    }

    #[test]
    fn modalities_are_what_they_say() {
        let (img, bg) = dotted();
        let p = MarkerParams::for_dot_radius(R);
        assert_eq!(Modality::RgbMarker.apply(&img, &p), img);
        assert_eq!(
            Modality::Rgb.apply(&img, &p),
            inpaint_telea(&img, &marker_mask(&img, &p), p.inpaint_radius_px)
        );
        let m = Modality::Marker.apply(&img, &p);
        // Dot contrast follows the background (brighter under the bump), so the weakest dot is
        // about half as bright as the strongest; every one stands well above the background.
        for (cx, cy) in centres() {
            let v = m.get_pixel(cx as u32, cy as u32)[0];
            assert!(v > 100, "dot centre ({cx}, {cy}): {v}");
        }
        // Far from any dot (between columns and rows) the marker image is dark.
        assert!(m.get_pixel(14, 14)[0] < 20);
        assert!(Modality::Marker.apply(&bg, &p).pixels().all(|v| v[0] < 60));
    }

    /// The point-by-point definition: the extreme over every point of the disc inside the
    /// image.
    fn morph_by_points(v: &[f32], w: usize, h: usize, radius: usize, max: bool) -> Vec<f32> {
        let r = radius as isize;
        let mut out = vec![0.0; v.len()];
        for y in 0..h as isize {
            for x in 0..w as isize {
                let mut acc = if max {
                    f32::NEG_INFINITY
                } else {
                    f32::INFINITY
                };
                for dy in -r..=r {
                    for dx in -r..=r {
                        let (xx, yy) = (x + dx, y + dy);
                        if dx * dx + dy * dy > r * r
                            || xx < 0
                            || yy < 0
                            || xx >= w as isize
                            || yy >= h as isize
                        {
                            continue;
                        }
                        let s = v[(yy * w as isize + xx) as usize];
                        acc = if max { acc.max(s) } else { acc.min(s) };
                    }
                }
                out[(y * w as isize + x) as usize] = acc;
            }
        }
        out
    }

    #[test]
    fn row_decomposed_morphology_equals_the_disc_definition() {
        // Sizes smaller and larger than the disc, radii 0..=9 (the product's is 9).
        for (w, h) in [(1, 1), (3, 2), (17, 11), (40, 23)] {
            let v: Vec<f32> = (0..w * h)
                .map(|i| ((i * 7919) % 101) as f32 / 101.0)
                .collect();
            for radius in [0, 1, 2, 4, 9] {
                for max in [true, false] {
                    assert_eq!(
                        morph(&v, w, h, radius, max),
                        morph_by_points(&v, w, h, radius, max),
                        "{w}×{h}, radius {radius}, max {max}"
                    );
                }
            }
        }
    }

    #[test]
    fn degenerate_inputs_do_not_panic() {
        let p = MarkerParams::default();
        let empty = RgbImage::new(0, 0);
        for m in Modality::ALL {
            assert_eq!(m.apply(&empty, &p).dimensions(), (0, 0));
        }
        let one = RgbImage::from_pixel(1, 1, image::Rgb([9, 8, 7]));
        for m in Modality::ALL {
            assert_eq!(m.apply(&one, &p).dimensions(), (1, 1));
        }
        // Everything masked: nothing to fill from, the input comes back.
        let img = RgbImage::from_pixel(5, 4, image::Rgb([100, 50, 25]));
        let all = GrayImage::from_pixel(5, 4, Luma([255]));
        assert_eq!(inpaint_telea(&img, &all, 3.0), img);
        // One known pixel fills the rest.
        let mut most = all.clone();
        most.put_pixel(0, 0, Luma([0]));
        let out = inpaint_telea(&img, &most, 3.0);
        assert!(out.pixels().all(|p| *p == image::Rgb([100, 50, 25])));
        // A mask of another size is ignored.
        assert_eq!(inpaint_telea(&img, &GrayImage::new(2, 2), 3.0), img);
        assert_eq!(MarkerParams::for_dot_radius(f32::NAN).dot_radius_px, 4.8);
    }

    #[test]
    fn modality_names_parse() {
        for (s, m) in [
            ("rgb", Modality::Rgb),
            ("R", Modality::Rgb),
            ("marker", Modality::Marker),
            ("M", Modality::Marker),
            ("rgb+marker", Modality::RgbMarker),
            ("R+M", Modality::RgbMarker),
        ] {
            assert_eq!(s.parse::<Modality>().unwrap(), m);
        }
        let e = "xyz".parse::<Modality>().unwrap_err();
        assert!(e.contains("rgb+marker") && e.contains("marker (M)"), "{e}");
    }
}
