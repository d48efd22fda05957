//! `rig bench sync`: what synchronisation accuracy costs in time.
//!
//! A known, smooth wrench (a press: normal load rising and falling as `sin²`, a shear out and
//! back) is sampled at 1 kHz by a simulated F/T device whose sample counter runs on its own
//! crystal: offset, a drift of +80 ppm, and one-way latency jitter (50 µs minimum plus an
//! exponential tail of mean 150 µs) on the way to the host. A camera takes frames at 30 Hz; their
//! stamps are mid-exposure on the host clock and arrive 3 to 7 ms later. The
//! [`Pairer`] is run with nearest, linear and cubic interpolation, each with the clock estimator
//! fitting the drift and with an offset-only fit, and every paired wrench is compared with the
//! true wrench at the frame's capture time. The table reports the force error (RMS and max of
//! the force vector error, N) and the wall time per frame of the whole pairing (wrench ingestion
//! included); an SVG plot of error against time goes to `--out` (default `target/bench/`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use rig_core::wrench::Wrench;

use crate::sync::{DeviceStamp, FrameIn, InterpMethod, Pairer, PairerConfig, WrenchIn};

#[derive(Debug, Args)]
pub struct SyncBenchArgs {
    /// A short run (10 s of simulated data instead of 120 s).
    #[arg(long)]
    pub quick: bool,
    /// Directory for the plot and the CSV.
    #[arg(long, default_value = "target/bench")]
    pub out: PathBuf,
}

/// The simulated devices.
#[derive(Debug, Clone)]
pub struct Scenario {
    pub duration_s: f64,
    pub wrench_hz: f64,
    pub frame_hz: f64,
    /// Device counter offset: the counter reads this many samples at host time 0.
    pub counter_offset: u64,
    pub drift_ppm: f64,
    pub min_latency_ns: f64,
    pub jitter_mean_ns: f64,
    /// One press lasts this long, s.
    pub press_s: f64,
    pub seed: u64,
}

impl Default for Scenario {
    fn default() -> Self {
        Self {
            duration_s: 120.0,
            wrench_hz: 1000.0,
            frame_hz: 30.0,
            // The u32 counter wraps 5 s into the run.
            counter_offset: u32::MAX as u64 - 5_000,
            drift_ppm: 80.0,
            min_latency_ns: 50_000.0,
            jitter_mean_ns: 150_000.0,
            press_s: 4.0,
            seed: 1,
        }
    }
}

/// The true wrench at host time `t_s`: normal load 0 → −8 N → 0 per press, shear ±2 N.
pub fn true_wrench(t_s: f64, press_s: f64) -> Wrench {
    let ph = std::f64::consts::PI * (t_s / press_s).rem_euclid(1.0);
    let fz = -8.0 * ph.sin().powi(2);
    let fx = 2.0 * (2.0 * ph).sin() * ph.sin();
    Wrench::from_array([fx, 0.3 * fx, fz, 0.0, 0.0, 0.0])
}

/// Result of one variant.
#[derive(Debug, Clone)]
pub struct Row {
    /// The simulated device drift, ppm.
    pub device_drift_ppm: f64,
    pub method: InterpMethod,
    pub drift: bool,
    pub frames: usize,
    pub rms_n: f64,
    pub max_n: f64,
    pub us_per_frame: f64,
    pub sync_p99_us: f64,
}

struct Rng(u64);
impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

enum Ev {
    W(WrenchIn),
    F(FrameIn, f64),
}

