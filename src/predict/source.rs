//! Where `rig predict`'s frames come from. Each source runs on the session's source thread and
//! hands frames to a [`Feed`]; none of them waits for the predictor (except a replay run as
//! fast as possible, which is lossless).
//!
//! - [`Replay`]: a recorded dataset (a `rig run` output, or a directory of them), the frames
//!   `rig eval` scores (those with a paired force, in frame order, trajectories of at least T
//!   frames), at their recorded timing × `speed` or as fast as possible. Each trajectory
//!   restarts the window with its own stride ⌊n/T⌋, so replay reproduces `rig eval`.
//! - [`SimRun`]: the simulated target sensor while the simulated UR5e runs a short plan: a
//!   `rig run` (the run machinery unchanged) recording into a temporary directory, whose
//!   record tap ([`crate::run::RunOptions::tap`], the live view's hook) hands each frame to the
//!   feed as it is recorded and notes each frame's paired and true force. The least invasive
//!   route: no second camera reader, the frames the predictor sees are the frames recorded,
//!   with the simulator's truth beside them. The tap is called on the run's collector task,
//!   and the feed returns at once, so the run is never slowed by the model.
//! - [`Camera`]: a V4L2 camera (the rig config's `[camera]`), read by the lab's V4L2 reader.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use super::eval_stride;
use super::session::{Feed, FrameImage, Input};
use crate::live::LiveView;
use crate::record::ImageFormat;
use crate::record::Record;
use crate::record::channels::{TOPIC_IMAGE, TOPIC_PAIRED, TOPIC_TRUTH};
use crate::record::manifest::{Manifest, Status};
use crate::record::reader::{self, Message};
use crate::train::data::{find_runs, marker_params, sensor_optics};
use crate::train::modality::MarkerParams;

/// Marker sizes of a rig's images, from its config's optics (as training reads a manifest's).
pub fn marker_of(config: &RigConfig) -> MarkerParams {
    serde_json::to_value(config)
        .map(|v| marker_params(&v))
        .unwrap_or_default()
}

/// A recorded dataset, replayed.
#[derive(Clone)]
pub struct Replay {
    pub dir: PathBuf,
    /// Playback speed against the recording's timing; `None`: as fast as possible (lossless).
    pub speed: Option<f64>,
    /// Frames per LSTM window (the model's T): trajectories shorter are left out, as
    /// `rig eval` leaves them out.
    pub seq_len: usize,
    /// Where the replayed frames are also shown (the live view).
    pub live: Option<Arc<LiveView>>,
}

/// One trajectory file of a replay.
struct TrajFile {
    path: PathBuf,
    id: Arc<str>,
    marker: MarkerParams,
    optics: Option<Arc<rig_core::optics::OpticsConfig>>,
}

impl Replay {
    /// The complete trajectories of the dataset, in `rig eval`'s order.
    fn files(&self) -> anyhow::Result<Vec<TrajFile>> {
        let mut files = Vec::new();
        for run in find_runs(&self.dir)? {
            let m = Manifest::load(&run).map_err(anyhow::Error::msg)?;
            let marker = marker_params(&m.config);
            let optics = sensor_optics(&m.config).ok().map(Arc::new);
            for t in &m.trajectories {
                if t.status != Status::Complete {
                    continue;
                }
                if let Some(file) = &t.file {
                    files.push(TrajFile {
                        path: run.join(file),
                        id: Arc::from(t.id.as_str()),
                        marker,
                        optics: optics.clone(),
                    });
                }
            }
        }
        if files.is_empty() {
            bail!(
                "{} has no complete trajectory to replay",
                self.dir.display()
            );
        }
        Ok(files)
    }

