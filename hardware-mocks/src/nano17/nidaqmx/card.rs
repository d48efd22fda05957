//! The simulated card's state: its devices (with their sensor, hook, faults and log), its
//! tasks (channels, timing, buffer, read position) and the device-level API of the stand-in
//! (`standin_*`). The NI-DAQmx calls on tasks are in the sibling `task` module.

use std::collections::HashMap;
use std::sync::{Mutex, MutexGuard, OnceLock};
use std::time::Instant;

use super::errors::{self, Fail};
use super::hook::{self, LOG_WIDTH, StandinHook, StandinStats};
use crate::nano17::SensorModel;

/// NI's default input buffer for a continuous task at 100 S/s to 10 kS/s, samples per channel.
pub const DEFAULT_BUFFER: u64 = 10_000;

/// Analog inputs per device (`ai0`..`ai15`).
pub const AI_CHANNELS: u32 = 16;
/// The card's bipolar input ranges, V.
pub const RANGES_V: [f64; 4] = [0.2, 1.0, 5.0, 10.0];
/// Aggregate sample rate limit of the card, samples per second over all channels.
pub const MAX_AGGREGATE_RATE: f64 = 250_000.0;
/// The device every stand-in starts with.
pub const DEFAULT_DEVICE: &str = "Dev1";
/// Where the Nano17 is wired: gauge i on `ai{i}`, the thermistor on `ai6`.
pub const THERMISTOR_INPUT: u32 = 6;
/// Seed of the default device's sensor noise.
pub const DEFAULT_SEED: u64 = 0x0D_A0_17;

/// What the Nano17 puts on input `ai`: gauge i, the thermistor, or nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wire {
    Gauge(usize),
    Thermistor,
    Open,
}

/// The wiring of ATI's DAQ F/T cable to the card.
pub fn wire(ai: u32) -> Wire {
    match ai {
        0..=5 => Wire::Gauge(ai as usize),
        THERMISTOR_INPUT => Wire::Thermistor,
        _ => Wire::Open,
    }
}

/// Faults injected into one device.
#[derive(Debug, Clone, Default)]
pub(crate) struct Injections {
    pub overrun_at: Option<u64>,
    pub remove_at: Option<u64>,
    pub fifo_at: Option<u64>,
    pub late_start_ns: u64,
}

/// The voltages a device's card read, by sample index of its current run.
#[derive(Debug, Clone, Default)]
pub(crate) struct Log {
    pub max: u64,
    pub values: Vec<[f64; LOG_WIDTH]>,
}

/// One simulated card with its Nano17.
pub(crate) struct Device {
    pub hook: Option<StandinHook>,
    epoch: Instant,
    pub model: SensorModel,
    pub injections: Injections,
    pub removed: bool,
    /// The running task that holds the card's analog inputs.
    pub reserved_by: Option<u64>,
    pub log: Option<Log>,
    pub stats: StandinStats,
    /// The clock's rate against real time, measured over the last stretch of ≥ 50 ms.
    pub pace: (Instant, u64, f64),
}

impl Device {
    fn new(hook: Option<StandinHook>, seed: u64) -> Self {
        Self {
            hook,
            epoch: Instant::now(),
            model: SensorModel::nano17(seed),
            injections: Injections::default(),
            removed: false,
            reserved_by: None,
            log: None,
            stats: StandinStats {
                log_width: LOG_WIDTH as u64,
                ..StandinStats::default()
            },
            pace: (Instant::now(), 0, 1.0),
        }
    }

    /// How many clock ns pass per real ns (1 until measured), given the clock's `now_ns`.
    pub fn clock_rate(&mut self, now_ns: u64) -> f64 {
        let (t, c, rate) = self.pace;
        let real = t.elapsed().as_nanos() as f64;
        if real >= 50e6 {
            let r = now_ns.saturating_sub(c) as f64 / real;
            self.pace = (
                Instant::now(),
                now_ns,
                if c == 0 || r <= 0.0 { rate } else { r },
            );
        }
        self.pace.2
    }

    /// The device's clock: the hook's, else real time since the device appeared.
    pub fn now_ns(&self) -> u64 {
        match self.hook.and_then(|h| h.now_ns.map(|f| (f, h.ctx))) {
            // SAFETY: the attaching side keeps `ctx` and the callback valid until detached,
            // and detaching takes the same lock this call runs under.
            Some((f, ctx)) => unsafe { f(ctx) },
            None => u64::try_from(self.epoch.elapsed().as_nanos()).unwrap_or(u64::MAX),
        }
    }

