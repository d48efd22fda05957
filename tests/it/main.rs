//! The rig's integration tests, in one test binary.
//!
//! Every file under `tests/` would otherwise be its own binary, and each one links the whole
//! `rig` library with burn: on a two-core CI machine that linking alone cost minutes. One binary
//! also lets the harness run the long tests (the quick demo, the simulated-rig runs) beside the
//! short ones. Each module is one area; `common` holds the helpers they share.
//!
//! Tests that share a process-wide resource say so and take a lock for it: simulated-rig runs
//! take [`common::one_rig_at_a_time`], and the in-process trainings take the trainer's lock
//! (burn's random generator is one per process).

mod common;

mod bench_sim;
mod camera_sim;
mod camera_v4l2;
mod contact_cache;
mod dataset_check;
mod demo;
mod disk_budget;
mod docs;
mod fault_drills;
mod flange_force;
mod flow;
mod ft_daq;
mod ft_netft;
mod ft_nidaqmx;
mod ft_serial;
mod inception;
mod live_view;
mod markers;
mod mcap_python;
mod plan_cli;
mod predict;
mod record_pipeline;
mod recording_format;
mod reproduce;
mod robot_faults;
mod robot_motion;
mod rtde_codec_props;
mod rtde_pause;
mod run_acceptance;
mod run_record;
mod safe_motion;
mod sim_cli;
mod sim_physics;
mod sim_sensor;
mod sync_bench;
mod sync_clock;
mod sync_pairer;
mod trainer;
mod ur_rtde_interop;
