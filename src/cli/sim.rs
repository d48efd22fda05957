//! `rig sim …`: the contact + optics simulator from the command line, so a person can look.
//!
//! - `rig sim render --indenter cone --depth 0.6 --shear 1.0,30 [--config FILE] --out frame.png
//!   [--json]` simulates one contact state (finite-layer boundary elements, Coulomb friction
//!   for the shear) with the config's sensor optics and every image effect, writes the frame and
//!   prints the wrench (`--json`: `{"fx":..,"fy":..,"fz":..,"tx":..,"ty":..,"tz":..}`, N and
//!   N·mm, force on the gel in the sensor surface frame).
//! - `rig sim forces [--indenter all|NAME,…] [--all-depths] [--config FILE] [--csv FILE]`
//!   steps the plan's trajectories through the run's sensor physics, without the robot, and
//!   prints each indenter's peak |Fx|, |Fy|, |Fz|, shear and |F| against the config's force
//!   limit: what a recording will see, in minutes.
//! - `rig sim contact-sheet --depth D --out docs/indenters.png` renders every built-in indenter
//!   at one depth into a labelled grid (labels in a tiny built-in bitmap font).

use std::path::{Path, PathBuf};

use crate::simrig::render::{contact_sheet, render_scene};
use crate::simrig::sim::{Scene, SimOutput, simulate};
use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use rig_core::indenter::Indenter;
use rig_core::wrench::Wrench;

/// Arguments of `rig sim`.
#[derive(Debug, Args)]
pub struct SimArgs {
    #[command(subcommand)]
    pub what: SimCommand,
}

#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Simulate one contact, write the sensor image and print the wrench.
    Render(RenderArgs),
    /// Render every built-in indenter at one depth into one labelled PNG.
    ContactSheet(ContactSheetArgs),
    /// The peak forces the plan will produce, per indenter, from the run's physics.
    Forces(ForcesArgs),
}

/// Arguments of `rig sim forces`.
#[derive(Debug, Args)]
pub struct ForcesArgs {
    /// Indenters: `all` (every built-in one) or comma-separated names or files.
    #[arg(long, value_name = "NAMES", default_value = "all")]
    pub indenter: String,
    /// Every depth of the plan (default: its deepest only, where the forces peak).
    #[arg(long)]
    pub all_depths: bool,
    /// Rig config whose `[elastomer]`, `[plan]` and `[safety]` to use (default as for `rig sim
    /// render`).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Also write the table as CSV.
    #[arg(long, value_name = "FILE")]
    pub csv: Option<PathBuf>,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

/// Arguments of `rig sim render`.
#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Built-in indenter name (see `rig indenters`) or a path to an indenter .toml or .stl file.
    #[arg(long, value_name = "NAME")]
    pub indenter: String,
    /// Indentation depth below the undeformed surface, mm.
    #[arg(long, value_name = "MM")]
    pub depth: f64,
    /// Shear at depth: distance in mm and direction in degrees from +x, e.g. `1.0,30`.
    #[arg(long, value_name = "MM,DEG", default_value = "0,0")]
    pub shear: String,
    /// Contact point on the gel, mm, e.g. `0,0` (the default, the gel centre).
    #[arg(long, value_name = "X,Y", default_value = "0,0")]
    pub at: String,
    /// Rig config (TOML) whose `[elastomer]` and `[optics]` to use. Default: ./rig.toml if present,
    /// else the built-in simulated source sensor.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where to write the PNG frame.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
    /// Print the wrench as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Arguments of `rig sim contact-sheet`.
#[derive(Debug, Args)]
pub struct ContactSheetArgs {
    /// Indentation depth of every indenter, mm.
    #[arg(long, value_name = "MM", default_value_t = 0.6)]
    pub depth: f64,
    /// Rig config whose optics to use (default as for `rig sim render`).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Where to write the PNG.
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
}

pub fn run(args: &SimArgs) -> anyhow::Result<()> {
    match &args.what {
        SimCommand::Render(a) => render_command(a),
        SimCommand::ContactSheet(a) => contact_sheet_command(a),
        SimCommand::Forces(a) => forces_command(a),
    }
}

/// Parses `a,b` into two finite numbers.
fn pair(text: &str, what: &str) -> anyhow::Result<[f64; 2]> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let parsed: Option<Vec<f64>> = parts
        .iter()
        .map(|p| p.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect();
    match parsed.as_deref() {
        Some([a, b]) => Ok([*a, *b]),
        _ => bail!("{what} {text:?}: expected two numbers separated by a comma, e.g. 1.0,30"),
    }
}

fn simulate_checked(scene: &Scene) -> anyhow::Result<SimOutput> {
    if !(scene.pose.depth_mm.is_finite() && scene.pose.depth_mm >= 0.0) {
        bail!("--depth {}: must be a number ≥ 0 (mm)", scene.pose.depth_mm);
    }
    let out = simulate(scene).map_err(|e| anyhow::anyhow!("cannot simulate: {e}"))?;
    Ok(out)
}

fn render_command(args: &RenderArgs) -> anyhow::Result<()> {
    let loaded = super::config::resolve_config(args.config.as_deref())?;
    let indenter = Indenter::load(&args.indenter)?;
    let [dist, angle] = pair(&args.shear, "--shear")?;
    let at = pair(&args.at, "--at")?;
    let (s, c) = angle.to_radians().sin_cos();
    let scene = render_scene(
        &loaded.config,
        indenter,
        at,
        args.depth,
        [dist * c, dist * s],
    );
    let out = simulate_checked(&scene)?;
    let image = out
        .image
        .as_ref()
        .context("the simulator returned no image for an image scene")?;
    save_png(image, &args.out)?;
    print_wrench(&out.wrench, args.json);
    if !args.json {
        println!(
            "contact area {:.2} mm²; frame {} × {} written to {}",
            out.contact_area_mm2,
            image.width(),
            image.height(),
            args.out.display()
        );
    }
    Ok(())
}

fn print_wrench(w: &Wrench, json: bool) {
    let [fx, fy, fz] = w.force_n;
    let [tx, ty, tz] = w.torque_nmm;
    if json {
        println!(
            "{}",
            serde_json::json!({"fx": fx, "fy": fy, "fz": fz, "tx": tx, "ty": ty, "tz": tz})
        );
    } else {
        println!("force  N    fx {fx:9.4}  fy {fy:9.4}  fz {fz:9.4}");
        println!("torque N·mm tx {tx:9.4}  ty {ty:9.4}  tz {tz:9.4}");
    }
}

fn save_png(image: &image::RgbImage, path: &Path) -> anyhow::Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create directory {}", dir.display()))?;
    }
    image
        .save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("cannot write {}", path.display()))
}

