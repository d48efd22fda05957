//! `rig bench predict`: what one frame of `rig predict` costs, on one core of this CPU.
//!
//! The deployment model (the default force config: ResNet-18 encoder of width 16, 64-d
//! embedding, LSTM, T = 8, at the trainer's default 64 × 48 input; untrained weights, whose
//! values do not change the time) fed 320 × 240 frames of the simulated target sensor as the
//! simulated camera delivers them (lossless PNG), through [`Predictor::push`] exactly as
//! `rig predict` runs it: decode, modality at the camera's resolution, resize, encoder on the
//! frame, LSTM over the window of T frames at the model's stride (for the `flow` modality the
//! markers tracked from the first frame with sim-target's optics; the frames cycle through five
//! presses, so the tracker also meets jumps a real trajectory does not make). Per modality: p50
//! and p99 of
//! each step and of the whole frame. The process is pinned to one CPU first, so burn's worker
//! threads share that core. Prints a table and writes `predict.csv` (default `target/bench/`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use clap::Args;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use crate::predict::source::marker_of;
use crate::predict::{Predictor, PredictorOptions};
use crate::train::data::ImageSpec;
use crate::train::force::{ForceConfig, ForceModel};
use crate::train::modality::Modality;

#[derive(Debug, Args)]
pub struct PredictBenchArgs {
    /// Frames measured per modality (after 10 warm-up frames).
    #[arg(long, default_value_t = 300)]
    pub frames: usize,
    /// A quick look: 40 frames, the R+M modality only.
    #[arg(long)]
    pub quick: bool,
    /// Run on every core instead of pinning the process to one.
    #[arg(long)]
    pub all_cores: bool,
    #[arg(long, value_name = "DIR", default_value = "target/bench")]
    pub out: PathBuf,
}

/// One modality's per-frame times, ms.
#[derive(Debug, Clone)]
pub struct PredictRow {
    pub modality: Modality,
    pub frames: usize,
    /// (p50, p99) of: PNG decode, modality + resize, encoder, LSTM + MLP, the whole frame.
    pub decode: (f64, f64),
    pub prepare: (f64, f64),
    pub encode: (f64, f64),
    pub head: (f64, f64),
    pub total: (f64, f64),
}

