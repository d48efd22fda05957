//! GelSight-type sensor optics as configured in a rig config's `[optics]` section.
//!
//! A GelSight sensor is a camera looking through a clear block at the back of a reflective gel
//! pad, lit from the sides by coloured LEDs at a grazing angle. Where an object presses the gel,
//! the surface tilts; a tilted patch faces some LEDs more and others less, so its colour encodes
//! its normal (Johnson & Adelson 2009; Yuan et al. 2017). Black dots printed on the gel
//! ("markers") move with the surface and show shear.
//!
//! This section describes one such sensor for the simulator (`hardware-mocks::sim::optics`):
//!
//! - the image: `width_px` × `height_px` pixels of `mm_per_px` each, centred on the gel centre
//!   (image x along the surface frame's x, image rows running from +y at the top to −y);
//! - `leds`: each LED's colour (linear RGB, 0..1 per channel, may exceed 1 for a bright LED) and
//!   the direction the light comes from (azimuth from +x towards +y, elevation above the gel);
//! - `background`: the colour of the flat, untouched gel and how uneven the illumination is;
//! - `markers`: the printed dot pattern (square grid or hexagonal, spacing, dot size, offset of
//!   the pattern, per-dot position jitter from a seed, dot colour);
//! - `camera_offset_mm`: where the image centre sits on the gel (assembly tolerance);
//! - `camera_rotation_deg`: how far the camera is turned about its axis against the gel
//!   (assembly tolerance; the LEDs turn with it, being mounted in the same housing);
//! - `effects`: what the images show beyond shading (markers, shadows, blur, vignetting,
//!   noise), so each sensor records exactly the effects its camera has.
//!
//! Every value has a default (the shipped source sensor's), so `[optics]` may name only what
//! differs. [`OpticsConfig::problems`] checks the values and names the offending key.

use serde::{Deserialize, Serialize};

use crate::problem::Problem;

/// Largest image side the simulator renders, pixels (a typo must not allocate gigabytes).
pub const MAX_SIDE_PX: u32 = 4096;
/// Most LEDs a sensor may have.
pub const MAX_LEDS: usize = 8;

/// `[optics]`: camera resolution and scale, LEDs, background and marker pattern.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OpticsConfig {
    /// Image width, pixels (GelSight Mini after crop: 320).
    pub width_px: u32,
    /// Image height, pixels (GelSight Mini after crop: 240).
    pub height_px: u32,
    /// Size of one pixel on the gel surface, mm. The default maps 320 px onto the 10 mm gel.
    pub mm_per_px: f64,
    /// How strongly a surface tilt changes the colour: the shading term of each LED is
    /// multiplied by this gain before it is added to the background.
    pub shading_gain: f64,
    /// Strength of the specular highlight of each LED (0: matte gel).
    pub specular: f64,
    /// The LEDs around the gel.
    pub leds: Vec<LedConfig>,
    /// The untouched gel's appearance.
    pub background: BackgroundConfig,
    /// The printed marker pattern.
    pub markers: MarkerConfig,
    /// Where the camera's image centre sits on the gel, mm in the surface frame (assembly
    /// tolerance: a real sensor's camera is rarely centred on its gel to better than a few
    /// tenths of a mm).
    pub camera_offset_mm: [f64; 2],
    /// How far the camera (with its LEDs, in the same housing) is turned about its axis against
    /// the gel, degrees, counter-clockwise seen from the camera: the image's x axis lies along
    /// the gel's x turned by this angle. Assembly tolerance, a degree or two on a real sensor.
    pub camera_rotation_deg: f64,
    /// Which image effects the simulated camera renders (`[optics.effects]`).
    pub effects: EffectsConfig,
}

/// `[optics.effects]`: what the simulated camera's images show beyond the shading of the gel.
/// A recording holds exactly these effects; an effect that is off costs nothing.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EffectsConfig {
    /// Draw the printed markers (none are drawn when `optics.markers.pattern = "none"`).
    pub markers: bool,
    /// Shadows cast by the raised gel in the grazing LED light.
    pub shadows: bool,
    /// Defocus blur, Gaussian σ in pixels; 0: off.
    pub blur_sigma_px: f64,
    /// Darkening towards the image corners, fraction at the corner in [0, 1); 0: off.
    pub vignetting: f64,
    /// Camera noise, Gaussian σ in 8-bit levels; 0: off.
    pub noise_sigma: f64,
}

