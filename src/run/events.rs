//! What a run's streams carry, count and stop on, shared by the streams' tasks
//! ([`super::streams`]) and the safety supervisor ([`super::safety`]): the [`Trip`] that stops
//! motion, the [`Event`]s forwarded to the recording, the [`StreamCounters`], the
//! [`StreamSettings`], and the hand-over into the collector's channel (`forward`).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use rig_core::wrench::Wrench;
use tokio::sync::mpsc;

use crate::force::WrenchSample;
use crate::record::ImageFormat;

/// Why motion must stop now.
#[derive(Debug, Clone, PartialEq)]
pub enum Trip {
    /// The measured force exceeded `safety.max_force_n`.
    ForceLimit { force_n: f64, limit_n: f64 },
    /// The F/T sensor reports an axis at or beyond its range.
    Saturated { force_n: f64 },
    /// The F/T stream ended.
    FtLost(String),
    /// No F/T sample for this long (clock time, ms).
    FtStalled { after_ms: f64 },
    /// The camera stream ended.
    CameraLost(String),
    /// No frame for this long (clock time, ms).
    CameraStalled { after_ms: f64 },
    /// The controller reports the TCP outside the safety envelope (position, mm).
    OutsideEnvelope { tcp_mm: [f64; 3] },
    /// The controller reports a non-finite TCP pose.
    NonFinitePose,
    /// No F/T sensor: the UR5e's flange sensor read |F| past `safety.max_force_n` less its
    /// accuracy margin ([`super::flange`]).
    FlangeForceLimit {
        force_n: f64,
        threshold_n: f64,
        limit_n: f64,
    },
}

impl Trip {
    /// A lost or stalled stream cannot be recorded from: the run stops.
    pub fn is_fatal(&self) -> bool {
        !matches!(
            self,
            Trip::ForceLimit { .. } | Trip::Saturated { .. } | Trip::FlangeForceLimit { .. }
        )
    }
}

impl std::fmt::Display for Trip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Trip::ForceLimit { force_n, limit_n } => write!(
                f,
                "force limit: |F| = {force_n:.3} N exceeds safety.max_force_n = {limit_n} N; the \
                 robot was stopped and retracted. Check the plan's depths and the indenter"
            ),
            Trip::Saturated { force_n } => write!(
                f,
                "the F/T sensor saturated (|F| = {force_n:.3} N); the robot was stopped and \
                 retracted. Reduce the depth or use a sensor with a larger range"
            ),
            Trip::FtLost(why) => write!(f, "the F/T stream ended: {why}"),
            Trip::FtStalled { after_ms } => write!(
                f,
                "the F/T stream stalled: no sample for {after_ms:.0} ms; check the sensor's \
                 cable and power"
            ),
            Trip::CameraLost(why) => write!(f, "the camera stream ended: {why}"),
            Trip::OutsideEnvelope { tcp_mm } => write!(
                f,
                "the robot reports its TCP at ({:.1}, {:.1}, {:.1}) mm, outside the safety \
                 envelope; the robot was stopped. Check the TCP offset and the envelope in the \
                 config, jog the arm back by hand",
                tcp_mm[0], tcp_mm[1], tcp_mm[2]
            ),
            Trip::NonFinitePose => write!(
                f,
                "the robot reports a non-finite TCP pose; the robot was stopped. Check the \
                 controller and the RTDE link"
            ),
            Trip::CameraStalled { after_ms } => write!(
                f,
                "the camera stalled: no frame for {after_ms:.0} ms; check its USB cable, or \
                 whether another program holds it"
            ),
            Trip::FlangeForceLimit {
                force_n,
                threshold_n,
                limit_n,
            } => write!(
                f,
                "force limit (UR5e flange sensor): |F| = {force_n:.2} N is past {threshold_n:.2} \
                 N, safety.max_force_n = {limit_n} N less the flange sensor's accuracy; the \
                 robot was stopped and retracted. Check the plan's depths and the indenter \
                 (with no [force_sensor] the arm's own sensor is the force watch)"
            ),
        }
    }
}

/// A frame ready to record.
#[derive(Debug, Clone)]
pub struct EncodedFrame {
    /// The device's sequence number.
    pub seq: u64,
    /// Capture stamp on the host clock, ns: the source's mapped capture time (V4L2 buffer
    /// stamps on `CLOCK_MONOTONIC`) when it has one, else the device's stamp.
    pub stamp_ns: u64,
    /// Host clock time the frame was received, ns.
    pub host_rx_ns: u64,
    /// Frames the sequence numbers say were lost just before this one.
    pub dropped_before: u64,
    /// The image as it is recorded ([`stored_image`](super::streams::stored_image)).
    pub format: ImageFormat,
    pub data: Vec<u8>,
    /// Simulated rig only: the true capture time and the simulator's wrench then.
    pub truth: Option<(u64, Wrench)>,
}

/// What the streams forward.
#[derive(Debug, Clone)]
pub enum Event {
    Wrench(WrenchSample),
    Frame(Box<EncodedFrame>),
}

