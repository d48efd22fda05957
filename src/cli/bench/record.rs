//! `rig bench record [--seconds S] [--out DIR]`: how fast the recorder writes, on one core,
//! against the data rate of a run.
//!
//! The data of one second of a run at the default rates: 30 frames of the simulated camera at
//! 320 × 240 (rendered by the simulator: the cone pressed and sheared, every optical effect on,
//! then PNG-encoded as the run's encoder thread does; the PNG encoding is not timed, it runs on
//! its own thread in a run), 1000 F/T samples (the Nano17 at 1 kHz), 500 TCP poses (RTDE at
//! 500 Hz), 30 paired wrenches and 30 true wrenches. The benchmark writes S seconds of it through
//! one [`TrajectoryWriter`] on the calling thread (one core: zstd single-threaded), `finish`
//! (summary, fsync, rename) included, and reports the bytes per second written against the
//! data rate: the ratio is how many runs in real time one core of recording keeps up with.
//! Prints a table and writes `record.csv` into `--out`.

use std::io::Write as _;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;
use rig_core::pose::Pose;
use rig_core::wrench::Wrench;

use crate::plan::StageName;
use crate::record::{ImageFormat, Record, TrajectoryWriter};
use crate::sync::{PairedFrame, SyncStatus};

/// Arguments of `rig bench record`.
#[derive(Debug, Args)]
pub struct RecordBenchArgs {
    /// Seconds of run data to write (each rep).
    #[arg(long, value_name = "S", default_value_t = 20)]
    pub seconds: u32,
    /// Repetitions (the table shows the slowest and the fastest).
    #[arg(long, default_value_t = 3)]
    pub reps: u32,
    /// Where the CSV goes (and, while it runs, the scratch trajectory file).
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    pub out: PathBuf,
}

/// Rates of a run at the defaults.
pub const FPS: u32 = 30;
pub const FT_HZ: u32 = 1000;
pub const RTDE_HZ: u32 = 500;

/// One measurement.
#[derive(Debug, Clone)]
pub struct RecordBench {
    pub seconds: u32,
    /// Message bytes handed to the writer per second of run data.
    pub data_bytes_per_s: f64,
    /// Bytes of the finished file.
    pub file_bytes: u64,
    pub wall_s: f64,
    /// Message bytes written per wall-clock second.
    pub write_bytes_per_s: f64,
}

impl RecordBench {
    /// How many times the run's data rate the writer sustains.
    pub fn ratio(&self) -> f64 {
        self.write_bytes_per_s / self.data_bytes_per_s
    }
}

/// Frames rendered by the simulator (cone, several depths and shears), PNG-encoded.
pub fn sim_frames(n: usize) -> anyhow::Result<Vec<Vec<u8>>> {
    let config = RigConfig::sim_source();
    let mut frames = Vec::with_capacity(n);
    for k in 0..n {
        let s = k as f64 / n.max(1) as f64;
        let scene = crate::simrig::render::render_scene(
            &config,
            Indenter::builtin("cone")?,
            [0.0, 0.0],
            0.2 + 0.6 * s,
            [0.8 * s, 0.0],
        );
        let out = crate::simrig::sim::simulate(&scene).map_err(|e| anyhow::anyhow!("{e}"))?;
        let img = out
            .image
            .context("the simulator returned no image for an image scene")?;
        frames.push(crate::record::png::encode(&img)?);
    }
    Ok(frames)
}

/// One second of run data starting at `t0_ns` (frames cycled from `frames`).
fn second(t0_ns: u64, frames: &[Vec<u8>], frame_k: &mut usize) -> Vec<Record> {
    let mut out = Vec::with_capacity((FT_HZ + RTDE_HZ + 3 * FPS) as usize);
    for i in 0..FT_HZ {
        let t_ns = t0_ns + u64::from(i) * 1_000_000_000 / u64::from(FT_HZ);
        let x = f64::from(i) * 1e-3;
        out.push(Record::Wrench {
            t_ns,
            seq: Some(i64::from(i)),
            wrench: Wrench::from_array([0.1 * x.sin(), 0.05, -1.5 + 0.01 * x, 2.0, -1.0, 0.3]),
        });
        if i % (FT_HZ / RTDE_HZ) == 0 {
            out.push(Record::Pose {
                t_ns,
                pose: Pose::new(0.4, 0.1, 0.2 - 1e-4 * x, 0.0, std::f64::consts::PI, 0.0),
            });
        }
        // Exactly FPS frames a second, evenly spread.
        if (i * FPS) % FT_HZ < FPS {
            let seq = *frame_k as i64;
            let data = frames[*frame_k % frames.len()].clone();
            *frame_k += 1;
            out.push(Record::Frame {
                seq,
                t_ns,
                format: ImageFormat::Png,
                data,
            });
            let w = Wrench::from_array([0.1, 0.05, -1.5, 2.0, -1.0, 0.3]);
            out.push(Record::Paired(PairedFrame {
                frame_seq: seq,
                t_frame_ns: t_ns as f64,
                wrench: Some(w),
                sync_error_ns: Some(120_000.0),
                status: SyncStatus::Ok,
                stage: Some(StageName::Shear),
                tcp_pose: Some(Pose::new(0.4, 0.1, 0.2, 0.0, std::f64::consts::PI, 0.0)),
            }));
            out.push(Record::Truth {
                frame_seq: seq,
                t_ns,
                wrench: w,
            });
        }
    }
    out
}

