//! [`FtError`]: what went wrong with an F/T stream or its settings. Messages say what to check.

use rig_core::ft::SampleFlags;
use rig_core::ft::cal::CalError;
use rig_core::ft::transform::TransformError;

/// What went wrong with the F/T sensor.
#[derive(Debug, Clone, thiserror::Error)]
pub enum FtError {
    #[error(
        "cannot open F/T port {port}: {reason}; is the sensor plugged in, and is another rig using it?"
    )]
    PortOpen { port: String, reason: String },
    #[error("F/T port {port} closed: {reason}; was the cable unplugged or the device powered off?")]
    PortClosed { port: String, reason: String },
    #[error(
        "no answer from the F/T device at {device} within {timeout_ms} ms ({what}); check the cable, baud rate and power"
    )]
    NoAnswer {
        device: String,
        what: String,
        timeout_ms: u64,
    },
    #[error("F/T I/O error on {device}: {reason}")]
    Io { device: String, reason: String },
    #[error(
        "F/T sensor saturated ({flags}); the stream was stopped (force_sensor.saturation = \"stop\")"
    )]
    Saturated { flags: SampleFlags },
    #[error(transparent)]
    Calibration(#[from] CalError),
    #[error("force_sensor tool transform: {0}")]
    Transform(#[from] TransformError),
    #[error("force_sensor config: {0}")]
    Config(String),
    /// The NI-DAQmx library could not be loaded (the message says what to install).
    #[error("{0}")]
    NiLibrary(String),
    /// An NI-DAQmx call failed: NI's own message, and what to check.
    #[error("NI-DAQmx {call} failed with status {code}: {message}{}", hint.as_ref().map(|h| format!(" ({h})")).unwrap_or_default())]
    Ni {
        call: String,
        code: i32,
        message: String,
        hint: Option<String>,
    },
    #[error("F/T stream already stopped")]
    Stopped,
}
