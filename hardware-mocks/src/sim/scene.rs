//! What a frame of the simulator is about and what it asks for: the [`Scene`] (elastomer,
//! indenter, pose, optics) and its [`Effects`], with the option types those name (the contact
//! and friction models, viscoelasticity, image effects), and what a frame reports
//! ([`SimStats`], [`SimError`]).
//!
//! The simulator's stages ([`super::contact`], [`super::optics`]) read these types; this file
//! imports neither of them, so the dependencies run one way.

use std::str::FromStr;
use std::sync::Arc;

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;

/// Where the indenter is, in the sensor surface frame (x, y along the undeformed gel surface,
/// origin at its centre; z its outward normal).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IndenterPose {
    /// The indenter axis's contact point on the undeformed surface, mm.
    pub contact_mm: [f64; 2],
    /// Indentation depth of the indenter tip below the undeformed surface, mm. At most the gel
    /// thickness; ≤ 0 means not touching (zero force).
    pub depth_mm: f64,
    /// Tangential displacement of the indenter from the contact point, mm. The indenter's axis
    /// is at `contact_mm + shear_mm`.
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

impl Scene {
    /// A force-only scene with the default effects (finite-layer BEM, no friction, no image).
    pub fn new(elastomer: ElastomerConfig, indenter: Arc<Indenter>, pose: IndenterPose) -> Self {
        Self {
            elastomer,
            indenter,
            pose,
            optics: None,
            effects: Effects::default(),
        }
    }
}

/// Grid cell of the contact physics every command simulates a sensor with, mm: 25 × 20 cells
/// on the 10 × 8 mm gel, each overlap sub-sampled at 0.1 mm (see the `contact` module docs for
/// its error against the 0.1 mm grid and its cost).
pub const SENSOR_CELL_MM: f64 = 0.4;

impl Effects {
    /// The contact physics of a sensor, the same for every command that simulates one
    /// (`rig run` on the simulated rig, `rig sim render` and `rig sim forces`, the demo): the
    /// finite layer at [`SENSOR_CELL_MM`], Coulomb friction with history (stick tracked on the
    /// gel's material points), and the elastomer's viscoelastic relaxation when its config has
    /// one. Force only; add a field or an image as needed.
    pub fn sensor(elastomer: &ElastomerConfig) -> Self {
        Self {
            contact: ContactModel::Layer,
            cell_mm: Some(SENSOR_CELL_MM),
            friction: FrictionModel::Incremental,
            viscoelastic: Viscoelastic::from_elastomer(elastomer),
            surface_field: false,
            image: None,
        }
    }
}

/// The effects a scene asks for. Default: finite-thickness layer BEM at the default grid,
/// no friction, no viscoelasticity, no surface field, no image (force only).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Effects {
    /// Normal contact model.
    pub contact: ContactModel,
    /// Grid cell size of the gridded models (Winkler, BEM) and of the surface field, mm.
    /// `None`: [`DEFAULT_CELL_MM`](super::contact::DEFAULT_CELL_MM).
    pub cell_mm: Option<f64>,
    /// Tangential behaviour.
    pub friction: FrictionModel,
    /// Standard-linear-solid relaxation of the contact forces (needs a [`Simulator`](super::Simulator) and times).
    pub viscoelastic: Option<Viscoelastic>,
    /// Return the surface field even when no image is rendered.
    pub surface_field: bool,
    /// Render an image, with these image effects. `None`: force only, no rendering work.
    pub image: Option<ImageEffects>,
}

/// Counters of the work one frame did: which stages ran, and how much they cost.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimStats {
    /// Normal contact solves (1 per frame with contact; 0 at zero depth).
    pub normal_solves: u32,
    /// Constrained-CG iterations of the normal BEM solve.
    pub normal_iterations: u32,
    /// Tangential (friction) solves.
    pub tangential_solves: u32,
    /// Iterations of the tangential solver.
    pub tangential_iterations: u32,
    /// 2-D FFTs (forward or inverse) executed.
    pub ffts: u32,
    /// Influence kernels built (0 when the cached ones were reused).
    pub kernels_built: u32,
    /// Normal solves repeated on a larger window because the deformed gel touched the
    /// indenter outside the first (see `contact/window.rs`).
    pub windows_grown: u32,
    /// Surface fields assembled.
    pub fields_built: u32,
    /// Images rendered.
    pub images_rendered: u32,
    /// Pixels shaded, times LEDs (0 for an untouched gel: its image is cached).
    pub shaded_pixels: u32,
    /// Marker dots drawn.
    pub markers_drawn: u32,
    /// Shadow sweeps (one per LED).
    pub shadow_sweeps: u32,
    /// Blur passes (two per colour plane).
    pub blur_passes: u32,
    /// Frames darkened by the vignette.
    pub vignette_frames: u32,
    /// Camera-noise samples drawn.
    pub noise_samples: u32,
    /// Whether the iterative solvers met their tolerance (true when none ran).
    pub converged: bool,
}

