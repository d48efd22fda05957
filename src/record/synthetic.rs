//! Synthetic trajectories: small generated PNG frames and smooth wrench/pose streams, recorded
//! through the real [`Recorder`]. Used by the tests (dataset check, resume, the Python reader)
//! and handy to try `rig dataset check` without a rig.

use std::path::Path;

use rig_core::pose::Pose;
use rig_core::wrench::Wrench;

use super::channels::Record;
use super::manifest::{Counts, Manifest, SensorInfo};
use super::pipeline::{Recorder, RecorderConfig};
use super::writer::RecordError;
use crate::plan::StageName;
use crate::sync::{DeviceStamp, FrameIn, Pairer, PairerConfig, WrenchIn};

/// Shape of one synthetic trajectory.
#[derive(Debug, Clone)]
pub struct SyntheticSpec {
    /// Duration, ms of host time.
    pub duration_ms: u64,
    /// Frame period, ms (30 Hz ≈ 33).
    pub frame_period_ms: u64,
    /// Frame sequence numbers to leave out (simulated drops).
    pub drop_frames: Vec<u64>,
    /// Image size.
    pub width: u32,
    pub height: u32,
    /// Also record the synthetic true wrench at each recorded frame's capture time on
    /// `/sim/true_wrench`, as the simulated rig does (default: no truth channel, as a lab rig).
    pub truth: bool,
}

impl Default for SyntheticSpec {
    fn default() -> Self {
        Self {
            duration_ms: 400,
            frame_period_ms: 33,
            drop_frames: Vec::new(),
            width: 16,
            height: 12,
            truth: false,
        }
    }
}

/// A small PNG whose pixels depend on `k`.
pub fn png_frame(width: u32, height: u32, k: u64) -> Vec<u8> {
    let img = image::RgbImage::from_fn(width, height, |x, y| {
        image::Rgb([(x * 13 + k as u32) as u8, (y * 17) as u8, (k * 7) as u8])
    });
    // Encoding an in-memory RGB8 image to PNG only fails on allocation failure.
    super::png::encode(&img).unwrap_or_default()
}

/// The synthetic true force (N) at `t_ms` of a trajectory of `duration_ms`: a loading ramp,
/// a shear, its reverse and the unloading.
pub fn true_wrench(t_ms: f64, duration_ms: f64) -> Wrench {
    let s = (t_ms / duration_ms).clamp(0.0, 1.0);
    let fz = -2.0 * (std::f64::consts::PI * s).sin();
    let fx = 0.5 * (2.0 * std::f64::consts::PI * s).sin();
    Wrench::from_array([fx, 0.0, fz, 0.0, 0.0, 0.0])
}

/// Stage of a synthetic trajectory at fraction `s` of its duration.
pub fn stage_at(s: f64) -> StageName {
    match s {
        s if s < 0.25 => StageName::Down,
        s if s < 0.5 => StageName::Shear,
        s if s < 0.75 => StageName::Reverse,
        _ => StageName::Up,
    }
}

/// Record one synthetic trajectory through `rec` (already begun is not required: this calls
/// `begin` and `finish`). Returns the counts written.
pub async fn record_one(
    rec: &Recorder,
    id: &str,
    spec: &SyntheticSpec,
) -> Result<Counts, RecordError> {
    rec.begin(id).await?;
    // The synthetic links have known minimum latencies (5 ms for frames, 200 µs for the wrench).
    let mut cfg = PairerConfig::default();
    cfg.frame_clock.min_latency_ns = 5e6;
    cfg.wrench_clock.min_latency_ns = 2e5;
    let mut pairer = Pairer::new(cfg);
    let dur = spec.duration_ms as f64;
    let mut stage = None;
    let mut frame_k = 0u64;
    for ms in 0..=spec.duration_ms {
        let t_ns = ms * 1_000_000;
        let s = ms as f64 / dur;
        let st = stage_at(s);
        if stage != Some(st) {
            stage = Some(st);
            pairer.set_stage(t_ns as f64, st);
            rec.send(Record::Stage { t_ns, stage: st }).await?;
        }
        let wrench = true_wrench(ms as f64, dur);
        // The device counts samples; the host receives each 200 µs later.
        pairer.push_wrench(WrenchIn {
            stamp: DeviceStamp::Counter(ms),
            host_rx_ns: t_ns + 200_000,
            wrench,
        });
        rec.send(Record::Wrench {
            t_ns,
            seq: Some(ms as i64),
            wrench,
        })
        .await?;
        if ms % 2 == 0 {
            let pose = Pose::new(0.4, 0.1, 0.2 - 0.001 * s, 0.0, std::f64::consts::PI, 0.0);
            pairer.push_pose(t_ns as f64, pose);
            rec.send(Record::Pose { t_ns, pose }).await?;
        }
        if ms % spec.frame_period_ms == 0 {
            let seq = frame_k;
            frame_k += 1;
            if !spec.drop_frames.contains(&seq) {
                pairer.push_frame(FrameIn {
                    seq,
                    stamp: DeviceStamp::Nanos(t_ns),
                    host_rx_ns: t_ns + 5_000_000,
                });
                rec.send(Record::Frame {
                    seq: seq as i64,
                    t_ns,
                    format: super::channels::ImageFormat::Png,
                    data: png_frame(spec.width, spec.height, seq),
                })
                .await?;
                if spec.truth {
                    rec.send(Record::Truth {
                        frame_seq: seq as i64,
                        t_ns,
                        wrench,
                    })
                    .await?;
                }
            }
        }
        for p in pairer.poll() {
            rec.send(Record::Paired(p)).await?;
        }
    }
    for p in pairer.finish() {
        rec.send(Record::Paired(p)).await?;
    }
    rec.finish(pairer.stats().frames_dropped).await
}

/// Record a whole synthetic dataset of `ids` into `dir`; returns the final manifest.
pub async fn record_dataset(
    dir: &Path,
    ids: &[String],
    spec: &SyntheticSpec,
) -> Result<Manifest, RecordError> {
    let manifest = Manifest::new(
        "synthetic",
        SensorInfo {
            id: "sim-source".into(),
            role: "source".into(),
        },
        serde_json::json!({"synthetic": true}),
        serde_json::json!({"matrix": "identity"}),
        ids,
    );
    let rec = Recorder::start(dir, manifest, RecorderConfig::default())?;
    for id in ids {
        record_one(&rec, id, spec).await?;
    }
    rec.close().await
}
