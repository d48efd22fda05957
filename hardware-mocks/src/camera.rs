//! The simulated GelSight camera: renders the scene at its frame rate on the shared clock.
//!
//! Real UVC tactile sensors are not ideal cameras (references: GelSight Mini is nominally
//! 25 fps, users see 15-18 fps through some back ends; frames are lost when the reader falls
//! behind), so this one can be made just as imperfect, all of it seeded and reproducible:
//!
//! - **Real rate below nominal**: frames come every `1 / actual_fps`, not `1 / nominal_fps`.
//! - **Jitter**: each capture time moves by a uniform offset within `±jitter_ns`.
//! - **Injected drops**: given sequence numbers, and/or a drop probability. A dropped frame is
//!   not rendered (no work) but still consumes its sequence number, as a V4L2 driver's
//!   `sequence` counter does, so the reader detects the gap.
//! - **Overruns**: the camera keeps `queue_len` frames (the driver's buffers); when the reader
//!   falls further behind, new frames are lost, counted, and again leave a sequence gap.
//! - **Device clock**: frames carry a device timestamp from the camera's own clock (an offset
//!   and a drift in ppm from the shared clock), as hardware does; the rig must map it.
//!
//! The capture time in clock nanoseconds (`capture_t_ns`) is also attached: the ground truth a
//! test compares the rig's timestamp mapping against.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rig_core::clock::Clock;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use crate::sim::{Scene, Simulator};

/// Renders the frame captured at clock time `t_ns`; `None`: no image (counted as a failed
/// render, the sequence number is consumed).
pub trait FrameRenderer: Send + Sync + 'static {
    fn render_at(&self, t_ns: u64) -> Option<image::RgbImage>;
}

impl<F> FrameRenderer for F
where
    F: Fn(u64) -> Option<image::RgbImage> + Send + Sync + 'static,
{
    fn render_at(&self, t_ns: u64) -> Option<image::RgbImage> {
        self(t_ns)
    }
}

/// A renderer that simulates `scene_at(t_ns)` with one [`Simulator`] (so friction history
/// carries from frame to frame) and returns its image. The scene must ask for an image
/// (`effects.image`) and carry optics; a scene that cannot be simulated gives no frame.
pub fn scene_renderer<S>(scene_at: S, noise_seed: u64) -> impl FrameRenderer
where
    S: Fn(u64) -> Scene + Send + Sync + 'static,
{
    let sim = Mutex::new(Simulator::with_noise_seed(noise_seed));
    move |t_ns: u64| {
        let scene = scene_at(t_ns);
        let mut sim = sim.lock().unwrap_or_else(|p| p.into_inner());
        sim.step(&scene, t_ns as f64 * 1e-9).ok()?.image
    }
}

/// How the simulated camera behaves.
#[derive(Debug, Clone, PartialEq)]
pub struct SimCameraConfig {
    /// The rate the camera claims (what a V4L2 driver would report), Hz.
    pub nominal_fps: f64,
    /// The rate it really delivers, Hz (≤ nominal; GelSight Mini: 25 claimed, often less).
    pub actual_fps: f64,
    /// Capture-time jitter: each frame moves by a uniform offset in `±jitter_ns`.
    pub jitter_ns: u64,
    /// Probability that a frame is lost (0..1).
    pub drop_probability: f64,
    /// Sequence numbers of frames to lose.
    pub drop_sequences: Vec<u64>,
    /// Seed of the jitter and random drops.
    pub seed: u64,
    /// Device clock: `device_ts = device_offset_ns + t · (1 + drift_ppm · 10⁻⁶)`.
    pub device_offset_ns: u64,
    pub drift_ppm: f64,
    /// Frames buffered for a slow reader before new ones are lost.
    pub queue_len: usize,
    /// What each frame is sent as: raw pixels, or a JPEG image (a UVC camera's MJPEG stream).
    pub encoding: SimEncoding,
}

