//! The disk budget of a recording: what a run will write, checked against the free space of
//! the output's file system before anything connects, and again before each trajectory.
//!
//! # The estimate
//!
//! A trajectory's file holds, from its first stage's start to its end (the transit and the tare
//! before it are not recorded):
//!
//! - its **frames**: the trajectory's planned duration (each stage's moves with the trapezoid
//!   speed profile of [`crate::plan::Stage::duration_estimate_s`], acceleration included) ×
//!   `camera.fps`, each [`Budget::frame`] bytes: the sensor's measured stored frame
//!   ([`FrameFigure`]) × [`FRAME_MARGIN`], plus its MCAP record ([`FRAME_RECORD_BYTES`]);
//! - the **other channels**, per second of the same duration: the full-rate wrench at
//!   `force_sensor.rate_hz`, the TCP pose at `robot.rtde_frequency_hz`, and per frame its paired
//!   wrench and (simulated rig) its true wrench; four stage labels; and the file's fixed part
//!   (header, schemas, summary, index: [`FILE_BYTES`]). The per-sample figures below were
//!   measured on real recordings (see their docs).
//!
//! The run is refused when the free space cannot hold the estimate × [`MARGIN`] plus
//! [`RESERVE_BYTES`]; the same test is made before each trajectory for that trajectory.
//!
//! # The sensor's bytes per frame
//!
//! - simulated camera: one representative pressed frame, rendered with the sensor's optics and
//!   image effects ([`crate::simrig::render::render_scene`]: the indenter at the plan's deepest
//!   depth, at the end of its slide), built as the simulated camera builds its frames
//!   ([`crate::simrig::frame_as_sent`]) and encoded exactly as the recorder stores it
//!   ([`super::streams::stored_image`]);
//! - V4L2 camera: nothing can be measured before the camera is opened, so the preflight uses a
//!   conservative figure for the configured format ([`format_bound`]); once the camera streams
//!   (it is open before the robot moves), the run measures the frames the recorder stored and
//!   uses their mean × [`FRAME_MARGIN`] from then on ([`Budget::refine`]), first before the
//!   first motion.

use std::path::{Path, PathBuf};

use anyhow::Context;
use rig_core::config::{CameraFormat, CameraKind, RigConfig};
use rig_core::indenter::Indenter;

use crate::plan::{Plan, Trajectory};
use crate::record::{Manifest, Status, final_name};

/// A frame's stored bytes are taken × 1.25. The stored size follows what the frame shows: PNG
/// (lossless) and JPEG both grow with detail, i.e. with the contact patch, the markers it moves
/// and the camera noise. The representative frame is already one of the largest (deepest
/// press, end of the slide). Measured on `p0-d0.8-a000` (cone, `sim-source`, 320 × 240): the
/// 146 PNG frames of a `format = "raw"` recording took 103.6-105.2 kB (the rendered frame
/// 105.0 kB), the JPEG frames (quality 90) of an MJPEG one 16.0-18.1 kB, ±7 % about their
/// mean. 25 % covers that spread, another noise draw, and indenters or contact points with
/// more edge than the one rendered, without doubling the estimate.
pub const FRAME_MARGIN: f64 = 1.25;

/// The whole estimate is taken × 1.10 before it is compared with the free space: the robot's
/// real stages run a little longer than their trapezoid profile (settling at each waypoint,
/// the frames still arriving as the last stage ends: 146 frames recorded for 144 planned on
/// the simulated rig, +1.4 %), zstd compresses interleaved channels a little differently from
/// run to run, and the file system rounds every file up to its blocks.
pub const MARGIN: f64 = 1.10;

/// Kept free besides the estimate: the manifest (rewritten atomically, so twice its size for a
/// moment), the directory entries, and the partial file's write buffer.
pub const RESERVE_BYTES: u64 = 1 << 20;

// The per-sample figures: bytes one message of each channel takes in a trajectory file, its
// MCAP record and message-index entry included, zstd-compressed as the recorder writes it.
// Measured (`tests::measure_recording`) on two simulated-rig recordings of `p0-d0.8-a000`
// (cone, 1 kHz Net F/T, 500 Hz RTDE, 320 × 240 at 25 fps; MJPEG and raw frames): each
// channel's messages rewritten alone with the recorder's settings, less the empty file, per
// message: wrench 61.9 / 62.9, TCP pose 35.0 / 34.7, paired wrench 96.4 / 100.9, true wrench
// 58.5 / 58.2, stage label 56.8 / 55.0 bytes; the empty file 6507 bytes. Written together, the
// channels' messages took 17 % / 22 % more than alone (interleaved, the wrench and pose
// messages compress less well); the figures below carry that 22 %.

