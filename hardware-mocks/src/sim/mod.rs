//! The contact + optics simulator behind the simulated rig.
//!
//! A [`Scene`] says what is pressed into what (elastomer, indenter, indenter pose), how the
//! sensor looks (optics), and which **effects** it needs. Each effect is an explicit stage, and
//! a scene that does not name an effect does not pay for it: a force-only scene renders no
//! image, a scene without markers draws none, a scene without friction history computes no
//! stick/slip state.
//!
//! - [`contact`]: contact mechanics (Hertz, Winkler layer, FFT boundary elements for a
//!   half-space or a finite layer, Coulomb friction with history) producing the wrench and,
//!   when asked, the surface fields.
//! - [`optics`]: GelSight shading, markers, and image effects, from the surface fields.

pub mod contact;
pub mod optics;

use std::sync::Arc;

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;
use rig_core::wrench::Wrench;

/// Where the indenter is, in the sensor surface frame (x, y along the undeformed gel surface,
/// origin at its centre; z its outward normal).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IndenterPose {
    /// The indenter axis's contact point on the undeformed surface, mm.
    pub contact_mm: [f64; 2],
    /// Indentation depth of the indenter tip below the undeformed surface, mm (≥ 0).
    pub depth_mm: f64,
    /// Tangential displacement of the indenter from the contact point, mm.
    pub shear_mm: [f64; 2],
}

/// A scene: everything the simulator needs for one contact state, and the effects to compute.
#[derive(Debug, Clone)]
pub struct Scene {
    pub elastomer: ElastomerConfig,
    pub indenter: Arc<Indenter>,
    pub pose: IndenterPose,
    /// Sensor optics; needed only when `effects.image` is set.
    pub optics: Option<OpticsConfig>,
    pub effects: Effects,
}

/// The effects a scene asks for. Defaults: Hertz-free general model choice is left to the
/// contact module; no friction history, no image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Effects {
    pub contact: contact::ContactModel,
    pub friction: contact::FrictionModel,
    /// Render an image, with these image effects. `None`: force only, no rendering work.
    pub image: Option<optics::ImageEffects>,
}

/// What the simulator computed for a scene.
#[derive(Debug, Clone)]
pub struct SimOutput {
    /// Force exerted by the indenter on the gel, in the sensor surface frame (pressing gives
    /// Fz < 0, as in the paper's range Fz −16..0 N); torque about the contact point on the
    /// undeformed surface.
    pub wrench: Wrench,
    /// Surface fields, when an effect needed them (images do).
    pub field: Option<contact::SurfaceField>,
    /// The sensor image, when the scene asked for one.
    pub image: Option<image::RgbImage>,
}
