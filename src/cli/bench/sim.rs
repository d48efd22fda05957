//! `rig bench sim`: what accuracy costs in time for the contact simulator.
//!
//! For each contact model and grid cell, a sphere (R = 4 mm) pressed 0.5 mm into the default gel
//! is simulated repeatedly (force only, caches warm, as the simulated rig runs it), and its force
//! is compared with the model's analytic reference:
//!
//! - `hertz`: the formula itself (no grid; its error against the exact sphere is 1.25%);
//! - `winkler`: the spring layer under the exact sphere, `k π d² (R − d/3)`;
//! - `half-space` and `layer-thick` (the layer model with h = 500 mm): Hertz;
//! - `layer` (the real 3 mm gel, no closed form): the finest grid of the run.
//!
//! Then the physics a run steps (`Effects::sensor`: the finite layer, Coulomb friction with
//! history, relaxation) along a trajectory as the plan drives it: pressed to 0.5 mm, held, slid
//! 1 mm along x, at the run's 50 Hz. Each row's time is the mean per step, its error the larger
//! relative error of the peak |Fz| and the peak shear against the sensor physics on the finest
//! grid:
//!
//! - `sensor` on each grid (the run's default, 0.4 mm, is marked in the plot);
//! - `sensor, no relaxation`: the effect left off;
//! - `half-space + friction` and `winkler + friction`: the cheaper models with the same friction
//!   and relaxation, on the default grid.
//!
//! Prints a table and writes `sim.svg` (force error against time per frame, log-log) and
//! `sim.csv` into `--out` (default `target/bench/`).

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use crate::simrig::sim::contact::analytic;
use crate::simrig::sim::{ContactModel, Effects, IndenterPose, Scene, Simulator};
use anyhow::Context;
use clap::Args;
use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;

#[derive(Debug, Args)]
pub struct SimBenchArgs {
    /// Run a small subset (two coarse grids): seconds instead of a minute.
    #[arg(long)]
    pub quick: bool,
    /// Directory for sim.svg and sim.csv.
    #[arg(long, default_value = "target/bench")]
    pub out: PathBuf,
}

/// One measured configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct SimBenchRow {
    /// Model label (`hertz`, `winkler`, `half-space`, `layer-thick`, `layer`).
    pub model: String,
    /// Grid cell, mm (`None` for the gridless Hertz).
    pub cell_mm: Option<f64>,
    /// Mean wall time per frame with warm caches, ms.
    pub ms_per_frame: f64,
    /// First frame (kernel build + FFT planning), ms.
    pub first_frame_ms: f64,
    /// |F| from the model, N.
    pub force_n: f64,
    /// Reference force, N.
    pub reference_n: f64,
    /// |F − F_ref| / F_ref (trajectory rows: the larger of the peak |Fz|'s and the peak
    /// shear's).
    pub rel_error: f64,
    /// Trajectory rows: peak shear |Ft| and its reference, N.
    pub shear_n: Option<(f64, f64)>,
}

const RADIUS_MM: f64 = 4.0;
const DEPTH_MM: f64 = 0.5;

