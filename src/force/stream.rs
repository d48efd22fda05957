//! A running F/T stream: the channel between a reader and its consumer ([`FtStream`] on the
//! consumer's side, [`Sink`] on the reader's), the samples ([`WrenchSample`]), the counters
//! ([`FtStats`]), and the controls a reader obeys (tare, stop).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rig_core::ft::SampleFlags;
use rig_core::wrench::Wrench;
use tokio::sync::{mpsc, oneshot};

use super::conditioning::{Conditioner, TareReport};
use super::error::FtError;

/// Samples buffered between a reader and its consumer; beyond this they are dropped and
/// counted in [`FtStats::consumer_overflow`].
pub const CHANNEL_CAPACITY: usize = 1 << 16;

/// One wrench sample at the tool point (the indenter tip when a tool transform is set).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WrenchSample {
    /// Host clock time when the sample's bytes were read, ns.
    pub t_host_ns: u64,
    /// The device's sequence number (RDT sequence, DAQ frame sequence, unwrapped to u64); for a
    /// serial controller, which has none, the record count since the stream started.
    pub device_seq: u64,
    /// Fx, Fy, Fz (N) and Tx, Ty, Tz (N·mm), tared, at the tool point.
    pub wrench: Wrench,
    /// The device's raw status word (0 = healthy).
    pub status: u32,
    /// What is wrong with this sample, if anything.
    pub flags: SampleFlags,
}

/// Counters of one stream; shared with the reader.
#[derive(Debug, Default)]
pub struct FtStats {
    pub samples: AtomicU64,
    pub lost: AtomicU64,
    pub reordered: AtomicU64,
    pub duplicates: AtomicU64,
    pub garbage: AtomicU64,
    pub truncated: AtomicU64,
    pub checksum_errors: AtomicU64,
    pub saturated: AtomicU64,
    pub status_errors: AtomicU64,
    pub dropped_saturated: AtomicU64,
    pub consumer_overflow: AtomicU64,
}

/// A copy of [`FtStats`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct FtStatsSnapshot {
    /// Samples delivered.
    pub samples: u64,
    /// Records the device sent that never arrived (sequence gaps).
    pub lost: u64,
    /// Records that arrived after a later one.
    pub reordered: u64,
    /// Records seen twice (dropped).
    pub duplicates: u64,
    /// Garbage between records: bytes (DAQ, binary serial) or lines (ASCII serial).
    pub garbage: u64,
    /// Records cut short.
    pub truncated: u64,
    /// Frames whose checksum failed (DAQ) or binary records that failed the plausibility check.
    pub checksum_errors: u64,
    /// Samples flagged saturated.
    pub saturated: u64,
    /// Samples with a non-zero device status.
    pub status_errors: u64,
    /// Saturated samples dropped by policy.
    pub dropped_saturated: u64,
    /// Samples dropped because the consumer fell behind.
    pub consumer_overflow: u64,
}

impl std::fmt::Display for FtStatsSnapshot {
    /// `lost 0, reordered 0, …`, for operator read-outs.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "lost {}, reordered {}, duplicates {}, garbage {}, truncated {}, checksum errors {}, \
             saturated {}, status errors {}, dropped saturated {}, consumer overflow {}",
            self.lost,
            self.reordered,
            self.duplicates,
            self.garbage,
            self.truncated,
            self.checksum_errors,
            self.saturated,
            self.status_errors,
            self.dropped_saturated,
            self.consumer_overflow
        )
    }
}

impl FtStats {
    pub fn snapshot(&self) -> FtStatsSnapshot {
        let g = |a: &AtomicU64| a.load(Ordering::Acquire);
        FtStatsSnapshot {
            samples: g(&self.samples),
            lost: g(&self.lost),
            reordered: g(&self.reordered),
            duplicates: g(&self.duplicates),
            garbage: g(&self.garbage),
            truncated: g(&self.truncated),
            checksum_errors: g(&self.checksum_errors),
            saturated: g(&self.saturated),
            status_errors: g(&self.status_errors),
            dropped_saturated: g(&self.dropped_saturated),
            consumer_overflow: g(&self.consumer_overflow),
        }
    }

