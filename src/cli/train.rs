//! `rig train translate|force` and `rig eval`: the trainer's command line. The training itself
//! is [`crate::train`].

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};

use crate::train::modality::Modality;
use crate::train::{Progress, TrainerConfig, cyclegan, data, eval, force, report};
use rig_nn::Depth;

#[derive(Debug, Args)]
pub struct TrainArgs {
    #[command(subcommand)]
    pub command: TrainCommand,
}

#[derive(Debug, Subcommand)]
pub enum TrainCommand {
    /// CycleGAN: translate the source sensor's images into the target sensor's style.
    Translate(TranslateArgs),
    /// Train the force model (encoder + LSTM) on labelled (translated or source) sequences.
    Force(ForceArgs),
}

#[derive(Debug, Args)]
pub struct Common {
    /// Trainer settings (TOML with `[data]`, `[translate]`, `[force]`); paper defaults otherwise.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Network input size, WIDTHxHEIGHT (multiples of 4).
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Random seed of the weights and the batch order (default: the config's, 1).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Epochs to train (default: the config's; the paper's 30 for the translator, 20 for the
    /// force model).
    #[arg(long)]
    pub epochs: Option<usize>,
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or("expected WIDTHxHEIGHT, e.g. 64x48")?;
    let w: u32 = w.trim().parse().map_err(|_| format!("bad width {w:?}"))?;
    let h: u32 = h.trim().parse().map_err(|_| format!("bad height {h:?}"))?;
    if w < 8 || h < 8 || !w.is_multiple_of(4) || !h.is_multiple_of(4) {
        return Err(format!(
            "{w}x{h}: width and height must be multiples of 4, at least 8"
        ));
    }
    Ok((w, h))
}

impl Common {
    fn config(&self) -> anyhow::Result<TrainerConfig> {
        let mut c = TrainerConfig::load(self.config.as_deref())?;
        if let Some((w, h)) = self.size {
            c.data.width = w;
            c.data.height = h;
        }
        if let Some(s) = self.seed {
            c.translate.seed = s;
            c.force.seed = s;
        }
        if let Some(e) = self.epochs {
            c.translate.epochs = e;
            c.force.epochs = e;
        }
        Ok(c)
    }
}

#[derive(Debug, Args)]
pub struct TranslateArgs {
    /// The labelled source-sensor dataset (a `rig run` output, or a directory of them).
    #[arg(long)]
    pub source: PathBuf,
    /// The target sensor's dataset (only its images are read).
    #[arg(long)]
    pub target: PathBuf,
    /// Where `translated/` (the source images in the target's style, with the source forces),
    /// `translator/` (the weights), `samples/` and the FID/KID table (`results.md`) go.
    #[arg(long)]
    pub out: PathBuf,
    /// Iterations per epoch (default: one pass over the larger image set).
    #[arg(long)]
    pub steps_per_epoch: Option<usize>,
    /// Inception weights for FID/KID (default: $RIG_INCEPTION_WEIGHTS, else
    /// ~/.cache/rig/inception-fid.safetensors, written by scripts/fetch-inception).
    #[arg(long, value_name = "FILE")]
    pub inception: Option<PathBuf>,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct ForceArgs {
    /// Labelled data: the translated dataset (`<translate out>/translated`) or a source dataset
    /// (the source-only baseline).
    #[arg(long)]
    pub data: PathBuf,
    /// The model directory: weights (`model.safetensors`) after every epoch, the state
    /// `--resume` needs, and the training log.
    #[arg(long)]
    pub out: PathBuf,
    /// The control group: the encoder's embedding straight into the MLP.
    #[arg(long)]
    pub no_lstm: bool,
    /// What the model reads: the paper's `rgb+marker` (R+M), `rgb` (R) or `marker` (M); or
    /// `flow` (D: the markers' displacement from each trajectory's first frame, in mm on a fixed
    /// grid) or `flow+shading` (D+S: the same, with the gel's shading change since the first
    /// frame). Train D and D+S on the source's recordings; they need no translation.
    #[arg(long, default_value = "rgb+marker")]
    pub modality: Modality,
    /// ResNet depth of the encoder: 18, 34 or 50 (default: the config's, 18; the paper's is 50).
    #[arg(long)]
    pub depth: Option<Depth>,
    /// Name in result tables (default: from the data, the modality and --no-lstm).
    #[arg(long)]
    pub method: Option<String>,
    /// Continue from the checkpoint in --out.
    #[arg(long)]
    pub resume: bool,
    #[command(flatten)]
    pub common: Common,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Model directories (`rig train force --out`); several give one table.
    #[arg(long, required = true, num_args = 1..)]
    pub model: Vec<PathBuf>,
    /// Target-sensor dataset with forces.
    #[arg(long)]
    pub data: PathBuf,
    /// Where results.md/.csv/.json and the plots go (default: the first model's eval/); with
    /// several models, each one's plots and per-indenter table go in models/NAME/ there.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Trainer settings (TOML); `rig eval` reads the seen/unseen split from `[data]` (default:
    /// the paper's split).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
}

pub fn train(args: &TrainArgs) -> anyhow::Result<()> {
    let progress = std::io::stderr().is_terminal();
    match &args.command {
        TrainCommand::Translate(a) => {
            let mut cfg = a.common.config()?;
            if a.steps_per_epoch.is_some() {
                cfg.translate.steps_per_epoch = a.steps_per_epoch;
            }
            let spec = cfg.spec(Modality::RgbMarker);
            let zoom = crate::train::cyclegan::source_zoom(&cfg.translate, &a.source, &a.target)?;
            let source = data::load_labelled_zoomed(&a.source, &spec, zoom, progress)?
                .seen_only(&cfg.data.split);
            let target = data::load_unlabelled(&a.target, &spec, progress)?;
            // Before training: a damaged or missing explicitly named weights file stops here.
            let net = eval::load_inception(a.inception.as_deref(), cfg.fid.batch, false)?;
            let t = cyclegan::translate(
                &source,
                &target,
                &cfg.translate,
                &a.out,
                Progress::bar_or_lines(progress),
            )?;
            // I_s is the source sensor's own frames, also when the translator saw them magnified.
            let source_images = if zoom == 1.0 {
                source.images()
            } else {
                let mut raw = data::load_unlabelled(&a.source, &spec, progress)?;
                raw.trajectories
                    .retain(|t| cfg.data.split.trains_on(&t.indenter));
                raw
            };
            let translated_images = t.set.images();
            let mut table = report::Table {
                fid: eval::translation_fid(
                    [&source_images, &target, &translated_images],
                    &cfg.data.split,
                    &cfg.fid,
                    net.as_ref().ok(),
                    progress,
                )?,
                ..Default::default()
            };
            table.fid_notes = eval::fid_notes(&net, &table.fid, &cfg.fid);
            table.write(&a.out)?;
            println!(
                "translated {} source trajectories into {} (cycle loss {:.3} after {} iterations); samples in {}",
                t.set.trajectories.len(),
                a.out.join("translated").display(),
                t.info.last.cycle,
                t.info.iterations,
                a.out.join("samples").display()
            );
            print!("{}", table.markdown());
            Ok(())
        }
        TrainCommand::Force(a) => {
            let mut cfg = a.common.config()?;
            if a.no_lstm {
                cfg.force.lstm = false;
            }
            if let Some(d) = a.depth {
                cfg.force.depth = d;
            }
            let spec = cfg.spec(a.modality);
            let set = data::load_labelled(&a.data, &spec, progress)?.seen_only(&cfg.data.split);
            let method = a.method.clone().unwrap_or_else(|| {
                let role = data::role_of(&a.data).ok();
                default_method(role.as_deref(), a.modality, a.no_lstm)
            });
            let r = force::train(
                &set,
                &cfg.force,
                &method,
                &a.out,
                a.resume,
                Progress::bar_or_lines(progress),
            )?;
            println!(
                "{method}: {} epochs, loss {:.4}, {:.1} sequences/s ({:.0} images/s); model in {}",
                r.epochs_done,
                r.last_loss,
                r.sequences_per_s,
                r.images_per_s,
                a.out.display()
            );
            Ok(())
        }
    }
}

pub fn eval(args: &EvalArgs) -> anyhow::Result<()> {
    let progress = std::io::stderr().is_terminal();
    let cfg = TrainerConfig::load(args.config.as_deref())?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| args.model[0].join("eval"));
    let mut table = report::Table::default();
    let dirs = plot_dirs(&out, &args.model);
    for (m, plots) in args.model.iter().zip(&dirs) {
        table.rows.extend(eval::evaluate(
            m,
            &args.data,
            plots,
            &cfg.data.split,
            progress,
        )?);
    }
    if args.model.len() > 1 {
        println!(
            "each model's plots and per-indenter table in {}",
            out.join("models").display()
        );
    }
    table.write(&out)?;
    print!("{}", table.markdown());
    println!("results in {}", out.display());
    Ok(())
}

/// Where each model's plots and per-indenter table go: `out` for one model; for several,
/// `out/models/NAME` (NAME its directory's name, numbered when two share one), as `rig
/// reproduce` lays them out, so that models of one method do not overwrite each other's files.
fn plot_dirs(out: &Path, models: &[PathBuf]) -> Vec<PathBuf> {
    if models.len() <= 1 {
        return vec![out.to_path_buf(); models.len()];
    }
    let mut used = std::collections::HashSet::new();
    models
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let base = m.file_name().map_or_else(
                || format!("model-{}", k + 1),
                |n| n.to_string_lossy().into_owned(),
            );
            let mut name = base.clone();
            let mut n = 2;
            while !used.insert(name.clone()) {
                name = format!("{base}-{n}");
                n += 1;
            }
            out.join("models").join(name)
        })
        .collect()
}

