//! The simulated rig: hardware mocks that speak the real devices' protocols over real sockets,
//! so the rig (and third-party clients such as PyPI `ur-rtde`) can run against them unchanged.
//!
//! - [`ur5e`]: a UR5e controller — RTDE server at 500 Hz, dashboard server, secondary interface
//!   whose URScript interpreter runs the programs it is sent (the rig's control program among
//!   them), a trapezoidal moveL model and injectable
//!   faults (protective stop, emergency stop, RTDE connection drop, delayed start
//!   acknowledgement, text messages mid-handshake).
//! - [`sim`]: the contact + optics simulator that turns one scene into forces and images.
//! - [`camera`]: the simulated GelSight camera, rendering the scene at its (imperfect) frame
//!   rate on the shared clock.
//! - [`truth`]: the ground truth (true wrench) the simulated devices sample.
//!
//! Every mock takes its time from one [`rig_core::clock::Clock`], so the whole simulated rig can
//! run faster than real time (`Clock::scaled`) or be stepped by a test (`Clock::manual`). The
//! mocks run in-process (tests, `rig run` without hardware) or as separate processes through the
//! `rig-mock` binary.

pub mod camera;
pub mod nano17;
pub mod rig_sim;
pub mod sim;
pub mod truth;
pub mod ur5e;