/// Counters of the streams (the progress bar reads them).
#[derive(Debug, Default)]
pub struct StreamCounters {
    pub wrench: AtomicU64,
    pub frames: AtomicU64,
    /// Frames the camera's sequence numbers say were lost.
    pub frames_dropped: AtomicU64,
    /// Frames that could not be converted or encoded (counted, not recorded).
    pub frames_unencodable: AtomicU64,
    /// Frames encoded as they are stored ([`stored_image`](super::streams::stored_image)), and
    /// their bytes in all: the
    /// disk budget's measure of the camera's frames ([`super::budget`]).
    pub stored_frames: AtomicU64,
    pub stored_frame_bytes: AtomicU64,
    /// Times a stream found the collector's input full and waited.
    pub backpressure_waits: AtomicU64,
    /// Capture stamp of the newest frame handed to the collector, ns (0: none yet).
    pub newest_frame_stamp_ns: AtomicU64,
    /// Clock time the newest frame arrived from the camera, ns (0: none yet); the supervisor's
    /// camera stall check reads it.
    pub last_frame_rx_ns: AtomicU64,
    /// Samples and frames the reading tasks could not queue toward the recording (it was too
    /// far behind); a trajectory during which this grows fails.
    pub recording_lost: AtomicU64,
    /// The force limit applies to every tared sample; to an untared one (its reading holds
    /// the sensor's bias, on a Nano17 up to a few N, not a contact force) only when this is
    /// set, because the config asks for no tare. The flag travels with the sample: samples
    /// still queued from before the first tare cannot trip the limit however late the
    /// stream task reads them.
    pub(super) force_limit_untared: AtomicBool,
    /// The F/T forwarder is handing a sample to the collector (set for the duration of the
    /// hand-over: it stays set while the collector's input is full).
    pub(super) ft_forwarder_waiting: AtomicBool,
    backpressure_warned: AtomicBool,
    recording_lost_warned: AtomicBool,
}

impl StreamCounters {
    fn get(v: &AtomicU64) -> u64 {
        v.load(Ordering::Relaxed)
    }
    pub fn wrench(&self) -> u64 {
        Self::get(&self.wrench)
    }
    pub fn frames(&self) -> u64 {
        Self::get(&self.frames)
    }
    pub fn frames_dropped(&self) -> u64 {
        Self::get(&self.frames_dropped)
    }
    pub fn recording_lost(&self) -> u64 {
        Self::get(&self.recording_lost)
    }
    pub fn stored_frames(&self) -> u64 {
        Self::get(&self.stored_frames)
    }
    /// Frames stored so far and their bytes, read together (the bytes are counted first).
    pub fn stored_frame_sizes(&self) -> (u64, u64) {
        let n = self.stored_frames.load(Ordering::Acquire);
        (n, Self::get(&self.stored_frame_bytes))
    }
    pub(super) fn force_limit_armed_untared(&self) -> bool {
        self.force_limit_untared.load(Ordering::Acquire)
    }
    pub(super) fn note_recording_lost(&self) {
        self.recording_lost.fetch_add(1, Ordering::Relaxed);
        if !self.recording_lost_warned.swap(true, Ordering::Relaxed) {
            tracing::error!(
                "the recording is too far behind the streams (a stalled disk?): samples are \
                 being lost for it; the trajectory will fail. Safety checks go on"
            );
        }
    }
}

/// Settings of [`Streams::start`](super::streams::Streams::start).
#[derive(Debug, Clone)]
pub struct StreamSettings {
    /// `safety.max_force_n`: |F| above it trips.
    pub max_force_n: f64,
    /// No F/T sample for this long (clock time) trips.
    pub ft_stall: Duration,
    /// No frame for this long (clock time) trips.
    pub camera_stall: Duration,
    /// A reported TCP position outside it trips (checked on every robot state the supervisor
    /// sees; `None`: not checked).
    pub envelope: Option<rig_core::config::Envelope>,
    /// No F/T sensor: the force check on the UR5e's flange readings (every robot state).
    pub flange: Option<super::flange::FlangeGuard>,
}

/// Forward `ev` into `tx`, waiting (and counting it) when the channel is full. `false` when the
/// receiver is gone.
pub(super) async fn forward<T>(tx: &mpsc::Sender<T>, ev: T, counters: &StreamCounters) -> bool {
    match tx.try_send(ev) {
        Ok(()) => true,
        Err(mpsc::error::TrySendError::Full(ev)) => {
            note_backpressure(counters);
            tx.send(ev).await.is_ok()
        }
        Err(mpsc::error::TrySendError::Closed(_)) => false,
    }
}

pub(super) fn note_backpressure(counters: &StreamCounters) {
    counters.backpressure_waits.fetch_add(1, Ordering::Relaxed);
    if !counters.backpressure_warned.swap(true, Ordering::Relaxed) {
        tracing::warn!(
            "recording back-pressure: the writer is behind the streams (slow disk?); the \
             streams wait, their device buffers fill. Counted in the summary"
        );
    }
}
