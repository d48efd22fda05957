//! One trajectory file, written beside its final name and renamed when complete.
//!
//! Life of a file: [`TrajectoryWriter::create`] opens `.<id>.mcap.partial` in the output
//! directory; [`TrajectoryWriter::write`] appends messages (every I/O error is returned, so a
//! full disk fails the trajectory at the message whose bytes did not fit); [`TrajectoryWriter::finish`]
//! writes the MCAP summary and footer, `fsync`s the file, renames it to `<id>.mcap` and `fsync`s
//! the directory so the rename itself survives a power cut. [`TrajectoryWriter::abort`] (and a
//! drop without `finish`) removes the partial. A crash can therefore leave a partial behind, never
//! a half-written file under the final name; resume ([`super::resume`](mod@super::resume)) removes stale partials.
//! Reading a file back is [`super::reader`].
//!
//! # The file's layout
//!
//! Chunked, compressed and indexed: messages go into zstd chunks of about 1 MiB (uncompressed),
//! each followed by its message indexes; the summary holds the schemas, channels, statistics
//! (message count per channel), chunk indexes and summary offsets, so an indexed reader seeks
//! by time and topic. Compression is single-threaded (`compression_threads(0)`): the recorder
//! runs on one blocking thread, and zstd's worker threads would compete with the run.
//!
//! # Write failures never panic
//!
//! The `mcap` crate (0.24) leaves its writer without its inner stream when an I/O error
//! interrupts a chunk, and its `Drop` (which finishes the file) then panics. The writer here
//! never lets the crate see an error: the crate writes into a `Sink` that records the first
//! I/O error of the file and from then on swallows every write and seek (they succeed and go
//! nowhere), so the crate's state stays consistent and its `Drop` finishes into the void.
//! [`TrajectoryWriter`] checks the sink after every call and fails the trajectory with the
//! recorded error; abandoning a file closes it and removes the partial. Should the crate ever
//! return an error of its own (not I/O), its writer is not dropped but forgotten
//! (`std::mem::forget`: a bounded leak of its buffers, the file already closed by the sink),
//! because its state after such an error is not known to be safe to drop.
use std::collections::BTreeMap;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::channels::{self, CHANNELS, ENCODING, Record};
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
    #[error(
        "the recording's disk ({dir}) completed no write for {limit_s:.0} s while {what}: it is \
         stalled or unreachable. Trajectories already complete are intact; once the disk is back, \
         run the same command with --resume to record the rest"
    )]
    Stalled {
        dir: PathBuf,
        limit_s: f64,
        what: String,
    },
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

/// Target uncompressed size of a chunk.
pub const CHUNK_SIZE: u64 = 1 << 20;

/// What the [`Sink`] shares with its [`TrajectoryWriter`].
#[derive(Debug)]
struct SinkState {
    /// The file; `None` once abandoned (closed) or handed back by `finish`.
    file: Option<BufWriter<File>>,
    /// Logical position: where the next byte would go.
    pos: u64,
    /// Highest position written (the logical end of the file).
    end: u64,
    /// The first I/O error; from then on writes and seeks go nowhere.
    error: Option<io::Error>,
    /// Test drill: fail (with an I/O error) once the file would pass this many bytes.
    fail_after: Option<u64>,
}

/// The stream under the `mcap` writer: never returns an error to it (see the module doc).
#[derive(Debug, Clone)]
struct Sink(Arc<Mutex<SinkState>>);

impl Sink {
    fn state(&self) -> std::sync::MutexGuard<'_, SinkState> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
}

impl SinkState {
    fn live(&mut self) -> Option<&mut BufWriter<File>> {
        if self.error.is_some() {
            return None;
        }
        self.file.as_mut()
    }
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut s = self.state();
        let pos = s.pos;
        let over = s
            .fail_after
            .is_some_and(|limit| pos + buf.len() as u64 > limit);
        if over {
            s.error = Some(io::Error::other(format!(
                "simulated write failure at byte {pos} (RecorderConfig::fail_after_bytes)"
            )));
        }
        if let Some(f) = s.live()
            && let Err(e) = f.write_all(buf)
        {
            s.error = Some(e);
        }
        s.pos += buf.len() as u64;
        s.end = s.end.max(s.pos);
        Ok(buf.len())
    }
    fn flush(&mut self) -> io::Result<()> {
        let mut s = self.state();
        if let Some(f) = s.live()
            && let Err(e) = f.flush()
        {
            s.error = Some(e);
        }
        Ok(())
    }
}

impl Seek for Sink {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let mut s = self.state();
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::Current(d) => s.pos.checked_add_signed(d),
            SeekFrom::End(d) => s.end.checked_add_signed(d),
        };
        let Some(target) = target else {
            // Only a bug in the crate could ask for this; it is an error of the file, reported
            // by the writer like an I/O error.
            s.error.get_or_insert_with(|| {
                io::Error::new(
                    io::ErrorKind::InvalidInput,
                    "seek before the start of the file",
                )
            });
            return Ok(s.pos);
        };
        // `stream_position` is a seek too: only a real move goes to the file (a BufWriter
        // flushes on every seek).
        if target != s.pos
            && let Some(f) = s.live()
            && let Err(e) = f.seek(SeekFrom::Start(target))
        {
            s.error = Some(e);
        }
        s.pos = target;
        Ok(target)
    }
}