/// Writes `seconds` of run data into a trajectory file in `dir` and times it.
pub fn measure(
    dir: &std::path::Path,
    frames: &[Vec<u8>],
    seconds: u32,
) -> anyhow::Result<RecordBench> {
    // The data is made before the clock starts: the benchmark times the writer only.
    let mut frame_k = 0;
    let data: Vec<Vec<Record>> = (0..seconds)
        .map(|s| second(u64::from(s) * 1_000_000_000, frames, &mut frame_k))
        .collect();
    let bytes: usize = data.iter().flatten().map(|r| r.encode().2.len()).sum();
    let start = Instant::now();
    let mut w = TrajectoryWriter::create(dir, "bench-record")?;
    for rec in data.iter().flatten() {
        w.write(rec)?;
    }
    w.finish()?;
    let wall_s = start.elapsed().as_secs_f64();
    let path = dir.join(crate::record::final_name("bench-record"));
    let file_bytes = std::fs::metadata(&path)?.len();
    std::fs::remove_file(&path)?;
    Ok(RecordBench {
        seconds,
        data_bytes_per_s: bytes as f64 / f64::from(seconds.max(1)),
        file_bytes,
        wall_s,
        write_bytes_per_s: bytes as f64 / wall_s.max(1e-9),
    })
}

pub fn run(args: &RecordBenchArgs) -> anyhow::Result<()> {
    if cfg!(debug_assertions) {
        eprintln!("note: a debug build; use `cargo run --release` for representative numbers");
    }
    anyhow::ensure!(
        args.seconds > 0 && args.reps > 0,
        "--seconds and --reps must be at least 1"
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let frames = sim_frames(FPS as usize)?;
    let mean_png = frames.iter().map(Vec::len).sum::<usize>() / frames.len();
    let mut results = Vec::new();
    for _ in 0..args.reps {
        results.push(measure(&args.out, &frames, args.seconds)?);
    }
    println!(
        "recorder write throughput, one core: {FPS} fps 320×240 PNG (sim, mean {:.1} kB), \
         F/T {FT_HZ} Hz, RTDE {RTDE_HZ} Hz, paired + true wrench per frame",
        mean_png as f64 / 1e3
    );
    println!(
        "{:>4} {:>9} {:>12} {:>12} {:>10} {:>12} {:>9}",
        "rep", "seconds", "data MB/s", "file MB", "wall s", "write MB/s", "× data"
    );
    let csv_path = args.out.join("record.csv");
    let mut csv = std::fs::File::create(&csv_path)
        .with_context(|| format!("cannot write {}", csv_path.display()))?;
    writeln!(
        csv,
        "rep,seconds,data_bytes_per_s,file_bytes,wall_s,write_bytes_per_s,ratio"
    )?;
    for (i, r) in results.iter().enumerate() {
        println!(
            "{:>4} {:>9} {:>12.2} {:>12.2} {:>10.3} {:>12.1} {:>9.1}",
            i + 1,
            r.seconds,
            r.data_bytes_per_s / 1e6,
            r.file_bytes as f64 / 1e6,
            r.wall_s,
            r.write_bytes_per_s / 1e6,
            r.ratio()
        );
        writeln!(
            csv,
            "{},{},{:.0},{},{:.4},{:.0},{:.2}",
            i + 1,
            r.seconds,
            r.data_bytes_per_s,
            r.file_bytes,
            r.wall_s,
            r.write_bytes_per_s,
            r.ratio()
        )?;
    }
    let worst = results
        .iter()
        .map(RecordBench::ratio)
        .fold(f64::INFINITY, f64::min);
    println!(
        "slowest rep: {worst:.1}× the run's data rate (goal ≥ 5×); table in {}",
        csv_path.display()
    );
    Ok(())
}
