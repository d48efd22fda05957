//! Simulated ATI Nano17 front ends: an F/T controller on a pty, a Net F/T on UDP, a DAQ
//! gauge stream on a pty, and an NI data-acquisition card behind NI-DAQmx's C API
//! ([`nidaqmx`], exported as a C library by the `nidaqmx-standin` crate).
//!
//! All of them sample a [`WrenchSource`] (the true wrench at the tool point, N and N·mm) on the
//! shared [`Clock`](rig_core::clock::Clock) at their configured rate, and push it through the same [`SensorModel`]:
//!
//! 1. the tool transform's inverse: tool-point wrench → sensor-frame wrench;
//! 2. noise at the sensor's resolution (Gaussian, σ = one resolution step per axis:
//!    Nano17 SI-25-0.25 1/160 N, 1/32 N·mm, 1/64 N·mm for Tz);
//! 3. the inverse calibration: `V = M⁻¹ F + bias_v` (a fixed per-gauge offset, so an untared
//!    reading is visibly wrong), then the inverse of the temperature compensation at the
//!    model's thermistor reading;
//! 4. gauge saturation: voltages clamp at ±[`GAUGE_RANGE_V`].
//!
//! The DAQ mock and the NI card send those voltages; the controller and Net F/T mocks, like the real boxes,
//! apply the calibration themselves (forward, with compensation) and send counts, so what the
//! rig receives is exactly what a real controller with this calibration would send.
//!
//! Faults ([`Faults`]) are injected at run time from a test or the `rig-mock` binary: garbage
//! bytes, truncated and corrupted records, dropped / reordered / duplicated packets (Net F/T),
//! forced saturation, and an unplugged port (the pty master is closed).

pub mod daq;
pub mod netft;
pub mod nidaqmx;
pub mod pty;
pub mod serial;

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rig_core::ft::NANO17_SI_25_RESOLUTION;
use rig_core::ft::cal::{Calibration, GAUGE_RANGE_V};
use rig_core::ft::transform::ToolTransform;
use tokio::sync::oneshot;

use pty::PtyMaster;

pub use crate::truth::{ConstantWrench, SharedWrenchSource, WrenchSource};

/// The configuration of one kind of simulated front end; says where the rig reaches it (a pty
/// path, a UDP address). Each kind's [`MockHandle`] has its own `start`.
pub trait MockConfig {
    /// Where the rig reaches a running mock: [`PathBuf`] for a pty, [`SocketAddr`] for UDP.
    type Endpoint;
}

/// A running simulated front end: where it is, its fault injector and counters, and its task.
/// [`MockHandle::shutdown`] is a graceful stop; dropping the handle aborts the task. The three
/// kinds are [`daq::DaqMock`], [`serial::SerialControllerMock`] and [`netft::NetFtMock`].
pub struct MockHandle<C: MockConfig> {
    endpoint: C::Endpoint,
    faults: Arc<Faults>,
    stats: Arc<MockStats>,
    stop: Option<oneshot::Sender<()>>,
    task: Option<tokio::task::JoinHandle<()>>,
}

impl<C: MockConfig> MockHandle<C> {
    /// Spawns `run(faults, stats, stop)` on the current tokio runtime, reachable at `endpoint`.
    pub(crate) fn spawn<F, Fut>(endpoint: C::Endpoint, run: F) -> Self
    where
        F: FnOnce(Arc<Faults>, Arc<MockStats>, oneshot::Receiver<()>) -> Fut,
        Fut: std::future::Future<Output = ()> + Send + 'static,
    {
        let faults = Arc::new(Faults::default());
        let stats = Arc::new(MockStats::default());
        let (stop_tx, stop_rx) = oneshot::channel();
        let task = tokio::spawn(run(faults.clone(), stats.clone(), stop_rx));
        Self {
            endpoint,
            faults,
            stats,
            stop: Some(stop_tx),
            task: Some(task),
        }
    }

    /// The fault injector.
    pub fn faults(&self) -> &Arc<Faults> {
        &self.faults
    }

    /// What the mock did, for exact comparison with what the rig counted.
    pub fn stats(&self) -> &Arc<MockStats> {
        &self.stats
    }

    /// Stops the mock (it closes its pty or socket) and waits for it.
    pub async fn shutdown(mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }
}

impl<C: MockConfig<Endpoint = PathBuf>> MockHandle<C> {
    /// Opens a pty and spawns `run(pty, faults, stats, stop)` on it, reachable at its path.
    pub(crate) fn spawn_on_pty<F, Fut>(run: F) -> std::io::Result<Self>
    where
        F: FnOnce(PtyMaster, Arc<Faults>, Arc<MockStats>, oneshot::Receiver<()>) -> Fut,
        Fut: std::future::Future<Output = ()> + Send + 'static,
    {
        let pty = PtyMaster::open()?;
        let path = pty.path().to_owned();
        Ok(Self::spawn(path, |faults, stats, stop| {
            run(pty, faults, stats, stop)
        }))
    }

