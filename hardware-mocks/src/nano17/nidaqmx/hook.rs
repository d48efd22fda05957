//! The stand-in library's extra C symbols (beside NI's): how a simulator hands a simulated
//! card its clock, its true wrench and its faults, and how a test reads what the card did.
//!
//! These are plain C types, because the rig reaches the stand-in through `dlopen` like NI's
//! own library: nothing Rust-typed crosses that boundary. The symbols and their C signatures:
//!
//! ```text
//! int32 standin_attach(const char *device, const StandinHook *hook); // NULL hook: free-running
//! int32 standin_detach(const char *device);        // no callback runs after it returns
//! int32 standin_inject(const char *device, uInt32 fault, uInt64 at_sample, uInt64 arg);
//! int32 standin_log(const char *device, uInt64 max_samples);   // keep what the card read
//! uInt64 standin_log_read(const char *device, uInt64 first, uInt64 n, float64 *out);
//! int32 standin_stats(const char *device, StandinStats *out);
//! ```

use std::ffi::c_void;

/// Version of [`StandinHook`] this build understands.
pub const HOOK_VERSION: u32 = 1;

/// `now_ns(ctx)`: the simulator's clock, ns.
pub type NowFn = unsafe extern "C" fn(ctx: *mut c_void) -> u64;
/// `wrench_at(ctx, t_ns, out)`: writes the true wrench at the sensor's reference point, sensor
/// frame (`[Fx, Fy, Fz]` N, `[Tx, Ty, Tz]` N·mm), at clock time `t_ns` into `out[0..6]`.
pub type WrenchAtFn = unsafe extern "C" fn(ctx: *mut c_void, t_ns: u64, out: *mut f64);
/// `faults(ctx)`: the simulator's fault bits now ([`FAULT_BIT_REMOVED`], [`FAULT_BIT_OVERLOAD`]).
pub type FaultsFn = unsafe extern "C" fn(ctx: *mut c_void) -> u32;
/// `acquiring(ctx, on)`: a task on the device started (1) or stopped (0) acquiring. While one
/// runs, its reads poll `now_ns`; a simulator can pace its clock on those polls.
pub type AcquiringFn = unsafe extern "C" fn(ctx: *mut c_void, on: u32);

/// Fault bit: the card has been unplugged (reads fail with `-200045` from the current sample).
pub const FAULT_BIT_REMOVED: u32 = 1 << 0;
/// Fault bit: the sensor is overloaded (every gauge at its amplifier's limit).
pub const FAULT_BIT_OVERLOAD: u32 = 1 << 1;

/// What a simulator hands a simulated card (`standin_attach`). The callbacks must be callable
/// from any thread until `standin_detach` returns.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct StandinHook {
    /// [`HOOK_VERSION`].
    pub version: u32,
    pub ctx: *mut c_void,
    pub now_ns: Option<NowFn>,
    pub wrench_at: Option<WrenchAtFn>,
    /// `None`: no faults.
    pub faults: Option<FaultsFn>,
    /// `None`: not told.
    pub acquiring: Option<AcquiringFn>,
}

// The hook is a set of C callbacks the attaching side promises are thread-safe.
unsafe impl Send for StandinHook {}

/// Injected faults (`standin_inject`'s `fault`).
pub mod fault {
    /// The host stalls when its reads reach `at_sample`: the card overwrites unread samples and
    /// the read fails with `-200279`.
    pub const OVERRUN: u32 = 1;
    /// The card is unplugged at `at_sample`: reads fail with `-200045`.
    pub const REMOVE: u32 = 2;
    /// The card's onboard memory overflows at `at_sample`: the acquisition stops and reads
    /// fail with `-200361` until the task is restarted.
    pub const FIFO_OVERFLOW: u32 = 3;
    /// The sample clock starts `arg` ns of clock time after `DAQmxStartTask`.
    pub const LATE_START: u32 = 4;
    /// Clears every injected fault of the device.
    pub const CLEAR: u32 = 0;
}

/// What the card did (`standin_stats`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StandinStats {
    /// Samples per channel the card acquired in the current (or last) run of its task.
    pub acquired: u64,
    /// Samples per channel reads returned.
    pub returned: u64,
    /// Samples per channel acquired but never returned (overwritten or skipped by a read
    /// position jump).
    pub skipped: u64,
    /// Clock time of sample 0 of the current run, ns.
    pub first_sample_ns: u64,
    /// The sample clock's rate, Hz (0 before timing is configured).
    pub rate_hz: f64,
    /// Times the task was started.
    pub starts: u64,
    /// Values per logged sample ([`LOG_WIDTH`]).
    pub log_width: u64,
}

/// Values per logged sample: the six gauge channels and the thermistor channel as read, V.
pub const LOG_WIDTH: usize = 7;
