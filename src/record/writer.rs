//! One trajectory file, written beside its final name and renamed when complete.
//!
//! Life of a file: [`TrajectoryWriter::create`] opens `.<id>.mcap.partial` in the output
//! directory; [`TrajectoryWriter::write`] appends messages (every I/O error is returned, so a
//! full disk fails the trajectory at the message that did not fit); [`TrajectoryWriter::finish`]
//! writes the MCAP summary and footer, `fsync`s the file, renames it to `<id>.mcap` and `fsync`s
//! the directory so the rename itself survives a power cut. [`TrajectoryWriter::abort`] (and a
//! drop without `finish`) removes the partial. A crash can therefore leave a partial behind, never
//! a half-written file under the final name; resume ([`super::resume`]) removes stale partials.
//! Reading a file back is [`super::reader`].

use std::collections::BTreeMap;
use std::fs::{self, File, OpenOptions};
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use super::channels::{self, CHANNELS, Record};
use super::manifest::Counts;
use crate::durable::sync_dir;

/// File name of a complete trajectory.
pub fn final_name(id: &str) -> String {
    format!("{id}.mcap")
}

/// File name of a trajectory being written.
pub fn partial_name(id: &str) -> String {
    format!(".{id}.mcap.partial")
}

/// The trajectory id of a partial file name, if it is one.
pub fn partial_id(file_name: &str) -> Option<&str> {
    file_name.strip_prefix('.')?.strip_suffix(".mcap.partial")
}

/// Errors of recording, each saying what to do.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error(
        "writing {path}: {source}{hint}",
        hint = if is_disk_full(source) { " (the disk is full: free space or choose another --out; completed trajectories are intact)" } else { "" }
    )]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("writing MCAP {path}: {message}")]
    Mcap { path: PathBuf, message: String },
    #[error("trajectory id {0:?} is not a plain file name (letters, digits, '-', '_', '.')")]
    BadId(String),
    #[error("no trajectory is open: call begin first")]
    NotOpen,
    #[error("trajectory {0} is already open")]
    AlreadyOpen(String),
    #[error("the recorder's writer task has stopped: {0}")]
    WriterGone(String),
    #[error("trajectory {id} failed: {reason}")]
    Failed { id: String, reason: String },
}

fn is_disk_full(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::StorageFull || e.raw_os_error() == Some(28)
}

impl RecordError {
    fn from_mcap(path: &Path, e: mcap::McapError) -> Self {
        match e {
            mcap::McapError::Io(source) => RecordError::Io {
                path: path.to_owned(),
                source,
            },
            other => RecordError::Mcap {
                path: path.to_owned(),
                message: other.to_string(),
            },
        }
    }
}

/// Trajectory ids become file names: keep them plain.
pub fn check_id(id: &str) -> Result<(), RecordError> {
    let ok = !id.is_empty()
        && !id.starts_with('.')
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(())
    } else {
        Err(RecordError::BadId(id.to_owned()))
    }
}

/// Writer of one trajectory's MCAP file.
pub struct TrajectoryWriter {
    id: String,
    partial: PathBuf,
    final_path: PathBuf,
    dir: PathBuf,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    channel_ids: BTreeMap<&'static str, u16>,
    sequence: u32,
    counts: Counts,
}

impl std::fmt::Debug for TrajectoryWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TrajectoryWriter")
            .field("id", &self.id)
            .field("counts", &self.counts)
            .finish()
    }
}

