//! `rig predict`: a trained force model on a live camera, frame by frame: the new sensor as a
//! force sensor.
//!
//! - [`Predictor`] (this file): the library entry point a robot program embeds. It loads a
//!   model directory and turns each frame into a force estimate ([`Predictor::push`]).
//! - [`session`]: the instrument around it: frames are read on their own thread and handed
//!   to the predictor's thread through a one-frame mailbox, so inference never blocks capture;
//!   counters, latency and the summary.
//! - [`source`]: where frames come from: the simulated target sensor during a short `rig run`
//!   on the simulated rig, a V4L2 camera, or a recorded dataset replayed at its timing.
//! - [`output`]: where estimates go: CSV or JSON lines on stdout, an MCAP file, the live view.
//!
//! # A frame, from the camera to a force
//!
//! Exactly what training and `rig eval` do with a recorded frame ([`crate::train::data`]): the
//! frame is decoded to RGB, resized to the network's input (triangle filter) and put into the
//! model's modality there (marker sizes from the rig config's optics, scaled to that size), as
//! a translated training set's frames are. Any camera size with the model's aspect
//! ratio therefore works; another aspect ratio (which the resize would distort) or a frame
//! smaller than the network's input is refused with the sizes in the message.
//!
//! # The LSTM's window
//!
//! `rig eval` reads a trajectory of n frames at the stride s = ⌊n/T⌋ (the spacing of the
//! training sequences, T frames spread over a trajectory): windows {o, o+s, …, o+(T−1)s}, and
//! a window of the same stride ending on each frame past sT ([`crate::train::eval::eval_windows`]).
//! The LSTM is causal and starts from a zero state at a window's first frame, so the force
//! `rig eval` scores for frame i depends on frames i, i−s, i−2s, … only: on the
//! min(T, ⌊i/s⌋ + 1) frames at stride s ending at i. That rule needs no knowledge of n beyond
//! the stride, so the predictor applies it as frames arrive: it keeps the embeddings of the
//! last (T−1)·s + 1 frames in a ring (each frame is encoded once) and runs the LSTM over the
//! window ending at the new frame. Per frame: one encoder pass and one LSTM pass over at most T
//! embeddings.
//!
//! - **Replay** knows each trajectory's length: it uses s = ⌊n/T⌋ and restarts the ring at each
//!   trajectory ([`Predictor::start_trajectory`]), which reproduces `rig eval`'s windows frame
//!   for frame (the same forces up to float rounding; `tests/it/predict.rs` checks the MAE).
//! - **Live** does not know n: the stride defaults to ⌊n/T⌋ for the median training trajectory
//!   ([`ModelInfo::frames_per_trajectory`]), or `--stride`; the ring runs on across
//!   trajectories (the frames before a press are the history the window sees).
//!
//! # Tare
//!
//! Like an F/T sensor's bias, a model's output without contact is seldom exactly zero (the
//! sigmoid's range, a sensor whose lighting differs from the training data's). With a tare
//! ([`PredictorOptions::tare_frames`] > 0), the first frames establish the no-contact
//! reference: their estimates are averaged and subtracted from every later one, and
//! [`Predictor::push`] returns `None` for them. `rig predict` tares live sources by default
//! (like `rig run`, which tares the F/T at approach height: start without contact) and not a
//! replay, whose purpose is to reproduce `rig eval`'s numbers.

pub mod output;
pub mod session;
pub mod source;

use std::collections::VecDeque;
use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::bail;
use serde::Serialize;

use crate::train::data::{FramePrep, ImageSpec};
use crate::train::force::{ForceModel, ModelInfo};
use crate::train::modality::MarkerParams;

/// Frames whose estimates make the no-contact reference when taring (`--tare`).
pub const DEFAULT_TARE_FRAMES: usize = 8;

