//! `rig bench train`: what the force model's accuracy costs in time, on this machine's CPU.
//!
//! - For each encoder depth (ResNet-18, 34, 50): training throughput (sequences/s, images/s)
//!   and inference latency per frame.
//! - For a few model sizes: held-out MAE against cumulative training time, epoch by epoch.
//!
//! Data: a labelled dataset (default `runs/demo/data/source`, which `rig demo --quick` records);
//! a quarter of the trajectories (every shear direction and depth among them) is held out. Writes `train.csv` and `train.svg`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use plotters::prelude::*;

use crate::chart;

use crate::train::Progress;
use crate::train::data::{self, ImageSpec, LabelledSet};
use crate::train::eval::eval_windows;
use crate::train::force::{self, ForceConfig, ForceModel};
use crate::train::modality::Modality;
use rig_nn::Depth;

#[derive(Debug, Args)]
pub struct TrainBenchArgs {
    /// Labelled data (a `rig run` output or a directory of them).
    #[arg(long, default_value = "runs/demo/data/source")]
    pub data: PathBuf,
    /// Network input size, WIDTHxHEIGHT.
    #[arg(long, default_value = "32x24")]
    pub size: String,
    /// Epochs per MAE curve.
    #[arg(long, default_value_t = 8)]
    pub epochs: usize,
    /// Smaller measurements (a quick look, noisier numbers).
    #[arg(long)]
    pub quick: bool,
    /// Where the CSV and the plot go (`train.csv` and `train.svg`, or `speed.csv`).
    #[arg(long, value_name = "DIR", default_value = "bench-out")]
    pub out: PathBuf,
    /// Only the speed table, on random data (no dataset needed): training sequences/s and
    /// inference ms/frame of the force model per encoder depth at --size, --width and
    /// --batch, and CycleGAN iterations/s. `scripts/bench-torch` runs the same shapes in
    /// PyTorch beside it. Writes `speed.csv`.
    #[arg(long)]
    pub speed: bool,
    /// --speed: the encoder's first-stage width.
    #[arg(long, default_value_t = 16)]
    pub width: usize,
    /// --speed: sequences a batch.
    #[arg(long, default_value_t = 8)]
    pub batch: usize,
    /// --speed: timed steps per measurement.
    #[arg(long, default_value_t = 10)]
    pub steps: usize,
    /// --speed: encoder depths to measure.
    #[arg(long, value_delimiter = ',', default_value = "18,34,50")]
    pub depths: Vec<Depth>,
    /// --speed: the CycleGAN measured, NGF,RES_BLOCKS,WIDTHxHEIGHT,BATCH (the quick demo's by
    /// default); `none` to skip it.
    #[arg(long, default_value = "8,2,32x24,4")]
    pub gan: String,
}

/// `WIDTHxHEIGHT`.
fn parse_size(s: &str) -> anyhow::Result<(u32, u32)> {
    s.split_once('x')
        .and_then(|(w, h)| Some((w.parse().ok()?, h.parse().ok()?)))
        .filter(|&(w, h)| w > 0 && h > 0)
        .with_context(|| format!("{s:?}: a size is WIDTHxHEIGHT, e.g. 64x48"))
}

/// `rig bench train --speed`.
fn run_speed(args: &TrainBenchArgs) -> anyhow::Result<()> {
    use crate::train::cyclegan::{CycleGan, TranslateConfig};
    use rig_nn::GanShape;
    let (w, h) = parse_size(&args.size)?;
    let spec = ImageSpec {
        width: w,
        height: h,
        modality: Modality::RgbMarker,
    };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(threads);
    std::fs::create_dir_all(&args.out)?;
    let mut csv = String::from("what,depth,width,size,batch,threads,value,unit\n");
    println!(
        "rig, {threads} threads: force model at {w}×{h}, width {}, batch {} × T = 8\n",
        args.width, args.batch
    );
    println!("| encoder | train seq/s | train img/s | inference ms/frame |");
    println!("| --- | ---: | ---: | ---: |");
    for &depth in &args.depths {
        let cfg = ForceConfig {
            depth,
            width: args.width,
            batch: args.batch,
            ..ForceConfig::default()
        };
        let s = force::speed::step_speed(&cfg, spec, args.steps);
        println!(
            "| ResNet-{depth} | {:.1} | {:.0} | {:.3} |",
            s.sequences_per_s, s.images_per_s, s.infer_ms_per_frame
        );
        let size = format!("{w}x{h}");
        for (what, v, unit) in [
            ("train", s.sequences_per_s, "seq/s"),
            ("infer", s.infer_ms_per_frame, "ms/frame"),
        ] {
            csv += &format!(
                "{what},{depth},{},{size},{},{threads},{v:.4},{unit}\n",
                args.width, args.batch
            );
        }
    }
    if args.gan != "none" {
        let parts: Vec<&str> = args.gan.split(',').collect();
        let [ngf, blocks, size, batch] = parts[..] else {
            anyhow::bail!(
                "--gan {:?}: NGF,RES_BLOCKS,WIDTHxHEIGHT,BATCH or none",
                args.gan
            );
        };
        let num = |v: &str| {
            v.parse::<usize>()
                .ok()
                .filter(|&n| n > 0)
                .with_context(|| format!("--gan: {v:?} is not a positive number"))
        };
        let (gw, gh) = parse_size(size)?;
        let (ngf, blocks, batch) = (num(ngf)?, num(blocks)?, num(batch)?);
        let cfg = TranslateConfig {
            shape: GanShape {
                ngf,
                ndf: ngf,
                res_blocks: blocks,
                disc_layers: 3,
                down: 2,
            },
            batch,
            ..TranslateConfig::default()
        };
        let it = CycleGan::step_speed(&cfg, gw as usize, gh as usize, args.steps);
        println!("\nCycleGAN (ngf {ngf}, {blocks} blocks, {gw}×{gh}, batch {batch}): {it:.2} it/s");
        csv += &format!("gan,,{ngf},{gw}x{gh},{batch},{threads},{it:.4},it/s\n");
    }
    let path = args.out.join("speed.csv");
    std::fs::write(&path, csv)?;
    println!("\n{}", path.display());
    Ok(())
}

