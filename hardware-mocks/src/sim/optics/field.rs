//! Surface fields as the renderer needs them: the image's pixel grid over the gel ([`Raster`]),
//! the fields resampled onto it, and a purely geometric field for tests and previews.

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;

use super::super::contact::SurfaceField;

/// The pixel grid of an image over the gel: the camera's frame is the gel's turned by
/// `optics.camera_rotation_deg` and shifted by `optics.camera_offset_mm`.
pub(crate) struct Raster {
    pub width: usize,
    pub height: usize,
    pub mm_per_px: f64,
    /// The image centre on the gel, mm (`optics.camera_offset_mm`).
    pub offset_mm: [f64; 2],
    /// Cosine and sine of the camera's rotation against the gel (`optics.camera_rotation_deg`).
    pub rot: [f64; 2],
}

impl Raster {
    pub(crate) fn new(optics: &OpticsConfig) -> Self {
        let side = |v: u32| (v.min(rig_core::optics::MAX_SIDE_PX)) as usize;
        let mm_per_px = if optics.mm_per_px.is_finite() && optics.mm_per_px > 0.0 {
            optics.mm_per_px
        } else {
            OpticsConfig::default().mm_per_px
        };
        let offset_mm = optics
            .camera_offset_mm
            .map(|v| if v.is_finite() { v } else { 0.0 });
        let angle = if optics.camera_rotation_deg.is_finite() {
            optics.camera_rotation_deg.clamp(-45.0, 45.0).to_radians()
        } else {
            0.0
        };
        // sin_cos(0) is exactly (0, 1): an unturned camera is `aligned`.
        let (sin, cos) = angle.sin_cos();
        Self {
            width: side(optics.width_px),
            height: side(optics.height_px),
            mm_per_px,
            offset_mm,
            rot: [cos, sin],
        }
    }

    /// Whether the camera's axes are the gel's (no rotation): pixel columns then share an x
    /// and rows a y, and resampling is separable.
    pub fn aligned(&self) -> bool {
        self.rot == [1.0, 0.0]
    }

    /// Camera-frame position of column `u`'s centre, mm from the image centre.
    pub fn cam_x(&self, u: usize) -> f64 {
        (u as f64 + 0.5 - self.width as f64 / 2.0) * self.mm_per_px
    }

    /// Camera-frame position of row `v`'s centre, mm from the image centre (row 0 at the top,
    /// the camera's +y).
    pub fn cam_y(&self, v: usize) -> f64 {
        (self.height as f64 / 2.0 - v as f64 - 0.5) * self.mm_per_px
    }

    /// Where on the gel a camera-frame point (mm from the image centre) lies, mm.
    pub fn gel_of_cam(&self, a: f64, b: f64) -> [f64; 2] {
        let [c, s] = self.rot;
        [
            self.offset_mm[0] + c * a - s * b,
            self.offset_mm[1] + s * a + c * b,
        ]
    }

    /// Where on the gel pixel `(u, v)`'s centre lies, mm.
    pub fn gel_of(&self, u: usize, v: usize) -> [f64; 2] {
        self.gel_of_cam(self.cam_x(u), self.cam_y(v))
    }

    /// Fractional pixel position (column, row) of a gel point, mm: the inverse of
    /// [`Self::gel_of`].
    pub fn px_of(&self, x_mm: f64, y_mm: f64) -> [f64; 2] {
        let [c, s] = self.rot;
        let (dx, dy) = (x_mm - self.offset_mm[0], y_mm - self.offset_mm[1]);
        let (a, b) = (c * dx + s * dy, -s * dx + c * dy);
        [
            a / self.mm_per_px + self.width as f64 / 2.0 - 0.5,
            self.height as f64 / 2.0 - 0.5 - b / self.mm_per_px,
        ]
    }

    /// A gel-frame vector (a gradient, a displacement) in the camera's frame.
    pub fn to_cam(&self, v: [f32; 2]) -> [f32; 2] {
        let [c, s] = self.rot.map(|r| r as f32);
        [c * v[0] + s * v[1], -s * v[0] + c * v[1]]
    }

