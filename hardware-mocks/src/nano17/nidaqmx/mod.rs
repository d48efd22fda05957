//! A simulated NI data-acquisition card with the Nano17 wired to it (ATI's DAQ F/T system),
//! behind the subset of NI-DAQmx's C API the rig uses. The `nidaqmx-standin` crate exports it
//! as a C library with NI's symbols, so the rig's NI reader is tested through its real
//! `dlopen` path; this module is that library's behaviour, testable without the C shell.
//!
//! # The card
//!
//! An X-series-like multifunction card per device name (`Dev1` exists from the start; a
//! simulator or test adds others with `standin_attach`): analog inputs `ai0`..`ai15`, bipolar
//! input ranges ±0.2, ±1, ±5 and ±10 V (the smallest that holds the requested span is used, and
//! a reading clamps at it), 250 kS/s aggregate. The Nano17 is wired the way ATI wires it:
//! gauges G0..G5 on `ai0`..`ai5`, the thermistor on `ai6`; other inputs read 0 V. The voltages
//! come from [`SensorModel`](super::SensorModel) (the simulated Nano17's calibration, zero-load offsets, noise,
//! thermistor), sampling the true wrench the device's hook gives, or zero without a hook.
//!
//! # Timing
//!
//! A started task's sample clock ticks at the configured rate from `DAQmxStartTask` (plus an
//! injected late start): sample `k` is taken at `t0 + k / rate` on the device's clock, the
//! hook's (a simulator's clock, which may run faster than real time) or real time without one.
//! A read waits until its samples have been taken (its timeout counts on that clock); a sample
//! is generated when it is first read, at its own time. The buffer holds the configured number
//! of samples per channel: a read of samples older than `acquired − buffer` fails with
//! `-200279` (in overwrite mode the acquisition goes on; the read position may be moved with
//! `DAQmx_Read_RelativeTo` / `DAQmx_Read_Offset`).
//!
//! # Faults ([`hook::fault`])
//!
//! Overrun at sample N (the host stalls when its reads reach N, until the card has overwritten
//! the unread samples), removal at sample N (`-200045`), onboard FIFO overflow at N (the
//! acquisition stops, `-200361`), late start (the sample clock starts late), and the hook's own
//! fault bits (a simulator unplugging the card or overloading the sensor mid-run). A wrong
//! device or channel name is refused as NI refuses it (`-200220`, `-200170`).

mod card;
pub mod errors;
pub mod hook;
mod task;

pub use card::{
    AI_CHANNELS, Channel, DEFAULT_DEVICE, DEFAULT_SEED, MAX_AGGREGATE_RATE, RANGES_V, ReadOutcome,
    System, THERMISTOR_INPUT, Wire, wire,
};