#[derive(Debug, Clone)]
pub struct SpeedRow {
    pub depth: Depth,
    pub width: usize,
    pub sequences_per_s: f64,
    pub images_per_s: f64,
    pub infer_ms_per_frame: f64,
}

#[derive(Debug, Clone)]
pub struct CurvePoint {
    pub model: String,
    pub epoch: usize,
    pub seconds: f64,
    pub mae: [f64; 3],
}

fn split_holdout(set: &LabelledSet) -> anyhow::Result<(LabelledSet, LabelledSet)> {
    let mut tr = (Vec::new(), Vec::new());
    let mut ho = (Vec::new(), Vec::new());
    for (i, t) in set.trajectories.iter().enumerate() {
        // A quarter, rotating through the plan's order so that every shear direction and depth
        // is both trained on and held out.
        let dst = if (i + i / 4) % 4 == 3 {
            &mut ho
        } else {
            &mut tr
        };
        dst.0.push(t.clone());
        dst.1.push(set.forces(i).to_vec());
    }
    Ok((
        LabelledSet::from_parts(set.spec, tr.0, tr.1)?,
        LabelledSet::from_parts(set.spec, ho.0, ho.1)?,
    ))
}

/// Held-out MAE per axis, N.
pub fn holdout_mae(model: &ForceModel, set: &LabelledSet) -> [f64; 3] {
    let lengths: Vec<usize> = set.trajectories.iter().map(|t| t.frames).collect();
    let windows = eval_windows(&lengths, model.info.config.seq_len);
    let seqs: Vec<_> = windows.iter().map(|(s, _)| s.clone()).collect();
    let pred = model.predict(&set.trajectories, &seqs, 16);
    let mut sum = [0f64; 3];
    let mut n = 0usize;
    for ((s, skip), p) in windows.iter().zip(pred) {
        for (k, &i) in s.frames.iter().enumerate().skip(*skip) {
            let t = set.forces(s.traj)[i];
            for a in 0..3 {
                sum[a] += (p[k][a] - t[a]).abs() as f64;
            }
            n += 1;
        }
    }
    sum.map(|s| s / n.max(1) as f64)
}

