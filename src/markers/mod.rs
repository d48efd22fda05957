//! Marker displacement: a sensor-independent view of shear.
//!
//! A force model trained on one GelSight's images does not carry shear to a second sensor whose
//! printed marker lattice has another pitch: the model learns the source's lattice as a texture.
//! What both sensors share is the *motion of the gel*. This module measures it from the marker
//! dots and puts it on a grid in millimetres that does not depend on the pitch:
//!
//! 1. [`detect`]: the marker dots of one image, with sub-pixel centroids ([`Marker`]);
//! 2. [`Tracker`]: the dots of a trajectory's first (no-contact) frame, followed frame by frame;
//!    each reference marker's position and displacement in millimetres in the sensor's axes
//!    ([`TrackedMarker`]);
//! 3. [`resample`]: the displacement field on a fixed [`GridSpec`] in millimetres (a normalised
//!    Gaussian-weighted average of the tracked markers' displacements).
//!
//! The inputs are the sensor's optics as a recording's manifest carries them (`config.optics`,
//! [`rig_core::optics::OpticsConfig`]): image size, mm per pixel, camera rotation, marker
//! spacing, dot diameter and dot colour against the gel's ([`SensorGeometry::from_optics`]).
//! Nothing here needs the simulator; it runs the same on a real sensor's frames.
//!
//! # Coordinates and signs
//!
//! - **Pixels** (`*_px`): `[column, row]`, pixel centres at whole numbers (the top-left pixel's
//!   centre is `[0, 0]`), rows growing downwards. This is the convention of the simulator's
//!   `mm_to_px`.
//! - **Camera millimetres**: origin at the image centre, `a` along the columns (right), `b` up
//!   the image (row 0 is the camera's `+y`): `a = (u + ½ − W/2)·s`, `b = (H/2 − v − ½)·s` with
//!   `s = mm_per_px` ([`rig_core::optics`]: the image is a top view of the gel).
//! - **Sensor millimetres** (`*_mm`, "the sensor's axes"): the gel surface frame's `x`, `y`
//!   axes, origin at the image centre. The camera is turned by `θ = camera_rotation_deg`
//!   (counter-clockwise seen from the camera: the image's x axis lies along the gel's x turned
//!   by θ), so a camera vector `(a, b)` is `R(θ)·(a, b)` in sensor axes:
//!   `x = a cos θ − b sin θ`, `y = a sin θ + b cos θ`. This undoes the rotation: two sensors that
//!   differ only in how their cameras are turned report the same vectors for the same gel
//!   motion. The camera's offset on the gel (`camera_offset_mm`, an assembly tolerance a real
//!   sensor rarely knows) is *not* applied: sensor millimetres are centred on what the camera
//!   sees. ([`SensorGeometry::gel_centre_mm`] says where the gel centre lies, where the offset
//!   is known.)
//! - **Displacement** (`displacement_mm`): where a marker is now minus where it was in the
//!   reference frame, sensor millimetres: `+x` means the gel moved towards the gel's `+x`.
//!   Material (Lagrangian) description: each displacement belongs to the marker's *reference*
//!   position, as a simulator's surface field `u(X)` does.
//! - **Grid** ([`GridSpec`]): `ny` rows of `nx` cells, row-major, row 0 at the top (`+y`, like
//!   an image of an unturned camera), cells `spacing_mm` apart and centred on the image centre
//!   ([`Tracker::grid_on_gel`]: on the gel's centre). Each cell holds `[dx, dy]` in millimetres
//!   in sensor axes, averaged over the markers tracked in the current frame (lost ones left
//!   out); zero where no marker is in reach.
//!
//! # Accuracy and cost
//!
//! On the simulated sensors (`tests/it/markers.rs`, against the simulator's own truth): dot
//! centroids within 0.025 px of the printed centres on an untouched gel; tracked displacements
//! within 0.11 px (3.4 µm) of the gel's true tangential displacement through a sheared press,
//! rms 0.014–0.032 px; the grid fields of a 0.8, 0.9 and 1.1 mm lattice within 2.3 % (rms) of
//! each other's peak. Detection is O(pixels): about 1.2–2 ms a 320 × 240 frame in the
//! debug build (`rig` at opt-level 1, on a loaded two-core machine); tracking and the grid add
//! about 0.1 ms.

mod detect;
mod grid;
mod shading;
mod track;

use rig_core::optics::{MarkerPattern, OpticsConfig};

pub use detect::{Detector, FLOOR_LEVELS, Marker, detect};
pub use grid::{GridSpec, MAX_GRID_CELLS, MIN_WEIGHT, resample, resample_points};
pub use shading::{Shading, WINDOW_HALF_MM};
pub use track::{FrameSummary, TrackedMarker, Tracker};

/// Whether the dots are darker or lighter than the gel around them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Polarity {
    /// Dark dots on a bright gel (the usual GelSight markers).
    #[default]
    Dark,
    /// Light dots on a dark gel.
    Light,
}

