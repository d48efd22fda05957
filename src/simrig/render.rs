//! Pictures of the simulator for people: the scene `rig sim render` draws (finite-layer contact,
//! Coulomb friction, every image effect), and the labelled contact sheet of indenters with its
//! tiny built-in bitmap font.

use std::sync::Arc;

use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use super::sim::contact::FrictionModel;
use super::sim::optics::ImageEffects;
use super::sim::{Effects, IndenterPose, Scene};

/// The scene of `rig sim render`: the sensor physics of a run ([`Effects::sensor`]) held at one
/// contact state (one shear step from the unloaded gel, relaxed: no viscoelastic overshoot),
/// and the image effects of the sensor's `[optics.effects]` (what its recordings show).
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
    let optics = config.optics.clone().unwrap_or_default();
    let effects = ImageEffects::from_optics(&optics);
    scene.optics = Some(optics);
    scene.effects = Effects {
        friction: FrictionModel::Monotonic,
        viscoelastic: None,
        image: Some(effects),
        ..Effects::sensor(&config.elastomer)
    };
    scene
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
