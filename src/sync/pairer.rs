//! Pairing frames with the wrench: a sans-IO state machine fed in any interleaving.
//!
//! Inputs, each with the host time it was received (`host_rx_ns`, from the shared clock):
//!
//! - frames: device stamp + sequence counter ([`Pairer::push_frame`]);
//! - wrench samples: device stamp (a counter or a clock) ([`Pairer::push_wrench`]);
//! - TCP poses on the host clock ([`Pairer::push_pose`]) and stage changes ([`Pairer::set_stage`]).
//!
//! Each device clock goes through its own [`DeviceClock`] (offset + drift). A frame is held until
//! the wrench stream has passed its mid-exposure time by enough samples for the chosen
//! interpolation (or by more than the gap limit, in which case the verdict is a refusal), and
//! until the pose stream has passed it too (if poses are being fed). [`Pairer::poll`] then
//! returns it as a [`PairedFrame`] with the wrench interpolated at that time, mapped with the
//! clock fit as it stands *then*, which is better than at the frame's arrival.
//! [`Pairer::finish`] releases whatever is left at the end of a trajectory, with verdicts.
//!
//! Frame drops are read from sequence gaps and counted, with each gap reported in
//! [`PairerStats::frame_gaps`]; wrench gaps likewise from counter gaps. Nothing is swallowed: a
//! frame that cannot be paired still comes out, with `wrench: None` and the reason.

use std::collections::VecDeque;

use rig_core::pose::{self, Pose};
use rig_core::wrench::Wrench;

use super::clock_map::{
    ClockEvent, DeviceClock, DeviceStamp, DeviceTimebase, EstimatorConfig, Unwrapper,
};
use super::interp::{self, InterpError, InterpLimits, InterpMethod, TimedWrench};
use crate::plan::StageName;

/// Configuration of a [`Pairer`].
#[derive(Debug, Clone)]
pub struct PairerConfig {
    pub method: InterpMethod,
    pub limits: InterpLimits,
    /// Time from mid-exposure to the frame's stamp, ns (subtracted from the mapped stamp).
    pub exposure_latency_ns: f64,
    pub frame_timebase: DeviceTimebase,
    pub frame_clock: EstimatorConfig,
    pub wrench_timebase: DeviceTimebase,
    pub wrench_clock: EstimatorConfig,
    /// Width of the frame sequence counter (V4L2: 32).
    pub frame_seq_bits: u32,
    /// Wrench history kept behind the newest sample when no frame waits for it, ns.
    pub history_ns: f64,
}

impl Default for PairerConfig {
    fn default() -> Self {
        Self {
            method: InterpMethod::Cubic,
            limits: InterpLimits::default(),
            exposure_latency_ns: 0.0,
            frame_timebase: DeviceTimebase::Nanos,
            frame_clock: EstimatorConfig::default(),
            wrench_timebase: DeviceTimebase::Counter {
                bits: 32,
                nominal_hz: 1000.0,
            },
            wrench_clock: EstimatorConfig::default(),
            frame_seq_bits: 32,
            history_ns: 2e9,
        }
    }
}

/// A frame, as the camera task received it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameIn {
    /// V4L2 `sequence` (wraps at `2^frame_seq_bits`).
    pub seq: u64,
    pub stamp: DeviceStamp,
    pub host_rx_ns: u64,
}

/// A wrench sample, as the F/T task received it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WrenchIn {
    pub stamp: DeviceStamp,
    pub host_rx_ns: u64,
    pub wrench: Wrench,
}

/// Why a frame's wrench is missing or flagged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SyncStatus {
    /// Interpolated between samples.
    Ok,
    /// Held from the stream's first/last sample within the extrapolation bound.
    Held,
    /// Refused: the frame time lies beyond the stream by more than the bound.
    OutOfRange,
    /// Refused: the frame time falls in a gap of the wrench stream.
    Gap,
    /// Refused: no wrench sample at all, or an unusable frame stamp.
    NoData,
}

impl SyncStatus {
    pub fn as_str(self) -> &'static str {
        match self {
            SyncStatus::Ok => "ok",
            SyncStatus::Held => "held",
            SyncStatus::OutOfRange => "out_of_range",
            SyncStatus::Gap => "gap",
            SyncStatus::NoData => "no_data",
        }
    }
}

