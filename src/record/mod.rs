//! Recording: one MCAP file per trajectory, a run manifest, resume, and a bounded writer.
//!
//! - [`channels`]: the six channels (frames, wrench, TCP pose, paired wrench, stage labels and,
//!   on the simulated rig, the true wrench), their JSON schemas and message bodies ([`Record`]).
//! - [`png`]: the lossless frame encoding of the recordings.
//! - [`writer`]: [`TrajectoryWriter`] writes `.<id>.mcap.partial`, then fsyncs and renames it to
//!   `<id>.mcap` when the trajectory completes.
//! - [`reader`]: the one reader of trajectory files ([`read_file`], [`reader::messages`]), for
//!   `rig dataset check`, `--resume` and the trainer.
//! - [`manifest`]: `manifest.json` (config, calibration, indenter, sensor, software version and
//!   every trajectory's status), written atomically ([`crate::durable`]).
//! - [`resume`]: which planned trajectories are complete and which must be redone.
//! - [`pipeline`]: [`Recorder`], the tokio-facing bounded queue in front of a blocking writer.
//! - [`synthetic`]: generated trajectories (small PNGs, smooth wrench and pose) for tests.
//!
//! # Why the `mcap` crate, not `foxglove`
//!
//! The `foxglove` SDK (0.16) can write one file per trajectory with its own `Context`, but its
//! `Channel::log` returns nothing: a failed write to a sink is only reported through a
//! `tracing` warning ("error logging message") and the message is gone. A recorder that must fail
//! a trajectory on a full disk, and never keep a file that silently lost frames, needs the error
//! at the write, which the `mcap` crate's `Writer::write_to_known_channel` returns. The `mcap`
//! crate (without default features: uncompressed, no C dependencies) also leaves the file's life
//! (partial name, fsync, rename) to us and builds in seconds. The price is that the Foxglove
//! schemas are written out here as JSON schemas (`foxglove.CompressedImage`,
//! `foxglove.PoseInFrame`) rather than taken from the SDK's protobuf descriptors, and images are
//! base64 in JSON (a third larger than raw bytes); the Foxglove app reads both. The live view
//! (Foxglove WebSocket) is a separate concern and can still use the `foxglove` crate.

pub mod channels;
pub mod manifest;
pub mod pipeline;
pub mod png;
pub mod reader;
pub mod resume;
pub mod synthetic;
pub mod writer;

pub use channels::{
    CHANNELS, Record, TOPIC_IMAGE, TOPIC_PAIRED, TOPIC_POSE, TOPIC_STAGE, TOPIC_WRENCH,
};
pub use manifest::{Counts, MANIFEST_NAME, Manifest, SensorInfo, Status, TrajectoryEntry};
pub use pipeline::{Recorder, RecorderConfig, RecorderStats, WriterGate};
pub use reader::{FileContents, read_file};
pub use resume::{ResumePlan, resume};
pub use writer::{RecordError, TrajectoryWriter, final_name, partial_name};