fn events(s: &Scenario) -> Vec<(u64, Ev)> {
    let mut rng = Rng(s.seed.max(1) * 0x9E37_79B9_7F4A_7C15);
    let mut ev = Vec::new();
    let rate = 1.0 + s.drift_ppm * 1e-6;
    // Device sample k is taken at host time k / (wrench_hz · rate): the device crystal runs fast.
    let n = (s.duration_s * s.wrench_hz) as u64;
    for k in 0..n {
        let t_s = k as f64 / (s.wrench_hz * rate);
        let lat = s.min_latency_ns - s.jitter_mean_ns * (1.0 - rng.uniform()).ln();
        let rx = (t_s * 1e9 + lat) as u64;
        ev.push((
            rx,
            Ev::W(WrenchIn {
                stamp: DeviceStamp::Counter((s.counter_offset + k) % (1 << 32)),
                host_rx_ns: rx,
                wrench: true_wrench(t_s, s.press_s),
            }),
        ));
    }
    let nf = (s.duration_s * s.frame_hz) as u64;
    for j in 1..nf {
        let t_ns = (j as f64 / s.frame_hz * 1e9) as u64;
        let rx = t_ns + 3_000_000 + (rng.uniform() * 4e6) as u64;
        ev.push((
            rx,
            Ev::F(
                FrameIn {
                    seq: j,
                    stamp: DeviceStamp::Nanos(t_ns),
                    host_rx_ns: rx,
                },
                t_ns as f64 * 1e-9,
            ),
        ));
    }
    ev.sort_by_key(|(t, _)| *t);
    ev
}

/// Run one variant over the scenario's events.
pub fn run_variant(s: &Scenario, method: InterpMethod, drift: bool) -> Row {
    let evs = events(s);
    let mut cfg = PairerConfig {
        method,
        ..Default::default()
    };
    cfg.wrench_clock.estimate_drift = drift;
    cfg.wrench_clock.min_latency_ns = s.min_latency_ns;
    // Frame stamps are on the host's monotonic clock (drift-free) and arrive at least 3 ms later.
    cfg.frame_clock.estimate_drift = false;
    cfg.frame_clock.min_latency_ns = 3e6;
    let mut truth = std::collections::HashMap::new();
    let mut p = Pairer::new(cfg);
    let mut out = Vec::new();
    let start = Instant::now();
    for (_, e) in evs {
        match e {
            Ev::W(w) => p.push_wrench(w),
            Ev::F(f, t_s) => {
                truth.insert(f.seq as i64, t_s);
                p.push_frame(f);
            }
        }
        out.extend(p.poll());
    }
    out.extend(p.finish());
    let elapsed = start.elapsed().as_secs_f64();
    let mut errs = Vec::new();
    let mut sync = Vec::new();
    for f in &out {
        let (Some(w), Some(t_s)) = (f.wrench, truth.get(&f.frame_seq)) else {
            continue;
        };
        let tw = true_wrench(*t_s, s.press_s);
        let e: f64 = (0..3)
            .map(|k| (w.force_n[k] - tw.force_n[k]).powi(2))
            .sum::<f64>()
            .sqrt();
        errs.push(e);
        if let Some(se) = f.sync_error_ns {
            sync.push(se);
        }
    }
    let n = errs.len().max(1) as f64;
    sync.sort_by(f64::total_cmp);
    Row {
        device_drift_ppm: s.drift_ppm,
        method,
        drift,
        frames: errs.len(),
        rms_n: (errs.iter().map(|e| e * e).sum::<f64>() / n).sqrt(),
        max_n: errs.iter().copied().fold(0.0, f64::max),
        us_per_frame: elapsed * 1e6 / out.len().max(1) as f64,
        sync_p99_us: sync
            .get(((sync.len() as f64 * 0.99) as usize).min(sync.len().saturating_sub(1)))
            .copied()
            .unwrap_or(0.0)
            * 1e-3,
    }
}

/// Every variant, for a device crystal running fast (+ppm) and slow (−ppm).
///
/// The sign matters to an offset-only fit: the minimum of `host − device` over the window sits at
/// the newest sample when the device runs fast (so frames near "now" see little error) and at the
/// oldest when it runs slow (error up to drift × window length).
pub fn run_all(s: &Scenario) -> Vec<Row> {
    let mut rows = Vec::new();
    for sign in [1.0, -1.0] {
        let s = Scenario {
            drift_ppm: sign * s.drift_ppm.abs(),
            ..s.clone()
        };
        for drift in [false, true] {
            for m in [
                InterpMethod::Nearest,
                InterpMethod::Linear,
                InterpMethod::Cubic,
            ] {
                rows.push(run_variant(&s, m, drift));
            }
        }
    }
    rows
}

