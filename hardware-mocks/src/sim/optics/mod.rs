//! GelSight optics: turns the deformed gel surface into the image the sensor's camera sees.
//!
//! # Model
//!
//! A GelSight sensor images the back of a reflective membrane lit by coloured LEDs at grazing
//! angles (Johnson & Adelson 2009; Yuan, Dong & Adelson 2017). The renderer follows the
//! "normal map + shading + background + marker texture" family of simulators (Gomes et al.'s
//! Phong model, Taxim's background-plus-lookup; Si & Yuan 2022) with these stages, each a
//! function of the [`SurfaceField`] and the sensor's [`OpticsConfig`]:
//!
//! 1. **Geometry.** The camera sees the surface come towards it where the gel is pressed:
//!    height `h = −uz` (mm). The field is resampled bilinearly at every pixel centre; the
//!    gradient `∇h` is taken on the field's grid (central differences) and interpolated, and the
//!    unit normal is `n = (−∂h/∂x, −∂h/∂y, 1)/‖·‖`.
//! 2. **Shading.** Each LED `i` has colour `cᵢ` and a direction `Lᵢ` (azimuth, elevation). The
//!    colour added to the background is
//!    `Σᵢ cᵢ · [g·(sᵢ·max(0, n·Lᵢ) − Lᵢ,z) + k_s·(sᵢ·max(0, n·Hᵢ)^40 − Hᵢ,z^40)]`
//!    with `g` = `shading_gain`, `k_s` = `specular`, `Hᵢ` the Blinn half vector of `Lᵢ` and the
//!    view `(0, 0, 1)`, and `sᵢ` the shadow factor (1 without shadows). Subtracting the flat
//!    surface's terms makes an untouched gel render exactly as the background, and a slope
//!    facing an LED take that LED's colour: the GelSight colour-encodes-normal effect.
//! 3. **Background.** The flat gel's colour plus a linear brightness ramp towards each LED
//!    (`background.uneven` × its colour at the image's edge): uneven illumination. The same
//!    optics, effects and seed render an untouched gel as [`background`]: the reference frame a
//!    lab records before contact.
//! 4. **Markers** (effect). Dots are a texture on the material: pixel `p` shows the material
//!    point `X` with `X + u(X) = p` (two fixed-point steps `X ← p − u(X)`, `u` the tangential
//!    displacement), so dots move with the surface. Distances on the surface are measured with
//!    the slope (`√(|d|² + (∇h·d)²)`), so dots on the flanks of an indentation are seen
//!    foreshortened: the normal displacement distorts them.
//! 5. **Shadows** (effect). A ray from the surface towards each LED is marched over the height
//!    map; where the raised (pressed) gel blocks it, that LED's light drops to 30 % (light
//!    scattered in the gel keeps shadows from being black).
//! 6. **Blur** (effect): separable Gaussian, σ in pixels (defocus, gel thickness).
//! 7. **Vignetting** (effect): brightness × `1 − v·(r/r_corner)²`.
//! 8. **Noise** (effect): Gaussian, σ in 8-bit levels, seeded: the same seed gives the same
//!    image.
//!
//! The image maps the surface frame onto pixels as a top view: column `u` is at
//! `x = (u + ½ − W/2)·mm_per_px`, row `v` at `y = (H/2 − v − ½)·mm_per_px` (row 0 is +y).
//!
//! # Cost
//!
//! Shading is a few dozen floating-point operations per pixel; markers add nine distance
//! tests; shadows a ray march bounded by the indentation depth; blur `6σ + 1` taps per pass.
//! `rig bench render` measures each effect on and off.

mod field;
mod markers;
mod noise;

use rig_core::optics::OpticsConfig;

use super::contact::SurfaceField;
use field::Raster;

pub use super::scene::ImageEffects;
pub use field::geometric_field;

/// One LED, precomputed.
struct Light {
    rgb: [f32; 3],
    dir: [f32; 3],
    half: [f32; 3],
    flat_spec: f32,
    tan_elevation: f64,
    azimuth: [f64; 2],
}

const SPECULAR_EXPONENT: i32 = 40;
/// Share of an LED's light that still reaches a shadowed point (scattering in the gel).
const SHADOW_FLOOR: f32 = 0.3;

