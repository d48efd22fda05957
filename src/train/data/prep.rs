//! The network's image of each frame, in a trajectory's order: [`FramePrep`] (the paper's
//! modalities frame by frame, the marker-displacement ones from the trajectory's first frame).

use anyhow::Context;

use super::images::{ImageSpec, prepare_image};
use crate::train::modality::{FLOW_LEVELS_PER_MM, MarkerParams, Modality, SHADING_LEVELS};

/// Makes a trajectory's frames, in order, into the network's images: [`prepare_image`] for
/// the paper's modalities, and for [`Modality::Flow`] the markers tracked from the first frame
/// given (the trajectory's no-contact start, or a live session's first frame), their
/// displacement resampled on a grid of the network's size over [`FLOW_VIEW_MM`] of gel.
pub struct FramePrep {
    spec: ImageSpec,
    params: MarkerParams,
    flow: Option<Flow>,
}

struct Flow {
    geometry: crate::markers::SensorGeometry,
    grid: crate::markers::GridSpec,
    /// The shading change's grid: the same cells over [`SHADING_VIEW_MM`].
    shading_grid: crate::markers::GridSpec,
    tracker: Option<crate::markers::Tracker>,
    shading: Option<crate::markers::Shading>,
}

/// The gel area a [`Modality::Flow`] image covers, mm (x, y), centred on the image centre:
/// `markers::GridSpec`'s default area, inside the view of the simulated sensors and of one
/// with a 1.1–1.2 mm marker pitch.
pub const FLOW_VIEW_MM: [f64; 2] = [8.0, 6.0];

/// The gel area the shading change (D+S's blue) covers, mm: the whole 10 × 7.5 mm view of the
/// sensors in use. The shading needs no markers, so it need not stop where the markers' field
/// does, and the large indenters' rims, which carry their normal force, lie in the outer
/// millimetre (docs/experiments.md, *Normal force across sensors*).
pub const SHADING_VIEW_MM: [f64; 2] = [10.0, 7.5];

/// A grid of `nx × ny` cells over `view` mm (the larger spacing of the two axes).
fn grid_over(view: [f64; 2], nx: usize, ny: usize) -> crate::markers::GridSpec {
    crate::markers::GridSpec {
        nx,
        ny,
        spacing_mm: (view[0] / nx.max(1) as f64).max(view[1] / ny.max(1) as f64),
        ..crate::markers::GridSpec::default()
    }
}

impl FramePrep {
    /// `optics`: the sensor's (needed for [`Modality::Flow`] only).
    pub fn new(
        spec: &ImageSpec,
        params: MarkerParams,
        optics: Option<&rig_core::optics::OpticsConfig>,
    ) -> anyhow::Result<Self> {
        let flow = if spec.modality.per_frame() {
            None
        } else {
            let optics = optics.context("marker displacement needs the sensor's optics")?;
            let geometry =
                crate::markers::SensorGeometry::from_optics(optics).map_err(anyhow::Error::msg)?;
            let (nx, ny) = (spec.width as usize, spec.height as usize);
            let grid = grid_over(FLOW_VIEW_MM, nx, ny);
            grid.check().map_err(anyhow::Error::msg)?;
            Some(Flow {
                geometry,
                grid,
                shading_grid: grid_over(SHADING_VIEW_MM, nx, ny),
                tracker: None,
                shading: None,
            })
        };
        Ok(Self {
            spec: *spec,
            params,
            flow,
        })
    }

    /// The network's image of the next frame (`spec.frame_bytes()` RGB bytes).
    pub fn next(&mut self, img: &image::RgbImage) -> anyhow::Result<Vec<u8>> {
        let Some(flow) = self.flow.as_mut() else {
            return Ok(prepare_image(img, &self.spec, &self.params));
        };
        let tracker = match flow.tracker.as_mut() {
            Some(t) => {
                t.update(img).map_err(anyhow::Error::msg)?;
                t
            }
            None => flow.tracker.insert(
                crate::markers::Tracker::new(img, &flow.geometry)
                    .map_err(anyhow::Error::msg)
                    .context("the reference (first) frame")?,
            ),
        };
        let field = tracker.grid(&flow.grid);
        if self.spec.modality != Modality::FlowShading {
            return Ok(flow_image(&field, &[]));
        }
        let shading = match flow.shading.as_mut() {
            Some(s) => s,
            None => flow.shading.insert(
                crate::markers::Shading::new(img, &flow.geometry, &flow.shading_grid)
                    .map_err(anyhow::Error::msg)?,
            ),
        };
        let shade = shading.field(img).map_err(anyhow::Error::msg)?;
        Ok(flow_image(&field, &shade))
    }
}

