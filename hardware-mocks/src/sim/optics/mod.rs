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
//! 4. **Markers** (effect). Dots are printed on the material: the dot at `c` is seen at
//!    `c + u(c)` (`u` the tangential displacement), and its disc is mapped by the local
//!    deformation `J = I + ∇u` (a pixel at `c + u(c) + J·d` shows the material offset `d`), so
//!    dots move and stretch with the surface, shear and slip included. Distances on the surface
//!    are measured with the slope (`√(|d|² + (∇h·d)²)`), so dots on the flanks of an
//!    indentation are seen foreshortened: the normal displacement distorts them.
//! 5. **Shadows** (effect). Where the raised (pressed) gel stands above the ray from a surface
//!    point towards an LED, that LED's light drops to 30 % (light scattered in the gel keeps
//!    shadows from being black); one sweep per LED finds every point's horizon.
//! 6. **Blur** (effect): separable Gaussian, σ in pixels (defocus, gel thickness).
//! 7. **Vignetting** (effect): brightness × `1 − v·(r/r_corner)²`.
//! 8. **Noise** (effect): Gaussian (an Irwin–Hall sum of four uniforms, bounded at ±3.25σ),
//!    σ in 8-bit levels, seeded: the same seed gives the same image.
//!
//! The image maps the surface frame onto pixels as a top view: pixel `(u, v)` is at
//! `o + R(θ)·((u + ½ − W/2)·mm_per_px, (H/2 − v − ½)·mm_per_px)` on the gel (row 0 is the
//! camera's +y), with `o` the camera's offset on the gel (`camera_offset_mm`) and `R(θ)` its
//! rotation about its axis (`camera_rotation_deg`). The LEDs sit in the camera's housing, so
//! their directions and the illumination ramp are in the camera's frame, and the surface's
//! gradient is turned into that frame before shading.
//!
//! # Cost
//!
//! A [`Renderer`] keeps everything that does not depend on the contact (see its docs), so an
//! untouched gel costs a copy, and a contact costs its own pixels: shading a few dozen
//! floating-point operations per pixel and LED (over planes of `f32`, vectorised), markers a
//! small box per dot, shadows one O(pixels) sweep per LED, blur `6σ + 1` taps per pass, noise
//! one random draw per four samples. `rig bench render` measures each effect on and off.

mod field;
mod markers;
mod noise;

use rig_core::optics::OpticsConfig;

use super::contact::SurfaceField;
use field::{Raster, Region};

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
/// non-finite values read as zero, and an image side of 0 gives an empty image. Builds a
/// [`Renderer`] for the one frame: a camera rendering many frames keeps one instead.
pub fn render(
    optics: &OpticsConfig,
    effects: &ImageEffects,
    field: &SurfaceField,
    noise_seed: u64,
) -> image::RgbImage {
    Renderer::new(optics, effects).render(field, noise_seed)
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
    let [x0, x1, y0, y1] = raster.gel_bounds(0.0);
    let (w, h) = (raster.width as f64, raster.height as f64);
    m.centres_in(x0, x1, y0, y1)
        .into_iter()
        .filter(|c| {
            let [u, v] = raster.px_of(c[0], c[1]);
            (-0.5..w - 0.5).contains(&u) && (-0.5..h - 0.5).contains(&v)
        })
        .collect()
}

/// Pixel position (column, row; fractional) of a surface-frame point, mm.
pub fn mm_to_px(optics: &OpticsConfig, p_mm: [f64; 2]) -> [f64; 2] {
    Raster::new(optics).px_of(p_mm[0], p_mm[1])
}

/// Largest tangential displacement a marker dot may have and still be drawn, mm: dots this far
/// outside the image are kept in case the gel carries them in.
const MARKER_REACH_MM: f64 = 3.0;

/// The work of rendering, by effect: an effect the scene does not ask for counts zero.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RenderStats {
    /// Frames rendered.
    pub frames: u64,
    /// Frames with a contact (the rest were the cached untouched gel).
    pub contact_frames: u64,
    /// Pixels shaded (pixel × LED).
    pub shaded_pixels: u64,
    /// Marker dots drawn moved by the gel.
    pub markers_drawn: u64,
    /// Shadow sweeps (one per LED and contact frame).
    pub shadow_sweeps: u64,
    /// Blur passes over a colour plane (two per plane and frame).
    pub blur_passes: u64,
    /// Frames darkened by the vignette.
    pub vignette_frames: u64,
    /// Noise samples drawn (one per pixel and channel).
    pub noise_samples: u64,
}

