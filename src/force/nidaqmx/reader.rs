//! The NI reader's thread: one task with the six gauge channels (and the thermistor), a
//! hardware-timed continuous acquisition, blocks read in a loop, and what each NI status means.

use rig_core::clock::Clock;
use rig_core::ft::SampleFlags;
use rig_core::ft::cal::OutputRange;
use rig_core::ft::nidaqmx::{self as ni, ErrorClass, PhysicalChannel, TerminalConfig};
use tokio::sync::mpsc::UnboundedReceiver;
use tokio::sync::mpsc::error::TryRecvError;

use super::library::{Api, Handle};
use crate::force::conditioning::Conditioner;
use crate::force::error::FtError;
use crate::force::stream::{Control, FtStats, Sink};

/// Clock time without a single sample after which the card counts as silent.
pub const SILENCE_TIMEOUT_S: f64 = 2.0;
/// Each read waits at most this long (clock time) so the thread sees its controls.
pub const READ_TIMEOUT_S: f64 = 0.2;
/// Samples per channel per read, as a fraction of a second: 5 ms blocks (200 reads a second),
/// so the safety supervisor sees each sample at most a block late.
pub const BLOCK_S: f64 = 0.005;
/// The card's buffer, seconds of samples: what a stalled host may fall behind before samples
/// are overwritten (and counted as lost).
pub const BUFFER_S: f64 = 2.0;

/// How the task is set up.
#[derive(Debug, Clone)]
pub struct TaskSpec {
    pub gauges: Vec<PhysicalChannel>,
    pub thermistor: Option<PhysicalChannel>,
    pub terminal: TerminalConfig,
    pub rate_hz: f64,
    /// The input range of every channel: the calibration file's output range.
    pub range: OutputRange,
}

impl TaskSpec {
    pub fn block(&self) -> usize {
        (self.rate_hz * BLOCK_S).round().max(1.0) as usize
    }
    pub fn buffer(&self) -> u64 {
        ((self.rate_hz * BUFFER_S).round() as u64).max(4 * self.block() as u64)
    }
    fn channels(&self) -> usize {
        6 + usize::from(self.thermistor.is_some())
    }
}

/// A configured, started task. Cleared when dropped.
pub(super) struct Task {
    api: &'static Api,
    handle: Handle,
}

impl Drop for Task {
    fn drop(&mut self) {
        self.api.clear_task(self.handle);
    }
}

impl Task {
    /// Creates the task, its channels, timing and buffer, and starts it.
    pub(super) fn start(api: &'static Api, spec: &TaskSpec) -> Result<Self, FtError> {
        let task = Task {
            api,
            handle: api.create_task("rig-nano17")?,
        };
        let (lo, hi) = (spec.range.min_v, spec.range.max_v);
        let gauges = ni::join_channels(&spec.gauges);
        api.create_ai_voltage_chan(task.handle, &gauges, spec.terminal.value(), lo, hi)?;
        if let Some(t) = &spec.thermistor {
            api.create_ai_voltage_chan(task.handle, &t.to_string(), spec.terminal.value(), lo, hi)?;
        }
        api.cfg_samp_clk_timing(task.handle, spec.rate_hz, spec.buffer())?;
        api.cfg_input_buffer(
            task.handle,
            u32::try_from(spec.buffer()).unwrap_or(u32::MAX),
        )?;
        // The card keeps acquiring when the host falls behind: the sample clock never stops,
        // so indices stay exact, and an overwritten stretch is skipped and counted.
        api.set_read_overwrite(task.handle, ni::val::OVERWRITE_UNREAD_SAMPS)?;
        api.start_task(task.handle)?;
        Ok(task)
    }
}

/// The read loop's state: where the card's read position is and what it is worth in
/// `device_seq`.
pub(super) struct Reader {
    pub api: &'static Api,
    pub task: Task,
    pub spec: TaskSpec,
    pub cond: Conditioner,
    pub sink: Sink,
    pub clock: Clock,
    /// The card's read position in the current acquisition (samples per channel consumed,
    /// skipped ones included).
    read_pos: u64,
    /// A jump of the read position set after an overrun, taken by the next read.
    pending_skip: u64,
    /// `device_seq` of the current acquisition's sample 0 (a restart after a FIFO overflow
    /// continues the count).
    base: u64,
    lost: u64,
    after_gap: bool,
    last_sample_ns: u64,
}

impl Reader {
    pub(super) fn new(
        api: &'static Api,
        task: Task,
        spec: TaskSpec,
        cond: Conditioner,
        sink: Sink,
        clock: Clock,
    ) -> Self {
        let now = clock.now_ns();
        Self {
            api,
            task,
            spec,
            cond,
            sink,
            clock,
            read_pos: 0,
            pending_skip: 0,
            base: 0,
            lost: 0,
            after_gap: false,
            last_sample_ns: now,
        }
    }

