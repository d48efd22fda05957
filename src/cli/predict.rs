//! `rig predict`: a trained force model reading the target sensor's camera, frame by frame;
//! estimates on stdout (JSON lines or CSV), optionally into an MCAP file and the live view, a
//! summary on stderr. The instrument itself is [`crate::predict`].

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use super::config::{LOCAL_CONFIG, resolve_config};
use crate::predict::output::{Format, Output, predicted_channel};
use crate::predict::session::{self, Feed, Summary};
use crate::predict::source::{Camera, Replay, SimRun, marker_of};
use crate::predict::{DEFAULT_TARE_FRAMES, Predictor, PredictorOptions};

/// Arguments of `rig predict`.
#[derive(Debug, Args)]
pub struct PredictArgs {
    /// The model directory (`rig train force --out`).
    #[arg(long, value_name = "DIR")]
    pub model: PathBuf,
    /// Rig config (TOML): a lab rig reads its `[camera]` (V4L2); a simulated rig runs a short
    /// plan on its simulated sensor. Default: ./rig.toml if present, else the built-in
    /// simulated target sensor (rig-configs/sim-target.toml).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Replay a recorded dataset (a `rig run` output or a directory of them) instead of a
    /// camera, with `rig eval`'s windows: its numbers are `rig eval`'s.
    #[arg(long, value_name = "DIR")]
    pub replay: Option<PathBuf>,
    /// Replay speed against the recorded timing (1 = as recorded), or `max`: as fast as the
    /// model goes, every frame estimated.
    #[arg(long, value_name = "X|max", default_value = "1", value_parser = parse_speed)]
    pub replay_speed: ReplaySpeed,
    /// Simulated rig: the indenter the simulated robot presses.
    #[arg(long, value_name = "NAME", default_value = "sphere")]
    pub indenter: String,
    /// Simulated rig: how many trajectories of its plan to run.
    #[arg(long, value_name = "N", default_value_t = 3)]
    pub limit: usize,
    /// Simulated rig: clock speed against real time (1: the camera at its configured rate).
    #[arg(long, value_name = "F", default_value_t = 1.0)]
    pub speed_factor: f64,
    /// V4L2 camera: stop after N frames (default: until Ctrl-C).
    #[arg(long, value_name = "N")]
    pub frames: Option<u64>,
    /// Frames between the LSTM window's frames (default: the stride `rig eval` uses for the
    /// model's typical training trajectory; a replay uses each trajectory's own).
    #[arg(long, value_name = "S", conflicts_with = "replay")]
    pub stride: Option<usize>,
    /// Take a no-contact reference from the first frames and subtract it (default for a camera;
    /// start without contact).
    #[arg(long, conflicts_with = "no_tare")]
    pub tare: bool,
    /// No tare (default for --replay, whose numbers must be `rig eval`'s).
    #[arg(long)]
    pub no_tare: bool,
    /// D+S models: scale the camera's shading change by G to the training sensor's scale
    /// (`rig eval` prints the gain it finds for a recorded dataset of this sensor; a replay
    /// finds it itself). Default 1.
    #[arg(long, value_name = "G", conflicts_with = "replay")]
    pub shading_gain: Option<f64>,
    /// Frames whose estimates make the tare.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_TARE_FRAMES)]
    pub tare_frames: usize,
    /// Serve the live view (Foxglove WebSocket) with the frames and `/predict/wrench` on this
    /// loopback address (default 127.0.0.1:8765).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8765")]
    pub live: Option<std::net::SocketAddr>,
    /// Also serve the live view to pages of this origin (`SCHEME://HOST[:PORT]`, e.g.
    /// `https://app.foxglove.dev` for Foxglove's web app). Repeatable.
    #[arg(long, value_name = "ORIGIN", requires = "live")]
    pub live_allow_origin: Vec<crate::live::AllowedOrigin>,
    /// Also write the estimates into this MCAP file (`/predict/wrench`).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// CSV lines on stdout instead of JSON lines.
    #[arg(long, conflicts_with = "quiet")]
    pub csv: bool,
    /// No lines on stdout, the summary only.
    #[arg(long)]
    pub quiet: bool,
    /// The summary as JSON on stdout at the end (after the lines).
    #[arg(long)]
    pub summary_json: bool,
}

