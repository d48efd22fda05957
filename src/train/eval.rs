//! `rig eval`: a force model on the target sensor's data, in the paper's terms: MAE and R² per
//! axis and the total-force MAE, for the seen and unseen indenter groups; FID/KID between image
//! sets (on the features of [`rig_nn::inception`]) and a colour-statistics distance.

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::path::Path;

use rig_nn::{FEATURE_DIM, Inception, device};
use serde::{Deserialize, Serialize};

use super::batch::{Rng, Sequence};
use super::data::{EvalSet, ImageSpec, Split, Trajectory, UnlabelledSet};
use super::force::ForceModel;
use super::inception::{self, WeightsError};
use super::metrics::{self, AxisScores};
use super::report::{FidRow, Row};

/// Predictions and truths of one model on one evaluation set, per frame.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Predictions {
    pub indenter: Vec<String>,
    /// The frame's trajectory (an index into the evaluated set) and its index in it.
    pub traj: Vec<usize>,
    pub frame: Vec<usize>,
    pub pred: Vec<[f64; 3]>,
    pub truth: Vec<[f64; 3]>,
}

impl Predictions {
    /// The predicted and true forces of the frames whose indenter `keep` accepts.
    fn frames_where(&self, keep: impl Fn(&str) -> bool) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        self.indenter
            .iter()
            .zip(self.pred.iter().zip(&self.truth))
            .filter(|(ind, _)| keep(ind))
            .map(|(_, (a, b))| (*a, *b))
            .unzip()
    }
}

/// Evaluation sequences: every frame of every trajectory scored exactly once, in windows of T
/// frames in time order that span the trajectory the way the training sequences do.
///
/// Training draws T frames in time order from the whole trajectory (the paper's sampling), so
/// the LSTM learns from frames about n/T apart. Windows of consecutive frames would show it a
/// history it never saw in training. Here a trajectory of n frames is read at the stride
/// s = ⌊n/T⌋: the windows {o, o+s, …, o+(T−1)s} for o = 0..s cover frames 0..sT exactly once,
/// and each of the (fewer than T) frames after them ends a window of the same stride, of which
/// only that last frame is scored. Returns each window with how many of its leading positions
/// are not scored.
pub fn eval_windows(lengths: &[usize], t: usize) -> Vec<(Sequence, usize)> {
    let mut out = Vec::new();
    for (traj, &n) in lengths.iter().enumerate() {
        if n < t || t == 0 {
            continue;
        }
        let s = n / t;
        for o in 0..s {
            let frames = (0..t).map(|k| o + k * s).collect();
            out.push((Sequence { traj, frames }, 0));
        }
        // s·t ≤ n < (s+1)·t: at most t − 1 frames are left, each ≥ s·t, so a window of stride s
        // ending on one starts at ≥ s.
        for last in s * t..n {
            let frames = (0..t).map(|k| last - (t - 1 - k) * s).collect();
            out.push((Sequence { traj, frames }, t - 1));
        }
    }
    out
}

/// Run the model over the set.
pub fn predict(model: &ForceModel, set: &EvalSet) -> Predictions {
    let lengths: Vec<usize> = set.trajectories.iter().map(|t| t.frames).collect();
    let windows = eval_windows(&lengths, model.info.config.seq_len);
    let seqs: Vec<Sequence> = windows.iter().map(|(s, _)| s.clone()).collect();
    let out = model.predict(&set.trajectories, &seqs, 16);
    let mut p = Predictions::default();
    for ((seq, skip), pred) in windows.iter().zip(out) {
        let truth = set.forces(seq.traj);
        for (k, &i) in seq.frames.iter().enumerate().skip(*skip) {
            p.indenter.push(set.trajectories[seq.traj].indenter.clone());
            p.traj.push(seq.traj);
            p.frame.push(i);
            p.pred.push(pred[k].map(|v| v as f64));
            p.truth.push(truth[i].map(|v| v as f64));
        }
    }
    p
}

/// The set's force range per axis, N: max − min over every frame (0 for an empty set).
pub fn force_range(set: &EvalSet) -> [f64; 3] {
    let mut bounds = [(f32::INFINITY, f32::NEG_INFINITY); 3];
    for i in 0..set.trajectories.len() {
        for f in set.forces(i) {
            for a in 0..3 {
                bounds[a] = (bounds[a].0.min(f[a]), bounds[a].1.max(f[a]));
            }
        }
    }
    bounds.map(|(lo, hi)| if hi >= lo { (hi - lo) as f64 } else { 0.0 })
}

