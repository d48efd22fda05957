//! `rig bench render`: what each image effect costs. Frames per second of the GelSight renderer
//! at 320 × 240 (GelSight Mini) and 640 × 480 (R1.5), for shading alone, each effect alone on
//! top of it, and everything on; printed as a table and plotted as SVG (`render_fps.svg`).
//!
//! The surface field is computed once (finite-layer BEM, sphere at 0.6 mm with 0.5 mm shear),
//! so the numbers are the optics alone, rendered the way the simulated camera renders: one
//! [`Renderer`] per sensor and effect set (its untouched-gel image and buffers kept), one frame
//! after another on one thread. Release builds only give meaningful numbers.

use std::path::PathBuf;
use std::time::Instant;

use crate::simrig::sim::optics::{ImageEffects, Renderer};
use anyhow::Context;
use clap::Args;
use plotters::prelude::*;

use crate::chart;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

#[derive(Debug, Args)]
pub struct RenderBenchArgs {
    /// Fewer frames per measurement (a quick look, noisier numbers).
    #[arg(long)]
    pub quick: bool,
    /// Directory for the plot.
    #[arg(long, value_name = "DIR", default_value = "bench-out")]
    pub out: PathBuf,
}

/// One measured row.
#[derive(Debug, Clone)]
pub struct RenderResult {
    pub effects: &'static str,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
}

/// The effect sets measured: shading only, each effect alone, all.
pub fn effect_sets() -> Vec<(&'static str, ImageEffects)> {
    let base = ImageEffects::shading_only();
    let all = ImageEffects::realistic();
    vec![
        ("shading only", base),
        (
            "+ markers",
            ImageEffects {
                markers: true,
                ..base
            },
        ),
        (
            "+ shadows",
            ImageEffects {
                shadows: true,
                ..base
            },
        ),
        (
            "+ blur",
            ImageEffects {
                blur_sigma_px: all.blur_sigma_px,
                ..base
            },
        ),
        (
            "+ vignetting",
            ImageEffects {
                vignetting: all.vignetting,
                ..base
            },
        ),
        (
            "+ noise",
            ImageEffects {
                noise_sigma: all.noise_sigma,
                ..base
            },
        ),
        ("all effects", all),
    ]
}

/// Measures every effect set at both resolutions; `min_time_s` of rendering per row.
pub fn measure(min_time_s: f64) -> anyhow::Result<Vec<RenderResult>> {
    let config = RigConfig::sim_source();
    let optics = config.optics.clone().unwrap_or_default();
    let mut scene = crate::simrig::render::render_scene(
        &config,
        Indenter::builtin("sphere")?,
        [0.0, 0.0],
        0.6,
        [0.5, 0.0],
    );
    scene.effects.image = None;
    scene.effects.surface_field = true;
    let out = crate::simrig::sim::simulate(&scene).map_err(|e| anyhow::anyhow!("{e}"))?;
    let field = out
        .field
        .context("the simulator returned no surface field")?;
    let mut results = Vec::new();
    for (w, h) in [(320, 240), (640, 480)] {
        let o = optics.with_resolution(w, h);
        for (name, fx) in effect_sets() {
            // One warm-up frame, then as many as fit in the time (at least 3).
            let renderer = Renderer::new(&o, &fx);
            let _ = renderer.render(&field, 0);
            let start = Instant::now();
            let mut n = 0u64;
            while n < 3 || start.elapsed().as_secs_f64() < min_time_s {
                let _ = renderer.render(&field, n);
                n += 1;
            }
            results.push(RenderResult {
                effects: name,
                width: w,
                height: h,
                fps: n as f64 / start.elapsed().as_secs_f64(),
            });
        }
    }
    Ok(results)
}

pub fn run(args: &RenderBenchArgs) -> anyhow::Result<()> {
    if cfg!(debug_assertions) {
        eprintln!("note: a debug build; use `cargo run --release` for representative numbers");
    }
    let results = measure(if args.quick { 0.2 } else { 1.5 })?;
    println!(
        "{:<14} {:>12} {:>12}",
        "effects", "320x240 fps", "640x480 fps"
    );
    for (name, _) in effect_sets() {
        let fps = |w: u32| {
            results
                .iter()
                .find(|r| r.effects == name && r.width == w)
                .map_or(f64::NAN, |r| r.fps)
        };
        println!("{:<14} {:>12.1} {:>12.1}", name, fps(320), fps(640));
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let path = args.out.join("render_fps.svg");
    plot(&results, &path)?;
    println!("plot written to {}", path.display());
    Ok(())
}

fn plot(results: &[RenderResult], path: &std::path::Path) -> anyhow::Result<()> {
    let sets = effect_sets();
    let max_fps = results.iter().map(|r| r.fps).fold(1.0, f64::max) * 1.1;
    chart::svg(path, (900, 480), |root| {
        let mut chart = chart::builder(root, "GelSight renderer: frames per second")
            .build_cartesian_2d(0f64..sets.len() as f64, 0f64..max_fps)?;
        chart
            .configure_mesh()
            .x_labels(sets.len())
            .x_label_formatter(&|x| {
                let i = x.floor() as usize;
                sets.get(i).map_or(String::new(), |(n, _)| (*n).to_string())
            })
            .y_desc("frames per second")
            .draw()?;
        for (k, (w, colour)) in [(320u32, BLUE), (640, RED)].into_iter().enumerate() {
            let bars: Vec<_> = sets
                .iter()
                .enumerate()
                .filter_map(|(i, (name, _))| {
                    let r = results
                        .iter()
                        .find(|r| r.effects == *name && r.width == w)?;
                    let x0 = i as f64 + 0.1 + 0.4 * k as f64;
                    Some(Rectangle::new(
                        [(x0, 0.0), (x0 + 0.38, r.fps)],
                        colour.filled(),
                    ))
                })
                .collect();
            chart
                .draw_series(bars)?
                .label(if w == 320 { "320 × 240" } else { "640 × 480" })
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 10, y + 5)], colour.filled())
                });
        }
        chart::legend(&mut chart)?;
        Ok(())
    })
}