/// How a [`Predictor`] reads frames (default: the model's stride, no tare, the default marker
/// sizes).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PredictorOptions {
    /// Frames between the LSTM window's frames; `None`: from the model
    /// ([`default_stride`]).
    pub stride: Option<usize>,
    /// Frames whose estimates are averaged into the no-contact reference (0: no tare).
    pub tare_frames: usize,
    /// Marker sizes of the camera's images, for the `rgb` and `marker` modalities.
    pub marker: MarkerParams,
    /// The camera's optics (scale, turn, markers), for the `flow` modality: its markers are
    /// tracked from each trajectory's first frame.
    pub optics: Option<rig_core::optics::OpticsConfig>,
}

/// One force estimate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Estimate {
    /// The frame's timestamp, ns (capture time on the rig clock, or the recording's).
    pub t_ns: u64,
    /// Force on the gel, N (tared when a tare was taken).
    pub force_n: [f64; 3],
    /// The model's output before the tare, N.
    pub raw_force_n: [f64; 3],
}

/// What is known of a frame's true force, N.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Truth {
    /// The F/T wrench paired with the frame (what `rig eval` scores against).
    pub paired: Option<[f64; 3]>,
    /// Simulated rig: the simulator's force at the frame's true capture time.
    pub sim: Option<[f64; 3]>,
}

/// Where a frame's time went, for the benchmark.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StageTimes {
    /// Modality and resize to the network's input.
    pub prepare: Duration,
    /// The encoder on this frame.
    pub encode: Duration,
    /// The LSTM and MLP over the window.
    pub head: Duration,
}

/// The stride `rig eval` would read a trajectory of `frames` frames at: ⌊n/T⌋, at least 1.
pub fn eval_stride(frames: usize, seq_len: usize) -> usize {
    (frames / seq_len.max(1)).max(1)
}

/// The live stride of a model: eval's for its median training trajectory.
pub fn default_stride(info: &ModelInfo) -> anyhow::Result<usize> {
    match info.frames_per_trajectory {
        Some(n) => Ok(eval_stride(n, info.config.seq_len)),
        None => bail!(
            "the model does not record how long its training trajectories were (it was trained \
             before `rig predict` existed), so the LSTM window's stride is unknown: give \
             --stride S (`rig eval` uses ⌊n/{}⌋ for a trajectory of n frames), or retrain it",
            info.config.seq_len
        ),
    }
}

/// The library entry point: a model directory loaded, frames in, force estimates out.
pub struct Predictor {
    model: ForceModel,
    /// D+S: the factor on the shading change that brings this sensor's to the training
    /// sensor's scale ([`Self::set_shading_gain`]); 1 otherwise.
    shading_gain: f64,
    marker: MarkerParams,
    optics: Option<rig_core::optics::OpticsConfig>,
    /// How the trajectory under way's frames become the network's input (made at its first
    /// frame: the `flow` modality's reference).
    prep: Option<FramePrep>,
    stride: usize,
    /// Embeddings of the last (T−1)·stride + 1 frames since the trajectory started, oldest
    /// first.
    ring: VecDeque<Vec<f32>>,
    tare_frames: usize,
    tare_sum: [f64; 3],
    tare_seen: usize,
    offset: Option<[f64; 3]>,
    last_times: StageTimes,
}

impl Predictor {
    /// Loads the model in `dir` (`rig train force --out`). Errors say what is wrong: no
    /// model there, a model of another format version, unreadable weights, no known stride.
    pub fn load(dir: &Path, opts: PredictorOptions) -> anyhow::Result<Self> {
        let model = ForceModel::load(dir)?;
        Self::new(model, opts)
    }

