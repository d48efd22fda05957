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
//! iterations, and each image effect's work: pixels shaded, marker dots, shadow sweeps, blur
//! passes, vignetting, noise samples), so "a force-only scene does no rendering work" and "an
//! effect the sensor's config leaves off is not computed" are testable statements.
//!
//! - [`contact`]: contact mechanics (Hertz, Winkler layer, FFT boundary elements for a
//!   half-space or a finite layer, Coulomb friction with history) producing the wrench and,
//!   when asked, the surface fields. Its module docs give the models, their limits and the
//!   convergence table.
//! - [`optics`]: GelSight shading, markers, and image effects, from the surface fields.
//! - [`scene`]: the scene, the effects and models it asks for, and what a frame reports
//!   ([`SimStats`], [`SimError`]); both stages read it, it imports neither.
//!
//! Use [`simulate`] for one stateless frame, or a [`Simulator`] for a sequence of frames: it
//! keeps the FFT plans and influence kernels of the last grid, and the history that friction
//! ([`FrictionModel::Incremental`]) and viscoelastic relaxation need.

pub mod contact;
pub use contact::History;
pub mod optics;
pub mod scene;

use rig_core::wrench::Wrench;

pub use contact::SurfaceField;
pub use scene::{
    ContactModel, Effects, FrictionModel, ImageEffects, IndenterPose, Scene, SimError, SimStats,
    Viscoelastic,
};

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
    /// The renderer of the last optics and image effects (its cached background is reused
    /// while they stay the same).
    renderer: Option<(
        rig_core::optics::OpticsConfig,
        ImageEffects,
        optics::Renderer,
    )>,
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

    /// [`Self::step`] without advancing the history: the scene at `time_s` as a step from
    /// `from` (a history saved by [`Self::history`]; `None`: the current one) would give it,
    /// after which the simulator is as it was (the caches aside, which hold no state of the
    /// contact). What the simulated rig answers for an instant between its steps, so that
    /// asking does not change the steps that follow.
    pub fn probe(
        &mut self,
        from: Option<&History>,
        scene: &Scene,
        time_s: f64,
    ) -> Result<SimOutput, SimError> {
        // The step replaces the history it starts from, so the current one is moved aside
        // when `from` takes its place, and copied only when the step starts from it.
        let current = match from {
            Some(h) => self.contact.replace_history(h.clone()),
            None => self.contact.history(),
        };
        let frames = self.frames;
        let out = self.step(scene, time_s);
        self.contact.replace_history(current);
        self.frames = frames;
        out
    }

    /// A copy of the contact's history (friction and relaxation), for [`Self::probe`].
    pub fn history(&self) -> History {
        self.contact.history()
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
                if self
                    .renderer
                    .as_ref()
                    .is_none_or(|(o, e, _)| o != optics || e != effects)
                {
                    let r = optics::Renderer::new(optics, effects);
                    self.renderer = Some((optics.clone(), *effects, r));
                }
                let (_, _, renderer) = self.renderer.as_ref().expect("just set");
                let (img, r) = renderer.render_counted(field, seed);
                let n = |v: u64| u32::try_from(v).unwrap_or(u32::MAX);
                stats.shaded_pixels = n(r.shaded_pixels);
                stats.markers_drawn = n(r.markers_drawn);
                stats.shadow_sweeps = n(r.shadow_sweeps);
                stats.blur_passes = n(r.blur_passes);
                stats.vignette_frames = n(r.vignette_frames);
                stats.noise_samples = n(r.noise_samples);
                Some(img)
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