/// One frame with its wrench, stage and pose.
#[derive(Debug, Clone, PartialEq)]
pub struct PairedFrame {
    /// Unwrapped frame sequence number.
    pub frame_seq: i64,
    /// Mid-exposure time on the host clock, ns.
    pub t_frame_ns: f64,
    /// The wrench at `t_frame_ns` (`None` when refused, see `status`).
    pub wrench: Option<Wrench>,
    /// Distance to the nearest wrench sample, ns (`None` when there was none).
    pub sync_error_ns: Option<f64>,
    pub status: SyncStatus,
    /// The stage in progress at the frame time (`None` before the first stage began).
    pub stage: Option<StageName>,
    /// TCP pose interpolated at the frame time (`None` without pose samples).
    pub tcp_pose: Option<Pose>,
}

/// A hole in a sequence: `missing` numbers after `after_seq`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SeqGap {
    pub after_seq: i64,
    pub missing: u64,
}

/// Counters of a [`Pairer`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PairerStats {
    pub frames_in: u64,
    pub frames_out: u64,
    pub frames_dropped: u64,
    pub frame_gaps: Vec<SeqGap>,
    /// Frames repeated or arriving out of order (ignored, counted).
    pub frames_reordered: u64,
    pub wrench_in: u64,
    pub wrench_lost: u64,
    pub wrench_gaps: Vec<SeqGap>,
    pub wrench_reordered: u64,
    pub clock_events: Vec<(&'static str, ClockEvent)>,
}

#[derive(Debug, Clone, Copy)]
struct PendingFrame {
    seq: i64,
    epoch: u32,
    device_ns: i64,
}

#[derive(Debug, Clone, Copy)]
struct WrenchEntry {
    epoch: u32,
    device_ns: i64,
    wrench: Wrench,
}

/// The pairing state machine. See the module doc.
#[derive(Debug)]
pub struct Pairer {
    cfg: PairerConfig,
    frame_clock: DeviceClock,
    wrench_clock: DeviceClock,
    frame_seq: Unwrapper,
    last_frame_seq: Option<i64>,
    frames: VecDeque<PendingFrame>,
    wrench: VecDeque<WrenchEntry>,
    poses: VecDeque<(f64, Pose)>,
    stages: Vec<(f64, StageName)>,
    stats: PairerStats,
}

impl Pairer {
    pub fn new(cfg: PairerConfig) -> Self {
        Self {
            frame_clock: DeviceClock::new(cfg.frame_timebase.clone(), cfg.frame_clock.clone()),
            wrench_clock: DeviceClock::new(cfg.wrench_timebase.clone(), cfg.wrench_clock.clone()),
            frame_seq: Unwrapper::new(cfg.frame_seq_bits.clamp(1, 63)),
            last_frame_seq: None,
            frames: VecDeque::new(),
            wrench: VecDeque::new(),
            poses: VecDeque::new(),
            stages: Vec::new(),
            stats: PairerStats::default(),
            cfg,
        }
    }

    pub fn stats(&self) -> &PairerStats {
        &self.stats
    }

    /// The frame and wrench clock estimators (for drift reports).
    pub fn clocks(&mut self) -> (&mut DeviceClock, &mut DeviceClock) {
        (&mut self.frame_clock, &mut self.wrench_clock)
    }

    /// Frames waiting for the wrench stream.
    pub fn pending(&self) -> usize {
        self.frames.len()
    }

    pub fn push_frame(&mut self, f: FrameIn) {
        self.stats.frames_in += 1;
        let (seq, _) = self.frame_seq.unwrap(f.seq);
        if let Some(last) = self.last_frame_seq {
            if seq <= last {
                self.stats.frames_reordered += 1;
                return;
            }
            if seq > last + 1 {
                let missing = (seq - last - 1) as u64;
                self.stats.frames_dropped += missing;
                self.stats.frame_gaps.push(SeqGap {
                    after_seq: last,
                    missing,
                });
            }
        }
        self.last_frame_seq = Some(seq);
        let Some((device_ns, _)) = self.frame_clock.device_ns(f.stamp) else {
            // An unusable stamp: the frame still comes out, refused.
            self.frames.push_back(PendingFrame {
                seq,
                epoch: u32::MAX,
                device_ns: 0,
            });
            return;
        };
        let (epoch, ev) = self.frame_clock.estimator.observe(device_ns, f.host_rx_ns);
        if let Some(ev) = ev {
            self.stats.clock_events.push(("frame", ev));
        }
        self.frames.push_back(PendingFrame {
            seq,
            epoch,
            device_ns,
        });
    }

