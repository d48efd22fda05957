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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::markers::{SensorGeometry, Shading};
    use image::RgbImage;

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
