//! Cameras: the [`FrameSource`] trait and its two implementations.
//!
//! - [`v4l2`]: a UVC tactile sensor (GelSight Mini, R1.5) through Video4Linux2. The pure parts
//!   — format negotiation, choosing the capture node, CLOCK_MONOTONIC → rig clock mapping,
//!   drop detection from sequence gaps, the dedicated reading thread — are written over a small
//!   [`v4l2::DeviceLayer`] trait and tested against a fake; the real layer (the `v4l` crate)
//!   is behind the cargo feature `v4l`.
//!
//! The simulated GelSight camera implements the same trait in `crate::simrig`; what only a
//! simulator knows (the true capture time and wrench) travels with its frames in
//! [`Frame::truth`], never through the trait.
//!
//! Every frame carries the device's timestamp and sequence number, the host time it was
//! received, and the number of frames lost just before it, so the sync stage can pair it with
//! force samples and the recorder can report drops.

pub mod v4l2;

use std::future::Future;
use std::pin::Pin;

/// Pixel encoding of a frame's bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum PixelFormat {
    /// 8-bit RGB, row-major, no padding.
    Rgb8,
    /// YUV 4:2:2 packed (`Y0 U Y1 V`), what UVC cameras send uncompressed.
    Yuyv,
    /// Motion-JPEG: each frame is one JPEG image.
    Mjpeg,
}

impl PixelFormat {
    /// The V4L2 fourcc of the format.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Rgb8 => *b"RGB3",
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpeg => *b"MJPG",
        }
    }

    /// The format of a V4L2 fourcc, if supported.
    pub fn from_fourcc(fourcc: [u8; 4]) -> Option<Self> {
        match &fourcc {
            b"RGB3" => Some(PixelFormat::Rgb8),
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"MJPG" => Some(PixelFormat::Mjpeg),
            _ => None,
        }
    }
}

/// The negotiated stream format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameFormat {
    pub pixel: PixelFormat,
    pub width: u32,
    pub height: u32,
    /// Frame rate the device was set to (what it claims; the real rate may be lower).
    pub fps: f64,
}

/// One captured frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Device frame counter (V4L2 `sequence`); gaps mean lost frames.
    pub sequence: u64,
    /// Device timestamp, ns (V4L2: the buffer's CLOCK_MONOTONIC stamp, uvcvideo: start of
    /// frame; simulated camera: its own device clock).
    pub device_ts_ns: u64,
    /// Capture time on the rig's clock, when the source can map its device clock itself
    /// (V4L2 CLOCK_MONOTONIC stamps); `None`: map `device_ts_ns` with the sync estimator.
    pub capture_t_ns: Option<u64>,
    /// When the reader received the frame, rig clock ns.
    pub received_t_ns: u64,
    /// Frames lost between the previous delivered frame and this one.
    pub dropped_before: u64,
    pub format: FrameFormat,
    /// Pixel data in `format.pixel`.
    pub data: Vec<u8>,
    /// Simulated cameras only: the ground truth of this frame. Real cameras: `None`.
    pub truth: Option<FrameTruth>,
}

/// What a simulated camera knows of a frame that a real one cannot: when it was really
/// captured and the true contact wrench then, the truth a recording is checked against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTruth {
    /// True capture time, rig clock ns.
    pub capture_t_ns: u64,
    /// The true wrench on the gel at `capture_t_ns` (N, N·mm), when known.
    pub wrench: rig_core::wrench::Wrench,
}

impl Frame {
    /// The frame as an RGB image (RGB8, YUYV, or MJPEG decoded; the decoded size must match
    /// the negotiated format).
    pub fn to_rgb(&self) -> Result<image::RgbImage, CameraError> {
        let (w, h) = (self.format.width, self.format.height);
        let n = w as usize * h as usize;
        match self.format.pixel {
            PixelFormat::Rgb8 => {
                if self.data.len() < n * 3 {
                    return Err(CameraError::ShortFrame {
                        got: self.data.len(),
                        want: n * 3,
                    });
                }
                image::RgbImage::from_raw(w, h, self.data[..n * 3].to_vec()).ok_or(
                    CameraError::ShortFrame {
                        got: self.data.len(),
                        want: n * 3,
                    },
                )
            }
            PixelFormat::Yuyv => yuyv_to_rgb(&self.data, w, h),
            PixelFormat::Mjpeg => {
                let img = image::load_from_memory_with_format(&self.data, image::ImageFormat::Jpeg)
                    .map_err(|e| CameraError::BadFrame(format!("MJPEG frame: {e}")))?
                    .to_rgb8();
                if img.dimensions() != (w, h) {
                    return Err(CameraError::BadFrame(format!(
                        "MJPEG frame decodes to {}×{}, but the negotiated format is {w}×{h}",
                        img.width(),
                        img.height()
                    )));
                }
                Ok(img)
            }
        }
    }
}

