//! Prepared datasets: what the translator writes (source frames in the target's style, with
//! the source's forces) and the trainer reads like a recording: `prepared.json`, the index,
//! and `frames.bin`, every trajectory's network-sized frames back to back.

use std::fs;
use std::io::Write;
use std::path::Path;

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use super::images::{ImageSpec, prepare_image};
use super::sets::{LabelledSet, Loaded, Trajectory};
use crate::train::modality::{MarkerParams, Modality};

/// Name of a prepared dataset's index.
pub const PREPARED_INDEX: &str = "prepared.json";
const PREPARED_FRAMES: &str = "frames.bin";

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PreparedIndex {
    format: String,
    /// `translated`: source images in the target's style, with the source forces.
    role: String,
    width: u32,
    height: u32,
    modality: Modality,
    trajectories: Vec<PreparedTrajectory>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct PreparedTrajectory {
    id: String,
    indenter: String,
    frames: usize,
    forces: Option<Vec<[f32; 3]>>,
}

/// The role a prepared dataset's index gives it (`translated`).
pub(super) fn prepared_role(dir: &Path) -> anyhow::Result<String> {
    Ok(read_prepared_index(dir)?.role)
}

fn read_prepared_index(dir: &Path) -> anyhow::Result<PreparedIndex> {
    let path = dir.join(PREPARED_INDEX);
    let text = fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_slice(&text)
        .with_context(|| format!("{} is not a prepared index", path.display()))
}

/// Write a labelled set as a prepared dataset (`prepared.json` + `frames.bin`), atomically.
pub fn write_prepared(dir: &Path, set: &LabelledSet, role: &str) -> anyhow::Result<()> {
    fs::create_dir_all(dir)?;
    let index = PreparedIndex {
        format: "rig-prepared-1".into(),
        role: role.into(),
        width: set.spec.width,
        height: set.spec.height,
        modality: set.spec.modality,
        trajectories: set
            .trajectories
            .iter()
            .zip(&set.forces)
            .map(|(t, f)| PreparedTrajectory {
                id: t.id.clone(),
                indenter: t.indenter.clone(),
                frames: t.frames,
                forces: Some(f.clone()),
            })
            .collect(),
    };
    let tmp = dir.join(format!("{PREPARED_FRAMES}.partial"));
    {
        let mut f = std::io::BufWriter::new(fs::File::create(&tmp)?);
        for t in &set.trajectories {
            f.write_all(&t.pixels)?;
        }
        f.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    }
    fs::rename(&tmp, dir.join(PREPARED_FRAMES))?;
    crate::durable::write_atomic(
        &dir.join(PREPARED_INDEX),
        &serde_json::to_vec_pretty(&index)?,
    )?;
    Ok(())
}

pub(super) fn load_prepared(
    dir: &Path,
    spec: &ImageSpec,
    want_forces: bool,
) -> anyhow::Result<Vec<Loaded>> {
    let index = read_prepared_index(dir)?;
    let stored = ImageSpec {
        width: index.width,
        height: index.height,
        modality: index.modality,
    };
    let all = fs::read(dir.join(PREPARED_FRAMES)).context("cannot read frames.bin")?;
    let need: usize = index
        .trajectories
        .iter()
        .map(|t| t.frames * stored.frame_bytes())
        .sum();
    if all.len() != need {
        bail!(
            "{}: frames.bin holds {} bytes, the index needs {need}",
            dir.display(),
            all.len()
        );
    }
    if !spec.modality.per_frame() && stored.modality != spec.modality {
        bail!(
            "{} holds {} images at {}×{}; marker displacement is measured on recorded frames: \
             give the recording instead",
            dir.display(),
            stored.modality,
            stored.width,
            stored.height
        );
    }
    if stored.modality != Modality::RgbMarker && stored.modality != spec.modality {
        bail!(
            "{} holds {} images; {} cannot be derived from them",
            dir.display(),
            stored.modality,
            spec.modality
        );
    }
    // Marker dots scale with the image: a recorded 320-px frame has dots of about 5 px radius.
    let params = MarkerParams::for_dot_radius((5.0 * stored.width as f32 / 320.0).max(0.5));
    let mut out = Vec::new();
    let mut off = 0;
    for t in index.trajectories {
        let n = t.frames * stored.frame_bytes();
        let raw = &all[off..off + n];
        off += n;
        let pixels = if stored == *spec {
            raw.to_vec()
        } else {
            let mut px = Vec::with_capacity(t.frames * spec.frame_bytes());
            for chunk in raw.chunks_exact(stored.frame_bytes()) {
                let img = image::RgbImage::from_raw(stored.width, stored.height, chunk.to_vec())
                    .context("bad frame size")?;
                px.extend_from_slice(&prepare_image(&img, spec, &params));
            }
            px
        };
        out.push(Loaded {
            traj: Trajectory {
                id: t.id,
                indenter: t.indenter,
                pixels,
                frames: t.frames,
            },
            forces: if want_forces { t.forces } else { None },
        });
    }
    Ok(out)
}