impl RenderStats {
    fn add(&mut self, o: &RenderStats) {
        self.frames += o.frames;
        self.contact_frames += o.contact_frames;
        self.shaded_pixels += o.shaded_pixels;
        self.markers_drawn += o.markers_drawn;
        self.shadow_sweeps += o.shadow_sweeps;
        self.blur_passes += o.blur_passes;
        self.vignette_frames += o.vignette_frames;
        self.noise_samples += o.noise_samples;
    }
}

/// One sensor's renderer: everything that does not depend on the contact (the LED directions,
/// the uneven background, the undeformed marker dots, the vignette, and the whole image of the
/// untouched gel) computed once, so a frame costs only the pixels the contact changes.
///
/// Work per frame, by effect (the effects a scene does not ask for cost nothing):
///
/// - an untouched gel (the field is flat, or changes no pixel by more than a small fraction of
///   an 8-bit level; see `field.rs`) is the cached image, plus noise when asked for;
/// - shading runs only over the pixels whose field cells change the image (and their shadows'
///   reach when shadows are on), one LED at a time over planes of `f32` (the loops vectorise);
/// - markers are drawn per dot, not per pixel: each dot is moved by the gel's tangential
///   displacement at its centre and deformed by the local displacement gradient (an affine
///   map, exact to first order over a dot's 0.1–0.2 mm), and foreshortened by the slope
///   (`√(|d|² + (∇h·d)²)`), then drawn with a one-pixel anti-aliased edge;
/// - blur, vignetting and noise run over the whole frame.
///
/// The working buffers are kept between frames (behind a lock; a second thread rendering at
/// the same moment allocates its own).
pub struct Renderer {
    raster: Raster,
    lights: Vec<Light>,
    gain: f32,
    spec: f32,
    effects: ImageEffects,
    /// The background with its illumination ramp, no markers: where shading starts (R, G, B
    /// planes).
    base: [Vec<f32>; 3],
    /// Undeformed dot centres (image plus [`MARKER_REACH_MM`]), radius, colour; when drawn.
    dots: Option<(Vec<[f64; 2]>, f64, [f32; 3])>,
    /// Per-pixel vignette factor, when on.
    vignette: Option<Vec<f32>>,
    /// The untouched gel after every effect but noise.
    flat: [Vec<f32>; 3],
    /// ... and as 8-bit pixels.
    flat_u8: image::RgbImage,
    scratch: std::sync::Mutex<Option<Scratch>>,
    totals: std::sync::Mutex<RenderStats>,
}

/// A frame's working buffers.
#[derive(Default)]
struct Scratch {
    px: field::PixelField,
    img: [Vec<f32>; 3],
    /// `1/‖(−∇h, 1)‖` of one row.
    nz: Vec<f32>,
    /// A row of ones (no shadow).
    lit: Vec<f32>,
    tmp: Vec<f32>,
}

impl std::fmt::Debug for Renderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Renderer")
            .field("width", &self.raster.width)
            .field("height", &self.raster.height)
            .field("effects", &self.effects)
            .finish_non_exhaustive()
    }
}

