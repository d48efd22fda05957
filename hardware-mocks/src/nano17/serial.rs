//! A simulated ATI F/T controller on a pty (see `rig_core::ft::serial` for the protocol).
//!
//! Behaviour modelled on the controller manual: every command byte is echoed; a command is
//! executed at CR, then a CR LF and the `>` prompt follow. `CD A` / `CD B` select ASCII or
//! binary records, `CD R` resolved output (the only output mode simulated), `QR` prints one
//! record, `QS` streams records at the configured rate until any byte arrives (that byte is
//! swallowed, then CR LF `>`), `SB` makes the present reading the zero, `SA n` sets averaging
//! (accepted and echoed; the simulated noise is not averaged). Unknown commands answer
//! `Error`. The status word is 0, or [`STATUS_SATURATED`] when a gauge is at the ADC limit.
//!
//! Counts are `round(F · CPF)`, `round(T · CPT)` of the resolved, biased wrench.

use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use rig_core::clock::Clock;
use rig_core::ft::serial::{
    Command, CountsRecord, DEFAULT_COUNTS_PER_FORCE, DEFAULT_COUNTS_PER_TORQUE, OutputMode,
};
use rig_core::ft::{DEFAULT_RATE_HZ, wrench_to_counts};
use tokio::sync::oneshot;

use super::pty::PtyMaster;
use super::{
    Faults, MockConfig, MockHandle, MockStats, SensorModel, SharedWrenchSource, sample_time_ns,
};

/// Status word of a record taken while a gauge is saturated (the mock's choice of bit).
pub const STATUS_SATURATED: u32 = 0x0001;

/// Configuration of the simulated controller.
#[derive(Debug, Clone)]
pub struct SerialMockConfig {
    /// Records per second while streaming (`QS`).
    pub rate_hz: f64,
    /// Counts per newton.
    pub counts_per_force: f64,
    /// Counts per N·mm.
    pub counts_per_torque: f64,
    /// Output mode at power-up.
    pub mode: OutputMode,
    /// Noise seed.
    pub seed: u64,
}

impl Default for SerialMockConfig {
    fn default() -> Self {
        Self {
            rate_hz: DEFAULT_RATE_HZ,
            counts_per_force: DEFAULT_COUNTS_PER_FORCE,
            counts_per_torque: DEFAULT_COUNTS_PER_TORQUE,
            mode: OutputMode::Ascii,
            seed: 17,
        }
    }
}

/// A running simulated controller.
pub type SerialControllerMock = MockHandle<SerialMockConfig>;

impl MockConfig for SerialMockConfig {
    type Endpoint = PathBuf;
}

impl SerialControllerMock {
    /// Opens a pty and starts the controller on it. Needs a tokio runtime.
    pub fn start(
        cfg: SerialMockConfig,
        model: SensorModel,
        source: SharedWrenchSource,
        clock: Clock,
    ) -> io::Result<Self> {
        Self::spawn_on_pty(|pty, faults, stats, stop| {
            run(pty, cfg, model, source, clock, faults, stats, stop)
        })
    }
}

struct Controller {
    cfg: SerialMockConfig,
    model: SensorModel,
    source: SharedWrenchSource,
    faults: Arc<Faults>,
    stats: Arc<MockStats>,
    mode: OutputMode,
    bias: [f64; 6],
}

impl Controller {
    fn record(&mut self, t_ns: u64) -> CountsRecord {
        let truth = self.source.wrench_at(t_ns).to_array();
        let m = self.model.measure(&truth, self.faults.saturated());
        let w = self.model.resolve(&m);
        let biased: [f64; 6] = std::array::from_fn(|i| w[i] - self.bias[i]);
        let counts = wrench_to_counts(
            &biased,
            self.cfg.counts_per_force,
            self.cfg.counts_per_torque,
        );
        let status = if m.saturated_gauges != 0 {
            STATUS_SATURATED
        } else {
            0
        };
        CountsRecord { status, counts }
    }

    fn encode(&self, r: &CountsRecord) -> Vec<u8> {
        match self.mode {
            OutputMode::Ascii => r.encode_ascii(),
            OutputMode::Binary => r.encode_binary().to_vec(),
        }
    }