/// Table rows for the seen and unseen groups (those present) and all together.
pub fn rows(method: &str, modality: &str, p: &Predictions, split: &Split) -> Vec<Row> {
    let mut rows = Vec::new();
    // One threshold for every group: the loaded frames are the same whichever group they
    // are scored in.
    let load = metrics::ShearLoad::of(&p.truth);
    for group in ["seen", "unseen", "all"] {
        let (pred, truth) = p.frames_where(|ind| group == "all" || split.group(ind) == group);
        if pred.is_empty() {
            continue;
        }
        let s: AxisScores = metrics::score_at(&pred, &truth, load);
        rows.push(Row {
            method: method.into(),
            modality: modality.into(),
            group: group.into(),
            mae: s.mae,
            r2: s.r2,
            total_mae: s.total_mae,
            n: s.n,
            loaded_mae: (s.loaded_n > 0).then_some(s.loaded_mae),
            loaded_n: s.loaded_n,
        });
    }
    rows
}

/// Evaluate a model directory on a target dataset; writes the table and the plots into `out`.
pub fn evaluate(
    model_dir: &Path,
    data: &Path,
    out: &Path,
    split: &Split,
    progress: bool,
) -> anyhow::Result<Vec<Row>> {
    let model = ForceModel::load(model_dir)?;
    let set = super::data::load_eval(data, &model.spec(), progress)?;
    evaluate_on(&model, &set, data, out, split).map(|(rows, _)| rows)
}

/// [`evaluate`] on a loaded set (`data` names it in messages and plot titles): the rows, and
/// the predictions they were scored on.
pub fn evaluate_on(
    model: &ForceModel,
    set: &EvalSet,
    data: &Path,
    out: &Path,
    split: &Split,
) -> anyhow::Result<(Vec<Row>, Predictions)> {
    // A D+S model reads another sensor's shading at its training sensor's scale.
    let gain = set.shading_gain_for(model.info.shading_mean, split);
    let scaled;
    let set = if gain == 1.0 {
        set
    } else {
        eprintln!(
            "{}: the shading change scaled ×{gain:.3} to the training sensor's (mean over {})",
            model.info.method,
            data.display()
        );
        scaled = set.with_shading_gain(gain);
        &scaled
    };
    let p = predict(model, set);
    if p.pred.is_empty() {
        anyhow::bail!(
            "{} has no trajectory of {} frames to evaluate",
            data.display(),
            model.info.config.seq_len
        );
    }
    let rows = rows(
        &model.info.method,
        model.spec().modality.paper_name(),
        &p,
        split,
    );
    std::fs::create_dir_all(out)?;
    super::report::plot_pred_vs_true(
        &out.join(format!("pred-vs-true-{}.svg", slug(&model.info.method))),
        &format!(
            "{} ({}) on {}",
            model.info.method,
            model.spec().modality.paper_name(),
            data.display()
        ),
        &p.pred,
        &p.truth,
    )?;
    write_indenter_csv(
        &out.join(format!("per-indenter-{}.csv", slug(&model.info.method))),
        &indenter_rows(&p, split),
    )?;
    Ok((rows, p))
}

/// One indenter's scores (`rig eval` writes them beside the table, `per-indenter-*.csv`): which
/// indenters hold an axis back is what the pooled R² cannot say.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IndenterRow {
    pub indenter: String,
    pub group: String,
    pub scores: AxisScores,
    /// Mean true |Fz| over its frames, N: how hard the indenter presses.
    pub mean_abs_fz: f64,
    /// Mean (predicted − true) per axis, N: a model that under-reads an indenter's force shows
    /// it here, where its R² alone could be lifted by the other indenters.
    pub bias: [f64; 3],
}

