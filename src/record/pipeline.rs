//! The bounded writer pipeline: producers on tokio, one blocking writer behind a bounded queue.
//!
//! Producers (the camera, F/T and robot tasks, and the pairer) call [`Recorder::send`]. The queue
//! is bounded: when the disk cannot keep up, `send` waits for room (back-pressure) instead of
//! dropping anything, and logs a warning with the queue depth (the first time in a stall and then
//! every 100th wait, so a slow disk is visible without flooding the log). The writer runs on a
//! blocking thread (`spawn_blocking`): PNG payloads and `fsync` must not stall the runtime.
//!
//! A write error (disk full, I/O error) fails the open trajectory: its partial file is removed,
//! the manifest marks it failed with the error, later messages of that trajectory are discarded
//! (they cannot be written) and [`Recorder::finish`] returns the error. Files of trajectories
//! completed earlier are untouched.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};

use tokio::sync::{mpsc, oneshot};
use tokio::task::JoinHandle;

use super::channels::Record;
use super::manifest::{Counts, Manifest, Status};
use super::writer::{RecordError, TrajectoryWriter, check_id, final_name};

/// Holds the writer thread while closed: a slow disk on demand (tests and demonstrations).
#[derive(Debug, Clone, Default)]
pub struct WriterGate(Arc<(Mutex<bool>, Condvar)>);

impl WriterGate {
    /// A gate that starts open.
    pub fn new() -> Self {
        Self::default()
    }
    pub fn close(&self) {
        *self.0.0.lock().unwrap_or_else(|e| e.into_inner()) = true;
    }
    pub fn open(&self) {
        *self.0.0.lock().unwrap_or_else(|e| e.into_inner()) = false;
        self.0.1.notify_all();
    }
    fn wait(&self) {
        let mut closed = self.0.0.lock().unwrap_or_else(|e| e.into_inner());
        while *closed {
            closed = self.0.1.wait(closed).unwrap_or_else(|e| e.into_inner());
        }
    }
}

/// Configuration of a [`Recorder`].
#[derive(Debug, Clone)]
pub struct RecorderConfig {
    /// Messages the queue holds before producers wait. At 1 kHz wrench + 500 Hz pose + 30 Hz
    /// frames, 4096 is about 2.7 s of data.
    pub queue_capacity: usize,
    /// Optional gate in front of every write (see [`WriterGate`]).
    pub gate: Option<WriterGate>,
    /// Drill: each trajectory file fails with an I/O error once it would pass this many bytes
    /// (a chunk write failing mid-trajectory, without filling a disk). `None` in real runs.
    pub fail_after_bytes: Option<u64>,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            queue_capacity: 4096,
            gate: None,
            fail_after_bytes: None,
        }
    }
}

/// Counters shared with the writer.
#[derive(Debug, Default)]
pub struct RecorderStats {
    /// Times a producer found the queue full and had to wait.
    pub backpressure_waits: AtomicU64,
    /// Messages accepted into the queue.
    pub queued: AtomicU64,
    /// Messages written to files.
    pub written: AtomicU64,
    /// Messages discarded because their trajectory had already failed or none was open.
    pub discarded: AtomicU64,
}

enum Cmd {
    Begin(String),
    Rec(Record),
    Finish {
        frames_dropped: u64,
        reply: oneshot::Sender<Result<Counts, RecordError>>,
    },
    Abort {
        reason: String,
        reply: oneshot::Sender<()>,
    },
}

/// Handle of the recording pipeline of one run.
#[derive(Debug)]
pub struct Recorder {
    tx: mpsc::Sender<Cmd>,
    capacity: usize,
    stats: Arc<RecorderStats>,
    task: JoinHandle<Manifest>,
    dir: PathBuf,
}

