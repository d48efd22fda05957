//! Video4Linux2 capture of a UVC tactile sensor, written over a small [`DeviceLayer`] trait.
//!
//! What a UVC sensor needs, and where it is done:
//!
//! - **Choosing the node** ([`choose_capture_node`]): uvcvideo exposes two `/dev/video*` nodes
//!   per camera, one for frames (`V4L2_CAP_VIDEO_CAPTURE`) and one for metadata
//!   (`V4L2_CAP_META_CAPTURE`). A config naming the metadata node is redirected to its sibling
//!   on the same bus.
//! - **Format negotiation** ([`negotiate`]): the exact requested size; among the pixel formats
//!   offering it, one that reaches the requested rate wins over one that does not, then the
//!   preference order (MJPEG first: uncompressed YUYV often cannot reach 30 fps at 640 × 480
//!   over USB 2). The rate is the smallest offered rate at or above the request.
//! - **Timestamps** ([`MonotonicMap`]): buffers carry CLOCK_MONOTONIC stamps (uvcvideo: start
//!   of frame). The rig's system clock runs on the same monotonic clock from another origin, so
//!   the map is one offset, estimated from (buffer stamp, receive time) pairs as the lower
//!   envelope of `receive − stamp` (Olson 2010, passive synchronisation, with zero drift), less
//!   a configured minimum transfer latency.
//! - **Drops** ([`super::SequenceTracker`]): gaps in the 32-bit `sequence` counter, plus frames
//!   the reader had to discard because the consumer was behind.
//! - **Never stale** ([`V4l2Source`]): a dedicated thread dequeues and requeues buffers as fast
//!   as the driver fills them, copying each frame out, so the driver never runs out of buffers
//!   and the newest frame is always the one delivered next; a slow consumer loses frames in the
//!   rig's queue (counted), not in the driver.
//!
//! The real layer over the `v4l` crate (mmap buffers) is `device` (cargo feature `v4l`).

#[cfg(feature = "v4l")]
pub mod device;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use rig_core::clock::Clock;
use tokio::sync::mpsc;

use super::{
    CameraError, CaptureStats, Frame, FrameFormat, FrameFuture, FrameSource, PixelFormat,
    SequenceTracker,
};

/// One `/dev/video*` node as `VIDIOC_QUERYCAP` describes it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeInfo {
    pub path: String,
    /// Card name, e.g. "GelSight Mini R0B 2BNK-CE6Y".
    pub card: String,
    /// Bus info, shared by the nodes of one physical camera, e.g. "usb-0000:00:14.0-1".
    pub bus: String,
    /// The node delivers frames (`device_caps` has VIDEO_CAPTURE).
    pub video_capture: bool,
    /// The node delivers metadata (`device_caps` has META_CAPTURE).
    pub meta_capture: bool,
}

