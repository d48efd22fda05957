//! V4L2 capture against a fake device layer: node choice, format negotiation, CLOCK_MONOTONIC
//! mapping, drop detection and the reading thread — no hardware needed.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use rig::camera::v4l2::{
    DeviceLayer, MonotonicMap, NodeInfo, OfferedMode, RawFrame, Request, V4l2Options, V4l2Source,
    choose_capture_node, negotiate,
};
use rig::camera::{CameraError, FrameFormat, FrameSource, PixelFormat};
use rig_core::clock::Clock;

fn gelsight_mini_modes() -> Vec<OfferedMode> {
    vec![
        OfferedMode {
            pixel: PixelFormat::Yuyv,
            width: 640,
            height: 480,
            fps: vec![10.0, 5.0],
        },
        OfferedMode {
            pixel: PixelFormat::Yuyv,
            width: 320,
            height: 240,
            fps: vec![30.0, 25.0, 15.0],
        },
        OfferedMode {
            pixel: PixelFormat::Mjpeg,
            width: 640,
            height: 480,
            fps: vec![30.0, 25.0],
        },
    ]
}

#[test]
fn negotiation_prefers_a_format_that_reaches_the_rate() {
    let modes = gelsight_mini_modes();
    // 640x480 at 25: YUYV tops out at 10 fps, MJPEG reaches 25.
    let f = negotiate(&modes, &Request::new(640, 480, 25.0)).unwrap();
    assert_eq!(
        (f.pixel, f.width, f.height, f.fps),
        (PixelFormat::Mjpeg, 640, 480, 25.0)
    );
    // Even when YUYV is preferred.
    let mut req = Request::new(640, 480, 25.0);
    req.prefer = vec![PixelFormat::Yuyv, PixelFormat::Mjpeg];
    assert_eq!(negotiate(&modes, &req).unwrap().pixel, PixelFormat::Mjpeg);
    // 320x240 only in YUYV; the smallest rate at or above the request.
    let f = negotiate(&modes, &Request::new(320, 240, 20.0)).unwrap();
    assert_eq!((f.pixel, f.fps), (PixelFormat::Yuyv, 25.0));
    // Nobody reaches 60: the fastest offered.
    let f = negotiate(&modes, &Request::new(640, 480, 60.0)).unwrap();
    assert_eq!((f.pixel, f.fps), (PixelFormat::Mjpeg, 30.0));
    // An unoffered size names what is offered.
    let e = negotiate(&modes, &Request::new(800, 600, 25.0)).unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.contains("800x600") && msg.contains("Mjpeg 640x480"),
        "{msg}"
    );
}

#[test]
fn the_metadata_node_is_redirected_to_its_capture_sibling() {
    let node = |path: &str, bus: &str, cap: bool| NodeInfo {
        path: path.into(),
        card: "GelSight Mini".into(),
        bus: bus.into(),
        video_capture: cap,
        meta_capture: !cap,
    };
    let nodes = vec![
        node("/dev/video0", "usb-1", true),
        node("/dev/video1", "usb-1", false),
        node("/dev/video2", "usb-2", true),
        node("/dev/video3", "usb-2", false),
    ];
    assert_eq!(
        choose_capture_node("/dev/video0", &nodes).unwrap(),
        "/dev/video0"
    );
    assert_eq!(
        choose_capture_node("/dev/video3", &nodes).unwrap(),
        "/dev/video2"
    );
    let e = choose_capture_node("/dev/video9", &nodes)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("/dev/video9") && e.contains("/dev/video0 (GelSight Mini, capture, usb-1)"),
        "{e}"
    );
    let lonely = vec![node("/dev/video5", "usb-3", false)];
    assert!(choose_capture_node("/dev/video5", &lonely).is_err());
}

#[test]
fn monotonic_stamps_map_onto_the_rig_clock_by_the_lowest_gap() {
    // The rig clock's epoch is at CLOCK_MONOTONIC 5 s; frames are stamped at start of frame and
    // received 8-20 ms later.
    let epoch = 5_000_000_000u64;
    let mut map = MonotonicMap::new(8_000_000);
    assert_eq!(map.to_host(epoch), None);
    let latencies_ms = [15u64, 9, 20, 8, 12];
    for (k, lat) in latencies_ms.iter().enumerate() {
        let capture_host = 1_000_000_000 + k as u64 * 40_000_000;
        map.observe(epoch + capture_host, capture_host + lat * 1_000_000);
    }
    // Lowest gap: 8 ms latency, minus the configured 8 ms minimum: exact.
    assert_eq!(map.to_host(epoch + 2_000_000_000), Some(2_000_000_000));
    // A stamp before the epoch has no rig-clock time.
    assert_eq!(map.to_host(0), None);
}