impl Default for EffectsConfig {
    /// A GelSight Mini's look: markers, shadows, 0.8 px blur, 25 % vignetting, noise σ 1.5.
    fn default() -> Self {
        Self {
            markers: true,
            shadows: true,
            blur_sigma_px: 0.8,
            vignetting: 0.25,
            noise_sigma: 1.5,
        }
    }
}

/// `[[optics.leds]]`: one LED (or LED strip) lighting the gel from the side.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedConfig {
    /// Colour, linear RGB, each channel ≥ 0 (1 = full scale).
    pub rgb: [f64; 3],
    /// Direction the light comes from, degrees from +x towards +y.
    pub azimuth_deg: f64,
    /// Elevation of the light above the gel plane, degrees, in (0, 90]; GelSight LEDs are
    /// grazing (about 20-40°).
    pub elevation_deg: f64,
}

/// `[optics.background]`: the flat gel as the camera sees it without contact.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BackgroundConfig {
    /// Mean colour of the flat gel, linear RGB in [0, 1].
    pub rgb: [f64; 3],
    /// Unevenness of the illumination in [0, 1): each LED brightens the side of the gel it sits
    /// on by up to this fraction of its colour.
    pub uneven: f64,
}

/// Marker layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum MarkerPattern {
    /// Square grid.
    #[default]
    Grid,
    /// Hexagonal (every other row shifted by half a spacing).
    Hex,
    /// No markers printed on this gel.
    None,
}

/// `[optics.markers]`: the dots printed on the gel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MarkerConfig {
    /// `"grid"`, `"hex"` or `"none"`.
    pub pattern: MarkerPattern,
    /// Distance between neighbouring dots, mm.
    pub spacing_mm: f64,
    /// Dot diameter, mm (less than the spacing).
    pub dot_diameter_mm: f64,
    /// Shift of the whole pattern from a dot at the gel centre, mm.
    pub offset_mm: [f64; 2],
    /// Each dot is displaced by up to this much in x and y (printing tolerance), mm; 0: a
    /// perfect pattern. Less than half the free space between dots.
    pub jitter_mm: f64,
    /// Seed of the jitter, so a sensor's dots are the same in every image.
    pub jitter_seed: u64,
    /// Dot colour, linear RGB in [0, 1].
    pub rgb: [f64; 3],
}

impl Default for OpticsConfig {
    fn default() -> Self {
        Self {
            width_px: 320,
            height_px: 240,
            mm_per_px: 10.0 / 320.0,
            shading_gain: 0.9,
            specular: 0.15,
            leds: vec![
                LedConfig {
                    rgb: [0.95, 0.2, 0.15],
                    azimuth_deg: 90.0,
                    elevation_deg: 30.0,
                },
                LedConfig {
                    rgb: [0.15, 0.85, 0.25],
                    azimuth_deg: 210.0,
                    elevation_deg: 30.0,
                },
                LedConfig {
                    rgb: [0.15, 0.3, 0.95],
                    azimuth_deg: 330.0,
                    elevation_deg: 30.0,
                },
            ],
            background: BackgroundConfig::default(),
            markers: MarkerConfig::default(),
            camera_offset_mm: [0.0, 0.0],
            camera_rotation_deg: 0.0,
            effects: EffectsConfig::default(),
        }
    }
}

impl Default for BackgroundConfig {
    fn default() -> Self {
        Self {
            rgb: [0.45, 0.45, 0.48],
            uneven: 0.12,
        }
    }
}

impl Default for MarkerConfig {
    fn default() -> Self {
        Self {
            pattern: MarkerPattern::Grid,
            spacing_mm: 0.9,
            dot_diameter_mm: 0.3,
            offset_mm: [0.0, 0.0],
            jitter_mm: 0.0,
            jitter_seed: 1,
            rgb: [0.06, 0.06, 0.07],
        }
    }
}

impl OpticsConfig {
    /// Field of view on the gel, mm (`[width, height]`).
    pub fn field_of_view_mm(&self) -> [f64; 2] {
        [
            f64::from(self.width_px) * self.mm_per_px,
            f64::from(self.height_px) * self.mm_per_px,
        ]
    }

    /// The same sensor imaged at another resolution over the same field of view (width decides
    /// the scale), e.g. 640 × 480 for a GelSight R1.5-like camera.
    pub fn with_resolution(&self, width_px: u32, height_px: u32) -> Self {
        let fov = self.field_of_view_mm();
        Self {
            width_px,
            height_px,
            mm_per_px: fov[0] / f64::from(width_px.max(1)),
            ..self.clone()
        }
    }