    /// The gel-frame box `[x0, x1] × [y0, y1]` (mm) that holds the whole image, grown by
    /// `margin_mm` on every side.
    pub fn gel_bounds(&self, margin_mm: f64) -> [f64; 4] {
        let (hw, hh) = (
            self.width as f64 / 2.0 * self.mm_per_px,
            self.height as f64 / 2.0 * self.mm_per_px,
        );
        let corners =
            [[-hw, -hh], [hw, -hh], [-hw, hh], [hw, hh]].map(|[a, b]| self.gel_of_cam(a, b));
        let [x0, x1, y0, y1] = bounding_box(&corners);
        [
            x0 - margin_mm,
            x1 + margin_mm,
            y0 - margin_mm,
            y1 + margin_mm,
        ]
    }
}

/// The axis-aligned box `[x0, x1, y0, y1]` around `points`.
fn bounding_box(points: &[[f64; 2]]) -> [f64; 4] {
    let lo = |k: usize| points.iter().map(|p| p[k]).fold(f64::INFINITY, f64::min);
    let hi = |k: usize| {
        points
            .iter()
            .map(|p| p[k])
            .fold(f64::NEG_INFINITY, f64::max)
    };
    [lo(0), hi(0), lo(1), hi(1)]
}

/// Below these a cell does not change the image (so the renderer leaves its pixels as the
/// background): a slope of 2·10⁻⁴ shades by under 0.05 of an 8-bit level, a tangential shift of
/// 10⁻⁴ mm moves a marker edge by 0.003 px, and a height under 1 µm casts no shadow (the shadow
/// march ignores it too).
const ACTIVE_SLOPE: f32 = 2e-4;
const ACTIVE_SHIFT_MM: f32 = 1e-4;
const ACTIVE_HEIGHT_MM: f32 = 1e-3;

/// A surface field as the renderer reads it: per cell of the field's grid, height (`−uz`, mm),
/// its gradient (central differences), and the tangential displacement (mm), in `f32`.
pub(crate) struct CellField {
    nx: usize,
    ny: usize,
    inv_cell: f64,
    origin_mm: [f64; 2],
    /// `[h, ∂h/∂x, ∂h/∂y, ux, uy]` per cell, `k = j·nx + i`.
    cells: Vec<[f32; 5]>,
    /// Cells that change the image: `(i0, i1, j0, j1)`, inclusive; `None`: none does.
    active: Option<(usize, usize, usize, usize)>,
}

impl CellField {
    /// `None` when the field is malformed (wrong lengths, bad grid): it renders as untouched.
    /// Non-finite values read as zero.
    pub fn new(field: &SurfaceField) -> Option<Self> {
        let usable = field.nx > 0
            && field.ny > 0
            && field.cell_mm.is_finite()
            && field.cell_mm > 0.0
            && field.origin_mm.iter().all(|v| v.is_finite())
            && [&field.uz_mm, &field.ux_mm, &field.uy_mm]
                .iter()
                .all(|v| v.len() == field.nx * field.ny);
        if !usable {
            return None;
        }
        let (nx, ny, cell) = (field.nx, field.ny, field.cell_mm as f32);
        let clean = |v: f64| if v.is_finite() { v as f32 } else { 0.0 };
        let h: Vec<f32> = field.uz_mm.iter().map(|&u| -clean(u)).collect();
        let mut cells = vec![[0f32; 5]; nx * ny];
        let (mut i0, mut i1, mut j0, mut j1) = (usize::MAX, 0, usize::MAX, 0);
        for j in 0..ny {
            for i in 0..nx {
                let k = j * nx + i;
                let at = |ii: usize, jj: usize| h[jj * nx + ii];
                let dx = if nx < 2 {
                    0.0
                } else {
                    let (a, b) = (i.saturating_sub(1), (i + 1).min(nx - 1));
                    (at(b, j) - at(a, j)) / ((b - a) as f32 * cell)
                };
                let dy = if ny < 2 {
                    0.0
                } else {
                    let (a, b) = (j.saturating_sub(1), (j + 1).min(ny - 1));
                    (at(i, b) - at(i, a)) / ((b - a) as f32 * cell)
                };
                let c = [h[k], dx, dy, clean(field.ux_mm[k]), clean(field.uy_mm[k])];
                if c[0].abs() > ACTIVE_HEIGHT_MM
                    || c[1].abs().max(c[2].abs()) > ACTIVE_SLOPE
                    || c[3].abs().max(c[4].abs()) > ACTIVE_SHIFT_MM
                {
                    (i0, i1, j0, j1) = (i0.min(i), i1.max(i), j0.min(j), j1.max(j));
                }
                cells[k] = c;
            }
        }
        Some(Self {
            nx,
            ny,
            inv_cell: 1.0 / field.cell_mm,
            origin_mm: field.origin_mm,
            cells,
            active: (i0 <= i1).then_some((i0, i1, j0, j1)),
        })
    }