/// Measures every model at every cell (`quick`: cells 0.4 and 0.2 mm only).
pub fn measure(quick: bool) -> anyhow::Result<Vec<SimBenchRow>> {
    let cells: &[f64] = if quick {
        &[0.4, 0.2]
    } else {
        &[0.4, 0.2, 0.1, 0.05]
    };
    let sphere = Arc::new(Indenter::builtin("sphere")?);
    let gel = ElastomerConfig::default();
    let e_star = gel.youngs_modulus_mpa / (1.0 - gel.poisson_ratio.powi(2));
    let hertz = analytic::hertz_sphere_n(e_star, RADIUS_MM, DEPTH_MM);
    let m = gel.youngs_modulus_mpa * (1.0 - gel.poisson_ratio)
        / ((1.0 + gel.poisson_ratio) * (1.0 - 2.0 * gel.poisson_ratio));
    let winkler = analytic::winkler_sphere_n(m / gel.thickness_mm, RADIUS_MM, DEPTH_MM);
    let thick = ElastomerConfig {
        thickness_mm: 500.0,
        ..gel.clone()
    };

    let mut rows = Vec::new();
    let mut push = |label: &str,
                    gel: &ElastomerConfig,
                    model: ContactModel,
                    cell: Option<f64>,
                    reference: f64|
     -> anyhow::Result<()> {
        let mut scene = Scene::new(
            gel.clone(),
            sphere.clone(),
            IndenterPose {
                depth_mm: DEPTH_MM,
                ..IndenterPose::default()
            },
        );
        scene.effects.contact = model;
        scene.effects.cell_mm = cell;
        let (force, first_ms, ms) = time_frames(&scene)?;
        rows.push(SimBenchRow {
            model: label.to_owned(),
            cell_mm: cell,
            ms_per_frame: ms,
            first_frame_ms: first_ms,
            force_n: force,
            reference_n: reference,
            rel_error: (force - reference).abs() / reference,
            shear_n: None,
        });
        Ok(())
    };
    push("hertz", &gel, ContactModel::Hertz, None, hertz)?;
    for &c in cells {
        push("winkler", &gel, ContactModel::Winkler, Some(c), winkler)?;
    }
    for &c in cells {
        push("half-space", &gel, ContactModel::HalfSpace, Some(c), hertz)?;
    }
    for &c in cells {
        push("layer-thick", &thick, ContactModel::Layer, Some(c), hertz)?;
    }
    for &c in cells {
        push("layer", &gel, ContactModel::Layer, Some(c), f64::NAN)?;
    }
    // The 3 mm layer has no closed form: compare with its finest grid.
    let finest = finest(&rows, "layer").map_or(f64::NAN, |r| r.force_n);
    for r in rows.iter_mut().filter(|r| r.model == "layer") {
        r.reference_n = finest;
        r.rel_error = (r.force_n - finest).abs() / finest;
    }
    rows.extend(measure_trajectories(quick, &sphere, &gel)?);
    Ok(rows)
}

/// The trajectory rows: the run's sensor physics on each grid, without relaxation, and the
/// cheaper models with the same effects; errors against the sensor physics on the finest grid.
fn measure_trajectories(
    quick: bool,
    sphere: &Arc<Indenter>,
    gel: &ElastomerConfig,
) -> anyhow::Result<Vec<SimBenchRow>> {
    let cells: &[f64] = if quick {
        &[0.8, 0.4]
    } else {
        &[0.8, 0.4, 0.2, 0.1]
    };
    let sensor = Effects::sensor(gel);
    let mut runs: Vec<(&str, Effects)> = cells
        .iter()
        .map(|&c| {
            (
                "sensor",
                Effects {
                    cell_mm: Some(c),
                    ..sensor.clone()
                },
            )
        })
        .collect();
    runs.push((
        "sensor, no relaxation",
        Effects {
            viscoelastic: None,
            ..sensor.clone()
        },
    ));
    for (label, model) in [
        ("half-space + friction", ContactModel::HalfSpace),
        ("winkler + friction", ContactModel::Winkler),
    ] {
        runs.push((
            label,
            Effects {
                contact: model,
                ..sensor.clone()
            },
        ));
    }
    let mut rows = Vec::new();
    for (label, effects) in runs {
        let (fz, ft, ms) = step_trajectory(sphere, gel, &effects)?;
        rows.push(SimBenchRow {
            model: label.to_owned(),
            cell_mm: effects.cell_mm,
            ms_per_frame: ms,
            first_frame_ms: f64::NAN,
            force_n: fz,
            reference_n: f64::NAN,
            rel_error: f64::NAN,
            shear_n: Some((ft, f64::NAN)),
        });
    }
    let finest = finest(&rows, "sensor").map_or((f64::NAN, f64::NAN), |r| {
        (r.force_n, r.shear_n.map_or(f64::NAN, |s| s.0))
    });
    for r in &mut rows {
        let ft = r.shear_n.map_or(f64::NAN, |s| s.0);
        r.reference_n = finest.0;
        r.shear_n = Some((ft, finest.1));
        r.rel_error =
            ((r.force_n - finest.0).abs() / finest.0).max((ft - finest.1).abs() / finest.1);
    }
    Ok(rows)
}