fn lights(optics: &OpticsConfig) -> Vec<Light> {
    optics
        .leds
        .iter()
        .filter(|l| {
            l.rgb.iter().all(|c| c.is_finite())
                && l.azimuth_deg.is_finite()
                && l.elevation_deg.is_finite()
        })
        .map(|l| {
            let (sa, ca) = l.azimuth_deg.to_radians().sin_cos();
            let el = l
                .elevation_deg
                .to_radians()
                .clamp(1e-3, std::f64::consts::FRAC_PI_2);
            let (se, ce) = el.sin_cos();
            let dir = [ce * ca, ce * sa, se];
            let h = [dir[0], dir[1], dir[2] + 1.0];
            let hn = (h[0] * h[0] + h[1] * h[1] + h[2] * h[2]).sqrt();
            let half = [h[0] / hn, h[1] / hn, h[2] / hn];
            Light {
                rgb: l.rgb.map(|c| c.max(0.0) as f32),
                dir: dir.map(|v| v as f32),
                half: half.map(|v| v as f32),
                flat_spec: (half[2] as f32).powi(SPECULAR_EXPONENT),
                tan_elevation: el.tan(),
                azimuth: [ca, sa],
            }
        })
        .collect()
}

/// Render the sensor image of a deformed gel surface.
///
/// Never panics on odd input: an empty or malformed field renders as an untouched gel,
/// non-finite values read as zero, and an image side of 0 gives an empty image.
pub fn render(
    optics: &OpticsConfig,
    effects: &ImageEffects,
    field: &SurfaceField,
    noise_seed: u64,
) -> image::RgbImage {
    let raster = Raster::new(optics);
    let pixels = field::resample(field, &raster);
    render_pixels(optics, effects, &raster, &pixels, noise_seed)
}

/// The untouched gel with the same optics, effects and noise seed: the reference ("background")
/// frame. `render` of a contact minus this is zero away from the contact.
pub fn background(
    optics: &OpticsConfig,
    effects: &ImageEffects,
    noise_seed: u64,
) -> image::RgbImage {
    render(optics, effects, &SurfaceField::default(), noise_seed)
}

/// Undeformed centres of the marker dots inside the image, mm in the surface frame (empty for a
/// sensor without markers).
pub fn marker_centres_mm(optics: &OpticsConfig) -> Vec<[f64; 2]> {
    let raster = Raster::new(optics);
    let Some(m) = markers::Markers::new(&optics.markers) else {
        return Vec::new();
    };
    let hx = raster.width as f64 / 2.0 * raster.mm_per_px;
    let hy = raster.height as f64 / 2.0 * raster.mm_per_px;
    m.centres_in(-hx, hx, -hy, hy)
}

/// Pixel position (column, row; fractional) of a surface-frame point, mm.
pub fn mm_to_px(optics: &OpticsConfig, p_mm: [f64; 2]) -> [f64; 2] {
    let r = Raster::new(optics);
    [
        p_mm[0] / r.mm_per_px + r.width as f64 / 2.0 - 0.5,
        r.height as f64 / 2.0 - 0.5 - p_mm[1] / r.mm_per_px,
    ]
}