    /// Bilinear value at a surface point (mm); zero more than half a cell outside the grid.
    pub fn sample(&self, x_mm: f64, y_mm: f64) -> [f32; 5] {
        let (Some((i0, i1, tx)), Some((j0, j1, ty))) = (
            bracket((x_mm - self.origin_mm[0]) * self.inv_cell, self.nx),
            bracket((y_mm - self.origin_mm[1]) * self.inv_cell, self.ny),
        ) else {
            return [0.0; 5];
        };
        self.lerp(i0, i1, tx, j0, j1, ty)
    }

    fn lerp(&self, i0: usize, i1: usize, tx: f32, j0: usize, j1: usize, ty: f32) -> [f32; 5] {
        let nx = self.nx;
        let (a, b, c, d) = (
            &self.cells[j0 * nx + i0],
            &self.cells[j0 * nx + i1],
            &self.cells[j1 * nx + i0],
            &self.cells[j1 * nx + i1],
        );
        let mut s = [0f32; 5];
        for q in 0..5 {
            let top = a[q] + (b[q] - a[q]) * tx;
            let bottom = c[q] + (d[q] - c[q]) * tx;
            s[q] = top + (bottom - top) * ty;
        }
        s
    }
}

/// Pixel rectangle `[u0, u1) × [v0, v1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Region {
    pub u0: usize,
    pub u1: usize,
    pub v0: usize,
    pub v1: usize,
}