    /// The pty path the rig opens.
    pub fn path(&self) -> &Path {
        &self.endpoint
    }
}

impl<C: MockConfig<Endpoint = SocketAddr>> MockHandle<C> {
    /// The UDP address the rig sends its requests to.
    pub fn addr(&self) -> SocketAddr {
        self.endpoint
    }
}

impl<C: MockConfig> Drop for MockHandle<C> {
    fn drop(&mut self) {
        if let Some(t) = &self.task {
            t.abort();
        }
    }
}

/// The simulated Nano17's calibration file (also shipped as a test file).
pub const SIM_CAL_XML: &str = include_str!("../../../tests/data/nano17_useraxis.cal");

/// The simulated Nano17's calibration.
pub fn sim_calibration() -> Calibration {
    // The embedded file is part of the build and covered by tests.
    Calibration::parse(SIM_CAL_XML).expect("embedded simulated calibration parses")
}

/// Per-gauge zero-load offset of the simulated sensor, volts (a real Nano17 reads tens to
/// hundreds of millivolts unloaded).
pub const SIM_BIAS_V: [f64; 6] = [0.1231, -0.0872, 0.2044, -0.1507, 0.0613, -0.0329];
/// The simulated thermistor reading, volts (a little off the calibration's `T0`, so the
/// temperature compensation matters).
pub const SIM_THERMISTOR_V: f64 = 1.2734;

/// A small, seedable PRNG (SplitMix64) with Gaussian samples (Box-Muller); enough for noise.
#[derive(Debug, Clone)]
pub struct Rng {
    state: u64,
    spare: Option<f64>,
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self {
            state: seed,
            spare: None,
        }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// Standard normal.
    pub fn gaussian(&mut self) -> f64 {
        if let Some(s) = self.spare.take() {
            return s;
        }
        let (u1, u2) = (self.uniform(), self.uniform());
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * std::f64::consts::PI * u2).sin_cos();
        self.spare = Some(r * s);
        r * c
    }
}

/// The physical sensor: true tool wrench → gauge voltages. See the module docs.
#[derive(Debug, Clone)]
pub struct SensorModel {
    pub calibration: Calibration,
    pub tool: ToolTransform,
    /// Zero-load gauge offsets, volts.
    pub bias_v: [f64; 6],
    /// Noise σ per axis, N and N·mm (sensor frame).
    pub noise_std: [f64; 6],
    /// Thermistor reading, volts.
    pub thermistor_v: f64,
    rng: Rng,
}

/// One simulated measurement.
#[derive(Debug, Clone, Copy)]
pub struct Measurement {
    /// Raw gauge voltages as the DAQ sees them (clamped at the ADC range).
    pub gauges_v: [f64; 6],
    /// Bit i: gauge i at the ADC range.
    pub saturated_gauges: u8,
    pub thermistor_v: f64,
}

impl SensorModel {
    /// The simulated Nano17 SI-25-0.25: [`sim_calibration`], identity tool transform,
    /// [`SIM_BIAS_V`], noise at the resolution.
    pub fn nano17(seed: u64) -> Self {
        Self {
            calibration: sim_calibration(),
            tool: ToolTransform::identity(),
            bias_v: SIM_BIAS_V,
            noise_std: NANO17_SI_25_RESOLUTION,
            thermistor_v: SIM_THERMISTOR_V,
            rng: Rng::new(seed),
        }
    }

    /// Samples the gauges for a true tool-point wrench `[Fx..Tz]` (N, N·mm). `force_saturate`
    /// drives every gauge to the ADC limit (an overload).
    pub fn measure(&mut self, true_tool: &[f64; 6], force_saturate: bool) -> Measurement {
        let mut w = self.tool.invert(true_tool);
        for (wi, s) in w.iter_mut().zip(self.noise_std) {
            *wi += s * self.rng.gaussian();
        }
        let clean = self.calibration.gauges_for(&w);
        let mut comp = [0.0; 6];
        for i in 0..6 {
            comp[i] = clean[i] + self.bias_v[i];
        }
        let mut g = match &self.calibration.temperature {
            Some(tc) => tc.uncompensate(&comp, self.thermistor_v),
            None => comp,
        };
        let mut sat = 0u8;
        for (i, gi) in g.iter_mut().enumerate() {
            if force_saturate {
                *gi = if *gi >= 0.0 {
                    GAUGE_RANGE_V
                } else {
                    -GAUGE_RANGE_V
                };
            }
            if gi.abs() >= GAUGE_RANGE_V || !gi.is_finite() {
                *gi = gi.clamp(-GAUGE_RANGE_V, GAUGE_RANGE_V);
                sat |= 1 << i;
            }
        }
        Measurement {
            gauges_v: g,
            saturated_gauges: sat,
            thermistor_v: self.thermistor_v,
        }
    }

    /// What a controller with this calibration resolves a measurement to (sensor frame, N and
    /// N·mm, offset included): compensation, then `M · V`.
    pub fn resolve(&self, m: &Measurement) -> [f64; 6] {
        let (g, _) = self
            .calibration
            .compensate(&m.gauges_v, Some(m.thermistor_v));
        self.calibration.wrench(&g, &[0.0; 6])
    }
}