/// Bytes one full-rate wrench sample takes (62.9 measured alone, × 1.22 interleaved).
pub const WRENCH_BYTES: f64 = 78.0;
/// Bytes one TCP pose (every RTDE state) takes (35.0 alone, × 1.22).
pub const POSE_BYTES: f64 = 44.0;
/// Bytes one paired-wrench message (one per frame) takes (100.9 alone, × 1.22).
pub const PAIRED_BYTES: f64 = 124.0;
/// Bytes one true-wrench message (simulated rig, one per frame) takes (58.5 alone, × 1.22).
pub const TRUE_WRENCH_BYTES: f64 = 72.0;
/// Bytes one stage label takes (four a trajectory; 56.8 measured).
pub const STAGE_BYTES: f64 = 64.0;
/// Bytes a frame's message takes besides its image: the MCAP record (31), the protobuf fields
/// around the image (about 30) and the message-index entry (16). zstd takes a little off the
/// image bytes themselves (2 % of the PNG frames', 17 % of the JPEG frames' measured), which
/// is left as margin.
pub const FRAME_RECORD_BYTES: f64 = 80.0;
/// Bytes of a trajectory file without messages: header, the six schemas and channels, the
/// metadata, the summary and footer (6507 measured), and its entry in the manifest.
pub const FILE_BYTES: u64 = 8 * 1024;

/// A conservative stored size of one V4L2 frame of the configured format, before any frame
/// has been seen: raw frames (RGB, YUYV) are stored as PNG, which never takes much more than
/// the raw RGB bytes (3 per pixel; a PNG row adds one filter byte, deflate's stored blocks a
/// few bytes per 64 KiB); an MJPEG camera's JPEG is stored as sent, taken at 1.5 bytes per
/// pixel: the simulated sensor's frame (shading, markers, noise) takes 0.9 at JPEG quality 100
/// (the test below) and 0.22 at 90, and a UVC camera's firmware encodes at 2-4 bits per pixel.
/// A camera that falls back to the other format is caught by the frames measured before the
/// first motion ([`Budget::refine`]).
pub fn format_bound(format: CameraFormat, width: u32, height: u32) -> u64 {
    let px = u64::from(width) * u64::from(height);
    match format {
        CameraFormat::Mjpeg => px * 3 / 2 + 1024,
        CameraFormat::Raw => px * 3 + u64::from(height) + (px * 3).div_ceil(65_535) * 5 + 1024,
    }
}

/// Where the bytes per frame come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameBasis {
    /// No camera: no frames.
    NoCamera,
    /// A frame rendered by the simulator and encoded as the recorder stores it.
    Rendered,
    /// [`format_bound`]: nothing measured yet.
    FormatBound,
    /// The mean of the frames the run stored so far.
    Measured,
}

/// The stored size of one frame, before [`FRAME_MARGIN`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameFigure {
    pub stored_bytes: u64,
    pub basis: FrameBasis,
}

impl FrameFigure {
    /// No camera: no frames.
    const NO_CAMERA: FrameFigure = FrameFigure {
        stored_bytes: 0,
        basis: FrameBasis::NoCamera,
    };

    fn describe(&self) -> &'static str {
        match self.basis {
            FrameBasis::NoCamera => "no camera",
            FrameBasis::Rendered => "a pressed frame rendered by the simulator, stored as recorded",
            FrameBasis::FormatBound => "a conservative figure for the camera's format",
            FrameBasis::Measured => "the frames stored so far",
        }
    }
}

/// The rates and the per-frame size an estimate is made of.
#[derive(Debug, Clone, PartialEq)]
pub struct Budget {
    /// Frames per second (0: no camera).
    pub fps: f64,
    /// Wrench samples per second.
    pub ft_hz: f64,
    /// TCP poses per second.
    pub rtde_hz: f64,
    /// The simulated rig records a true wrench per frame.
    pub truth: bool,
    pub frame: FrameFigure,
}

/// What an estimate counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Estimate {
    pub trajectories: u64,
    pub frames: u64,
    pub bytes: u64,
}

impl std::ops::Add for Estimate {
    type Output = Estimate;
    fn add(self, o: Estimate) -> Estimate {
        Estimate {
            trajectories: self.trajectories + o.trajectories,
            frames: self.frames + o.frames,
            bytes: self.bytes + o.bytes,
        }
    }
}

impl std::iter::Sum for Estimate {
    fn sum<I: Iterator<Item = Estimate>>(it: I) -> Estimate {
        it.fold(Estimate::default(), |a, b| a + b)
    }
}

impl Estimate {
    /// The free space it asks for: × [`MARGIN`], plus [`RESERVE_BYTES`].
    pub fn required(&self) -> u64 {
        with_margin(self.bytes)
    }
}

/// `bytes` × [`MARGIN`] + [`RESERVE_BYTES`].
pub fn with_margin(bytes: u64) -> u64 {
    (bytes as f64 * MARGIN).ceil() as u64 + RESERVE_BYTES
}