/// The row of `model` on its finest grid.
fn finest<'a>(rows: &'a [SimBenchRow], model: &str) -> Option<&'a SimBenchRow> {
    rows.iter()
        .filter(|r| r.model == model)
        .min_by(|a, b| a.cell_mm.partial_cmp(&b.cell_mm).expect("finite cells"))
}

/// Steps one trajectory at 50 Hz (down to [`DEPTH_MM`] at 1 mm/s, held 0.1 s, a 1 mm slide
/// along x at 1 mm/s) with `effects`: peak |Fz|, peak shear (N), mean wall time per step (ms).
fn step_trajectory(
    sphere: &Arc<Indenter>,
    gel: &ElastomerConfig,
    effects: &Effects,
) -> anyhow::Result<(f64, f64, f64)> {
    const DT_S: f64 = 0.02;
    const SPEED_MM_S: f64 = 1.0;
    const SLIDE_MM: f64 = 1.0;
    let down = (DEPTH_MM / (SPEED_MM_S * DT_S)).round() as usize;
    let slide = (SLIDE_MM / (SPEED_MM_S * DT_S)).round() as usize;
    let mut poses: Vec<(f64, f64)> = (1..=down)
        .map(|k| (DEPTH_MM * k as f64 / down as f64, 0.0))
        .collect();
    poses.extend((0..5).map(|_| (DEPTH_MM, 0.0)));
    poses.extend((1..=slide).map(|k| (DEPTH_MM, SLIDE_MM * k as f64 / slide as f64)));
    let mut scene = Scene::new(gel.clone(), sphere.clone(), IndenterPose::default());
    scene.effects = effects.clone();
    let mut sim = Simulator::new();
    let (mut fz, mut ft) = (0.0_f64, 0.0_f64);
    let t0 = Instant::now();
    for (k, &(depth, shear)) in poses.iter().enumerate() {
        scene.pose = IndenterPose {
            depth_mm: depth,
            shear_mm: [shear, 0.0],
            ..IndenterPose::default()
        };
        let out = sim.step(&scene, k as f64 * DT_S)?;
        let f = out.wrench.force_n;
        fz = fz.max(f[2].abs());
        ft = ft.max(f[0].hypot(f[1]));
    }
    let ms = t0.elapsed().as_secs_f64() * 1e3 / poses.len() as f64;
    Ok((fz, ft, ms))
}

/// Force, first-frame time and mean warm time per frame (ms).
fn time_frames(scene: &Scene) -> anyhow::Result<(f64, f64, f64)> {
    let mut sim = Simulator::new();
    let t0 = Instant::now();
    let first = sim.step(scene, 0.0)?;
    let first_ms = t0.elapsed().as_secs_f64() * 1e3;
    let force = -first.wrench.force_n[2];
    let (mut n, t1) = (0u32, Instant::now());
    while n < 3 || (t1.elapsed().as_secs_f64() < 0.5 && n < 10_000) {
        let out = sim.step(scene, 0.0)?;
        std::hint::black_box(out.wrench);
        n += 1;
    }
    Ok((force, first_ms, t1.elapsed().as_secs_f64() * 1e3 / n as f64))
}

/// Formats the rows as a Markdown table.
pub fn table(rows: &[SimBenchRow]) -> String {
    let mut s = String::from(
        "| model | cell (mm) | ms/frame | first frame (ms) | F (N) | reference (N) | error |\n\
         |---|---|---|---|---|---|---|\n",
    );
    for r in rows {
        // Trajectory rows: ms per step, peak |Fz| and peak shear against the reference's.
        let (first, force, reference) = match r.shear_n {
            Some((ft, ft_ref)) => (
                "stepped".to_owned(),
                format!("{:.5} / {ft:.5}", r.force_n),
                format!("{:.5} / {ft_ref:.5}", r.reference_n),
            ),
            None => (
                format!("{:.1}", r.first_frame_ms),
                format!("{:.5}", r.force_n),
                format!("{:.5}", r.reference_n),
            ),
        };
        s.push_str(&format!(
            "| {} | {} | {:.3} | {first} | {force} | {reference} | {:.3}% |\n",
            r.model,
            r.cell_mm.map_or("analytic".into(), |c| c.to_string()),
            r.ms_per_frame,
            r.rel_error * 100.0
        ));
    }
    s
}