/// Faults to inject, shared between a test (or the `rig-mock` binary) and a running mock.
#[derive(Debug, Default)]
pub struct Faults {
    garbage: Mutex<Vec<u8>>,
    truncate_next: AtomicU32,
    corrupt_next: AtomicU32,
    saturate: AtomicBool,
    unplug: AtomicBool,
    mute: AtomicBool,
    /// Net F/T: drop every n-th packet (0 = none).
    pub drop_every: AtomicU32,
    /// Net F/T: every n-th packet is held back and sent after the next one (0 = none).
    pub reorder_every: AtomicU32,
    /// Net F/T: every n-th packet is sent twice (0 = none).
    pub duplicate_every: AtomicU32,
}

impl Faults {
    /// Sends these bytes before the next record.
    pub fn inject_garbage(&self, bytes: &[u8]) {
        if let Ok(mut g) = self.garbage.lock() {
            g.extend_from_slice(bytes);
        }
    }
    /// Cuts the next `n` records short (about half their bytes).
    pub fn truncate_records(&self, n: u32) {
        self.truncate_next.fetch_add(n, Ordering::AcqRel);
    }
    /// Corrupts one byte in each of the next `n` records (a checksum failure on the DAQ).
    pub fn corrupt_records(&self, n: u32) {
        self.corrupt_next.fetch_add(n, Ordering::AcqRel);
    }
    /// Overloads the sensor (every gauge at the ADC limit) until cleared.
    pub fn set_saturated(&self, on: bool) {
        self.saturate.store(on, Ordering::Release);
    }
    /// Unplugs the port: the mock closes its end and stops.
    pub fn unplug(&self) {
        self.unplug.store(true, Ordering::Release);
    }

    /// Stops emitting records until cleared: samples are skipped, neither sent nor counted (a
    /// device sequence jumps over them). Lets a test compare what was sent with what arrived
    /// once the line is quiet.
    pub fn set_muted(&self, on: bool) {
        self.mute.store(on, Ordering::Release);
    }
    pub(crate) fn muted(&self) -> bool {
        self.mute.load(Ordering::Acquire)
    }

    pub(crate) fn take_garbage(&self) -> Vec<u8> {
        self.garbage
            .lock()
            .map(|mut g| std::mem::take(&mut *g))
            .unwrap_or_default()
    }
    pub(crate) fn take_one(counter: &AtomicU32) -> bool {
        counter
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| n.checked_sub(1))
            .is_ok()
    }
    pub(crate) fn take_truncate(&self) -> bool {
        Self::take_one(&self.truncate_next)
    }
    pub(crate) fn take_corrupt(&self) -> bool {
        Self::take_one(&self.corrupt_next)
    }
    /// Whether an overload is being injected.
    pub fn saturated(&self) -> bool {
        self.saturate.load(Ordering::Acquire)
    }
    /// Whether the port has been unplugged.
    pub fn unplugged(&self) -> bool {
        self.unplug.load(Ordering::Acquire)
    }
}

/// What a mock did, for exact comparison with what the rig counted.
#[derive(Debug, Default)]
pub struct MockStats {
    /// Records (packets, frames) sent intact.
    pub sent: AtomicU64,
    /// Records sampled but deliberately not sent (Net F/T drops).
    pub dropped: AtomicU64,
    /// Records sent after a later one (Net F/T reordering).
    pub reordered: AtomicU64,
    /// Records sent twice (Net F/T).
    pub duplicated: AtomicU64,
    /// Records cut short.
    pub truncated: AtomicU64,
    /// Records with a corrupted byte.
    pub corrupted: AtomicU64,
    /// Garbage bytes sent.
    pub garbage_bytes: AtomicU64,
    /// Commands received (serial) or requests (Net F/T).
    pub commands: AtomicU64,
    /// Clock time (ns) of sample 0 of the current stream (DAQ: since start; serial: since the
    /// last `QS`). With it a test maps a record's sequence number to the instant the simulated
    /// sensor measured it, which does not depend on when the host got round to reading it.
    pub stream_start_ns: AtomicU64,
}

impl MockStats {
    pub fn get(v: &AtomicU64) -> u64 {
        v.load(Ordering::Acquire)
    }

    /// The instant (clock ns) the simulated sensor measured sample `seq` of the current stream
    /// at `rate_hz`: the truth a front end's output for that sample is compared with.
    pub fn sample_time_ns(&self, seq: u64, rate_hz: f64) -> u64 {
        sample_time_ns(Self::get(&self.stream_start_ns), seq, rate_hz)
    }
}

/// Time of sample `k` of a stream started at `t0_ns` at `rate_hz`.
pub(crate) fn sample_time_ns(t0_ns: u64, k: u64, rate_hz: f64) -> u64 {
    t0_ns + (k as f64 * 1e9 / rate_hz).round() as u64
}