impl Budget {
    /// The rates of `config` with `frame` as the stored size of a frame.
    pub fn new(config: &RigConfig, frame: FrameFigure) -> Self {
        Budget {
            fps: config.camera.as_ref().map_or(0.0, |c| c.fps.max(0.0)),
            ft_hz: config
                .force_sensor
                .as_ref()
                .map_or(0.0, |f| f.rate_hz.max(0.0)),
            rtde_hz: config.robot.rtde_frequency_hz.max(0.0),
            truth: config.robot.simulated && config.camera.is_some(),
            frame: if config.camera.is_some() {
                frame
            } else {
                FrameFigure::NO_CAMERA
            },
        }
    }

    /// The budget of a run of `plan` on `config` (the frame measured as the module doc says).
    pub fn for_run(config: &RigConfig, plan: &Plan, indenter: &Indenter) -> Self {
        Self::new(config, frame_figure(config, plan, indenter))
    }

    /// Bytes one frame is counted at: its stored size × [`FRAME_MARGIN`] and its record.
    pub fn frame_bytes(&self) -> u64 {
        if self.frame.basis == FrameBasis::NoCamera {
            return 0;
        }
        (self.frame.stored_bytes as f64 * FRAME_MARGIN + FRAME_RECORD_BYTES).ceil() as u64
    }

    /// Frames of trajectory `t`: its planned duration × fps, rounded up (a rounding error of
    /// the pose maths, a micro-frame, is not a frame).
    pub fn frames(&self, t: &Trajectory) -> u64 {
        (t.duration_estimate_s() * self.fps - 1e-6).ceil().max(0.0) as u64
    }

    /// The estimate of one trajectory's file.
    pub fn trajectory(&self, t: &Trajectory) -> Estimate {
        let s = t.duration_estimate_s().max(0.0);
        let frames = self.frames(t);
        let per_frame = self.frame_bytes() as f64
            + PAIRED_BYTES
            + if self.truth { TRUE_WRENCH_BYTES } else { 0.0 };
        let frames_part = frames as f64 * if self.fps > 0.0 { per_frame } else { 0.0 };
        let streams = s * (self.ft_hz * WRENCH_BYTES + self.rtde_hz * POSE_BYTES);
        let labels = t.stages.len() as f64 * STAGE_BYTES;
        Estimate {
            trajectories: 1,
            frames,
            bytes: (frames_part + streams + labels).ceil() as u64 + FILE_BYTES,
        }
    }

    /// The estimate of every trajectory of `ts`.
    pub fn trajectories<'a>(&self, ts: impl IntoIterator<Item = &'a Trajectory>) -> Estimate {
        ts.into_iter().map(|t| self.trajectory(t)).sum()
    }

    /// Takes the frames the run stored so far (`frames`, `bytes` in all) into account: a
    /// conservative figure is replaced by their mean; a rendered one is raised to it if the
    /// real frames are larger.
    pub fn refine(&mut self, frames: u64, bytes: u64) {
        if frames == 0 || self.frame.basis == FrameBasis::NoCamera {
            return;
        }
        let mean = bytes.div_ceil(frames);
        match self.frame.basis {
            FrameBasis::FormatBound | FrameBasis::Measured => {
                self.frame = FrameFigure {
                    stored_bytes: mean,
                    basis: FrameBasis::Measured,
                }
            }
            FrameBasis::Rendered if mean > self.frame.stored_bytes => {
                self.frame = FrameFigure {
                    stored_bytes: mean,
                    basis: FrameBasis::Measured,
                }
            }
            _ => {}
        }
    }
}

/// The stored size of one frame of `config`'s camera for `plan` (see the module doc).
pub fn frame_figure(config: &RigConfig, plan: &Plan, indenter: &Indenter) -> FrameFigure {
    let Some(cam) = &config.camera else {
        return FrameFigure::NO_CAMERA;
    };
    let bound = FrameFigure {
        stored_bytes: format_bound(cam.format, cam.width_px, cam.height_px),
        basis: FrameBasis::FormatBound,
    };
    if cam.kind != CameraKind::Sim {
        return bound;
    }
    match rendered_frame_bytes(config, plan, indenter) {
        Ok(bytes) => FrameFigure {
            stored_bytes: bytes,
            basis: FrameBasis::Rendered,
        },
        Err(e) => {
            tracing::warn!(
                "disk budget: cannot render a frame to measure ({e:#}); counting {} bytes a frame",
                bound.stored_bytes
            );
            bound
        }
    }
}

/// The stored size of the simulated sensor's frame of the plan's deepest press, at the end of
/// its slide.
fn rendered_frame_bytes(
    config: &RigConfig,
    plan: &Plan,
    indenter: &Indenter,
) -> anyhow::Result<u64> {
    let deepest = plan
        .trajectories
        .iter()
        .fold(None::<&Trajectory>, |best, t| match best {
            Some(b) if b.depth_mm >= t.depth_mm => Some(b),
            _ => Some(t),
        })
        .context("the plan has no trajectories")?;
    let (s, c) = deepest.angle_deg.to_radians().sin_cos();
    let d = config.plan.shear_distance_mm;
    let scene = crate::simrig::render::render_scene(
        config,
        indenter.clone(),
        deepest.point_mm,
        deepest.depth_mm,
        [d * c, d * s],
    );
    let out = crate::simrig::sim::simulate(&scene).map_err(|e| anyhow::anyhow!("{e}"))?;
    let image = out
        .image
        .context("the simulator returned no image for an image scene")?;
    let camera = config
        .camera
        .as_ref()
        .context("the config has no [camera]")?;
    let frame = crate::simrig::frame_as_sent(camera, image).map_err(anyhow::Error::msg)?;
    let (_, stored) = super::streams::stored_image(&frame).map_err(anyhow::Error::msg)?;
    Ok(stored.len() as u64)
}