/// Which contact model a scene uses (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum ContactModel {
    /// Analytic sphere on a half-space.
    Hertz,
    /// Independent springs `k = M / h`.
    Winkler,
    /// FFT boundary elements on an elastic half-space.
    HalfSpace,
    /// FFT boundary elements on a layer of the gel's thickness bonded to a rigid base.
    #[default]
    Layer,
}

impl ContactModel {
    pub const ALL: [ContactModel; 4] = [
        ContactModel::Hertz,
        ContactModel::Winkler,
        ContactModel::HalfSpace,
        ContactModel::Layer,
    ];

    /// Name as used on command lines: `hertz`, `winkler`, `half-space`, `layer`.
    pub fn name(self) -> &'static str {
        match self {
            ContactModel::Hertz => "hertz",
            ContactModel::Winkler => "winkler",
            ContactModel::HalfSpace => "half-space",
            ContactModel::Layer => "layer",
        }
    }
}

impl std::fmt::Display for ContactModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for ContactModel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        ContactModel::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                format!("unknown contact model `{s}`; one of: hertz, winkler, half-space, layer")
            })
    }
}

/// Tangential behaviour.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum FrictionModel {
    /// No tangential traction (no tangential solve at all).
    #[default]
    None,
    /// Coulomb stick/slip, each frame one shear step from the unloaded state (no history).
    Monotonic,
    /// Coulomb stick/slip with history carried between frames by a `Simulator`.
    Incremental,
}

/// Standard-linear-solid relaxation of the contact force.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Viscoelastic {
    /// Instantaneous over relaxed modulus, ≥ 1.
    pub instant_ratio: f64,
    /// Relaxation time, s (> 0).
    pub tau_s: f64,
}

impl Viscoelastic {
    /// The elastomer's relaxation (`instant_modulus_ratio`, `relaxation_time_s`); `None` when
    /// its ratio is 1 (no relaxation).
    pub fn from_elastomer(e: &ElastomerConfig) -> Option<Self> {
        (e.instant_modulus_ratio != 1.0).then_some(Self {
            instant_ratio: e.instant_modulus_ratio,
            tau_s: e.relaxation_time_s,
        })
    }
}

/// Image effects a scene asks for, beyond shading over the background (always done when an
/// image is rendered). [`ImageEffects::default`] is shading only; [`ImageEffects::realistic`]
/// turns everything on with values close to a GelSight Mini's look.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageEffects {
    /// Draw the printed markers (when the sensor's pattern is not `none`).
    pub markers: bool,
    /// Cast shadows from the raised gel.
    pub shadows: bool,
    /// Gaussian blur σ, pixels; 0: off.
    pub blur_sigma_px: f64,
    /// Darkening at the image corners, fraction in [0, 1); 0: off.
    pub vignetting: f64,
    /// Sensor noise σ, 8-bit levels; 0: off.
    pub noise_sigma: f64,
}

impl Default for ImageEffects {
    fn default() -> Self {
        Self::shading_only()
    }
}

impl ImageEffects {
    /// Shading over the background, nothing else.
    pub const fn shading_only() -> Self {
        Self {
            markers: false,
            shadows: false,
            blur_sigma_px: 0.0,
            vignetting: 0.0,
            noise_sigma: 0.0,
        }
    }

    /// What a sensor's `[optics.effects]` asks for (markers only if it has a marker pattern).
    pub fn from_optics(optics: &OpticsConfig) -> Self {
        let e = &optics.effects;
        Self {
            markers: e.markers && optics.markers.pattern != rig_core::optics::MarkerPattern::None,
            shadows: e.shadows,
            blur_sigma_px: e.blur_sigma_px,
            vignetting: e.vignetting,
            noise_sigma: e.noise_sigma,
        }
    }

    /// Every effect on, with a GelSight Mini's look: the defaults of `[optics.effects]`
    /// ([`rig_core::optics::EffectsConfig::default`]: markers, shadows, 0.8 px blur, 25 %
    /// vignetting, noise σ = 1.5 levels) on a sensor with markers.
    pub fn realistic() -> Self {
        Self::from_optics(&OpticsConfig::default())
    }
}

/// Why a scene cannot be simulated. Every message says what to change.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error(
        "depth {depth_mm} mm exceeds the gel thickness {thickness_mm} mm: the indenter would hit the rigid backing; press less deep"
    )]
    DepthBeyondThickness { depth_mm: f64, thickness_mm: f64 },
    #[error(
        "the Hertz model needs a single spherical cap, but indenter `{indenter}` is {reason}; use the `half-space`, `layer` or `winkler` model"
    )]
    NotASphere { indenter: String, reason: String },
    #[error("{name} = {value}: {reason}")]
    InvalidParameter {
        name: &'static str,
        value: f64,
        reason: String,
    },
    #[error("the scene asks for an image but has no optics: set `scene.optics`")]
    MissingOptics,
    #[error("contact grid: {0}")]
    Grid(String),
}