impl Renderer {
    pub fn new(optics: &OpticsConfig, effects: &ImageEffects) -> Self {
        let raster = Raster::new(optics);
        let (w, h) = (raster.width, raster.height);
        let lights = lights(optics);
        let gain = finite_or(optics.shading_gain, 0.0).max(0.0) as f32;
        let spec = finite_or(optics.specular, 0.0).max(0.0) as f32;

        // Background: base colour + a zero-mean ramp towards each LED.
        let colour = optics.background.rgb.map(|c| finite_or(c, 0.5) as f32);
        let uneven = finite_or(optics.background.uneven, 0.0).clamp(0.0, 1.0) as f32;
        let half_w = w as f64 / 2.0 * raster.mm_per_px;
        let half_h = h as f64 / 2.0 * raster.mm_per_px;
        let reach = (half_w * half_w + half_h * half_h).sqrt().max(1e-9);
        let mut base = [vec![0f32; w * h], vec![0f32; w * h], vec![0f32; w * h]];
        // The LEDs sit in the camera's housing: the ramp runs in the camera's frame.
        for v in 0..h {
            let y = raster.cam_y(v);
            for u in 0..w {
                let x = raster.cam_x(u);
                let mut c = colour;
                for l in &lights {
                    let ramp = (0.5 * (x * l.azimuth[0] + y * l.azimuth[1]) / reach) as f32;
                    for (ck, lk) in c.iter_mut().zip(l.rgb) {
                        *ck += uneven * lk * ramp;
                    }
                }
                for k in 0..3 {
                    base[k][v * w + u] = c[k];
                }
            }
        }

        let dots = effects
            .markers
            .then(|| markers::Markers::new(&optics.markers))
            .flatten()
            .map(|m| {
                let [x0, x1, y0, y1] = raster.gel_bounds(MARKER_REACH_MM);
                let centres = m.centres_in(x0, x1, y0, y1);
                let dot = optics.markers.rgb.map(|c| finite_or(c, 0.0) as f32);
                (centres, m.radius_mm(), dot)
            });

        let vignette = (effects.vignetting.is_finite() && effects.vignetting > 0.0).then(|| {
            let amount = effects.vignetting.min(1.0) as f32;
            let (cx, cy) = (w as f32 / 2.0, h as f32 / 2.0);
            let r2max = (cx * cx + cy * cy).max(f32::MIN_POSITIVE);
            let mut f = vec![1f32; w * h];
            for v in 0..h {
                for u in 0..w {
                    let (dx, dy) = (u as f32 + 0.5 - cx, v as f32 + 0.5 - cy);
                    f[v * w + u] = 1.0 - amount * (dx * dx + dy * dy) / r2max;
                }
            }
            f
        });

        let mut r = Self {
            raster,
            lights,
            gain,
            spec,
            effects: *effects,
            base,
            dots,
            vignette,
            flat: Default::default(),
            flat_u8: image::RgbImage::new(w as u32, h as u32),
            scratch: std::sync::Mutex::new(None),
            totals: std::sync::Mutex::new(RenderStats::default()),
        };
        let mut flat = r.base.clone();
        let mut tmp = Vec::new();
        let mut once = RenderStats::default();
        r.draw_dots(None, &mut flat, &mut once);
        r.finish(&mut flat, &mut tmp, &mut once);
        r.flat_u8 = quantize(&flat, w, h, 0.0, 0);
        r.flat = flat;
        r
    }

    /// The sensor image of `field`; frame noise from `noise_seed`.
    pub fn render(&self, field: &SurfaceField, noise_seed: u64) -> image::RgbImage {
        self.render_counted(field, noise_seed).0
    }

