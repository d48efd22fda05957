//! Nano17 force/torque sensing (being written).

pub mod cli;
