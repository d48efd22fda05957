//! Pure, I/O-free parts shared by the rig and its hardware mocks.
//!
//! The rig (`rig` crate) embeds the simulated rig (`hardware-mocks`) for its default, hardware-free
//! run, and the mocks need the same clock, pose maths, protocol codec, rig configuration and
//! indenter geometry. Those shared parts live here so that neither crate depends on the other's
//! I/O code and there is no dependency cycle.

pub mod clock;
pub mod config;
pub mod control;
pub mod ft;
pub mod indenter;
pub mod optics;
pub mod pose;
pub mod problem;
pub mod rtde;
pub mod urscript;
pub mod wrench;