    /// Reads the dataset into `feed`.
    pub fn run(self, feed: Arc<Feed>) -> anyhow::Result<()> {
        if let Some(s) = self.speed
            && !(s.is_finite() && s > 0.0)
        {
            bail!("--replay-speed must be a positive number (or `max`), got {s}");
        }
        for (traj, f) in self.files()?.into_iter().enumerate() {
            if feed.stop_requested() {
                break;
            }
            let bytes = std::fs::read(&f.path).with_context(|| format!("{}", f.path.display()))?;
            let mut frames: Vec<(i64, (ImageFormat, Vec<u8>))> = Vec::new();
            let mut paired: BTreeMap<i64, (u64, [f64; 3])> = BTreeMap::new();
            let wanted = |t: &str| t == TOPIC_IMAGE || t == TOPIC_PAIRED || t == TOPIC_TRUTH;
            for msg in reader::messages_on(&bytes, wanted).map_err(anyhow::Error::msg)? {
                match msg
                    .map_err(anyhow::Error::msg)
                    .with_context(|| format!("{}", f.path.display()))?
                {
                    Message::Frame {
                        seq, format, data, ..
                    } => frames.push((seq, (format, data))),
                    Message::Paired(m) => {
                        if let Some(force) = m.force_n {
                            paired.insert(m.frame_seq, (m.t_ns, force));
                        }
                    }
                    Message::Truth(t) => feed.note_sim(traj, t.frame_seq, t.wrench.force_n),
                    _ => {}
                }
            }
            // The frames `rig eval` scores: those with a paired force, in frame order.
            frames.retain(|(seq, _)| paired.contains_key(seq));
            frames.sort_by_key(|(seq, _)| *seq);
            if frames.len() < self.seq_len {
                tracing::info!(
                    "{}: {} frames, fewer than T = {}; left out as `rig eval` leaves it out",
                    f.id,
                    frames.len(),
                    self.seq_len
                );
                continue;
            }
            let stride = eval_stride(frames.len(), self.seq_len);
            let t_first = paired[&frames[0].0].0;
            let start = Instant::now();
            for (seq, (format, data)) in frames {
                if feed.stop_requested() {
                    break;
                }
                let (t_ns, force) = paired[&seq];
                feed.note_paired(traj, seq, force);
                if let Some(speed) = self.speed {
                    let due =
                        Duration::from_secs_f64(t_ns.saturating_sub(t_first) as f64 / 1e9 / speed);
                    if let Some(wait) = due.checked_sub(start.elapsed()) {
                        std::thread::sleep(wait);
                    }
                }
                if let Some(live) = &self.live {
                    live.publish(&Record::Frame {
                        seq,
                        t_ns,
                        format,
                        data: data.clone(),
                    });
                }
                feed.offer(Input {
                    traj,
                    traj_id: Some(f.id.clone()),
                    stride: Some(stride),
                    marker: Some(f.marker),
                    optics: f.optics.clone(),
                    seq,
                    t_ns,
                    image: FrameImage::Stored(format, data),
                    handed_at: Instant::now(),
                });
            }
        }
        Ok(())
    }
}

/// The simulated rig running a short plan; its camera's frames are the input.
pub struct SimRun {
    pub config: RigConfig,
    pub indenter: Indenter,
    /// Trajectories of the plan to run.
    pub limit: usize,
    /// The simulated clock's speed (1: real time, so the camera runs at its configured rate).
    pub speed_factor: f64,
    /// Where the run's records are also shown (the live view).
    pub live: Option<Arc<LiveView>>,
}

/// Removes the temporary recording directory however the run ends.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

