//! The simulated GelSight camera on a manual clock: its real rate, injected drops, jitter,
//! overruns and device clock, through the rig's `FrameSource`.

use std::sync::Arc;
use std::time::Duration;

use hardware_mocks::camera::{SimCamera, SimCameraConfig, capture_time_ns, is_dropped};
use rig::camera::{FrameSource, PixelFormat};
use rig::simrig::SimFrameSource;
use rig_core::clock::Clock;

fn solid(t_ns: u64) -> Option<image::RgbImage> {
    // Encode the capture time in the image so the test can check what was rendered when.
    let v = ((t_ns / 1_000_000) % 251) as u8;
    Some(image::RgbImage::from_pixel(8, 6, image::Rgb([v, 0, 0])))
}

async fn step_until_frame(
    src: &mut SimFrameSource,
    handle: &rig_core::clock::ClockHandle,
) -> rig::camera::Frame {
    loop {
        tokio::select! {
            f = src.next_frame() => return f.unwrap(),
            _ = tokio::time::sleep(Duration::from_millis(1)) => handle.advance(Duration::from_millis(1)),
        }
    }
}

#[tokio::test]
async fn frames_come_at_the_real_rate_with_sequence_gaps_for_drops() {
    let (clock, handle) = Clock::manual();
    let config = SimCameraConfig {
        nominal_fps: 25.0,
        actual_fps: 20.0, // slower than claimed, like a GelSight Mini behind some back ends
        drop_sequences: vec![2, 3],
        drift_ppm: 100.0,
        ..SimCameraConfig::default()
    };
    let cam = SimCamera::spawn(clock.clone(), config.clone(), Arc::new(solid)).unwrap();
    let mut src = SimFrameSource::new(cam, clock.clone(), 8, 6);
    assert_eq!(src.format().fps, 25.0);
    let mut got = Vec::new();
    for _ in 0..4 {
        let f = step_until_frame(&mut src, &handle).await;
        assert_eq!(f.format.pixel, PixelFormat::Rgb8);
        assert_eq!(f.data.len(), 8 * 6 * 3);
        got.push((
            f.sequence,
            f.dropped_before,
            f.device_ts_ns,
            f.received_t_ns,
        ));
    }
    let seqs: Vec<_> = got.iter().map(|g| (g.0, g.1)).collect();
    assert_eq!(seqs, [(0, 0), (1, 0), (4, 2), (5, 0)]);
    // Frame k is captured at (k + 1) · 50 ms; the device clock runs 100 ppm fast from its
    // offset; the rig receives it no earlier.
    for &(seq, _, dev, recv) in &got {
        let t = (seq + 1) * 50_000_000;
        assert_eq!(dev, config.device_ts_ns(t));
        assert_eq!(dev, 1_000_000_000_000 + t + t / 10_000);
        assert!(
            recv >= t && recv < t + 5_000_000,
            "{seq}: received {recv} for {t}"
        );
    }
    let stats = src.camera_stats();
    assert_eq!(stats.injected_drops, 2);
    assert_eq!(src.stats().dropped, 2);
}

#[test]
fn jitter_and_random_drops_are_seeded_and_bounded() {
    let config = SimCameraConfig {
        jitter_ns: 3_000_000,
        drop_probability: 0.2,
        seed: 42,
        ..SimCameraConfig::default()
    };
    let mut moved = 0;
    for seq in 0..500 {
        let t = capture_time_ns(&config, 0, seq);
        let nominal = (seq + 1) * 40_000_000;
        let off = t as i64 - nominal as i64;
        assert!(off.abs() <= 3_000_000, "{seq}: {off}");
        moved += usize::from(off != 0);
        assert_eq!(t, capture_time_ns(&config, 0, seq));
    }
    assert!(moved > 450);
    let drops = (0..1000).filter(|&s| is_dropped(&config, s)).count();
    assert!(
        (150..250).contains(&drops),
        "{drops} of 1000 dropped at p = 0.2"
    );
    let other = SimCameraConfig {
        seed: 43,
        ..config.clone()
    };
    assert_ne!(
        (0..100).map(|s| is_dropped(&config, s)).collect::<Vec<_>>(),
        (0..100).map(|s| is_dropped(&other, s)).collect::<Vec<_>>()
    );
}