    /// The true wrench (sensor frame) at clock time `t_ns`: the hook's, else zero.
    pub fn wrench_at(&self, t_ns: u64) -> [f64; 6] {
        let mut w = [0.0; 6];
        if let Some(h) = self.hook
            && let Some(f) = h.wrench_at
        {
            // SAFETY: as in `now_ns`; `w` has room for the six values.
            unsafe { f(h.ctx, t_ns, w.as_mut_ptr()) };
        }
        w
    }

    /// Tells the hook a task started or stopped acquiring.
    pub fn acquiring(&self, on: bool) {
        if let Some(h) = self.hook
            && let Some(f) = h.acquiring
        {
            // SAFETY: as in `now_ns`.
            unsafe { f(h.ctx, u32::from(on)) };
        }
    }

    /// The hook's fault bits now.
    pub fn fault_bits(&self) -> u32 {
        match self.hook.and_then(|h| h.faults.map(|f| (f, h.ctx))) {
            // SAFETY: as in `now_ns`.
            Some((f, ctx)) => unsafe { f(ctx) },
            None => 0,
        }
    }
}

/// The process's simulated NI system: its devices and tasks.
pub struct System {
    inner: Mutex<Inner>,
}

pub(crate) struct Inner {
    pub devices: HashMap<String, Device>,
    pub tasks: HashMap<u64, Task>,
    next_handle: u64,
}

impl Default for System {
    fn default() -> Self {
        Self::new()
    }
}

impl System {
    /// A system with one free-running device, [`DEFAULT_DEVICE`].
    pub fn new() -> Self {
        let mut devices = HashMap::new();
        devices.insert(DEFAULT_DEVICE.to_owned(), Device::new(None, DEFAULT_SEED));
        Self {
            inner: Mutex::new(Inner {
                devices,
                tasks: HashMap::new(),
                next_handle: 1,
            }),
        }
    }

    /// The process-wide system the C library exports.
    pub fn global() -> &'static System {
        static SYSTEM: OnceLock<System> = OnceLock::new();
        SYSTEM.get_or_init(System::new)
    }

    pub(crate) fn lock(&self) -> MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Adds `device` (or replaces its hook): with a hook it follows the simulator's clock, true
    /// wrench and faults; without one it runs on real time with no load. Its faults and log are
    /// reset; a running task on it keeps running.
    pub fn attach(&self, device: &str, hook: Option<StandinHook>) -> Result<(), Fail> {
        if let Some(h) = hook
            && (h.version != hook::HOOK_VERSION || h.now_ns.is_none() || h.wrench_at.is_none())
        {
            return Err(Fail::new(
                errors::INVALID_ATTRIBUTE_VALUE,
                format!(
                    "standin_attach: hook version {} (this stand-in: {}) or a missing callback",
                    h.version,
                    hook::HOOK_VERSION
                ),
            ));
        }
        check_device_name(device)?;
        let mut g = self.lock();
        let seed = DEFAULT_SEED
            ^ device
                .bytes()
                .fold(0u64, |a, b| a.rotate_left(8) ^ u64::from(b));
        match g.devices.get_mut(device) {
            Some(d) => {
                d.hook = hook;
                d.pace = (Instant::now(), 0, 1.0);
                d.injections = Injections::default();
                d.removed = false;
                d.log = None;
            }
            None => {
                g.devices.insert(device.to_owned(), Device::new(hook, seed));
            }
        }
        Ok(())
    }

    /// Drops `device`'s hook: no callback runs after this returns. A task still running on the
    /// device then fails as if the card had been removed.
    pub fn detach(&self, device: &str) -> Result<(), Fail> {
        let mut g = self.lock();
        let d = device_mut(&mut g, device)?;
        if d.hook.take().is_some() {
            d.removed = true;
        }
        Ok(())
    }

    /// Injects a fault ([`hook::fault`]) into `device`.
    pub fn inject(&self, device: &str, fault: u32, at_sample: u64, arg: u64) -> Result<(), Fail> {
        let mut g = self.lock();
        let d = device_mut(&mut g, device)?;
        let inj = &mut d.injections;
        match fault {
            hook::fault::CLEAR => *inj = Injections::default(),
            hook::fault::OVERRUN => inj.overrun_at = Some(at_sample),
            hook::fault::REMOVE => inj.remove_at = Some(at_sample),
            hook::fault::FIFO_OVERFLOW => inj.fifo_at = Some(at_sample),
            hook::fault::LATE_START => inj.late_start_ns = arg,
            other => {
                return Err(Fail::new(
                    errors::INVALID_ATTRIBUTE_VALUE,
                    format!("standin_inject: unknown fault {other}"),
                ));
            }
        }
        Ok(())
    }

    /// Keeps the voltages the card reads from now on (up to `max` samples of a run; 0 stops).
    pub fn set_log(&self, device: &str, max: u64) -> Result<(), Fail> {
        let mut g = self.lock();
        let d = device_mut(&mut g, device)?;
        d.log = (max > 0).then(|| Log {
            max,
            values: Vec::new(),
        });
        Ok(())
    }

    /// Logged samples `first..first + n` of the current run (`[f64; LOG_WIDTH]` each; NaN for a
    /// sample not read). Fewer when the log is shorter.
    pub fn log_read(&self, device: &str, first: u64, n: u64) -> Vec<[f64; LOG_WIDTH]> {
        let g = self.lock();
        let Some(log) = g.devices.get(device).and_then(|d| d.log.as_ref()) else {
            return Vec::new();
        };
        let len = log.values.len() as u64;
        let (a, b) = (first.min(len), first.saturating_add(n).min(len));
        log.values[a as usize..b as usize].to_vec()
    }

    /// What `device`'s card did so far.
    pub fn stats(&self, device: &str) -> Result<StandinStats, Fail> {
        let mut g = self.lock();
        let inner = &mut *g;
        let d = inner
            .devices
            .get(device)
            .ok_or_else(|| unknown_device(device))?;
        let mut s = d.stats;
        if let Some(t) = d.reserved_by.and_then(|h| inner.tasks.get(&h)) {
            s.acquired = t.acquired(d, d.now_ns());
        }
        Ok(s)
    }
}

