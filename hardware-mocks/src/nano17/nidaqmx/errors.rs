//! The simulated card's status codes and messages, and NI's extended error information: the
//! text of the last error on the calling thread (`DAQmxGetExtendedErrorInfo`).
//!
//! The codes are NI-DAQmx's (`NIDAQmx.h`); the messages are the stand-in's own words, written
//! in NI's shape: what happened, then the property or device involved, then the status code.

use std::cell::RefCell;

pub use rig_core::ft::nidaqmx::code::*;

/// `DAQmxErrorInvalidTask`: the task handle is not a task (cleared, or never made).
pub const INVALID_TASK: i32 = -200088;
/// `DAQmxErrorInvalidAttributeValue`: a value the card does not support (range, rate, mode).
pub const INVALID_ATTRIBUTE_VALUE: i32 = -200077;
/// `DAQmxErrorReadBufferTooSmall`: the caller's array cannot hold the samples asked for.
pub const READ_BUFFER_TOO_SMALL: i32 = -200229;

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

/// A failed call: its status and the extended message.
#[derive(Debug, Clone, PartialEq)]
pub struct Fail {
    pub code: i32,
    pub message: String,
}

impl Fail {
    pub fn new(code: i32, detail: impl Into<String>) -> Self {
        Self {
            code,
            message: format!(
                "{}\n\n{}\n\nStatus Code: {code}",
                describe(code),
                detail.into()
            ),
        }
    }
}

/// Records `f` as the calling thread's last error and returns its code.
pub fn record(f: &Fail) -> i32 {
    LAST_ERROR.with(|e| *e.borrow_mut() = f.message.clone());
    f.code
}

/// The calling thread's last error message (`DAQmxGetExtendedErrorInfo`).
pub fn last_error() -> String {
    LAST_ERROR.with(|e| e.borrow().clone())
}

/// The one-line description of a code (`DAQmxGetErrorString`).
pub fn describe(code: i32) -> &'static str {
    match code {
        0 => "No error.",
        SAMPLES_NO_LONGER_AVAILABLE => {
            "Attempted to read samples that are no longer available: they were overwritten in \
             the buffer before they were read. Read more often or make the buffer larger."
        }
        SAMPLES_NOT_YET_AVAILABLE => {
            "Some or all of the samples requested have not yet been acquired before the \
             timeout elapsed."
        }
        INPUT_FIFO_OVERFLOW | INPUT_FIFO_OVERFLOW_2 => {
            "Onboard device memory overflow: the driver could not move data from the device \
             fast enough. The acquisition has stopped."
        }
        DEVICE_REMOVED => "The device has been removed from the system.",
        DEVICE_ABSENT => "The device is not present or not available.",
        INVALID_DEVICE_ID => "Device identifier is invalid.",
        PHYSICAL_CHANNEL_DOES_NOT_EXIST => {
            "Physical channel specified does not exist on this device."
        }
        RESOURCE_RESERVED => "The specified resource is reserved by another task.",
        INVALID_TASK => "Task specified is invalid or does not exist.",
        INVALID_ATTRIBUTE_VALUE => "Requested value is not a supported value for this property.",
        READ_BUFFER_TOO_SMALL => "The array is too small for the samples requested.",
        _ => "Unknown error.",
    }
}
