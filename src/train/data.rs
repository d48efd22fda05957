//! Datasets for the trainer: recorded runs (`rig run` output: a manifest and an MCAP file per
//! trajectory) and prepared datasets (the translator's output), decoded once into a cache.
//!
//! Who may see forces is enforced by the types:
//! - [`LabelledSet`] (images + forces) is built only from source-sensor or translated datasets;
//!   [`load_labelled`] refuses a target-sensor dataset.
//! - [`UnlabelledSet`] (images only) is what translation gets from the target sensor; its loader
//!   never reads a force.
//! - [`EvalSet`] holds the target sensor's forces; only [`crate::train::eval`] reads them, and no
//!   training function accepts one.

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use super::modality::{MarkerParams, Modality};
use crate::record::channels::{TOPIC_IMAGE, TOPIC_PAIRED};
use crate::record::manifest::{Manifest, Status};
use crate::record::reader::{self, Message};

mod cache;
mod images;
mod prep;
mod prepared;
mod sets;
pub use images::{ImageSpec, prepare_image};
pub use prep::{
    FLOW_VIEW_MM, FramePrep, SHADING_VIEW_MM, apply_shading_gain, flow_image, mean_shading,
    mirror_flow_image, shading_gain,
};
use prepared::load_prepared;
pub use prepared::{PREPARED_INDEX, write_prepared};
use sets::Loaded;
pub use sets::{
    EvalSet, LabelledSet, PAPER_EXCLUDED, PAPER_UNSEEN, Split, Trajectory, UnlabelledSet,
};

/// The gain that brings the shading change of `trajectories` (images of `spec`) to the scale of
/// a model trained on another sensor, [`shading_gain`] of the two [`mean_shading`]s: 1 unless
/// they are D+S and the model records its training set's mean (`trained`). Their mean is taken
/// over the indenters `split` trains on, as the model's was (the translator likewise reads the
/// target's seen indenters only), or over all when there is none of them.
pub fn shading_gain_of(
    spec: &ImageSpec,
    trajectories: &[Trajectory],
    trained: Option<f64>,
    split: &Split,
) -> f64 {
    fn pixels(t: &Trajectory) -> &[u8] {
        &t.pixels
    }
    if spec.modality != Modality::FlowShading {
        return 1.0;
    }
    let seen = |t: &&Trajectory| split.trains_on(&t.indenter);
    let here = if trajectories.iter().any(|t| seen(&t)) {
        mean_shading(trajectories.iter().filter(seen).map(pixels))
    } else {
        mean_shading(trajectories.iter().map(pixels))
    };
    match (trained, here) {
        (Some(t), Some(h)) => shading_gain(t, h),
        _ => 1.0,
    }
}

impl EvalSet {
    /// [`shading_gain_of`] this set's trajectories.
    pub fn shading_gain_for(&self, trained: Option<f64>, split: &Split) -> f64 {
        shading_gain_of(&self.spec, &self.trajectories, trained, split)
    }

    /// This set with its shading change scaled by `gain` ([`apply_shading_gain`]).
    pub fn with_shading_gain(&self, gain: f64) -> EvalSet {
        let mut set = self.clone();
        for t in &mut set.trajectories {
            apply_shading_gain(&mut t.pixels, gain);
        }
        set
    }
}

// ---------------------------------------------------------------------------------------------
// Loading

/// Forces of each trajectory's frames, N.
type ForceLists = Vec<Vec<[f32; 3]>>;

/// The runs in `dir`: `dir` itself when it holds a manifest, else its subdirectories that do.
pub fn find_runs(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    if dir.join("manifest.json").is_file() {
        return Ok(vec![dir.to_path_buf()]);
    }
    let mut runs = Vec::new();
    let entries = fs::read_dir(dir).with_context(|| format!("cannot read {}", dir.display()))?;
    for e in entries {
        let p = e?.path();
        if p.join("manifest.json").is_file() {
            runs.push(p);
        }
    }
    runs.sort();
    if runs.is_empty() {
        bail!(
            "{} holds no dataset: expected a manifest.json (a `rig run` output), subdirectories \
             with one, or a prepared dataset ({PREPARED_INDEX})",
            dir.display()
        );
    }
    Ok(runs)
}

