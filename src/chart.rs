//! The house style of the SVG charts that benchmarks and evaluations write: a white page, a
//! captioned chart with room for the axis labels, and a boxed legend. One place, so every plot
//! a person compares looks alike.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

mod png;
pub use png::{PngArea, PngBackend, font, png};

/// A drawing area of an SVG file.
pub type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Writes the SVG `path` of `size` pixels: a white page that `draw` draws on.
pub fn svg(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&Area<'_>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let root = SVGBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    draw(&root)?;
    root.present()?;
    Ok(())
}

/// A chart on `area` with `caption` on top and room for the axis labels; the caller sets its
/// coordinates.
pub fn builder<'a, 'b>(area: &'a Area<'b>, caption: &str) -> ChartBuilder<'a, 'b, SVGBackend<'b>> {
    let mut b = ChartBuilder::on(area);
    b.caption(caption, ("sans-serif", 20))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(64);
    b
}

/// Draws the legend of the series that have labels.
pub fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| anyhow::anyhow!("drawing the legend: {e}"))
}

/// [`legend`] at `position`, its labels `font_px` high (the multi-panel figures, where the
/// default place would cover the data).
pub fn legend_at<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
    font_px: u32,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .label_font(("sans-serif", font_px))
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .position(position)
        .draw()
        .map_err(|e| anyhow::anyhow!("drawing the legend: {e}"))
}
