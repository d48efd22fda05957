//! How the contact is simulated during a run ([`PhysicsConfig`]), with its defaults.

use std::io;

use rig_core::config::ElastomerConfig;

use crate::sim::{ContactModel, Effects, FrictionModel};

/// Default physics rate, Hz of clock time: two contact states per frame of a 25 fps camera.
/// The F/T twins read the wrench interpolated linearly between them (20 µm of motion apart at
/// the plan's 1 mm/s).
pub const DEFAULT_PHYSICS_RATE_HZ: f64 = 50.0;
/// Default number of `(t_ns, wrench)` samples kept: 4 s at 250 Hz.
pub const DEFAULT_HISTORY: usize = 1000;

/// How the contact is simulated during a run.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicsConfig {
    /// Physics steps per second of clock time.
    pub rate_hz: f64,
    /// Normal contact model.
    pub contact: ContactModel,
    /// Grid cell, mm (`None`: the simulator's default).
    pub cell_mm: Option<f64>,
    /// Tangential model; [`FrictionModel::Incremental`] carries stick/slip between steps.
    pub friction: FrictionModel,
    /// Apply the elastomer's viscoelastic relaxation (`[elastomer] instant_modulus_ratio`,
    /// `relaxation_time_s`) when it has one.
    pub viscoelastic: bool,
    /// Samples kept in the ring buffer (at least 2).
    pub history: usize,
    /// Step on demand too: a [`WrenchSource::wrench_at`](crate::truth::WrenchSource::wrench_at) or
    /// [`ContactPhysics::field_at`](super::ContactPhysics::field_at) for a
    /// time past the newest step first steps to the pose source's current pose, inline. The
    /// F/T mock and the camera then see the contact at their own sample time rather than up to
    /// a physics period (plus the task's wake-up delay, many ms on a scaled clock) late. The
    /// step runs on the caller's task (a few ms for the layer model at its default cell).
    pub on_demand: bool,
}

impl Default for PhysicsConfig {
    /// The sensor physics every command uses ([`Effects::sensor`]), stepped on demand at
    /// [`DEFAULT_PHYSICS_RATE_HZ`].
    fn default() -> Self {
        let sensor = Effects::sensor(&ElastomerConfig::default());
        Self {
            rate_hz: DEFAULT_PHYSICS_RATE_HZ,
            contact: sensor.contact,
            cell_mm: sensor.cell_mm,
            friction: sensor.friction,
            viscoelastic: true,
            history: DEFAULT_HISTORY,
            on_demand: true,
        }
    }
}

impl PhysicsConfig {
    /// The [`Effects`] of a physics step on `elastomer` (`surface_field` when a camera needs
    /// images).
    pub fn effects(&self, surface_field: bool, elastomer: &ElastomerConfig) -> Effects {
        Effects {
            contact: self.contact,
            cell_mm: self.cell_mm,
            friction: self.friction,
            viscoelastic: if self.viscoelastic {
                crate::sim::Viscoelastic::from_elastomer(elastomer)
            } else {
                None
            },
            surface_field,
            image: None,
        }
    }

    pub(super) fn validate(&self) -> io::Result<()> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(invalid(format!(
                "physics rate_hz must be > 0, got {}",
                self.rate_hz
            )));
        }
        if self.history < 2 {
            return Err(invalid(format!(
                "physics history must be at least 2, got {}",
                self.history
            )));
        }
        Ok(())
    }
}

/// An error for a setting out of range.
pub(super) fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}
