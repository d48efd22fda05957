//! PNG charts: plotters' bitmap backend, with the text drawn by `ab_glyph` in a font of the
//! system's (plotters' own bitmap text needs a font library the build does not carry).
//!
//! The font is the first of `$RIG_FONT` and a few usual places that parses (DejaVu Sans,
//! Liberation Sans, …). Without one the chart is still drawn, without its text, and a warning
//! says what to install.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use ab_glyph::{Font, FontArc, PxScale, ScaleFont, point};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters_backend::text_anchor::{HPos, VPos};
use plotters_backend::{
    BackendColor, BackendCoord, BackendStyle, BackendTextStyle, DrawingErrorKind,
};

/// A drawing area of a PNG chart.
pub type PngArea<'a> = DrawingArea<PngBackend<'a>, Shift>;

/// Draws a chart of `size` pixels on a white page and writes it to `path` as PNG.
pub fn png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&PngArea<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let mut buf = vec![255u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = PngBackend {
            inner: BitMapBackend::with_buffer(&mut buf, size),
            font: font(),
        }
        .into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    let img = image::RgbImage::from_raw(size.0, size.1, buf)
        .ok_or_else(|| anyhow::anyhow!("chart buffer of the wrong size"))?;
    img.save(path)
        .map_err(|e| anyhow::anyhow!("writing {}: {e}", path.display()))
}

/// Places a sans-serif TrueType font is usually found.
const FONT_PLACES: [&str; 6] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
    "/Library/Fonts/Arial.ttf",
];

/// The charts' font, found once (see the module docs).
pub fn font() -> Option<&'static FontArc> {
    static FONT: OnceLock<Option<FontArc>> = OnceLock::new();
    FONT.get_or_init(|| {
        let named = std::env::var_os("RIG_FONT").map(PathBuf::from);
        let found = named
            .into_iter()
            .chain(FONT_PLACES.iter().map(PathBuf::from))
            .find_map(|p| FontArc::try_from_vec(std::fs::read(&p).ok()?).ok());
        if found.is_none() {
            tracing::warn!(
                "no font for the PNG charts' text (set RIG_FONT to a .ttf file, or install \
                 fonts-dejavu-core): the charts are drawn without their labels"
            );
        }
        found
    })
    .as_ref()
}

/// The bitmap backend with text of its own.
pub struct PngBackend<'a> {
    inner: BitMapBackend<'a>,
    font: Option<&'static FontArc>,
}

/// The size of horizontal `text` at `px` pixels: its advance and the font's line height.
fn text_size(font: &FontArc, px: f32, text: &str) -> (f32, f32) {
    let f = font.as_scaled(PxScale::from(px));
    let mut w = 0.0;
    let mut prev = None;
    for c in text.chars() {
        let g = f.glyph_id(c);
        if let Some(p) = prev {
            w += f.kern(p, g);
        }
        w += f.h_advance(g);
        prev = Some(g);
    }
    (w, f.ascent() - f.descent())
}