pub(crate) fn check_device_name(device: &str) -> Result<(), Fail> {
    if device.is_empty() || device.contains(['/', ',', ':']) || device.contains(char::is_whitespace)
    {
        return Err(Fail::new(
            errors::INVALID_DEVICE_ID,
            format!("Device Specified: {device:?}"),
        ));
    }
    Ok(())
}

pub(crate) fn unknown_device(device: &str) -> Fail {
    Fail::new(
        errors::INVALID_DEVICE_ID,
        format!("Device Specified: {device}\nSuggested Device(s): {DEFAULT_DEVICE}"),
    )
}

pub(crate) fn device_mut<'a>(g: &'a mut Inner, device: &str) -> Result<&'a mut Device, Fail> {
    g.devices
        .get_mut(device)
        .ok_or_else(|| unknown_device(device))
}

impl Inner {
    pub(crate) fn new_handle(&mut self) -> u64 {
        let h = self.next_handle;
        self.next_handle += 1;
        h
    }
}

/// One analog input of a task.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    pub ai: u32,
    /// The card's range used for it, ±V.
    pub range_v: f64,
}

/// A read's result: samples per channel read, and the error that cut it short, if any.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadOutcome {
    pub read: usize,
    pub error: Option<Fail>,
}

#[derive(Debug, Clone)]
pub(crate) struct Run {
    pub t0_ns: u64,
    pub read_pos: u64,
    /// An error that ended the acquisition (overflow, removal); every read returns it.
    pub error: Option<Fail>,
}

/// A task: a device's channels and how they are sampled.
#[derive(Debug, Clone)]
pub(crate) struct Task {
    pub name: String,
    pub device: Option<String>,
    pub channels: Vec<Channel>,
    pub rate_hz: Option<f64>,
    pub finite: Option<u64>,
    pub buffer: Option<u64>,
    pub overwrite: bool,
    pub relative_to: i32,
    pub offset: i32,
    pub run: Option<Run>,
}

impl Task {
    pub fn buffer(&self) -> u64 {
        self.buffer
            .unwrap_or_else(|| self.finite.unwrap_or(0).max(DEFAULT_BUFFER))
    }

    pub fn sample_time_ns(&self, t0: u64, k: u64) -> u64 {
        let rate = self.rate_hz.unwrap_or(1.0);
        t0 + (k as f64 * 1e9 / rate).round() as u64
    }

    /// Samples per channel the sample clock has ticked by clock time `now` (0 when stopped), not
    /// counting what an injected removal or FIFO overflow stops.
    pub fn ticked(&self, now: u64) -> u64 {
        let (Some(run), Some(rate)) = (&self.run, self.rate_hz) else {
            return 0;
        };
        if now < run.t0_ns {
            return 0;
        }
        let n = ((now - run.t0_ns) as f64 * rate * 1e-9).floor() as u64 + 1;
        self.finite.map_or(n, |f| n.min(f))
    }

    /// Samples per channel acquired by clock time `now`.
    pub(crate) fn acquired(&self, dev: &Device, now: u64) -> u64 {
        let mut n = self.ticked(now);
        for cap in [dev.injections.remove_at, dev.injections.fifo_at]
            .into_iter()
            .flatten()
        {
            n = n.min(cap);
        }
        n
    }
}