    pub fn push_wrench(&mut self, w: WrenchIn) {
        self.stats.wrench_in += 1;
        let Some((device_ns, delta)) = self.wrench_clock.device_ns(w.stamp) else {
            self.stats.wrench_reordered += 1;
            return;
        };
        let is_counter = matches!(w.stamp, DeviceStamp::Counter(_));
        if is_counter && self.stats.wrench_in > 1 {
            if delta <= 0 {
                self.stats.wrench_reordered += 1;
                return;
            }
            if delta > 1 {
                self.stats.wrench_lost += (delta - 1) as u64;
                self.stats.wrench_gaps.push(SeqGap {
                    after_seq: self.wrench_seq_of(device_ns) - delta,
                    missing: (delta - 1) as u64,
                });
            }
        } else if let Some(last) = self.wrench.back()
            && device_ns <= last.device_ns
            && self.wrench_clock.estimator.epoch() == last.epoch
        {
            self.stats.wrench_reordered += 1;
            return;
        }
        let (epoch, ev) = self.wrench_clock.estimator.observe(device_ns, w.host_rx_ns);
        if let Some(ev) = ev {
            self.stats.clock_events.push(("wrench", ev));
        }
        self.wrench.push_back(WrenchEntry {
            epoch,
            device_ns,
            wrench: w.wrench,
        });
    }

    fn wrench_seq_of(&self, device_ns: i64) -> i64 {
        match &self.cfg.wrench_timebase {
            DeviceTimebase::Counter { nominal_hz, .. } => {
                (device_ns as f64 * nominal_hz / 1e9).round() as i64
            }
            _ => device_ns,
        }
    }

    /// A TCP pose at host time `t_ns` (RTDE samples mapped to the host clock by the caller).
    pub fn push_pose(&mut self, t_ns: f64, pose: Pose) {
        if let Some(&(last, _)) = self.poses.back()
            && t_ns <= last
        {
            return;
        }
        self.poses.push_back((t_ns, pose));
    }

    /// A stage began at host time `t_ns`.
    pub fn set_stage(&mut self, t_ns: f64, stage: StageName) {
        self.stages.push((t_ns, stage));
    }

    /// The stage in progress at host time `t_ns`.
    pub fn stage_at(&self, t_ns: f64) -> Option<StageName> {
        self.stages
            .iter()
            .rev()
            .find(|(t, _)| *t <= t_ns)
            .map(|(_, s)| *s)
    }

    /// Frames whose wrench is now final, in sequence order.
    pub fn poll(&mut self) -> Vec<PairedFrame> {
        self.release(false)
    }

    /// End of the trajectory: release every frame still held, with verdicts.
    pub fn finish(&mut self) -> Vec<PairedFrame> {
        self.release(true)
    }