/// What the marker measurement needs to know about a sensor: its image, its scale and turn,
/// and its dots.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorGeometry {
    /// Image width, pixels.
    pub width_px: u32,
    /// Image height, pixels.
    pub height_px: u32,
    /// Size of one pixel on the gel, mm.
    pub mm_per_px: f64,
    /// How far the camera is turned against the gel, degrees, counter-clockwise seen from the
    /// camera (`optics.camera_rotation_deg`; see the module docs for the sign).
    pub camera_rotation_deg: f64,
    /// The camera's offset on the gel, mm (`optics.camera_offset_mm`); used only by
    /// [`SensorGeometry::gel_centre_mm`].
    pub camera_offset_mm: [f64; 2],
    /// Distance between neighbouring dots, mm.
    pub spacing_mm: f64,
    /// Dot diameter, mm.
    pub dot_diameter_mm: f64,
    /// Dark dots on a bright gel, or light on dark.
    pub polarity: Polarity,
}

impl SensorGeometry {
    /// The geometry of a sensor as its `[optics]` section describes it. The polarity comes from
    /// the dot colour against the gel's background colour (luminance). An error when the sensor
    /// has no markers or its numbers cannot be used (see [`SensorGeometry::check`]).
    pub fn from_optics(optics: &OpticsConfig) -> Result<Self, String> {
        if optics.markers.pattern == MarkerPattern::None || !optics.effects.markers {
            return Err(
                "the sensor has no markers (optics.markers.pattern = \"none\" or \
                 optics.effects.markers = false): marker displacement needs printed dots"
                    .into(),
            );
        }
        let lum = |c: [f64; 3]| 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2];
        let polarity = if lum(optics.markers.rgb) <= lum(optics.background.rgb) {
            Polarity::Dark
        } else {
            Polarity::Light
        };
        let g = Self {
            width_px: optics.width_px,
            height_px: optics.height_px,
            mm_per_px: optics.mm_per_px,
            camera_rotation_deg: optics.camera_rotation_deg,
            camera_offset_mm: optics.camera_offset_mm,
            spacing_mm: optics.markers.spacing_mm,
            dot_diameter_mm: optics.markers.dot_diameter_mm,
            polarity,
        };
        g.check()?;
        Ok(g)
    }

    /// Every value usable: a non-empty image of at most
    /// [`MAX_SIDE_PX`](rig_core::optics::MAX_SIDE_PX) a side, a finite positive scale, a turn
    /// within ±45°, dots at least 2 px across and at least 2 px apart at their edges.
    pub fn check(&self) -> Result<(), String> {
        let max = rig_core::optics::MAX_SIDE_PX;
        if self.width_px == 0 || self.height_px == 0 || self.width_px > max || self.height_px > max
        {
            return Err(format!(
                "image size {}×{} px: each side must be 1 to {max} px",
                self.width_px, self.height_px
            ));
        }
        if !(self.mm_per_px.is_finite() && self.mm_per_px > 0.0) {
            return Err(format!(
                "mm_per_px = {:?} must be a finite number > 0",
                self.mm_per_px
            ));
        }
        if !(self.camera_rotation_deg.is_finite() && self.camera_rotation_deg.abs() <= 45.0) {
            return Err(format!(
                "camera_rotation_deg = {:?} must be a finite angle within ±45°",
                self.camera_rotation_deg
            ));
        }
        if !self.camera_offset_mm.iter().all(|v| v.is_finite()) {
            return Err(format!(
                "camera_offset_mm = {:?} must be two finite numbers",
                self.camera_offset_mm
            ));
        }
        let (dot, pitch) = (self.dot_px(), self.spacing_px());
        if !(dot.is_finite() && dot >= 2.0) {
            return Err(format!(
                "dot_diameter_mm = {:?} is {dot:.2} px at {} mm/px: dots must be at least 2 px \
                 across to be located",
                self.dot_diameter_mm, self.mm_per_px
            ));
        }
        if !(pitch.is_finite() && pitch >= dot + 2.0) {
            return Err(format!(
                "spacing_mm = {:?} ({pitch:.2} px) must exceed the dot diameter ({dot:.2} px) by \
                 at least 2 px, so neighbouring dots stay apart",
                self.spacing_mm
            ));
        }
        Ok(())
    }

    /// Dot diameter, pixels.
    pub fn dot_px(&self) -> f64 {
        self.dot_diameter_mm / self.mm_per_px
    }

    /// Marker spacing, pixels.
    pub fn spacing_px(&self) -> f64 {
        self.spacing_mm / self.mm_per_px
    }

    /// Cosine and sine of the camera's turn.
    fn rot(&self) -> [f64; 2] {
        let (s, c) = self.camera_rotation_deg.to_radians().sin_cos();
        [c, s]
    }

    /// A pixel position (`[column, row]`) in sensor millimetres (origin at the image centre).
    pub fn px_to_mm(&self, p: [f64; 2]) -> [f64; 2] {
        let s = self.mm_per_px;
        let a = (p[0] + 0.5 - f64::from(self.width_px) / 2.0) * s;
        let b = (f64::from(self.height_px) / 2.0 - p[1] - 0.5) * s;
        self.cam_to_sensor([a, b])
    }

    /// A position in sensor millimetres as a pixel position: the inverse of
    /// [`SensorGeometry::px_to_mm`].
    pub fn mm_to_px(&self, p: [f64; 2]) -> [f64; 2] {
        let [c, s] = self.rot();
        let (a, b) = (c * p[0] + s * p[1], -s * p[0] + c * p[1]);
        [
            a / self.mm_per_px + f64::from(self.width_px) / 2.0 - 0.5,
            f64::from(self.height_px) / 2.0 - 0.5 - b / self.mm_per_px,
        ]
    }

    /// A pixel displacement (`[columns, rows]`) in sensor millimetres.
    pub fn px_delta_to_mm(&self, d: [f64; 2]) -> [f64; 2] {
        self.cam_to_sensor([d[0] * self.mm_per_px, -d[1] * self.mm_per_px])
    }

    fn cam_to_sensor(&self, v: [f64; 2]) -> [f64; 2] {
        let [c, s] = self.rot();
        [c * v[0] - s * v[1], s * v[0] + c * v[1]]
    }

    /// Where the gel's centre lies in sensor millimetres: `−camera_offset_mm` (the camera's
    /// image centre sits at `camera_offset_mm` on the gel, in the gel's axes). A grid centred
    /// here instead of on the image centre lines two sensors up on their gels, where their
    /// offsets are known.
    pub fn gel_centre_mm(&self) -> [f64; 2] {
        [-self.camera_offset_mm[0], -self.camera_offset_mm[1]]
    }

    /// About how many dots lie wholly inside the image (a square lattice's count; a hexagonal
    /// one has 15 % more).
    pub fn expected_markers(&self) -> f64 {
        let pitch = self.spacing_px();
        let inside = |side: u32| (f64::from(side) - self.dot_px()).max(0.0) / pitch;
        inside(self.width_px) * inside(self.height_px)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn source() -> SensorGeometry {
        SensorGeometry::from_optics(&OpticsConfig::default()).unwrap()
    }

    #[test]
    fn the_default_optics_give_dark_dots_of_the_shipped_size() {
        let g = source();
        assert_eq!(g.polarity, Polarity::Dark);
        assert!((g.dot_px() - 9.6).abs() < 1e-9);
        assert!((g.spacing_px() - 28.8).abs() < 1e-9);
        let mut light = OpticsConfig::default();
        light.markers.rgb = [0.9, 0.9, 0.9];
        light.background.rgb = [0.2, 0.2, 0.2];
        assert_eq!(
            SensorGeometry::from_optics(&light).unwrap().polarity,
            Polarity::Light
        );
    }

    #[test]
    fn pixels_and_sensor_mm_agree_with_the_optics_convention() {
        let g = source();
        // The image centre is the origin; row 0 is +y.
        let c = g.px_to_mm([159.5, 119.5]);
        assert!(c[0].abs() < 1e-12 && c[1].abs() < 1e-12);
        let p = g.px_to_mm([0.0, 0.0]);
        assert!((p[0] + 159.5 / 32.0).abs() < 1e-12 && (p[1] - 119.5 / 32.0).abs() < 1e-12);
        // One column right is +x, one row down is −y.
        assert_eq!(g.px_delta_to_mm([32.0, 0.0]), [1.0, 0.0]);
        assert_eq!(g.px_delta_to_mm([0.0, 32.0]), [0.0, -1.0]);
        // Turned by +30°: the image's x axis is the gel's x turned 30° towards +y.
        let turned = SensorGeometry {
            camera_rotation_deg: 30.0,
            ..source()
        };
        let d = turned.px_delta_to_mm([32.0, 0.0]);
        let t = 30f64.to_radians();
        assert!((d[0] - t.cos()).abs() < 1e-12 && (d[1] - t.sin()).abs() < 1e-12);
        for q in [[3.25, 200.5], [310.0, 7.0]] {
            let back = turned.mm_to_px(turned.px_to_mm(q));
            assert!((back[0] - q[0]).abs() < 1e-9 && (back[1] - q[1]).abs() < 1e-9);
        }
    }

    #[test]
    fn unusable_geometry_is_an_error_that_names_the_value() {
        let mut none = OpticsConfig::default();
        none.markers.pattern = MarkerPattern::None;
        assert!(
            SensorGeometry::from_optics(&none)
                .unwrap_err()
                .contains("no markers")
        );
        for (g, key) in [
            (
                SensorGeometry {
                    width_px: 0,
                    ..source()
                },
                "image size",
            ),
            (
                SensorGeometry {
                    mm_per_px: f64::NAN,
                    ..source()
                },
                "mm_per_px",
            ),
            (
                SensorGeometry {
                    dot_diameter_mm: 0.01,
                    ..source()
                },
                "dot_diameter_mm",
            ),
            (
                SensorGeometry {
                    spacing_mm: 0.32,
                    ..source()
                },
                "spacing_mm",
            ),
            (
                SensorGeometry {
                    camera_rotation_deg: 90.0,
                    ..source()
                },
                "camera_rotation_deg",
            ),
        ] {
            let e = g.check().unwrap_err();
            assert!(e.contains(key), "{e}");
        }
    }
}
