//! What `rig run` records on the simulated sensors with their image effects on
//! (`[optics.effects]`: the shipped markers and noise, here with shadows, blur and vignetting
//! added): the frames show each sensor's own marker pattern (a square grid on sim-source, a
//! jittered hexagonal one on sim-target, whose camera sits 0.2 mm off centre and turned by
//! 1.5°), and the dots move with the gel the way the indenter slides.
//!
//! Dots are found with the trainer's own marker detector (black-hat morphology, then connected
//! components): what the marker modality sees.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rig::record::reader::{Message, messages};
use rig::simrig::sim::optics::{marker_centres_mm, mm_to_px};
use rig::train::modality::{MarkerParams, connected_components, marker_mask};
use rig_core::config::RigConfig;
use rig_core::optics::OpticsConfig;

use crate::common;

/// A shipped simulated config (`sim-source` or `sim-target`) with every image effect on (a
/// GelSight Mini's look: the shipped markers and noise, plus shadows, blur and vignetting), and
/// the plan narrowed to one contact point, one depth and `directions`, written as
/// `dir/<name>.toml`.
fn narrowed_config(dir: &Path, name: &str, depth_mm: f64, directions: &[f64]) -> PathBuf {
    let shipped = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/rig-configs"));
    let mut text = std::fs::read_to_string(shipped.join(format!("{name}.toml"))).unwrap();
    let dirs: Vec<String> = directions.iter().map(|d| format!("{d:.1}")).collect();
    for (from, to) in [
        (
            "contact_points_mm = [[0.0, 0.0], [-3.0, -2.0], [3.0, -2.0], [-3.0, 2.0], [3.0, 2.0]]",
            "contact_points_mm = [[0.0, 0.0]]".to_owned(),
        ),
        (
            "depths_mm = [0.2, 0.4, 0.6, 0.8]",
            format!("depths_mm = [{depth_mm}]"),
        ),
        (
            "directions_deg = [0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0, 210.0, 240.0, 270.0, 300.0, 330.0]",
            format!("directions_deg = [{}]", dirs.join(", ")),
        ),
        ("shadows = false", "shadows = true".to_owned()),
        ("blur_sigma_px = 0.0", "blur_sigma_px = 0.8".to_owned()),
        ("vignetting = 0.0", "vignetting = 0.25".to_owned()),
    ] {
        assert!(text.contains(from), "{name}.toml has no {from:?}");
        text = text.replace(from, &to);
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// One recorded trajectory: each frame's image by sequence number, and each frame's stage.
struct Trajectory {
    frames: BTreeMap<i64, image::RgbImage>,
    stages: BTreeMap<i64, String>,
}

fn read_trajectories(dir: &Path) -> Vec<Trajectory> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    files
        .iter()
        .map(|path| {
            let bytes = std::fs::read(path).unwrap();
            let mut t = Trajectory {
                frames: BTreeMap::new(),
                stages: BTreeMap::new(),
            };
            for m in messages(&bytes).unwrap() {
                match m.unwrap() {
                    Message::Frame {
                        seq, format, data, ..
                    } => {
                        let img = rig::record::png::decode_as(format, &data).unwrap();
                        t.frames.insert(seq, img);
                    }
                    Message::Paired(p) => {
                        t.stages.insert(p.frame_seq, p.stage.unwrap_or_default());
                    }
                    _ => {}
                }
            }
            t
        })
        .collect()
}

/// Centroids (column, row) of the marker dots the trainer's detector finds.
fn dots(img: &image::RgbImage, optics: &OpticsConfig) -> Vec<[f64; 2]> {
    let r_px = optics.markers.dot_diameter_mm / 2.0 / optics.mm_per_px;
    let mask = marker_mask(img, &MarkerParams::for_dot_radius(r_px as f32));
    connected_components(&mask)
        .into_iter()
        .filter(|c| c.pixels >= 8)
        .map(|c| [f64::from(c.centroid.0), f64::from(c.centroid.1)])
        .collect()
}

/// Where a sensor's dots are on its untouched gel, in pixels, keeping those at least a dot
/// spacing inside the image (the detector may miss a dot cut by the border).
fn expected_dots(optics: &OpticsConfig) -> Vec<[f64; 2]> {
    let margin = optics.markers.spacing_mm / optics.mm_per_px;
    let (w, h) = (f64::from(optics.width_px), f64::from(optics.height_px));
    marker_centres_mm(optics)
        .into_iter()
        .map(|c| mm_to_px(optics, c))
        .filter(|p| p[0] > margin && p[0] < w - margin && p[1] > margin && p[1] < h - margin)
        .collect()
}

/// Share of `expected` with a detected dot within `tol` pixels.
fn found_share(expected: &[[f64; 2]], found: &[[f64; 2]], tol: f64) -> f64 {
    let hit = expected
        .iter()
        .filter(|e| found.iter().any(|f| (f[0] - e[0]).hypot(f[1] - e[1]) < tol))
        .count();
    hit as f64 / expected.len().max(1) as f64
}

#[test]
fn recorded_frames_show_each_sensors_own_marker_pattern() {
    let tmp = tempfile::tempdir().unwrap();
    let mut sensors = Vec::new();
    let mut first_frames = Vec::new();
    for name in ["sim-source", "sim-target"] {
        let cfg = narrowed_config(tmp.path(), name, 0.4, &[0.0]);
        sensors.push((name, RigConfig::load(&cfg).unwrap().optics.unwrap()));
        let out = tmp.path().join(name);
        common::record_sim_run(&cfg, "sphere", &out, 1);
        let t = read_trajectories(&out).remove(0);
        assert!(t.frames.len() > 50, "{name}: {} frames", t.frames.len());
        first_frames.push(t.frames.values().next().unwrap().clone());
    }
    for (k, (name, optics)) in sensors.iter().enumerate() {
        let found = dots(&first_frames[k], optics);
        let own = expected_dots(optics);
        let other = expected_dots(&sensors[1 - k].1);
        assert!(own.len() > 40, "{name}: {} dots expected", own.len());
        // Every dot of the sensor's own pattern is there, within a pixel...
        let own_share = found_share(&own, &found, 1.0);
        assert!(
            own_share > 0.95,
            "{name}: {:.0} % of its {} dots found ({} blobs)",
            own_share * 100.0,
            own.len(),
            found.len()
        );
        // ... nearly every blob is one of them ...
        let stray = found
            .iter()
            .filter(|f| !own.iter().any(|e| (f[0] - e[0]).hypot(f[1] - e[1]) < 2.0))
            .filter(|f| {
                let m = optics.markers.spacing_mm / optics.mm_per_px;
                let (w, h) = (f64::from(optics.width_px), f64::from(optics.height_px));
                f[0] > m && f[0] < w - m && f[1] > m && f[1] < h - m
            })
            .count();
        assert!(stray <= 2, "{name}: {stray} blobs that are not its dots");
        // ... and the other sensor's pattern is not.
        let other_share = found_share(&other, &found, 1.0);
        assert!(
            other_share < 0.3,
            "{name}: {:.0} % of the other sensor's dots match",
            other_share * 100.0
        );
    }
}

/// Mean displacement (pixels) of the dots that moved between two frames, matching each dot to
/// the nearest one within `max_px`; dots that moved less than a pixel are left out.
fn mean_dot_motion(a: &[[f64; 2]], b: &[[f64; 2]], max_px: f64) -> Option<[f64; 2]> {
    let mut sum = [0.0, 0.0];
    let mut n = 0;
    for p in a {
        let nearest = b.iter().min_by(|x, y| {
            let dx = (x[0] - p[0]).hypot(x[1] - p[1]);
            let dy = (y[0] - p[0]).hypot(y[1] - p[1]);
            dx.total_cmp(&dy)
        })?;
        let d = [nearest[0] - p[0], nearest[1] - p[1]];
        let len = d[0].hypot(d[1]);
        if len >= 1.0 && len < max_px {
            sum = [sum[0] + d[0], sum[1] + d[1]];
            n += 1;
        }
    }
    (n >= 3).then(|| [sum[0] / n as f64, sum[1] / n as f64])
}

#[test]
fn markers_move_with_the_gel_along_the_shear_direction() {
    let tmp = tempfile::tempdir().unwrap();
    let directions = [0.0, 90.0, 180.0, 270.0];
    let cfg = narrowed_config(tmp.path(), "sim-source", 0.6, &directions);
    let out = tmp.path().join("run");
    common::record_sim_run(&cfg, "sphere", &out, directions.len());
    let optics = RigConfig::load(&cfg).unwrap().optics.unwrap();
    let spacing_px = optics.markers.spacing_mm / optics.mm_per_px;
    let trajectories = read_trajectories(&out);
    assert_eq!(trajectories.len(), directions.len());
    // Trajectories are recorded in plan order: the directions as listed.
    for (t, &deg) in trajectories.iter().zip(&directions) {
        let shear: Vec<i64> = t
            .stages
            .iter()
            .filter(|(_, s)| s.as_str() == "shear")
            .map(|(seq, _)| *seq)
            .collect();
        assert!(shear.len() > 10, "{deg}°: {} shear frames", shear.len());
        // The first shear frame against one a quarter of the way in: the indenter has slid
        // about a quarter mm (8 px), well under half a dot spacing, so nearest dots match.
        let (a, b) = (&t.frames[&shear[0]], &t.frames[&shear[shear.len() / 4]]);
        let motion = mean_dot_motion(&dots(a, &optics), &dots(b, &optics), spacing_px / 2.0)
            .unwrap_or_else(|| panic!("{deg}°: no dot moved"));
        // The slide direction in the image: +x is along columns, +y up the rows.
        let want = [deg.to_radians().cos(), -deg.to_radians().sin()];
        let len = motion[0].hypot(motion[1]);
        let cos = (motion[0] * want[0] + motion[1] * want[1]) / len;
        assert!(
            cos > 20f64.to_radians().cos(),
            "{deg}°: dots moved {motion:?} px, not along {want:?}"
        );
        assert!(len > 1.5, "{deg}°: dots moved only {len:.2} px");
    }
}