    fn release(&mut self, all: bool) -> Vec<PairedFrame> {
        let mut out = Vec::new();
        // Snapshots of both clock fits: every sample is mapped with the fit as it stands now.
        let wmaps = self.wrench_clock.estimator.epoch_maps();
        let fmaps = self.frame_clock.estimator.epoch_maps();
        let w_host_stamps = matches!(self.cfg.wrench_timebase, DeviceTimebase::HostNanos);
        let f_host_stamps = matches!(self.cfg.frame_timebase, DeviceTimebase::HostNanos);
        let host = |e: &WrenchEntry| {
            if w_host_stamps {
                return e.device_ns as f64;
            }
            wmaps
                .to_host(e.epoch, e.device_ns)
                .unwrap_or(f64::NEG_INFINITY)
        };
        let frame_time = |f: &PendingFrame| {
            if f.epoch == u32::MAX {
                return None;
            }
            let stamp = if f_host_stamps {
                f.device_ns as f64
            } else {
                fmaps.to_host(f.epoch, f.device_ns)?
            };
            Some(interp::mid_exposure_ns(stamp, self.cfg.exposure_latency_ns))
        };
        let newest_w = self.wrench.back().map(host);
        let newest_pose = self.poses.back().map(|p| p.0);
        while let Some(f) = self.frames.front().copied() {
            let t = frame_time(&f);
            let idx = t.map(|t| self.wrench.partition_point(|e| host(e) <= t));
            if !all && let (Some(_), Some(idx)) = (t, idx) {
                let t = t.unwrap_or_default();
                let Some(newest) = newest_w else { break };
                let after = self.wrench.len() - idx;
                let passed = after >= self.cfg.method.samples_after()
                    || newest > t + self.cfg.limits.max_gap_ns;
                let pose_ok = newest_pose.is_none_or(|p| p >= t);
                if !(passed && pose_ok) {
                    break;
                }
            }
            // Only the neighbours matter: map a small window around the frame time.
            let window: Vec<TimedWrench> = match idx {
                Some(i) => {
                    let lo = i.saturating_sub(3);
                    let hi = (i + 3).min(self.wrench.len());
                    self.wrench
                        .range(lo..hi)
                        .map(|e| TimedWrench {
                            t_ns: host(e),
                            wrench: e.wrench,
                        })
                        .collect()
                }
                None => Vec::new(),
            };
            out.push(self.pair(f, t, &window));
            self.frames.pop_front();
        }
        // Prune what neither the oldest waiting frame nor a late frame can still need.
        if let Some(newest) = newest_w {
            let mut keep_from = newest - self.cfg.history_ns;
            if let Some(t) = self.frames.front().and_then(frame_time) {
                keep_from = keep_from.min(t - self.cfg.limits.max_gap_ns);
            }
            // Two extra samples before the boundary for cubic tangents.
            let cut = self
                .wrench
                .partition_point(|e| host(e) < keep_from)
                .saturating_sub(2);
            self.wrench.drain(..cut);
            while self.poses.len() > 2 && self.poses[1].0 < keep_from {
                self.poses.pop_front();
            }
        }
        self.stats.frames_out += out.len() as u64;
        out
    }

    fn pair(&self, f: PendingFrame, t: Option<f64>, samples: &[TimedWrench]) -> PairedFrame {
        let Some(t) = t else {
            return PairedFrame {
                frame_seq: f.seq,
                t_frame_ns: f64::NAN,
                wrench: None,
                sync_error_ns: None,
                status: SyncStatus::NoData,
                stage: None,
                tcp_pose: None,
            };
        };
        let r = interp::interpolate(samples, t, self.cfg.method, &self.cfg.limits);
        let nearest = nearest_distance(samples, t);
        let (wrench, status) = match r {
            Ok(i) if i.inside => (Some(i.wrench), SyncStatus::Ok),
            Ok(i) => (Some(i.wrench), SyncStatus::Held),
            Err(InterpError::OutOfRange { .. }) => (None, SyncStatus::OutOfRange),
            Err(InterpError::Gap { .. }) => (None, SyncStatus::Gap),
            Err(InterpError::Empty | InterpError::BadTime) => (None, SyncStatus::NoData),
        };
        PairedFrame {
            frame_seq: f.seq,
            t_frame_ns: t,
            wrench,
            sync_error_ns: nearest,
            status,
            stage: self.stage_at(t),
            tcp_pose: self.pose_at(t),
        }
    }

    /// TCP pose at `t_ns`: interpolated between the bracketing samples, else the nearest one.
    pub fn pose_at(&self, t_ns: f64) -> Option<Pose> {
        let i = self.poses.partition_point(|p| p.0 < t_ns);
        match (
            i.checked_sub(1).and_then(|j| self.poses.get(j)),
            self.poses.get(i),
        ) {
            (Some(a), Some(b)) if b.0 > a.0 => {
                Some(pose::interpolate(&a.1, &b.1, (t_ns - a.0) / (b.0 - a.0)))
            }
            (_, Some(b)) => Some(b.1),
            (Some(a), None) => Some(a.1),
            (None, None) => None,
        }
    }
}

fn nearest_distance(samples: &[TimedWrench], t_ns: f64) -> Option<f64> {
    let i = samples.partition_point(|s| s.t_ns < t_ns);
    let a = i.checked_sub(1).map(|j| (t_ns - samples[j].t_ns).abs());
    let b = samples.get(i).map(|s| (s.t_ns - t_ns).abs());
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}
