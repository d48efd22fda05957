//! The simulated GelSight camera as a [`FrameSource`].
//!
//! `hardware_mocks::camera::SimCamera` renders frames at its (imperfect) rate on the shared
//! clock; this adapter stamps them with the rig's receive time, counts sequence gaps and hands
//! them out as the camera sent them: MJPEG frames (a GelSight Mini's stream, `[camera] format =
//! "mjpeg"`) or RGB pixels (`"raw"`). Each frame keeps the camera's own device timestamp
//! (`device_ts_ns`; `capture_t_ns` is `None`). In `rig run` the simulated camera's device clock
//! is the shared clock itself (offset 0, [`super::start`]), as a UVC camera's buffer stamps are
//! the host's CLOCK_MONOTONIC, so the run pairs frames with the stamp taken as host time
//! (`DeviceTimebase::HostNanos`); a camera with an offset needs a mapping first.
//!
//! What only the simulator knows travels with the frame, in [`Frame::truth`]: the instant the
//! frame was really captured and, when a truth source is attached ([`SimFrameSource::with_truth`]),
//! the true contact wrench at that instant. The lab's [`FrameSource`] trait knows nothing of it.

use hardware_mocks::camera::{SimCamera, SimEncoding, SimPayload};
use hardware_mocks::truth::SharedWrenchSource;
use rig_core::clock::Clock;

use crate::camera::{
    CameraError, CaptureStats, Frame, FrameFormat, FrameFuture, FrameSource, FrameTruth,
    PixelFormat, SequenceTracker,
};

/// A [`FrameSource`] over a running [`SimCamera`].
pub struct SimFrameSource {
    camera: SimCamera,
    clock: Clock,
    format: FrameFormat,
    seq: SequenceTracker,
    frames: u64,
    truth: Option<SharedWrenchSource>,
}

impl SimFrameSource {
    /// Wraps a camera rendering `width` × `height` images.
    pub fn new(camera: SimCamera, clock: Clock, width: u32, height: u32) -> Self {
        let fps = camera.config().nominal_fps;
        let pixel = match camera.config().encoding {
            SimEncoding::Raw => PixelFormat::Rgb8,
            SimEncoding::Mjpeg { .. } => PixelFormat::Mjpeg,
        };
        Self {
            camera,
            clock,
            format: FrameFormat {
                pixel,
                width,
                height,
                fps,
            },
            seq: SequenceTracker::new(None),
            frames: 0,
            truth: None,
        }
    }

    /// Attaches the true wrench of `source` at each frame's true capture time to the frame.
    pub fn with_truth(mut self, source: SharedWrenchSource) -> Self {
        self.truth = Some(source);
        self
    }

    /// The camera's own counters (delivered, injected drops, overruns).
    pub fn camera_stats(&self) -> hardware_mocks::camera::SimCameraStats {
        self.camera.stats()
    }

    /// Fault injection into the camera (stall).
    pub fn faults(&self) -> hardware_mocks::camera::CameraFaults {
        self.camera.faults()
    }
}

/// A frame's pixel format and bytes as the simulated camera sends them.
fn parts(payload: SimPayload) -> (PixelFormat, Vec<u8>) {
    match payload {
        SimPayload::Rgb(img) => (PixelFormat::Rgb8, img.into_raw()),
        SimPayload::Jpeg { bytes, .. } => (PixelFormat::Mjpeg, bytes),
    }
}

/// `image` as the simulated camera of `camera` would hand it to a run (its format: MJPEG at
/// its quality, or raw pixels), for what needs a frame's real bytes without a running camera
/// (the disk budget's measured frame).
pub fn frame_as_sent(
    camera: &rig_core::config::CameraConfig,
    image: image::RgbImage,
) -> Result<Frame, String> {
    let (width, height) = image.dimensions();
    let encoding = hardware_mocks::camera::SimCameraConfig::for_camera(camera).encoding;
    let (pixel, data) = parts(SimPayload::encode(image, encoding)?);
    Ok(Frame {
        sequence: 0,
        device_ts_ns: 0,
        capture_t_ns: None,
        received_t_ns: 0,
        dropped_before: 0,
        format: FrameFormat {
            pixel,
            width,
            height,
            fps: camera.fps,
        },
        data,
        truth: None,
    })
}

impl FrameSource for SimFrameSource {
    fn format(&self) -> FrameFormat {
        self.format
    }

    fn next_frame(&mut self) -> FrameFuture<'_> {
        Box::pin(async move {
            let f = self.camera.recv().await.ok_or(CameraError::Ended)?;
            let received_t_ns = self.clock.now_ns();
            let dropped_before = self.seq.observe(f.sequence);
            self.frames += 1;
            let truth = self.truth.as_ref().map(|src| FrameTruth {
                capture_t_ns: f.capture_t_ns,
                wrench: src.wrench_at(f.capture_t_ns),
            });
            let (width, height) = f.payload.dimensions();
            let (pixel, data) = parts(f.payload);
            Ok(Frame {
                sequence: f.sequence,
                device_ts_ns: f.device_ts_ns,
                capture_t_ns: None,
                received_t_ns,
                dropped_before,
                format: FrameFormat {
                    pixel,
                    width,
                    height,
                    ..self.format
                },
                data,
                truth,
            })
        })
    }

    fn stats(&self) -> CaptureStats {
        CaptureStats {
            frames: self.frames,
            dropped: self.seq.lost(),
        }
    }
}
