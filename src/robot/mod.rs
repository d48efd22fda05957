//! The UR5e: RTDE state stream, dashboard, control program and motion, behind one [`Robot`].
//!
//! How the rig moves the robot, and why this way:
//!
//! - **State** comes from RTDE ([`rtde`]): one output recipe at 500 Hz (e-Series) carrying the
//!   TCP pose, speed and force, the robot/safety/runtime modes and the control program's
//!   registers, decoded into a typed [`RobotState`] ([`state`]). A reader task publishes the
//!   latest state and every sample, and reconnects (recipes sent again) when the link fails.
//! - **Power and program control** go through the dashboard server ([`dashboard`]): power on,
//!   brake release, unlock protective stop, play/stop.
//! - **Motion** goes through the rig's own URScript program ([`urscript`]), uploaded over the
//!   secondary interface, which executes moveL and stop commands written to RTDE input
//!   registers and reports ack/done/status in output registers (`rig_core::control`). The
//!   sans-IO [`motion::MotionSequencer`] decides what to write and what the registers mean;
//!   [`Robot`] does the I/O.
//! - **Safety**: a move starts only when the robot is RUNNING, safety NORMAL or REDUCED and
//!   the program PLAYING (RTDE guide); every sample during a move is checked again, and a
//!   protective stop, emergency stop or program stop ends the move with an error that names
//!   the move's label (trajectory and stage). After such a fault every move is refused until
//!   [`Robot::recover`] has unlocked the stop and re-uploaded the program. A heartbeat is
//!   written on every RTDE output cycle (by the robot's own task, or by the run's safety
//!   supervisor once it holds the [`SafetyLine`]); the program arms the controller's RTDE
//!   watchdog on it (`rtde_set_watchdog`), so the program stops if the heartbeat stops. The
//!   same line carries the supervisor's stop request, served before any command.
//!
//! **Link loss during a move** ([`LinkLossPolicy`]): the reader task reconnects by itself.
//! With [`LinkLossPolicy::ContinueIfSafe`] (the default) the move then resumes when that is
//! safe: if the program is still running the move simply goes on; if the program stopped
//! (the watchdog fires after `1 / watchdog_min_hz` of silence) and the robot stands still in
//! RUNNING/NORMAL, the program is uploaded again and the interrupted move is re-issued with a
//! new sequence number (a moveL to the same target is harmless to repeat: it ends at the same
//! pose). Otherwise — the robot is still moving with no program, the safety state is not
//! normal, or the link does not come back within `reconnect_timeout` — the move ends with
//! [`MotionError::LinkLost`]. With [`LinkLossPolicy::Abort`] every link loss during a move ends
//! it with `LinkLost` (after a best-effort Stop once the link is back).
//!
//! [`Robot`]'s I/O is in `facade.rs`; its settings (`config.rs`), the moves it takes and the
//! reports it returns (`moves.rs`) and its errors (`error.rs`) have files of their own, as
//! they are what callers such as the run loop build and read without the I/O.

pub mod dashboard;
pub mod motion;
pub mod rtde;
pub mod state;
pub mod urscript;

mod config;
mod error;
mod facade;
mod moves;
mod safety_line;

pub use config::{LinkLossPolicy, RobotEndpoints, RobotOptions};
pub use dashboard::{Dashboard, DashboardError};
pub use error::MotionError;
pub use facade::{Robot, upload_program};
pub use motion::{CommandWrite, Fault, FaultRecord, MotionSequencer, SeqEvent, SequencerConfig};
pub use moves::{LoggedState, Move, MoveReport, MovesLog};
pub use rtde::{LinkStatus, RtdeClient, RtdeConfig, RtdeError, RtdeHandle, RtdeStats};
pub use safety_line::SafetyLine;
pub use state::RobotState;