/// `--replay-speed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReplaySpeed {
    Times(f64),
    Max,
}

fn parse_speed(s: &str) -> Result<ReplaySpeed, String> {
    if s.eq_ignore_ascii_case("max") {
        return Ok(ReplaySpeed::Max);
    }
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(ReplaySpeed::Times(x)),
        _ => Err(format!(
            "{s:?}: a positive number (1 = recorded timing) or `max`"
        )),
    }
}

/// The rig config of a live run: `--config`, else ./rig.toml, else the simulated target.
fn live_config(explicit: Option<&Path>) -> anyhow::Result<RigConfig> {
    if explicit.is_some() || Path::new(LOCAL_CONFIG).is_file() {
        return Ok(resolve_config(explicit)?.config);
    }
    eprintln!(
        "note: no --config given and no ./{LOCAL_CONFIG} here; using the built-in simulated \
         target sensor (rig-configs/sim-target.toml)"
    );
    Ok(RigConfig::sim_target())
}

pub fn run(args: &PredictArgs) -> anyhow::Result<()> {
    let summary = predict(args)?;
    eprint!("{}", summary.report());
    if args.summary_json {
        println!("{}", serde_json::to_string(&summary)?);
    }
    Ok(())
}

/// A replay's shading gain: `rig eval`'s for the dataset with the paper's split (the same
/// frames, so the same numbers).
fn replay_shading_gain(info: &crate::train::force::ModelInfo, dir: &Path) -> anyhow::Result<f64> {
    use crate::train::data;
    if info.spec.modality != crate::train::modality::Modality::FlowShading
        || info.shading_mean.is_none()
    {
        // Nothing to scale: no need to read the recording.
        return Ok(1.0);
    }
    // The frames eval reads: the labelled ones, or every frame of a recording without forces.
    let trajectories = if data::has_forces(dir)? {
        data::load_eval(dir, &info.spec, false)?.trajectories
    } else {
        data::load_unlabelled(dir, &info.spec, false)?.trajectories
    };
    Ok(data::shading_gain_of(
        &info.spec,
        &trajectories,
        info.shading_mean,
        &data::Split::default(),
    ))
}