/// Writes the error-against-time plot (log-log SVG).
pub fn plot(rows: &[SimBenchRow], path: &Path) -> anyhow::Result<()> {
    use plotters::prelude::*;

    use crate::chart;
    // Exact results (Hertz against itself, the finest layer grid) sit on a floor.
    const FLOOR: f64 = 1e-5;
    let pts = |r: &SimBenchRow| (r.ms_per_frame.max(1e-4), r.rel_error.max(FLOOR));
    let (mut tmin, mut tmax) = (f64::INFINITY, 0.0_f64);
    let mut emax = FLOOR * 10.0;
    for r in rows {
        let (t, e) = pts(r);
        tmin = tmin.min(t);
        tmax = tmax.max(t);
        emax = emax.max(e);
    }
    chart::svg(path, (800, 560), |root| {
        let mut chart = chart::builder(root, "rig bench sim: sphere R = 4 mm, d = 0.5 mm")
            .build_cartesian_2d(
                (tmin / 2.0..tmax * 2.0).log_scale(),
                (FLOOR / 2.0..emax * 2.0).log_scale(),
            )?;
        chart
            .configure_mesh()
            .x_desc("time per frame (ms)")
            .y_desc("relative force error")
            .draw()?;
        let models = [
            "hertz",
            "winkler",
            "half-space",
            "layer-thick",
            "layer",
            "sensor",
            "sensor, no relaxation",
            "half-space + friction",
            "winkler + friction",
        ];
        for (i, m) in models.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let series: Vec<(f64, f64)> = rows.iter().filter(|r| r.model == *m).map(pts).collect();
            if series.is_empty() {
                continue;
            }
            chart
                .draw_series(LineSeries::new(series.clone(), colour.stroke_width(2)))?
                .label(*m)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            chart.draw_series(
                series
                    .into_iter()
                    .map(|p| Circle::new(p, 4, colour.filled())),
            )?;
        }
        // The run's default: the sensor physics on its grid.
        let default = rows.iter().find(|r| {
            r.model == "sensor" && r.cell_mm == Some(crate::simrig::sim::scene::SENSOR_CELL_MM)
        });
        if let Some(r) = default {
            let p = pts(r);
            chart.draw_series([Circle::new(p, 9, BLACK.stroke_width(2))])?;
            chart.draw_series([Text::new("run default", p, ("sans-serif", 14).into_font())])?;
        }
        chart::legend(&mut chart)?;
        Ok(())
    })
}

pub fn run(args: &SimBenchArgs) -> anyhow::Result<()> {
    let rows = measure(args.quick)?;
    println!("{}", table(&rows));
    println!(
        "Trajectory rows (sensor …): the run's physics stepped down, held and slid at 50 Hz; \
         ms per step; F: peak |Fz| / peak shear; error: the larger of the two against `sensor` \
         on the finest grid.\n"
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let svg = args.out.join("sim.svg");
    plot(&rows, &svg).with_context(|| format!("cannot write {}", svg.display()))?;
    let csv = args.out.join("sim.csv");
    let mut text = String::from(
        "model,cell_mm,ms_per_frame,first_frame_ms,force_n,reference_n,shear_n,shear_reference_n,rel_error\n",
    );
    for r in &rows {
        let (ft, ft_ref) = r.shear_n.map_or((String::new(), String::new()), |(a, b)| {
            (a.to_string(), b.to_string())
        });
        text.push_str(&format!(
            "\"{}\",{},{},{},{},{},{ft},{ft_ref},{}\n",
            r.model,
            r.cell_mm.map_or(String::new(), |c| c.to_string()),
            r.ms_per_frame,
            r.first_frame_ms,
            r.force_n,
            r.reference_n,
            r.rel_error
        ));
    }
    std::fs::write(&csv, text).with_context(|| format!("cannot write {}", csv.display()))?;
    println!("wrote {} and {}", svg.display(), csv.display());
    Ok(())
}
