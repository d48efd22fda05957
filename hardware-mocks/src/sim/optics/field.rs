//! Surface fields as the renderer needs them: the image's pixel grid over the gel ([`Raster`]),
//! the fields resampled onto it, and a purely geometric field for tests and previews.

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;

use super::super::contact::SurfaceField;

/// The pixel grid of an image over the gel.
pub(crate) struct Raster {
    pub width: usize,
    pub height: usize,
    pub mm_per_px: f64,
}

impl Raster {
    pub(crate) fn new(optics: &OpticsConfig) -> Self {
        let side = |v: u32| (v.min(rig_core::optics::MAX_SIDE_PX)) as usize;
        let mm_per_px = if optics.mm_per_px.is_finite() && optics.mm_per_px > 0.0 {
            optics.mm_per_px
        } else {
            OpticsConfig::default().mm_per_px
        };
        Self {
            width: side(optics.width_px),
            height: side(optics.height_px),
            mm_per_px,
        }
    }

    pub fn x_mm(&self, u: usize) -> f64 {
        (u as f64 + 0.5 - self.width as f64 / 2.0) * self.mm_per_px
    }

    pub fn y_mm(&self, v: usize) -> f64 {
        (self.height as f64 / 2.0 - v as f64 - 0.5) * self.mm_per_px
    }
}

/// The gel surface at every pixel, in the camera's view: `height_mm` is how far the surface
/// has come towards the camera (`−uz`, ≥ 0 where pressed), `grad` its gradient, `shift` the
/// tangential displacement (ux, uy).
pub(crate) struct PixelField {
    pub height_mm: Vec<f32>,
    pub grad: Vec<[f32; 2]>,
    pub shift_mm: Vec<[f32; 2]>,
    /// Largest height anywhere, mm (bounds the shadow ray march).
    pub max_height_mm: f32,
    /// Whether the field is flat and still (every value zero): the renderer can skip work.
    pub flat: bool,
}

/// The two cells either side of fractional cell index `f` on an axis of `n` cells, and the
/// weight of the second; `None` when `f` lies more than half a cell outside the axis.
fn bracket(f: f64, n: usize) -> Option<(usize, usize, f32)> {
    if f < -0.5 || f > n as f64 - 0.5 {
        return None;
    }
    let f = f.clamp(0.0, (n - 1) as f64);
    let i0 = (f.floor() as usize).min(n.saturating_sub(2));
    let t = if n < 2 { 0.0 } else { (f - i0 as f64) as f32 };
    Some((i0, (i0 + 1).min(n - 1), t))
}