    /// Every problem with the values, each naming its key under `optics.`.
    pub fn problems(&self) -> Vec<Problem> {
        let mut out = Vec::new();
        let mut push = |key: String, reason: String| out.push(Problem { key, reason });
        for (key, v) in [("width_px", self.width_px), ("height_px", self.height_px)] {
            if v == 0 || v > MAX_SIDE_PX {
                push(
                    format!("optics.{key}"),
                    format!("{v} must be between 1 and {MAX_SIDE_PX} pixels"),
                );
            }
        }
        if !(self.mm_per_px.is_finite() && self.mm_per_px > 0.0) {
            push(
                "optics.mm_per_px".into(),
                format!("{:?} must be a finite number > 0", self.mm_per_px),
            );
        }
        for (key, v) in [
            ("shading_gain", self.shading_gain),
            ("specular", self.specular),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                push(
                    format!("optics.{key}"),
                    format!("{v:?} must be a finite number ≥ 0"),
                );
            }
        }
        if self.leds.is_empty() || self.leds.len() > MAX_LEDS {
            push(
                "optics.leds".into(),
                format!(
                    "{} LEDs given; a sensor needs 1 to {MAX_LEDS} ([[optics.leds]] tables)",
                    self.leds.len()
                ),
            );
        }
        for (i, led) in self.leds.iter().enumerate() {
            if let Some(reason) = rgb_problem(led.rgb, 4.0) {
                push(format!("optics.leds[{i}].rgb"), reason);
            }
            if !led.azimuth_deg.is_finite() {
                push(
                    format!("optics.leds[{i}].azimuth_deg"),
                    format!("{:?} is not a finite number", led.azimuth_deg),
                );
            }
            if !(led.elevation_deg.is_finite()
                && led.elevation_deg > 0.0
                && led.elevation_deg <= 90.0)
            {
                push(
                    format!("optics.leds[{i}].elevation_deg"),
                    format!(
                        "{:?} must be in (0, 90] degrees above the gel",
                        led.elevation_deg
                    ),
                );
            }
        }
        if let Some(reason) = rgb_problem(self.background.rgb, 1.0) {
            push("optics.background.rgb".into(), reason);
        }
        let u = self.background.uneven;
        if !(u.is_finite() && (0.0..1.0).contains(&u)) {
            push(
                "optics.background.uneven".into(),
                format!("{u:?} must be in [0, 1)"),
            );
        }
        if !self
            .camera_offset_mm
            .iter()
            .all(|v| v.is_finite() && v.abs() <= 5.0)
        {
            push(
                "optics.camera_offset_mm".into(),
                format!(
                    "{:?} must be two finite numbers within ±5 mm",
                    self.camera_offset_mm
                ),
            );
        }
        let r = self.camera_rotation_deg;
        if !(r.is_finite() && r.abs() <= 45.0) {
            push(
                "optics.camera_rotation_deg".into(),
                format!("{r:?} must be a finite angle within ±45 degrees"),
            );
        }
        let e = &self.effects;
        for (key, v, max) in [
            ("blur_sigma_px", e.blur_sigma_px, 10.0),
            ("noise_sigma", e.noise_sigma, 64.0),
        ] {
            if !(v.is_finite() && (0.0..=max).contains(&v)) {
                push(
                    format!("optics.effects.{key}"),
                    format!("{v:?} must be between 0 (off) and {max}"),
                );
            }
        }
        if !(e.vignetting.is_finite() && (0.0..1.0).contains(&e.vignetting)) {
            push(
                "optics.effects.vignetting".into(),
                format!("{:?} must be in [0, 1) (0: off)", e.vignetting),
            );
        }
        let m = &self.markers;
        if m.pattern != MarkerPattern::None {
            let spacing_ok = m.spacing_mm.is_finite() && m.spacing_mm > 0.0;
            if !spacing_ok {
                push(
                    "optics.markers.spacing_mm".into(),
                    format!("{:?} must be a finite number > 0", m.spacing_mm),
                );
            } else if self.mm_per_px.is_finite()
                && self.mm_per_px > 0.0
                && dots_in_view(self.field_of_view_mm(), m.spacing_mm) > 1.0e6
            {
                push(
                    "optics.markers.spacing_mm".into(),
                    format!(
                        "{} mm gives more than a million dots in the image; use a larger spacing",
                        m.spacing_mm
                    ),
                );
            }
            let dot_ok = m.dot_diameter_mm.is_finite() && m.dot_diameter_mm > 0.0;
            if !dot_ok {
                push(
                    "optics.markers.dot_diameter_mm".into(),
                    format!("{:?} must be a finite number > 0", m.dot_diameter_mm),
                );
            } else if spacing_ok && m.dot_diameter_mm >= m.spacing_mm {
                push(
                    "optics.markers.dot_diameter_mm".into(),
                    format!(
                        "{} mm must be less than optics.markers.spacing_mm = {} mm",
                        m.dot_diameter_mm, m.spacing_mm
                    ),
                );
            }
            if !(m.offset_mm[0].is_finite() && m.offset_mm[1].is_finite()) {
                push(
                    "optics.markers.offset_mm".into(),
                    "must be two finite numbers [x, y]".into(),
                );
            }
            let free = if spacing_ok && dot_ok {
                (m.spacing_mm - m.dot_diameter_mm) / 2.0
            } else {
                f64::INFINITY
            };
            if !(m.jitter_mm.is_finite() && m.jitter_mm >= 0.0) {
                push(
                    "optics.markers.jitter_mm".into(),
                    format!("{:?} must be a finite number ≥ 0", m.jitter_mm),
                );
            } else if m.jitter_mm > 0.0 && m.jitter_mm >= free {
                push(
                    "optics.markers.jitter_mm".into(),
                    format!(
                        "{} mm must be less than half the gap between dots ({free:.3} mm), so dots \
                         never overlap",
                        m.jitter_mm
                    ),
                );
            }
            if let Some(reason) = rgb_problem(m.rgb, 1.0) {
                push("optics.markers.rgb".into(), reason);
            }
        }
        out
    }
}

