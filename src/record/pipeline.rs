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
//!
//! # A disk that stops answering
//!
//! A write that never returns (a disk gone away under a hard NFS mount, a USB disk that hung)
//! reports no error: the writer thread just stays in it. So every wait on the writer
//! ([`Recorder::begin`], [`Recorder::finish`], [`Recorder::abort`], [`Recorder::close`], and
//! whatever else waits on it through [`Recorder::watch`]) gives up with
//! [`RecordError::Stalled`] once the writer has held work for [`STALL_LIMIT`] (real time)
//! without completing any of it. A slow disk that still completes a command now and then is
//! never called stalled, however deep its queue. Once declared stalled, later waits give up at
//! once, unless the writer has made progress since. The writer runs on a thread of its own, not
//! tokio's blocking pool, so a runtime can shut down while it hangs; it keeps a duplicate of the
//! output directory's lock while it lives, so no other run writes there until it ends (with the
//! process, or with the disk's return). What it had saved stays as it was: the manifest is
//! replaced atomically, so `--resume` finds the last version and redoes the rest.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use tokio::sync::{mpsc, oneshot};

use super::channels::Record;
use super::manifest::{Counts, Manifest, Status};
use super::writer::{RecordError, TrajectoryWriter, check_id, final_name};

/// How long the writer may hold work without completing any of it before the recording counts
/// as stalled (see the module doc), real time. A healthy disk completes a message in
/// milliseconds and an `fsync` of a trajectory file in well under a second; a USB disk waking
/// up takes a few seconds. Ten seconds with not one command done is a disk that is gone.
pub const STALL_LIMIT: Duration = Duration::from_secs(10);

/// Holds the writer thread while closed: a slow disk on demand (tests and demonstrations), or
/// one that never comes back (the stalled-disk drill, `rig run --sim-fault disk-stall@…`).
/// While closed, [`WriterGate::let_through`] lets a given number of commands pass: a disk that
/// completes one write now and then.
#[derive(Debug, Clone, Default)]
pub struct WriterGate(Arc<(Mutex<GateState>, Condvar)>);

#[derive(Debug, Default)]
struct GateState {
    closed: bool,
    /// Commands that may pass while closed.
    passes: u64,
}

impl WriterGate {
    /// A gate that starts open.
    pub fn new() -> Self {
        Self::default()
    }
    fn state(&self) -> std::sync::MutexGuard<'_, GateState> {
        self.0.0.lock().unwrap_or_else(|e| e.into_inner())
    }
    pub fn close(&self) {
        let mut s = self.state();
        s.closed = true;
        s.passes = 0;
    }
    pub fn open(&self) {
        self.state().closed = false;
        self.0.1.notify_all();
    }
    /// Lets `n` more commands pass a closed gate.
    pub fn let_through(&self, n: u64) {
        self.state().passes += n;
        self.0.1.notify_all();
    }
    fn wait(&self) {
        let mut s = self.state();
        loop {
            if !s.closed {
                return;
            }
            if s.passes > 0 {
                s.passes -= 1;
                return;
            }
            s = self.0.1.wait(s).unwrap_or_else(|e| e.into_inner());
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
    /// How long the writer may hold work without completing any before waits on it give up
    /// ([`STALL_LIMIT`] in runs; shorter in tests).
    pub stall_limit: Duration,
    /// The output directory's lock (a duplicate of the run's), kept by the writer thread
    /// until it ends, so that a writer outliving its run (a stalled disk) still keeps other
    /// runs out of the directory.
    pub dir_lock: Option<Arc<std::fs::File>>,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            queue_capacity: 4096,
            gate: None,
            fail_after_bytes: None,
            stall_limit: STALL_LIMIT,
            dir_lock: None,
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

/// The writer's progress, for the stall watch: commands queued or in hand, and commands done.
#[derive(Debug, Default)]
struct Progress {
    /// Commands pushed (and a close asked for) that the writer has not completed.
    pending: AtomicU64,
    /// Commands the writer completed.
    done: AtomicU64,
}

impl Progress {
    fn complete_one(&self) {
        self.done.fetch_add(1, Ordering::Release);
        // Saturating: a recorder dropped without `close` ends its writer uncounted.
        let _ = self
            .pending
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1));
    }
}

