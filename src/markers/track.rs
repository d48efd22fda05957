//! Following a trajectory's markers from its first (no-contact) frame.

use image::RgbImage;

use super::{Detector, GridSpec, Marker, SensorGeometry, resample, resample_points};

/// Fewest markers a reference frame must have, whatever the sensor.
const MIN_REFERENCE_MARKERS: usize = 4;
/// Share of the expected markers a reference frame must have.
const MIN_REFERENCE_SHARE: f64 = 0.5;
/// The association gate as a share of the marker spacing: a detection further than this from
/// a marker's last position is not that marker. A third of the spacing keeps a marker from
/// taking its neighbour's dot (which is a whole spacing away) while allowing for 0.3 mm of
/// motion a frame on a 0.9 mm lattice (a slide at 7 mm/s at 25 frames/s).
const GATE_SHARE: f64 = 1.0 / 3.0;

/// One marker of the reference frame as tracked so far.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrackedMarker {
    /// Where it was in the reference frame, pixels (`[column, row]`).
    pub reference_px: [f64; 2],
    /// Where it was last seen, pixels.
    pub position_px: [f64; 2],
    /// Where it was in the reference frame, sensor mm (origin at the image centre).
    pub reference_mm: [f64; 2],
    /// Last seen position minus reference position, sensor mm.
    pub displacement_mm: [f64; 2],
    /// Not found in the last frame: it keeps its last position and displacement.
    pub lost: bool,
    /// Frames in a row it has been lost (0 while tracked).
    pub frames_lost: u32,
}

/// What one [`Tracker::update`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct FrameSummary {
    /// Dots detected in the frame.
    pub detected: usize,
    /// Reference markers matched to one of them.
    pub matched: usize,
    /// Reference markers without a match (flagged lost).
    pub lost: usize,
    /// Detections no reference marker took (dots come in from outside the image, or not dots).
    pub unclaimed: usize,
}

/// Tracks the markers of a reference frame through the frames that follow it.
///
/// Each frame's detections are matched to the markers' last positions: the nearest detection
/// within a gate of a third of the marker spacing, each detection to one marker at most
/// (pairs are taken in order of distance, markers tracked in the last frame before lost ones, so
/// a lost marker never takes a dot its tracked neighbour is following). A marker without a
/// match keeps its last position and is flagged [`TrackedMarker::lost`] for the frame; it is
/// picked up again when a free detection comes within the gate of where it was last seen.
#[derive(Debug, Clone)]
pub struct Tracker {
    geom: SensorGeometry,
    detector: Detector,
    markers: Vec<TrackedMarker>,
    gate_px: f64,
    frames: u64,
}

impl Tracker {
    /// Detects the markers of `reference` (a frame without contact: the trajectory's first).
    ///
    /// An error, saying what is wrong, when the geometry is unusable, the frame's size is not
    /// the sensor's, or it has fewer than half the markers the sensor's lattice puts in view
    /// (a blank or black frame, another sensor's, markers off, a contact hiding most of them).
    pub fn new(reference: &RgbImage, geom: &SensorGeometry) -> Result<Self, String> {
        geom.check().map_err(|e| format!("sensor geometry: {e}"))?;
        check_size(reference, geom, "reference frame")?;
        let mut detector = Detector::new(geom);
        let found = detector.detect(reference);
        let expected = geom.expected_markers();
        let need = ((MIN_REFERENCE_SHARE * expected).ceil() as usize).max(MIN_REFERENCE_MARKERS);
        if found.len() < need {
            return Err(format!(
                "reference frame: {} marker dots found, at least {need} needed (about {:.0} \
                 expected for {} mm dots {} mm apart at {} mm/px); is it a frame of this sensor, \
                 without contact, with its markers visible?",
                found.len(),
                expected,
                geom.dot_diameter_mm,
                geom.spacing_mm,
                geom.mm_per_px
            ));
        }
        let markers = found
            .iter()
            .map(|m: &Marker| TrackedMarker {
                reference_px: m.px,
                position_px: m.px,
                reference_mm: geom.px_to_mm(m.px),
                displacement_mm: [0.0, 0.0],
                lost: false,
                frames_lost: 0,
            })
            .collect();
        Ok(Self {
            gate_px: GATE_SHARE * geom.spacing_px(),
            geom: geom.clone(),
            detector,
            markers,
            frames: 0,
        })
    }