impl DrawingBackend for PngBackend<'_> {
    type ErrorType = <BitMapBackend<'static> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }
    fn ensure_prepared(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.ensure_prepared()
    }
    fn present(&mut self) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.present()
    }
    fn draw_pixel(
        &mut self,
        point: BackendCoord,
        color: BackendColor,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_pixel(point, color)
    }
    fn draw_line<S: BackendStyle>(
        &mut self,
        from: BackendCoord,
        to: BackendCoord,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_line(from, to, style)
    }
    fn draw_rect<S: BackendStyle>(
        &mut self,
        upper_left: BackendCoord,
        bottom_right: BackendCoord,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_rect(upper_left, bottom_right, style, fill)
    }
    fn draw_path<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_path(path, style)
    }
    fn draw_circle<S: BackendStyle>(
        &mut self,
        center: BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.draw_circle(center, radius, style, fill)
    }
    fn fill_polygon<S: BackendStyle, I: IntoIterator<Item = BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        self.inner.fill_polygon(vert, style)
    }

    fn estimate_text_size<T: BackendTextStyle>(
        &self,
        text: &str,
        style: &T,
    ) -> Result<(u32, u32), DrawingErrorKind<Self::ErrorType>> {
        let (w, h) = match self.font {
            Some(f) => text_size(f, style.size() as f32, text),
            // No font: the space the text would take, so the layout stays the same.
            None => (
                0.55 * style.size() as f32 * text.chars().count() as f32,
                style.size() as f32,
            ),
        };
        Ok((w.ceil() as u32, h.ceil() as u32))
    }

    fn draw_text<T: BackendTextStyle>(
        &mut self,
        text: &str,
        style: &T,
        pos: BackendCoord,
    ) -> Result<(), DrawingErrorKind<Self::ErrorType>> {
        let color = style.color();
        let Some(font) = self.font else {
            return Ok(());
        };
        if color.alpha == 0.0 || text.is_empty() {
            return Ok(());
        }
        let px = style.size() as f32;
        let (w, h) = text_size(font, px, text);
        let anchor = style.anchor();
        // The text's top-left corner relative to the anchor, before the rotation.
        let dx = match anchor.h_pos {
            HPos::Left => 0.0,
            HPos::Center => -w / 2.0,
            HPos::Right => -w,
        };
        let dy = match anchor.v_pos {
            VPos::Top => 0.0,
            VPos::Center => -h / 2.0,
            VPos::Bottom => -h,
        };
        let scaled = font.as_scaled(PxScale::from(px));
        let baseline = scaled.ascent();
        let transform = style.transform();
        let (width, height) = self.get_size();
        let mut x = 0.0;
        let mut prev = None;
        for c in text.chars() {
            let id = scaled.glyph_id(c);
            if let Some(p) = prev {
                x += scaled.kern(p, id);
            }
            let glyph = id.with_scale_and_position(px, point(x, baseline));
            x += scaled.h_advance(id);
            prev = Some(id);
            let Some(outline) = font.outline_glyph(glyph) else {
                continue;
            };
            let b = outline.px_bounds();
            let mut result = Ok(());
            outline.draw(|gx, gy, coverage| {
                if result.is_err() || coverage <= 0.0 {
                    return;
                }
                let lx = (b.min.x + gx as f32 + dx).round() as i32;
                let ly = (b.min.y + gy as f32 + dy).round() as i32;
                let (tx, ty) = transform.transform(lx, ly);
                let (px, py) = (pos.0 + tx, pos.1 + ty);
                if px >= 0 && py >= 0 && (px as u32) < width && (py as u32) < height {
                    result = self.inner.draw_pixel(
                        (px, py),
                        BackendColor {
                            alpha: color.alpha * coverage.min(1.0) as f64,
                            rgb: color.rgb,
                        },
                    );
                }
            });
            result?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{font, png};
    use plotters::prelude::*;

    /// The PNG has the requested size, a white page, the drawn line's colour, and (where the
    /// machine has a font) dark text pixels inside the caption's box only.
    #[test]
    fn a_png_chart_has_its_page_its_line_and_its_caption() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("c.png");
        png(&path, (320, 200), |root| {
            let mut chart = ChartBuilder::on(root)
                .caption("Fz (N)", ("sans-serif", 24))
                .margin(10)
                .build_cartesian_2d(0.0..1.0, 0.0..1.0)?;
            chart.draw_series(LineSeries::new(
                [(0.0, 0.5), (1.0, 0.5)],
                RED.stroke_width(3),
            ))?;
            Ok(())
        })
        .unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (320, 200));
        assert_eq!(img.get_pixel(2, 199).0, [255, 255, 255]);
        let red = img.pixels().filter(|p| p.0 == [255, 0, 0]).count();
        assert!(
            red > 3 * 250,
            "{red} red pixels for a 3 px line across the chart"
        );
        let dark: Vec<(u32, u32)> = img
            .enumerate_pixels()
            .filter(|(_, _, p)| p.0.iter().all(|&c| c < 100))
            .map(|(x, y, _)| (x, y))
            .collect();
        if font().is_some() {
            assert!(
                dark.len() > 30,
                "the caption drew {} dark pixels",
                dark.len()
            );
            // The caption is centred on top: every dark pixel in the top 40 rows, near the middle.
            assert!(
                dark.iter().all(|&(x, y)| y < 40 && (100..220).contains(&x)),
                "{:?}",
                dark.iter()
                    .find(|&&(x, y)| !(y < 40 && (100..220).contains(&x)))
            );
        } else {
            assert!(dark.is_empty());
        }
    }
}