/// Watches waits on the writer: one that holds work without completing any for `limit` is
/// stalled (see the module doc).
#[derive(Debug)]
struct StallWatch {
    progress: Arc<Progress>,
    limit: Duration,
    dir: PathBuf,
    /// The `done` count when a stall was declared: until it moves, later waits give up at once.
    stalled_at: Mutex<Option<u64>>,
}

impl StallWatch {
    fn stalled(&self, what: &str) -> RecordError {
        RecordError::Stalled {
            dir: self.dir.clone(),
            limit_s: self.limit.as_secs_f64(),
            what: what.to_owned(),
        }
    }

    /// Whether a stall was declared and the writer has done nothing since.
    fn still_stalled(&self) -> bool {
        let at = *self.stalled_at.lock().unwrap_or_else(|e| e.into_inner());
        at.is_some_and(|n| n == self.progress.done.load(Ordering::Acquire))
    }

    async fn watch<F: std::future::Future>(
        &self,
        what: &str,
        fut: F,
    ) -> Result<F::Output, RecordError> {
        let mut fut = std::pin::pin!(fut);
        if self.still_stalled() {
            // No second grace for a disk already given up on: only an answer ready now counts.
            return tokio::select! {
                biased;
                v = &mut fut => Ok(v),
                () = std::future::ready(()) => Err(self.stalled(what)),
            };
        }
        let tick = (self.limit / 20).clamp(Duration::from_millis(1), Duration::from_millis(250));
        let mut seen = self.progress.done.load(Ordering::Acquire);
        let mut since = Instant::now();
        loop {
            tokio::select! {
                biased;
                v = &mut fut => return Ok(v),
                () = tokio::time::sleep(tick) => {}
            }
            let done = self.progress.done.load(Ordering::Acquire);
            let idle = self.progress.pending.load(Ordering::Acquire) == 0;
            if done != seen || idle {
                // The writer moved, or has nothing to do (the wait is on something else).
                seen = done;
                since = Instant::now();
            } else if since.elapsed() >= self.limit {
                *self.stalled_at.lock().unwrap_or_else(|e| e.into_inner()) = Some(done);
                tracing::error!(
                    "the recording's writer has completed nothing for {:.1} s while {what}: \
                     the disk under {} is stalled",
                    self.limit.as_secs_f64(),
                    self.dir.display()
                );
                return Err(self.stalled(what));
            }
        }
    }
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
    /// The final manifest, sent by the writer thread when it ends.
    ended: oneshot::Receiver<Manifest>,
    dir: PathBuf,
    watch: StallWatch,
    gate: Option<WriterGate>,
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
        let progress = Arc::new(Progress::default());
        let writer = WriterLoop {
            dir: dir.to_owned(),
            manifest,
            current: None,
            failed: None,
            gate: cfg.gate.clone(),
            fail_after_bytes: cfg.fail_after_bytes,
            stats: stats.clone(),
            progress: progress.clone(),
        };
        let (end_tx, ended) = oneshot::channel();
        let dir_lock = cfg.dir_lock;
        // A thread of its own, not tokio's blocking pool: a runtime waits for its blocking
        // tasks when it shuts down, and this one may hang in a write for ever.
        std::thread::Builder::new()
            .name("rig-recorder".into())
            .spawn(move || {
                let manifest = writer.run(rx);
                let _ = end_tx.send(manifest);
                drop(dir_lock);
            })
            .map_err(|e| RecordError::WriterGone(format!("cannot start its thread: {e}")))?;
        Ok(Self {
            tx,
            capacity,
            stats,
            ended,
            dir: dir.to_owned(),
            watch: StallWatch {
                progress,
                limit: cfg.stall_limit,
                dir: dir.to_owned(),
                stalled_at: Mutex::new(None),
            },
            gate: cfg.gate,
        })
    }

    /// The gate in front of the writer, if it was started with one (drills).
    pub fn gate(&self) -> Option<&WriterGate> {
        self.gate.as_ref()
    }

    /// `fut`, a wait that depends on the writer, unless the writer stalls first: it holds work
    /// and completes none of it for the stall limit ([`STALL_LIMIT`]). `what` says what was
    /// being waited for, in the error. Once a stall is declared, later waits give up at once
    /// (unless the writer has moved since).
    pub async fn watch<F: std::future::Future>(
        &self,
        what: &str,
        fut: F,
    ) -> Result<F::Output, RecordError> {
        self.watch.watch(what, fut).await
    }

    /// Whether a stall was declared and the writer has completed nothing since.
    pub fn is_stalled(&self) -> bool {
        self.watch.still_stalled()
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
        self.watch.progress.pending.fetch_add(1, Ordering::AcqRel);
        let r = self.push_counted(cmd).await;
        if r.is_err() {
            self.watch.progress.pending.fetch_sub(1, Ordering::AcqRel);
        }
        r
    }

    async fn push_counted(&self, cmd: Cmd) -> Result<(), RecordError> {
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

    /// Open trajectory `id` (its partial file); the manifest marks it pending. Waits for room in
    /// the queue, unless the writer stalls.
    pub async fn begin(&self, id: &str) -> Result<(), RecordError> {
        check_id(id)?;
        let what = format!("queueing the start of trajectory {id}");
        self.watch(&what, self.push(Cmd::Begin(id.to_owned())))
            .await?
    }

    /// Queue one message for the open trajectory; waits while the queue is full.
    pub async fn send(&self, rec: Record) -> Result<(), RecordError> {
        self.stats.queued.fetch_add(1, Ordering::Relaxed);
        self.push(Cmd::Rec(rec)).await
    }

    /// Complete the open trajectory: everything queued is written, the file renamed to its final
    /// name and the manifest marks it complete. Returns its counts, or why it failed.
    /// Fails with [`RecordError::Stalled`] when the writer stalls.
    pub async fn finish(&self, frames_dropped: u64) -> Result<Counts, RecordError> {
        let (reply, rx) = oneshot::channel();
        let done = async {
            self.push(Cmd::Finish {
                frames_dropped,
                reply,
            })
            .await?;
            rx.await
                .map_err(|_| RecordError::WriterGone("it stopped while finishing".into()))?
        };
        self.watch("finishing the trajectory's file", done).await?
    }

    /// Abandon the open trajectory (safety stop, link loss): no file under its final name; the
    /// manifest marks it failed with `reason`. Fails with [`RecordError::Stalled`] when the
    /// writer stalls (the manifest then still says pending, which `--resume` redoes too).
    pub async fn abort(&self, reason: &str) -> Result<(), RecordError> {
        let (reply, rx) = oneshot::channel();
        let done = async {
            self.push(Cmd::Abort {
                reason: reason.to_owned(),
                reply,
            })
            .await?;
            rx.await
                .map_err(|_| RecordError::WriterGone("it stopped while aborting".into()))
        };
        self.watch("marking the failed trajectory in the manifest", done)
            .await?
    }

    /// Stop the writer (an open trajectory is marked failed) and return the final manifest.
    /// Fails with [`RecordError::Stalled`] when the writer stalls; it is then left to end by
    /// itself (with the process, or when its disk comes back).
    pub async fn close(self) -> Result<Manifest, RecordError> {
        let Recorder {
            tx, ended, watch, ..
        } = self;
        // The writer's last work (the queue, an open trajectory's abort, the manifest) counts
        // as pending until it ends.
        watch.progress.pending.fetch_add(1, Ordering::AcqRel);
        drop(tx);
        watch
            .watch("closing the recording", ended)
            .await?
            .map_err(|_| RecordError::WriterGone("its thread ended without a manifest".into()))
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
    progress: Arc<Progress>,
}

impl WriterLoop {
    fn run(mut self, mut rx: mpsc::Receiver<Cmd>) -> Manifest {
        while let Some(cmd) = rx.blocking_recv() {
            self.command(cmd);
            self.progress.complete_one();
        }
        if self.current.is_some() {
            // Its file and the manifest are writes too, behind the gate like every other.
            if let Some(g) = &self.gate {
                g.wait();
            }
            self.abort("the recorder stopped before the trajectory was complete");
        }
        // The close's own pending count.
        self.progress.complete_one();
        self.manifest
    }

    fn command(&mut self, cmd: Cmd) {
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