/// `rig predict` without the printing of the summary (for tests).
pub fn predict(args: &PredictArgs) -> anyhow::Result<Summary> {
    let replay = args.replay.is_some();
    let tare = if args.tare {
        true
    } else if args.no_tare {
        false
    } else {
        !replay
    };
    if tare && args.tare_frames == 0 {
        anyhow::bail!("--tare-frames must be at least 1 (or use --no-tare)");
    }
    let config = if replay {
        None
    } else {
        Some(live_config(args.config.as_deref())?)
    };
    let opts = PredictorOptions {
        // A replay sets each trajectory's own stride; the model's default is not needed.
        stride: if replay { Some(1) } else { args.stride },
        tare_frames: if tare { args.tare_frames } else { 0 },
        marker: config.as_ref().map(marker_of).unwrap_or_default(),
        optics: config.as_ref().and_then(|c| c.optics.clone()),
    };
    let mut predictor = Predictor::load(&args.model, opts)?;
    let gain = match (&args.replay, args.shading_gain) {
        (_, Some(g)) => g,
        (Some(dir), None) => replay_shading_gain(predictor.info(), dir)?,
        (None, None) => 1.0,
    };
    predictor.set_shading_gain(gain)?;
    if gain != 1.0 {
        eprintln!("the shading change scaled ×{gain:.3} to the training sensor's");
    }
    if let Some(cam) = config.as_ref().and_then(|c| c.camera.as_ref()) {
        predictor
            .check_frame_size(cam.width_px, cam.height_px)
            .context("the rig config's [camera] does not fit the model")?;
    }
    let info = predictor.info();
    eprintln!(
        "model {} ({}, ResNet-{}, {}×{} {}), window T = {} at stride {}{}",
        args.model.display(),
        info.method,
        info.shape.depth,
        info.spec.width,
        info.spec.height,
        info.spec.modality,
        info.config.seq_len,
        if replay {
            "⌊n/T⌋ per trajectory (as `rig eval`)".to_string()
        } else {
            predictor.stride().to_string()
        },
        if tare {
            format!("; tare from the first {} frames", args.tare_frames)
        } else {
            String::new()
        }
    );
    let rt = tokio::runtime::Runtime::new()?;
    let live = match args.live {
        Some(addr) => {
            let live = rt
                .block_on(crate::live::LiveView::start_with_options(
                    addr,
                    crate::live::LiveOptions {
                        extra: vec![predicted_channel()],
                        allowed_origins: args.live_allow_origin.clone(),
                        ..crate::live::LiveOptions::default()
                    },
                ))
                .map_err(|e| anyhow::anyhow!("cannot start the live view on {addr}: {e}"))?;
            eprintln!(
                "live view: in the Foxglove app, open a Foxglove WebSocket connection to ws://{} \
                 (the force estimate is on /predict/wrench)",
                live.addr()
            );
            Some(Arc::new(live))
        }
        None => None,
    };
    let format = if args.quiet {
        Format::Quiet
    } else if args.csv {
        Format::Csv
    } else {
        Format::Json
    };
    let mut out = Output::new(format, Box::new(std::io::stdout()));
    if let Some(path) = &args.out {
        out = out.with_mcap(path)?;
    }
    if let Some(live) = &live {
        out = out.with_live(live.clone());
    }
    let seq_len = info.config.seq_len;
    // Ctrl-C ends the run like a normal end (the summary, a complete MCAP file); a second one
    // quits at once. (The simulated rig and the camera also stop their sources on it.)
    let stop_on_ctrl_c = |feed: &Arc<Feed>| {
        let feed = feed.clone();
        rt.spawn(async move {
            if tokio::signal::ctrl_c().await.is_ok() {
                feed.request_stop();
                eprintln!("\nCtrl-C: stopping after this frame (Ctrl-C again quits at once)");
                if tokio::signal::ctrl_c().await.is_ok() {
                    std::process::exit(130);
                }
            }
        });
    };
    let summary = if let Some(dir) = &args.replay {
        let speed = match args.replay_speed {
            ReplaySpeed::Max => None,
            ReplaySpeed::Times(x) => Some(x),
        };
        let feed = Arc::new(Feed::new(speed.is_none()));
        stop_on_ctrl_c(&feed);
        let source = Replay {
            dir: dir.clone(),
            speed,
            seq_len,
            live: live.clone(),
        };
        session::run(predictor, feed, move |f| source.run(f), &mut out)?
    } else {
        let config = config.expect("a live run has a config");
        let feed = Arc::new(Feed::new(false));
        stop_on_ctrl_c(&feed);
        if config.robot.simulated {
            let source = SimRun {
                indenter: Indenter::load(&args.indenter)?,
                config,
                limit: args.limit,
                speed_factor: args.speed_factor,
                live: live.clone(),
            };
            eprintln!(
                "simulated rig: {} trajectories of the {} plan, clock ×{}",
                args.limit, args.indenter, args.speed_factor
            );
            session::run(predictor, feed, move |f| source.run(f), &mut out)?
        } else {
            let source = Camera {
                config,
                frames: args.frames,
            };
            session::run(predictor, feed, move |f| source.run(f), &mut out)?
        }
    };
    if let Some(live) = live {
        let s = live.stats();
        tracing::info!(
            "live view: {} messages sent, {} dropped for slow clients",
            s.sent,
            s.dropped
        );
    }
    Ok(summary)
}