#[tokio::test]
async fn a_slow_reader_loses_frames_as_overruns() {
    let (clock, handle) = Clock::manual();
    let config = SimCameraConfig {
        queue_len: 2,
        ..SimCameraConfig::ideal(25.0)
    };
    let mut cam = SimCamera::spawn(clock.clone(), config, Arc::new(solid)).unwrap();
    // Ten frame periods pass without anyone reading.
    for _ in 0..400 {
        handle.advance(Duration::from_millis(1));
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    for _ in 0..50 {
        tokio::task::yield_now().await;
    }
    let stats = cam.stats();
    assert_eq!(stats.delivered, 2, "{stats:?}");
    assert!(stats.overruns >= 7, "{stats:?}");
    assert_eq!(cam.try_recv().unwrap().sequence, 0);
    assert_eq!(cam.try_recv().unwrap().sequence, 1);
}

#[test]
fn bad_camera_settings_are_refused() {
    let bad = SimCameraConfig {
        actual_fps: 30.0,
        ..SimCameraConfig::ideal(25.0)
    };
    assert!(bad.validate().unwrap_err().contains("actual_fps"));
    assert!(
        SimCameraConfig {
            drop_probability: 1.5,
            ..SimCameraConfig::default()
        }
        .validate()
        .is_err()
    );
    assert!(
        SimCameraConfig {
            queue_len: 0,
            ..SimCameraConfig::default()
        }
        .validate()
        .is_err()
    );
}

/// A textured frame (a smooth gradient with printed dots), like a gel image, so JPEG's error
/// bound is the one it has on real content.
fn gel_like(_t_ns: u64) -> Option<image::RgbImage> {
    Some(image::RgbImage::from_fn(64, 48, |x, y| {
        let dot = (x % 8 == 3 || x % 8 == 4) && (y % 8 == 3 || y % 8 == 4);
        if dot {
            image::Rgb([15, 15, 18])
        } else {
            image::Rgb([110 + (x as u8) / 2, 100 + (y as u8), 130])
        }
    }))
}

#[tokio::test]
async fn an_mjpeg_camera_sends_jpeg_frames_that_are_recorded_byte_for_byte() {
    use hardware_mocks::camera::SimEncoding;
    let (clock, handle) = Clock::manual();
    let config = SimCameraConfig {
        encoding: SimEncoding::Mjpeg { quality: 90 },
        ..SimCameraConfig::ideal(25.0)
    };
    let cam = SimCamera::spawn(clock.clone(), config, Arc::new(gel_like)).unwrap();
    let mut src = SimFrameSource::new(cam, clock.clone(), 64, 48);
    assert_eq!(src.format().pixel, PixelFormat::Mjpeg);
    let f = step_until_frame(&mut src, &handle).await;
    assert_eq!(f.format.pixel, PixelFormat::Mjpeg);
    // A JPEG: SOI marker first, EOI last, and far fewer bytes than the pixels.
    assert_eq!(&f.data[..3], &[0xff, 0xd8, 0xff]);
    assert_eq!(&f.data[f.data.len() - 2..], &[0xff, 0xd9]);
    assert!(f.data.len() < 64 * 48 * 3 / 2, "{} bytes", f.data.len());
    // It decodes to the rendered image within JPEG's loss at quality 90: a few levels on
    // average (4:2:2 chroma halves the colour resolution, so the dots' edges carry the most).
    let want = gel_like(0).unwrap();
    let got = f.to_rgb().unwrap();
    let n = want.as_raw().len() as f64;
    let mae: f64 = want
        .as_raw()
        .iter()
        .zip(got.as_raw())
        .map(|(a, b)| f64::from(a.abs_diff(*b)))
        .sum::<f64>()
        / n;
    assert!(mae > 0.0 && mae < 4.0, "mean error {mae} levels");
    // The recorder keeps the camera's bytes untouched.
    let (format, stored) = rig::run::streams::stored_image(&f).unwrap();
    assert_eq!(format, rig::record::ImageFormat::Jpeg);
    assert_eq!(stored, f.data);
}

#[test]
fn a_jpeg_quality_outside_1_to_100_is_refused() {
    use hardware_mocks::camera::SimEncoding;
    for quality in [0, 101] {
        let bad = SimCameraConfig {
            encoding: SimEncoding::Mjpeg { quality },
            ..SimCameraConfig::default()
        };
        let err = bad.validate().unwrap_err();
        assert!(err.contains(&format!("JPEG quality {quality}")), "{err}");
    }
}