fn p50_p99(mut v: Vec<f64>) -> (f64, f64) {
    v.sort_by(f64::total_cmp);
    let at = |p: f64| v[((p * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
    (at(0.5), at(0.99))
}

/// Pins this process (the calling thread, and every thread started after it) to its first
/// allowed CPU. Returns that CPU.
fn pin_to_one_cpu() -> anyhow::Result<usize> {
    use nix::sched::{CpuSet, sched_getaffinity, sched_setaffinity};
    use nix::unistd::Pid;
    let allowed = sched_getaffinity(Pid::from_raw(0)).context("cannot read the CPU affinity")?;
    let cpu = (0..CpuSet::count())
        .find(|&c| allowed.is_set(c).unwrap_or(false))
        .context("no CPU allowed")?;
    let mut one = CpuSet::new();
    one.set(cpu).context("bad CPU index")?;
    sched_setaffinity(Pid::from_raw(0), &one).context("cannot pin to one CPU")?;
    Ok(cpu)
}

/// 320 × 240 PNG frames of the simulated target sensor: the sphere at a few depths and
/// shears (the simulator's own camera renders the same way).
fn target_frames() -> anyhow::Result<Vec<Vec<u8>>> {
    let config = RigConfig::sim_target();
    let mut frames = Vec::new();
    for (depth, shear) in [(0.0, 0.0), (0.3, 0.0), (0.6, 0.0), (0.6, 0.5), (0.9, 1.0)] {
        let scene = crate::simrig::render::render_scene(
            &config,
            Indenter::load("sphere")?,
            [0.0, 0.0],
            depth,
            [shear, 0.0],
        );
        let out = crate::simrig::sim::simulate(&scene)
            .map_err(|e| anyhow::anyhow!("cannot simulate: {e}"))?;
        let img = out.image.context("the simulator gave no image")?;
        frames.push(crate::record::png::encode(&img)?);
    }
    Ok(frames)
}

pub fn measure(modality: Modality, frames: &[Vec<u8>], n: usize) -> anyhow::Result<PredictRow> {
    let cfg = ForceConfig::default();
    let spec = ImageSpec {
        width: 64,
        height: 48,
        modality,
    };
    // A trajectory of 60 frames (25 fps, the plan's ~2.4 s press): stride 7, a window of
    // 50 frames.
    let model = ForceModel::untrained(&cfg, spec, 60);
    let mut p = Predictor::new(
        model,
        PredictorOptions {
            marker: marker_of(&RigConfig::sim_target()),
            // The flow modality tracks the frames' markers: sim-target's optics.
            optics: RigConfig::sim_target().optics,
            ..PredictorOptions::default()
        },
    )?;
    let (mut decode, mut prepare, mut encode, mut head, mut total) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let ms = |d: std::time::Duration| d.as_secs_f64() * 1e3;
    for i in 0..n + 10 {
        let png = &frames[i % frames.len()];
        let t0 = Instant::now();
        let img = crate::record::png::decode(png)?;
        let t_decode = t0.elapsed();
        p.push(&img, i as u64)?;
        let t_total = t0.elapsed();
        if i >= 10 {
            let st = p.last_times();
            decode.push(ms(t_decode));
            prepare.push(ms(st.prepare));
            encode.push(ms(st.encode));
            head.push(ms(st.head));
            total.push(ms(t_total));
        }
    }
    Ok(PredictRow {
        modality,
        frames: n,
        decode: p50_p99(decode),
        prepare: p50_p99(prepare),
        encode: p50_p99(encode),
        head: p50_p99(head),
        total: p50_p99(total),
    })
}

pub fn run(args: &PredictBenchArgs) -> anyhow::Result<()> {
    let cores = if args.all_cores {
        "all cores".to_string()
    } else {
        format!("one core (CPU {})", pin_to_one_cpu()?)
    };
    let n = if args.quick { 40 } else { args.frames.max(1) };
    let modalities: Vec<Modality> = if args.quick {
        vec![Modality::RgbMarker]
    } else {
        Modality::ANY.to_vec()
    };
    eprintln!("rendering 320×240 frames of the simulated target sensor…");
    let frames = target_frames()?;
    let mut rows = Vec::new();
    for m in modalities {
        eprintln!("{m}: {n} frames…");
        rows.push(measure(m, &frames, n)?);
    }
    println!(
        "rig predict, per frame, on {cores}: 320×240 PNG in, ResNet-18 w16 → LSTM(64), 64×48 \
         input, T = 8 (ms, p50 / p99)\n"
    );
    println!("| modality | frames | decode | modality + resize | encoder | LSTM + MLP | total |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: |");
    let cell = |v: (f64, f64)| format!("{:.2} / {:.2}", v.0, v.1);
    for r in &rows {
        println!(
            "| {} | {} | {} | {} | {} | {} | {} |",
            r.modality.paper_name(),
            r.frames,
            cell(r.decode),
            cell(r.prepare),
            cell(r.encode),
            cell(r.head),
            cell(r.total)
        );
    }
    std::fs::create_dir_all(&args.out)?;
    let mut csv = String::from(
        "modality,frames,decode_p50_ms,decode_p99_ms,prepare_p50_ms,prepare_p99_ms,\
         encode_p50_ms,encode_p99_ms,head_p50_ms,head_p99_ms,total_p50_ms,total_p99_ms\n",
    );
    for r in &rows {
        csv += &format!(
            "{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4}\n",
            r.modality.name(),
            r.frames,
            r.decode.0,
            r.decode.1,
            r.prepare.0,
            r.prepare.1,
            r.encode.0,
            r.encode.1,
            r.head.0,
            r.head.1,
            r.total.0,
            r.total.1
        );
    }
    let path = args.out.join("predict.csv");
    std::fs::write(&path, csv)?;
    println!("\n{} (target: p99 ≤ 10 ms per frame)", path.display());
    Ok(())
}
