//! `rig sim …`: the contact + optics simulator from the command line, so a person can look.
//!
//! - `rig sim render --indenter cone --depth 0.6 --shear 1.0,30 [--config FILE] --out frame.png
//!   [--json]` simulates one contact state (finite-layer boundary elements, Coulomb friction
//!   for the shear) with the config's sensor optics and every image effect, writes the frame and
//!   prints the wrench (`--json`: `{"fx":..,"fy":..,"fz":..,"tx":..,"ty":..,"tz":..}`, N and
//!   N·mm, force on the gel in the sensor surface frame).
//! - `rig sim contact-sheet --depth D --out docs/indenters.png` renders every built-in indenter
//!   at one depth into a labelled grid (labels in a tiny built-in bitmap font).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use hardware_mocks::sim::contact::{ContactModel, FrictionModel};
use hardware_mocks::sim::optics::ImageEffects;
use hardware_mocks::sim::{Effects, IndenterPose, Scene, SimOutput, simulate};
use rig_core::config::RigConfig;
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
    /// Rig config (TOML) whose [elastomer] and [optics] to use. Default: ./rig.toml if present,
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

/// The scene of `rig sim render`: layer BEM, monotonic Coulomb friction, every image effect.
pub fn render_scene(
    config: &RigConfig,
    indenter: Indenter,
    contact_mm: [f64; 2],
    depth_mm: f64,
    shear_mm: [f64; 2],
) -> Scene {
    let mut scene = Scene::new(
        config.elastomer.clone(),
        Arc::new(indenter),
        IndenterPose {
            contact_mm,
            depth_mm,
            shear_mm,
        },
    );
    scene.optics = Some(config.optics.clone().unwrap_or_default());
    scene.effects = Effects {
        contact: ContactModel::Layer,
        friction: FrictionModel::Monotonic,
        image: Some(ImageEffects::realistic()),
        ..Effects::default()
    };
    scene
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

/// Lays tiles out in a grid of 5 columns, each with its label underneath, and a title on top.
pub fn contact_sheet(tiles: &[(String, image::RgbImage)], title: &str) -> image::RgbImage {
    const COLS: u32 = 5;
    const PAD: u32 = 6;
    const LABEL: u32 = 2 * 8 + 4;
    let (tw, th) = tiles.first().map_or((320, 240), |(_, t)| t.dimensions());
    let rows = (tiles.len() as u32).div_ceil(COLS).max(1);
    let header = LABEL + PAD;
    let width = COLS * (tw + PAD) + PAD;
    let height = header + rows * (th + LABEL + PAD) + PAD;
    let mut sheet = image::RgbImage::from_pixel(width, height, image::Rgb([24, 24, 28]));
    draw_text(&mut sheet, PAD, PAD, title, 2, [230, 230, 230]);
    for (k, (name, tile)) in tiles.iter().enumerate() {
        let (col, row) = (k as u32 % COLS, k as u32 / COLS);
        let x0 = PAD + col * (tw + PAD);
        let y0 = header + row * (th + LABEL + PAD);
        image::imageops::replace(&mut sheet, tile, i64::from(x0), i64::from(y0));
        draw_text(&mut sheet, x0 + 2, y0 + th + 3, name, 2, [230, 230, 230]);
    }
    sheet
}

/// Draws `text` with the built-in 5 × 7 font, each font pixel `scale` × `scale`.
pub fn draw_text(img: &mut image::RgbImage, x: u32, y: u32, text: &str, scale: u32, rgb: [u8; 3]) {
    let mut cx = x;
    for ch in text.chars() {
        let rows = glyph(ch.to_ascii_lowercase());
        for (r, bits) in rows.iter().enumerate() {
            for c in 0..5u32 {
                if bits & (0b10000 >> c) == 0 {
                    continue;
                }
                for dy in 0..scale {
                    for dx in 0..scale {
                        let (px, py) = (cx + c * scale + dx, y + r as u32 * scale + dy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, image::Rgb(rgb));
                        }
                    }
                }
            }
        }
        cx += 6 * scale;
    }
}

/// 5 × 7 glyphs, one byte per row, bit 4 the leftmost column. Unknown characters draw a box.
fn glyph(c: char) -> [u8; 7] {
    match c {
        'a' => [0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'b' => [0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E],
        'c' => [0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E],
        'd' => [0x1E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1E],
        'e' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F],
        'f' => [0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10],
        'g' => [0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F],
        'h' => [0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11],
        'i' => [0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E],
        'j' => [0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C],
        'k' => [0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11],
        'l' => [0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F],
        'm' => [0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11],
        'n' => [0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11],
        'o' => [0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'p' => [0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10],
        'q' => [0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D],
        'r' => [0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11],
        's' => [0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E],
        't' => [0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04],
        'u' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E],
        'v' => [0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04],
        'w' => [0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A],
        'x' => [0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11],
        'y' => [0x11, 0x11, 0x0A, 0x04, 0x04, 0x04, 0x04],
        'z' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F],
        '0' => [0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E],
        '1' => [0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E],
        '2' => [0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F],
        '3' => [0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E],
        '4' => [0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02],
        '5' => [0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E],
        '6' => [0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E],
        '7' => [0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E],
        '9' => [0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C],
        '.' => [0, 0, 0, 0, 0, 0x0C, 0x0C],
        ',' => [0, 0, 0, 0, 0x0C, 0x04, 0x08],
        '_' => [0, 0, 0, 0, 0, 0, 0x1F],
        '-' => [0, 0, 0, 0x1F, 0, 0, 0],
        ' ' => [0; 7],
        _ => [0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F],
    }
}
