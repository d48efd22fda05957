//! Matching two sensors' marker pitches before translation.
//!
//! A CycleGAN translator carries the source's marker motion (shear) to the target's style only
//! when the two lattices are about as far apart in pixels: with sim-target's markers 22 % coarser
//! than the source's, the generator redraws the target's lattice as a fixed texture and no shear
//! crosses (docs/experiments.md, *The protocol's runs*). A lab knows both gels' marker spacing and
//! both cameras' scale, so the source's frames can be magnified by the ratio of the pitches before
//! the translator sees them. The price is geometry: a contact then looks that much larger in the
//! translated images than the same contact does on the target.
//!
//! The translator's setting that asks for it is [`super::cyclegan::source_zoom`]; the zoom
//! itself is applied as the source's frames are loaded ([`super::data::load_labelled_zoomed`]).

use std::path::Path;

use anyhow::Context;

use crate::record::manifest::Manifest;

/// The marker pitch of the recordings in `dir` as a fraction of the frame's width (spacing,
/// mm, over the width the camera sees, mm), from the rig config in the first run's manifest;
/// `None` when it does not say (a lab rig without `[optics.markers]`, or markers off).
pub fn marker_pitch(dir: &Path) -> anyhow::Result<Option<f64>> {
    let runs = super::data::find_runs(dir)?;
    let Some(run) = runs.first() else {
        return Ok(None);
    };
    let m = Manifest::load(run).map_err(anyhow::Error::msg)?;
    Ok(pitch_of(&m.config))
}

fn pitch_of(config: &serde_json::Value) -> Option<f64> {
    let optics = &config["optics"];
    if optics["effects"]["markers"].as_bool() == Some(false) {
        return None;
    }
    let spacing = optics["markers"]["spacing_mm"].as_f64()?;
    let mm_px = optics["mm_per_px"].as_f64()?;
    let width = optics["width_px"].as_f64()?;
    let pitch = spacing / (mm_px * width);
    (pitch.is_finite() && pitch > 0.0).then_some(pitch)
}

/// How many times the source's frames are magnified so that its markers lie as far apart in
/// the frame as the target's: the target's pitch over the source's.
pub fn pitch_zoom(source: &Path, target: &Path) -> anyhow::Result<f64> {
    let pitch = |dir: &Path, which: &str| {
        marker_pitch(dir)?.with_context(|| {
            format!(
                "matching marker pitches needs the {which} recordings' marker spacing and camera \
                 scale ([optics] mm_per_px, width_px and [optics.markers] spacing_mm in the rig \
                 config their manifest holds), and {} does not say them",
                dir.display()
            )
        })
    };
    let z = pitch(target, "target")? / pitch(source, "source")?;
    anyhow::ensure!(
        (0.25..=4.0).contains(&z),
        "the target's marker pitch is {z:.2} × the source's: too far apart to match by zooming"
    );
    Ok(z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pitch_is_the_spacing_over_the_width_the_camera_sees() {
        let config = |spacing: f64, mm_px: f64, markers: bool| {
            serde_json::json!({ "optics": {
                "mm_per_px": mm_px, "width_px": 320,
                "effects": { "markers": markers },
                "markers": { "spacing_mm": spacing },
            }})
        };
        // sim-source (0.9 mm over 10 mm) and sim-target (1.1 mm over 10 mm).
        let s = pitch_of(&config(0.9, 0.03125, true)).unwrap();
        let t = pitch_of(&config(1.1, 0.03125, true)).unwrap();
        assert!((s - 0.09).abs() < 1e-12 && (t / s - 1.1 / 0.9).abs() < 1e-12);
        // The same gel seen over a field 1.22 × wider: the pitch in the frame shrinks with it.
        let wide = pitch_of(&config(1.1, 0.03125 * 1.1 / 0.9, true)).unwrap();
        assert!((wide - s).abs() < 1e-12);
        assert_eq!(pitch_of(&config(0.9, 0.03125, false)), None);
        assert_eq!(pitch_of(&serde_json::json!({})), None);
    }
}