/// Free bytes for an unprivileged writer on the file system holding `path` (or its nearest
/// existing ancestor, for a directory not created yet).
pub fn free_bytes(path: &Path) -> std::io::Result<u64> {
    let at = existing_ancestor(path);
    let s = nix::sys::statvfs::statvfs(at.as_path()).map_err(std::io::Error::from)?;
    #[allow(clippy::useless_conversion)] // the field types differ between targets
    let (blocks, size) = (
        u64::from(s.blocks_available()),
        u64::from(s.fragment_size()),
    );
    Ok(blocks.saturating_mul(size))
}

/// `path` itself if it exists, else its nearest existing ancestor (`.` for a relative path
/// whose first component does not exist).
fn existing_ancestor(path: &Path) -> PathBuf {
    path.ancestors()
        .find(|p| !p.as_os_str().is_empty() && p.exists())
        .map_or_else(|| PathBuf::from("."), Path::to_path_buf)
}

/// The file system a path is on (of its nearest existing ancestor).
fn device_of(path: &Path) -> Option<u64> {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(existing_ancestor(path))
        .ok()
        .map(|m| m.dev())
}

/// Bytes as a person reads them: `12.3 MB` (SI units, as `df -H`).
pub fn human(bytes: u64) -> String {
    const UNITS: [&str; 5] = ["kB", "MB", "GB", "TB", "PB"];
    if bytes < 1000 {
        return format!("{bytes} B");
    }
    let mut v = bytes as f64;
    let mut unit = "B";
    for u in UNITS {
        if v < 1000.0 {
            break;
        }
        v /= 1000.0;
        unit = u;
    }
    format!("{v:.1} {unit}")
}

/// Bytes and their readable form: `12.3 MB (12345678 bytes)`.
fn both(bytes: u64) -> String {
    format!("{} ({bytes} bytes)", human(bytes))
}

/// Before anything connects: the estimate of the trajectories of `planned` not in `complete`,
/// refused when the free space of `out`'s file system cannot hold it (with its margin). The
/// error says both numbers and what to do. The budget is returned for the run's later checks.
pub(crate) fn preflight(
    config: &RigConfig,
    plan: &Plan,
    indenter: &Indenter,
    planned: &[Trajectory],
    complete: &[String],
    out: &Path,
) -> anyhow::Result<Budget> {
    let budget = Budget::for_run(config, plan, indenter);
    let todo: Vec<&Trajectory> = planned
        .iter()
        .filter(|t| !complete.contains(&t.id))
        .collect();
    let est = budget.trajectories(todo.iter().copied());
    let free = match free_bytes(out) {
        Ok(f) => f,
        Err(e) => {
            tracing::warn!(
                "disk budget: cannot read the free space of {} ({e}); not checked",
                out.display()
            );
            return Ok(budget);
        }
    };
    let need = est.required();
    tracing::info!(
        "disk budget: {} trajectories, {} frames at about {} each ({}), need about {}; {} free in {}",
        est.trajectories,
        est.frames,
        human(budget.frame_bytes()),
        budget.frame.describe(),
        human(need),
        human(free),
        out.display()
    );
    if need <= free {
        return Ok(budget);
    }
    // The --limit that would fit: the longest prefix of the plan whose trajectories still to
    // record fit the free space.
    let mut fits = 0usize;
    let mut acc = Estimate::default();
    for (k, t) in planned.iter().enumerate() {
        if complete.contains(&t.id) {
            continue;
        }
        acc = acc + budget.trajectory(t);
        if acc.required() > free {
            break;
        }
        fits = k + 1;
    }
    let limit = if fits > 0 {
        format!(", or record part of the plan with --limit {fits} (what fits now)")
    } else {
        ", or record part of the plan with --limit".to_owned()
    };
    anyhow::bail!(
        "not enough disk space for this recording: its {} trajectories need about {}, but the \
         file system of {} has {} free ({} frames at about {} each, counted from {}, the other \
         channels, a {:.0} % margin and {} kept free). Nothing was started. Free space there, \
         choose another --out on a larger disk{limit}",
        est.trajectories,
        both(need),
        out.display(),
        both(free),
        est.frames,
        human(budget.frame_bytes()),
        budget.frame.describe(),
        (MARGIN - 1.0) * 100.0,
        human(RESERVE_BYTES),
    )
}