/// The mean relative shading change over D+S images (their blue channel, [`SHADING_LEVELS`]),
/// every cell of every frame; `None` for no pixels. A sensor's shading scale: over recordings
/// of one plan, two sensors' means differ by how strongly their LEDs shade the same slopes.
pub fn mean_shading<'a>(images: impl IntoIterator<Item = &'a [u8]>) -> Option<f64> {
    let (mut sum, mut n) = (0u64, 0u64);
    for px in images {
        for p in px.chunks_exact(3) {
            sum += u64::from(p[2]);
            n += 1;
        }
    }
    (n > 0).then(|| sum as f64 / n as f64 / SHADING_LEVELS)
}

/// The gain that brings a sensor's shading to the scale of the sensor a model was trained on:
/// the ratio of their [`mean_shading`] over recordings of the same plan (no labels needed). 1
/// when either mean is zero or not finite.
pub fn shading_gain(trained: f64, sensor: f64) -> f64 {
    let g = trained / sensor;
    if trained > 0.0 && sensor > 0.0 && g.is_finite() {
        g
    } else {
        1.0
    }
}

/// Scales the shading change (blue) of D+S images by `gain`, rounded and clamped to a byte.
/// The same on every path that feeds a model (`rig eval`, `rig predict`), so they agree frame
/// for frame.
pub fn apply_shading_gain(pixels: &mut [u8], gain: f64) {
    if gain == 1.0 {
        return;
    }
    for p in pixels.chunks_exact_mut(3) {
        p[2] = (f64::from(p[2]) * gain).round().clamp(0.0, 255.0) as u8;
    }
}

/// A displacement field (`[dx, dy]` mm a cell, row-major) as a [`Modality::Flow`] image, with
/// the shading change (one value a cell, [`SHADING_LEVELS`]) in blue for
/// [`Modality::FlowShading`]; blue is mid-grey where `shading` has no value (D).
pub fn flow_image(field: &[[f32; 2]], shading: &[f32]) -> Vec<u8> {
    let level = |v: f32| {
        (128.0 + f64::from(v) * FLOW_LEVELS_PER_MM)
            .round()
            .clamp(0.0, 255.0) as u8
    };
    let shade = |k: usize| {
        shading.get(k).map_or(128, |&v| {
            (f64::from(v) * SHADING_LEVELS).round().clamp(0.0, 255.0) as u8
        })
    };
    field
        .iter()
        .enumerate()
        .flat_map(|(k, d)| [level(d[0]), level(d[1]), shade(k)])
        .collect()
}

