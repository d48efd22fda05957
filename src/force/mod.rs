//! Nano17 force/torque sensing: three front ends, one stream of [`WrenchSample`]s.
//!
//! The protocol cores are sans-IO and live in `rig_core::ft`; this module owns the ports and
//! sockets, the timestamps and the per-sample conditioning:
//!
//! - [`serial`]: an ATI F/T controller on a serial port (`serialport`, no libudev): set the
//!   record format (`CD A` / `CD B`) and resolved output (`CD R`), optionally bias (`SB`),
//!   stream with `QS`, stop with a CR.
//! - [`netft`]: a Net F/T over UDP (RDT): start/stop streaming, optional software bias, exact
//!   loss / reorder counts from the RDT sequence.
//! - [`daq`]: raw gauge voltages in the project's DAQ framing, turned into a wrench with the
//!   sensor's calibration file (temperature-compensated when the file allows).
//!
//! Every reader timestamps a sample with the shared [`Clock`] when its bytes arrive
//! (`t_host_ns`) and keeps the device's own sequence (`device_seq`), so the sync stage can map
//! device time to host time with its estimator. Each sample then goes through a [`Conditioner`]:
//! tare (bias) subtraction, the tool transform to the indenter tip, and checks. Saturation
//! (any gauge at its ADC range, any axis at its max load) and a non-zero device status are set
//! in [`WrenchSample::flags`], never passed silently; the `saturation` policy of the config can
//! also drop such samples or end the stream.
//!
//! Bad input never panics: garbage, truncated records, checksum failures, lost and reordered
//! packets are counted in [`FtStats`]; an unplugged port ends the stream with
//! [`FtError::PortClosed`], reported by [`FtStream::finish`].

pub mod cli;
pub mod daq;
pub mod netft;
pub mod serial;

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rig_core::clock::Clock;
use rig_core::config::{ForceSensorConfig, ForceSensorKind, SaturationPolicy};
use rig_core::ft::bias::{BiasEstimate, BiasEstimator};
use rig_core::ft::cal::{CalError, Calibration};
use rig_core::ft::transform::{ToolTransform, TransformError};
use rig_core::ft::{NANO17_SI_25_MAX, SampleFlags};
use rig_core::wrench::Wrench;
use tokio::sync::{mpsc, oneshot};

pub use rig_core::ft::SampleFlags as Flags;

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

