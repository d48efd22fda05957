//! The simulated hardware's integration tests, in one test binary (one link instead of one per
//! file); `common` is the small sans-IO RTDE client they share.

mod common;

mod contact_convergence;
mod contact_effects;
mod contact_hard_cases;
mod contact_physics;
mod contact_tape;
mod nano17;
mod optics_indenters;
mod optics_render;
mod optics_sensors;
mod rig_sim;
mod ur5e;
mod ur5e_program;
