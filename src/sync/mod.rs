//! Time: device clocks onto the host clock, and each frame paired with the wrench at its time.
//!
//! Everything here is sans-IO (the quinn-proto model): the functions and state
//! machines take the host time of each observation as an argument and never read a clock, so
//! every timing case (counter wrap, clock jump, drift, jitter, drops) is a deterministic test.
//!
//! - [`clock_map`]: [`ClockEstimator`], an offset + skew fit of one device clock against the host
//!   clock (lower convex hull of one-way stamps, Olson-style min-latency decimation, drift bound,
//!   jump detection with re-lock); [`Unwrapper`] for wrapping counters; [`DeviceClock`] joining
//!   a device's raw stamps to the estimator.
//! - [`interp`]: the wrench at a frame time (nearest, linear, cubic Hermite/Catmull-Rom) with
//!   the sync error, refusing extrapolation beyond a bound and interpolation across gaps.
//! - [`pairer`]: [`Pairer`], fed frames, wrench samples, poses and stage changes in any order,
//!   emitting [`PairedFrame`]s once the wrench stream has passed each frame's time, and counting
//!   frame drops from sequence gaps.

pub mod clock_map;
pub mod interp;
pub mod pairer;

pub use clock_map::{
    ClockEstimator, ClockEvent, DeviceClock, DeviceStamp, DeviceTimebase, EstimatorConfig, Mapping,
    Unwrapper,
};
pub use interp::{
    InterpError, InterpLimits, InterpMethod, Interpolated, TimedWrench, interpolate,
    mid_exposure_ns,
};
pub use pairer::{
    FrameIn, PairedFrame, Pairer, PairerConfig, PairerStats, SeqGap, SyncStatus, WrenchIn,
};
