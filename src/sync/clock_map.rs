//! Mapping a device clock onto the host clock: offset + skew, from one-way timestamps.
//!
//! # Model
//!
//! A device stamps a sample with its own time `x` (ns of device time, after unwrapping, see
//! [`Unwrapper`]) and the host receives it at `y = t_host_ns` of the shared
//! [`rig_core::clock::Clock`]. Between the two lies a transport latency `d ≥ d_min`:
//!
//! ```text
//! y = α + β·x + d,     d = d_min + (non-negative jitter)
//! ```
//!
//! Only the lower envelope of the `(x, y)` cloud carries information about `α + d_min` and `β`:
//! every point lies on or above the line `α + d_min + β·x`. One-way measurements cannot separate
//! `α` from `d_min`; the minimum latency is a configured constant
//! ([`EstimatorConfig::min_latency_ns`], 0 when unknown) and the estimator returns the line
//! `y = α + β·x` with that constant subtracted.
//!
//! # Fit: lower convex hull over a sliding window
//!
//! This is the linear-programming skew estimator of Moon, Skelly & Towsley (*Estimation and
//! removal of clock skew from network delay measurements*, INFOCOM 1999): minimise
//! `Σ (y_i − α − β·x_i)` subject to `y_i ≥ α + β·x_i`. Its solution lies on the lower convex hull
//! of the points (Zhang, Liu & Xia, *Clock synchronization algorithms for network measurements*,
//! INFOCOM 2002): the objective equals `N·(ȳ − (α + β·x̄))`, so the optimal line is the hull's
//! supporting line at the mean `x̄`, i.e. the hull edge whose x-span contains `x̄`. It is exact
//! when the jitter is zero (all points on one line) and, unlike a least-squares fit, unbiased by
//! jitter, which only ever pushes points *up*.
//!
//! To keep the cost bounded at 1 kHz the window is decimated the way Olson's passive
//! synchronisation tracks minimum latency (E. Olson, *A passive solution to the sensor
//! synchronization problem*, IROS 2010): device time is cut into buckets of
//! [`EstimatorConfig::bucket_ns`] and only each bucket's lowest point (minimum `y − x`) is kept;
//! the hull only ever uses low points. The hull is refitted lazily when a mapping is asked for.
//!
//! **Drift bound.** With very few samples (or a short span) a hull edge between two jittery
//! points can have an absurd slope. The skew is therefore clamped to
//! `nominal ± max_drift_ppm`; with a clamped slope the offset is the supporting line of that
//! slope (the Olson bound: minimum of `y − β·x`). With a single sample the estimator is an
//! offset-only fit at the nominal rate. [`EstimatorConfig::estimate_drift`] `= false` always
//! uses the nominal rate (what the sync bench compares against).
//!
//! # Jumps
//!
//! A sample far *below* the current line (more than `jump_tolerance_ns`, impossible under the
//! model: negative latency) or far above it (more than `jump_tolerance_ns` of latency, which a
//! single late packet may also cause) is held as *suspect* and not fitted. When
//! [`EstimatorConfig::jump_confirm`] consecutive suspects agree with each other, the device clock
//! has stepped: the old fit is frozen under its epoch number (so samples stamped before the jump
//! still map correctly, [`ClockEstimator::to_host_in`]), the window restarts from the suspects,
//! and [`ClockEvent::Jump`] reports the step. A suspect followed by a normal sample was only a
//! late packet ([`ClockEvent::Outlier`]); late points are harmless to a lower hull, so it is
//! fitted after all.

use std::collections::VecDeque;

/// Configuration of a [`ClockEstimator`].
#[derive(Debug, Clone, PartialEq)]
pub struct EstimatorConfig {
    /// Nominal host nanoseconds per device nanosecond (1.0 when the device counts real ns).
    pub nominal_rate: f64,
    /// Largest believable drift from the nominal rate, ppm (crystal oscillators: ±50–100 ppm).
    pub max_drift_ppm: f64,
    /// Fit the skew (true) or only the offset at the nominal rate (false).
    pub estimate_drift: bool,
    /// Width of a decimation bucket in device ns (the lowest point of each is kept).
    pub bucket_ns: i64,
    /// Buckets in the sliding window (window length = `bucket_ns · window_buckets`).
    pub window_buckets: usize,
    /// Known minimum transport latency, ns, subtracted from the fitted line.
    pub min_latency_ns: f64,
    /// Distance from the fitted line beyond which a sample is suspect, ns.
    pub jump_tolerance_ns: f64,
    /// Consecutive, mutually consistent suspects that confirm a clock jump.
    pub jump_confirm: usize,
}

