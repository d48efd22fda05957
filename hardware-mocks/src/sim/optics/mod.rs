//! GelSight optics (skeleton; being written).

use rig_core::optics::OpticsConfig;

use super::contact::SurfaceField;

/// Image effects a scene asks for.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ImageEffects {}

/// Render the sensor image of a deformed gel surface.
pub fn render(
    _optics: &OpticsConfig,
    _effects: &ImageEffects,
    _field: &SurfaceField,
    _noise_seed: u64,
) -> image::RgbImage {
    todo!("optics renderer")
}