impl Frame {
    /// Checks an MJPEG frame without decoding its pixels: it starts with a JPEG's start-of-image
    /// marker, ends with its end-of-image marker (zero bytes after it are allowed: some UVC
    /// cameras pad their buffers), and its frame header declares the negotiated size. That
    /// refuses the corrupt frames USB transfers make (truncated, zero-filled, another mode's)
    /// at a small part of a decode's cost. Other formats pass.
    pub fn check_jpeg(&self) -> Result<(), CameraError> {
        if self.format.pixel != PixelFormat::Mjpeg {
            return Ok(());
        }
        let bad = |why: String| Err(CameraError::BadFrame(format!("MJPEG frame: {why}")));
        let data = &self.data;
        if !data.starts_with(&[0xff, 0xd8]) {
            return bad("no start-of-image marker".into());
        }
        let end = data.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
        if end < 4 || data[end - 2..end] != [0xff, 0xd9] {
            return bad(format!(
                "no end-of-image marker: truncated ({} bytes)",
                data.len()
            ));
        }
        use image::ImageDecoder as _;
        let decoder = image::codecs::jpeg::JpegDecoder::new(std::io::Cursor::new(&data[..end]))
            .map_err(|e| CameraError::BadFrame(format!("MJPEG frame: {e}")))?;
        let (w, h) = decoder.dimensions();
        if (w, h) != (self.format.width, self.format.height) {
            return bad(format!(
                "its header says {w}×{h}, but the negotiated format is {}×{}",
                self.format.width, self.format.height
            ));
        }
        Ok(())
    }
}

/// BT.601 limited-range YUYV → RGB.
pub fn yuyv_to_rgb(data: &[u8], width: u32, height: u32) -> Result<image::RgbImage, CameraError> {
    let want = width as usize * height as usize * 2;
    if data.len() < want || width % 2 == 1 {
        return Err(CameraError::ShortFrame {
            got: data.len(),
            want,
        });
    }
    let mut out = Vec::with_capacity(want / 2 * 3);
    for q in data[..want].chunks_exact(4) {
        let (u, v) = (f32::from(q[1]) - 128.0, f32::from(q[3]) - 128.0);
        for y in [q[0], q[2]] {
            let c = 1.164 * (f32::from(y) - 16.0);
            let px = [c + 1.596 * v, c - 0.392 * u - 0.813 * v, c + 2.017 * u];
            out.extend(px.map(|x| x.round().clamp(0.0, 255.0) as u8));
        }
    }
    image::RgbImage::from_raw(width, height, out).ok_or(CameraError::ShortFrame {
        got: data.len(),
        want,
    })
}

/// Counters of a frame source.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct CaptureStats {
    /// Frames delivered to the caller.
    pub frames: u64,
    /// Frames known to be lost (sequence gaps, plus frames the reader had to discard).
    pub dropped: u64,
}

/// Why a camera cannot deliver.
#[derive(Debug, thiserror::Error)]
pub enum CameraError {
    #[error("camera {device}: {reason}")]
    Device { device: String, reason: String },
    #[error(
        "camera offers no format the rig can use (wanted {wanted}); offered: {offered}. Pick a \
         resolution/rate from the offered list in [camera]"
    )]
    NoFormat { wanted: String, offered: String },
    #[error("frame has {got} bytes, expected at least {want}")]
    ShortFrame { got: usize, want: usize },
    /// A frame whose payload cannot be decoded (corrupt JPEG, wrong size); the stream goes on.
    #[error("bad frame: {0}")]
    BadFrame(String),
    #[error("the camera stream ended")]
    Ended,
}

/// A boxed future of the next frame.
pub type FrameFuture<'a> = Pin<Box<dyn Future<Output = Result<Frame, CameraError>> + Send + 'a>>;

/// A stream of camera frames.
pub trait FrameSource: Send {
    /// The negotiated format.
    fn format(&self) -> FrameFormat;
    /// Waits for the next frame. [`CameraError::Ended`] once the source has stopped.
    fn next_frame(&mut self) -> FrameFuture<'_>;
    /// Frames delivered and lost so far.
    fn stats(&self) -> CaptureStats;
}

/// Counts lost frames from device sequence numbers (V4L2 `sequence` is a `u32` that wraps).
///
/// A gap of `n` between consecutive sequence numbers means `n − 1` frames were lost. A number
/// that goes backwards (the driver restarted the stream) starts counting afresh, losing nothing.
#[derive(Debug, Clone, Default)]
pub struct SequenceTracker {
    last: Option<u64>,
    wrap_bits: Option<u32>,
    lost: u64,
}

impl SequenceTracker {
    /// A tracker for a counter of `bits` bits (32 for V4L2); `None`: a 64-bit counter.
    pub fn new(bits: Option<u32>) -> Self {
        Self {
            last: None,
            wrap_bits: bits.filter(|&b| (1..64).contains(&b)),
            lost: 0,
        }
    }

    /// Feeds the next sequence number; returns how many frames were lost just before it.
    pub fn observe(&mut self, seq: u64) -> u64 {
        let gap = match (self.last, self.wrap_bits) {
            (None, _) => 0,
            (Some(last), Some(bits)) => {
                let modulus = 1u64 << bits;
                let d = seq.wrapping_sub(last) & (modulus - 1);
                // A "gap" of more than half the counter is a step backwards: a restart.
                if d == 0 || d > modulus / 2 { 0 } else { d - 1 }
            }
            (Some(last), None) => {
                if seq > last {
                    seq - last - 1
                } else {
                    0
                }
            }
        };
        self.last = Some(seq);
        self.lost += gap;
        gap
    }