/// What the simulated camera sends for each frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SimEncoding {
    /// 8-bit RGB pixels, as rendered.
    #[default]
    Raw,
    /// Each frame one baseline JPEG image at this quality (1..=100), encoded on the render
    /// thread: what a GelSight Mini's MJPEG stream carries. Chroma is kept at full resolution
    /// (4:4:4): many UVC cameras halve it (4:2:2), which on sim-target's coloured shading costs
    /// 1.5× the error for 13 % fewer bytes (docs/experiments.md, *MJPEG frames*).
    Mjpeg { quality: u8 },
}

impl Default for SimCameraConfig {
    fn default() -> Self {
        Self {
            nominal_fps: 25.0,
            actual_fps: 25.0,
            jitter_ns: 0,
            drop_probability: 0.0,
            drop_sequences: Vec::new(),
            seed: 0,
            device_offset_ns: 1_000_000_000_000,
            drift_ppm: 0.0,
            queue_len: 4,
            encoding: SimEncoding::Raw,
        }
    }
}

impl SimCameraConfig {
    /// A camera delivering `fps` exactly, with no imperfection.
    pub fn ideal(fps: f64) -> Self {
        Self {
            nominal_fps: fps,
            actual_fps: fps,
            ..Self::default()
        }
    }

    /// An ideal camera as a rig config's `[camera]` asks for it: its rate, and MJPEG at its
    /// quality or raw pixels.
    pub fn for_camera(camera: &rig_core::config::CameraConfig) -> Self {
        let encoding = match camera.format {
            rig_core::config::CameraFormat::Mjpeg => SimEncoding::Mjpeg {
                quality: camera.jpeg_quality,
            },
            rig_core::config::CameraFormat::Raw => SimEncoding::Raw,
        };
        Self {
            encoding,
            ..Self::ideal(camera.fps)
        }
    }

    /// Checks the values; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        let pos = |v: f64| v.is_finite() && v > 0.0;
        if !pos(self.nominal_fps) {
            return Err(format!("nominal_fps {} must be > 0", self.nominal_fps));
        }
        if !pos(self.actual_fps) || self.actual_fps > self.nominal_fps {
            return Err(format!(
                "actual_fps {} must be > 0 and at most nominal_fps {}",
                self.actual_fps, self.nominal_fps
            ));
        }
        if !(0.0..=1.0).contains(&self.drop_probability) {
            return Err(format!(
                "drop_probability {} must be in [0, 1]",
                self.drop_probability
            ));
        }
        if !self.drift_ppm.is_finite() || self.drift_ppm.abs() > 1e5 {
            return Err(format!("drift_ppm {} must be within ±1e5", self.drift_ppm));
        }
        if self.queue_len == 0 {
            return Err("queue_len must be at least 1".into());
        }
        if let SimEncoding::Mjpeg { quality } = self.encoding
            && !(1..=100).contains(&quality)
        {
            return Err(format!("JPEG quality {quality} must be in 1..=100"));
        }
        Ok(())
    }

    /// Device timestamp of clock time `t_ns`.
    pub fn device_ts_ns(&self, t_ns: u64) -> u64 {
        let drift = t_ns as f64 * self.drift_ppm * 1e-6;
        (self.device_offset_ns as f64 + t_ns as f64 + drift).max(0.0) as u64
    }
}

/// One delivered frame.
#[derive(Debug, Clone)]
pub struct SimFrame {
    /// Frame counter of the camera: consecutive, except where frames were lost.
    pub sequence: u64,
    /// Timestamp from the camera's own clock, ns.
    pub device_ts_ns: u64,
    /// Ground truth: the shared clock's time of the capture, ns.
    pub capture_t_ns: u64,
    pub payload: SimPayload,
}

/// A frame's bytes as the camera sends them.
#[derive(Debug, Clone, PartialEq)]
pub enum SimPayload {
    /// The rendered pixels ([`SimEncoding::Raw`]).
    Rgb(image::RgbImage),
    /// One JPEG image of `width` × `height` ([`SimEncoding::Mjpeg`]).
    Jpeg {
        width: u32,
        height: u32,
        bytes: Vec<u8>,
    },
}