    pub(crate) fn set(a: &AtomicU64, v: u64) {
        a.store(v, Ordering::Release);
    }
    pub(crate) fn add(a: &AtomicU64, v: u64) {
        a.fetch_add(v, Ordering::AcqRel);
    }
}

/// Messages from a stream's owner to its reader.
#[derive(Debug)]
pub enum Control {
    Tare {
        samples: u64,
        reply: oneshot::Sender<TareReport>,
    },
    Stop,
}

/// The reader's side of a stream: where samples, counters and the final error go.
#[derive(Clone)]
pub struct Sink {
    pub tx: mpsc::Sender<WrenchSample>,
    pub stats: Arc<FtStats>,
    pub error: Arc<Mutex<Option<FtError>>>,
}

impl Sink {
    /// Delivers one sample (counting it, or counting an overflow).
    pub fn deliver(&self, s: WrenchSample) {
        if s.flags.contains(SampleFlags::SATURATED)
            || s.flags.contains(SampleFlags::GAUGE_SATURATED)
        {
            FtStats::add(&self.stats.saturated, 1);
        }
        if s.flags.contains(SampleFlags::DEVICE_STATUS) {
            FtStats::add(&self.stats.status_errors, 1);
        }
        match self.tx.try_send(s) {
            Ok(()) => FtStats::add(&self.stats.samples, 1),
            Err(_) => FtStats::add(&self.stats.consumer_overflow, 1),
        }
    }

    /// Records the error that ended the stream (the first one wins).
    pub fn fail(&self, e: FtError) {
        tracing::warn!("F/T stream ended: {e}");
        if let Ok(mut g) = self.error.lock()
            && g.is_none()
        {
            *g = Some(e);
        }
    }

    /// Conditions a reading and delivers it. Returns false when the policy says stop.
    #[allow(clippy::too_many_arguments)]
    pub fn condition_and_deliver(
        &self,
        cond: &mut Conditioner,
        raw: &[f64; 6],
        thermistor_v: Option<f64>,
        status: u32,
        flags: SampleFlags,
        t_host_ns: u64,
        device_seq: u64,
    ) -> bool {
        let c = cond.process(raw, thermistor_v, status, flags);
        let sample = WrenchSample {
            t_host_ns,
            device_seq,
            wrench: Wrench::from_array(c.wrench),
            status,
            flags: c.flags,
        };
        if c.stop {
            FtStats::add(&self.stats.saturated, 1);
            self.fail(FtError::Saturated { flags: c.flags });
            return false;
        }
        if !c.keep {
            FtStats::add(&self.stats.saturated, 1);
            FtStats::add(&self.stats.dropped_saturated, 1);
            return true;
        }
        self.deliver(sample);
        true
    }
}

/// A running F/T stream. Dropping it stops the reader.
pub struct FtStream {
    rx: mpsc::Receiver<WrenchSample>,
    stats: Arc<FtStats>,
    error: Arc<Mutex<Option<FtError>>>,
    ctl: mpsc::UnboundedSender<Control>,
    done: Option<oneshot::Receiver<()>>,
    keepalive: Vec<Box<dyn std::any::Any + Send>>,
    /// What this stream reads, for messages ("serial /dev/ttyUSB0").
    pub description: String,
}

impl FtStream {
    /// Makes the channel pair for a reader. The reader calls `done_tx.send(())` when it ends.
    pub fn channel(
        description: String,
    ) -> (
        FtStream,
        Sink,
        mpsc::UnboundedReceiver<Control>,
        oneshot::Sender<()>,
    ) {
        let (tx, rx) = mpsc::channel(CHANNEL_CAPACITY);
        let (ctl_tx, ctl_rx) = mpsc::unbounded_channel();
        let (done_tx, done_rx) = oneshot::channel();
        let stats = Arc::new(FtStats::default());
        let error = Arc::new(Mutex::new(None));
        (
            FtStream {
                rx,
                stats: stats.clone(),
                error: error.clone(),
                ctl: ctl_tx,
                done: Some(done_rx),
                keepalive: Vec::new(),
                description,
            },
            Sink { tx, stats, error },
            ctl_rx,
            done_tx,
        )
    }