/// Resamples `field` (bilinear; zero outside its grid, non-finite values read as zero) at the
/// pixel centres of `raster`. Gradients are taken on the field's own grid by central
/// differences and then interpolated, so a coarse field still shades smoothly.
pub(crate) fn resample(field: &SurfaceField, raster: &Raster) -> PixelField {
    let n = raster.width * raster.height;
    let usable = field.nx > 0
        && field.ny > 0
        && field.cell_mm.is_finite()
        && field.cell_mm > 0.0
        && field.origin_mm.iter().all(|v| v.is_finite())
        && [&field.uz_mm, &field.ux_mm, &field.uy_mm]
            .iter()
            .all(|v| v.len() == field.nx * field.ny);
    if !usable {
        return PixelField {
            height_mm: vec![0.0; n],
            grad: vec![[0.0; 2]; n],
            shift_mm: vec![[0.0; 2]; n],
            max_height_mm: 0.0,
            flat: true,
        };
    }
    let (nx, ny, cell) = (field.nx, field.ny, field.cell_mm);
    let clean = |v: f64| if v.is_finite() { v as f32 } else { 0.0 };
    // Per cell: height (−uz), dh/dx, dh/dy, ux, uy.
    let h: Vec<f32> = field.uz_mm.iter().map(|&u| -clean(u)).collect();
    let mut cells = vec![[0f32; 5]; nx * ny];
    let mut flat = true;
    for j in 0..ny {
        for i in 0..nx {
            let k = j * nx + i;
            let at = |ii: usize, jj: usize| h[jj * nx + ii];
            let dx = if nx < 2 {
                0.0
            } else {
                let (a, b) = (i.saturating_sub(1), (i + 1).min(nx - 1));
                (at(b, j) - at(a, j)) / ((b - a) as f32 * cell as f32)
            };
            let dy = if ny < 2 {
                0.0
            } else {
                let (a, b) = (j.saturating_sub(1), (j + 1).min(ny - 1));
                (at(i, b) - at(i, a)) / ((b - a) as f32 * cell as f32)
            };
            let c = [h[k], dx, dy, clean(field.ux_mm[k]), clean(field.uy_mm[k])];
            flat &= c.iter().all(|&v| v == 0.0);
            cells[k] = c;
        }
    }
    let mut out = PixelField {
        height_mm: vec![0.0; n],
        grad: vec![[0.0; 2]; n],
        shift_mm: vec![[0.0; 2]; n],
        max_height_mm: 0.0,
        flat,
    };
    if flat {
        return out;
    }
    let inv_cell = 1.0 / cell;
    for v in 0..raster.height {
        let y = raster.y_mm(v);
        let Some((j0, j1, ty)) = bracket((y - field.origin_mm[1]) * inv_cell, ny) else {
            continue;
        };
        for u in 0..raster.width {
            let x = raster.x_mm(u);
            let Some((i0, i1, tx)) = bracket((x - field.origin_mm[0]) * inv_cell, nx) else {
                continue;
            };
            let (a, b, c, d) = (
                &cells[j0 * nx + i0],
                &cells[j0 * nx + i1],
                &cells[j1 * nx + i0],
                &cells[j1 * nx + i1],
            );
            let mut s = [0f32; 5];
            for q in 0..5 {
                let top = a[q] + (b[q] - a[q]) * tx;
                let bottom = c[q] + (d[q] - c[q]) * tx;
                s[q] = top + (bottom - top) * ty;
            }
            let p = v * raster.width + u;
            out.height_mm[p] = s[0];
            out.grad[p] = [s[1], s[2]];
            out.shift_mm[p] = [s[3], s[4]];
            out.max_height_mm = out.max_height_mm.max(s[0]);
        }
    }
    out
}

