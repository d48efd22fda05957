//! A simulated DAQ gauge front end on a pty (framing: `rig_core::ft::daq`).
//!
//! It streams from the moment it starts, one frame per sample at the configured rate, whether
//! or not anyone has the port open (like a microcontroller that just runs); frames written
//! while no one reads stay in the pty buffer up to its size, then writes wait. Gauge voltages
//! come from the [`SensorModel`] (inverse calibration, offset, noise, temperature), quantised
//! to 1 µV; status bits 0-5 flag gauges at the ADC range. Device time is the clock time in µs.
//!
//! Faults: garbage bytes, truncated frames (cut after half their bytes, the next frame
//! follows at once), corrupted frames (one data byte flipped: a CRC failure), forced
//! saturation, and unplugging (the pty master closes).

use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use rig_core::clock::Clock;
use rig_core::ft::daq::DaqFrame;
use tokio::sync::oneshot;

use super::pty::PtyMaster;
use super::{
    Faults, MockConfig, MockHandle, MockStats, SensorModel, SharedWrenchSource, sample_time_ns,
};

/// Configuration of the simulated DAQ front end.
#[derive(Debug, Clone)]
pub struct DaqMockConfig {
    pub rate_hz: f64,
    /// Send the thermistor channel (else [`rig_core::ft::daq::NO_THERMISTOR`]).
    pub thermistor: bool,
    pub seed: u64,
}

impl Default for DaqMockConfig {
    fn default() -> Self {
        Self {
            rate_hz: rig_core::ft::DEFAULT_RATE_HZ,
            thermistor: true,
            seed: 7,
        }
    }
}

/// A running simulated DAQ front end.
pub type DaqMock = MockHandle<DaqMockConfig>;

impl MockConfig for DaqMockConfig {
    type Endpoint = PathBuf;
}

impl DaqMock {
    /// Opens a pty and starts streaming. Needs a tokio runtime.
    pub fn start(
        cfg: DaqMockConfig,
        model: SensorModel,
        source: SharedWrenchSource,
        clock: Clock,
    ) -> io::Result<Self> {
        Self::spawn_on_pty(|pty, faults, stats, stop| {
            run(pty, cfg, model, source, clock, faults, stats, stop)
        })
    }
}

#[allow(clippy::too_many_arguments)]
async fn run(
    pty: PtyMaster,
    cfg: DaqMockConfig,
    mut model: SensorModel,
    source: SharedWrenchSource,
    clock: Clock,
    faults: Arc<Faults>,
    stats: Arc<MockStats>,
    mut stop: oneshot::Receiver<()>,
) {
    let t0 = clock.now_ns();
    stats.stream_start_ns.store(t0, Ordering::Release);
    let mut k: u64 = 0;
    let mut out = Vec::new();
    loop {
        if faults.unplugged() {
            return;
        }
        let due = sample_time_ns(t0, k, cfg.rate_hz);
        tokio::select! {
            _ = &mut stop => return,
            _ = clock.sleep_until_ns(due) => {}
        }
        let now = clock.now_ns();
        out.clear();
        loop {
            let t = sample_time_ns(t0, k, cfg.rate_hz);
            if t > now {
                break;
            }
            if faults.muted() {
                k += 1;
                continue;
            }
            let truth = source.wrench_at(t).to_array();
            let m = model.measure(&truth, faults.saturated());
            let frame = DaqFrame {
                sequence: k as u32,
                device_time_us: (t / 1000) as u32,
                gauges_uv: m.gauges_v.map(DaqFrame::volts_to_uv),
                thermistor_uv: if cfg.thermistor {
                    DaqFrame::volts_to_uv(m.thermistor_v)
                } else {
                    rig_core::ft::daq::NO_THERMISTOR
                },
                status: m.saturated_gauges,
            };
            k += 1;
            let garbage = faults.take_garbage();
            if !garbage.is_empty() {
                stats
                    .garbage_bytes
                    .fetch_add(garbage.len() as u64, Ordering::AcqRel);
                out.extend_from_slice(&garbage);
            }
            let mut bytes = frame.encode();
            if faults.take_truncate() {
                stats.truncated.fetch_add(1, Ordering::AcqRel);
                out.extend_from_slice(&bytes[..bytes.len() / 2]);
                continue;
            }
            if faults.take_corrupt() {
                stats.corrupted.fetch_add(1, Ordering::AcqRel);
                bytes[20] ^= 0x5a;
                out.extend_from_slice(&bytes);
                continue;
            }
            stats.sent.fetch_add(1, Ordering::AcqRel);
            out.extend_from_slice(&bytes);
        }
        // Real time may have been lost waiting for a reader: that is the pty's back-pressure,
        // not a dropped sample (every sample is still written, late).
        if !out.is_empty() && pty.write_all(&out).await.is_err() {
            return;
        }
    }
}