fn label(r: &Row) -> String {
    format!(
        "{:+.0}ppm {} {}",
        r.device_drift_ppm,
        r.method.name(),
        if r.drift { "+drift" } else { "offset-only" }
    )
}

fn plot(rows: &[Row], path: &std::path::Path) -> anyhow::Result<()> {
    use plotters::prelude::*;

    use crate::chart;
    chart::svg(path, (800, 500), |root| {
        let xmax = rows.iter().map(|r| r.us_per_frame).fold(0.0, f64::max) * 1.3 + 1e-3;
        let ymin = rows
            .iter()
            .map(|r| r.rms_n)
            .fold(f64::INFINITY, f64::min)
            .max(1e-9)
            / 3.0;
        let ymax = rows.iter().map(|r| r.rms_n).fold(0.0, f64::max).max(1e-8) * 3.0;
        let mut chart = chart::builder(root, "rig bench sync: force error vs time per frame")
            .build_cartesian_2d(0.0..xmax, (ymin..ymax).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("pairing time per frame (µs)")
            .y_desc("RMS force error (N)")
            .draw()?;
        for r in rows {
            let color = match r.method {
                InterpMethod::Nearest => RED,
                InterpMethod::Linear => BLUE,
                InterpMethod::Cubic => GREEN,
            };
            let p = (r.us_per_frame, r.rms_n.max(ymin));
            if r.drift {
                chart.draw_series(std::iter::once(Circle::new(p, 6, color.filled())))?;
            } else if r.device_drift_ppm < 0.0 {
                chart.draw_series(std::iter::once(TriangleMarker::new(
                    p,
                    6,
                    color.stroke_width(2),
                )))?;
            } else {
                chart.draw_series(std::iter::once(Cross::new(p, 6, color.stroke_width(2))))?;
            }
            chart.draw_series(std::iter::once(Text::new(
                label(r),
                (p.0, p.1),
                ("sans-serif", 13),
            )))?;
        }
        Ok(())
    })
}

pub fn run(args: &SyncBenchArgs) -> anyhow::Result<()> {
    let s = Scenario {
        duration_s: if args.quick { 10.0 } else { 120.0 },
        ..Default::default()
    };
    println!(
        "sync bench: {:.0} s, wrench {} Hz (counter from {}, drift ±{} ppm, latency {:.0} µs + exp(mean {:.0} µs)), frames {} Hz",
        s.duration_s,
        s.wrench_hz,
        s.counter_offset,
        s.drift_ppm.abs(),
        s.min_latency_ns * 1e-3,
        s.jitter_mean_ns * 1e-3,
        s.frame_hz
    );
    let rows = run_all(&s);
    println!(
        "{:<30} {:>7} {:>12} {:>12} {:>14} {:>12}",
        "variant", "frames", "RMS err (N)", "max err (N)", "sync p99 (µs)", "µs/frame"
    );
    let mut csv =
        String::from("device_drift_ppm,method,drift,frames,rms_n,max_n,sync_p99_us,us_per_frame\n");
    for r in &rows {
        println!(
            "{:<30} {:>7} {:>12.2e} {:>12.2e} {:>14.1} {:>12.2}",
            label(r),
            r.frames,
            r.rms_n,
            r.max_n,
            r.sync_p99_us,
            r.us_per_frame
        );
        csv.push_str(&format!(
            "{},{},{},{},{},{},{},{}\n",
            r.device_drift_ppm,
            r.method.name(),
            r.drift,
            r.frames,
            r.rms_n,
            r.max_n,
            r.sync_p99_us,
            r.us_per_frame
        ));
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let svg = args.out.join("sync.svg");
    plot(&rows, &svg).with_context(|| format!("writing {}", svg.display()))?;
    std::fs::write(args.out.join("sync.csv"), csv)?;
    println!("plot: {}", svg.display());
    Ok(())
}
