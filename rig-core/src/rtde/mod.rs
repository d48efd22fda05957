//! RTDE (Real-Time Data Exchange), UR's TCP protocol on port 30004: the sans-IO codec and
//! the controller's variable table. The async client lives in the `rig` crate
//! (`rig::robot::rtde`), the simulated controller's server in `hardware-mocks`.

pub mod codec;
pub mod fields;

pub use codec::*;