/// The role (`source` / `target` / `translated`) of the dataset(s) in `dir`.
pub fn role_of(dir: &Path) -> anyhow::Result<String> {
    if dir.join(PREPARED_INDEX).is_file() {
        return prepared::prepared_role(dir);
    }
    let mut roles: Vec<String> = find_runs(dir)?
        .iter()
        .map(|r| {
            Manifest::load(r)
                .map(|m| m.sensor.role)
                .map_err(anyhow::Error::msg)
        })
        .collect::<anyhow::Result<_>>()?;
    roles.sort();
    roles.dedup();
    match roles.as_slice() {
        [one] => Ok(one.clone()),
        _ => bail!("{} mixes sensor roles {roles:?}", dir.display()),
    }
}

/// Source-sensor or translated images with forces. A target-sensor dataset is refused: its
/// forces exist only to evaluate.
pub fn load_labelled(dir: &Path, spec: &ImageSpec, progress: bool) -> anyhow::Result<LabelledSet> {
    load_labelled_zoomed(dir, spec, 1.0, progress)
}

/// [`load_labelled`] with each recorded frame first magnified `zoom` times about its centre
/// (`images::zoom_about_centre`; 1: as recorded). The translator's source images take
/// this step when the two sensors' marker pitches are matched ([`super::pitch::pitch_zoom`]).
/// A prepared dataset is already at the network's size and is loaded as it is.
pub fn load_labelled_zoomed(
    dir: &Path,
    spec: &ImageSpec,
    zoom: f64,
    progress: bool,
) -> anyhow::Result<LabelledSet> {
    let role = role_of(dir)?;
    if role == "target" {
        bail!(
            "{} is a target-sensor dataset: its forces are for evaluation only (`rig eval`), \
             never for training",
            dir.display()
        );
    }
    let loaded = load_any(dir, spec, zoom, true, progress)?;
    let (trajectories, forces) = labelled_parts(loaded, dir)?;
    LabelledSet::from_parts(*spec, trajectories, forces)
}

/// Images only, from any dataset (forces are not even read).
pub fn load_unlabelled(
    dir: &Path,
    spec: &ImageSpec,
    progress: bool,
) -> anyhow::Result<UnlabelledSet> {
    let loaded = load_any(dir, spec, 1.0, false, progress)?;
    Ok(UnlabelledSet {
        spec: *spec,
        trajectories: loaded.into_iter().map(|l| l.traj).collect(),
    })
}

/// Whether the dataset(s) in `dir` hold forces: false when a run was recorded without an F/T
/// sensor ([`Manifest::records_forces`]), whose images serve the translator only.
pub fn has_forces(dir: &Path) -> anyhow::Result<bool> {
    if dir.join(PREPARED_INDEX).is_file() {
        return Ok(true);
    }
    for run in find_runs(dir)? {
        if !Manifest::load(&run)
            .map_err(anyhow::Error::msg)?
            .records_forces()
        {
            return Ok(false);
        }
    }
    Ok(true)
}

/// Images with forces for evaluation, from any dataset that has forces.
pub fn load_eval(dir: &Path, spec: &ImageSpec, progress: bool) -> anyhow::Result<EvalSet> {
    let loaded = load_any(dir, spec, 1.0, true, progress)?;
    let (trajectories, forces) = labelled_parts(loaded, dir)?;
    EvalSet::from_parts(*spec, trajectories, forces)
}

