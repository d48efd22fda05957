//! The TransForce rig: contact-plan data collection for vision-based tactile sensors, and the
//! TransForce trainer.
//!
//! # The house
//!
//! Three crates, three layers, each importing only the ones below it:
//!
//! - **`rig-core`**: pure, shared parts with no I/O: the clock, pose maths, the RTDE codec,
//!   the rig config and its validation, indenters, F/T framing, calibration and sequence
//!   tracking, the control register map. Both other crates use it.
//! - **`hardware-mocks`**: the simulated rig (UR5e, Nano17 twins, GelSight camera, one contact
//!   + optics simulator). In this crate only [`simrig`] imports it.
//! - **`rig`** (this crate), in rooms:
//!   - the **command layer**, [`cli`]: one file per subcommand; it parses, resolves the rig
//!     config, calls the domain rooms and prints. No other room imports it.
//!   - the **lab devices**: [`robot`] (the UR5e over RTDE, the dashboard and the rig's own
//!     URScript control program), [`force`] (Nano17 front ends: serial, Net F/T, DAQ),
//!     [`camera`] (the [`camera::FrameSource`] trait and V4L2). They know nothing of a
//!     simulator.
//!   - the **pipeline**: [`plan`] (the contact plan, every waypoint checked against the
//!     envelope), [`sync`] (clock estimators and frame/wrench pairing), [`record`] (MCAP files,
//!     the manifest, resume, the one reader), [`durable`] (atomic files), [`run`] (`rig run`,
//!     which drives the robot along the plan and records it), [`live`] (the Foxglove live
//!     view).
//!   - **after the recording**: [`dataset`] (`rig dataset check`), [`train`] (CycleGAN
//!     translation, the force model, evaluation, the demo), [`chart`] (the plots' house style).
//!   - **the product in use**: [`predict`] (`rig predict`): a trained force model on the
//!     target sensor's camera, frame by frame ([`predict::Predictor`], the library entry point
//!     a robot program embeds), replaying a recording through the same path, or reading the
//!     simulated sensor while the simulated robot runs a short plan.
//!   - the **simulated rig**, [`simrig`]: starts `hardware-mocks` in-process and hands the rest
//!     lab-shaped things (robot endpoints, an F/T stream read by the lab front end, a frame
//!     source). The simulator's ground truth travels with its frames
//!     ([`camera::Frame::truth`]).
//!
//! # Two data flows
//!
//! **A frame, from the camera to the MCAP file.** The camera's reader thread (V4L2, or the
//! simulated camera) stamps each frame and counts sequence gaps ([`camera::Frame`]); the
//! camera task of [`run::streams`] watches for stalls and hands it to the encoder thread
//! ([`run::streams::stored_image`]: an MJPEG camera's JPEG as received, else lossless PNG,
//! [`record::png`]); the collector ([`run::collector`]) gives it to the pairer
//! ([`sync::Pairer`]), which maps its time onto the rig clock and interpolates the wrench at
//! it; the collector queues the frame, its paired wrench (and on the simulated rig its true
//! wrench) on the [`record::Recorder`], whose writer thread writes them into the trajectory's
//! `.partial` file ([`record::TrajectoryWriter`]), renamed when the trajectory completes.
//!
//! **An F/T sample, from the parser to the paired wrench.** A front end's reader
//! ([`force::serial`], [`force::netft`], [`force::daq`]) parses records with `rig-core`'s
//! framing, tracks the device's sequence (loss, reordering), converts counts or gauge volts to
//! a tared wrench at the tool point and delivers a [`force::WrenchSample`] stamped on the rig
//! clock; the F/T task of [`run::streams`] checks the force limit and saturation on it and
//! forwards it; the collector writes it and feeds it to the pairer, whose estimator maps the
//! device's sample counter onto the rig clock, so each frame's wrench is interpolated between
//! the samples around its capture time.
//!
//! **A frame, from the camera to a force estimate** (`rig predict`). A source thread
//! ([`predict::source`]: the V4L2 reader, the simulated camera's frames as a short `rig run`
//! records them, or a replayed recording) hands each frame to a one-frame mailbox
//! ([`predict::session::Feed`]) and goes back to its camera; the predictor's thread takes the
//! newest frame, decodes it, puts it into the model's modality and size exactly as training
//! did ([`train::data::prepare_image`]), encodes it once, runs the LSTM over the last T frames'
//! cached embeddings at `rig eval`'s stride ([`predict::Predictor`]), subtracts the tare and
//! writes the estimate to stdout, an MCAP file and the live view's `/predict/wrench`
//! ([`predict::output`]).
//!
//! # Time
//!
//! There is one clock, `rig_core::clock::Clock` (the system clock, or a simulated one that may
//! run faster than real time); every device is stamped on it. Time values carry their unit in
//! the name (`t_ns`, `*_ns` for clock nanoseconds, `*_us`, `*_ms`, `*_s`) or are a
//! `std::time::Duration`.

pub mod camera;
pub mod chart;
pub mod cli;
pub mod dataset;
pub mod durable;
pub mod force;
pub mod live;
pub mod markers;
pub mod plan;
pub mod predict;
pub mod record;
pub mod robot;
pub mod run;
pub mod simrig;
pub mod sync;
pub mod train;

/// The rig's cache directory, `${XDG_CACHE_HOME:-~/.cache}/rig`: the Inception weights, the
/// simulated rig's contact tapes. Nothing in it is precious: each user of it can make it again.
pub fn cache_root() -> std::path::PathBuf {
    std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(std::path::PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".cache")))
        .unwrap_or_else(|| std::path::PathBuf::from(".cache"))
        .join("rig")
}