/// Scores per indenter, in name order, with the shear-loaded frames chosen as in [`rows`] (one
/// threshold over every frame).
pub fn indenter_rows(p: &Predictions, split: &Split) -> Vec<IndenterRow> {
    let load = metrics::ShearLoad::of(&p.truth);
    let mut names: Vec<&String> = p.indenter.iter().collect();
    names.sort();
    names.dedup();
    names
        .into_iter()
        .map(|name| {
            let (pred, truth) = p.frames_where(|ind| ind == name);
            let n = pred.len().max(1) as f64;
            IndenterRow {
                indenter: name.clone(),
                group: split.group(name).into(),
                scores: metrics::score_at(&pred, &truth, load),
                mean_abs_fz: truth.iter().map(|t| t[2].abs()).sum::<f64>() / n,
                bias: std::array::from_fn(|a| {
                    pred.iter()
                        .zip(&truth)
                        .map(|(p, t)| p[a] - t[a])
                        .sum::<f64>()
                        / n
                }),
            }
        })
        .collect()
}

/// The per-indenter scores as CSV: R², MAE and bias per axis, the shear-loaded MAE.
pub fn write_indenter_csv(path: &Path, rows: &[IndenterRow]) -> std::io::Result<()> {
    let mut s = String::from(
        "indenter,group,frames,mean_abs_fz_n,r2_fx,r2_fy,r2_fz,mae_fx_n,mae_fy_n,mae_fz_n,\
         bias_fx_n,bias_fy_n,bias_fz_n,loaded_frames,loaded_mae_fx_n,loaded_mae_fy_n\n",
    );
    for r in rows {
        let c = &r.scores;
        s.push_str(&format!(
            "{},{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{:.4},{},{:.4},{:.4}\n",
            r.indenter,
            r.group,
            c.n,
            r.mean_abs_fz,
            c.r2[0],
            c.r2[1],
            c.r2[2],
            c.mae[0],
            c.mae[1],
            c.mae[2],
            r.bias[0],
            r.bias[1],
            r.bias[2],
            c.loaded_n,
            c.loaded_mae[0],
            c.loaded_mae[1],
        ));
    }
    std::fs::write(path, s)
}

pub fn slug(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect::<String>()
        .split('-')
        .filter(|p| !p.is_empty())
        .collect::<Vec<_>>()
        .join("-")
}

// ---------------------------------------------------------------------------------------------
// FID / KID

/// How FID and KID are computed between image sets (`[fid]` in the trainer config).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FidConfig {
    /// Images drawn (a fixed sample) from each set and indenter group. Inception takes about
    /// 0.25 s an image on one CPU core, so this bounds the time FID takes; published FIDs use
    /// 50 000 images, and FID from fewer than 2048 (the feature size) is biased upward: compare
    /// FIDs of equal sample sizes only.
    pub max_images: usize,
    /// KID: the number of random subsets and their size (the reference practice: 100 of 1000),
    /// smaller when the sets are.
    pub kid_subsets: usize,
    pub kid_subset_size: usize,
    /// Images per Inception forward pass.
    pub batch: usize,
}

impl Default for FidConfig {
    fn default() -> Self {
        Self {
            max_images: 1000,
            kid_subsets: 100,
            kid_subset_size: 1000,
            batch: 16,
        }
    }
}

/// The Inception network for FID/KID, or why there is none. Weights at the default location
/// that are missing make FID/KID unavailable (with a note in the table) unless `required`;
/// weights named by a flag or `$RIG_INCEPTION_WEIGHTS` that are missing, and a damaged file
/// anywhere, are an error.
pub fn load_inception(
    flag: Option<&Path>,
    batch: usize,
    required: bool,
) -> anyhow::Result<Result<Inception, String>> {
    let w = inception::weights_path(flag);
    match inception::load(&w.path, &device()) {
        Ok(mut net) => {
            net.batch = batch.max(1);
            Ok(Ok(net))
        }
        Err(e @ WeightsError::Missing { .. }) if !w.explicit && !required => Ok(Err(e.to_string())),
        Err(e) => Err(e.into()),
    }
}