    /// Applies faults to one encoded record and appends it to `out`.
    fn emit(&self, rec: Vec<u8>, out: &mut Vec<u8>) {
        let garbage = self.faults.take_garbage();
        if !garbage.is_empty() {
            self.stats
                .garbage_bytes
                .fetch_add(garbage.len() as u64, Ordering::AcqRel);
            out.extend_from_slice(&garbage);
        }
        if self.faults.take_truncate() {
            self.stats.truncated.fetch_add(1, Ordering::AcqRel);
            let keep = rec.len() / 2;
            out.extend_from_slice(&rec[..keep]);
            if self.mode == OutputMode::Ascii {
                // A cut line still ends where the next record starts on a new line.
                out.extend_from_slice(b"\r\n");
            }
            return;
        }
        self.stats.sent.fetch_add(1, Ordering::AcqRel);
        out.extend_from_slice(&rec);
    }
}

#[allow(clippy::too_many_arguments)]
async fn run(
    pty: PtyMaster,
    cfg: SerialMockConfig,
    model: SensorModel,
    source: SharedWrenchSource,
    clock: Clock,
    faults: Arc<Faults>,
    stats: Arc<MockStats>,
    mut stop: oneshot::Receiver<()>,
) {
    let mut c = Controller {
        mode: cfg.mode,
        cfg,
        model,
        source,
        faults: faults.clone(),
        stats,
        bias: [0.0; 6],
    };
    let mut line: Vec<u8> = Vec::new();
    let mut buf = [0u8; 256];
    // Streaming state: start time and index of the next sample.
    let mut stream: Option<(u64, u64)> = None;
    let mut out: Vec<u8> = Vec::new();
    loop {
        if faults.unplugged() {
            tracing::info!("simulated F/T controller unplugged");
            return;
        }
        let next_due = stream.map(|(t0, k)| sample_time_ns(t0, k, c.cfg.rate_hz));
        tokio::select! {
            _ = &mut stop => return,
            r = pty.read(&mut buf) => {
                let n = match r {
                    Ok(0) => continue,
                    Ok(n) => n,
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                    // EIO: no slave open right now; wait and retry.
                    Err(_) => { clock.sleep(std::time::Duration::from_millis(5)).await; continue; }
                };
                out.clear();
                for &b in &buf[..n] {
                    if stream.is_some() {
                        // Any byte stops a QS stream.
                        stream = None;
                        out.extend_from_slice(b"\r\n>");
                        line.clear();
                        continue;
                    }
                    if b == b'\r' || b == b'\n' {
                        if b == b'\n' && line.is_empty() { continue; }
                        out.extend_from_slice(b"\r\n");
                        let text = String::from_utf8_lossy(&line).into_owned();
                        line.clear();
                        c.stats.commands.fetch_add(1, Ordering::AcqRel);
                        match Command::parse(&text) {
                            Some(Command::OutputAscii) => { c.mode = OutputMode::Ascii; out.push(b'>'); }
                            Some(Command::OutputBinary) => { c.mode = OutputMode::Binary; out.push(b'>'); }
                            Some(Command::OutputResolved | Command::Averaging(_)) => out.push(b'>'),
                            Some(Command::StopStream) => out.push(b'>'),
                            Some(Command::Bias) => {
                                let t = clock.now_ns();
                                let truth = c.source.wrench_at(t).to_array();
                                let m = c.model.measure(&truth, c.faults.saturated());
                                c.bias = c.model.resolve(&m);
                                out.push(b'>');
                            }
                            Some(Command::QueryRecord) => {
                                let r = c.record(clock.now_ns());
                                let enc = c.encode(&r);
                                c.emit(enc, &mut out);
                                if c.mode == OutputMode::Binary { out.extend_from_slice(b"\r\n"); }
                                out.push(b'>');
                            }
                            Some(Command::QueryStream) => {
                                let t0 = clock.now_ns();
                                c.stats.stream_start_ns.store(t0, Ordering::Release);
                                stream = Some((t0, 0));
                            }
                            None => out.extend_from_slice(b"Error\r\n>"),
                        }
                    } else {
                        // Echo as the controller does.
                        out.push(b);
                        line.push(b);
                        if line.len() > 64 { line.clear(); }
                    }
                }
                if !out.is_empty() && pty.write_all(&out).await.is_err() { return; }
            }
            _ = async {
                match next_due {
                    Some(t) => clock.sleep_until_ns(t).await,
                    None => std::future::pending().await,
                }
            } => {
                let Some((t0, mut k)) = stream else { continue };
                let now = clock.now_ns();
                out.clear();
                loop {
                    let t = sample_time_ns(t0, k, c.cfg.rate_hz);
                    if t > now { break; }
                    if faults.muted() { k += 1; continue; }
                    let r = c.record(t);
                    let enc = c.encode(&r);
                    c.emit(enc, &mut out);
                    k += 1;
                }
                stream = Some((t0, k));
                if pty.write_all(&out).await.is_err() { return; }
            }
        }
    }
}