    /// Follows the markers into `frame`. An error (and no change) when the frame's size is not
    /// the sensor's; a frame without dots (blank, dropped, covered) is not an error: every
    /// marker is lost in it.
    pub fn update(&mut self, frame: &RgbImage) -> Result<FrameSummary, String> {
        check_size(frame, &self.geom, "frame")?;
        let found = self.detector.detect(frame);
        let gate2 = self.gate_px * self.gate_px;
        // Every (marker, detection) pair within the gate: markers tracked in the last frame
        // first, then by distance.
        let mut pairs: Vec<(bool, f64, usize, usize)> = Vec::new();
        for (i, m) in self.markers.iter().enumerate() {
            let p = m.position_px;
            for (j, d) in found.iter().enumerate() {
                let (dx, dy) = (d.px[0] - p[0], d.px[1] - p[1]);
                if dx.abs() > self.gate_px || dy.abs() > self.gate_px {
                    continue;
                }
                let r2 = dx * dx + dy * dy;
                if r2 <= gate2 {
                    pairs.push((m.lost, r2, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
        let mut taken_by = vec![usize::MAX; found.len()];
        let mut matched = vec![usize::MAX; self.markers.len()];
        for &(_, _, i, j) in &pairs {
            if matched[i] == usize::MAX && taken_by[j] == usize::MAX {
                matched[i] = j;
                taken_by[j] = i;
            }
        }
        let mut summary = FrameSummary {
            detected: found.len(),
            ..FrameSummary::default()
        };
        for (m, &j) in self.markers.iter_mut().zip(&matched) {
            if j == usize::MAX {
                m.lost = true;
                m.frames_lost = m.frames_lost.saturating_add(1);
                summary.lost += 1;
            } else {
                m.position_px = found[j].px;
                m.lost = false;
                m.frames_lost = 0;
                let d = [
                    m.position_px[0] - m.reference_px[0],
                    m.position_px[1] - m.reference_px[1],
                ];
                m.displacement_mm = self.geom.px_delta_to_mm(d);
                summary.matched += 1;
            }
        }
        summary.unclaimed = taken_by.iter().filter(|&&i| i == usize::MAX).count();
        self.frames += 1;
        Ok(summary)
    }

    /// The reference frame's markers, as tracked so far (in the order they were detected).
    pub fn markers(&self) -> &[TrackedMarker] {
        &self.markers
    }

    /// The sensor this tracker measures.
    pub fn geometry(&self) -> &SensorGeometry {
        &self.geom
    }

    /// The association gate, pixels.
    pub fn gate_px(&self) -> f64 {
        self.gate_px
    }

    /// Frames followed since the reference.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// The current displacement field on `spec`'s grid, centred on the image centre
    /// ([`resample`] of the tracked markers).
    pub fn grid(&self, spec: &GridSpec) -> Vec<[f32; 2]> {
        resample(&self.markers, spec)
    }

    /// [`Tracker::grid`] centred on the gel's centre instead of the image's
    /// ([`SensorGeometry::gel_centre_mm`]): for sensors whose camera offsets are known, so that
    /// their grids sample the same gel.
    pub fn grid_on_gel(&self, spec: &GridSpec) -> Vec<[f32; 2]> {
        let o = self.geom.gel_centre_mm();
        let (points, disp): (Vec<[f64; 2]>, Vec<[f64; 2]>) = self
            .markers
            .iter()
            .filter(|m| !m.lost)
            .map(|m| {
                let p = m.reference_mm;
                ([p[0] - o[0], p[1] - o[1]], m.displacement_mm)
            })
            .unzip();
        resample_points(&points, &disp, spec)
    }
}

fn check_size(img: &RgbImage, geom: &SensorGeometry, what: &str) -> Result<(), String> {
    if img.dimensions() == (geom.width_px, geom.height_px) {
        Ok(())
    } else {
        Err(format!(
            "{what} is {}×{} px, but the sensor's images are {}×{} px",
            img.width(),
            img.height(),
            geom.width_px,
            geom.height_px
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rig_core::optics::OpticsConfig;

    fn geom() -> SensorGeometry {
        SensorGeometry::from_optics(&OpticsConfig::default()).unwrap()
    }

    /// A 320 × 240 gel with hard-edged dots (radius 4.8 px) at `centres`.
    fn frame(centres: &[[f64; 2]]) -> RgbImage {
        let mut img = RgbImage::from_pixel(320, 240, image::Rgb([115, 115, 122]));
        for c in centres {
            for v in 0..240u32 {
                for u in 0..320u32 {
                    if (f64::from(u) - c[0]).hypot(f64::from(v) - c[1]) <= 4.8 {
                        img.put_pixel(u, v, image::Rgb([15, 15, 18]));
                    }
                }
            }
        }
        img
    }

    fn lattice(shift: [f64; 2]) -> Vec<[f64; 2]> {
        (0..8)
            .flat_map(|j| {
                (0..11).map(move |i| {
                    [
                        16.0 + 28.8 * f64::from(i) + shift[0],
                        18.0 + 28.8 * f64::from(j) + shift[1],
                    ]
                })
            })
            .collect()
    }

    #[test]
    fn a_shifted_lattice_is_followed_and_converted_to_sensor_mm() {
        let mut t = Tracker::new(&frame(&lattice([0.0, 0.0])), &geom()).unwrap();
        assert_eq!(t.markers().len(), 88);
        // 3 px right and 2 px down per frame, three frames.
        for k in 1..=3 {
            let s = t
                .update(&frame(&lattice([3.0 * f64::from(k), 2.0 * f64::from(k)])))
                .unwrap();
            assert_eq!(s.matched, 88);
        }
        for m in t.markers() {
            assert!(!m.lost);
            // 9 px right = +9/32 mm in x; 6 px down = −6/32 mm in y (the same dot shapes
            // moved by whole pixels: exact to rounding).
            let d = m.displacement_mm;
            assert!((d[0] - 9.0 / 32.0).abs() < 1e-6 && (d[1] + 6.0 / 32.0).abs() < 1e-6);
        }
    }

    #[test]
    fn a_dot_leaving_the_image_is_lost_and_does_not_take_its_neighbour() {
        let g = geom();
        let mut t = Tracker::new(&frame(&lattice([0.0, 0.0])), &g).unwrap();
        // Everything moves 4 px left a frame. The left column (from u = 16) is cut by the
        // border from frame 3 on (the detector drops cut dots), so it was last seen at u = 8;
        // in frame 9 its right neighbour (from u = 44.8) is at 8.8, 0.8 px from there and 4 px
        // from its own last position: the tracked marker still takes it.
        for k in 1..=9 {
            let shift = -4.0 * f64::from(k);
            let s = t.update(&frame(&lattice([shift, 0.0]))).unwrap();
            let cut = if k >= 3 { 8 } else { 0 };
            assert_eq!(
                (s.matched, s.lost, s.unclaimed),
                (88 - cut, cut, 0),
                "frame {k}"
            );
            for m in t.markers() {
                let left_column = m.reference_px[0] < 20.0;
                assert_eq!(m.lost, left_column && k >= 3, "frame {k}: {m:?}");
                if !m.lost {
                    let moved = m.position_px[0] - m.reference_px[0];
                    assert!((moved - shift).abs() < 1e-4, "frame {k}: {m:?}");
                }
            }
        }
        // A blank frame: every marker lost, no error; a wrong size: an error.
        let blank = RgbImage::from_pixel(320, 240, image::Rgb([115, 115, 122]));
        let s = t.update(&blank).unwrap();
        assert_eq!((s.detected, s.lost), (0, 88));
        assert!(t.markers().iter().all(|m| m.lost && m.frames_lost >= 1));
        let e = t.update(&RgbImage::new(640, 480)).unwrap_err();
        assert!(e.contains("640×480") && e.contains("320×240"), "{e}");
    }

    #[test]
    fn too_few_markers_or_a_wrong_size_in_the_reference_is_an_error() {
        let g = geom();
        let few: Vec<[f64; 2]> = lattice([0.0, 0.0]).into_iter().take(20).collect();
        let e = Tracker::new(&frame(&few), &g).unwrap_err();
        assert!(e.contains("20 marker dots found"), "{e}");
        let e = Tracker::new(&RgbImage::new(320, 240), &g).unwrap_err();
        assert!(e.contains("0 marker dots found"), "{e}");
        let e = Tracker::new(&RgbImage::new(100, 100), &g).unwrap_err();
        assert!(e.contains("100×100"), "{e}");
    }
}