    /// A predictor around a loaded model.
    pub fn new(model: ForceModel, opts: PredictorOptions) -> anyhow::Result<Self> {
        let stride = match opts.stride {
            Some(0) => bail!("the stride must be at least 1 frame"),
            Some(s) => s,
            None => default_stride(&model.info)?,
        };
        Ok(Self {
            model,
            shading_gain: 1.0,
            marker: opts.marker,
            optics: opts.optics,
            prep: None,
            stride,
            ring: VecDeque::new(),
            tare_frames: opts.tare_frames,
            tare_sum: [0.0; 3],
            tare_seen: 0,
            offset: if opts.tare_frames == 0 {
                Some([0.0; 3])
            } else {
                None
            },
            last_times: StageTimes::default(),
        })
    }

    pub fn info(&self) -> &ModelInfo {
        &self.model.info
    }

    /// The network's input: size and modality.
    pub fn spec(&self) -> ImageSpec {
        self.model.spec()
    }

    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The no-contact reference subtracted from every estimate, once taken.
    pub fn tare_offset(&self) -> Option<[f64; 3]> {
        self.offset
    }

    /// Starts a new trajectory: the window's history is dropped (the LSTM starts from a zero
    /// state at the next frame, as `rig eval` starts each trajectory), and with `stride` the
    /// window's stride changes (replay: ⌊n/T⌋ of the trajectory). The tare is kept.
    pub fn start_trajectory(&mut self, stride: Option<usize>) {
        self.ring.clear();
        self.prep = None;
        if let Some(s) = stride {
            self.stride = s.max(1);
        }
    }

    /// Marker sizes of the frames to come (a recording's own, in replay).
    pub fn set_marker(&mut self, marker: MarkerParams) {
        self.marker = marker;
        self.prep = None;
    }

    /// Optics of the frames to come (a recording's own, in replay), for the `flow` modality.
    pub fn set_optics(&mut self, optics: rig_core::optics::OpticsConfig) {
        self.optics = Some(optics);
        self.prep = None;
    }

    /// Where the last frame's time went.
    pub fn last_times(&self) -> StageTimes {
        self.last_times
    }

    /// Checks that frames of `width × height` can be given to the model: the same aspect
    /// ratio as the network's input (training resized recorded frames to it without
    /// cropping), and not smaller.
    pub fn check_frame_size(&self, width: u32, height: u32) -> anyhow::Result<()> {
        check_frame_size(&self.spec(), width, height)
    }

    /// A D+S model: scale the camera's shading change by `gain` (positive, finite), as
    /// `rig eval` does for a sensor whose shading is weaker or stronger than the training
    /// sensor's ([`crate::train::data::shading_gain`]). Other models ignore it.
    pub fn set_shading_gain(&mut self, gain: f64) -> anyhow::Result<()> {
        if !(gain > 0.0 && gain.is_finite()) {
            bail!("the shading gain must be positive and finite, not {gain}");
        }
        self.shading_gain = gain;
        Ok(())
    }

    /// One frame (RGB at the camera's resolution) and its timestamp: the force estimate, or
    /// `None` while the tare is being taken. An error (frame of the wrong size) leaves the
    /// predictor as it was.
    pub fn push(&mut self, frame: &image::RgbImage, t_ns: u64) -> anyhow::Result<Option<Estimate>> {
        self.check_frame_size(frame.width(), frame.height())?;
        let t0 = Instant::now();
        if self.prep.is_none() {
            let spec = self.spec();
            if !spec.modality.per_frame() && self.optics.is_none() {
                bail!(
                    "a {} model tracks the camera's markers: it needs the sensor's [optics] \
                     (give --config with the rig's config)",
                    spec.modality
                );
            }
            self.prep = Some(FramePrep::new(&spec, self.marker, self.optics.as_ref())?);
        }
        let mut px = self.prep.as_mut().expect("made above").next(frame)?;
        if self.model.info.spec.modality == crate::train::modality::Modality::FlowShading {
            crate::train::data::apply_shading_gain(&mut px, self.shading_gain);
        }
        self.last_times.prepare = t0.elapsed();
        Ok(self.push_prepared(&px, t_ns))
    }