/// A scripted device: modes, the format it really sets, and the buffers it returns (also used
/// by `recording_format`'s MJPEG test).
pub(crate) struct FakeDevice {
    pub(crate) modes: Vec<OfferedMode>,
    pub(crate) force_pixel: Option<PixelFormat>,
    pub(crate) frames: VecDeque<std::io::Result<Option<RawFrame>>>,
    pub(crate) log: Arc<Mutex<Vec<String>>>,
}

impl DeviceLayer for FakeDevice {
    fn modes(&mut self) -> std::io::Result<Vec<OfferedMode>> {
        Ok(self.modes.clone())
    }
    fn configure(&mut self, f: &FrameFormat) -> std::io::Result<FrameFormat> {
        self.log.lock().unwrap().push(format!(
            "configure {:?} {}x{} {}",
            f.pixel, f.width, f.height, f.fps
        ));
        Ok(FrameFormat {
            pixel: self.force_pixel.unwrap_or(f.pixel),
            ..*f
        })
    }
    fn start(&mut self, buffers: u32) -> std::io::Result<()> {
        self.log.lock().unwrap().push(format!("start {buffers}"));
        Ok(())
    }
    fn dequeue(&mut self) -> std::io::Result<Option<RawFrame>> {
        match self.frames.pop_front() {
            Some(f) => f,
            None => {
                std::thread::sleep(std::time::Duration::from_millis(1));
                Ok(None)
            }
        }
    }
}

fn raw(seq: u32, ts_ms: u64) -> std::io::Result<Option<RawFrame>> {
    Ok(Some(RawFrame {
        data: [126, 128, 126, 128].repeat(320 * 240 / 2),
        sequence: seq,
        timestamp_ns: ts_ms * 1_000_000,
        error: false,
    }))
}

#[tokio::test]
async fn the_reader_delivers_frames_and_counts_sequence_gaps() {
    let log = Arc::new(Mutex::new(Vec::new()));
    let mut frames: VecDeque<_> = [raw(10, 100), raw(11, 140), raw(14, 260), raw(15, 300)].into();
    // A corrupted buffer is a lost frame too.
    frames.push_back(Ok(Some(RawFrame {
        data: vec![],
        sequence: 16,
        timestamp_ns: 340_000_000,
        error: true,
    })));
    frames.push_back(raw(17, 380));
    let dev = FakeDevice {
        modes: gelsight_mini_modes(),
        force_pixel: None,
        frames,
        log: log.clone(),
    };
    let (clock, _handle) = Clock::manual();
    let mut src = V4l2Source::open(
        dev,
        "/dev/fake0",
        clock,
        &Request::new(320, 240, 25.0),
        &V4l2Options::default(),
    )
    .unwrap();
    assert_eq!(src.format().pixel, PixelFormat::Yuyv);
    let mut got = Vec::new();
    for _ in 0..5 {
        let f = src.next_frame().await.unwrap();
        got.push((f.sequence, f.dropped_before, f.device_ts_ns));
    }
    assert_eq!(
        got,
        [
            (10, 0, 100_000_000),
            (11, 0, 140_000_000),
            (14, 2, 260_000_000),
            (15, 0, 300_000_000),
            (17, 1, 380_000_000),
        ]
    );
    let stats = src.stats();
    assert_eq!((stats.frames, stats.dropped), (5, 3));
    assert_eq!(
        *log.lock().unwrap(),
        ["configure Yuyv 320x240 25", "start 4"]
    );
}

#[tokio::test]
async fn a_driver_that_changes_the_format_and_a_failing_device_are_errors() {
    let dev = FakeDevice {
        modes: gelsight_mini_modes(),
        force_pixel: Some(PixelFormat::Rgb8),
        frames: VecDeque::new(),
        log: Arc::default(),
    };
    let (clock, _h) = Clock::manual();
    let e = V4l2Source::open(
        dev,
        "/dev/fake0",
        clock.clone(),
        &Request::new(640, 480, 30.0),
        &V4l2Options::default(),
    )
    .err()
    .unwrap();
    assert!(matches!(e, CameraError::Device { .. }), "{e}");

    let dev = FakeDevice {
        modes: gelsight_mini_modes(),
        force_pixel: None,
        frames: [raw(0, 0), Err(std::io::Error::other("device unplugged"))].into(),
        log: Arc::default(),
    };
    let mut src = V4l2Source::open(
        dev,
        "/dev/fake0",
        clock,
        &Request::new(640, 480, 30.0),
        &V4l2Options::default(),
    )
    .unwrap();
    assert!(src.next_frame().await.is_ok());
    let e = src.next_frame().await.unwrap_err().to_string();
    assert!(e.contains("/dev/fake0") && e.contains("unplugged"), "{e}");
    assert!(matches!(src.next_frame().await, Err(CameraError::Ended)));
}