impl SimPayload {
    /// Encodes a rendered image as `encoding` asks.
    pub fn encode(image: image::RgbImage, encoding: SimEncoding) -> Result<Self, String> {
        match encoding {
            SimEncoding::Raw => Ok(SimPayload::Rgb(image)),
            SimEncoding::Mjpeg { quality } => {
                let (width, height) = image.dimensions();
                // A UVC frame is at most a few tens of kB: start near that to grow once.
                let mut bytes = Vec::with_capacity((width * height / 4) as usize);
                let (w, h) = match (u16::try_from(width), u16::try_from(height)) {
                    (Ok(w), Ok(h)) => (w, h),
                    _ => return Err(format!("a {width}×{height} frame is too large for JPEG")),
                };
                // The jpeg-encoder crate's SIMD encoder: about the size and error of the
                // `image` crate's at 4:4:4 and the same quality, in a third of the time.
                let mut encoder = jpeg_encoder::Encoder::new(&mut bytes, quality);
                encoder.set_sampling_factor(jpeg_encoder::SamplingFactor::R_4_4_4);
                encoder
                    .encode(image.as_raw(), w, h, jpeg_encoder::ColorType::Rgb)
                    .map_err(|e| format!("JPEG encoding of a {width}×{height} frame: {e}"))?;
                Ok(SimPayload::Jpeg {
                    width,
                    height,
                    bytes,
                })
            }
        }
    }

    /// Width and height of the frame, pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            SimPayload::Rgb(img) => img.dimensions(),
            SimPayload::Jpeg { width, height, .. } => (*width, *height),
        }
    }

    /// The frame as RGB pixels (a JPEG decoded: lossy against the render).
    pub fn to_rgb(&self) -> Result<image::RgbImage, String> {
        match self {
            SimPayload::Rgb(img) => Ok(img.clone()),
            SimPayload::Jpeg { bytes, .. } => {
                image::load_from_memory_with_format(bytes, image::ImageFormat::Jpeg)
                    .map(|i| i.to_rgb8())
                    .map_err(|e| format!("JPEG frame: {e}"))
            }
        }
    }
}

/// Counters of a running camera.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SimCameraStats {
    /// Frames rendered and delivered to the queue.
    pub delivered: u64,
    /// Frames lost on purpose (drop list or probability).
    pub injected_drops: u64,
    /// Frames lost because the reader was `queue_len` frames behind.
    pub overruns: u64,
    /// Frames whose scene could not be rendered.
    pub failed_renders: u64,
    /// Frames not sent while the camera was stalled ([`CameraFaults::set_stalled`]).
    pub stalled: u64,
}

#[derive(Default)]
struct Counters {
    stall: std::sync::atomic::AtomicBool,
    stalled: AtomicU64,
    delivered: AtomicU64,
    injected: AtomicU64,
    overruns: AtomicU64,
    failed: AtomicU64,
}

/// A running simulated camera. Dropping it stops the capture task.
pub struct SimCamera {
    rx: mpsc::Receiver<SimFrame>,
    task: JoinHandle<()>,
    counters: Arc<Counters>,
    config: SimCameraConfig,
}