fn labelled_parts(
    loaded: Vec<Loaded>,
    dir: &Path,
) -> anyhow::Result<(Vec<Trajectory>, ForceLists)> {
    let mut trajs = Vec::new();
    let mut forces = Vec::new();
    for l in loaded {
        let f = l.forces.with_context(|| {
            format!(
                "{}: trajectory {} has no force labels",
                dir.display(),
                l.traj.id
            )
        })?;
        trajs.push(l.traj);
        forces.push(f);
    }
    Ok((trajs, forces))
}

fn load_any(
    dir: &Path,
    spec: &ImageSpec,
    zoom: f64,
    want_forces: bool,
    progress: bool,
) -> anyhow::Result<Vec<Loaded>> {
    if dir.join(PREPARED_INDEX).is_file() {
        return load_prepared(dir, spec, want_forces);
    }
    let mut jobs = Vec::new();
    for run in find_runs(dir)? {
        let m = Manifest::load(&run).map_err(anyhow::Error::msg)?;
        // A target recorded without an F/T sensor: every frame, and no forces to give.
        let unlabelled = !m.records_forces();
        if unlabelled && want_forces {
            bail!(
                "{} was recorded without an F/T sensor (its rig config has no [force_sensor]): \
                 its frames carry no forces. Evaluating a force model needs a labelled target, \
                 recorded with an F/T sensor fitted; this recording serves the translator as it \
                 is (`rig train translate --target`)",
                run.display()
            );
        }
        // Dots grow with the magnification.
        let params = marker_params(&m.config).scaled(zoom as f32);
        let optics = if spec.modality.per_frame() {
            None
        } else {
            if zoom != 1.0 {
                bail!(
                    "{}: marker displacement is measured on the frames as recorded, not zoomed",
                    run.display()
                );
            }
            Some(sensor_optics(&m.config).with_context(|| {
                format!(
                    "{}: marker displacement needs the sensor's optics",
                    run.display()
                )
            })?)
        };
        for t in &m.trajectories {
            if t.status != Status::Complete {
                continue;
            }
            if let Some(file) = &t.file {
                jobs.push((
                    run.join(file),
                    t.id.clone(),
                    m.indenter.clone(),
                    params,
                    optics.clone(),
                    unlabelled,
                ));
            }
        }
    }
    if jobs.is_empty() {
        bail!("{} has no complete trajectory", dir.display());
    }
    let bar = super::progress_bar(progress, jobs.len() as u64, "decoding");
    let workers = std::thread::available_parallelism()
        .map_or(1, |n| n.get())
        .min(jobs.len());
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut results: Vec<Option<anyhow::Result<Loaded>>> = (0..jobs.len()).map(|_| None).collect();
    let slots = std::sync::Mutex::new(&mut results);
    std::thread::scope(|s| {
        for _ in 0..workers {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some((path, id, indenter, params, optics, unlabelled)) = jobs.get(i) else {
                        break;
                    };
                    let prep = FramePrep::new(spec, *params, optics.as_ref());
                    let want = if *unlabelled {
                        Want::EveryFrame
                    } else {
                        Want::Paired {
                            forces: want_forces,
                        }
                    };
                    let r = prep
                        .and_then(|prep| {
                            load_trajectory(path, id, indenter, spec, zoom, prep, want)
                        })
                        .with_context(|| format!("{}", path.display()));
                    bar.inc(1);
                    slots.lock().expect("loader poisoned")[i] = Some(r);
                }
            });
        }
    });
    bar.finish_and_clear();
    results
        .into_iter()
        .map(|r| r.expect("every job ran"))
        .collect()
}

/// Marker size in pixels of the recorded images, from the rig config in the manifest.
pub fn marker_params(config: &serde_json::Value) -> MarkerParams {
    let optics = &config["optics"];
    let dot = optics["markers"]["dot_diameter_mm"].as_f64();
    let mm_px = optics["mm_per_px"].as_f64();
    match (dot, mm_px) {
        (Some(d), Some(s)) if d > 0.0 && s > 0.0 => {
            MarkerParams::for_dot_radius((d / 2.0 / s) as f32)
        }
        _ => MarkerParams::default(),
    }
}

