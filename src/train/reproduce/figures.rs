//! The reproduction's figures, as PNG: the error distributions by force range (the paper's
//! violin figure) and predicted against true force over time for a few trajectories. On each
//! axis each method is shown with the modality it does best with there (seen group), named in
//! the legend: the paper's methods read R, M or R+M, the marker-displacement ones D or D+S.

use std::path::Path;

use plotters::prelude::*;

use super::findings::{Aggregate, best};
use super::methods::METHODS;
use crate::chart::{PngArea, png};
use crate::train::data::Split;
use crate::train::eval::Predictions;

const AXES: [&str; 3] = ["Fx", "Fy", "Fz"];

/// One evaluated model's predictions on the target set.
pub struct ModelPredictions {
    pub method: String,
    pub modality: String,
    pub seed: u64,
    pub p: Predictions,
}

/// The modality each method's figures show on each axis.
pub struct Shown(Vec<(String, [String; 3])>);

impl Shown {
    /// `method`'s modality on `axis`; `None` where it has no rows.
    fn of(&self, method: &str, axis: usize) -> Option<&str> {
        self.0
            .iter()
            .find(|(m, _)| m == method)
            .map(|(_, a)| a[axis].as_str())
    }
}

/// Each method's modality of lowest mean judged MAE on the seen group, per axis
/// ([`best`]).
pub fn figure_modalities(agg: &[Aggregate]) -> Shown {
    Shown(
        METHODS
            .iter()
            .filter_map(|m| {
                let b: [Option<&Aggregate>; 3] =
                    std::array::from_fn(|a| best(agg, m.name, "seen", a));
                b.iter().all(Option::is_some).then(|| {
                    (
                        m.name.to_owned(),
                        b.map(|x| x.map(|x| x.modality.clone()).unwrap_or_default()),
                    )
                })
            })
            .collect(),
    )
}

/// The colour of a method in every figure.
fn colour(method: &str) -> RGBColor {
    // "method (modality)", or the method alone.
    let name = match method.rsplit_once(" (") {
        Some((m, _)) if METHODS.iter().any(|x| x.name == m) => m,
        _ => method,
    };
    match name {
        "source-only" => RGBColor(214, 39, 40),
        "TransForce (no LSTM)" => RGBColor(44, 160, 44),
        "marker flow (no LSTM)" => RGBColor(148, 103, 189),
        "marker flow" => RGBColor(255, 127, 14),
        _ => RGBColor(31, 119, 180),
    }
}

/// Kernel density of `xs` (a Gaussian kernel, Silverman's bandwidth, at least `min_bw`) at
/// `grid`. At most 4000 of the values are used, evenly spaced in the list.
fn density(xs: &[f64], grid: &[f64], min_bw: f64) -> Vec<f64> {
    let stride = xs.len().div_ceil(4000).max(1);
    let v: Vec<f64> = xs.iter().step_by(stride).copied().collect();
    let n = v.len() as f64;
    if v.is_empty() {
        return vec![0.0; grid.len()];
    }
    let mean = v.iter().sum::<f64>() / n;
    let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
    let bw = (1.06 * sd * n.powf(-0.2)).max(min_bw);
    grid.iter()
        .map(|g| {
            v.iter()
                .map(|x| (-0.5 * ((g - x) / bw).powi(2)).exp())
                .sum::<f64>()
                / (n * bw * (2.0 * std::f64::consts::PI).sqrt())
        })
        .collect()
}