/// Before trajectory `rest[0]`: `Err` with the operator's message when the free space of
/// `out`'s file system cannot hold that trajectory (with its margin). `rest` is every
/// trajectory the run still has to record, `done` how many this run completed.
pub(crate) fn check_before(
    budget: &Budget,
    rest: &[&Trajectory],
    out: &Path,
    done: usize,
) -> Result<(), String> {
    let Some(next) = rest.first() else {
        return Ok(());
    };
    let Ok(free) = free_bytes(out) else {
        return Ok(());
    };
    let this = budget.trajectory(next).required();
    if this <= free {
        return Ok(());
    }
    let all = budget.trajectories(rest.iter().copied()).required();
    Err(format!(
        "not enough disk space left to record trajectory {}: the file system of {} has {} free, \
         this trajectory needs about {} and the rest of the plan ({} trajectories) about {}. \
         No new trajectory was started; the {done} completed in this run are kept and the rest \
         stay pending in the manifest. Free space (or move the recording to a larger disk), \
         then run the same command again with --resume",
        next.id,
        out.display(),
        both(free),
        both(this),
        rest.len(),
        both(all),
    ))
}

/// Waits (up to `timeout` of clock time) until the camera stream has stored `n` frames, so
/// that the first trajectory's check measures the real frames.
pub(crate) async fn await_frames(
    counters: &super::events::StreamCounters,
    clock: &rig_core::clock::Clock,
    n: u64,
    timeout: std::time::Duration,
) {
    let deadline = clock
        .now_ns()
        .saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
    while counters.stored_frames() < n && clock.now_ns() < deadline {
        clock.sleep(std::time::Duration::from_millis(20)).await;
    }
}

/// The size of `dir` as `du -sb` counts it: the apparent sizes of the directory and of
/// everything under it (links not followed, a file with several hard links once).
pub fn dir_bytes(dir: &Path) -> std::io::Result<u64> {
    use std::os::unix::fs::MetadataExt;
    let mut seen = std::collections::HashSet::new();
    let mut total = 0u64;
    let mut stack = vec![dir.to_path_buf()];
    while let Some(p) = stack.pop() {
        let m = std::fs::symlink_metadata(&p)?;
        if m.nlink() > 1 && !m.is_dir() && !seen.insert((m.dev(), m.ino())) {
            continue;
        }
        total += m.len();
        if m.is_dir() {
            for e in std::fs::read_dir(&p)? {
                stack.push(e?.path());
            }
        }
    }
    Ok(total)
}

/// What the recording in a run's output directory takes on disk, for the end-of-run report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiskUse {
    /// The output directory's size (`du -sb`).
    pub bytes: u64,
    /// Frames in its complete trajectories (the manifest's counts).
    pub frames: u64,
    /// What the estimate counted a frame at (stored size × margin + record), bytes.
    pub estimated_frame_bytes: u64,
}

impl DiskUse {
    /// Measures `out` once the recording is closed.
    pub fn of(out: &Path, budget: &Budget) -> Option<DiskUse> {
        let bytes = dir_bytes(out).ok()?;
        let frames = Manifest::load(out)
            .ok()
            .map(|m| {
                m.trajectories
                    .iter()
                    .filter(|t| t.status == Status::Complete)
                    .map(|t| t.counts.frames)
                    .sum()
            })
            .unwrap_or(0);
        Some(DiskUse {
            bytes,
            frames,
            estimated_frame_bytes: budget.frame_bytes(),
        })
    }

    /// The report's line.
    pub fn line(&self) -> String {
        let per_frame = match self.bytes.checked_div(self.frames) {
            Some(each) => format!(
                "{each} bytes per frame over its {} frames (estimated at {} before the run)",
                self.frames, self.estimated_frame_bytes
            ),
            None => "no frames".to_owned(),
        };
        format!("disk: {} written, {per_frame}\n", both(self.bytes))
    }
}

/// The trajectories of `plan` whose recording in `dir` is complete (the manifest says so and
/// the file is there), without touching anything.
fn complete_in(dir: &Path) -> Vec<String> {
    let Ok(m) = Manifest::load(dir) else {
        return Vec::new();
    };
    m.trajectories
        .iter()
        .filter(|t| t.status == Status::Complete && dir.join(final_name(&t.id)).is_file())
        .map(|t| t.id.clone())
        .collect()
}

