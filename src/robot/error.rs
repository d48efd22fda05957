//! Why a motion call failed, in words an operator can act on.
//!
//! The sequencer reports facts (a [`Fault`] with the mode that caused it, a [`Refusal`]); the
//! errors here add the move's label, what to do next and the controller's last text messages,
//! because at the rig the error message is often all the operator sees.

use std::net::SocketAddr;
use std::time::Duration;

use super::dashboard::DashboardError;
use super::motion::{Fault, FaultRecord, Refusal};
use super::rtde::RtdeError;

/// Why a motion call failed. Each says what the operator should do.
#[derive(Debug, Clone, thiserror::Error)]
pub enum MotionError {
    #[error(
        "move `{label}` refused: robot not ready ({modes}); run prepare() (power on, brake release, program upload) or check the teach pendant"
    )]
    NotReady { label: String, modes: String },
    #[error(
        "move `{label}` refused: motion is blocked since {previous}; inspect the robot, then call recover()"
    )]
    NeedsRecovery { label: String, previous: String },
    #[error(
        "protective stop during move `{label}` ({mode}); the robot stopped. Inspect the cause, then call recover() (unlocks the stop after UR's 5 s delay and restarts the program){messages}"
    )]
    ProtectiveStop {
        label: String,
        safety_mode: i32,
        mode: String,
        messages: String,
    },
    #[error(
        "emergency stop during move `{label}` ({mode}); release the emergency stop, then call recover(){messages}"
    )]
    EmergencyStop {
        label: String,
        safety_mode: i32,
        mode: String,
        messages: String,
    },
    #[error(
        "the control program stopped during move `{label}` ({state}); check the teach pendant for an error, then call recover(){messages}"
    )]
    ProgramStopped {
        label: String,
        runtime_state: u32,
        state: String,
        messages: String,
    },
    #[error("the robot left RUNNING during move `{label}` ({mode}); call recover(){messages}")]
    RobotNotRunning {
        label: String,
        robot_mode: i32,
        mode: String,
        messages: String,
    },
    #[error("the control program rejected move `{label}` (bad speed or acceleration?)")]
    Rejected { label: String },
    #[error(
        "move `{label}`: the control program did not acknowledge within {after:?}; is it running? Call recover()"
    )]
    AckTimeout { label: String, after: Duration },
    #[error(
        "move `{label}` did not finish within {after:?}; check speed scaling on the pendant, then call recover()"
    )]
    MoveTimeout { label: String, after: Duration },
    #[error("RTDE link lost during move `{label}`: {reason}; the move was abandoned")]
    LinkLost { label: String, reason: String },
    #[error("{0}")]
    BadMove(String),
    #[error("{step}: {reason}")]
    Prepare { step: &'static str, reason: String },
    #[error(
        "cannot upload the control program to the secondary interface at {addr}: {reason}; check that the robot is in Remote Control mode"
    )]
    Upload { addr: SocketAddr, reason: String },
    #[error(transparent)]
    Rtde(#[from] RtdeError),
    #[error(transparent)]
    Dashboard(#[from] DashboardError),
}

impl MotionError {
    /// The error for a fault the sequencer raised during move `rec.label`; `messages` is the
    /// controller's recent text messages as a suffix (empty if none).
    pub(super) fn from_fault(rec: FaultRecord, messages: String) -> Self {
        let label = rec.label;
        // Each mode fault is its own variant (callers match on which stop it was); they share
        // only the name lookup.
        let mode = rec.fault.mode_name().unwrap_or_default().to_owned();
        match rec.fault {
            Fault::ProtectiveStop { safety_mode } => Self::ProtectiveStop {
                label,
                safety_mode,
                mode,
                messages,
            },
            Fault::EmergencyStop { safety_mode } => Self::EmergencyStop {
                label,
                safety_mode,
                mode,
                messages,
            },
            Fault::ProgramStopped { runtime_state } => Self::ProgramStopped {
                label,
                runtime_state,
                state: mode,
                messages,
            },
            Fault::RobotNotRunning { robot_mode } => Self::RobotNotRunning {
                label,
                robot_mode,
                mode,
                messages,
            },
            Fault::Rejected => Self::Rejected { label },
            Fault::AckTimeout { after } => Self::AckTimeout { label, after },
            Fault::MoveTimeout { after } => Self::MoveTimeout { label, after },
        }
    }

    /// The error for move `label`, which the sequencer refused to issue.
    pub(super) fn from_refusal(label: &str, r: Refusal) -> Self {
        match r {
            Refusal::Faulted(f) => Self::NeedsRecovery {
                label: label.into(),
                previous: f.to_string(),
            },
            Refusal::NotAllowed(modes) => Self::NotReady {
                label: label.into(),
                modes,
            },
            other => Self::BadMove(other.to_string()),
        }
    }
}