/// Writer of one trajectory's MCAP file.
pub struct TrajectoryWriter {
    id: String,
    partial: PathBuf,
    final_path: PathBuf,
    dir: PathBuf,
    writer: Option<mcap::Writer<Sink>>,
    sink: Sink,
    channel_ids: BTreeMap<&'static str, u16>,
    sequence: u32,
    counts: Counts,
    /// Renamed to its final name: nothing to remove on drop.
    done: bool,
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
        Self::create_with(dir, id, None)
    }

    /// [`TrajectoryWriter::create`] with a write-failure drill: once the file would pass
    /// `fail_after_bytes`, every write fails (as a full disk would, with its own message).
    pub fn create_with(
        dir: &Path,
        id: &str,
        fail_after_bytes: Option<u64>,
    ) -> Result<Self, RecordError> {
        check_id(id)?;
        let partial = dir.join(partial_name(id));
        let file = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .open(&partial)
            .map_err(|source| RecordError::Io {
                path: partial.clone(),
                source,
            })?;
        let sink = Sink(Arc::new(Mutex::new(SinkState {
            file: Some(BufWriter::with_capacity(1 << 20, file)),
            pos: 0,
            end: 0,
            error: None,
            fail_after: fail_after_bytes,
        })));
        let mut w = Self {
            id: id.to_owned(),
            final_path: dir.join(final_name(id)),
            dir: dir.to_owned(),
            partial,
            writer: None,
            sink: sink.clone(),
            channel_ids: BTreeMap::new(),
            sequence: 0,
            counts: Counts::default(),
            done: false,
        };
        let opts = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            // zstd's fastest level: most bytes are camera JPEGs, which no level compresses,
            // and level 3 spent 3 % of a simulated run's CPU on them.
            .compression_level(1)
            .compression_threads(0)
            .chunk_size(Some(CHUNK_SIZE))
            .use_chunks(true)
            .profile("")
            .library(concat!("transforce-rig/", env!("CARGO_PKG_VERSION")));
        let created = opts.create(sink);
        w.writer = Some(w.checked(created)?);
        for (topic, schema_name) in CHANNELS {
            let writer = w.writer.as_mut().ok_or(RecordError::NotOpen)?;
            let sid = writer.add_schema(schema_name, ENCODING, &channels::schema_data(schema_name));
            let sid = w.checked(sid)?;
            let writer = w.writer.as_mut().ok_or(RecordError::NotOpen)?;
            let cid = writer.add_channel(sid, topic, ENCODING, &BTreeMap::new());
            let cid = w.checked(cid)?;
            w.channel_ids.insert(topic, cid);
        }
        Ok(w)
    }

    /// The result of an `mcap` call, with the sink's I/O error (if any) taking precedence: the
    /// crate itself never sees one.
    fn checked<T>(&mut self, r: mcap::McapResult<T>) -> Result<T, RecordError> {
        if let Some(source) = self.sink.state().error.take() {
            return Err(RecordError::Io {
                path: self.partial.clone(),
                source,
            });
        }
        r.map_err(|e| {
            // An error of the crate's own (not I/O): its state is unknown, so it is not dropped.
            if let Some(w) = self.writer.take() {
                self.close_file();
                std::mem::forget(w);
            }
            RecordError::from_mcap(&self.partial, e)
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
        // A frame's MCAP sequence is its camera sequence number (see `channels`); the other
        // channels count their messages in the file.
        let sequence = match rec {
            Record::Frame { seq, .. } => u32::try_from(*seq).map_err(|_| RecordError::Mcap {
                path: self.partial.clone(),
                message: format!(
                    "frame sequence number {seq} does not fit the MCAP message sequence (u32)"
                ),
            })?,
            _ => {
                self.sequence = self.sequence.wrapping_add(1);
                self.sequence
            }
        };
        let w = self.writer.as_mut().ok_or(RecordError::NotOpen)?;
        let r = w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id,
                sequence,
                log_time,
                publish_time: log_time,
            },
            &body,
        );
        self.checked(r)?;
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
        let mut meta = BTreeMap::new();
        meta.insert("id".to_owned(), self.id.clone());
        meta.insert(
            "counts".to_owned(),
            serde_json::to_string(&self.counts).unwrap_or_default(),
        );
        let w = self.writer.as_mut().ok_or(RecordError::NotOpen)?;
        let r = w.write_metadata(&mcap::records::Metadata {
            name: "rig.trajectory".into(),
            metadata: meta,
        });
        self.checked(r)?;
        let w = self.writer.as_mut().ok_or(RecordError::NotOpen)?;
        let r = w.finish();
        self.checked(r)?;
        let w = self.writer.take().ok_or(RecordError::NotOpen)?;
        drop(w.into_inner());
        let buf = self.sink.state().file.take().ok_or(RecordError::NotOpen)?;
        let file = buf.into_inner().map_err(|e| RecordError::Io {
            path: self.partial.clone(),
            source: e.into_error(),
        })?;
        file.sync_all().map_err(io(&self.partial))?;
        drop(file);
        fs::rename(&self.partial, &self.final_path).map_err(io(&self.final_path))?;
        self.done = true;
        sync_dir(&self.dir).map_err(io(&self.dir))?;
        Ok(self.counts.clone())
    }

    /// Give up on the trajectory: the partial file is removed.
    pub fn abort(self) {
        // Drop closes the file, drops the MCAP writer into the closed sink and removes the
        // partial.
        drop(self);
    }

    /// Closes the file and makes the sink swallow whatever the `mcap` writer still writes.
    fn close_file(&mut self) {
        let mut s = self.sink.state();
        s.error
            .get_or_insert_with(|| io::Error::other("the trajectory was abandoned"));
        s.file = None;
    }

    fn discard(&mut self) {
        self.close_file();
        // Dropping the writer finishes the file into the closed sink: nothing reaches the disk
        // and, the crate never having seen an error, nothing panics.
        drop(self.writer.take());
        let _ = fs::remove_file(&self.partial);
    }
}

impl Drop for TrajectoryWriter {
    fn drop(&mut self) {
        // After a successful finish the partial is already renamed: nothing to remove.
        if !self.done {
            self.discard();
        }
    }
}
