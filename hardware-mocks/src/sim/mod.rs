//! The contact + optics simulator behind the simulated rig.
//!
//! A [`Scene`] says what is pressed into what (elastomer, indenter, indenter pose), how the
//! sensor looks (optics), and which **effects** it needs. Each effect is an explicit stage, and
//! a scene that does not name an effect does not pay for it:
//!
//! | stage            | runs when                                                    |
//! |------------------|--------------------------------------------------------------|
//! | normal contact   | always (the wrench needs it); Hertz is analytic, no grid     |
//! | tangential solve | `effects.friction` is not [`FrictionModel::None`]            |
//! | viscoelasticity  | `effects.viscoelastic` is `Some`                             |
//! | surface field    | `effects.surface_field`, or an image is asked for            |
//! | image            | `effects.image` is `Some` (needs `scene.optics`)             |
//!
//! [`SimStats`] in every [`SimOutput`] counts the stages that ran (and the FFTs and solver
//! iterations), so "a force-only scene does no rendering work" is a testable statement.
//!
//! - [`contact`]: contact mechanics (Hertz, Winkler layer, FFT boundary elements for a
//!   half-space or a finite layer, Coulomb friction with history) producing the wrench and,
//!   when asked, the surface fields. Its module docs give the models, their limits and the
//!   convergence table.
//! - [`optics`]: GelSight shading, markers, and image effects, from the surface fields.
//!
//! Use [`simulate`] for one stateless frame, or a [`Simulator`] for a sequence of frames: it
//! keeps the FFT plans and influence kernels of the last grid, and the history that friction
//! ([`FrictionModel::Incremental`]) and viscoelastic relaxation need.

pub mod contact;
pub mod optics;

use std::sync::Arc;

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;
use rig_core::wrench::Wrench;

pub use contact::{ContactModel, FrictionModel, SurfaceField, Viscoelastic};

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

/// The effects a scene asks for. Default: finite-thickness layer BEM at the default grid,
/// no friction, no viscoelasticity, no surface field, no image (force only).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Effects {
    /// Normal contact model.
    pub contact: contact::ContactModel,
    /// Grid cell size of the gridded models (Winkler, BEM) and of the surface field, mm.
    /// `None`: [`contact::DEFAULT_CELL_MM`].
    pub cell_mm: Option<f64>,
    /// Tangential behaviour.
    pub friction: contact::FrictionModel,
    /// Standard-linear-solid relaxation of the contact forces (needs a [`Simulator`] and times).
    pub viscoelastic: Option<contact::Viscoelastic>,
    /// Return the surface field even when no image is rendered.
    pub surface_field: bool,
    /// Render an image, with these image effects. `None`: force only, no rendering work.
    pub image: Option<optics::ImageEffects>,
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
    /// Surface fields assembled.
    pub fields_built: u32,
    /// Images rendered.
    pub images_rendered: u32,
    /// Whether the iterative solvers met their tolerance (true when none ran).
    pub converged: bool,
}

/// What the simulator computed for a scene.
#[derive(Debug, Clone)]
pub struct SimOutput {
    /// Force exerted by the indenter on the gel, in the sensor surface frame (pressing gives
    /// Fz < 0, as in the paper's range Fz −16..0 N); torque about the contact point on the
    /// undeformed surface (`pose.contact_mm`, z = 0), N·mm.
    pub wrench: Wrench,
    /// Contact area, mm².
    pub contact_area_mm2: f64,
    /// Surface fields, when an effect needed them (images do).
    pub field: Option<contact::SurfaceField>,
    /// The sensor image, when the scene asked for one.
    pub image: Option<image::RgbImage>,
    /// The work this frame did.
    pub stats: SimStats,
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

/// Simulates one frame without history (friction, if any, as a monotonic shear from the
/// unloaded state; no relaxation). Equivalent to a fresh [`Simulator`]'s first step at t = 0.
pub fn simulate(scene: &Scene) -> Result<SimOutput, SimError> {
    Simulator::new().step(scene, 0.0)
}

/// A simulator for sequences of frames: caches kernels and FFT plans of the last grid, and
/// carries the friction and viscoelastic history between [`Simulator::step`] calls.
#[derive(Default)]
pub struct Simulator {
    contact: contact::ContactEngine,
    noise_seed: u64,
    frames: u64,
}

impl std::fmt::Debug for Simulator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Simulator")
            .field("noise_seed", &self.noise_seed)
            .field("frames", &self.frames)
            .finish_non_exhaustive()
    }
}

impl Simulator {
    pub fn new() -> Self {
        Self::default()
    }

    /// A simulator whose image noise follows `seed` (frame `n` uses `seed + n`).
    pub fn with_noise_seed(seed: u64) -> Self {
        Self {
            noise_seed: seed,
            ..Self::default()
        }
    }

    /// Forgets the friction and viscoelastic history (the gel is unloaded and relaxed); keeps
    /// the caches.
    pub fn reset(&mut self) {
        self.contact.reset_history();
    }

    /// Simulates the scene at time `time_s` (seconds on any monotonic clock; only differences
    /// matter, for viscoelastic relaxation), advancing the history.
    pub fn step(&mut self, scene: &Scene, time_s: f64) -> Result<SimOutput, SimError> {
        let wants_image = scene.effects.image.is_some();
        if wants_image && scene.optics.is_none() {
            return Err(SimError::MissingOptics);
        }
        let want_field = wants_image || scene.effects.surface_field;
        let mut stats = SimStats {
            converged: true,
            ..SimStats::default()
        };
        let solved = self.contact.solve(scene, time_s, want_field, &mut stats)?;
        let image = match (&scene.effects.image, &scene.optics, &solved.field) {
            (Some(effects), Some(optics), Some(field)) => {
                stats.images_rendered += 1;
                let seed = self.noise_seed.wrapping_add(self.frames);
                Some(optics::render(optics, effects, field, seed))
            }
            _ => None,
        };
        self.frames += 1;
        Ok(SimOutput {
            wrench: solved.wrench,
            contact_area_mm2: solved.contact_area_mm2,
            field: solved.field,
            image,
            stats,
        })
    }
}