    /// Frames lost so far.
    pub fn lost(&self) -> u64 {
        self.lost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequence_gaps_count_lost_frames_across_wraparound() {
        let mut t = SequenceTracker::new(Some(32));
        assert_eq!(t.observe(u64::from(u32::MAX) - 1), 0);
        assert_eq!(t.observe(u64::from(u32::MAX)), 0);
        assert_eq!(t.observe(2), 2); // 0 and 1 lost across the wrap
        assert_eq!(t.observe(3), 0);
        assert_eq!(t.observe(1), 0); // restart: backwards, nothing lost
        assert_eq!(t.observe(5), 3);
        assert_eq!(t.lost(), 5);
    }

    #[test]
    fn yuyv_grey_and_bad_sizes() {
        // Y = 126, U = V = 128: mid grey.
        let img = yuyv_to_rgb(&[126, 128, 126, 128], 2, 1).unwrap();
        assert_eq!(img.get_pixel(0, 0).0, [128, 128, 128]);
        assert!(yuyv_to_rgb(&[0; 3], 2, 1).is_err());
        assert!(yuyv_to_rgb(&[0; 8], 3, 1).is_err());
    }

    #[test]
    fn fourcc_round_trip() {
        for p in [PixelFormat::Rgb8, PixelFormat::Yuyv, PixelFormat::Mjpeg] {
            assert_eq!(PixelFormat::from_fourcc(p.fourcc()), Some(p));
        }
        assert_eq!(PixelFormat::from_fourcc(*b"H264"), None);
    }

    fn mjpeg_frame(data: Vec<u8>, width: u32, height: u32) -> Frame {
        Frame {
            sequence: 0,
            device_ts_ns: 0,
            capture_t_ns: None,
            received_t_ns: 0,
            dropped_before: 0,
            format: FrameFormat {
                pixel: PixelFormat::Mjpeg,
                width,
                height,
                fps: 30.0,
            },
            data,
            truth: None,
        }
    }

    #[test]
    fn mjpeg_frames_decode_and_bad_ones_are_errors() {
        // A smooth gradient, JPEG-encoded at high quality as a UVC camera would send it.
        let src = image::RgbImage::from_fn(32, 16, |x, y| {
            image::Rgb([(x * 8) as u8, (y * 16) as u8, 128])
        });
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode_image(&src)
            .unwrap();
        let got = mjpeg_frame(jpeg.clone(), 32, 16).to_rgb().unwrap();
        // JPEG is lossy: a smooth image at quality 95 comes back within a few levels.
        let worst = src
            .pixels()
            .zip(got.pixels())
            .flat_map(|(a, b)| (0..3).map(move |c| a[c].abs_diff(b[c])))
            .max()
            .unwrap();
        assert!(worst <= 8, "worst channel error {worst}");
        assert!(matches!(
            mjpeg_frame(jpeg.clone(), 64, 16).to_rgb(),
            Err(CameraError::BadFrame(_))
        ));
        assert!(matches!(
            mjpeg_frame(jpeg[..jpeg.len() / 3].to_vec(), 32, 16).to_rgb(),
            Err(CameraError::BadFrame(_))
        ));
        assert!(matches!(
            mjpeg_frame(vec![0xff, 0xd8, 1, 2, 3], 32, 16).to_rgb(),
            Err(CameraError::BadFrame(_))
        ));
    }
    #[test]
    fn mjpeg_check_refuses_truncated_padded_wrong_size_and_garbage_without_decoding() {
        let src = image::RgbImage::from_fn(32, 16, |x, y| {
            image::Rgb([(x * 8) as u8, (y * 16) as u8, 9])
        });
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 90)
            .encode_image(&src)
            .unwrap();
        assert!(mjpeg_frame(jpeg.clone(), 32, 16).check_jpeg().is_ok());
        // Zero padding after the end marker, as some UVC cameras send: still the same image.
        let mut padded = jpeg.clone();
        padded.extend([0u8; 64]);
        assert!(mjpeg_frame(padded, 32, 16).check_jpeg().is_ok());
        let refused = |data: Vec<u8>, w: u32, h: u32| {
            matches!(
                mjpeg_frame(data, w, h).check_jpeg(),
                Err(CameraError::BadFrame(_))
            )
        };
        assert!(
            refused(jpeg[..jpeg.len() - 10].to_vec(), 32, 16),
            "truncated"
        );
        assert!(refused(jpeg.clone(), 16, 32), "another mode's size");
        assert!(refused(vec![0xff, 0xd8, 1, 2, 3], 32, 16), "garbage");
        assert!(refused(vec![0u8; 512], 32, 16), "a zero-filled buffer");
        let mut no_soi = jpeg.clone();
        no_soi[1] = 0;
        assert!(refused(no_soi, 32, 16), "no start marker");
    }
}
