//! The TransForce rig: contact-plan data collection for vision-based tactile sensors.
//!
//! - [`plan`]: the contact plan (points × depths × directions; down → shear → reverse → up),
//!   every waypoint checked against the rig's safety envelope before anything moves.
//! - [`robot`]: the UR5e over RTDE, the dashboard and the rig's own URScript control program.
//! - [`run`]: `rig run`, which joins them, on the lab rig or the built-in simulated one.
//! - [`cli`]: the `rig` command line.
//!
//! Pure, shared parts (clock, pose maths, RTDE codec, config, indenters) live in `rig-core`;
//! the simulated hardware lives in `hardware-mocks`.

pub mod camera;
pub mod chart;
pub mod cli;
pub mod dataset;
pub mod durable;
pub mod force;
pub mod live;
pub mod plan;
pub mod record;
pub mod robot;
pub mod run;
pub mod simrig;
pub mod sync;
pub mod train;
