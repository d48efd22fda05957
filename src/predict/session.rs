//! The instrument around a [`Predictor`]: a frame source on its own thread, the predictor on
//! another, one frame slot between them, and the counters a summary reports.
//!
//! **Capture never waits for inference.** The source hands each frame to a [`Feed`] and goes
//! back to its camera: the feed holds at most one frame for the predictor. A frame that
//! arrives while the predictor is busy waits in the slot; if yet another arrives before the
//! predictor took it, the newer replaces it and the replaced frame is counted as skipped (so
//! the predictor always works on the newest frame, at most one frame late, and every frame the
//! source delivered is either estimated or counted). A replay run as fast as possible is
//! lossless instead ([`Feed::new`] with `lossless`): the reader waits for the slot to empty, so
//! every recorded frame is estimated, as `rig eval` scores them all.
//!
//! **Latency** is measured per frame from the hand-off to the feed to the estimate: the wait in
//! the slot, decoding, modality, resize and the model.

use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

use serde::Serialize;

use super::output::{Output, Row};
use super::{Estimate, Predictor, Truth};
use crate::train::metrics::{self, AxisScores};
use crate::train::modality::MarkerParams;

/// A frame's pixels as the source delivered them.
#[derive(Debug, Clone)]
pub enum FrameImage {
    /// A recorded frame as stored: PNG (the simulated camera, a raw-pixel camera) or the
    /// camera's own JPEG (a replayed recording, the simulated rig's recording tap).
    Stored(crate::record::ImageFormat, Vec<u8>),
    /// A camera frame in its own pixel format (V4L2: RGB, YUYV or MJPEG).
    Camera(Box<crate::camera::Frame>),
}

impl FrameImage {
    /// The frame as RGB at the camera's resolution.
    pub fn decode(&self) -> anyhow::Result<image::RgbImage> {
        match self {
            FrameImage::Stored(format, bytes) => crate::record::png::decode_as(*format, bytes)
                .map_err(|e| anyhow::anyhow!("frame is not a readable {format:?} image: {e}")),
            FrameImage::Camera(f) => f.to_rgb().map_err(anyhow::Error::from),
        }
    }
}

/// One frame handed to the predictor.
#[derive(Debug, Clone)]
pub struct Input {
    /// Which trajectory of a replay (0 for a live camera): a new value restarts the window.
    pub traj: usize,
    /// The trajectory's name (replay), for the output.
    pub traj_id: Option<Arc<str>>,
    /// Replay: the window stride of this trajectory (⌊n/T⌋, as `rig eval` reads it).
    pub stride: Option<usize>,
    /// Replay: marker sizes of this trajectory's recording (from its manifest's optics).
    pub marker: Option<MarkerParams>,
    /// Replay: the recording's optics (for the `flow` modality).
    pub optics: Option<Arc<rig_core::optics::OpticsConfig>>,
    /// The camera's frame counter.
    pub seq: i64,
    /// The frame's timestamp, ns.
    pub t_ns: u64,
    pub image: FrameImage,
    /// When the source handed it over (set by [`Feed::offer`]).
    pub handed_at: Instant,
}

#[derive(Default)]
struct Slot {
    frame: Option<Input>,
    closed: bool,
}

/// Between the source's thread and the predictor's: one frame slot, the counters, and the
/// truths the source knows.
pub struct Feed {
    slot: Mutex<Slot>,
    cv: Condvar,
    lossless: bool,
    delivered: AtomicU64,
    skipped: AtomicU64,
    stop: AtomicBool,
    truths: Mutex<HashMap<(usize, i64), Truth>>,
}