    /// Reads until stopped or the card fails; the error (if any) goes to the sink.
    pub(super) fn run(&mut self, mut ctl: UnboundedReceiver<Control>) {
        let nch = self.spec.channels();
        let block = self.spec.block();
        let mut buf = vec![0.0f64; block * nch];
        loop {
            if self.controls(&mut ctl) {
                return;
            }
            let (status, n) =
                self.api
                    .read_analog_f64(self.task.handle, block as i32, READ_TIMEOUT_S, &mut buf);
            let t_host_ns = self.clock.now_ns();
            if n > 0 && !self.deliver(&buf[..n * nch], n, t_host_ns) {
                return;
            }
            let outcome = match ni::classify(status) {
                ErrorClass::Ok | ErrorClass::Warning => Ok(()),
                ErrorClass::Timeout => self.silence(t_host_ns),
                ErrorClass::Overrun => self.skip_overwritten(),
                ErrorClass::FifoOverflow => self.restart(),
                ErrorClass::DeviceGone | ErrorClass::Fatal => {
                    Err(self.api.error("DAQmxReadAnalogF64", status))
                }
            };
            FtStats::set(&self.sink.stats.lost, self.lost);
            if let Err(e) = outcome {
                // A stream being stopped may see its card go (a simulator detaching it).
                if !self.controls(&mut ctl) {
                    self.sink.fail(e);
                }
                return;
            }
        }
    }

    /// Handles the control messages; true when the stream is to stop.
    fn controls(&mut self, ctl: &mut UnboundedReceiver<Control>) -> bool {
        loop {
            match ctl.try_recv() {
                Ok(Control::Tare { samples, reply }) => self.cond.start_tare(samples, reply),
                Ok(Control::Stop) | Err(TryRecvError::Disconnected) => return true,
                Err(TryRecvError::Empty) => return false,
            }
        }
    }

    /// Conditions and delivers `n` scans; false when the saturation policy says stop.
    fn deliver(&mut self, scans: &[f64], n: usize, t_host_ns: u64) -> bool {
        let nch = self.spec.channels();
        let first = self.read_pos + self.pending_skip;
        if self.pending_skip > 0 {
            self.lost += self.pending_skip;
            self.pending_skip = 0;
            self.after_gap = true;
            if let Err(e) = self.api.set_read_offset(self.task.handle, 0) {
                self.sink.fail(e);
                return false;
            }
        }
        self.read_pos = first + n as u64;
        self.last_sample_ns = t_host_ns;
        for (j, scan) in scans.chunks_exact(nch).enumerate() {
            let gauges: [f64; 6] = std::array::from_fn(|i| scan[i]);
            let thermistor = scan.get(6).copied();
            let mut flags = SampleFlags::NONE;
            if std::mem::take(&mut self.after_gap) {
                flags |= SampleFlags::AFTER_GAP;
            }
            let saturated = self.spec.range.saturated_gauges(&gauges);
            if saturated != 0 {
                flags |= SampleFlags::GAUGE_SATURATED;
            }
            let seq = self.base + first + j as u64;
            if !self.sink.condition_and_deliver(
                &mut self.cond,
                &gauges,
                thermistor,
                u32::from(saturated),
                flags,
                t_host_ns,
                seq,
            ) {
                return false;
            }
        }
        true
    }

    /// A read that timed out: fine unless the card has been silent too long.
    fn silence(&self, now_ns: u64) -> Result<(), FtError> {
        let silent_s = now_ns.saturating_sub(self.last_sample_ns) as f64 * 1e-9;
        if silent_s < SILENCE_TIMEOUT_S {
            return Ok(());
        }
        Err(FtError::NoAnswer {
            device: format!("NI {}", ni::join_channels(&self.spec.gauges)),
            what: "samples (is the card's sample clock running?)".into(),
            timeout_ms: (SILENCE_TIMEOUT_S * 1e3) as u64,
        })
    }

    /// After `-200279`: the samples from the read position up to what the card still holds
    /// were overwritten. Moves the read position (a relative offset) to an eighth of the buffer
    /// past the oldest sample still held, so the next read cannot race the card again; the
    /// jump is counted as lost when that read succeeds.
    fn skip_overwritten(&mut self) -> Result<(), FtError> {
        let acquired = self.api.total_acquired(self.task.handle)?;
        let buffer = self.spec.buffer();
        let target = acquired.saturating_sub(buffer) + buffer / 8;
        let skip = target.saturating_sub(self.read_pos).max(1);
        let offset = i32::try_from(skip).map_err(|_| FtError::Io {
            device: "NI-DAQmx".into(),
            reason: format!("the host fell {skip} samples behind the card"),
        })?;
        self.api.set_read_offset(self.task.handle, offset)?;
        self.pending_skip = skip;
        tracing::warn!(
            "NI-DAQmx overrun: {skip} samples overwritten before they were read (counted as lost)"
        );
        Ok(())
    }

    /// After an onboard FIFO overflow the acquisition has stopped: what the card acquired and
    /// no read returned is lost, and so are the sample periods until it runs again (measured on
    /// the rig's clock). Restarts the task and continues the sample count past them.
    fn restart(&mut self) -> Result<(), FtError> {
        let acquired = self
            .api
            .total_acquired(self.task.handle)
            .unwrap_or(self.read_pos);
        let stopped_ns = self.last_sample_ns;
        let _ = self.api.stop_task(self.task.handle);
        self.api.set_read_offset(self.task.handle, 0)?;
        self.api.start_task(self.task.handle)?;
        let gap_s = self.clock.now_ns().saturating_sub(stopped_ns) as f64 * 1e-9;
        let gap = (gap_s * self.spec.rate_hz).round() as u64;
        let unread = acquired.saturating_sub(self.read_pos + self.pending_skip);
        self.lost += self.pending_skip + unread + gap;
        self.base += self.read_pos + self.pending_skip + unread + gap;
        self.read_pos = 0;
        self.pending_skip = 0;
        self.after_gap = true;
        tracing::warn!(
            "NI-DAQmx onboard memory overflow: the acquisition was restarted; {} samples counted \
             as lost",
            unread + gap
        );
        Ok(())
    }
}
