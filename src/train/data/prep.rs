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
    tracker: Option<crate::markers::Tracker>,
    shading: Option<crate::markers::Shading>,
}

/// The gel area a [`Modality::Flow`] image covers, mm (x, y), centred on the image centre:
/// `markers::GridSpec`'s default area, inside the view of the simulated sensors and of one
/// with a 1.1–1.2 mm marker pitch.
pub const FLOW_VIEW_MM: [f64; 2] = [8.0, 6.0];

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
            let spacing_mm =
                (FLOW_VIEW_MM[0] / nx.max(1) as f64).max(FLOW_VIEW_MM[1] / ny.max(1) as f64);
            let grid = crate::markers::GridSpec {
                nx,
                ny,
                spacing_mm,
                ..crate::markers::GridSpec::default()
            };
            grid.check().map_err(anyhow::Error::msg)?;
            Some(Flow {
                geometry,
                grid,
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
                crate::markers::Shading::new(img, &flow.geometry, &flow.grid)
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