fn contact_sheet_command(args: &ContactSheetArgs) -> anyhow::Result<()> {
    let loaded = super::config::resolve_config(args.config.as_deref())?;
    let names = Indenter::list_builtin();
    let mut tiles = Vec::with_capacity(names.len());
    for name in names {
        let indenter = Indenter::builtin(name)?;
        let scene = render_scene(&loaded.config, indenter, [0.0, 0.0], args.depth, [0.0, 0.0]);
        let out = simulate_checked(&scene).with_context(|| format!("indenter {name}"))?;
        let image = out.image.context("no image")?;
        eprintln!("{name:>12}: fz {:8.3} N", out.wrench.force_n[2]);
        tiles.push((name.to_string(), image));
    }
    let sheet = contact_sheet(&tiles, &format!("depth {} mm", args.depth));
    save_png(&sheet, &args.out)?;
    println!(
        "{} indenters at {} mm written to {}",
        tiles.len(),
        args.depth,
        args.out.display()
    );
    Ok(())
}

fn forces_command(args: &ForcesArgs) -> anyhow::Result<()> {
    use crate::simrig::DEFAULT_PHYSICS_RATE_HZ;
    use crate::simrig::forces::plan_forces;
    let loaded = super::config::resolve_config(args.config.as_deref())?;
    let config = &loaded.config;
    let names: Vec<String> = if args.indenter == "all" {
        Indenter::list_builtin()
            .iter()
            .map(|s| (*s).to_owned())
            .collect()
    } else {
        args.indenter
            .split(',')
            .map(|s| s.trim().to_owned())
            .collect()
    };
    let indenters = names
        .iter()
        .map(|n| Indenter::load(n).with_context(|| format!("indenter {n}")))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let per = config.plan.contact_points_mm.len()
        * config.plan.directions_deg.len()
        * if args.all_depths {
            config.plan.depths_mm.len()
        } else {
            1
        };
    let bar =
        crate::train::progress_bar(!args.quiet, (per * indenters.len()) as u64, "trajectories");
    let tick = || bar.inc(1);
    let limit = config.safety.max_force_n;
    let mut rows = Vec::new();
    for ind in &indenters {
        let f = plan_forces(
            config,
            ind,
            !args.all_depths,
            DEFAULT_PHYSICS_RATE_HZ,
            &tick,
        )
        .map_err(|e| anyhow::anyhow!("indenter {}: cannot simulate: {e}", ind.name()))?;
        rows.push(f);
    }
    bar.finish_and_clear();
    println!(
        "{:<12} {:>6} {:>8} {:>8} {:>8} {:>8} {:>8} {:>10}  limit {limit} N",
        "indenter", "traj", "|Fx|", "|Fy|", "|Fz|", "shear", "|F|", "gross slip"
    );
    let mut csv = String::from(
        "indenter,trajectories,max_abs_fx_n,max_abs_fy_n,max_abs_fz_n,max_shear_n,max_norm_n,gross_slip_trajectories,over_limit\n",
    );
    for r in &rows {
        let over = r.max_norm_n > limit;
        println!(
            "{:<12} {:>6} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>8.3} {:>10}{}",
            r.indenter,
            r.trajectories,
            r.max_abs_n[0],
            r.max_abs_n[1],
            r.max_abs_n[2],
            r.max_shear_n,
            r.max_norm_n,
            r.gross_slip,
            if over {
                "  OVER THE LIMIT: a run trips"
            } else {
                ""
            }
        );
        csv.push_str(&format!(
            "{},{},{:.4},{:.4},{:.4},{:.4},{:.4},{},{}\n",
            r.indenter,
            r.trajectories,
            r.max_abs_n[0],
            r.max_abs_n[1],
            r.max_abs_n[2],
            r.max_shear_n,
            r.max_norm_n,
            r.gross_slip,
            over
        ));
    }
    if let Some(path) = &args.csv {
        std::fs::write(path, csv).with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}