impl Default for EstimatorConfig {
    fn default() -> Self {
        Self {
            nominal_rate: 1.0,
            max_drift_ppm: 500.0,
            estimate_drift: true,
            bucket_ns: 50_000_000,
            window_buckets: 200,
            min_latency_ns: 0.0,
            jump_tolerance_ns: 50_000_000.0,
            jump_confirm: 3,
        }
    }
}

/// A frozen linear map from device ns to host ns: `host = host0 + rate · (device − device0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mapping {
    pub device0_ns: i64,
    pub host0_ns: f64,
    /// Host ns per device ns (nominal rate × (1 + drift)).
    pub rate: f64,
}

impl Mapping {
    /// Host time (ns, may be fractional or negative before the clock's epoch) of `device_ns`.
    pub fn to_host(&self, device_ns: i64) -> f64 {
        self.host0_ns + self.rate * (device_ns - self.device0_ns) as f64
    }

    /// Device time of host time `host_ns` (the inverse map).
    pub fn to_device(&self, host_ns: f64) -> f64 {
        self.device0_ns as f64 + (host_ns - self.host0_ns) / self.rate
    }
}

/// The maps of every epoch of an estimator at one moment (see [`ClockEstimator::epoch_maps`]).
#[derive(Debug, Clone, PartialEq)]
pub struct EpochMaps {
    pub epoch: u32,
    pub current: Option<Mapping>,
    pub frozen: Vec<Mapping>,
}

impl EpochMaps {
    /// Host ns of `device_ns` stamped in `epoch` (`None` if that epoch has no map).
    pub fn to_host(&self, epoch: u32, device_ns: i64) -> Option<f64> {
        let m = if epoch == self.epoch {
            self.current.as_ref()
        } else {
            self.frozen.get(epoch as usize)
        };
        m.map(|m| m.to_host(device_ns))
    }
}

/// What an observation told the estimator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ClockEvent {
    /// The first sample: an offset-only lock at the nominal rate.
    Locked { epoch: u32 },
    /// A sample far from the fit that was not followed by others like it (a late packet).
    Outlier { residual_ns: f64 },
    /// The device clock stepped by about `step_ns` (host-equivalent ns; positive: the device now
    /// reads *earlier* than the old fit predicts for the same host time). A new epoch began.
    Jump {
        old_epoch: u32,
        new_epoch: u32,
        step_ns: f64,
    },
}

#[derive(Debug, Clone, Copy)]
struct Point {
    x: i64,
    y: f64,
}

/// Online offset + skew estimator for one device clock (sans-IO: host time is passed in).
#[derive(Debug, Clone)]
pub struct ClockEstimator {
    cfg: EstimatorConfig,
    /// Lowest point per bucket, ordered by bucket.
    buckets: VecDeque<(i64, Point)>,
    suspects: Vec<(Point, f64)>,
    epoch: u32,
    frozen: Vec<Mapping>,
    fit: Option<Mapping>,
    dirty: bool,
    samples: u64,
    outliers: u64,
    jumps: u64,
}

impl ClockEstimator {
    pub fn new(cfg: EstimatorConfig) -> Self {
        Self {
            cfg,
            buckets: VecDeque::new(),
            suspects: Vec::new(),
            epoch: 0,
            frozen: Vec::new(),
            fit: None,
            dirty: false,
            samples: 0,
            outliers: 0,
            jumps: 0,
        }
    }

    pub fn config(&self) -> &EstimatorConfig {
        &self.cfg
    }

    /// The current epoch (incremented by every confirmed jump).
    pub fn epoch(&self) -> u32 {
        self.epoch
    }

    /// Samples observed, samples classed as late outliers, jumps confirmed.
    pub fn counts(&self) -> (u64, u64, u64) {
        (self.samples, self.outliers, self.jumps)
    }