    /// Keeps `thing` (an in-process simulated device) alive as long as the stream.
    pub fn keep_alive(&mut self, thing: Box<dyn std::any::Any + Send>) {
        self.keepalive.push(thing);
    }

    /// The next sample; `None` when the stream has ended (see [`Self::finish`] for why).
    pub async fn next(&mut self) -> Option<WrenchSample> {
        self.rx.recv().await
    }

    /// A sample if one is buffered.
    pub fn try_next(&mut self) -> Option<WrenchSample> {
        self.rx.try_recv().ok()
    }

    /// Counters so far.
    pub fn stats(&self) -> FtStatsSnapshot {
        self.stats.snapshot()
    }

    /// The error that ended the stream, if it ended by one.
    pub fn error(&self) -> Option<FtError> {
        self.error.lock().ok().and_then(|g| g.clone())
    }

    /// A handle that tares this stream from another task while this one keeps reading it.
    pub fn tare_handle(&self) -> TareHandle {
        TareHandle {
            ctl: self.ctl.clone(),
            error: self.error.clone(),
        }
    }

    /// Tares over the next `samples` samples (the sensor must be unloaded). Samples keep
    /// flowing meanwhile; those before the tare completes use the previous bias.
    pub async fn tare(&mut self, samples: u64) -> Result<TareReport, FtError> {
        let (tx, rx) = oneshot::channel();
        self.ctl
            .send(Control::Tare { samples, reply: tx })
            .map_err(|_| self.error().unwrap_or(FtError::Stopped))?;
        rx.await
            .map_err(|_| self.error().unwrap_or(FtError::Stopped))
    }

    /// Stops the reader (it tells the device to stop), waits for it, and returns the final
    /// counters, or the error that had ended the stream.
    pub async fn finish(mut self) -> Result<FtStatsSnapshot, FtError> {
        let _ = self.ctl.send(Control::Stop);
        if let Some(d) = self.done.take() {
            let _ = d.await;
        }
        match self.error() {
            Some(e) => Err(e),
            None => Ok(self.stats()),
        }
    }
}

/// Tares an [`FtStream`] that another task reads (see [`FtStream::tare_handle`]).
#[derive(Clone)]
pub struct TareHandle {
    ctl: mpsc::UnboundedSender<Control>,
    error: Arc<Mutex<Option<FtError>>>,
}

impl TareHandle {
    /// As [`FtStream::tare`]; the samples must keep being read meanwhile.
    pub async fn tare(&self, samples: u64) -> Result<TareReport, FtError> {
        let err = || {
            self.error
                .lock()
                .ok()
                .and_then(|g| g.clone())
                .unwrap_or(FtError::Stopped)
        };
        let (tx, rx) = oneshot::channel();
        self.ctl
            .send(Control::Tare { samples, reply: tx })
            .map_err(|_| err())?;
        rx.await.map_err(|_| err())
    }
}

impl Drop for FtStream {
    fn drop(&mut self) {
        let _ = self.ctl.send(Control::Stop);
    }
}
/// Runs a front end's reader on a thread of its own (named `thread`): `setup` (open and
/// configure the device) and then `run` with what it gave, `done` fired when the thread ends.
/// Returns `stream` once `setup` succeeded, or `setup`'s error; `device` names the front end
/// if the thread cannot start.
pub(crate) async fn start_reader<S>(
    stream: FtStream,
    done: oneshot::Sender<()>,
    thread: &str,
    device: &str,
    setup: impl FnOnce() -> Result<S, FtError> + Send + 'static,
    run: impl FnOnce(S) + Send + 'static,
) -> Result<FtStream, FtError> {
    let (ready_tx, ready_rx) = oneshot::channel();
    std::thread::Builder::new()
        .name(thread.into())
        .spawn(move || {
            match setup() {
                Ok(s) => {
                    let _ = ready_tx.send(Ok(()));
                    run(s);
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            }
            let _ = done.send(());
        })
        .map_err(|e| FtError::Io {
            device: device.into(),
            reason: e.to_string(),
        })?;
    match ready_rx.await {
        Ok(Ok(())) => Ok(stream),
        Ok(Err(e)) => Err(e),
        Err(_) => Err(FtError::Stopped),
    }
}