    /// Everything this renderer has done so far.
    pub fn stats(&self) -> RenderStats {
        *self.totals.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// [`Self::render`], and the work it did.
    pub fn render_counted(
        &self,
        field: &SurfaceField,
        noise_seed: u64,
    ) -> (image::RgbImage, RenderStats) {
        let mut st = RenderStats {
            frames: 1,
            ..RenderStats::default()
        };
        let img = self.render_inner(field, noise_seed, &mut st);
        self.totals
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .add(&st);
        (img, st)
    }

    fn render_inner(
        &self,
        field: &SurfaceField,
        noise_seed: u64,
        st: &mut RenderStats,
    ) -> image::RgbImage {
        let (w, h) = (self.raster.width, self.raster.height);
        let sigma = if self.effects.noise_sigma.is_finite() && self.effects.noise_sigma > 0.0 {
            self.effects.noise_sigma.min(255.0) as f32
        } else {
            0.0
        };
        if w == 0 || h == 0 {
            return image::RgbImage::new(w as u32, h as u32);
        }
        let mut sc = self
            .scratch
            .try_lock()
            .ok()
            .and_then(|mut s| s.take())
            .unwrap_or_default();
        field::resample_into(field, &self.raster, &mut sc.px);
        if sigma > 0.0 {
            st.noise_samples = (w * h * 3) as u64;
        }
        let out = if sc.px.flat {
            if sigma > 0.0 {
                quantize(&self.flat, w, h, sigma, noise_seed)
            } else {
                self.flat_u8.clone()
            }
        } else {
            st.contact_frames = 1;
            for k in 0..3 {
                sc.img[k].clear();
                sc.img[k].extend_from_slice(&self.base[k]);
            }
            let mut region = sc.px.region;
            let shadows = if self.effects.shadows {
                let (sh, reach) = shadow_factors(&self.raster, &sc.px, &self.lights);
                st.shadow_sweeps = self.lights.len() as u64;
                region = Region {
                    u0: region.u0.min(reach.u0),
                    u1: region.u1.max(reach.u1),
                    v0: region.v0.min(reach.v0),
                    v1: region.v1.max(reach.v1),
                };
                Some(sh)
            } else {
                None
            };
            st.shaded_pixels = (region.u1.saturating_sub(region.u0)
                * region.v1.saturating_sub(region.v0)
                * self.lights.len()) as u64;
            self.shade(&mut sc, region, shadows.as_deref());
            self.draw_dots(sc.px.cells.as_ref(), &mut sc.img, st);
            self.finish(&mut sc.img, &mut sc.tmp, st);
            quantize(&sc.img, w, h, sigma, noise_seed)
        };
        if let Ok(mut slot) = self.scratch.try_lock() {
            *slot = Some(sc);
        }
        out
    }

    /// Adds each LED's shading over `region`, row by row and one LED at a time.
    fn shade(&self, sc: &mut Scratch, region: Region, shadows: Option<&[Vec<f32>]>) {
        let w = self.raster.width;
        let (gain, spec) = (self.gain, self.spec);
        let len = region.u1.saturating_sub(region.u0);
        if len == 0 {
            return;
        }
        sc.lit.resize(len, 1.0);
        sc.nz.resize(len, 0.0);
        let Scratch {
            px, img, nz, lit, ..
        } = sc;
        let [ir, ig, ib] = img;
        for v in region.v0..region.v1 {
            let row = v * w + region.u0..v * w + region.u1;
            // Every slice exactly `len` long: the loops below index without checks.
            let (gx, gy) = (&px.gx[row.clone()], &px.gy[row.clone()]);
            let nz = &mut nz[..len];
            for ((n, &x), &y) in nz.iter_mut().zip(gx).zip(gy) {
                *n = 1.0 / (x * x + y * y + 1.0).sqrt();
            }
            let nz = &nz[..len];
            let (r, g, b) = (
                &mut ir[row.clone()],
                &mut ig[row.clone()],
                &mut ib[row.clone()],
            );
            for (li, l) in self.lights.iter().enumerate() {
                let s = &shadows.map_or(&lit[..], |sh| &sh[li][row.clone()])[..len];
                let [dx, dy, dz] = l.dir;
                let [hx, hy, hz] = l.half;
                let [lr, lg, lb] = l.rgb;
                let flat = gain * dz + spec * l.flat_spec;
                for i in 0..len {
                    let (nz, nx, ny) = (nz[i], -gx[i] * nz[i], -gy[i] * nz[i]);
                    let lambert = (nx * dx + ny * dy + nz * dz).max(0.0);
                    let nh = (nx * hx + ny * hy + nz * hz).max(0.0);
                    // nh⁴⁰ = nh³² · nh⁸ by squaring.
                    let n2 = nh * nh;
                    let n8 = (n2 * n2) * (n2 * n2);
                    let n32 = (n8 * n8) * (n8 * n8);
                    let term = s[i] * (gain * lambert + spec * (n32 * n8)) - flat;
                    r[i] += lr * term;
                    g[i] += lg * term;
                    b[i] += lb * term;
                }
            }
        }
    }

    /// Draws every marker dot, moved and deformed by `cells` (undeformed when `None`).
    fn draw_dots(
        &self,
        cells: Option<&field::CellField>,
        img: &mut [Vec<f32>; 3],
        st: &mut RenderStats,
    ) {
        let Some((centres, radius, dot)) = &self.dots else {
            return;
        };
        st.markers_drawn += centres.len() as u64;
        let (w, h) = (self.raster.width, self.raster.height);
        let s = self.raster.mm_per_px;
        for &c in centres {
            // Displacement u, its gradient J − I, and the slope g at the dot.
            let (mut centre, mut jac, mut slope) = (c, [[1.0, 0.0], [0.0, 1.0]], [0.0, 0.0]);
            if let Some(cells) = cells {
                let at = cells.sample(c[0], c[1]);
                let d = s.max(0.5 * radius);
                let (xp, xm) = (cells.sample(c[0] + d, c[1]), cells.sample(c[0] - d, c[1]));
                let (yp, ym) = (cells.sample(c[0], c[1] + d), cells.sample(c[0], c[1] - d));
                let g = |a: f32, b: f32| f64::from(a - b) / (2.0 * d);
                jac = [
                    [1.0 + g(xp[3], xm[3]), g(yp[3], ym[3])],
                    [g(xp[4], xm[4]), 1.0 + g(yp[4], ym[4])],
                ];
                centre = [c[0] + f64::from(at[3]), c[1] + f64::from(at[4])];
                slope = [f64::from(at[1]), f64::from(at[2])];
                let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
                let norm = jac.iter().flatten().map(|v| v.abs()).sum::<f64>();
                if !(det > 0.1 && norm < 8.0) {
                    // A fold or a wild gradient: not a field the solver makes; draw it moved
                    // but undistorted.
                    jac = [[1.0, 0.0], [0.0, 1.0]];
                }
            }
            let det = jac[0][0] * jac[1][1] - jac[0][1] * jac[1][0];
            let inv = [
                [jac[1][1] / det, -jac[0][1] / det],
                [-jac[1][0] / det, jac[0][0] / det],
            ];
            // Pixels the dot can cover: ‖J‖∞ · (r + one pixel) around its centre.
            let row_sum =
                (jac[0][0].abs() + jac[0][1].abs()).max(jac[1][0].abs() + jac[1][1].abs());
            // (A turned camera sees that gel box turned: its pixel box is up to √2 wider.)
            let turn = self.raster.rot[0].abs() + self.raster.rot[1].abs();
            let ext = turn * row_sum * (radius + s) / s;
            let [cu, cv] = self.raster.px_of(centre[0], centre[1]);
            if !(cu.is_finite() && cv.is_finite()) {
                continue;
            }
            let u0 = (cu - ext).floor().max(0.0) as usize;
            let u1 = ((cu + ext).ceil() + 1.0).clamp(0.0, w as f64) as usize;
            let v0 = (cv - ext).floor().max(0.0) as usize;
            let v1 = ((cv + ext).ceil() + 1.0).clamp(0.0, h as f64) as usize;
            for v in v0..v1 {
                let b = self.raster.cam_y(v);
                for u in u0..u1 {
                    let p = self.raster.gel_of_cam(self.raster.cam_x(u), b);
                    let (dx, dy) = (p[0] - centre[0], p[1] - centre[1]);
                    // The material offset from the dot's centre that this pixel shows.
                    let d = [
                        inv[0][0] * dx + inv[0][1] * dy,
                        inv[1][0] * dx + inv[1][1] * dy,
                    ];
                    let along = slope[0] * d[0] + slope[1] * d[1];
                    let dist = (d[0] * d[0] + d[1] * d[1] + along * along).sqrt();
                    // Linear ramp one pixel wide across the dot's edge: cheap anti-aliasing.
                    let cov = ((radius - dist) / s + 0.5).clamp(0.0, 1.0) as f32;
                    if cov > 0.0 {
                        let p = v * w + u;
                        for k in 0..3 {
                            img[k][p] += (dot[k] - img[k][p]) * cov;
                        }
                    }
                }
            }
        }
    }

    /// Blur and vignetting, over the whole frame.
    fn finish(&self, img: &mut [Vec<f32>; 3], tmp: &mut Vec<f32>, st: &mut RenderStats) {
        let (w, h) = (self.raster.width, self.raster.height);
        if self.effects.blur_sigma_px.is_finite() && self.effects.blur_sigma_px > 0.0 {
            let kernel: Vec<f32> = field::gaussian_kernel(self.effects.blur_sigma_px)
                .into_iter()
                .map(|k| k as f32)
                .collect();
            for plane in img.iter_mut() {
                blur(plane, w, h, &kernel, tmp);
                st.blur_passes += 2;
            }
        }
        if let Some(f) = &self.vignette {
            st.vignette_frames += 1;
            for plane in img.iter_mut() {
                plane.iter_mut().zip(f).for_each(|(c, f)| *c *= f);
            }
        }
    }
}

/// Linear colour planes to 8-bit pixels, with Gaussian noise of `sigma` levels from `seed`.
fn quantize(img: &[Vec<f32>; 3], w: usize, h: usize, sigma: f32, seed: u64) -> image::RgbImage {
    let mut out = vec![0u8; w * h * 3];
    // Round half up: `as` truncates (the floor, for x ≥ 0), saturates to 0..=255 and maps NaN
    // to 0.
    let level = |x: f32| (x * 255.0 + 0.5) as u8;
    if sigma > 0.0 {
        let mut gauss = noise::Gaussian::new(seed);
        let scale = sigma / 255.0;
        // Four normal numbers per draw, in byte order (byte i takes number i % 4 of draw i / 4):
        // three draws for every four pixels.
        let [r, g, b] = img;
        let n = w * h;
        let mut quads = out.chunks_exact_mut(12);
        for (k, o) in (&mut quads).enumerate() {
            let p = 4 * k;
            let mut z = [0f32; 12];
            for d in 0..3 {
                z[4 * d..4 * d + 4].copy_from_slice(&gauss.next_quad());
            }
            for j in 0..4 {
                o[3 * j] = level(r[p + j] + scale * z[3 * j]);
                o[3 * j + 1] = level(g[p + j] + scale * z[3 * j + 1]);
                o[3 * j + 2] = level(b[p + j] + scale * z[3 * j + 2]);
            }
        }
        // Up to three pixels left over: the same order, from as many draws as they need.
        let rest = quads.into_remainder();
        let first = n - rest.len() / 3;
        let mut z = [0f32; 12];
        for d in 0..rest.len().div_ceil(4) {
            z[4 * d..4 * d + 4].copy_from_slice(&gauss.next_quad());
        }
        for (i, o) in rest.iter_mut().enumerate() {
            *o = level(img[i % 3][first + i / 3] + scale * z[i]);
        }
    } else {
        for (p, o) in out.chunks_exact_mut(3).enumerate() {
            o[0] = level(img[0][p]);
            o[1] = level(img[1][p]);
            o[2] = level(img[2][p]);
        }
    }
    image::RgbImage::from_raw(w as u32, h as u32, out).expect("w·h·3 bytes")
}

fn finite_or(v: f64, fallback: f64) -> f64 {
    if v.is_finite() { v } else { fallback }
}

/// Per LED and pixel, the share of the LED's light that reaches the surface (1: lit), and the
/// pixels that are shadowed or raised (the field's region when nothing is).
///
/// The ray towards an LED rises `tan(elevation)` per unit of run; a point is shadowed by how
/// far the highest "horizon" along that ray, `H(p) = max_{t>0} (h(p + t·d) − t·rise)`, stands
/// above it (a soft edge of half a pixel: `occ = clamp((H − h)/soft, 0, 1)`). `H` comes from
/// one sweep per LED: with the step `d` scaled so that it crosses exactly one row (or column)
/// of pixels, `H(p) = max(h, H)(p + d) − |d|·rise`, read by linear interpolation on the
/// previous row (or column), which the sweep has already done. That is O(pixels) per LED,
/// where marching every ray was O(pixels × reach).
fn shadow_factors(
    raster: &Raster,
    px: &field::PixelField,
    lights: &[Light],
) -> (Vec<Vec<f32>>, Region) {
    let (w, h) = (raster.width, raster.height);
    let s = raster.mm_per_px;
    let mut reach = px.region;
    let mut out = Vec::with_capacity(lights.len());
    // `top[p]` = max(h, H) at p: the highest the ray from p or beyond it reaches.
    let mut top = vec![0f32; w * h];
    let height = &px.height_mm;
    let soft = (0.5 * s) as f32;
    for l in lights {
        let mut lit = vec![1f32; w * h];
        if px.max_height_mm <= 0.0 {
            out.push(lit);
            continue;
        }
        let tan_e = l.tan_elevation.max(1e-3);
        // Towards the LED in pixel units (rows grow towards −y).
        let (du, dv) = (l.azimuth[0], -l.azimuth[1]);
        let along_rows = du.abs() >= dv.abs();
        // Unit step along the dominant axis; the other coordinate moves by `slope`.
        let (major, slope) = if along_rows {
            (du.signum(), dv / du.abs())
        } else {
            (dv.signum(), du / dv.abs())
        };
        let rise = (tan_e * s * (1.0 + slope * slope).sqrt()) as f32;
        let slope = slope as f32;
        // Lines along the dominant axis's perpendicular: columns (stepping in u) or rows.
        let (n_major, n_minor) = if along_rows { (w, h) } else { (h, w) };
        let idx = |major_i: usize, minor_i: usize| {
            if along_rows {
                minor_i * w + major_i
            } else {
                major_i * w + minor_i
            }
        };
        // Sweep from the LED's side: the first line has nothing beyond it.
        let order: Vec<usize> = if major > 0.0 {
            (0..n_major).rev().collect()
        } else {
            (0..n_major).collect()
        };
        // The step lands `slope` along the previous line: between pixels k + k_off and
        // k + k_off + 1, at `frac` of the way (the same for every k).
        let k_off = slope.floor() as isize;
        let frac = slope - slope.floor();
        let mut prev: Option<usize> = None;
        for &m in &order {
            for k in 0..n_minor {
                let p = idx(m, k);
                let hp = height[p];
                let k0 = k as isize + k_off;
                let horizon = match prev {
                    Some(pm) if k0 >= 0 && (k0 as usize) < n_minor => {
                        let k0 = k0 as usize;
                        let a = top[idx(pm, k0)];
                        // Past the last pixel the line ends: its last value stands.
                        let b = if k0 + 1 < n_minor {
                            top[idx(pm, k0 + 1)]
                        } else {
                            a
                        };
                        a + (b - a) * frac - rise
                    }
                    _ => f32::NEG_INFINITY,
                };
                top[p] = hp.max(horizon);
                if horizon > hp {
                    let occ = ((horizon - hp) / soft).min(1.0);
                    lit[p] = 1.0 - (1.0 - SHADOW_FLOOR) * occ;
                    let (u, v) = (p % w, p / w);
                    reach = Region {
                        u0: reach.u0.min(u),
                        u1: reach.u1.max(u + 1),
                        v0: reach.v0.min(v),
                        v1: reach.v1.max(v + 1),
                    };
                }
            }
            prev = Some(m);
        }
        out.push(lit);
    }
    (out, reach)
}

/// Separable Gaussian blur of one plane in place, edges clamped; `tmp` is scratch.
fn blur(img: &mut [f32], w: usize, h: usize, kernel: &[f32], tmp: &mut Vec<f32>) {
    if kernel.len() == 1 || w == 0 || h == 0 {
        return;
    }
    let r = kernel.len() / 2;
    tmp.clear();
    tmp.resize(w * h, 0.0);
    // Along rows: tap by tap over the whole row (vectorises), the clamped edges apart.
    for v in 0..h {
        let src = &img[v * w..(v + 1) * w];
        let dst = &mut tmp[v * w..(v + 1) * w];
        for (t, &k) in kernel.iter().enumerate() {
            // dst[u] += k · src[clamp(u + t − r)]
            let lo = r.saturating_sub(t).min(w);
            let hi = (w + r).saturating_sub(t).min(w).max(lo);
            dst[..lo].iter_mut().for_each(|d| *d += k * src[0]);
            let off = t as isize - r as isize;
            for u in lo..hi {
                dst[u] += k * src[(u as isize + off) as usize];
            }
            dst[hi..].iter_mut().for_each(|d| *d += k * src[w - 1]);
        }
    }
    // Along columns: whole rows at a time.
    img.fill(0.0);
    for v in 0..h {
        let dst_start = v * w;
        for (t, &k) in kernel.iter().enumerate() {
            let vv = (v + t).saturating_sub(r).min(h - 1);
            let src = &tmp[vv * w..(vv + 1) * w];
            let dst = &mut img[dst_start..dst_start + w];
            dst.iter_mut().zip(src).for_each(|(d, s)| *d += k * s);
        }
    }
}