/// The `q` quantile (0..1) of `v` (sorted in place; NaN-free).
fn quantile(v: &mut [f64], q: f64) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Absolute errors of every method (seeds pooled) on `axis` with its shown modality, in
/// `group`, as (|true force|, |error|) pairs per method in [`METHODS`] order, named
/// "method (modality)".
fn errors(
    preds: &[ModelPredictions],
    shown: &Shown,
    axis: usize,
    group: &str,
    split: &Split,
) -> Vec<(String, Vec<(f64, f64)>)> {
    METHODS
        .iter()
        .filter_map(|m| Some((m.name, shown.of(m.name, axis)?)))
        .map(|(method, modality)| {
            let pts = preds
                .iter()
                .filter(|m| m.method == method && m.modality == modality)
                .flat_map(|m| {
                    (0..m.p.pred.len())
                        .filter(|&i| split.group(&m.p.indenter[i]) == group)
                        .map(|i| {
                            let (p, t) = (m.p.pred[i][axis], m.p.truth[i][axis]);
                            (t.abs(), (p - t).abs())
                        })
                })
                .filter(|(t, e)| t.is_finite() && e.is_finite())
                .collect();
            (format!("{method} ({modality})"), pts)
        })
        .collect()
}

/// Violins of the absolute error by |true force| bin (4 bins from 0 to the 99.5th percentile
/// of |true force|), one per method, rows seen and unseen, columns Fx, Fy, Fz.
pub fn error_violins(
    path: &Path,
    preds: &[ModelPredictions],
    shown: &Shown,
    split: &Split,
) -> anyhow::Result<()> {
    const BINS: usize = 4;
    let groups = ["seen", "unseen"];
    png(path, (1500, 860), |root| {
        let root = root.titled(
            "Absolute error by force range on the target sensor (all seeds; violins: density, \
             dot: median)",
            ("sans-serif", 22),
        )?;
        let panels = root.split_evenly((groups.len(), 3));
        for (gi, group) in groups.iter().enumerate() {
            for a in 0..3 {
                let panel = &panels[gi * 3 + a];
                let errs = errors(preds, shown, a, group, split);
                let mut forces: Vec<f64> =
                    errs.iter().flat_map(|e| e.1.iter().map(|p| p.0)).collect();
                let mut all_err: Vec<f64> =
                    errs.iter().flat_map(|e| e.1.iter().map(|p| p.1)).collect();
                let top = quantile(&mut forces, 0.995).max(1e-3);
                let ymax = quantile(&mut all_err, 0.98).max(1e-3) * 1.05;
                violin_panel(
                    panel,
                    &format!("{}, {group}", AXES[a]),
                    &errs,
                    (top, ymax),
                    BINS,
                    gi == 0 && a == 0,
                )?;
            }
        }
        Ok(())
    })
}