impl SimRun {
    /// Runs the plan, handing frames to `feed`; stops early when the feed asks.
    pub fn run(self, feed: Arc<Feed>) -> anyhow::Result<()> {
        let dir = TempDir(std::env::temp_dir().join(format!(
            "rig-predict-{}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        )));
        let f = feed.clone();
        let live = self.live.clone();
        let tap: crate::run::collector::Tap = Arc::new(move |r: &Record| {
            if let Some(live) = &live {
                live.publish(r);
            }
            match r {
                Record::Frame {
                    seq,
                    t_ns,
                    format,
                    data,
                } => f.offer(Input {
                    traj: 0,
                    traj_id: None,
                    stride: None,
                    marker: None,
                    optics: None,
                    seq: *seq,
                    t_ns: *t_ns,
                    image: FrameImage::Stored(*format, data.clone()),
                    handed_at: Instant::now(),
                }),
                Record::Paired(p) => {
                    if let Some(w) = p.wrench {
                        f.note_paired(0, p.frame_seq, w.force_n);
                    }
                }
                Record::Truth {
                    frame_seq, wrench, ..
                } => f.note_sim(0, *frame_seq, wrench.force_n),
                _ => {}
            }
        });
        let opts = crate::run::RunOptions {
            limit: Some(self.limit),
            speed_factor: self.speed_factor,
            tap: Some(tap),
            ..crate::run::RunOptions::new(dir.0.clone())
        };
        let rt = tokio::runtime::Runtime::new()?;
        let summary = rt.block_on(async {
            tokio::select! {
                s = crate::run::run(&self.config, &self.indenter, &opts) => Some(s),
                _ = stopped(&feed) => None,
            }
        });
        match summary {
            None => Ok(()),
            Some(Err(e)) => Err(e.context("the simulated rig's run failed")),
            Some(Ok(s)) => match s.failure {
                Some((id, why)) if !feed.stop_requested() => {
                    bail!("the simulated rig's run failed at trajectory {id}: {why}")
                }
                _ => Ok(()),
            },
        }
    }
}

/// Resolves when the feed asks its source to stop, or on Ctrl-C (which asks it).
async fn stopped(feed: &Feed) {
    let poll = async {
        while !feed.stop_requested() {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    };
    tokio::select! {
        _ = poll => {}
        _ = tokio::signal::ctrl_c() => feed.request_stop(),
    }
}

/// A V4L2 camera, as the rig config's `[camera]` describes it.
pub struct Camera {
    pub config: RigConfig,
    /// Stop after this many frames (`None`: until Ctrl-C).
    pub frames: Option<u64>,
}

impl Camera {
    pub fn run(self, feed: Arc<Feed>) -> anyhow::Result<()> {
        let c = self.config.camera.as_ref().context(
            "the rig config has no [camera] section: `rig predict` reads the target sensor's \
             camera (see rig-configs/lab-example.toml)",
        )?;
        let rt = tokio::runtime::Runtime::new()?;
        rt.block_on(async {
            let clock = rig_core::clock::Clock::system();
            let cam = open_v4l2(c, &clock)?;
            read_camera(cam, self.frames, &feed).await
        })
    }
}

/// Reads `cam` into `feed` until it ends, `frames` have been read, or the feed asks to stop:
/// the camera half of [`Camera::run`], for any [`crate::camera::FrameSource`] (tests drive it
/// with a V4L2 source on a scripted device layer).
pub async fn read_camera(
    mut cam: Box<dyn crate::camera::FrameSource>,
    frames: Option<u64>,
    feed: &Feed,
) -> anyhow::Result<()> {
    let mut n = 0u64;
    loop {
        if frames.is_some_and(|max| n >= max) {
            return Ok(());
        }
        let frame = tokio::select! {
            f = cam.next_frame() => f,
            _ = stopped(feed) => return Ok(()),
        };
        match frame {
            Ok(frame) => {
                n += 1;
                feed.offer(Input {
                    traj: 0,
                    traj_id: None,
                    stride: None,
                    marker: None,
                    optics: None,
                    seq: frame.sequence as i64,
                    t_ns: frame.capture_t_ns.unwrap_or(frame.received_t_ns),
                    image: FrameImage::Camera(Box::new(frame)),
                    handed_at: Instant::now(),
                });
            }
            Err(crate::camera::CameraError::BadFrame(why)) => {
                tracing::warn!("camera: bad frame ({why}); skipped");
            }
            Err(crate::camera::CameraError::Ended) => return Ok(()),
            Err(e) => return Err(anyhow::Error::from(e)),
        }
    }
}

#[cfg(feature = "v4l")]
fn open_v4l2(
    c: &rig_core::config::CameraConfig,
    clock: &rig_core::clock::Clock,
) -> anyhow::Result<Box<dyn crate::camera::FrameSource>> {
    use crate::camera::v4l2;
    let device = c
        .device
        .as_deref()
        .context("camera.device is required for a V4L2 camera (e.g. /dev/video0)")?;
    Ok(Box::new(v4l2::device::open(
        device,
        clock.clone(),
        &v4l2::Request::for_camera(c),
        &v4l2::V4l2Options::default(),
    )?))
}

#[cfg(not(feature = "v4l"))]
fn open_v4l2(
    _c: &rig_core::config::CameraConfig,
    _clock: &rig_core::clock::Clock,
) -> anyhow::Result<Box<dyn crate::camera::FrameSource>> {
    bail!("this rig binary was built without V4L2 support; rebuild with `--features v4l`")
}