impl Recorder {
    /// Start recording into `dir` (created if missing) with `manifest`, which is saved at once.
    pub fn start(dir: &Path, manifest: Manifest, cfg: RecorderConfig) -> Result<Self, RecordError> {
        std::fs::create_dir_all(dir).map_err(|source| RecordError::Io {
            path: dir.to_owned(),
            source,
        })?;
        manifest.save(dir).map_err(|source| RecordError::Io {
            path: dir.join(super::manifest::MANIFEST_NAME),
            source,
        })?;
        let capacity = cfg.queue_capacity.max(1);
        let (tx, rx) = mpsc::channel(capacity);
        let stats = Arc::new(RecorderStats::default());
        let writer = WriterLoop {
            dir: dir.to_owned(),
            manifest,
            current: None,
            failed: None,
            gate: cfg.gate,
            fail_after_bytes: cfg.fail_after_bytes,
            stats: stats.clone(),
        };
        let task = tokio::task::spawn_blocking(move || writer.run(rx));
        Ok(Self {
            tx,
            capacity,
            stats,
            task,
            dir: dir.to_owned(),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    pub fn stats(&self) -> &RecorderStats {
        &self.stats
    }

    /// Messages waiting in the queue now.
    pub fn queue_depth(&self) -> usize {
        self.capacity - self.tx.capacity()
    }

    async fn push(&self, cmd: Cmd) -> Result<(), RecordError> {
        let gone = || RecordError::WriterGone("its queue is closed".into());
        match self.tx.try_reserve() {
            Ok(permit) => permit.send(cmd),
            Err(mpsc::error::TrySendError::Closed(())) => return Err(gone()),
            Err(mpsc::error::TrySendError::Full(())) => {
                let n = self
                    .stats
                    .backpressure_waits
                    .fetch_add(1, Ordering::Relaxed);
                if n.is_multiple_of(100) {
                    tracing::warn!(
                        queue_depth = self.queue_depth(),
                        capacity = self.capacity,
                        waits = n + 1,
                        "recorder queue full: the disk is slower than the data; producers wait (nothing is dropped)"
                    );
                }
                self.tx.reserve().await.map_err(|_| gone())?.send(cmd);
            }
        }
        Ok(())
    }

    /// Open trajectory `id` (its partial file); the manifest marks it pending.
    pub async fn begin(&self, id: &str) -> Result<(), RecordError> {
        check_id(id)?;
        self.push(Cmd::Begin(id.to_owned())).await
    }

    /// Queue one message for the open trajectory; waits while the queue is full.
    pub async fn send(&self, rec: Record) -> Result<(), RecordError> {
        self.stats.queued.fetch_add(1, Ordering::Relaxed);
        self.push(Cmd::Rec(rec)).await
    }

    /// Complete the open trajectory: everything queued is written, the file renamed to its final
    /// name and the manifest marks it complete. Returns its counts, or why it failed.
    pub async fn finish(&self, frames_dropped: u64) -> Result<Counts, RecordError> {
        let (reply, rx) = oneshot::channel();
        self.push(Cmd::Finish {
            frames_dropped,
            reply,
        })
        .await?;
        rx.await
            .map_err(|_| RecordError::WriterGone("it stopped while finishing".into()))?
    }

    /// Abandon the open trajectory (safety stop, link loss): no file under its final name; the
    /// manifest marks it failed with `reason`.
    pub async fn abort(&self, reason: &str) -> Result<(), RecordError> {
        let (reply, rx) = oneshot::channel();
        self.push(Cmd::Abort {
            reason: reason.to_owned(),
            reply,
        })
        .await?;
        rx.await
            .map_err(|_| RecordError::WriterGone("it stopped while aborting".into()))
    }

    /// Stop the writer (an open trajectory is marked failed) and return the final manifest.
    pub async fn close(self) -> Result<Manifest, RecordError> {
        drop(self.tx);
        self.task
            .await
            .map_err(|e| RecordError::WriterGone(e.to_string()))
    }
}

struct WriterLoop {
    dir: PathBuf,
    manifest: Manifest,
    current: Option<TrajectoryWriter>,
    /// The open trajectory failed: id and reason.
    failed: Option<(String, String)>,
    gate: Option<WriterGate>,
    fail_after_bytes: Option<u64>,
    stats: Arc<RecorderStats>,
}

impl WriterLoop {
    fn run(mut self, mut rx: mpsc::Receiver<Cmd>) -> Manifest {
        while let Some(cmd) = rx.blocking_recv() {
            if let Some(g) = &self.gate {
                g.wait();
            }
            match cmd {
                Cmd::Begin(id) => self.begin(id),
                Cmd::Rec(rec) => self.write(&rec),
                Cmd::Finish {
                    frames_dropped,
                    reply,
                } => {
                    let _ = reply.send(self.finish(frames_dropped));
                }
                Cmd::Abort { reason, reply } => {
                    self.abort(&reason);
                    let _ = reply.send(());
                }
            }
        }
        if self.current.is_some() {
            self.abort("the recorder stopped before the trajectory was complete");
        }
        self.manifest
    }

    fn save(&self) -> Result<(), RecordError> {
        self.manifest.save(&self.dir).map_err(|source| {
            let e = RecordError::Io {
                path: self.dir.join(super::manifest::MANIFEST_NAME),
                source,
            };
            tracing::error!("{e}");
            e
        })
    }

    fn mark_failed(&mut self, id: &str, reason: &str) {
        let e = self.manifest.entry_mut(id);
        e.status = Status::Failed;
        e.reason = Some(reason.to_owned());
        e.file = None;
        let _ = self.save();
    }

    fn begin(&mut self, id: String) {
        if let Some(w) = self.current.take() {
            let old = w.id().to_owned();
            w.abort();
            self.mark_failed(&old, "a new trajectory began before this one finished");
        }
        self.failed = None;
        let e = self.manifest.entry_mut(&id);
        e.status = Status::Pending;
        e.reason = None;
        e.file = None;
        let _ = self.save();
        match TrajectoryWriter::create_with(&self.dir, &id, self.fail_after_bytes) {
            Ok(w) => self.current = Some(w),
            Err(err) => {
                let reason = err.to_string();
                tracing::error!("trajectory {id}: {reason}");
                self.mark_failed(&id, &reason);
                self.failed = Some((id, reason));
            }
        }
    }

    fn write(&mut self, rec: &Record) {
        let Some(w) = self.current.as_mut() else {
            self.stats.discarded.fetch_add(1, Ordering::Relaxed);
            return;
        };
        match w.write(rec) {
            Ok(()) => {
                self.stats.written.fetch_add(1, Ordering::Relaxed);
            }
            Err(err) => {
                let w = self.current.take().expect("checked above");
                let id = w.id().to_owned();
                w.abort();
                let reason = err.to_string();
                tracing::error!("trajectory {id} failed: {reason}");
                self.stats.discarded.fetch_add(1, Ordering::Relaxed);
                self.mark_failed(&id, &reason);
                self.failed = Some((id, reason));
            }
        }
    }

    fn finish(&mut self, frames_dropped: u64) -> Result<Counts, RecordError> {
        if let Some((id, reason)) = self.failed.take() {
            return Err(RecordError::Failed { id, reason });
        }
        let w = self.current.take().ok_or(RecordError::NotOpen)?;
        let id = w.id().to_owned();
        match w.finish() {
            Ok(counts) => {
                let e = self.manifest.entry_mut(&id);
                e.status = Status::Complete;
                e.reason = None;
                e.counts = counts.clone();
                e.frames_dropped = frames_dropped;
                e.file = Some(final_name(&id));
                self.save()?;
                Ok(counts)
            }
            Err(err) => {
                let reason = err.to_string();
                // The rename may not have happened; make sure nothing stays under the final name.
                let _ = std::fs::remove_file(self.dir.join(super::writer::partial_name(&id)));
                self.mark_failed(&id, &reason);
                Err(RecordError::Failed { id, reason })
            }
        }
    }

    fn abort(&mut self, reason: &str) {
        let id = match self.current.take() {
            Some(w) => {
                let id = w.id().to_owned();
                w.abort();
                id
            }
            None => match self.failed.take() {
                Some((id, _)) => id,
                None => return,
            },
        };
        self.mark_failed(&id, reason);
    }
}