impl TrajectoryWriter {
    /// Open `<dir>/.<id>.mcap.partial` (truncating a stale one) and declare every channel.
    pub fn create(dir: &Path, id: &str) -> Result<Self, RecordError> {
        check_id(id)?;
        let partial = dir.join(partial_name(id));
        let io = |source| RecordError::Io {
            path: partial.clone(),
            source,
        };
        let file = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .open(&partial)
            .map_err(io)?;
        let opts = mcap::WriteOptions::new()
            .compression(None)
            // No chunks: after an I/O error inside a chunk, mcap 0.24's writer is left without
            // its inner writer and panics when dropped. Unchunked files are read linearly by
            // every reader, and the summary still carries the per-channel message counts.
            .use_chunks(false)
            .profile("")
            .library(concat!("transforce-rig/", env!("CARGO_PKG_VERSION")));
        let mut writer = opts
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|e| RecordError::from_mcap(&partial, e))?;
        let mut channel_ids = BTreeMap::new();
        for (topic, schema_name, schema) in CHANNELS {
            let sid = writer
                .add_schema(
                    schema_name,
                    "jsonschema",
                    channels::schema_text(schema).as_bytes(),
                )
                .map_err(|e| RecordError::from_mcap(&partial, e))?;
            let cid = writer
                .add_channel(sid, topic, "json", &BTreeMap::new())
                .map_err(|e| RecordError::from_mcap(&partial, e))?;
            channel_ids.insert(topic, cid);
        }
        Ok(Self {
            id: id.to_owned(),
            final_path: dir.join(final_name(id)),
            dir: dir.to_owned(),
            partial,
            writer: Some(writer),
            channel_ids,
            sequence: 0,
            counts: Counts::default(),
        })
    }

    pub fn id(&self) -> &str {
        &self.id
    }

    /// Messages written so far, per kind.
    pub fn counts(&self) -> &Counts {
        &self.counts
    }

    /// Append one message.
    pub fn write(&mut self, rec: &Record) -> Result<(), RecordError> {
        let (topic, log_time, body) = rec.encode();
        let channel_id = self.channel_ids[topic];
        let w = self.writer.as_mut().ok_or(RecordError::NotOpen)?;
        self.sequence = self.sequence.wrapping_add(1);
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence: self.sequence,
                log_time,
                publish_time: log_time,
            },
            &body,
        )
        .map_err(|e| RecordError::from_mcap(&self.partial, e))?;
        match rec {
            Record::Frame { .. } => self.counts.frames += 1,
            Record::Wrench { .. } => self.counts.wrench += 1,
            Record::Pose { .. } => self.counts.poses += 1,
            Record::Paired(_) => self.counts.paired += 1,
            Record::Stage { .. } => self.counts.stages += 1,
            Record::Truth { .. } => self.counts.truth += 1,
        }
        Ok(())
    }

    /// Complete the file: summary, fsync, rename to `<id>.mcap`, fsync the directory.
    pub fn finish(mut self) -> Result<Counts, RecordError> {
        let io = |path: &Path| {
            let path = path.to_owned();
            move |source| RecordError::Io { path, source }
        };
        let mut w = self.writer.take().ok_or(RecordError::NotOpen)?;
        let mut meta = BTreeMap::new();
        meta.insert("id".to_owned(), self.id.clone());
        meta.insert(
            "counts".to_owned(),
            serde_json::to_string(&self.counts).unwrap_or_default(),
        );
        w.write_metadata(&mcap::records::Metadata {
            name: "rig.trajectory".into(),
            metadata: meta,
        })
        .map_err(|e| RecordError::from_mcap(&self.partial, e))?;
        w.finish()
            .map_err(|e| RecordError::from_mcap(&self.partial, e))?;
        let buf = w.into_inner();
        let file = buf.into_inner().map_err(|e| RecordError::Io {
            path: self.partial.clone(),
            source: e.into_error(),
        })?;
        file.sync_all().map_err(io(&self.partial))?;
        drop(file);
        fs::rename(&self.partial, &self.final_path).map_err(io(&self.final_path))?;
        sync_dir(&self.dir).map_err(io(&self.dir))?;
        Ok(self.counts.clone())
    }

    /// Give up on the trajectory: the partial file is removed.
    pub fn abort(mut self) {
        self.discard();
    }

    fn discard(&mut self) {
        if let Some(w) = self.writer.take() {
            // Dropping the MCAP writer tries to finish the partial; errors are irrelevant now, and
            // a panic inside the crate must not take the writer thread down with it.
            let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(move || drop(w)));
            let _ = fs::remove_file(&self.partial);
        }
    }
}

impl Drop for TrajectoryWriter {
    fn drop(&mut self) {
        self.discard();
    }
}
