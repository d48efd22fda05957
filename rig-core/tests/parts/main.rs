//! rig-core's integration tests, in one test binary (one link instead of one per file).

mod config;
mod ft_cal;
mod ft_protocols;
mod indenter;
mod pose;