/// Colour statistics of an image (not Inception features): the mean colour of each cell of a
/// 4 × 4 grid (48 values) and the luminance standard deviation of each cell (16). Their Fréchet
/// distance (the table's "colour-stats FD") is cheap and sees the sensors' colour and shading
/// differences; it is not the FID and is not comparable with published numbers.
pub fn colour_features(frame: &[u8], spec: &ImageSpec) -> Vec<f64> {
    let (w, h) = (spec.width as usize, spec.height as usize);
    let g = 4;
    let mut sum = vec![[0f64; 3]; g * g];
    let mut lum = vec![(0f64, 0f64); g * g];
    let mut cnt = vec![0f64; g * g];
    for y in 0..h {
        for x in 0..w {
            let cell = (y * g / h.max(1)) * g + x * g / w.max(1);
            let p = &frame[(y * w + x) * 3..(y * w + x) * 3 + 3];
            let rgb = [
                p[0] as f64 / 255.0,
                p[1] as f64 / 255.0,
                p[2] as f64 / 255.0,
            ];
            let l = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2];
            for c in 0..3 {
                sum[cell][c] += rgb[c];
            }
            lum[cell].0 += l;
            lum[cell].1 += l * l;
            cnt[cell] += 1.0;
        }
    }
    let mut f = Vec::with_capacity(g * g * 4);
    for k in 0..g * g {
        let n = cnt[k].max(1.0);
        f.extend(sum[k].iter().map(|s| s / n));
        let m = lum[k].0 / n;
        f.push((lum[k].1 / n - m * m).max(0.0).sqrt());
    }
    f
}

/// A fixed sample (seeded) of at most `max` frames of the set's trajectories in `group`.
fn sample<'a>(
    set: &'a UnlabelledSet,
    split: &Split,
    group: &str,
    max: usize,
    seed: u64,
) -> Vec<&'a [u8]> {
    let trajs: &[Trajectory] = &set.trajectories;
    let all: Vec<(usize, usize)> = trajs
        .iter()
        .enumerate()
        .filter(|(_, t)| split.group(&t.indenter) == group)
        .flat_map(|(i, t)| (0..t.frames).map(move |k| (i, k)))
        .collect();
    let mut idx: Vec<usize> = (0..all.len()).collect();
    Rng(seed).shuffle(&mut idx);
    idx.truncate(max);
    idx.iter()
        .map(|&j| {
            let (i, k) = all[j];
            trajs[i].frame(k, &set.spec)
        })
        .collect()
}

/// The features of one set's sample in one group.
struct GroupFeatures {
    colour: Vec<Vec<f64>>,
    inception: Option<Vec<Vec<f64>>>,
}

/// The sample of set `i` (`(name, set)`) in `group`, through the colour statistics and, with a
/// network, through Inception (a progress bar per sample).
fn group_features(
    (name, set): (&str, &UnlabelledSet),
    i: usize,
    group: &str,
    split: &Split,
    cfg: &FidConfig,
    net: Option<&Inception>,
    progress: bool,
) -> anyhow::Result<GroupFeatures> {
    let frames = sample(set, split, group, cfg.max_images, 1 + i as u64);
    let colour = frames
        .iter()
        .map(|f| colour_features(f, &set.spec))
        .collect();
    let inception = match net {
        Some(net) if frames.len() >= 2 => {
            let bar = super::progress_bar(progress, frames.len() as u64, "inception");
            bar.set_message(format!("{name} {group}"));
            let f = net
                .features(
                    &frames,
                    set.spec.width as usize,
                    set.spec.height as usize,
                    |n| bar.inc(n as u64),
                )
                .map_err(|e| anyhow::anyhow!("Inception features of {name}: {e}"))?;
            bar.finish_and_clear();
            Some(
                f.into_iter()
                    .map(|v| v.into_iter().map(f64::from).collect())
                    .collect(),
            )
        }
        _ => None,
    };
    Ok(GroupFeatures { colour, inception })
}

/// The translation's FID/KID rows: I_s–I_t (before), Î_t–I_t (after) and I_s–Î_t, from the
/// source, target and translated images (`[I_s, I_t, Î_t]`).
pub fn translation_fid(
    [source, target, translated]: [&UnlabelledSet; 3],
    split: &Split,
    cfg: &FidConfig,
    net: Option<&Inception>,
    progress: bool,
) -> anyhow::Result<Vec<FidRow>> {
    fid_rows(
        &[("I_s", source), ("I_t", target), ("Î_t", translated)],
        &[(0, 1), (2, 1), (0, 2)],
        split,
        cfg,
        net,
        progress,
    )
}