/// A geometric stand-in for the contact solver, for tests and previews: the gel takes the
/// indenter's shape where they overlap, with an elastic-looking skirt around the contact, and
/// sticks to the indenter under shear.
///
/// - Normal: `uz = −max(o, G_σ ∗ o)`, `o = max(0, depth − gap)` the overlap of the undeformed gel
///   with the indenter at its sheared position and `G_σ` a Gaussian of σ = `skirt_mm`, so the
///   surface conforms inside the contact and sinks in smoothly around it.
/// - Tangential: `u = shear · max(c, G_σ' ∗ c)` with `c` the contact indicator and σ' = 2σ:
///   full stick inside the contact, decaying outside (as a Cerruti-like far field does).
/// - Pressure: a Winkler layer, `p = M o / h` with `M = E(1−ν)/((1+ν)(1−2ν))`; traction zero.
///
/// This is not a solution of elasticity; the real fields come from `sim::simulate`. The grid
/// covers the elastomer at `cell_mm`.
pub fn geometric_field(
    indenter: &Indenter,
    elastomer: &ElastomerConfig,
    contact_mm: [f64; 2],
    depth_mm: f64,
    shear_mm: [f64; 2],
    cell_mm: f64,
) -> SurfaceField {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    let cell_mm = if ok(cell_mm) { cell_mm } else { 0.05 };
    let size = [elastomer.size_x_mm, elastomer.size_y_mm].map(|s| if ok(s) { s } else { 10.0 });
    let nx = ((size[0] / cell_mm).round() as usize).clamp(1, 2048);
    let ny = ((size[1] / cell_mm).round() as usize).clamp(1, 2048);
    let cell_mm = size[0] / nx as f64;
    let origin = [
        -(nx as f64 - 1.0) / 2.0 * cell_mm,
        -(ny as f64 - 1.0) / 2.0 * cell_mm,
    ];
    let depth = if depth_mm.is_finite() { depth_mm } else { 0.0 };
    let shear = shear_mm.map(|s| if s.is_finite() { s } else { 0.0 });
    let axis = [contact_mm[0] + shear[0], contact_mm[1] + shear[1]];
    let mut overlap = vec![0.0; nx * ny];
    for j in 0..ny {
        for i in 0..nx {
            let x = origin[0] + i as f64 * cell_mm - axis[0];
            let y = origin[1] + j as f64 * cell_mm - axis[1];
            overlap[j * nx + i] = (depth - indenter.gap_mm(x, y)).max(0.0);
        }
    }
    let skirt_mm = 0.25;
    let blurred = gaussian_grid(&overlap, nx, ny, skirt_mm / cell_mm);
    let uz: Vec<f64> = overlap
        .iter()
        .zip(&blurred)
        .map(|(o, b)| -o.max(*b))
        .collect();
    let contact: Vec<f64> = overlap
        .iter()
        .map(|&o| if o > 0.0 { 1.0 } else { 0.0 })
        .collect();
    let spread = gaussian_grid(&contact, nx, ny, 2.0 * skirt_mm / cell_mm);
    let stick: Vec<f64> = contact
        .iter()
        .zip(&spread)
        .map(|(c, s)| c.max((2.0 * s).min(1.0)))
        .collect();
    let (e, nu, h) = (
        elastomer.youngs_modulus_mpa,
        elastomer.poisson_ratio,
        elastomer.thickness_mm,
    );
    let m = e * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let k = if m.is_finite() && ok(h) { m / h } else { 0.0 };
    SurfaceField {
        nx,
        ny,
        cell_mm,
        origin_mm: origin,
        ux_mm: stick.iter().map(|w| w * shear[0]).collect(),
        uy_mm: stick.iter().map(|w| w * shear[1]).collect(),
        pressure_mpa: overlap.iter().map(|o| k * o).collect(),
        traction_x_mpa: vec![0.0; nx * ny],
        traction_y_mpa: vec![0.0; nx * ny],
        uz_mm: uz,
    }
}

/// Separable Gaussian blur of a grid (σ in cells), edges clamped.
fn gaussian_grid(v: &[f64], nx: usize, ny: usize, sigma: f64) -> Vec<f64> {
    let kernel = gaussian_kernel(sigma);
    let r = kernel.len() / 2;
    // One pass along x, then one along y: each output cell is the kernel-weighted sum of the
    // cells `t - r` away along the pass's axis (index clamped to the grid).
    let pass = |src: &[f64], along_x: bool| {
        let mut dst = vec![0.0; src.len()];
        for j in 0..ny {
            for i in 0..nx {
                let mut s = 0.0;
                for (t, w) in kernel.iter().enumerate() {
                    let k = if along_x {
                        j * nx + (i + t).saturating_sub(r).min(nx - 1)
                    } else {
                        (j + t).saturating_sub(r).min(ny - 1) * nx + i
                    };
                    s += w * src[k];
                }
                dst[j * nx + i] = s;
            }
        }
        dst
    };
    pass(&pass(v, true), false)
}

/// Normalised Gaussian taps over ±3σ (a single tap of 1 for σ ≈ 0).
pub(crate) fn gaussian_kernel(sigma: f64) -> Vec<f64> {
    if !(sigma.is_finite() && sigma > 0.05) {
        return vec![1.0];
    }
    let r = (3.0 * sigma).ceil().min(256.0) as i64;
    let mut k: Vec<f64> = (-r..=r)
        .map(|t| (-(t * t) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = k.iter().sum();
    k.iter_mut().for_each(|w| *w /= sum);
    k
}