/// The node to capture from, given the configured one and all nodes present.
pub fn choose_capture_node(requested: &str, nodes: &[NodeInfo]) -> Result<String, CameraError> {
    let listing = || {
        nodes
            .iter()
            .map(|n| {
                let kind = if n.video_capture {
                    "capture"
                } else if n.meta_capture {
                    "metadata"
                } else {
                    "other"
                };
                format!("{} ({}, {kind}, {})", n.path, n.card, n.bus)
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    let Some(node) = nodes.iter().find(|n| n.path == requested) else {
        return Err(CameraError::Device {
            device: requested.to_owned(),
            reason: format!(
                "no such video node; present: [{}]. Is the sensor plugged in?",
                listing()
            ),
        });
    };
    if node.video_capture {
        return Ok(node.path.clone());
    }
    if let Some(sibling) = nodes
        .iter()
        .find(|n| n.video_capture && n.bus == node.bus && !n.bus.is_empty())
    {
        return Ok(sibling.path.clone());
    }
    Err(CameraError::Device {
        device: requested.to_owned(),
        reason: format!(
            "is not a capture node and has no capture sibling on bus {:?}; present: [{}]",
            node.bus,
            listing()
        ),
    })
}

/// One size a pixel format is offered at, with its frame rates.
#[derive(Debug, Clone, PartialEq)]
pub struct OfferedMode {
    pub pixel: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// Frame rates offered at this size, Hz.
    pub fps: Vec<f64>,
}

/// What the rig asks the camera for.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    /// Pixel formats in order of preference.
    pub prefer: Vec<PixelFormat>,
}

impl Request {
    /// `width` × `height` at `fps`, MJPEG preferred over YUYV.
    pub fn new(width: u32, height: u32, fps: f64) -> Self {
        Self {
            width,
            height,
            fps,
            prefer: vec![PixelFormat::Mjpeg, PixelFormat::Yuyv],
        }
    }

    /// What a config's `[camera]` asks for: its size and rate, in its `format` first (MJPEG,
    /// or raw YUYV), the other one as the fallback.
    pub fn for_camera(c: &rig_core::config::CameraConfig) -> Self {
        let mut req = Self::new(c.width_px, c.height_px, c.fps);
        if c.format == rig_core::config::CameraFormat::Raw {
            req.prefer.reverse();
        }
        req
    }
}

/// Picks the stream format for `req` among `offered` (see the module docs for the rules).
pub fn negotiate(offered: &[OfferedMode], req: &Request) -> Result<FrameFormat, CameraError> {
    let wanted = || {
        format!(
            "{}x{} at {} fps in {:?}",
            req.width, req.height, req.fps, req.prefer
        )
    };
    let offered_text = || {
        offered
            .iter()
            .map(|m| format!("{:?} {}x{} {:?} fps", m.pixel, m.width, m.height, m.fps))
            .collect::<Vec<_>>()
            .join("; ")
    };
    let tol = 1e-3 * req.fps.abs();
    let mut best: Option<((bool, usize), FrameFormat)> = None;
    for m in offered {
        let Some(rank) = req.prefer.iter().position(|p| *p == m.pixel) else {
            continue;
        };
        if (m.width, m.height) != (req.width, req.height) {
            continue;
        }
        let rates: Vec<f64> = m
            .fps
            .iter()
            .copied()
            .filter(|f| f.is_finite() && *f > 0.0)
            .collect();
        if rates.is_empty() {
            continue;
        }
        let at_least = rates
            .iter()
            .copied()
            .filter(|&f| f + tol >= req.fps)
            .reduce(f64::min);
        let (reaches, fps) = match at_least {
            Some(f) => (true, f),
            None => (false, rates.iter().copied().fold(0.0, f64::max)),
        };
        // Smaller key is better: reaching the rate first, then preference.
        let key = (!reaches, rank);
        let fmt = FrameFormat {
            pixel: m.pixel,
            width: m.width,
            height: m.height,
            fps,
        };
        let better = match &best {
            None => true,
            Some((k, f)) => key < *k || (key == *k && fps > f.fps && !reaches),
        };
        if better {
            best = Some((key, fmt));
        }
    }
    best.map(|(_, f)| f).ok_or_else(|| CameraError::NoFormat {
        wanted: wanted(),
        offered: offered_text(),
    })
}

/// Maps CLOCK_MONOTONIC buffer stamps onto the rig's clock (see the module docs).
#[derive(Debug, Clone, Default)]
pub struct MonotonicMap {
    /// `receive_host − stamp`, lowest seen, ns.
    min_gap_ns: Option<i128>,
    /// Known least time from start of frame to dequeue (e.g. one frame's transfer), ns.
    min_latency_ns: u64,
}

impl MonotonicMap {
    pub fn new(min_latency_ns: u64) -> Self {
        Self {
            min_gap_ns: None,
            min_latency_ns,
        }
    }

    /// Feeds a buffer stamp and the rig-clock time it was received.
    pub fn observe(&mut self, stamp_ns: u64, received_host_ns: u64) {
        let gap = i128::from(received_host_ns) - i128::from(stamp_ns);
        self.min_gap_ns = Some(self.min_gap_ns.map_or(gap, |g| g.min(gap)));
    }

    /// The capture time of a stamp on the rig's clock; `None` before any observation or when it
    /// would fall before the clock's epoch.
    pub fn to_host(&self, stamp_ns: u64) -> Option<u64> {
        let host = i128::from(stamp_ns) + self.min_gap_ns? - i128::from(self.min_latency_ns);
        u64::try_from(host).ok()
    }
}

/// A dequeued buffer, copied out of the driver's memory.
#[derive(Debug, Clone, PartialEq)]
pub struct RawFrame {
    pub data: Vec<u8>,
    /// The driver's frame counter (32 bits in V4L2).
    pub sequence: u32,
    /// Buffer timestamp, ns of CLOCK_MONOTONIC.
    pub timestamp_ns: u64,
    /// The driver flagged the buffer as corrupted (`V4L2_BUF_FLAG_ERROR`).
    pub error: bool,
}

/// The device operations capture needs; the `v4l` crate implements them for real hardware
/// (`device`), tests with a fake.
pub trait DeviceLayer: Send + 'static {
    /// Every pixel format, size and rate the device offers.
    fn modes(&mut self) -> std::io::Result<Vec<OfferedMode>>;
    /// Sets the format; returns what the driver actually set.
    fn configure(&mut self, format: &FrameFormat) -> std::io::Result<FrameFormat>;
    /// Allocates and maps `buffers` buffers and starts streaming.
    fn start(&mut self, buffers: u32) -> std::io::Result<()>;
    /// Waits for the next filled buffer, copies it out and gives the buffer back to the driver.
    /// `Ok(None)`: no frame within the layer's timeout (the reader checks for shutdown).
    fn dequeue(&mut self) -> std::io::Result<Option<RawFrame>>;
}

/// Options of a [`V4l2Source`].
#[derive(Debug, Clone, PartialEq)]
pub struct V4l2Options {
    /// Driver buffers (mmap).
    pub buffers: u32,
    /// Frames the rig's queue holds before the reader discards new ones.
    pub queue_len: usize,
    /// Least time from a buffer's stamp to its dequeue, ns (see [`MonotonicMap`]).
    pub min_latency_ns: u64,
}

impl Default for V4l2Options {
    fn default() -> Self {
        Self {
            buffers: 4,
            queue_len: 8,
            min_latency_ns: 0,
        }
    }
}

struct Shared {
    stop: AtomicBool,
    discarded: AtomicU64,
}

/// Frames from a V4L2 device, read on a dedicated thread.
pub struct V4l2Source {
    format: FrameFormat,
    rx: mpsc::Receiver<Result<Frame, CameraError>>,
    shared: Arc<Shared>,
    thread: Option<std::thread::JoinHandle<()>>,
    frames: u64,
    lost_in_driver: Arc<AtomicU64>,
}

impl V4l2Source {
    /// Negotiates `request` with the device, starts streaming and the reading thread.
    pub fn open<D: DeviceLayer>(
        mut device: D,
        name: &str,
        clock: Clock,
        request: &Request,
        options: &V4l2Options,
    ) -> Result<Self, CameraError> {
        let dev_err = |e: std::io::Error, what: &str| CameraError::Device {
            device: name.to_owned(),
            reason: format!("{what}: {e}"),
        };
        let modes = device.modes().map_err(|e| dev_err(e, "listing formats"))?;
        let wanted = negotiate(&modes, request)?;
        let got = device
            .configure(&wanted)
            .map_err(|e| dev_err(e, "setting the format"))?;
        if (got.pixel, got.width, got.height) != (wanted.pixel, wanted.width, wanted.height) {
            return Err(CameraError::Device {
                device: name.to_owned(),
                reason: format!(
                    "asked for {:?} {}x{}, the driver set {:?} {}x{}",
                    wanted.pixel, wanted.width, wanted.height, got.pixel, got.width, got.height
                ),
            });
        }
        device
            .start(options.buffers.max(2))
            .map_err(|e| dev_err(e, "starting the stream"))?;
        let (tx, rx) = mpsc::channel(options.queue_len.max(1));
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            discarded: AtomicU64::new(0),
        });
        let lost_in_driver = Arc::new(AtomicU64::new(0));
        let reader = Reader {
            device,
            name: name.to_owned(),
            clock,
            format: got,
            map: MonotonicMap::new(options.min_latency_ns),
            seq: SequenceTracker::new(Some(32)),
            tx,
            shared: shared.clone(),
            lost: lost_in_driver.clone(),
        };
        let thread = std::thread::Builder::new()
            .name(format!("v4l2 {name}"))
            .spawn(move || reader.run())
            .map_err(|e| dev_err(e, "starting the reader thread"))?;
        Ok(Self {
            format: got,
            rx,
            shared,
            thread: Some(thread),
            frames: 0,
            lost_in_driver,
        })
    }
}

