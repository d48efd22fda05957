//! Ground truth shared by the simulated devices.
//!
//! The simulated F/T front ends do not invent forces: they sample a [`WrenchSource`], the true
//! wrench of the scene at a clock time, and pass it through the sensor's inverse calibration.
//! The contact simulator implements it from the simulated robot's TCP pose; tests use simple
//! sources (constants, ramps) whose value at any time is known exactly.

use std::sync::Arc;

use rig_core::wrench::Wrench;

/// The true wrench at the F/T sensor's tool point at clock time `t_ns` (N, N·mm), in the frame
/// the sensor's tool transform maps to (see the F/T mock docs).
pub trait WrenchSource: Send + Sync + 'static {
    fn wrench_at(&self, t_ns: u64) -> Wrench;
}

/// A constant wrench.
#[derive(Debug, Clone, Copy)]
pub struct ConstantWrench(pub Wrench);

impl WrenchSource for ConstantWrench {
    fn wrench_at(&self, _t_ns: u64) -> Wrench {
        self.0
    }
}

/// Any `Fn(t_ns) -> Wrench` is a source.
impl<F> WrenchSource for F
where
    F: Fn(u64) -> Wrench + Send + Sync + 'static,
{
    fn wrench_at(&self, t_ns: u64) -> Wrench {
        self(t_ns)
    }
}

/// A shared, dynamically typed source.
pub type SharedWrenchSource = Arc<dyn WrenchSource>;