fn render_pixels(
    optics: &OpticsConfig,
    effects: &ImageEffects,
    raster: &Raster,
    px: &field::PixelField,
    noise_seed: u64,
) -> image::RgbImage {
    let (w, h) = (raster.width, raster.height);
    let mut img = vec![[0f32; 3]; w * h];
    if w == 0 || h == 0 {
        return image::RgbImage::new(w as u32, h as u32);
    }
    let lights = lights(optics);
    let gain = finite_or(optics.shading_gain, 0.0).max(0.0) as f32;
    let spec = finite_or(optics.specular, 0.0).max(0.0) as f32;

    // Background: base colour + a zero-mean ramp towards each LED.
    let base = optics.background.rgb.map(|c| finite_or(c, 0.5) as f32);
    let uneven = finite_or(optics.background.uneven, 0.0).clamp(0.0, 1.0) as f32;
    let half_w = w as f64 / 2.0 * raster.mm_per_px;
    let half_h = h as f64 / 2.0 * raster.mm_per_px;
    let reach = (half_w * half_w + half_h * half_h).sqrt().max(1e-9);

    let shadows = if effects.shadows && !px.flat {
        Some(shadow_factors(raster, px, &lights))
    } else {
        None
    };

    for v in 0..h {
        let y = raster.y_mm(v);
        for u in 0..w {
            let x = raster.x_mm(u);
            let p = v * w + u;
            let mut c = base;
            for l in &lights {
                let ramp = (0.5 * (x * l.azimuth[0] + y * l.azimuth[1]) / reach) as f32;
                for (ck, lk) in c.iter_mut().zip(l.rgb) {
                    *ck += uneven * lk * ramp;
                }
            }
            if !px.flat {
                let [gx, gy] = px.grad[p];
                let inv = 1.0 / (gx * gx + gy * gy + 1.0).sqrt();
                let n = [-gx * inv, -gy * inv, inv];
                for (li, l) in lights.iter().enumerate() {
                    let s = shadows.as_ref().map_or(1.0, |sh| sh[li][p]);
                    let lambert = (n[0] * l.dir[0] + n[1] * l.dir[1] + n[2] * l.dir[2]).max(0.0);
                    let nh = (n[0] * l.half[0] + n[1] * l.half[1] + n[2] * l.half[2]).max(0.0);
                    let term = gain * (s * lambert - l.dir[2])
                        + spec * (s * nh.powi(SPECULAR_EXPONENT) - l.flat_spec);
                    for (ck, lk) in c.iter_mut().zip(l.rgb) {
                        *ck += lk * term;
                    }
                }
            }
            img[p] = c;
        }
    }

    if effects.markers
        && let Some(mut m) = markers::Markers::new(&optics.markers)
    {
        // Material points stay within the image plus the largest tangential displacement.
        let reach = px
            .shift_mm
            .iter()
            .map(|d| d[0].abs().max(d[1].abs()))
            .fold(0f32, f32::max)
            .min(50.0) as f64;
        m.cache_region(
            -half_w - reach,
            half_w + reach,
            -half_h - reach,
            half_h + reach,
        );
        let dot = optics.markers.rgb.map(|c| finite_or(c, 0.0) as f32);
        draw_markers(raster, px, &m, dot, &mut img);
    }
    if effects.blur_sigma_px.is_finite() && effects.blur_sigma_px > 0.0 {
        blur(&mut img, w, h, effects.blur_sigma_px);
    }
    if effects.vignetting.is_finite() && effects.vignetting > 0.0 {
        let v_amt = effects.vignetting.min(1.0) as f32;
        let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
        let r2max = cx * cx + cy * cy;
        for v in 0..h {
            for u in 0..w {
                let (dx, dy) = (u as f32 + 0.5 - cx, v as f32 + 0.5 - cy);
                let f = 1.0 - v_amt * (dx * dx + dy * dy) / r2max;
                img[v * w + u].iter_mut().for_each(|c| *c *= f);
            }
        }
    }
    let mut out = image::RgbImage::new(w as u32, h as u32);
    let sigma = if effects.noise_sigma.is_finite() && effects.noise_sigma > 0.0 {
        effects.noise_sigma.min(255.0) as f32
    } else {
        0.0
    };
    let mut gauss = noise::Gaussian::new(noise_seed);
    for (o, c) in out.pixels_mut().zip(&img) {
        for (ok, ck) in o.0.iter_mut().zip(c) {
            let mut level = ck * 255.0;
            if sigma > 0.0 {
                level += sigma * gauss.next() as f32;
            }
            *ok = level.round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

fn finite_or(v: f64, fallback: f64) -> f64 {
    if v.is_finite() { v } else { fallback }
}

fn draw_markers(
    raster: &Raster,
    px: &field::PixelField,
    m: &markers::Markers,
    dot: [f32; 3],
    img: &mut [[f32; 3]],
) {
    let (w, h) = (raster.width, raster.height);
    let s = raster.mm_per_px;
    // Shift at a surface point, from the nearest pixel (zero outside the image).
    let shift_at = |x: f64, y: f64| -> [f64; 2] {
        let u = (x / s + w as f64 / 2.0 - 0.5).round();
        let v = (h as f64 / 2.0 - 0.5 - y / s).round();
        if u < 0.0 || v < 0.0 || u >= w as f64 || v >= h as f64 {
            return [0.0, 0.0];
        }
        let d = px.shift_mm[v as usize * w + u as usize];
        [f64::from(d[0]), f64::from(d[1])]
    };
    for v in 0..h {
        let y = raster.y_mm(v);
        for u in 0..w {
            let x = raster.x_mm(u);
            let p = v * w + u;
            let (mut mx, mut my) = (x, y);
            if !px.flat {
                // Undo the tangential displacement: find X with X + u(X) = p.
                let d0 = px.shift_mm[p];
                mx = x - f64::from(d0[0]);
                my = y - f64::from(d0[1]);
                let d1 = shift_at(mx, my);
                mx = x - d1[0];
                my = y - d1[1];
            }
            let g = px.grad[p];
            let cov = m.coverage([mx, my], [f64::from(g[0]), f64::from(g[1])], s) as f32;
            if cov > 0.0 {
                let c = &mut img[p];
                for k in 0..3 {
                    c[k] += (dot[k] - c[k]) * cov;
                }
            }
        }
    }
}

/// Per LED and pixel, the share of the LED's light that reaches the surface (1: lit).
fn shadow_factors(raster: &Raster, px: &field::PixelField, lights: &[Light]) -> Vec<Vec<f32>> {
    let (w, h) = (raster.width, raster.height);
    let s = raster.mm_per_px;
    // Only pixels within a shadow's reach of the raised region can be shadowed.
    const RAISED_MM: f32 = 1e-3;
    let (mut u0, mut u1, mut v0, mut v1) = (usize::MAX, 0, usize::MAX, 0);
    for v in 0..h {
        for u in 0..w {
            if px.height_mm[v * w + u] > RAISED_MM {
                u0 = u0.min(u);
                u1 = u1.max(u);
                v0 = v0.min(v);
                v1 = v1.max(v);
            }
        }
    }
    let mut out = Vec::with_capacity(lights.len());
    for l in lights {
        let mut lit = vec![1f32; w * h];
        if u0 > u1 {
            out.push(lit);
            continue;
        }
        let tan_e = l.tan_elevation.max(1e-3);
        let reach_px = (f64::from(px.max_height_mm) / tan_e / s).ceil().min(1024.0) as usize;
        // Step along the light's azimuth in pixel units (rows grow towards −y).
        let (du, dv) = (l.azimuth[0], -l.azimuth[1]);
        let rise_per_px = (tan_e * s) as f32;
        let soft_mm = (0.5 * s) as f32;
        let lo_u = u0.saturating_sub(reach_px);
        let hi_u = (u1 + reach_px).min(w - 1);
        let lo_v = v0.saturating_sub(reach_px);
        let hi_v = (v1 + reach_px).min(h - 1);
        // Sample offsets along the ray, at most 48 per pixel: (column, row, rise in mm).
        let stride = (reach_px as f64 / 48.0).max(1.0);
        let offsets: Vec<(isize, isize, f32)> = (1..)
            .map(|k| k as f64 * stride)
            .take_while(|&t| t <= reach_px as f64 + stride)
            .map(|t| {
                (
                    (t * du).round() as isize,
                    (t * dv).round() as isize,
                    t as f32 * rise_per_px,
                )
            })
            .collect();
        for v in lo_v..=hi_v {
            for u in lo_u..=hi_u {
                let p = v * w + u;
                let h0 = px.height_mm[p];
                let headroom = px.max_height_mm - h0;
                if headroom <= RAISED_MM {
                    continue;
                }
                let mut occ = 0f32;
                for &(ou, ov, rise) in &offsets {
                    if rise > headroom + soft_mm {
                        break;
                    }
                    let (qu, qv) = (u as isize + ou, v as isize + ov);
                    if qu < 0 || qv < 0 || qu >= w as isize || qv >= h as isize {
                        break;
                    }
                    let hq = px.height_mm[qv as usize * w + qu as usize];
                    occ = occ.max(((hq - h0 - rise) / soft_mm).clamp(0.0, 1.0));
                    if occ >= 1.0 {
                        break;
                    }
                }
                lit[p] = 1.0 - (1.0 - SHADOW_FLOOR) * occ;
            }
        }
        out.push(lit);
    }
    out
}

/// Separable Gaussian blur in place, edges clamped.
fn blur(img: &mut [[f32; 3]], w: usize, h: usize, sigma: f64) {
    let kernel: Vec<f32> = field::gaussian_kernel(sigma)
        .into_iter()
        .map(|k| k as f32)
        .collect();
    if kernel.len() == 1 {
        return;
    }
    let r = kernel.len() / 2;
    let mut tmp = vec![[0f32; 3]; w * h];
    for v in 0..h {
        let row = &img[v * w..(v + 1) * w];
        for u in 0..w {
            let mut acc = [0f32; 3];
            for (t, k) in kernel.iter().enumerate() {
                let uu = (u + t).saturating_sub(r).min(w - 1);
                for c in 0..3 {
                    acc[c] += k * row[uu][c];
                }
            }
            tmp[v * w + u] = acc;
        }
    }
    for v in 0..h {
        for u in 0..w {
            let mut acc = [0f32; 3];
            for (t, k) in kernel.iter().enumerate() {
                let vv = (v + t).saturating_sub(r).min(h - 1);
                for c in 0..3 {
                    acc[c] += k * tmp[vv * w + u][c];
                }
            }
            img[v * w + u] = acc;
        }
    }
}