impl Drop for V4l2Source {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        self.rx.close();
        // The reader notices within one dequeue timeout; do not block the caller on it.
        drop(self.thread.take());
    }
}

impl FrameSource for V4l2Source {
    fn format(&self) -> FrameFormat {
        self.format
    }

    fn next_frame(&mut self) -> FrameFuture<'_> {
        Box::pin(async move {
            let f = self.rx.recv().await.ok_or(CameraError::Ended)??;
            self.frames += 1;
            Ok(f)
        })
    }

    fn stats(&self) -> CaptureStats {
        CaptureStats {
            frames: self.frames,
            dropped: self.lost_in_driver.load(Ordering::Relaxed)
                + self.shared.discarded.load(Ordering::Relaxed),
        }
    }
}

struct Reader<D> {
    device: D,
    name: String,
    clock: Clock,
    format: FrameFormat,
    map: MonotonicMap,
    seq: SequenceTracker,
    tx: mpsc::Sender<Result<Frame, CameraError>>,
    shared: Arc<Shared>,
    lost: Arc<AtomicU64>,
}

impl<D: DeviceLayer> Reader<D> {
    fn run(mut self) {
        // Frames discarded in the rig's queue since the last delivered one: they are lost too.
        let mut discarded_run = 0u64;
        while !self.shared.stop.load(Ordering::Acquire) {
            let raw = match self.device.dequeue() {
                Ok(Some(raw)) => raw,
                Ok(None) => continue,
                Err(e) => {
                    let _ = self.tx.try_send(Err(CameraError::Device {
                        device: self.name.clone(),
                        reason: format!("capture failed: {e}"),
                    }));
                    return;
                }
            };
            let received = self.clock.now_ns();
            let gap = self.seq.observe(u64::from(raw.sequence));
            self.lost.fetch_add(gap, Ordering::Relaxed);
            if raw.error {
                // A corrupted buffer is a lost frame.
                self.lost.fetch_add(1, Ordering::Relaxed);
                discarded_run += 1;
                continue;
            }
            self.map.observe(raw.timestamp_ns, received);
            let frame = Frame {
                sequence: u64::from(raw.sequence),
                device_ts_ns: raw.timestamp_ns,
                capture_t_ns: self.map.to_host(raw.timestamp_ns),
                received_t_ns: received,
                dropped_before: gap + discarded_run,
                format: self.format,
                data: raw.data,
                truth: None,
            };
            match self.tx.try_send(Ok(frame)) {
                Ok(()) => discarded_run = 0,
                Err(mpsc::error::TrySendError::Full(_)) => {
                    self.shared.discarded.fetch_add(1, Ordering::Relaxed);
                    discarded_run += 1;
                }
                Err(mpsc::error::TrySendError::Closed(_)) => return,
            }
        }
    }
}