impl std::fmt::Debug for SimCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimCamera")
            .field("config", &self.config)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl Drop for SimCamera {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Fault injection into a running [`SimCamera`] (cheap to clone; outlives moves of the camera).
#[derive(Clone)]
pub struct CameraFaults(Arc<Counters>);

impl CameraFaults {
    /// A stalled camera keeps its clock and sequence counter running but sends nothing (a USB
    /// camera whose stream hangs); frames due meanwhile are lost and counted in
    /// [`SimCameraStats::stalled`]. Clearing the stall resumes delivery, with a sequence gap.
    pub fn set_stalled(&self, on: bool) {
        self.0.stall.store(on, Ordering::Release);
    }
}

impl SimCamera {
    /// Fault injection handle.
    pub fn faults(&self) -> CameraFaults {
        CameraFaults(self.counters.clone())
    }

    /// Starts capturing on `clock`: the first frame is due one period after now. Must be called
    /// within a tokio runtime.
    pub fn spawn(
        clock: Clock,
        config: SimCameraConfig,
        renderer: Arc<dyn FrameRenderer>,
    ) -> Result<Self, String> {
        config.validate()?;
        let (tx, rx) = mpsc::channel(config.queue_len);
        let counters = Arc::new(Counters::default());
        let task = tokio::spawn(capture_loop(
            clock,
            config.clone(),
            renderer,
            tx,
            counters.clone(),
        ));
        Ok(Self {
            rx,
            task,
            counters,
            config,
        })
    }

    /// The next frame; `None` once the capture task has ended.
    pub async fn recv(&mut self) -> Option<SimFrame> {
        self.rx.recv().await
    }

    /// A frame already waiting, if any.
    pub fn try_recv(&mut self) -> Option<SimFrame> {
        self.rx.try_recv().ok()
    }

    pub fn config(&self) -> &SimCameraConfig {
        &self.config
    }

    pub fn stats(&self) -> SimCameraStats {
        SimCameraStats {
            delivered: self.counters.delivered.load(Ordering::Relaxed),
            injected_drops: self.counters.injected.load(Ordering::Relaxed),
            overruns: self.counters.overruns.load(Ordering::Relaxed),
            failed_renders: self.counters.failed.load(Ordering::Relaxed),
            stalled: self.counters.stalled.load(Ordering::Relaxed),
        }
    }
}

/// Capture time of frame `seq` (before `start`): `start + (seq + 1)/actual_fps + jitter`.
pub fn capture_time_ns(config: &SimCameraConfig, start_ns: u64, seq: u64) -> u64 {
    let period = 1e9 / config.actual_fps;
    let nominal = start_ns as f64 + (seq + 1) as f64 * period;
    let jitter = if config.jitter_ns > 0 {
        let j = config.jitter_ns.min((period / 2.0) as u64) as f64;
        (2.0 * unit(config.seed, seq, 0) - 1.0) * j
    } else {
        0.0
    };
    (nominal + jitter).max(0.0) as u64
}

/// Whether frame `seq` is lost on purpose.
pub fn is_dropped(config: &SimCameraConfig, seq: u64) -> bool {
    config.drop_sequences.contains(&seq)
        || (config.drop_probability > 0.0 && unit(config.seed, seq, 1) < config.drop_probability)
}

fn unit(seed: u64, seq: u64, stream: u64) -> f64 {
    // SplitMix64's finaliser over (seed, seq, stream).
    let mut z = (seed ^ seq.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ stream.rotate_left(29))
        .wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

async fn capture_loop(
    clock: Clock,
    config: SimCameraConfig,
    renderer: Arc<dyn FrameRenderer>,
    tx: mpsc::Sender<SimFrame>,
    counters: Arc<Counters>,
) {
    // Frames render on the blocking pool, up to one per core at a time, and are delivered in
    // sequence order: a renderer slower than the frame period then still keeps up when the
    // machine has cores to spare. Each frame renders the scene at its own capture time.
    let parallel = std::thread::available_parallelism().map_or(1, |n| n.get().min(4));
    // Capture times are whole multiples of the frame period of clock time (without jitter),
    // so a contact physics stepping on a grid of the same or a divided period has each frame's
    // contact already solved.
    let period_ns = (1e9 / config.actual_fps).round().max(1.0) as u64;
    let start = (clock.now_ns().div_ceil(period_ns) * period_ns).saturating_sub(period_ns);
    let mut seq = 0u64;
    let mut next_t = capture_time_ns(&config, start, seq);
    let pool = RenderPool::new(parallel);
    type Render = tokio::sync::oneshot::Receiver<Option<SimPayload>>;
    let mut inflight: std::collections::VecDeque<(u64, u64, Render)> =
        std::collections::VecDeque::new();
    loop {
        let capture_due = inflight.len() < parallel;
        tokio::select! {
            biased;
            r = async { (&mut inflight.front_mut().expect("checked non-empty").2).await },
                if !inflight.is_empty() =>
            {
                let (fseq, t, _) = inflight.pop_front().expect("checked non-empty");
                let payload = match r {
                    Ok(Some(p)) => p,
                    _ => {
                        counters.failed.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                };
                let frame = SimFrame {
                    sequence: fseq,
                    device_ts_ns: config.device_ts_ns(t),
                    capture_t_ns: t,
                    payload,
                };
                match tx.try_send(frame) {
                    Ok(()) => {
                        counters.delivered.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(mpsc::error::TrySendError::Full(_)) => {
                        counters.overruns.fetch_add(1, Ordering::Relaxed);
                    }
                    Err(mpsc::error::TrySendError::Closed(_)) => return,
                }
            }
            _ = clock.sleep_until_ns(next_t), if capture_due => {
                let (this, t) = (seq, next_t);
                seq += 1;
                next_t = capture_time_ns(&config, start, seq);
                if tx.is_closed() {
                    return;
                }
                if is_dropped(&config, this) {
                    counters.injected.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                if counters.stall.load(Ordering::Acquire) {
                    counters.stalled.fetch_add(1, Ordering::Relaxed);
                    continue;
                }
                // Rendering (and the camera's own JPEG encoding) is CPU work: keep it off the
                // async workers. A frame that cannot be encoded counts as a failed render.
                let r = renderer.clone();
                let encoding = config.encoding;
                let job = move || {
                    let img = r.render_at(t)?;
                    SimPayload::encode(img, encoding)
                        .map_err(|e| tracing::warn!("simulated camera: {e}"))
                        .ok()
                };
                inflight.push_back((this, t, pool.run(job)));
            }
        }
    }
}

/// The camera's render threads. Rendering and encoding are most of a simulated run's CPU; on a
/// machine with few cores they ran beside the contact physics, which the simulated clock waits
/// for, so its steps queued behind renders and the clock held. These threads run at a lower
/// scheduling priority (nice +5 where the OS allows it): the physics, the devices and the
/// recorder go first, and the renders take the rest of the CPU, which is most of it.
struct RenderPool {
    jobs: std::sync::mpsc::Sender<Box<dyn FnOnce() + Send>>,
}

impl RenderPool {
    fn new(threads: usize) -> Self {
        let (jobs, rx) = std::sync::mpsc::channel::<Box<dyn FnOnce() + Send>>();
        let rx = Arc::new(Mutex::new(rx));
        for k in 0..threads.max(1) {
            let rx = rx.clone();
            let spawned = std::thread::Builder::new()
                .name(format!("sim-camera-render-{k}"))
                .spawn(move || {
                    lower_this_threads_priority();
                    loop {
                        // The lock is held only while waiting for the next job.
                        let job = match rx.lock() {
                            Ok(rx) => rx.recv(),
                            Err(_) => return,
                        };
                        match job {
                            Ok(job) => job(),
                            Err(_) => return, // the camera stopped
                        }
                    }
                });
            if let Err(e) = spawned {
                tracing::error!("simulated camera: cannot start a render thread: {e}");
            }
        }
        Self { jobs }
    }

    /// Runs `job` on a render thread; the receiver gets its result (or is closed if the job
    /// panicked or no render thread could start, which the camera counts as a failed render).
    fn run(
        &self,
        job: impl FnOnce() -> Option<SimPayload> + Send + 'static,
    ) -> tokio::sync::oneshot::Receiver<Option<SimPayload>> {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let _ = self.jobs.send(Box::new(move || {
            let _ = tx.send(job());
        }));
        rx
    }
}

/// Nice +5 for the calling thread (Linux schedules threads separately); where that is refused,
/// the thread keeps its priority.
fn lower_this_threads_priority() {
    #[cfg(target_os = "linux")]
    {
        use nix::libc;
        // SAFETY: plain system calls on the calling thread's own id, no memory passed.
        let r = unsafe {
            let tid = libc::gettid();
            let now = libc::getpriority(libc::PRIO_PROCESS, tid as libc::id_t);
            libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, (now + 5).min(19))
        };
        if r != 0 {
            tracing::debug!("simulated camera: render thread keeps its priority");
        }
    }
}

/// Sleeps one frame period of clock time (helper for tests that step a manual clock).
pub fn period(config: &SimCameraConfig) -> Duration {
    Duration::from_secs_f64(1.0 / config.actual_fps)
}
