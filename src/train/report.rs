//! The result table in the paper's shape (method × modality, MAE and R² per axis, total-force
//! MAE, per indenter group) as Markdown, CSV and JSON, and predicted-against-true plots.

use std::path::Path;

use plotters::prelude::*;

use crate::chart;
use serde::{Deserialize, Serialize};

use super::metrics;

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct Row {
    pub method: String,
    pub modality: String,
    pub group: String,
    pub mae: [f64; 3],
    pub r2: [f64; 3],
    pub total_mae: f64,
    pub n: usize,
    /// MAE per axis over the shear-loaded frames (`metrics::ShearLoad`: true |F_shear| above
    /// 10 % of its range over the evaluation set). `None` when no frame is loaded, and in
    /// results written before it was measured.
    #[serde(default)]
    pub loaded_mae: Option<[f64; 3]>,
    /// How many frames are shear-loaded.
    #[serde(default)]
    pub loaded_n: usize,
}

impl Row {
    /// The shear-loaded MAE of `axis`, NaN where not measured.
    pub fn loaded(&self, axis: usize) -> f64 {
        self.loaded_mae.map_or(f64::NAN, |m| m[axis])
    }
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct FidRow {
    pub group: String,
    /// Which two image sets: `I_s–I_t` (before translation), `Î_t–I_t` (after), `I_s–Î_t`.
    pub pair: String,
    /// Images sampled from each set.
    pub n: [usize; 2],
    /// FID on Inception-v3 features (Heusel et al. 2017); empty without the Inception weights.
    pub fid: Option<f64>,
    /// KID (Bińkowski et al. 2018): mean and standard deviation over subsets.
    pub kid: Option<f64>,
    pub kid_std: Option<f64>,
    /// [how many subsets, of what size].
    pub kid_subsets: Option<[usize; 2]>,
    /// Fréchet distance of colour statistics (`eval::colour_features`): not an FID.
    pub colour_fd: Option<f64>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Table {
    pub rows: Vec<Row>,
    pub fid: Vec<FidRow>,
    /// Why FID/KID are missing, or what to keep in mind reading them.
    #[serde(default)]
    pub fid_notes: Vec<String>,
    /// The evaluation set's force range per axis, N (max − min over every frame), when known:
    /// the markdown then also gives each MAE as % of it (the paper's measure).
    #[serde(default)]
    pub range_n: Option<[f64; 3]>,
}

fn num(v: f64) -> String {
    if v.is_finite() {
        format!("{v:.3}")
    } else {
        "—".into()
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

impl Table {
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        if !self.rows.is_empty() {
            // R² first: an axis the model did not learn (R² ≤ 0) can still have a small MAE
            // over all frames when most frames carry little force on it. The shear-loaded
            // MAE is over the frames that do carry shear.
            s.push_str(
                "| Method | Modality | Group | R² Fx | R² Fy | R² Fz | MAE Fx | MAE Fy | MAE Fz | MAE |F| | loaded MAE Fx | loaded MAE Fy | n | loaded n |\n",
            );
            s.push_str(
                "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
            );
            for r in &self.rows {
                s.push_str(&format!(
                    "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    r.method,
                    r.modality,
                    r.group,
                    num(r.r2[0]),
                    num(r.r2[1]),
                    num(r.r2[2]),
                    num(r.mae[0]),
                    num(r.mae[1]),
                    num(r.mae[2]),
                    num(r.total_mae),
                    num(r.loaded(0)),
                    num(r.loaded(1)),
                    r.n,
                    r.loaded_n
                ));
            }
            s.push_str(
                "\nMAE in N. Loaded: the frames whose true shear |F_shear| = √(Fx² + Fy²) is above 10 % of its range over the evaluation set.\n",
            );
        }
        if let (Some(range), false) = (self.range_n, self.rows.is_empty()) {
            s.push_str(&format!(
                "\nMAE as % of the target's force range (Fx {:.2} N, Fy {:.2} N, Fz {:.2} N), the paper's measure, over all frames and over the shear-loaded ones:\n\n\
                 | Method | Modality | Group | Fx % | Fy % | Fz % | loaded Fx % | loaded Fy % |\n\
                 | --- | --- | --- | ---: | ---: | ---: | ---: | ---: |\n",
                range[0], range[1], range[2]
            ));
            for r in &self.rows {
                let pct = |v: f64, a: usize| {
                    if range[a] > 0.0 && v.is_finite() {
                        format!("{:.1}", 100.0 * v / range[a])
                    } else {
                        "—".into()
                    }
                };
                s.push_str(&format!(
                    "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
                    r.method,
                    r.modality,
                    r.group,
                    pct(r.mae[0], 0),
                    pct(r.mae[1], 1),
                    pct(r.mae[2], 2),
                    pct(r.loaded(0), 0),
                    pct(r.loaded(1), 1)
                ));
            }
        }
        if !self.fid.is_empty() {
            if !s.is_empty() {
                s.push('\n');
            }
            s.push_str(
                "| Images | Group | n | FID | KID | KID subsets | Colour-stats FD |\n\
                 | --- | --- | --- | ---: | ---: | ---: | ---: |\n",
            );
            let opt = |v: Option<f64>| num(v.unwrap_or(f64::NAN));
            for f in &self.fid {
                let kid = match (f.kid, f.kid_std) {
                    (Some(k), Some(sd)) => format!("{k:.4} ± {sd:.4}"),
                    (Some(k), None) => format!("{k:.4}"),
                    _ => "—".into(),
                };
                let subsets = f
                    .kid_subsets
                    .map(|[n, m]| format!("{n} × {m}"))
                    .unwrap_or_else(|| "—".into());
                s.push_str(&format!(
                    "| {} | {} | {} / {} | {} | {} | {} | {} |\n",
                    f.pair,
                    f.group,
                    f.n[0],
                    f.n[1],
                    opt(f.fid),
                    kid,
                    subsets,
                    opt(f.colour_fd)
                ));
            }
            for n in &self.fid_notes {
                s.push_str(&format!("\n{n}\n"));
            }
        }
        s
    }

    pub fn csv(&self) -> String {
        let mut s = String::from(
            "method,modality,group,mae_fx,mae_fy,mae_fz,mae_total,r2_fx,r2_fy,r2_fz,n,loaded_mae_fx,loaded_mae_fy,loaded_mae_fz,loaded_n\n",
        );
        for r in &self.rows {
            s.push_str(&format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
                csv_field(&r.method),
                csv_field(&r.modality),
                csv_field(&r.group),
                r.mae[0],
                r.mae[1],
                r.mae[2],
                r.total_mae,
                r.r2[0],
                r.r2[1],
                r.r2[2],
                r.n,
                r.loaded(0),
                r.loaded(1),
                r.loaded(2),
                r.loaded_n
            ));
        }
        s
    }

    /// `results.md`, `results.csv`, `results.json` in `dir`, each written atomically.
    pub fn write(&self, dir: &Path) -> anyhow::Result<()> {
        std::fs::create_dir_all(dir)?;
        let w = crate::durable::write_atomic;
        w(&dir.join("results.md"), self.markdown().as_bytes())?;
        w(&dir.join("results.csv"), self.csv().as_bytes())?;
        w(&dir.join("results.json"), &serde_json::to_vec_pretty(self)?)?;
        Ok(())
    }
}

/// The most points a predicted-against-true panel draws.
pub const MAX_SCATTER: usize = 4000;

/// Predicted against true force, one panel per axis, with the y = x line; non-finite points are
/// skipped, and empty or constant data still give a plot. The captions' MAE and R² are of every
/// point; at most [`MAX_SCATTER`] of them are drawn, evenly spaced in the list (a full
/// evaluation has tens of thousands of frames, and an SVG of them all is tens of megabytes).
pub fn plot_pred_vs_true(
    path: &Path,
    title: &str,
    pred: &[[f64; 3]],
    truth: &[[f64; 3]],
) -> anyhow::Result<()> {
    chart::svg(path, (1200, 440), |root| {
        let root = root.titled(title, ("sans-serif", 18))?;
        let panels = root.split_evenly((1, 3));
        for (a, panel) in panels.iter().enumerate() {
            let pts: Vec<(f64, f64)> = truth
                .iter()
                .zip(pred)
                .map(|(t, p)| (t[a], p[a]))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect();
            let (mut lo, mut hi) = pts
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), (x, y)| {
                    (l.min(*x).min(*y), h.max(*x).max(*y))
                });
            if !(lo.is_finite() && hi.is_finite()) {
                (lo, hi) = (-1.0, 1.0);
            }
            if hi - lo < 1e-9 {
                (lo, hi) = (lo - 0.5, hi + 0.5);
            }
            let pad = 0.05 * (hi - lo);
            let (xs, ys): (Vec<f64>, Vec<f64>) = pts.iter().copied().unzip();
            let stride = pts.len().div_ceil(MAX_SCATTER).max(1);
            let caption = format!(
                "{}: MAE {} N, R² {}",
                metrics::AXES[a],
                num(metrics::mae(&ys, &xs)),
                num(metrics::r2(&ys, &xs))
            );
            let mut chart = ChartBuilder::on(panel)
                .caption(caption, ("sans-serif", 15))
                .margin(10)
                .x_label_area_size(36)
                .y_label_area_size(48)
                .build_cartesian_2d(lo - pad..hi + pad, lo - pad..hi + pad)?;
            chart
                .configure_mesh()
                .x_desc("true force (N)")
                .y_desc("predicted force (N)")
                .draw()?;
            chart.draw_series(LineSeries::new([(lo, lo), (hi, hi)], BLACK.mix(0.5)))?;
            chart.draw_series(
                pts.iter()
                    .step_by(stride)
                    .map(|p| Circle::new(*p, 2, BLUE.mix(0.4).filled())),
            )?;
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table() -> Table {
        Table {
            rows: vec![
                Row {
                    method: "TransForce".into(),
                    modality: "R+M".into(),
                    group: "seen".into(),
                    mae: [0.1, 0.2, 0.3],
                    r2: [0.9, 0.8, f64::NAN],
                    total_mae: 0.25,
                    n: 10,
                    loaded_mae: Some([0.4, 0.6, 0.5]),
                    loaded_n: 3,
                },
                Row {
                    method: "a, \"b\"".into(),
                    modality: "M".into(),
                    group: "unseen".into(),
                    mae: [1.0, 2.0, 3.0],
                    r2: [-0.5, 0.0, 1.0],
                    total_mae: 2.5,
                    n: 4,
                    loaded_mae: None,
                    loaded_n: 0,
                },
            ],
            fid_notes: Vec::new(),
            range_n: None,
            fid: vec![
                FidRow {
                    group: "seen".into(),
                    pair: "I_s–I_t".into(),
                    n: [64, 60],
                    fid: Some(12.5),
                    kid: Some(0.01),
                    kid_std: Some(0.002),
                    kid_subsets: Some([100, 60]),
                    colour_fd: Some(0.25),
                },
                FidRow {
                    group: "unseen".into(),
                    pair: "I_s–I_t".into(),
                    n: [8, 9],
                    fid: None,
                    kid: None,
                    kid_std: None,
                    kid_subsets: None,
                    colour_fd: Some(1.5),
                },
            ],
        }
    }

    #[test]
    fn markdown_and_csv_have_the_papers_columns() {
        let md = table().markdown();
        assert!(md.contains("| TransForce | R+M | seen | 0.900 | 0.800 | — | 0.100 | 0.200 | 0.300 | 0.250 | 0.400 | 0.600 | 10 | 3 |"), "{md}");
        assert!(md.contains("| a, \"b\" | M | unseen | -0.500 | 0.000 | 1.000 | 1.000 | 2.000 | 3.000 | 2.500 | — | — | 4 | 0 |"), "{md}");
        assert!(
            md.contains(
                "| I_s–I_t | seen | 64 / 60 | 12.500 | 0.0100 ± 0.0020 | 100 × 60 | 0.250 |"
            ),
            "{md}"
        );
        assert!(
            md.contains("| I_s–I_t | unseen | 8 / 9 | — | — | — | 1.500 |"),
            "{md}"
        );
        let csv = table().csv();
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(
            lines[0],
            "method,modality,group,mae_fx,mae_fy,mae_fz,mae_total,r2_fx,r2_fy,r2_fz,n,loaded_mae_fx,loaded_mae_fy,loaded_mae_fz,loaded_n"
        );
        assert_eq!(
            lines[1],
            "TransForce,R+M,seen,0.1,0.2,0.3,0.25,0.9,0.8,NaN,10,0.4,0.6,0.5,3"
        );
        assert_eq!(
            lines[2],
            "\"a, \"\"b\"\"\",M,unseen,1,2,3,2.5,-0.5,0,1,4,NaN,NaN,NaN,0"
        );
    }

    #[test]
    fn with_a_force_range_the_markdown_gives_each_mae_as_percent_of_it() {
        let mut t = table();
        assert!(!t.markdown().contains("% of the target"));
        t.range_n = Some([2.0, 4.0, 0.0]);
        let md = t.markdown();
        assert!(md.contains("(Fx 2.00 N, Fy 4.00 N, Fz 0.00 N)"), "{md}");
        // 0.1 / 2 and 0.2 / 4 are 5 %; a zero range has no percentage; loaded 0.4 / 2 and
        // 0.6 / 4 are 20 and 15 %.
        assert!(
            md.contains("| TransForce | R+M | seen | 5.0 | 5.0 | — | 20.0 | 15.0 |"),
            "{md}"
        );
        assert!(
            md.contains("| a, \"b\" | M | unseen | 50.0 | 50.0 | — | — | — |"),
            "{md}"
        );
    }

    #[test]
    fn write_creates_three_files_and_json_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let t = table();
        t.write(dir.path()).unwrap();
        for f in ["results.md", "results.csv", "results.json"] {
            assert!(dir.path().join(f).is_file());
        }
        let back: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("results.json")).unwrap())
                .unwrap();
        assert_eq!(back["rows"][1]["method"], "a, \"b\"");
        assert_eq!(back["rows"].as_array().unwrap().len(), 2);
    }