/// One panel of [`error_violins`]; `legend`: whether this panel carries the methods' legend.
fn violin_panel(
    panel: &PngArea<'_>,
    caption: &str,
    errs: &[(String, Vec<(f64, f64)>)],
    (top, ymax): (f64, f64),
    bins: usize,
    legend: bool,
) -> anyhow::Result<()> {
    let mut chart = ChartBuilder::on(panel)
        .caption(caption, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(52)
        .build_cartesian_2d(0.0..top, 0.0..ymax)?;
    chart
        .configure_mesh()
        .x_labels(bins + 1)
        .x_desc("|true force| (N)")
        .y_desc("|error| (N)")
        .label_style(("sans-serif", 14))
        .light_line_style(TRANSPARENT)
        .draw()?;
    let width = top / bins as f64;
    let slot = width / (errs.len() as f64 + 0.5);
    let grid: Vec<f64> = (0..=60).map(|k| ymax * k as f64 / 60.0).collect();
    for b in 0..bins {
        let (lo, hi) = (b as f64 * width, (b + 1) as f64 * width);
        for (k, (method, pts)) in errs.iter().enumerate() {
            let mut e: Vec<f64> = pts
                .iter()
                .filter(|(t, _)| *t >= lo && (*t < hi || b + 1 == bins && *t <= hi))
                .map(|p| p.1)
                .collect();
            if e.len() < 5 {
                continue;
            }
            let d = density(&e, &grid, ymax / 200.0);
            let dmax = d.iter().copied().fold(0.0, f64::max);
            if dmax <= 0.0 {
                continue;
            }
            let centre = lo + slot * (k as f64 + 0.75);
            let half = 0.45 * slot;
            // The violin spans the errors' own range, not the whole axis.
            let shown = |&(_, v): &(&f64, &f64)| *v > 1e-3 * dmax;
            let body: Vec<(f64, f64)> = grid
                .iter()
                .zip(&d)
                .skip_while(|p| !shown(p))
                .take_while(shown)
                .map(|(y, v)| (*y, half * v / dmax))
                .collect();
            let outline: Vec<(f64, f64)> = body
                .iter()
                .map(|(y, w)| (centre + w, *y))
                .chain(body.iter().rev().map(|(y, w)| (centre - w, *y)))
                .collect();
            let c = colour(method);
            chart.draw_series(std::iter::once(Polygon::new(outline.clone(), c.mix(0.45))))?;
            chart.draw_series(std::iter::once(PathElement::new(outline, c)))?;
            let median = quantile(&mut e, 0.5);
            chart.draw_series(std::iter::once(Circle::new(
                (centre, median.min(ymax)),
                3,
                BLACK.filled(),
            )))?;
        }
    }
    if !legend {
        return Ok(());
    }
    for (method, _) in errs {
        let c = colour(method);
        chart
            .draw_series(std::iter::empty::<Circle<(f64, f64), i32>>())?
            .label(method.as_str())
            .legend(move |(x, y)| {
                Rectangle::new([(x, y - 5), (x + 14, y + 5)], c.mix(0.6).filled())
            });
    }
    crate::chart::legend_at(&mut chart, SeriesLabelPosition::UpperRight, 13)
}

/// The trajectories the time figure shows: up to `per_group` indenters of the seen and of the
/// unseen group, each one's trajectory at the centre point (`p0`), direction 0° and the
/// deepest depth recorded there.
pub fn pick_trajectories(ids: &[(String, String)], split: &Split, per_group: usize) -> Vec<usize> {
    let deepest = |ind: &str| {
        ids.iter()
            .enumerate()
            .filter(|(_, (i, id))| i == ind && id.starts_with("p0-") && id.ends_with("-a000"))
            .max_by(|a, b| a.1.1.cmp(&b.1.1))
            .map(|(k, _)| k)
    };
    let mut out = Vec::new();
    for group in ["seen", "unseen"] {
        let mut indenters: Vec<&str> = Vec::new();
        for (ind, _) in ids {
            if split.group(ind) == group && !indenters.contains(&ind.as_str()) {
                indenters.push(ind);
            }
        }
        out.extend(indenters.iter().filter_map(|i| deepest(i)).take(per_group));
    }
    out
}

/// Predicted (seed 1 of each method) and true force against time for the trajectories
/// `picks` (indices into the evaluated set, named by `ids`), a row each, a column per axis.
pub fn force_over_time(
    path: &Path,
    preds: &[ModelPredictions],
    shown: &Shown,
    ids: &[(String, String)],
    picks: &[usize],
    fps: f64,
) -> anyhow::Result<()> {
    anyhow::ensure!(!picks.is_empty(), "no trajectory to plot");
    let seed = preds.iter().map(|m| m.seed).min().unwrap_or(1);
    png(path, (1500, 250 * picks.len() as u32 + 50), |root| {
        let root = root.titled(
            &format!("Force over time on the target sensor (seed {seed} of each method)"),
            ("sans-serif", 22),
        )?;
        let panels = root.split_evenly((picks.len(), 3));
        for (row, &traj) in picks.iter().enumerate() {
            for a in 0..3 {
                let mut series: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
                let mut truth: Vec<(f64, f64)> = Vec::new();
                for method in METHODS.map(|m| m.name) {
                    let Some(modality) = shown.of(method, a) else {
                        continue;
                    };
                    let Some(m) = preds
                        .iter()
                        .find(|m| m.method == method && m.modality == modality && m.seed == seed)
                    else {
                        continue;
                    };
                    let mut pts: Vec<(usize, f64, f64)> = (0..m.p.pred.len())
                        .filter(|&i| m.p.traj[i] == traj)
                        .map(|i| (m.p.frame[i], m.p.pred[i][a], m.p.truth[i][a]))
                        .collect();
                    pts.sort_by_key(|p| p.0);
                    if truth.is_empty() {
                        truth = pts.iter().map(|p| (p.0 as f64 / fps, p.2)).collect();
                    }
                    series.push((
                        format!("{method} ({modality})"),
                        pts.iter().map(|p| (p.0 as f64 / fps, p.1)).collect(),
                    ));
                }
                let (ind, id) = &ids[traj];
                time_panel(
                    &panels[row * 3 + a],
                    &format!("{ind} {id}: {}", AXES[a]),
                    &truth,
                    &series,
                    row == 0 && a == 0,
                )?;
            }
        }
        Ok(())
    })
}

/// One panel of [`force_over_time`]; `legend`: whether this panel carries the legend.
fn time_panel(
    panel: &PngArea<'_>,
    caption: &str,
    truth: &[(f64, f64)],
    series: &[(String, Vec<(f64, f64)>)],
    legend: bool,
) -> anyhow::Result<()> {
    let all = truth.iter().chain(series.iter().flat_map(|s| s.1.iter()));
    let (mut x1, mut lo, mut hi) = (1e-3_f64, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in all.filter(|p| p.0.is_finite() && p.1.is_finite()) {
        x1 = x1.max(x);
        lo = lo.min(y);
        hi = hi.max(y);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (-1.0, 1.0);
    }
    let pad = 0.08 * (hi - lo).max(0.1);
    let mut chart = ChartBuilder::on(panel)
        .caption(caption, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(34)
        .y_label_area_size(48)
        .build_cartesian_2d(0.0..x1, lo - pad..hi + pad)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("force (N)")
        .label_style(("sans-serif", 13))
        .light_line_style(TRANSPARENT)
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            truth.iter().copied(),
            BLACK.stroke_width(3),
        ))?
        .label("true (Nano17)")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], BLACK.stroke_width(3)));
    for (method, pts) in series {
        let c = colour(method);
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))?
            .label(method.as_str())
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
    }
    if !legend {
        return Ok(());
    }
    crate::chart::legend_at(&mut chart, SeriesLabelPosition::UpperLeft, 12)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The density integrates to one over a grid that covers the data, and peaks at the data.
    #[test]
    fn the_density_integrates_to_one_and_peaks_at_the_data() {
        let xs: Vec<f64> = (0..1000)
            .map(|i| 2.0 + 0.1 * ((i % 21) as f64 - 10.0) / 10.0)
            .collect();
        let grid: Vec<f64> = (0..=400).map(|k| k as f64 * 0.01).collect();
        let d = density(&xs, &grid, 1e-3);
        let integral: f64 = d.iter().sum::<f64>() * 0.01;
        assert!((integral - 1.0).abs() < 0.01, "{integral}");
        let peak = grid[d
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0];
        assert!((peak - 2.0).abs() < 0.05, "{peak}");
        assert_eq!(density(&[], &grid, 1e-3), vec![0.0; grid.len()]);
    }

    #[test]
    fn the_picked_trajectories_are_the_deepest_straight_ones_per_group() {
        let ids: Vec<(String, String)> = [
            ("sphere", "p0-d0.2-a000"),
            ("sphere", "p0-d0.8-a000"),
            ("sphere", "p0-d0.8-a090"),
            ("cone", "p1-d0.8-a000"),
            ("cone", "p0-d0.4-a000"),
            ("hexagon", "p0-d0.6-a000"),
        ]
        .iter()
        .map(|(a, b)| (a.to_string(), b.to_string()))
        .collect();
        let split = Split {
            unseen: vec!["cone".into()],
            ..Split::default()
        };
        assert_eq!(pick_trajectories(&ids, &split, 2), vec![1, 5, 4]);
        assert_eq!(pick_trajectories(&ids, &split, 1), vec![1, 4]);
    }
}