    /// [`Self::push`] for a frame already in the network's modality and size
    /// (`spec().frame_bytes()` RGB bytes).
    pub fn push_prepared(&mut self, px: &[u8], t_ns: u64) -> Option<Estimate> {
        let t = self.model.info.config.seq_len.max(1);
        let t0 = Instant::now();
        let e = self
            .model
            .encode(&[px])
            .pop()
            .expect("one frame, one embedding");
        self.last_times.encode = t0.elapsed();
        self.ring.push_back(e);
        while self.ring.len() > (t - 1) * self.stride + 1 {
            self.ring.pop_front();
        }
        let t1 = Instant::now();
        let last = self.ring.len() - 1;
        let k_max = (t - 1).min(last / self.stride);
        let window: Vec<&[f32]> = (0..=k_max)
            .rev()
            .map(|k| self.ring[last - k * self.stride].as_slice())
            .collect();
        let raw = self.model.force_at_last(&window).map(|v| v as f64);
        self.last_times.head = t1.elapsed();
        let offset = match self.offset {
            Some(o) => o,
            None => {
                for (sum, r) in self.tare_sum.iter_mut().zip(raw) {
                    *sum += r;
                }
                self.tare_seen += 1;
                if self.tare_seen >= self.tare_frames {
                    let n = self.tare_seen as f64;
                    self.offset = Some(self.tare_sum.map(|s| s / n));
                }
                return None;
            }
        };
        Some(Estimate {
            t_ns,
            force_n: std::array::from_fn(|a| raw[a] - offset[a]),
            raw_force_n: raw,
        })
    }
}

/// See [`Predictor::check_frame_size`].
pub fn check_frame_size(spec: &ImageSpec, width: u32, height: u32) -> anyhow::Result<()> {
    let (mw, mh) = (spec.width, spec.height);
    let aspect = |w: u32, h: u32| w as f64 / h.max(1) as f64;
    let (cam, model) = (aspect(width, height), aspect(mw, mh));
    if width == 0 || height == 0 || ((cam - model) / model).abs() > 0.02 {
        bail!(
            "the camera gives {width}×{height} frames (aspect {cam:.3}), but the model was \
             trained on {mw}×{mh} images (aspect {model:.3}). Training put each recorded frame \
             into the modality at its own resolution and resized it to {mw}×{mh} without \
             cropping, and so does `rig predict`; a frame of another aspect ratio would be \
             distorted. Set the camera to a mode with the model's aspect ratio (e.g. {}×{}), \
             or train a model on this camera's frames",
            width,
            width as u64 * mh as u64 / mw.max(1) as u64
        );
    }
    if width < mw || height < mh {
        bail!(
            "the camera gives {width}×{height} frames, smaller than the model's {mw}×{mh} input: \
             the model would see an enlarged, blurred image it never saw in training. Set the \
             camera to at least {mw}×{mh}"
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::modality::Modality;

    fn spec() -> ImageSpec {
        ImageSpec {
            width: 64,
            height: 48,
            modality: Modality::RgbMarker,
        }
    }

    #[test]
    fn frame_sizes_of_the_models_aspect_are_accepted_others_are_explained() {
        assert!(check_frame_size(&spec(), 320, 240).is_ok());
        assert!(check_frame_size(&spec(), 64, 48).is_ok());
        assert!(check_frame_size(&spec(), 640, 480).is_ok());
        let wide = check_frame_size(&spec(), 320, 180).unwrap_err().to_string();
        assert!(wide.contains("320×180") && wide.contains("64×48"), "{wide}");
        assert!(wide.contains("aspect"), "{wide}");
        let small = check_frame_size(&spec(), 32, 24).unwrap_err().to_string();
        assert!(small.contains("smaller than the model's 64×48"), "{small}");
    }

    #[test]
    fn the_eval_stride_is_the_training_spacing() {
        assert_eq!(eval_stride(58, 8), 7);
        assert_eq!(eval_stride(5, 8), 1);
        assert_eq!(eval_stride(0, 8), 1);
    }
}