    /// Whether any sample has been seen in the current epoch.
    pub fn is_locked(&self) -> bool {
        !self.buckets.is_empty()
    }

    /// Feed one sample: device time `device_ns` (unwrapped) received at host time `host_ns`.
    /// Returns the epoch the sample belongs to and what, if anything, happened.
    pub fn observe(&mut self, device_ns: i64, host_ns: u64) -> (u32, Option<ClockEvent>) {
        self.samples += 1;
        let p = Point {
            x: device_ns,
            y: host_ns as f64,
        };
        let Some(m) = self.mapping() else {
            self.insert(p);
            return (self.epoch, Some(ClockEvent::Locked { epoch: self.epoch }));
        };
        let residual = p.y - m.to_host(p.x);
        let tol = self.cfg.jump_tolerance_ns;
        if residual.abs() <= tol {
            // A normal sample: any held suspects were late packets (those above the line) and
            // are harmless to fit; ones below the line were not confirmed and are dropped.
            let mut event = None;
            for (s, r) in std::mem::take(&mut self.suspects) {
                self.outliers += 1;
                event = Some(ClockEvent::Outlier { residual_ns: r });
                if r > 0.0 {
                    self.insert(s);
                }
            }
            self.insert(p);
            return (self.epoch, event);
        }
        // Suspect. Do the suspects agree with one another (same step)?
        if let Some(&(_, r0)) = self.suspects.first()
            && (residual - r0).abs() > tol
        {
            self.outliers += self.suspects.len() as u64;
            self.suspects.clear();
        }
        self.suspects.push((p, residual));
        if self.suspects.len() < self.cfg.jump_confirm.max(1) {
            return (self.epoch, None);
        }
        // Confirmed: freeze the old fit, restart the window from the suspects.
        let step = self.suspects.iter().map(|(_, r)| *r).sum::<f64>() / self.suspects.len() as f64;
        self.frozen.push(m);
        let old = self.epoch;
        self.epoch += 1;
        self.jumps += 1;
        self.buckets.clear();
        self.fit = None;
        for (s, _) in std::mem::take(&mut self.suspects) {
            self.insert(s);
        }
        (
            self.epoch,
            Some(ClockEvent::Jump {
                old_epoch: old,
                new_epoch: self.epoch,
                step_ns: step,
            }),
        )
    }

    fn insert(&mut self, p: Point) {
        let b = p.x.div_euclid(self.cfg.bucket_ns.max(1));
        let key = |q: &Point| q.y - q.x as f64 * self.cfg.nominal_rate;
        match self.buckets.binary_search_by_key(&b, |(k, _)| *k) {
            Ok(i) => {
                if key(&p) < key(&self.buckets[i].1) {
                    self.buckets[i].1 = p;
                    self.dirty = true;
                }
            }
            Err(i) => {
                self.buckets.insert(i, (b, p));
                self.dirty = true;
            }
        }
        while self.buckets.len() > self.cfg.window_buckets.max(2) {
            self.buckets.pop_front();
        }
        if self.fit.is_none() {
            self.dirty = true;
        }
    }

    /// The current map (refitted if samples arrived since the last call); `None` before the
    /// first sample.
    pub fn mapping(&mut self) -> Option<Mapping> {
        if self.dirty {
            self.fit = self.refit();
            self.dirty = false;
        }
        self.fit
    }

    /// Map device time of the current epoch to host ns.
    pub fn to_host(&mut self, device_ns: i64) -> Option<f64> {
        self.mapping().map(|m| m.to_host(device_ns))
    }

    /// Map device time stamped in `epoch` (the old fit for an epoch ended by a jump).
    pub fn to_host_in(&mut self, epoch: u32, device_ns: i64) -> Option<f64> {
        if epoch == self.epoch {
            self.to_host(device_ns)
        } else {
            self.frozen
                .get(epoch as usize)
                .map(|m| m.to_host(device_ns))
        }
    }

    /// The mapping that applies to `epoch`, without refitting (`None` if unknown).
    pub fn mapping_of(&mut self, epoch: u32) -> Option<Mapping> {
        if epoch == self.epoch {
            self.mapping()
        } else {
            self.frozen.get(epoch as usize).copied()
        }
    }