    #[test]
    fn a_large_evaluation_draws_at_most_max_scatter_points_a_panel() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.svg");
        let truth: Vec<[f64; 3]> = (0..20_001)
            .map(|i| [i as f64, -(i as f64), 0.5 * i as f64])
            .collect();
        let pred: Vec<[f64; 3]> = truth.iter().map(|t| t.map(|v| v + 1.0)).collect();
        plot_pred_vs_true(&path, "big", &pred, &truth).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        let circles = svg.matches("<circle").count();
        assert!(
            (3 * 3000..=3 * MAX_SCATTER).contains(&circles),
            "{circles} points drawn for 3 × 20001"
        );
        // The captions are of every point: MAE exactly 1 N on each axis.
        assert_eq!(
            svg.matches("MAE 1.000 N").count(),
            3,
            "{}",
            &svg[..svg.len().min(2000)]
        );
    }

    #[test]
    fn plots_survive_empty_constant_and_nan_data() {
        let dir = tempfile::tempdir().unwrap();
        type Case = (Vec<[f64; 3]>, Vec<[f64; 3]>);
        let cases: Vec<Case> = vec![
            (
                vec![[0.1, 0.2, -1.0], [0.0, 0.3, -2.0]],
                vec![[0.0, 0.2, -1.1], [0.1, 0.2, -2.2]],
            ),
            (vec![], vec![]),
            (vec![[1.0; 3]; 4], vec![[1.0; 3]; 4]),
            (vec![[f64::NAN, 1.0, f64::INFINITY]], vec![[0.0, 1.0, 2.0]]),
        ];
        for (i, (p, t)) in cases.iter().enumerate() {
            let path = dir.path().join(format!("p{i}.svg"));
            plot_pred_vs_true(&path, "test", p, t).unwrap();
            assert!(std::fs::read_to_string(&path).unwrap().contains("<svg"));
        }
    }
}
