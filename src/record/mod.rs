//! Recording: one MCAP file per trajectory, a run manifest, resume, and a bounded writer.
//!
//! - [`channels`]: the six channels (frames, wrench, TCP pose, paired wrench, stage labels and,
//!   on the simulated rig, the true wrench), their schemas and protobuf bodies ([`Record`]).
//! - [`proto`]: the hand-written protobuf encoder, field reader and `FileDescriptorSet`s.
//! - [`png`]: the lossless PNG of raw-pixel frames, and decoding either stored image format.
//! - [`writer`]: [`TrajectoryWriter`] writes `.<id>.mcap.partial` (zstd chunks, indexed), then
//!   fsyncs and renames it to `<id>.mcap` when the trajectory completes; a failed write never
//!   panics (see its module doc).
//! - [`reader`]: the one reader of trajectory files ([`read_file`], [`reader::messages`]), for
//!   `rig dataset check`, `rig dataset export`, `--resume` and the trainer; it reads today's
//!   protobuf files and the first format's JSON ones ([`legacy`]).
//! - [`manifest`]: `manifest.json` (config, calibration, indenter, sensor, software version and
//!   every trajectory's status), written atomically ([`crate::durable`]).
//! - [`resume`](mod@resume): which planned trajectories are complete and which must be redone.
//! - [`pipeline`]: [`Recorder`], the tokio-facing bounded queue in front of a blocking writer.
//! - [`synthetic`]: generated trajectories (small PNGs, smooth wrench and pose) for tests.
//!
//! # Why the `mcap` crate, not `foxglove`
//!
//! The `foxglove` SDK (0.16) can write one file per trajectory with its own `Context`, but its
//! `Channel::log` returns nothing: a failed write to a sink is only reported through a
//! `tracing` warning ("error logging message") and the message is gone. A recorder that must fail
//! a trajectory on a full disk, and never keep a file that silently lost frames, needs the error
//! at the write, which the `mcap` crate's `Writer::write_to_known_channel` returns (through the
//! writer's error-recording sink, [`writer`]). The `mcap` crate (with its `zstd` feature only)
//! also leaves the file's life (partial name, fsync, rename) to us. The Foxglove schemas are
//! written out here ([`proto`]) rather than taken from the SDK; the live view (Foxglove
//! WebSocket) advertises the same channels and encodings.

pub mod channels;
pub mod legacy;
pub mod manifest;
pub mod pipeline;
pub mod png;
pub mod proto;
pub mod reader;
pub mod resume;
pub mod synthetic;
pub mod writer;

pub use channels::{
    CHANNELS, ImageFormat, Record, TOPIC_IMAGE, TOPIC_PAIRED, TOPIC_POSE, TOPIC_STAGE, TOPIC_WRENCH,
};
pub use manifest::{Counts, MANIFEST_NAME, Manifest, SensorInfo, Status, TrajectoryEntry};
pub use pipeline::{Recorder, RecorderConfig, RecorderStats, STALL_LIMIT, WriterGate};
pub use reader::{FileContents, read_file};
pub use resume::{ResumePlan, resume};
pub use writer::{RecordError, TrajectoryWriter, final_name, partial_name};