/// A force model's name in result tables when `--method` gives none, as `rig reproduce` names
/// its models: a marker-displacement modality (D, D+S) is the marker-flow method whatever it
/// trains on; an image modality is TransForce on translated data (`role`), else source-only.
fn default_method(role: Option<&str>, modality: Modality, no_lstm: bool) -> String {
    let base = if Modality::MARKERS.contains(&modality) {
        crate::train::demo::METHOD_MARKER_FLOW
    } else if role == Some("translated") {
        "TransForce"
    } else {
        "source-only"
    };
    if no_lstm {
        format!("{base} (no LSTM)")
    } else {
        base.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn several_models_get_a_plot_folder_each_and_one_model_the_out_folder() {
        let out = Path::new("/r/eval");
        assert_eq!(
            plot_dirs(out, &[PathBuf::from("/m/a")]),
            vec![out.to_path_buf()]
        );
        let dirs = plot_dirs(
            out,
            &[
                PathBuf::from("/m/ds1"),
                PathBuf::from("/n/ds1"),
                PathBuf::from("/m/ds2/"),
                PathBuf::from("/"),
            ],
        );
        assert_eq!(
            dirs,
            [
                "/r/eval/models/ds1",
                "/r/eval/models/ds1-2",
                "/r/eval/models/ds2",
                "/r/eval/models/model-4",
            ]
            .map(PathBuf::from)
        );
    }

    #[test]
    fn a_model_is_named_by_its_modality_and_data_as_the_reproduce_names_it() {
        for (role, modality, no_lstm, want) in [
            (Some("source"), Modality::FlowShading, false, "marker flow"),
            (
                Some("source"),
                Modality::Flow,
                true,
                "marker flow (no LSTM)",
            ),
            (Some("translated"), Modality::RgbMarker, false, "TransForce"),
            (
                Some("translated"),
                Modality::Marker,
                true,
                "TransForce (no LSTM)",
            ),
            (Some("source"), Modality::Rgb, false, "source-only"),
            (None, Modality::Rgb, true, "source-only (no LSTM)"),
        ] {
            assert_eq!(
                default_method(role, modality, no_lstm),
                want,
                "{role:?} {modality:?}"
            );
        }
    }
}