/// The gel surface at every pixel, in the camera's view, as planes (one value per pixel, row
/// major): `height_mm` is how far the surface has come towards the camera (`−uz`, ≥ 0 where
/// pressed), `gx`, `gy` its gradient. Only `region` is filled (zero elsewhere): the pixels over
/// the cells that change the image. Kept between frames by the renderer (its planes are
/// reused; [`resample_into`] clears what the last frame wrote).
#[derive(Default)]
pub(crate) struct PixelField {
    pub height_mm: Vec<f32>,
    pub gx: Vec<f32>,
    pub gy: Vec<f32>,
    /// Largest height anywhere, mm (bounds the shadow ray march).
    pub max_height_mm: f32,
    /// Whether the field leaves the image untouched: the renderer skips all contact work.
    pub flat: bool,
    pub region: Region,
    /// The field on its own grid, for point lookups (marker dots); `None` when flat.
    pub cells: Option<CellField>,
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
/// pixel centres of `raster`, over the pixels the field's active cells can reach, into `out`.
/// Gradients are taken on the field's own grid by central differences and then interpolated,
/// so a coarse field still shades smoothly.
pub(crate) fn resample_into(field: &SurfaceField, raster: &Raster, out: &mut PixelField) {
    let (w, n) = (raster.width, raster.width * raster.height);
    if out.height_mm.len() != n {
        *out = PixelField {
            height_mm: vec![0.0; n],
            gx: vec![0.0; n],
            gy: vec![0.0; n],
            ..PixelField::default()
        };
    } else {
        // Clear what the last frame wrote.
        let r = out.region;
        for v in r.v0..r.v1 {
            let row = v * w + r.u0..v * w + r.u1;
            out.height_mm[row.clone()].fill(0.0);
            out.gx[row.clone()].fill(0.0);
            out.gy[row].fill(0.0);
        }
    }
    out.max_height_mm = 0.0;
    out.flat = true;
    out.region = Region::default();
    out.cells = None;
    let Some(cells) = CellField::new(field) else {
        return;
    };
    let Some((i0, i1, j0, j1)) = cells.active else {
        return;
    };
    // Pixels whose bilinear support touches an active cell: within one cell of its centre
    // (the pixel box around the four corners of that gel rectangle, for a turned camera).
    let cell = field.cell_mm;
    let x_lo = field.origin_mm[0] + (i0 as f64 - 1.0) * cell;
    let x_hi = field.origin_mm[0] + (i1 as f64 + 1.0) * cell;
    let y_lo = field.origin_mm[1] + (j0 as f64 - 1.0) * cell;
    let y_hi = field.origin_mm[1] + (j1 as f64 + 1.0) * cell;
    let (wf, hf) = (raster.width as f64, raster.height as f64);
    let corners =
        [[x_lo, y_lo], [x_hi, y_lo], [x_lo, y_hi], [x_hi, y_hi]].map(|[x, y]| raster.px_of(x, y));
    let [u_lo, u_hi, v_lo, v_hi] = bounding_box(&corners);
    let region = Region {
        u0: u_lo.clamp(0.0, wf).floor() as usize,
        u1: (u_hi.clamp(0.0, wf).ceil() as usize + 1).min(raster.width),
        v0: v_lo.clamp(0.0, hf).floor() as usize,
        v1: (v_hi.clamp(0.0, hf).ceil() as usize + 1).min(raster.height),
    };
    out.flat = false;
    out.region = region;
    let max_h = if raster.aligned() {
        resample_aligned(&cells, raster, region, out)
    } else {
        resample_turned(&cells, raster, region, out)
    };
    out.max_height_mm = max_h;
    out.cells = Some(cells);
}

/// [`resample_into`]'s pixels for a camera whose axes are the gel's: per row, the field is
/// interpolated between its two cell rows first (once per cell), then each pixel between two of
/// those. Returns the largest height.
fn resample_aligned(
    cells: &CellField,
    raster: &Raster,
    region: Region,
    out: &mut PixelField,
) -> f32 {
    let w = raster.width;
    let cols: Vec<Option<(usize, usize, f32)>> = (region.u0..region.u1)
        .map(|u| {
            bracket(
                (raster.gel_of(u, 0)[0] - cells.origin_mm[0]) * cells.inv_cell,
                cells.nx,
            )
        })
        .collect();
    let mut line = vec![[0f32; 3]; cells.nx];
    let mut max_h = 0f32;
    for v in region.v0..region.v1 {
        let Some((j0, j1, ty)) = bracket(
            (raster.gel_of(0, v)[1] - cells.origin_mm[1]) * cells.inv_cell,
            cells.ny,
        ) else {
            continue;
        };
        let (a, b) = (
            &cells.cells[j0 * cells.nx..(j0 + 1) * cells.nx],
            &cells.cells[j1 * cells.nx..(j1 + 1) * cells.nx],
        );
        for ((o, a), b) in line.iter_mut().zip(a).zip(b) {
            for q in 0..3 {
                o[q] = a[q] + (b[q] - a[q]) * ty;
            }
        }
        let row = v * w + region.u0..v * w + region.u1;
        let (hs, gxs, gys) = (
            &mut out.height_mm[row.clone()],
            &mut out.gx[row.clone()],
            &mut out.gy[row],
        );
        for (k, c) in cols.iter().enumerate() {
            let Some((i0, i1, tx)) = *c else {
                continue;
            };
            let (a, b) = (line[i0], line[i1]);
            hs[k] = a[0] + (b[0] - a[0]) * tx;
            gxs[k] = a[1] + (b[1] - a[1]) * tx;
            gys[k] = a[2] + (b[2] - a[2]) * tx;
            max_h = max_h.max(hs[k]);
        }
    }
    max_h
}

/// [`resample_into`]'s pixels for a turned camera: each pixel's gel point is looked up on its
/// own (bilinear), and the gradient is turned into the camera's frame, where the LEDs are.
/// Returns the largest height.
fn resample_turned(
    cells: &CellField,
    raster: &Raster,
    region: Region,
    out: &mut PixelField,
) -> f32 {
    let w = raster.width;
    let mut max_h = 0f32;
    for v in region.v0..region.v1 {
        for u in region.u0..region.u1 {
            let [x, y] = raster.gel_of(u, v);
            let c = cells.sample(x, y);
            let [gx, gy] = raster.to_cam([c[1], c[2]]);
            let p = v * w + u;
            out.height_mm[p] = c[0];
            out.gx[p] = gx;
            out.gy[p] = gy;
            max_h = max_h.max(c[0]);
        }
    }
    max_h
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
