//! The real [`DeviceLayer`]: a `/dev/video*` node through the `v4l` crate, with mmap buffers.
//!
//! Buffer flags: the `v4l` crate does not expose the timestamp-type bits of `v4l2_buffer.flags`;
//! uvcvideo always stamps with CLOCK_MONOTONIC (start of frame), which is what this layer
//! assumes.

use std::io;
use std::time::Duration;

use v4l::buffer::Type;
use v4l::frameinterval::FrameIntervalEnum;
use v4l::framesize::FrameSizeEnum;
use v4l::io::traits::CaptureStream;
use v4l::prelude::{Device, MmapStream};
use v4l::video::Capture;
use v4l::video::capture::Parameters;
use v4l::{Format, FourCC};

use super::{
    CameraError, DeviceLayer, FrameFormat, NodeInfo, OfferedMode, RawFrame, Request, V4l2Options,
    V4l2Source, choose_capture_node,
};
use crate::camera::PixelFormat;
use rig_core::clock::Clock;

/// How long one dequeue waits before the reader checks for shutdown.
const DEQUEUE_TIMEOUT: Duration = Duration::from_millis(500);

/// Every video node on the system.
pub fn list_nodes() -> Vec<NodeInfo> {
    v4l::context::enum_devices()
        .into_iter()
        .filter_map(|node| {
            let path = node.path().display().to_string();
            let caps = Device::with_path(node.path()).ok()?.query_caps().ok()?;
            Some(NodeInfo {
                path,
                card: caps.card,
                bus: caps.bus,
                video_capture: caps
                    .capabilities
                    .contains(v4l::capability::Flags::VIDEO_CAPTURE),
                meta_capture: caps
                    .capabilities
                    .contains(v4l::capability::Flags::META_CAPTURE),
            })
        })
        .collect()
}

/// Opens the capture node for `configured` (its capture sibling when it names the metadata
/// node) and starts streaming `request`.
pub fn open(
    configured: &str,
    clock: Clock,
    request: &Request,
    options: &V4l2Options,
) -> Result<V4l2Source, CameraError> {
    let path = choose_capture_node(configured, &list_nodes())?;
    let layer = V4lLayer::open(&path).map_err(|e| CameraError::Device {
        device: path.clone(),
        reason: format!("cannot open: {e} (permissions? is another program using it?)"),
    })?;
    V4l2Source::open(layer, &path, clock, request, options)
}

/// A V4L2 device and, once started, its mmap stream.
pub struct V4lLayer {
    device: Device,
    stream: Option<MmapStream<'static>>,
}

impl V4lLayer {
    pub fn open(path: &str) -> io::Result<Self> {
        Ok(Self {
            device: Device::with_path(path)?,
            stream: None,
        })
    }
}

fn fps_of(interval: &v4l::Fraction) -> Option<f64> {
    (interval.numerator > 0)
        .then(|| f64::from(interval.denominator) / f64::from(interval.numerator))
}

impl DeviceLayer for V4lLayer {
    fn modes(&mut self) -> io::Result<Vec<OfferedMode>> {
        let mut out = Vec::new();
        for desc in self.device.enum_formats()? {
            let Some(pixel) = PixelFormat::from_fourcc(desc.fourcc.repr) else {
                continue;
            };
            for size in self.device.enum_framesizes(desc.fourcc)? {
                let sizes: Vec<(u32, u32)> = match size.size {
                    FrameSizeEnum::Discrete(d) => vec![(d.width, d.height)],
                    FrameSizeEnum::Stepwise(s) => {
                        vec![(s.min_width, s.min_height), (s.max_width, s.max_height)]
                    }
                };
                for (width, height) in sizes {
                    let mut fps = Vec::new();
                    for iv in self
                        .device
                        .enum_frameintervals(desc.fourcc, width, height)?
                    {
                        match iv.interval {
                            FrameIntervalEnum::Discrete(f) => fps.extend(fps_of(&f)),
                            FrameIntervalEnum::Stepwise(s) => {
                                fps.extend(fps_of(&s.min));
                                fps.extend(fps_of(&s.max));
                            }
                        }
                    }
                    out.push(OfferedMode {
                        pixel,
                        width,
                        height,
                        fps,
                    });
                }
            }
        }
        Ok(out)
    }

    fn configure(&mut self, format: &FrameFormat) -> io::Result<FrameFormat> {
        let want = Format::new(
            format.width,
            format.height,
            FourCC::new(&format.pixel.fourcc()),
        );
        let got = self.device.set_format(&want)?;
        let fps = format.fps.round().clamp(1.0, 1000.0) as u32;
        let params = self.device.set_params(&Parameters::with_fps(fps))?;
        let pixel = PixelFormat::from_fourcc(got.fourcc.repr).ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::Unsupported,
                "driver chose an unknown pixel format",
            )
        })?;
        Ok(FrameFormat {
            pixel,
            width: got.width,
            height: got.height,
            fps: fps_of(&params.interval).unwrap_or(format.fps),
        })
    }

    fn start(&mut self, buffers: u32) -> io::Result<()> {
        let mut stream = MmapStream::with_buffers(&self.device, Type::VideoCapture, buffers)?;
        stream.set_timeout(DEQUEUE_TIMEOUT);
        self.stream = Some(stream);
        Ok(())
    }

    fn dequeue(&mut self) -> io::Result<Option<RawFrame>> {
        let Some(stream) = self.stream.as_mut() else {
            return Err(io::Error::other("stream not started"));
        };
        match stream.next() {
            Ok((buf, meta)) => {
                let used = (meta.bytesused as usize).min(buf.len());
                let ts = &meta.timestamp;
                let ns = (ts.sec as i128) * 1_000_000_000 + (ts.usec as i128) * 1_000;
                Ok(Some(RawFrame {
                    data: buf[..used].to_vec(),
                    sequence: meta.sequence,
                    timestamp_ns: u64::try_from(ns).unwrap_or(0),
                    error: meta.flags.contains(v4l::buffer::Flags::ERROR),
                }))
            }
            Err(e)
                if e.kind() == io::ErrorKind::TimedOut || e.kind() == io::ErrorKind::WouldBlock =>
            {
                Ok(None)
            }
            Err(e) => Err(e),
        }
    }
}