    /// A snapshot of every epoch's map (refitting the current one if needed), for mapping many
    /// samples without borrowing the estimator.
    pub fn epoch_maps(&mut self) -> EpochMaps {
        EpochMaps {
            epoch: self.epoch,
            current: self.mapping(),
            frozen: self.frozen.clone(),
        }
    }

    /// Current drift from the nominal rate, ppm.
    pub fn drift_ppm(&mut self) -> Option<f64> {
        let nominal = self.cfg.nominal_rate;
        self.mapping().map(|m| (m.rate / nominal - 1.0) * 1e6)
    }

    fn refit(&self) -> Option<Mapping> {
        let pts: Vec<Point> = self.buckets.iter().map(|(_, p)| *p).collect();
        let first = *pts.first()?;
        let nominal = self.cfg.nominal_rate;
        let (lo, hi) = (
            nominal * (1.0 - self.cfg.max_drift_ppm * 1e-6),
            nominal * (1.0 + self.cfg.max_drift_ppm * 1e-6),
        );
        // Work relative to the first point so f64 keeps sub-ns resolution.
        let x0 = first.x;
        let y0 = first.y;
        let rel: Vec<(f64, f64)> = pts.iter().map(|p| ((p.x - x0) as f64, p.y - y0)).collect();
        let support = |rate: f64| {
            // Lowest line of slope `rate`: the offset is min(y − rate·x).
            rel.iter()
                .map(|&(x, y)| y - rate * x)
                .fold(f64::INFINITY, f64::min)
        };
        let mut rate = nominal;
        if self.cfg.estimate_drift && rel.len() >= 2 {
            let hull = lower_hull(&rel);
            let mean_x = rel.iter().map(|p| p.0).sum::<f64>() / rel.len() as f64;
            if hull.len() >= 2 {
                let k = hull
                    .windows(2)
                    .position(|w| w[1].0 >= mean_x)
                    .unwrap_or(hull.len() - 2);
                let (a, b) = (hull[k], hull[k + 1]);
                if b.0 > a.0 {
                    rate = (b.1 - a.1) / (b.0 - a.0);
                }
            }
            rate = rate.clamp(lo, hi);
        }
        let offset = support(rate) - self.cfg.min_latency_ns;
        Some(Mapping {
            device0_ns: x0,
            host0_ns: y0 + offset,
            rate,
        })
    }
}

/// Lower convex hull (Andrew's monotone chain) of points sorted by x; collinear points dropped.
fn lower_hull(pts: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut hull: Vec<(f64, f64)> = Vec::with_capacity(pts.len());
    for &p in pts {
        while hull.len() >= 2 {
            let (a, b) = (hull[hull.len() - 2], hull[hull.len() - 1]);
            let cross = (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0);
            if cross <= 0.0 {
                hull.pop();
            } else {
                break;
            }
        }
        // Same x as the last point: keep the lower one.
        if let Some(last) = hull.last_mut()
            && last.0 == p.0
        {
            if p.1 < last.1 {
                *last = p;
            }
            continue;
        }
        hull.push(p);
    }
    hull
}

/// Unwraps a `bits`-wide counter (a u32 sequence number, a u16 serial counter) into a
/// monotonically extended `i64`.
///
/// Each new raw value is taken as the nearest value modulo `2^bits` to the previous one, so a
/// wrap from `u32::MAX` to `0` is one step forward. A step backwards of less than half the range
/// is reported as such (negative delta: a reordered or repeated sample), never as a wrap.
#[derive(Debug, Clone)]
pub struct Unwrapper {
    bits: u32,
    last_raw: Option<u64>,
    value: i64,
}

impl Unwrapper {
    pub fn new(bits: u32) -> Self {
        assert!((1..=63).contains(&bits), "counter width 1..=63 bits");
        Self {
            bits,
            last_raw: None,
            value: 0,
        }
    }