/// What went wrong with the F/T sensor. Messages say what to check.
#[derive(Debug, Clone, thiserror::Error)]
pub enum FtError {
    #[error(
        "cannot open F/T port {port}: {reason}; is the sensor plugged in, and is another rig using it?"
    )]
    PortOpen { port: String, reason: String },
    #[error("F/T port {port} closed: {reason}; was the cable unplugged or the device powered off?")]
    PortClosed { port: String, reason: String },
    #[error(
        "no answer from the F/T device at {device} within {timeout_ms} ms ({what}); check the cable, baud rate and power"
    )]
    NoAnswer {
        device: String,
        what: String,
        timeout_ms: u64,
    },
    #[error("F/T I/O error on {device}: {reason}")]
    Io { device: String, reason: String },
    #[error(
        "F/T sensor saturated ({flags}); the stream was stopped (force_sensor.saturation = \"stop\")"
    )]
    Saturated { flags: SampleFlags },
    #[error(transparent)]
    Calibration(#[from] CalError),
    #[error("force_sensor tool transform: {0}")]
    Transform(#[from] TransformError),
    #[error("force_sensor config: {0}")]
    Config(String),
    #[error("F/T stream already stopped")]
    Stopped,
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

/// Result of a tare.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TareReport {
    /// The bias in the front end's raw units (N and N·mm for counts; volts for DAQ gauges).
    pub raw: BiasEstimate,
    /// The bias and noise as a wrench (sensor frame, N and N·mm).
    pub wrench: BiasEstimate,
}

/// How raw readings become a sensor-frame wrench.
#[derive(Debug, Clone)]
pub enum RawMap {
    /// Counts from a controller or Net F/T: N = counts / cpf, N·mm = counts / cpt.
    Counts {
        counts_per_force: f64,
        counts_per_torque: f64,
    },
    /// Gauge volts: `F = M · (V' − bias)`, `V'` temperature-compensated when enabled.
    Gauges {
        calibration: Box<Calibration>,
        temperature_compensation: bool,
    },
}

/// One sample after conditioning.
#[derive(Debug, Clone, Copy)]
pub struct Conditioned {
    pub wrench: [f64; 6],
    pub flags: SampleFlags,
    /// The sample should be delivered (false: dropped by the saturation policy).
    pub keep: bool,
    /// The policy says stop.
    pub stop: bool,
}

struct PendingTare {
    target: u64,
    raw: BiasEstimator,
    wrench: BiasEstimator,
    reply: oneshot::Sender<TareReport>,
}

/// Per-sample conditioning, sans I/O: tare, tool transform, saturation and status checks.
pub struct Conditioner {
    map: RawMap,
    tool: ToolTransform,
    max_loads: [f64; 6],
    policy: SaturationPolicy,
    bias: Option<[f64; 6]>,
    tare: Option<PendingTare>,
}

impl Conditioner {
    pub fn new(
        map: RawMap,
        tool: ToolTransform,
        max_loads: [f64; 6],
        policy: SaturationPolicy,
    ) -> Self {
        Self {
            map,
            tool,
            max_loads,
            policy,
            bias: None,
            tare: None,
        }
    }

    /// Sets the bias directly (raw units).
    pub fn set_bias(&mut self, bias: [f64; 6]) {
        self.bias = Some(bias);
    }

    /// The current bias (raw units), if tared.
    pub fn bias(&self) -> Option<[f64; 6]> {
        self.bias
    }

    /// Starts a tare over the next `n` samples; the report is sent on `reply`.
    pub fn start_tare(&mut self, n: u64, reply: oneshot::Sender<TareReport>) {
        self.tare = Some(PendingTare {
            target: n.max(2),
            raw: BiasEstimator::new(),
            wrench: BiasEstimator::new(),
            reply,
        });
    }

    fn to_sensor(&self, raw: &[f64; 6], bias: &[f64; 6]) -> [f64; 6] {
        match &self.map {
            RawMap::Counts {
                counts_per_force,
                counts_per_torque,
            } => {
                let tared: [f64; 6] = std::array::from_fn(|i| raw[i] - bias[i]);
                rig_core::ft::counts_to_wrench(&tared, *counts_per_force, *counts_per_torque)
            }
            RawMap::Gauges { calibration, .. } => calibration.wrench(raw, bias),
        }
    }

    /// Conditions one reading. `raw`: counts (as f64) or gauge volts; `thermistor_v` for DAQ;
    /// `status`: the device's status word; `flags`: what the reader already knows (gaps,
    /// reordering, gauge saturation).
    pub fn process(
        &mut self,
        raw: &[f64; 6],
        thermistor_v: Option<f64>,
        status: u32,
        mut flags: SampleFlags,
    ) -> Conditioned {
        let raw = match &self.map {
            RawMap::Gauges {
                calibration,
                temperature_compensation: true,
            } if calibration.temperature.is_some() => {
                let (g, ok) = calibration.compensate(raw, thermistor_v);
                if !ok || thermistor_v.is_none() {
                    flags |= SampleFlags::TEMPERATURE_UNCOMPENSATED;
                }
                g
            }
            _ => *raw,
        };
        if let Some(t) = self.tare.as_mut() {
            t.raw.push(&raw);
            let w = self.to_sensor(&raw, &[0.0; 6]);
            if let Some(t) = self.tare.as_mut() {
                t.wrench.push(&w);
            }
        }
        if self
            .tare
            .as_ref()
            .is_some_and(|t| t.raw.count() >= t.target)
            && let Some(t) = self.tare.take()
            && let Some(est) = t.raw.estimate()
        {
            self.bias = Some(est.mean);
            let _ = t.reply.send(TareReport {
                raw: est,
                wrench: self.wrench_estimate(&est, &t.wrench),
            });
        }
        let zero = [0.0; 6];
        let bias = self.bias.as_ref().unwrap_or(&zero);
        if self.bias.is_none() {
            flags |= SampleFlags::UNTARED;
        }
        let sensor = self.to_sensor(&raw, bias);
        let mask = rig_core::ft::saturation_mask(&sensor, &self.max_loads);
        if mask != 0 {
            flags.set_saturated_axes(mask);
        }
        if status != 0 {
            flags |= SampleFlags::DEVICE_STATUS;
        }
        let saturated =
            flags.contains(SampleFlags::SATURATED) || flags.contains(SampleFlags::GAUGE_SATURATED);
        let (keep, stop) = match (saturated, self.policy) {
            (false, _) | (true, SaturationPolicy::Flag) => (true, false),
            (true, SaturationPolicy::Drop) => (false, false),
            (true, SaturationPolicy::Stop) => (false, true),
        };
        Conditioned {
            wrench: self.tool.apply(&sensor),
            flags,
            keep,
            stop,
        }
    }

    fn wrench_estimate(&self, raw: &BiasEstimate, wrench: &BiasEstimator) -> BiasEstimate {
        let mean = self.to_sensor(&raw.mean, &[0.0; 6]);
        match wrench.estimate() {
            Some(mut w) => {
                w.mean = mean;
                w.n = raw.n;
                let n = raw.n as f64;
                w.std_error = w.std.map(|s| s / n.sqrt());
                w
            }
            None => BiasEstimate {
                n: raw.n,
                mean,
                std: [0.0; 6],
                std_error: [0.0; 6],
            },
        }
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

/// Everything a front end needs besides its port, resolved from a `[force_sensor]` section.
#[derive(Debug, Clone)]
pub struct FrontEndSettings {
    pub tool: ToolTransform,
    pub max_loads: [f64; 6],
    pub saturation: SaturationPolicy,
    pub calibration: Option<Calibration>,
    pub temperature_compensation: bool,
    pub counts_per_force: f64,
    pub counts_per_torque: f64,
    pub rate_hz: f64,
}

impl FrontEndSettings {
    /// Loads the calibration file (if any) and checks the tool transform.
    pub fn from_config(cfg: &ForceSensorConfig) -> Result<Self, FtError> {
        let tool = ToolTransform::from_angles(
            cfg.tool_offset_mm,
            cfg.tool_rotation_deg.map(f64::to_radians),
        )?;
        let calibration = match &cfg.calibration_file {
            Some(p) => Some(Calibration::load(p)?),
            None => None,
        };
        let max_loads = cfg
            .max_loads
            .or(calibration.as_ref().map(|c| c.max_loads))
            .unwrap_or(NANO17_SI_25_MAX);
        let (dcpf, dcpt) = match cfg.kind {
            ForceSensorKind::Netft | ForceSensorKind::Sim => (
                rig_core::ft::netft::FACTORY_COUNTS_PER_FORCE,
                rig_core::ft::netft::FACTORY_COUNTS_PER_TORQUE,
            ),
            _ => (
                rig_core::ft::serial::DEFAULT_COUNTS_PER_FORCE,
                rig_core::ft::serial::DEFAULT_COUNTS_PER_TORQUE,
            ),
        };
        Ok(Self {
            tool,
            max_loads,
            saturation: cfg.saturation,
            calibration,
            temperature_compensation: cfg.temperature_compensation,
            counts_per_force: cfg.counts_per_force.unwrap_or(dcpf),
            counts_per_torque: cfg.counts_per_torque.unwrap_or(dcpt),
            rate_hz: cfg.rate_hz,
        })
    }

    /// A conditioner for counts.
    pub fn counts_conditioner(&self) -> Conditioner {
        Conditioner::new(
            RawMap::Counts {
                counts_per_force: self.counts_per_force,
                counts_per_torque: self.counts_per_torque,
            },
            self.tool.clone(),
            self.max_loads,
            self.saturation,
        )
    }
}

/// Opens the front end a `[force_sensor]` section describes and starts streaming. `kind =
/// "sim"` starts the simulated Nano17 (a Net F/T on loopback) in-process, with no load.
pub async fn open(cfg: &ForceSensorConfig, clock: Clock) -> Result<FtStream, FtError> {
    let settings = FrontEndSettings::from_config(cfg)?;
    match cfg.kind {
        ForceSensorKind::Serial => {
            let port = cfg
                .port
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.port is required".into()))?;
            serial::open(
                serial::SerialOptions {
                    port,
                    baud: cfg.baud.unwrap_or(115_200),
                    output: cfg.output,
                    device_bias: false,
                },
                settings,
                clock,
            )
            .await
        }
        ForceSensorKind::Daq => {
            let port = cfg
                .port
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.port is required".into()))?;
            daq::open(&port, cfg.baud.unwrap_or(921_600), settings, clock).await
        }
        ForceSensorKind::Netft => {
            let addr = cfg
                .address
                .clone()
                .ok_or_else(|| FtError::Config("force_sensor.address is required".into()))?;
            netft::open(&addr, false, settings, clock).await
        }
        ForceSensorKind::Sim => {
            let source: hardware_mocks::truth::SharedWrenchSource =
                Arc::new(hardware_mocks::truth::ConstantWrench(Wrench::ZERO));
            open_sim(source, settings, clock).await
        }
    }
}

/// The simulated Nano17 (a Net F/T mock on loopback) driven by `source`, read by the real
/// Net F/T reader.
pub async fn open_sim(
    source: hardware_mocks::truth::SharedWrenchSource,
    settings: FrontEndSettings,
    clock: Clock,
) -> Result<FtStream, FtError> {
    use hardware_mocks::nano17::{SensorModel, netft::NetFtMock, netft::NetFtMockConfig};
    let mut model = SensorModel::nano17(0x5eed);
    model.tool = settings.tool.clone();
    let mock = NetFtMock::start(
        NetFtMockConfig {
            rate_hz: settings.rate_hz,
            counts_per_force: settings.counts_per_force,
            counts_per_torque: settings.counts_per_torque,
            ..NetFtMockConfig::default()
        },
        model,
        source,
        clock.clone(),
    )
    .await
    .map_err(|e| FtError::Io {
        device: "simulated Net F/T".into(),
        reason: e.to_string(),
    })?;
    let mut stream = netft::open(&mock.addr().to_string(), false, settings, clock).await?;
    stream.description = format!("simulated Nano17 (Net F/T on {})", mock.addr());
    stream.keep_alive(Box::new(mock));
    Ok(stream)
}