fn dots_in_view(fov_mm: [f64; 2], spacing_mm: f64) -> f64 {
    (fov_mm[0] / spacing_mm) * (fov_mm[1] / spacing_mm)
}

fn rgb_problem(rgb: [f64; 3], max: f64) -> Option<String> {
    let ok = rgb.iter().all(|c| c.is_finite() && (0.0..=max).contains(c));
    (!ok).then(|| format!("{rgb:?}: each channel must be in [0, {max}]"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_cover_the_gel_width() {
        let o = OpticsConfig::default();
        assert!(o.problems().is_empty(), "{:?}", o.problems());
        assert_eq!(o.field_of_view_mm(), [10.0, 7.5]);
        let big = o.with_resolution(640, 480);
        assert_eq!(big.field_of_view_mm(), [10.0, 7.5]);
    }

    #[test]
    fn bad_values_name_their_keys() {
        let mut o = OpticsConfig {
            width_px: 0,
            ..OpticsConfig::default()
        };
        o.leds[1].elevation_deg = 0.0;
        o.leds[2].rgb = [f64::NAN, 0.0, 0.0];
        o.markers.dot_diameter_mm = 2.0;
        o.background.uneven = 1.0;
        o.camera_offset_mm = [0.2, f64::INFINITY];
        o.camera_rotation_deg = 90.0;
        o.effects.noise_sigma = -1.0;
        o.effects.vignetting = 1.0;
        let keys: Vec<String> = o.problems().into_iter().map(|p| p.key).collect();
        assert_eq!(
            keys,
            [
                "optics.width_px",
                "optics.leds[1].elevation_deg",
                "optics.leds[2].rgb",
                "optics.background.uneven",
                "optics.camera_offset_mm",
                "optics.camera_rotation_deg",
                "optics.effects.noise_sigma",
                "optics.effects.vignetting",
                "optics.markers.dot_diameter_mm",
            ]
        );
    }

    #[test]
    fn jitter_must_keep_dots_apart_and_no_leds_is_an_error() {
        let mut o = OpticsConfig {
            leds: Vec::new(),
            ..OpticsConfig::default()
        };
        o.markers.jitter_mm = 0.4; // gap is (0.9 - 0.3) / 2 = 0.3
        let keys: Vec<String> = o.problems().into_iter().map(|p| p.key).collect();
        assert_eq!(keys, ["optics.leds", "optics.markers.jitter_mm"]);
    }

    #[test]
    fn a_partial_section_parses_with_defaults() {
        let o: OpticsConfig =
            toml::from_str("width_px = 640\n[markers]\npattern = \"hex\"\nspacing_mm = 1.2\n")
                .unwrap();
        assert_eq!(o.width_px, 640);
        assert_eq!(o.markers.pattern, MarkerPattern::Hex);
        assert_eq!(o.markers.dot_diameter_mm, 0.3);
        assert_eq!(o.leds.len(), 3);
        assert!(toml::from_str::<OpticsConfig>("colour = 1").is_err());
    }
}