/// A D or D+S image (`width × height`, RGB) mirrored left-right when `flip & 1` and top-bottom
/// when `flip & 2`: the mirror image of the contact, whose x (red) or y (green) displacement
/// changes sign about mid-grey; the shading (blue) only moves. The grid is centred on the gel
/// and in its axes, so this is the field a mirrored indenter makes on an isotropic gel (its
/// force's x or y component negated), up to the LEDs' side in the shading.
pub fn mirror_flow_image(img: &[u8], width: usize, height: usize, flip: u8) -> Vec<u8> {
    let neg = |v: u8| (256 - u16::from(v)).min(255) as u8;
    let mut out = vec![0u8; img.len()];
    for y in 0..height {
        let sy = if flip & 2 != 0 { height - 1 - y } else { y };
        for x in 0..width {
            let sx = if flip & 1 != 0 { width - 1 - x } else { x };
            let s = &img[(sy * width + sx) * 3..][..3];
            let d = &mut out[(y * width + x) * 3..][..3];
            d[0] = if flip & 1 != 0 { neg(s[0]) } else { s[0] };
            d[1] = if flip & 2 != 0 { neg(s[1]) } else { s[1] };
            d[2] = s[2];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::markers::{SensorGeometry, Shading};
    use image::RgbImage;

    #[test]
    fn a_mirrored_flow_image_is_the_mirrored_field() {
        // A 3 × 2 field whose cells all differ; its mirror images made from the mirrored
        // field itself must equal the mirrored image, and two mirrors undo each other.
        let field: Vec<[f32; 2]> = (0..6)
            .map(|k| [0.1 * k as f32 - 0.2, 0.3 - 0.05 * k as f32])
            .collect();
        let shading: Vec<f32> = (0..6).map(|k| 0.02 * k as f32).collect();
        let img = flow_image(&field, &shading);
        let at = |x: usize, y: usize| y * 3 + x;
        for flip in 0..4u8 {
            let (fx, fy) = (flip & 1 != 0, flip & 2 != 0);
            let mut mf = vec![[0f32; 2]; 6];
            let mut ms = vec![0f32; 6];
            for y in 0..2 {
                for x in 0..3 {
                    let (sx, sy) = (if fx { 2 - x } else { x }, if fy { 1 - y } else { y });
                    let [dx, dy] = field[at(sx, sy)];
                    mf[at(x, y)] = [if fx { -dx } else { dx }, if fy { -dy } else { dy }];
                    ms[at(x, y)] = shading[at(sx, sy)];
                }
            }
            let mirrored = mirror_flow_image(&img, 3, 2, flip);
            assert_eq!(mirrored, flow_image(&mf, &ms), "flip {flip}");
            assert_eq!(
                mirror_flow_image(&mirrored, 3, 2, flip),
                img,
                "flip {flip} twice"
            );
        }
        assert_eq!(mirror_flow_image(&img, 3, 2, 0), img);
    }

    #[test]
    fn a_weaker_sensor_s_shading_is_brought_to_the_training_sensor_s_scale() {
        // Two D+S frames of 2 cells: blue 10 and 30 levels (mean 20), then 0 and 40 (mean 20).
        let a: Vec<u8> = vec![128, 128, 10, 128, 128, 30];
        let b: Vec<u8> = vec![128, 128, 0, 128, 128, 40];
        let m = mean_shading([a.as_slice(), b.as_slice()]).unwrap();
        assert!((m - 20.0 / SHADING_LEVELS).abs() < 1e-12, "{m}");
        assert_eq!(mean_shading(std::iter::empty::<&[u8]>()), None);
        // A sensor whose shading runs at 0.64 of the training sensor's gets ×1.5625.
        let g = shading_gain(m, 0.64 * m);
        assert!((g - 1.5625).abs() < 1e-12, "{g}");
        // Nothing to scale by: 1.
        assert_eq!(shading_gain(m, 0.0), 1.0);
        assert_eq!(shading_gain(0.0, m), 1.0);
        assert_eq!(shading_gain(f64::NAN, m), 1.0);
        // Only blue moves; it rounds and stops at 255.
        let mut px: Vec<u8> = vec![100, 50, 10, 128, 128, 200];
        apply_shading_gain(&mut px, 1.5625);
        assert_eq!(px, [100, 50, 16, 128, 128, 255]);
    }

    #[test]
    fn the_shading_grid_spans_the_whole_view_and_sees_a_change_at_its_edge() {
        // 32 × 24 cells over 10 × 7.5 mm: 0.3125 mm apart, the outermost centres 0.16 mm in
        // from a 320 × 240 view's edge at 0.03125 mm/px; the displacement's grid stops 1 mm in.
        let g = grid_over(SHADING_VIEW_MM, 32, 24);
        assert_eq!(g.spacing_mm, 0.3125);
        assert!((g.cell_mm(0, 0)[0] + 4.84375).abs() < 1e-12);
        assert!((g.cell_mm(31, 23)[1] + 3.59375).abs() < 1e-12);
        let d = grid_over(FLOW_VIEW_MM, 32, 24);
        assert_eq!(d.spacing_mm, 0.25);

        // A rim along the view's edge (|x| > 4.8 mm) brightened by 20 %: the shading grid's
        // edge columns read it; the displacement grid's, whose tents (boxes reaching 0.875 mm)
        // stop at 4.75 mm, read none of it.
        let optics = rig_core::optics::OpticsConfig::default();
        let geom = SensorGeometry::from_optics(&optics).unwrap();
        let reference = RgbImage::from_pixel(320, 240, image::Rgb([100, 100, 100]));
        let rim = RgbImage::from_fn(320, 240, |x, _| {
            let x_mm = (x as f64 + 0.5 - 160.0) * optics.mm_per_px;
            image::Rgb(if x_mm.abs() > 4.8 { [120; 3] } else { [100; 3] })
        });
        let edge = |grid| {
            let mut s = Shading::new(&reference, &geom, &grid).unwrap();
            let f = s.field(&rim).unwrap();
            (0..grid.ny)
                .map(|j| f[j * grid.nx])
                .fold(f32::MAX, f32::min)
        };
        let (whole, inner) = (edge(g), edge(d));
        assert!(whole > 0.02, "the whole view's edge column reads {whole}");
        assert!(
            inner < 1e-6,
            "the displacement grid's edge column reads {inner}"
        );
    }
}