/// Before `rig demo` or `rig reproduce` records anything: the sum of the estimates of every
/// recording of `jobs` (rig config, output directory of the run, indenter), less what is
/// already complete there, refused when a file system cannot hold its part. `what` names the
/// command in the message, `smaller` how to ask it for less (if it can be).
pub fn check_collection(
    jobs: &[(&RigConfig, PathBuf, &str)],
    what: &str,
    smaller: Option<&str>,
) -> anyhow::Result<()> {
    // By file system: (a directory on it, estimate, runs).
    let mut by_fs: std::collections::BTreeMap<u64, (PathBuf, Estimate, u64)> = Default::default();
    let mut frame_bytes = 0u64;
    for (config, dir, name) in jobs {
        let indenter = Indenter::load(name)?;
        let plan = Plan::build(config, &indenter)
            .with_context(|| format!("planning {name} on {}", config.sensor.id))?;
        let complete = complete_in(dir);
        let todo: Vec<&Trajectory> = plan
            .trajectories
            .iter()
            .filter(|t| !complete.contains(&t.id))
            .collect();
        if todo.is_empty() {
            continue;
        }
        let budget = Budget::for_run(config, &plan, &indenter);
        frame_bytes = frame_bytes.max(budget.frame_bytes());
        let est = budget.trajectories(todo);
        let Some(dev) = device_of(dir) else {
            continue;
        };
        let e = by_fs
            .entry(dev)
            .or_insert_with(|| (dir.clone(), Estimate::default(), 0));
        e.1 = e.1 + est;
        e.2 += 1;
    }
    for (dir, est, runs) in by_fs.values() {
        let need = (est.bytes as f64 * MARGIN).ceil() as u64 + RESERVE_BYTES * runs;
        let Ok(free) = free_bytes(dir) else {
            continue;
        };
        tracing::info!(
            "disk budget: {runs} recordings, {} trajectories, {} frames, need about {}; {} free",
            est.trajectories,
            est.frames,
            human(need),
            human(free)
        );
        if need > free {
            let smaller = smaller.map(|s| format!(", or {s}")).unwrap_or_default();
            anyhow::bail!(
                "not enough disk space for {what}'s recordings: {runs} recordings of {} \
                 trajectories need about {}, but the file system of {} has {} free ({} frames \
                 at up to {} each, the other channels, a {:.0} % margin and {} kept free per \
                 recording). Nothing was recorded. Free space there or choose another --out on \
                 a larger disk{smaller}",
                est.trajectories,
                both(need),
                existing_ancestor(dir).display(),
                both(free),
                est.frames,
                human(frame_bytes),
                (MARGIN - 1.0) * 100.0,
                human(RESERVE_BYTES),
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::PixelFormat;

    fn cone_plan(config: &RigConfig) -> Plan {
        Plan::build(config, &Indenter::builtin("cone").unwrap()).unwrap()
    }

    fn budget(config: &RigConfig, stored: u64) -> Budget {
        Budget::new(
            config,
            FrameFigure {
                stored_bytes: stored,
                basis: FrameBasis::Rendered,
            },
        )
    }

    #[test]
    fn a_trajectory_is_its_stages_durations_times_the_rates() {
        let config = RigConfig::sim_source();
        let plan = cone_plan(&config);
        let t = &plan.trajectories[0]; // p0-d0.2-a000
        // Down 2.2 mm at 1 mm/s, 10 mm/s²: 2.3 s; shear and reverse 2 mm at 2 mm/s, 20 mm/s²:
        // 1.1 s each; up 2.2 mm at 5 mm/s, 50 mm/s²: 0.54 s. 5.04 s in all.
        let s = t.duration_estimate_s();
        assert!((s - 5.04).abs() < 1e-9, "{s}");
        let b = budget(&config, 100_000);
        assert_eq!(
            (b.fps, b.ft_hz, b.rtde_hz, b.truth),
            (25.0, 1000.0, 500.0, true)
        );
        // 5.04 s × 25 fps = 126 frames.
        assert_eq!(b.frames(t), 126);
        // 100 kB × 1.25 + the frame's record.
        assert_eq!(b.frame_bytes(), 125_000 + FRAME_RECORD_BYTES as u64);
        let e = b.trajectory(t);
        let want = 126.0 * (b.frame_bytes() as f64 + PAIRED_BYTES + TRUE_WRENCH_BYTES)
            + s * (1000.0 * WRENCH_BYTES + 500.0 * POSE_BYTES)
            + 4.0 * STAGE_BYTES;
        assert_eq!(e.bytes, want.ceil() as u64 + FILE_BYTES);
        assert_eq!((e.trajectories, e.frames), (1, 126));
        // Three of them, and the margin on top.
        let three = b.trajectories(&plan.trajectories[..3]);
        assert_eq!(three.trajectories, 3);
        assert_eq!(three.frames, 3 * 126);
        assert_eq!(three.bytes, 3 * e.bytes);
        assert_eq!(
            three.required(),
            (three.bytes as f64 * 1.1).ceil() as u64 + (1 << 20)
        );
    }

    #[test]
    fn without_a_camera_only_the_streams_count() {
        let mut config = RigConfig::sim_source();
        config.camera = None;
        let plan = cone_plan(&config);
        let b = budget(&config, 100_000);
        assert_eq!(b.frame.basis, FrameBasis::NoCamera);
        let t = &plan.trajectories[0];
        let e = b.trajectory(t);
        assert_eq!(e.frames, 0);
        let s = t.duration_estimate_s();
        assert!((s - 5.04).abs() < 1e-9, "{s}");
        let want = s * (1000.0 * WRENCH_BYTES + 500.0 * POSE_BYTES) + 4.0 * STAGE_BYTES;
        assert_eq!(e.bytes, want.ceil() as u64 + FILE_BYTES);
    }

    #[test]
    fn format_bounds_hold_a_png_of_noise_and_a_sensor_jpeg_at_full_quality() {
        use image::{Rgb, RgbImage};
        // Noise: PNG cannot compress it; the bound must still hold the file.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let img = RgbImage::from_fn(320, 240, |_, _| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            Rgb([state as u8, (state >> 8) as u8, (state >> 16) as u8])
        });
        let png = crate::record::png::encode(&img).unwrap();
        let bound = format_bound(CameraFormat::Raw, 320, 240);
        assert!(png.len() as u64 <= bound, "{} > {bound}", png.len());
        assert!(bound < 320 * 240 * 3 + 4096, "{bound}");
        // A sensor's image (the simulated one: shading, markers, noise) as JPEG at quality 100,
        // more than a UVC camera's firmware spends: under the 1.5 bytes a pixel counted.
        let config = RigConfig::sim_source();
        let scene = crate::simrig::render::render_scene(
            &config,
            Indenter::builtin("cone").unwrap(),
            [0.0, 0.0],
            0.8,
            [2.0, 0.0],
        );
        let frame = crate::simrig::sim::simulate(&scene).unwrap().image.unwrap();
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 100)
            .encode_image(&frame)
            .unwrap();
        assert_eq!(
            format_bound(CameraFormat::Mjpeg, 320, 240),
            320 * 240 * 3 / 2 + 1024
        );
        assert!((jpeg.len() as u64) < 320 * 240, "{}", jpeg.len());
    }

    #[test]
    fn measured_frames_replace_a_bound_and_raise_a_rendered_figure() {
        let config = RigConfig::sim_source();
        let mut b = Budget::new(
            &config,
            FrameFigure {
                stored_bytes: 230_000,
                basis: FrameBasis::FormatBound,
            },
        );
        b.refine(0, 0);
        assert_eq!(b.frame.basis, FrameBasis::FormatBound);
        b.refine(4, 100_002);
        assert_eq!(
            b.frame,
            FrameFigure {
                stored_bytes: 25_001,
                basis: FrameBasis::Measured
            }
        );
        let mut r = budget(&config, 30_000);
        r.refine(10, 250_000); // smaller real frames: the rendered figure stays
        assert_eq!(r.frame.stored_bytes, 30_000);
        r.refine(10, 400_000);
        assert_eq!(r.frame.stored_bytes, 40_000);
        assert_eq!(r.frame.basis, FrameBasis::Measured);
    }

    #[test]
    fn the_simulated_sensors_frame_is_rendered_and_stored_as_recorded() {
        let config = RigConfig::sim_source();
        let indenter = Indenter::builtin("cone").unwrap();
        let plan = Plan::build(&config, &indenter).unwrap();
        let f = frame_figure(&config, &plan, &indenter);
        assert_eq!(f.basis, FrameBasis::Rendered);
        // A 320 × 240 frame with markers and noise: far below its raw 230 kB as PNG, far above
        // a flat image.
        assert!(f.stored_bytes > 10_000, "{f:?}");
        assert!(
            f.stored_bytes < format_bound(CameraFormat::Raw, 320, 240),
            "{f:?}"
        );
        // The frame is the simulated camera's: MJPEG in the shipped sensors, a few tens of kB.
        assert!(f.stored_bytes < 40_000, "{f:?}");
        let cam = config.camera.clone().unwrap();
        let frame = crate::simrig::frame_as_sent(&cam, image::RgbImage::new(320, 240)).unwrap();
        assert_eq!(frame.format.pixel, PixelFormat::Mjpeg);
        assert_eq!((frame.format.width, frame.format.height), (320, 240));
        let raw = rig_core::config::CameraConfig {
            format: CameraFormat::Raw,
            ..cam
        };
        let frame = crate::simrig::frame_as_sent(&raw, image::RgbImage::new(320, 240)).unwrap();
        assert_eq!(frame.format.pixel, PixelFormat::Rgb8);
        assert_eq!(frame.data.len(), 320 * 240 * 3);
    }

    #[test]
    fn bytes_read_as_people_read_them() {
        assert_eq!(human(999), "999 B");
        assert_eq!(human(1000), "1.0 kB");
        assert_eq!(human(12_345_678), "12.3 MB");
        assert_eq!(human(2_500_000_000), "2.5 GB");
        assert_eq!(both(1_500_000), "1.5 MB (1500000 bytes)");
    }

    #[test]
    fn the_directory_size_is_du_s_b() {
        let tmp = tempfile::tempdir().unwrap();
        let d = tmp.path();
        std::fs::write(d.join("a"), vec![0u8; 1234]).unwrap();
        std::fs::create_dir(d.join("sub")).unwrap();
        std::fs::write(d.join("sub/b"), vec![0u8; 100]).unwrap();
        std::fs::hard_link(d.join("a"), d.join("a2")).unwrap();
        let dirs =
            std::fs::metadata(d).unwrap().len() + std::fs::metadata(d.join("sub")).unwrap().len();
        assert_eq!(dir_bytes(d).unwrap(), 1234 + 100 + dirs);
        if let Ok(out) = std::process::Command::new("du").arg("-sb").arg(d).output() {
            let du: u64 = String::from_utf8_lossy(&out.stdout)
                .split_whitespace()
                .next()
                .and_then(|s| s.parse().ok())
                .unwrap();
            assert_eq!(dir_bytes(d).unwrap(), du);
        }
    }

    #[test]
    fn free_space_is_read_for_a_directory_not_made_yet() {
        let tmp = tempfile::tempdir().unwrap();
        let here = free_bytes(tmp.path()).unwrap();
        let deeper = free_bytes(&tmp.path().join("not/yet")).unwrap();
        assert!(here > 0);
        // Same file system, read a moment apart.
        assert!(here.abs_diff(deeper) < 64 << 20, "{here} {deeper}");
    }
    /// The per-sample figures above, measured on a real recording: each channel's messages of
    /// the file `RIG_BUDGET_MCAP` rewritten alone with the recorder's settings, less an empty
    /// file, per message. `RIG_BUDGET_MCAP=runs/x/p0-d0.8-a000.mcap cargo test --lib -p rig
    /// budget::tests::measure_recording -- --ignored --nocapture`.
    #[test]
    #[ignore = "a measurement on a recording named by RIG_BUDGET_MCAP"]
    fn measure_recording() {
        use std::collections::BTreeMap;
        let Some(path) = std::env::var_os("RIG_BUDGET_MCAP") else {
            return;
        };
        let bytes = std::fs::read(&path).unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let write = |name: &str, msgs: &[mcap::Message<'_>]| -> u64 {
            let p = tmp.path().join(name);
            let f = std::io::BufWriter::new(std::fs::File::create(&p).unwrap());
            let mut w = mcap::WriteOptions::new()
                .compression(Some(mcap::Compression::Zstd))
                .compression_threads(0)
                .chunk_size(Some(crate::record::writer::CHUNK_SIZE))
                .use_chunks(true)
                .profile("")
                .create(f)
                .unwrap();
            let mut ids = BTreeMap::new();
            for (topic, schema) in crate::record::CHANNELS {
                let sid = w
                    .add_schema(
                        schema,
                        crate::record::channels::ENCODING,
                        &crate::record::channels::schema_data(schema),
                    )
                    .unwrap();
                let cid = w
                    .add_channel(
                        sid,
                        topic,
                        crate::record::channels::ENCODING,
                        &BTreeMap::new(),
                    )
                    .unwrap();
                ids.insert(topic.to_string(), cid);
            }
            for m in msgs {
                w.write_to_known_channel(
                    &mcap::records::MessageHeader {
                        channel_id: ids[&m.channel.topic],
                        sequence: m.sequence,
                        log_time: m.log_time,
                        publish_time: m.publish_time,
                    },
                    &m.data,
                )
                .unwrap();
            }
            w.finish().unwrap();
            drop(w);
            std::fs::metadata(&p).unwrap().len()
        };
        let all: Vec<mcap::Message<'_>> = mcap::read::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| m.unwrap())
            .collect();
        let empty = write("empty", &[]);
        println!(
            "file {} bytes, {} messages; empty file {empty} bytes",
            bytes.len(),
            all.len()
        );
        let mut topics: BTreeMap<String, Vec<mcap::Message<'_>>> = BTreeMap::new();
        for m in &all {
            topics
                .entry(m.channel.topic.clone())
                .or_default()
                .push(m.clone());
        }
        let mut sum = empty;
        for (topic, msgs) in &topics {
            let size = write(&topic.replace('/', "_"), msgs);
            let per = (size - empty) as f64 / msgs.len() as f64;
            sum += size - empty;
            print!(
                "{topic}: {} messages, {} bytes, {per:.1} bytes each",
                msgs.len(),
                size - empty
            );
            if topic == crate::record::TOPIC_IMAGE {
                let sizes: Vec<usize> = crate::record::reader::messages(&bytes)
                    .unwrap()
                    .filter_map(|m| match m.unwrap() {
                        crate::record::reader::Message::Frame { data, .. } => Some(data.len()),
                        _ => None,
                    })
                    .collect();
                let mean = sizes.iter().sum::<usize>() as f64 / sizes.len() as f64;
                let (lo, hi) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
                print!(
                    "; images min {lo} mean {mean:.0} max {hi}; record overhead {:.1}",
                    per - mean
                );
            }
            println!();
        }
        println!(
            "sum of the channels' files {sum} bytes against the file's {}",
            bytes.len()
        );
    }
}
