//! One trajectory file: written beside its final name, renamed when complete; and read back.
//!
//! Life of a file: [`TrajectoryWriter::create`] opens `.<id>.mcap.partial` in the output
//! directory; [`TrajectoryWriter::write`] appends messages (every I/O error is returned, so a
//! full disk fails the trajectory at the message that did not fit); [`TrajectoryWriter::finish`]
//! writes the MCAP summary and footer, `fsync`s the file, renames it to `<id>.mcap` and `fsync`s
//! the directory so the rename itself survives a power cut. [`TrajectoryWriter::abort`] (and a
//! drop without `finish`) removes the partial. A crash can therefore leave a partial behind, never
//! a half-written file under the final name; resume ([`super::resume`]) removes stale partials.

use std::collections::BTreeMap;
use std::fs::{self, File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use rig_core::wrench::Wrench;

use super::channels::{self, CHANNELS, PairedMsg, Record, TOPIC_IMAGE, TOPIC_PAIRED};
use super::manifest::Counts;

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

/// `fsync` a directory so that a rename in it is durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    File::open(dir)?.sync_all()
}

/// Write `bytes` to `path` atomically: a temporary beside it, fsync, rename, fsync the directory.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp"));
    let res = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        fs::rename(&tmp, path)?;
        sync_dir(dir)
    })();
    if res.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    res
}

/// What a complete trajectory file holds.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct FileContents {
    pub counts: Counts,
    /// Topics found, with their schema names.
    pub channels: BTreeMap<String, String>,
    /// Sync error (ns) of every paired frame that has one.
    pub sync_errors_ns: Vec<f64>,
    /// Paired frames whose wrench was refused or held, by status.
    pub paired_status: BTreeMap<String, u64>,
    /// Frame sequence numbers in file order.
    pub frame_seqs: Vec<i64>,
    /// Wrench counter values in file order (when the device has a counter).
    pub wrench_seqs: Vec<i64>,
    /// Log times of wrench messages, ns.
    pub wrench_times_ns: Vec<u64>,
    /// Every paired-wrench message in file order: its frame and its wrench (absent when the
    /// pairing was refused).
    pub paired: Vec<PairedRead>,
    /// Simulated rig only: every true-wrench message in file order (one per frame).
    pub truth: Vec<TruthRead>,
    /// The MCAP summary's message count per topic (cross-check of the linear read).
    pub summary_counts: BTreeMap<String, u64>,
}

/// One `/sync/paired_wrench` message as read back: the frame it belongs to and its wrench.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PairedRead {
    pub frame_seq: i64,
    /// Force, N (`None` when the pairing was refused).
    pub force_n: Option<[f64; 3]>,
    /// Torque, N·mm (`None` when the pairing was refused).
    pub torque_nmm: Option<[f64; 3]>,
}

/// One `/sim/true_wrench` message as read back: the simulator's wrench at the frame's true
/// capture time.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TruthRead {
    pub frame_seq: i64,
    pub wrench: Wrench,
}

/// Read a trajectory file completely: every record parsed, every message decoded.
pub fn read_file(path: &Path) -> Result<FileContents, String> {
    let bytes = fs::read(path).map_err(|e| format!("cannot read: {e}"))?;
    read_bytes(&bytes)
}

/// [`read_file`] over bytes in memory.
pub fn read_bytes(bytes: &[u8]) -> Result<FileContents, String> {
    let summary = mcap::read::Summary::read(bytes)
        .map_err(|e| format!("unreadable MCAP summary: {e}"))?
        .ok_or("no MCAP summary section (file not finished)")?;
    let mut out = FileContents::default();
    if let Some(stats) = &summary.stats {
        for (cid, n) in &stats.channel_message_counts {
            if let Some(ch) = summary.channels.get(cid) {
                out.summary_counts.insert(ch.topic.clone(), *n);
            }
        }
    }
    for ch in summary.channels.values() {
        let schema = ch
            .schema
            .as_ref()
            .map(|s| s.name.clone())
            .unwrap_or_default();
        out.channels.insert(ch.topic.clone(), schema);
    }
    let stream =
        mcap::read::MessageStream::new(bytes).map_err(|e| format!("unreadable MCAP: {e}"))?;
    for msg in stream {
        let msg = msg.map_err(|e| format!("corrupt MCAP record: {e}"))?;
        let topic = msg.channel.topic.as_str();
        let bad = |e: serde_json::Error| format!("bad {topic} message: {e}");
        match topic {
            TOPIC_IMAGE => {
                let m: channels::ImageMsg = serde_json::from_slice(&msg.data).map_err(bad)?;
                if m.format != "png" || channels::base64_decode(&m.data).is_none() {
                    return Err(format!("frame {} is not base64 PNG", m.seq));
                }
                out.frame_seqs.push(m.seq);
                out.counts.frames += 1;
            }
            channels::TOPIC_WRENCH => {
                let m: channels::WrenchMsg = serde_json::from_slice(&msg.data).map_err(bad)?;
                if let Some(s) = m.seq {
                    out.wrench_seqs.push(s);
                }
                out.wrench_times_ns.push(msg.log_time);
                out.counts.wrench += 1;
            }
            channels::TOPIC_POSE => {
                let _: channels::PoseMsg = serde_json::from_slice(&msg.data).map_err(bad)?;
                out.counts.poses += 1;
            }
            TOPIC_PAIRED => {
                let m: PairedMsg = serde_json::from_slice(&msg.data).map_err(bad)?;
                if let Some(e) = m.sync_error_ns {
                    out.sync_errors_ns.push(e);
                }
                *out.paired_status.entry(m.status).or_default() += 1;
                out.paired.push(PairedRead {
                    frame_seq: m.frame_seq,
                    force_n: m.force_n,
                    torque_nmm: m.torque_nmm,
                });
                out.counts.paired += 1;
            }
            channels::TOPIC_STAGE => {
                let _: channels::StageMsg = serde_json::from_slice(&msg.data).map_err(bad)?;
                out.counts.stages += 1;
            }
            channels::TOPIC_TRUTH => {
                let m: channels::TruthMsg = serde_json::from_slice(&msg.data).map_err(bad)?;
                out.truth.push(TruthRead {
                    frame_seq: m.frame_seq,
                    wrench: Wrench {
                        force_n: m.force_n,
                        torque_nmm: m.torque_nmm,
                    },
                });
                out.counts.truth += 1;
            }
            other => return Err(format!("unexpected channel {other}")),
        }
    }
    for (topic, n) in &out.summary_counts {
        let seen = out.counts.of_topic(topic);
        if seen != *n {
            return Err(format!(
                "summary says {n} messages on {topic}, the file holds {seen}"
            ));
        }
    }
    Ok(out)
}