/// FID, KID and the colour-statistics distance between named image sets: one row per pair
/// (`sets[i]`, `sets[j]`, named "i–j") and indenter group present in both. Each set's sample is
/// passed through Inception once, however many pairs it is in. Without `net` the FID and KID
/// are left empty.
pub fn fid_rows(
    sets: &[(&str, &UnlabelledSet)],
    pairs: &[(usize, usize)],
    split: &Split,
    cfg: &FidConfig,
    net: Option<&Inception>,
    progress: bool,
) -> anyhow::Result<Vec<FidRow>> {
    let mut cache: HashMap<(usize, &str), GroupFeatures> = HashMap::new();
    let mut rows = Vec::new();
    for &(i, j) in pairs {
        for group in ["seen", "unseen"] {
            for k in [i, j] {
                if let Entry::Vacant(e) = cache.entry((k, group)) {
                    e.insert(group_features(
                        sets[k], k, group, split, cfg, net, progress,
                    )?);
                }
            }
            let (a, b) = (&cache[&(i, group)], &cache[&(j, group)]);
            if a.colour.len() < 2 || b.colour.len() < 2 {
                continue;
            }
            let (fid, kid) = match (&a.inception, &b.inception) {
                (Some(fa), Some(fb)) => (
                    metrics::fid(fa, fb).ok(),
                    metrics::kid(fa, fb, cfg.kid_subsets, cfg.kid_subset_size, 3).ok(),
                ),
                _ => (None, None),
            };
            rows.push(FidRow {
                group: group.into(),
                pair: format!("{}–{}", sets[i].0, sets[j].0),
                n: [a.colour.len(), b.colour.len()],
                fid,
                kid: kid.map(|k| k.mean),
                // Subsets as large as both samples are the samples themselves, every time: no
                // spread to report.
                kid_std: kid
                    .filter(|k| k.subset_size < a.colour.len().max(b.colour.len()))
                    .map(|k| k.std),
                kid_subsets: kid.map(|k| [k.subsets, k.subset_size]),
                colour_fd: metrics::fid(&a.colour, &b.colour).ok(),
            });
        }
    }
    Ok(rows)
}