    /// The unwrapped value of `raw` and its delta from the previous one (0 for the first).
    pub fn unwrap(&mut self, raw: u64) -> (i64, i64) {
        let modulus = 1i128 << self.bits;
        let raw = (raw as i128 % modulus) as u64;
        let Some(last) = self.last_raw else {
            self.last_raw = Some(raw);
            self.value = raw as i64;
            return (self.value, 0);
        };
        let mut d = (raw as i128 - last as i128).rem_euclid(modulus);
        if d >= modulus / 2 {
            d -= modulus;
        }
        let d = d as i64;
        if d > 0 {
            self.last_raw = Some(raw);
            self.value += d;
            (self.value, d)
        } else {
            // Backwards or repeated: report it relative to the newest value, keep the state.
            (self.value + d, d)
        }
    }
}

/// How a device stamps its samples.
#[derive(Debug, Clone, PartialEq)]
pub enum DeviceTimebase {
    /// A nanosecond timestamp (V4L2 buffer stamps, a device's own ns clock).
    Nanos,
    /// Nanoseconds of the host clock itself (V4L2 buffers flagged `TIMESTAMP_MONOTONIC` on the
    /// host's `CLOCK_MONOTONIC`; a simulated device on the shared clock): taken as host times,
    /// with no offset or drift to estimate.
    HostNanos,
    /// Seconds as `f64` (the RTDE `timestamp` field).
    Seconds,
    /// A `bits`-wide sample counter at a nominal rate (F/T sequence numbers).
    Counter { bits: u32, nominal_hz: f64 },
}

/// A raw device stamp, in the form the device sends it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DeviceStamp {
    Nanos(u64),
    Seconds(f64),
    Counter(u64),
}

/// A device clock: raw stamps → unwrapped device ns → host ns.
#[derive(Debug, Clone)]
pub struct DeviceClock {
    timebase: DeviceTimebase,
    unwrap: Option<Unwrapper>,
    pub estimator: ClockEstimator,
}

impl DeviceClock {
    /// `cfg.nominal_rate` is ignored for counters (one count is `1e9 / nominal_hz` ns).
    pub fn new(timebase: DeviceTimebase, cfg: EstimatorConfig) -> Self {
        let unwrap = match &timebase {
            DeviceTimebase::Counter { bits, .. } => Some(Unwrapper::new(*bits)),
            _ => None,
        };
        Self {
            timebase,
            unwrap,
            estimator: ClockEstimator::new(cfg),
        }
    }

    /// Device ns of a raw stamp (counters: unwrapped count × nominal period) and, for counters,
    /// the count delta from the previous stamp (1 = no sample lost). `None` for a non-finite
    /// seconds stamp.
    pub fn device_ns(&mut self, stamp: DeviceStamp) -> Option<(i64, i64)> {
        match (stamp, &self.timebase) {
            (DeviceStamp::Nanos(ns), _) => Some((ns.min(i64::MAX as u64) as i64, 0)),
            (DeviceStamp::Seconds(s), _) => {
                (s.is_finite() && s.abs() < 9.0e9).then(|| ((s * 1e9).round() as i64, 0))
            }
            (DeviceStamp::Counter(c), DeviceTimebase::Counter { nominal_hz, .. }) => {
                let u = self.unwrap.as_mut()?;
                let (n, d) = u.unwrap(c);
                Some(((n as f64 * 1e9 / nominal_hz).round() as i64, d))
            }
            (DeviceStamp::Counter(c), _) => Some((c.min(i64::MAX as u64) as i64, 0)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hull_drops_points_above_and_collinear() {
        let h = lower_hull(&[(0.0, 0.0), (1.0, 5.0), (2.0, 2.0), (3.0, 3.0), (4.0, 4.0)]);
        assert_eq!(h, vec![(0.0, 0.0), (4.0, 4.0)]);
    }

    #[test]
    fn unwrapper_crosses_u32_wrap_and_reports_backsteps() {
        let mut u = Unwrapper::new(32);
        assert_eq!(u.unwrap(u32::MAX as u64 - 1), (u32::MAX as i64 - 1, 0));
        assert_eq!(u.unwrap(u32::MAX as u64), (u32::MAX as i64, 1));
        assert_eq!(u.unwrap(0), (u32::MAX as i64 + 1, 1));
        assert_eq!(u.unwrap(3), (u32::MAX as i64 + 4, 3));
        assert_eq!(u.unwrap(2), (u32::MAX as i64 + 3, -1));
    }
}
