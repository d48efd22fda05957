//! RTDE errors, shared by every layer of the client.
//!
//! One enum for the whole link, because the reader task treats them alike (it reconnects, or
//! publishes the last one as the link's failure) and the callers show them to an operator:
//! each message names what to check on the robot, the network or the recipe.

use std::fmt;
use std::net::SocketAddr;
use std::time::Duration;

use rig_core::rtde::{DataType, DecodeError, EncodeError, TextMessage};

/// Which way a recipe goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecipeKind {
    Output,
    Input,
}

impl fmt::Display for RecipeKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Output => "output",
            Self::Input => "input",
        })
    }
}

/// What went wrong on the RTDE link. Messages say what the operator should check.
#[derive(Debug, Clone, thiserror::Error)]
pub enum RtdeError {
    #[error(
        "cannot reach the UR controller's RTDE port at {addr}: {reason}; check that the robot is powered, on the network, and that RTDE is enabled (Settings > Security > Services)"
    )]
    Connect { addr: SocketAddr, reason: String },
    #[error(
        "RTDE {kind} recipe: `{variable}` is not a controller {kind} variable (RTDE guide); fix the recipe"
    )]
    UnknownVariable { kind: RecipeKind, variable: String },
    #[error(
        "controller refused the RTDE {kind} recipe: no variable named `{variable}` (NOT_FOUND); the controller software may be too old for it"
    )]
    NotFound { kind: RecipeKind, variable: String },
    #[error(
        "controller refused the RTDE input recipe: `{variable}` is IN_USE by another client (a fieldbus, another RTDE program such as ur_rtde, or a second rig); close that client or choose free registers"
    )]
    InUse { variable: String },
    #[error("controller answered the {kind} recipe with {got} types for {sent} variables")]
    RecipeLength {
        kind: RecipeKind,
        sent: usize,
        got: usize,
    },
    #[error(
        "controller refused RTDE protocol versions 2 and 1; is port {0} really a UR controller's RTDE port?"
    )]
    ProtocolRefused(SocketAddr),
    #[error("controller refused to start RTDE streaming{messages}")]
    StartRefused { messages: String },
    #[error(
        "RTDE handshake stalled waiting for the {phase} reply ({timeout:?} of clock time){messages}"
    )]
    HandshakeTimeout {
        phase: &'static str,
        timeout: Duration,
        messages: String,
    },
    #[error("RTDE stream out of sync: {0}; the connection was dropped")]
    OutOfSync(DecodeError),
    #[error("the controller closed the RTDE connection{messages}")]
    Closed { messages: String },
    #[error("no RTDE data for {0:?} of clock time; is the controller still running?")]
    Stalled(Duration),
    #[error("RTDE I/O error: {0}")]
    Io(String),
    #[error("RTDE package could not be encoded: {0}")]
    Encode(#[from] EncodeError),
    #[error("RTDE link is down (reconnecting); try again when it is up")]
    NotConnected,
    #[error("no input recipe number {0}")]
    NoSuchRecipe(usize),
    #[error("input values do not match recipe {recipe}: expected {expected:?}, got {got:?}")]
    InputTypes {
        recipe: usize,
        expected: Vec<DataType>,
        got: Vec<DataType>,
    },
    #[error("gave up on the RTDE link after {attempts} attempts; last error: {last}")]
    GaveUp { attempts: u32, last: Box<RtdeError> },
    #[error("the RTDE client was shut down")]
    Shutdown,
    #[error("cannot {action} RTDE streaming while the link is {phase}")]
    WrongPhase {
        action: &'static str,
        phase: &'static str,
    },
    #[error("the controller refused to pause RTDE streaming{messages}")]
    PauseRefused { messages: String },
}

impl RtdeError {
    pub(super) fn io(e: std::io::Error) -> Self {
        Self::Io(e.to_string())
    }
}

/// The controller's recent text messages as a suffix for an error message (empty if none).
pub(super) fn describe_messages(msgs: &[TextMessage]) -> String {
    if msgs.is_empty() {
        return String::new();
    }
    let mut s = String::from("; controller messages: ");
    for (i, m) in msgs.iter().enumerate() {
        if i > 0 {
            s.push_str(" | ");
        }
        s.push_str(&format!("[{:?}] {}: {}", m.level, m.source, m.message));
    }
    s
}