pub fn run(args: &TrainBenchArgs) -> anyhow::Result<()> {
    if args.speed {
        return run_speed(args);
    }
    let (w, h) = parse_size(&args.size)?;
    let spec = ImageSpec {
        width: w,
        height: h,
        modality: Modality::RgbMarker,
    };
    let all = data::load_labelled(&args.data, &spec, false).with_context(|| {
        format!(
            "no labelled data in {} (record some with `rig demo --quick` first)",
            args.data.display()
        )
    })?;
    let (train, holdout) = split_holdout(&all)?;
    let tmp = tempfile_dir(&args.out)?;
    let base = ForceConfig {
        epochs: 1,
        ..ForceConfig::default()
    };

    // Throughput and latency per depth.
    let mut speed = Vec::new();
    for depth in Depth::ALL {
        let width = if args.quick { 4 } else { 8 };
        let cfg = ForceConfig {
            depth,
            width,
            ..base.clone()
        };
        let dir = tmp.join(format!("speed-{depth}"));
        let r = force::train(&train, &cfg, "bench", &dir, false, Progress::Silent)?;
        let model = ForceModel::load(&dir)?;
        let lengths: Vec<usize> = holdout.trajectories.iter().map(|t| t.frames).collect();
        let seqs: Vec<_> = eval_windows(&lengths, cfg.seq_len)
            .into_iter()
            .map(|(s, _)| s)
            .collect();
        let frames = seqs.len() * cfg.seq_len;
        let t0 = Instant::now();
        let _ = model.predict(&holdout.trajectories, &seqs, 16);
        let infer = t0.elapsed().as_secs_f64() * 1e3 / frames.max(1) as f64;
        speed.push(SpeedRow {
            depth,
            width,
            sequences_per_s: r.sequences_per_s,
            images_per_s: r.images_per_s,
            infer_ms_per_frame: infer,
        });
    }

    // MAE against training time for a few sizes.
    let sizes: Vec<(Depth, usize)> = if args.quick {
        vec![(Depth::R18, 4), (Depth::R18, 8)]
    } else {
        vec![
            (Depth::R18, 4),
            (Depth::R18, 8),
            (Depth::R18, 16),
            (Depth::R34, 8),
        ]
    };
    let mut curve = Vec::new();
    for (depth, width) in sizes {
        let name = format!("resnet{depth} w{width}");
        let dir = tmp.join(format!("curve-{depth}-{width}"));
        let mut secs = 0.0;
        for epoch in 1..=args.epochs {
            let cfg = ForceConfig {
                depth,
                width,
                epochs: epoch,
                ..base.clone()
            };
            let t0 = Instant::now();
            force::train(&train, &cfg, "bench", &dir, epoch > 1, Progress::Silent)?;
            secs += t0.elapsed().as_secs_f64();
            let mae = holdout_mae(&ForceModel::load(&dir)?, &holdout);
            eprintln!("{name} epoch {epoch}: {secs:.1} s, MAE {mae:.3?} N");
            curve.push(CurvePoint {
                model: name.clone(),
                epoch,
                seconds: secs,
                mae,
            });
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);

    println!("| encoder | width | train seq/s | train img/s | inference ms/frame |");
    println!("| --- | ---: | ---: | ---: | ---: |");
    for r in &speed {
        println!(
            "| ResNet-{} | {} | {:.1} | {:.0} | {:.2} |",
            r.depth, r.width, r.sequences_per_s, r.images_per_s, r.infer_ms_per_frame
        );
    }
    println!("\n| model | epoch | training s | MAE Fx | MAE Fy | MAE Fz |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: |");
    for p in &curve {
        println!(
            "| {} | {} | {:.1} | {:.3} | {:.3} | {:.3} |",
            p.model, p.epoch, p.seconds, p.mae[0], p.mae[1], p.mae[2]
        );
    }
    std::fs::create_dir_all(&args.out)?;
    let mut csv = String::from(
        "kind,model,epoch,seconds,mae_fx,mae_fy,mae_fz,seq_per_s,img_per_s,infer_ms\n",
    );
    for r in &speed {
        csv.push_str(&format!(
            "speed,resnet{} w{},,,,,,{},{},{}\n",
            r.depth, r.width, r.sequences_per_s, r.images_per_s, r.infer_ms_per_frame
        ));
    }
    for p in &curve {
        csv.push_str(&format!(
            "curve,{},{},{},{},{},{},,,\n",
            p.model, p.epoch, p.seconds, p.mae[0], p.mae[1], p.mae[2]
        ));
    }
    std::fs::write(args.out.join("train.csv"), csv)?;
    plot(&curve, &args.out.join("train.svg"))?;
    println!(
        "wrote {} and {}",
        args.out.join("train.csv").display(),
        args.out.join("train.svg").display()
    );
    Ok(())
}

fn tempfile_dir(out: &Path) -> anyhow::Result<PathBuf> {
    let dir = out.join(format!(".bench-train-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// Mean MAE over the three axes against training time, one line per model size.
fn plot(curve: &[CurvePoint], path: &Path) -> anyhow::Result<()> {
    let mean = |p: &CurvePoint| (p.mae[0] + p.mae[1] + p.mae[2]) / 3.0;
    let tmax = curve.iter().map(|p| p.seconds).fold(1.0, f64::max);
    let emax = curve.iter().map(mean).fold(1e-3, f64::max);
    chart::svg(path, (800, 560), |root| {
        let mut chart = chart::builder(
            root,
            "rig bench train: held-out force MAE against training time (CPU)",
        )
        .build_cartesian_2d(0.0..tmax * 1.05, 0.0..emax * 1.1)?;
        chart
            .configure_mesh()
            .x_desc("training time (s)")
            .y_desc("mean MAE over Fx, Fy, Fz (N)")
            .draw()?;
        let mut names: Vec<&str> = curve.iter().map(|p| p.model.as_str()).collect();
        names.dedup();
        for (i, name) in names.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let pts: Vec<(f64, f64)> = curve
                .iter()
                .filter(|p| p.model == *name)
                .map(|p| (p.seconds, mean(p)))
                .collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))?
                .label(*name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            chart.draw_series(pts.into_iter().map(|p| Circle::new(p, 4, colour.filled())))?;
        }
        chart::legend(&mut chart)?;
        Ok(())
    })
}