impl Feed {
    /// A feed; `lossless`: [`Self::offer`] waits for the slot instead of replacing its frame
    /// (a replay as fast as possible).
    pub fn new(lossless: bool) -> Self {
        Self {
            slot: Mutex::new(Slot::default()),
            cv: Condvar::new(),
            lossless,
            delivered: AtomicU64::new(0),
            skipped: AtomicU64::new(0),
            stop: AtomicBool::new(false),
            truths: Mutex::new(HashMap::new()),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Slot> {
        self.slot.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Hands a frame to the predictor. Returns at once (unless lossless): a frame still
    /// waiting in the slot is replaced and counted as skipped.
    pub fn offer(&self, mut input: Input) {
        self.delivered.fetch_add(1, Ordering::Relaxed);
        let mut slot = self.lock();
        if self.lossless {
            while slot.frame.is_some() && !slot.closed {
                slot = self.cv.wait(slot).unwrap_or_else(|p| p.into_inner());
            }
        }
        // Lossless: the frame is handed over when the slot takes it (the reader's wait for
        // the predictor is not the frame's latency).
        input.handed_at = Instant::now();
        if slot.closed {
            return;
        }
        if slot.frame.replace(input).is_some() {
            self.skipped.fetch_add(1, Ordering::Relaxed);
        }
        drop(slot);
        self.cv.notify_all();
    }

    /// Records the paired F/T force of frame `seq` of trajectory `traj`.
    pub fn note_paired(&self, traj: usize, seq: i64, force_n: [f64; 3]) {
        self.truths_mut().entry((traj, seq)).or_default().paired = Some(force_n);
    }

    /// Records the simulator's true force of frame `seq` of trajectory `traj`.
    pub fn note_sim(&self, traj: usize, seq: i64, force_n: [f64; 3]) {
        self.truths_mut().entry((traj, seq)).or_default().sim = Some(force_n);
    }

    fn truths_mut(&self) -> std::sync::MutexGuard<'_, HashMap<(usize, i64), Truth>> {
        self.truths.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn truth(&self, traj: usize, seq: i64) -> Truth {
        self.truths_mut()
            .get(&(traj, seq))
            .copied()
            .unwrap_or_default()
    }

    /// The source is done: the predictor finishes the frame in the slot and ends.
    pub fn close(&self) {
        self.lock().closed = true;
        self.cv.notify_all();
    }

    /// Asks the source to stop (the predictor failed, or the user pressed Ctrl-C).
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
        self.close();
    }

    /// Whether the source should stop.
    pub fn stop_requested(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// The next frame; `None` once closed and empty.
    fn take(&self) -> Option<Input> {
        let mut slot = self.lock();
        loop {
            if let Some(f) = slot.frame.take() {
                drop(slot);
                self.cv.notify_all();
                return Some(f);
            }
            if slot.closed {
                return None;
            }
            slot = self.cv.wait(slot).unwrap_or_else(|p| p.into_inner());
        }
    }
}

/// What a session did.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    /// Frames the source delivered.
    pub frames: u64,
    /// Frames estimated (the tare's included).
    pub processed: u64,
    /// Frames whose estimates made the tare (no output).
    pub tare_frames: u64,
    /// Frames replaced in the slot before the predictor could take them.
    pub skipped: u64,
    /// Frames that could not be decoded.
    pub bad: u64,
    /// The no-contact reference subtracted, N.
    pub tare_offset_n: Option<[f64; 3]>,
    /// The window's stride at the end (replay: of the last trajectory).
    pub stride: usize,
    /// Hand-off to estimate, ms.
    pub latency_ms_p50: f64,
    pub latency_ms_p99: f64,
    pub latency_ms_max: f64,
    /// Estimates against the paired F/T force (what `rig eval` scores against).
    pub vs_paired: Option<AxisScores>,
    /// Estimates against the simulator's true force.
    pub vs_sim: Option<AxisScores>,
    /// Every estimate, in order: (trajectory, frame, estimate).
    #[serde(skip)]
    pub estimates: Vec<(usize, i64, Estimate)>,
}

impl Summary {
    /// The summary for people (stderr at exit).
    pub fn report(&self) -> String {
        let mut s = format!(
            "predict: {} frames, {} estimated ({} for the tare), {} skipped, {} undecodable; \
             window stride {}\n",
            self.frames, self.processed, self.tare_frames, self.skipped, self.bad, self.stride
        );
        s += &format!(
            "latency (frame handed over → estimate): p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms\n",
            self.latency_ms_p50, self.latency_ms_p99, self.latency_ms_max
        );
        if let Some(o) = self.tare_offset_n {
            s += &format!(
                "tare: no-contact reference ({:.3}, {:.3}, {:.3}) N subtracted\n",
                o[0], o[1], o[2]
            );
        }
        for (what, sc) in [
            ("the paired F/T force", &self.vs_paired),
            ("the simulator's true force", &self.vs_sim),
        ] {
            if let Some(sc) = sc {
                s += &format!(
                    "MAE against {what} over {} frames: Fx {:.4} Fy {:.4} Fz {:.4} N, total \
                     force {:.4} N\n",
                    sc.n, sc.mae[0], sc.mae[1], sc.mae[2], sc.total_mae
                );
            }
        }
        s
    }
}

fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let k = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[k.min(sorted.len() - 1)]
}

/// Runs `source` on its own thread and the predictor on this one until the source ends (or
/// fails, or the predictor fails: then the source is asked to stop). Estimates go to `out`.
pub fn run(
    mut predictor: Predictor,
    feed: Arc<Feed>,
    source: impl FnOnce(Arc<Feed>) -> anyhow::Result<()> + Send + 'static,
    out: &mut Output,
) -> anyhow::Result<Summary> {
    let f = feed.clone();
    let reader = std::thread::Builder::new()
        .name("predict-source".into())
        .spawn(move || {
            let r = source(f.clone());
            f.close();
            r
        })?;
    let mut latencies = Vec::new();
    let mut estimates = Vec::new();
    let mut bad = 0u64;
    let mut tare = 0u64;
    let mut cur_traj = usize::MAX;
    let mut failure = None;
    while let Some(input) = feed.take() {
        if input.traj != cur_traj {
            predictor.start_trajectory(input.stride);
            if let Some(m) = input.marker {
                predictor.set_marker(m);
            }
            if let Some(o) = &input.optics {
                predictor.set_optics((**o).clone());
            }
            cur_traj = input.traj;
        }
        let img = match input.image.decode() {
            Ok(img) => img,
            Err(e) => {
                bad += 1;
                tracing::warn!("frame {}: {e:#}; skipped", input.seq);
                continue;
            }
        };
        let est = match predictor.push(&img, input.t_ns) {
            Ok(e) => e,
            Err(e) => {
                failure = Some(e);
                feed.request_stop();
                break;
            }
        };
        latencies.push(input.handed_at.elapsed().as_secs_f64() * 1e3);
        match est {
            None => tare += 1,
            Some(est) => {
                let truth = feed.truth(input.traj, input.seq);
                if let Err(e) = out.emit(&Row {
                    traj_id: input.traj_id.as_deref(),
                    seq: input.seq,
                    estimate: &est,
                    truth: &truth,
                }) {
                    failure = Some(e);
                    feed.request_stop();
                    break;
                }
                estimates.push((input.traj, input.seq, est));
            }
        }
    }
    let source_result = reader
        .join()
        .map_err(|_| anyhow::anyhow!("the frame source's thread panicked"))?;
    out.finish()?;
    if let Some(e) = failure {
        return Err(e);
    }
    source_result?;
    let mut sorted = latencies.clone();
    sorted.sort_by(f64::total_cmp);
    let score = |pick: fn(&Truth) -> Option<[f64; 3]>| {
        let (p, t): (Vec<[f64; 3]>, Vec<[f64; 3]>) = estimates
            .iter()
            .filter_map(|(traj, seq, e)| pick(&feed.truth(*traj, *seq)).map(|t| (e.force_n, t)))
            .unzip();
        (!p.is_empty()).then(|| metrics::score(&p, &t))
    };
    Ok(Summary {
        frames: feed.delivered.load(Ordering::Relaxed),
        processed: latencies.len() as u64,
        tare_frames: tare,
        skipped: feed.skipped.load(Ordering::Relaxed),
        bad,
        tare_offset_n: predictor.tare_offset().filter(|_| tare > 0),
        stride: predictor.stride(),
        latency_ms_p50: percentile(&sorted, 50.0),
        latency_ms_p99: percentile(&sorted, 99.0),
        latency_ms_max: sorted.last().copied().unwrap_or(f64::NAN),
        vs_paired: score(|t| t.paired),
        vs_sim: score(|t| t.sim),
        estimates,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn input(seq: i64) -> Input {
        Input {
            traj: 0,
            traj_id: None,
            stride: None,
            marker: None,
            optics: None,
            seq,
            t_ns: seq as u64,
            image: FrameImage::Stored(crate::record::ImageFormat::Png, Vec::new()),
            handed_at: Instant::now(),
        }
    }

    #[test]
    fn a_frame_replaced_before_the_predictor_took_it_is_counted_skipped() {
        let feed = Feed::new(false);
        feed.offer(input(1));
        feed.offer(input(2));
        feed.offer(input(3));
        assert_eq!(feed.take().map(|i| i.seq), Some(3));
        feed.offer(input(4));
        assert_eq!(feed.take().map(|i| i.seq), Some(4));
        feed.close();
        assert!(feed.take().is_none());
        assert_eq!(feed.delivered.load(Ordering::Relaxed), 4);
        assert_eq!(feed.skipped.load(Ordering::Relaxed), 2);
    }

    #[test]
    fn a_lossless_feed_waits_for_the_predictor() {
        let feed = Arc::new(Feed::new(true));
        let f = feed.clone();
        let producer = std::thread::spawn(move || {
            for s in 0..50 {
                f.offer(input(s));
            }
            f.close();
        });
        let mut got = Vec::new();
        while let Some(i) = feed.take() {
            got.push(i.seq);
        }
        producer.join().unwrap();
        assert_eq!(got, (0..50).collect::<Vec<_>>());
        assert_eq!(feed.skipped.load(Ordering::Relaxed), 0);
    }
}