/// The sensor's optics from a manifest's rig config.
pub fn sensor_optics(config: &serde_json::Value) -> anyhow::Result<rig_core::optics::OpticsConfig> {
    let optics = config
        .get("optics")
        .context("the manifest's config has no [optics] section")?;
    serde_json::from_value(optics.clone()).context("the manifest's [optics] section")
}

/// Which frames of a trajectory file to load.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Want {
    /// The frames with a paired force (with their forces when `forces`).
    Paired { forces: bool },
    /// Every frame, no forces: a recording without an F/T sensor has no paired records.
    EveryFrame,
}

/// Decode one trajectory file (through the cache).
fn load_trajectory(
    path: &Path,
    id: &str,
    indenter: &str,
    spec: &ImageSpec,
    zoom: f64,
    mut prep: FramePrep,
    want: Want,
) -> anyhow::Result<Loaded> {
    let want_forces = want == Want::Paired { forces: true };
    let every_frame = want == Want::EveryFrame;
    let stamp = cache::stamp(path)?;
    let cache = cache::path_for(path, id, spec, zoom, every_frame);
    if let Some((pixels, frames, forces)) = cache::read(&cache, stamp, spec) {
        return Ok(Loaded {
            traj: Trajectory {
                id: id.into(),
                indenter: indenter.into(),
                pixels,
                frames,
            },
            forces: want_forces.then_some(forces).flatten(),
        });
    }
    let bytes = fs::read(path)?;
    let mut images: Vec<(i64, (crate::record::ImageFormat, Vec<u8>))> = Vec::new();
    let mut paired: BTreeMap<i64, [f32; 3]> = BTreeMap::new();
    // Only the frames and their paired forces are decoded.
    let wanted = |topic: &str| topic == TOPIC_IMAGE || topic == TOPIC_PAIRED;
    for msg in reader::messages_on(&bytes, wanted).map_err(anyhow::Error::msg)? {
        match msg.map_err(anyhow::Error::msg)? {
            Message::Frame {
                seq, format, data, ..
            } => images.push((seq, (format, data))),
            Message::Paired(m) => {
                if let Some(f) = m.force_n {
                    paired.insert(m.frame_seq, [f[0] as f32, f[1] as f32, f[2] as f32]);
                }
            }
            _ => {}
        }
    }
    // Frames without a paired force (refused pairings) are left out of every set, so that a
    // labelled and an unlabelled load of one file agree. A file recorded without an F/T sensor
    // has none paired: all its frames are kept.
    if !every_frame {
        images.retain(|(seq, _)| paired.contains_key(seq));
    }
    images.sort_by_key(|(seq, _)| *seq);
    let mut pixels = Vec::with_capacity(images.len() * spec.frame_bytes());
    let mut forces = Vec::with_capacity(images.len());
    for (seq, (format, data)) in &images {
        let img = crate::record::png::decode_as(*format, data)
            .with_context(|| format!("frame {seq} is not a readable {}", format.as_str()))?;
        let img = if zoom == 1.0 {
            img
        } else {
            images::zoom_about_centre(&img, zoom)
        };
        pixels.extend_from_slice(&prep.next(&img).with_context(|| format!("frame {seq}"))?);
        if let Some(f) = paired.get(seq) {
            forces.push(*f);
        }
    }
    let frames = images.len();
    cache::write(&cache, stamp, spec, &pixels, frames, &forces);
    Ok(Loaded {
        traj: Trajectory {
            id: id.into(),
            indenter: indenter.into(),
            pixels,
            frames,
        },
        forces: want_forces.then_some(forces),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_defaults_to_the_papers_groups() {
        let s = Split::default();
        assert_eq!(s.group("cone"), "unseen");
        assert_eq!(s.group("sphere"), "seen");
        assert_eq!(s.group("paralines"), "excluded");
        assert!(s.trains_on("hexagon"));
        assert!(!s.trains_on("torus"));
    }

    #[test]
    fn labelled_parts_are_checked() {
        let spec = ImageSpec {
            width: 2,
            height: 2,
            modality: Modality::RgbMarker,
        };
        let traj = Trajectory {
            id: "t".into(),
            indenter: "cone".into(),
            pixels: vec![0; 24],
            frames: 2,
        };
        assert!(LabelledSet::from_parts(spec, vec![traj.clone()], vec![vec![[0.0; 3]; 2]]).is_ok());
        assert!(
            LabelledSet::from_parts(spec, vec![traj.clone()], vec![vec![[0.0; 3]; 3]]).is_err()
        );
        let nan = LabelledSet::from_parts(spec, vec![traj], vec![vec![[f32::NAN, 0.0, 0.0]; 2]]);
        assert!(nan.unwrap_err().to_string().contains("not finite"));
    }

    /// A 160 × 120 frame of dark 3.2 px-radius dots on a 16 px lattice over a lit gradient: at
    /// 32 × 24, dots of 0.64 px radius 3.2 px apart, the simulated target's at the CPU
    /// protocol's sizes.
    fn dotted_frame() -> image::RgbImage {
        image::RgbImage::from_fn(160, 120, |x, y| {
            let (dx, dy) = ((x % 16) as f32 - 8.0, (y % 16) as f32 - 8.0);
            let shade = 120 + (x / 2) as u8;
            if dx * dx + dy * dy <= 3.2 * 3.2 {
                image::Rgb([25, 20, 20])
            } else {
                image::Rgb([shade, shade.saturating_sub(20), 90])
            }
        })
    }

    #[test]
    fn a_frame_and_its_network_sized_copy_give_the_same_modality_image() {
        // A translated set holds network-sized R+M frames; R and M are derived from them. A
        // recorded frame must give the force model the same image as its resized copy would,
        // or the TransForce models are tested on images unlike those they learnt from.
        let big = dotted_frame();
        let params = MarkerParams::for_dot_radius(3.2);
        let small = image::imageops::resize(&big, 32, 24, image::imageops::FilterType::Triangle);
        for modality in Modality::ALL {
            let spec = ImageSpec {
                width: 32,
                height: 24,
                modality,
            };
            let from_big = prepare_image(&big, &spec, &params);
            let from_small = prepare_image(&small, &spec, &params.scaled(0.2));
            assert_eq!(from_big.len(), 32 * 24 * 3);
            assert_eq!(from_big, from_small, "{modality}");
        }
        // And M still finds the dots at that size: bright on the pixels holding dot centres
        // (1.6, 4.8 and 11.2 px), dark on those halfway between them (3.2, 6.4 and 9.6 px).
        let spec = ImageSpec {
            width: 32,
            height: 24,
            modality: Modality::Marker,
        };
        let m = prepare_image(&big, &spec, &params);
        let at = |x: usize, y: usize| m[(y * 32 + x) * 3] as i32;
        let (on, off) = (
            at(1, 1) + at(4, 4) + at(11, 11),
            at(3, 3) + at(6, 9) + at(9, 6),
        );
        assert!(on > off + 3 * 40, "dots {on}, between them {off}");
    }

    #[test]
    fn marker_sizes_scale_with_the_image() {
        let p = MarkerParams {
            threshold: 0.2,
            ..MarkerParams::for_dot_radius(3.2)
        };
        let q = p.scaled(0.2);
        assert!((q.dot_radius_px - 0.64).abs() < 1e-6);
        assert_eq!(q.threshold, 0.2);
        assert_eq!(q.inpaint_radius_px, 2.0);
        assert_eq!(p.scaled(2.0).dot_radius_px, 6.4);
        for bad in [0.0, -1.0, f32::NAN, f32::INFINITY] {
            assert_eq!(p.scaled(bad), p);
        }
        // Never below half a pixel.
        assert_eq!(p.scaled(0.01).dot_radius_px, 0.5);
    }
}