/// What the FID/KID table needs said: that Inception was not available, or that KID's subsets
/// are smaller than the reference 1000.
pub fn fid_notes(net: &Result<Inception, String>, rows: &[FidRow], cfg: &FidConfig) -> Vec<String> {
    let mut notes = Vec::new();
    if let Err(e) = net {
        notes.push(format!("FID and KID not computed: {e}"));
    }
    if let Some(m) = rows
        .iter()
        .filter_map(|r| r.kid_subsets.map(|s| s[1]))
        .filter(|&m| m < cfg.kid_subset_size)
        .min()
    {
        notes.push(format!(
            "KID subsets are smaller than the reference {} (as small as {m}) because the image samples are (at most {} per set and group); FID from fewer than {} images is biased upward, so compare rows with equal n.",
            cfg.kid_subset_size,
            cfg.max_images,
            FEATURE_DIM
        ));
    }
    notes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_indenter_scores_show_the_indenter_a_pooled_score_hides() {
        // The sphere is read exactly; the wave's Fz is read at half its size. Pooled, the
        // sphere's spread lifts R² Fz; per indenter the wave's bias and R² show it.
        let mut p = Predictions::default();
        for k in 0..10 {
            let fz = -(k as f64);
            for (name, scale) in [("sphere", 1.0), ("wave", 0.5)] {
                p.indenter.push(name.into());
                p.traj.push(0);
                p.frame.push(k);
                p.truth.push([0.1 * k as f64, 0.0, fz]);
                p.pred.push([0.1 * k as f64, 0.0, scale * fz]);
            }
        }
        let split = Split {
            unseen: vec!["wave".into()],
            excluded: Vec::new(),
        };
        let rows = indenter_rows(&p, &split);
        let names: Vec<&str> = rows.iter().map(|r| r.indenter.as_str()).collect();
        assert_eq!(names, ["sphere", "wave"]);
        let (sphere, wave) = (&rows[0], &rows[1]);
        assert_eq!(
            (sphere.group.as_str(), wave.group.as_str()),
            ("seen", "unseen")
        );
        assert_eq!(sphere.scores.n, 10);
        assert_eq!(sphere.scores.r2[2], 1.0);
        assert_eq!(sphere.bias, [0.0; 3]);
        assert!((sphere.mean_abs_fz - 4.5).abs() < 1e-12);
        // Half of Fz = −k: bias +k/2 on average, 2.25 N; R² = 1 − Σ(k/2)² / Σ(k − 4.5)².
        assert!((wave.bias[2] - 2.25).abs() < 1e-12, "{:?}", wave.bias);
        let ss_res: f64 = (0..10).map(|k| (k as f64 / 2.0).powi(2)).sum();
        let ss_tot: f64 = (0..10).map(|k| (k as f64 - 4.5).powi(2)).sum();
        assert!((wave.scores.r2[2] - (1.0 - ss_res / ss_tot)).abs() < 1e-12);
        // Shear is read exactly on both: loaded MAE 0 where frames are loaded.
        assert!(wave.scores.loaded_n > 0);
        assert_eq!(wave.scores.loaded_mae[0], 0.0);
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("per-indenter.csv");
        write_indenter_csv(&csv, &rows).unwrap();
        let text = std::fs::read_to_string(&csv).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 3);
        assert!(lines[0].starts_with("indenter,group,frames,"));
        assert!(
            lines[2].starts_with("wave,unseen,10,4.5000,"),
            "{}",
            lines[2]
        );
    }

    #[test]
    fn a_d_s_set_is_scaled_to_the_model_s_shading_and_other_sets_are_not() {
        use super::super::modality::Modality;
        let traj = |blue: u8| Trajectory {
            id: "a".into(),
            indenter: "sphere".into(),
            pixels: [128, 128, blue].repeat(4 * 4),
            frames: 1,
        };
        let set = |modality| {
            let spec = ImageSpec {
                width: 4,
                height: 4,
                modality,
            };
            EvalSet::from_parts(spec, vec![traj(20)], vec![vec![[0.0; 3]]]).unwrap()
        };
        let ds = set(Modality::FlowShading);
        // The model's training frames averaged 30 levels; these 20: ×1.5, blue 20 → 30.
        let trained = 30.0 / super::super::modality::SHADING_LEVELS;
        let split = Split::default();
        let g = ds.shading_gain_for(Some(trained), &split);
        assert!((g - 1.5).abs() < 1e-12, "{g}");
        let scaled = ds.with_shading_gain(g);
        assert!(
            scaled.trajectories[0]
                .pixels
                .chunks(3)
                .all(|p| p == [128, 128, 30])
        );
        assert_eq!(scaled.forces(0), ds.forces(0));
        // A model that records no mean, or another modality: no gain.
        assert_eq!(ds.shading_gain_for(None, &split), 1.0);
        assert_eq!(
            set(Modality::Flow).shading_gain_for(Some(trained), &split),
            1.0
        );
    }

    #[test]
    fn the_force_range_spans_every_trajectory_per_axis() {
        let spec = ImageSpec {
            width: 4,
            height: 4,
            modality: super::super::modality::Modality::Rgb,
        };
        let traj = |id: &str, n: usize| Trajectory {
            id: id.into(),
            indenter: "sphere".into(),
            pixels: vec![0; n * spec.frame_bytes()],
            frames: n,
        };
        let set = EvalSet::from_parts(
            spec,
            vec![traj("a", 2), traj("b", 3)],
            vec![
                vec![[0.5, -1.0, 0.0], [1.5, 0.0, -4.0]],
                vec![[-0.5, 2.0, -16.0], [0.0, 0.0, -2.0], [0.25, 1.0, 0.0]],
            ],
        )
        .unwrap();
        assert_eq!(force_range(&set), [2.0, 3.0, 16.0]);
        let empty = EvalSet::from_parts(spec, Vec::new(), Vec::new()).unwrap();
        assert_eq!(force_range(&empty), [0.0; 3]);
    }

    #[test]
    fn eval_windows_score_every_frame_once_at_the_training_stride() {
        let lens = [20, 8, 5, 9, 58, 63, 64];
        let w = eval_windows(&lens, 8);
        for (traj, &n) in lens.iter().enumerate() {
            let mut seen = vec![0; n];
            for (s, skip) in w.iter().filter(|(s, _)| s.traj == traj) {
                assert_eq!(s.frames.len(), 8);
                // Evenly spaced, in time order, at the stride ⌊n/T⌋, inside the trajectory.
                assert!(s.frames.windows(2).all(|p| p[1] == p[0] + n / 8));
                assert!(*s.frames.last().unwrap() < n);
                for &i in s.frames.iter().skip(*skip) {
                    seen[i] += 1;
                }
            }
            if n >= 8 {
                assert!(seen.iter().all(|&c| c == 1), "traj {traj}: {seen:?}");
            } else {
                assert!(seen.iter().all(|&c| c == 0));
            }
        }
        // 58 frames: stride 7, windows at offsets 0..7 cover 0..56; frames 56 and 57 each end
        // one more window.
        let w58: Vec<_> = w.iter().filter(|(s, _)| s.traj == 4).collect();
        assert_eq!(w58.len(), 9);
        assert_eq!(w58[0].0.frames, vec![0, 7, 14, 21, 28, 35, 42, 49]);
        assert_eq!(w58[8].0.frames, vec![8, 15, 22, 29, 36, 43, 50, 57]);
        assert_eq!(w58[8].1, 7);
    }

    #[test]
    fn features_of_a_flat_image_are_its_colour() {
        let spec = ImageSpec {
            width: 8,
            height: 8,
            modality: super::super::modality::Modality::RgbMarker,
        };
        let px: Vec<u8> = [51u8, 102, 204].repeat(64);
        let f = colour_features(&px, &spec);
        assert_eq!(f.len(), 64);
        for k in 0..16 {
            assert!((f[k * 4] - 0.2).abs() < 1e-12);
            assert!((f[k * 4 + 1] - 0.4).abs() < 1e-12);
            assert!((f[k * 4 + 2] - 0.8).abs() < 1e-12);
            assert!(f[k * 4 + 3].abs() < 1e-6);
        }
    }

    fn flat_set(colours: &[(&str, [u8; 3], usize)]) -> UnlabelledSet {
        let spec = ImageSpec {
            width: 8,
            height: 8,
            modality: super::super::modality::Modality::RgbMarker,
        };
        UnlabelledSet {
            spec,
            trajectories: colours
                .iter()
                .enumerate()
                .map(|(k, (ind, rgb, frames))| Trajectory {
                    id: format!("t{k}"),
                    indenter: ind.to_string(),
                    // Frame f is the colour brightened by f (so the samples vary).
                    pixels: (0..*frames)
                        .flat_map(|f| rgb.map(|c| c.saturating_add(f as u8)).repeat(64))
                        .collect(),
                    frames: *frames,
                })
                .collect(),
        }
    }

    #[test]
    fn fid_rows_sample_each_set_per_group_and_say_when_inception_is_missing() {
        let split = Split {
            unseen: vec!["cone".into()],
            excluded: Vec::new(),
        };
        let a = flat_set(&[("sphere", [100, 50, 50], 30), ("cone", [100, 50, 50], 3)]);
        let b = flat_set(&[("sphere", [40, 120, 60], 30), ("cone", [40, 120, 60], 1)]);
        let cfg = FidConfig {
            max_images: 20,
            ..FidConfig::default()
        };
        let rows = fid_rows(
            &[("A", &a), ("B", &b)],
            &[(0, 1), (0, 0)],
            &split,
            &cfg,
            None,
            false,
        )
        .unwrap();
        // The unseen group has a single B frame: no row for it in A–B; A–A has both groups.
        let groups: Vec<(&str, &str)> = rows
            .iter()
            .map(|r| (r.pair.as_str(), r.group.as_str()))
            .collect();
        assert_eq!(
            groups,
            [("A–B", "seen"), ("A–A", "seen"), ("A–A", "unseen")]
        );
        assert_eq!(rows[0].n, [20, 20]);
        assert_eq!(rows[2].n, [3, 3]);
        assert!(rows[0].colour_fd.unwrap() > 0.1, "{:?}", rows[0]);
        assert!(
            rows[1].colour_fd.unwrap() < 1e-9,
            "the same sample: {:?}",
            rows[1]
        );
        assert!(rows.iter().all(|r| r.fid.is_none() && r.kid.is_none()));
        let notes = fid_notes(&Err("no weights at X".into()), &rows, &cfg);
        assert_eq!(notes, ["FID and KID not computed: no weights at X"]);
    }
}
