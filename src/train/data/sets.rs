//! The trainer's sets and the split they are cut by: [`Split`] (which indenters training sees),
//! [`Trajectory`] (one run's frames), and the three sets, whose types keep target forces out of
//! training (see the parent module's docs).

use anyhow::bail;
use serde::{Deserialize, Serialize};

use super::images::ImageSpec;

/// The paper's unseen indenter group; `paralines` is left out of training (contact covers the
/// whole field of view, a failure case of translation).
pub const PAPER_UNSEEN: [&str; 6] = ["sphere_s", "triangle", "pacman", "wave", "torus", "cone"];
pub const PAPER_EXCLUDED: [&str; 1] = ["paralines"];

/// The seen/unseen indenter split: training uses the seen group only; evaluation reports both.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Split {
    pub unseen: Vec<String>,
    pub excluded: Vec<String>,
}

impl Default for Split {
    fn default() -> Self {
        Self {
            unseen: PAPER_UNSEEN.iter().map(|s| s.to_string()).collect(),
            excluded: PAPER_EXCLUDED.iter().map(|s| s.to_string()).collect(),
        }
    }
}

impl Split {
    pub fn group(&self, indenter: &str) -> &'static str {
        if self.excluded.iter().any(|e| e == indenter) {
            "excluded"
        } else if self.unseen.iter().any(|e| e == indenter) {
            "unseen"
        } else {
            "seen"
        }
    }
    pub fn trains_on(&self, indenter: &str) -> bool {
        self.group(indenter) == "seen"
    }
}

/// One trajectory's frames (RGB u8, frame after frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub id: String,
    pub indenter: String,
    pub pixels: Vec<u8>,
    pub frames: usize,
}

impl Trajectory {
    pub fn frame(&self, i: usize, spec: &ImageSpec) -> &[u8] {
        let n = spec.frame_bytes();
        &self.pixels[i * n..(i + 1) * n]
    }
}

/// Source-sensor (or translated) images with their force labels, N.
#[derive(Debug, Clone)]
pub struct LabelledSet {
    pub spec: ImageSpec,
    pub trajectories: Vec<Trajectory>,
    pub(super) forces: Vec<Vec<[f32; 3]>>,
}

/// Images only.
#[derive(Debug, Clone)]
pub struct UnlabelledSet {
    pub spec: ImageSpec,
    pub trajectories: Vec<Trajectory>,
}

/// Target-sensor images with their forces: for evaluation only.
#[derive(Debug, Clone)]
pub struct EvalSet {
    pub spec: ImageSpec,
    pub trajectories: Vec<Trajectory>,
    pub(super) forces: Vec<Vec<[f32; 3]>>,
}

/// The constructor and accessors a set of frames with forces has, whichever side of the
/// training/evaluation wall it stands on (the two stay distinct types).
macro_rules! with_forces {
    ($set:ident) => {
        impl $set {
            /// A set from frames and forces made in memory (tests, synthetic data, a load).
            pub fn from_parts(
                spec: ImageSpec,
                trajectories: Vec<Trajectory>,
                forces: Vec<Vec<[f32; 3]>>,
            ) -> anyhow::Result<Self> {
                check_parts(&spec, &trajectories, &forces)?;
                Ok(Self {
                    spec,
                    trajectories,
                    forces,
                })
            }
            pub fn forces(&self, traj: usize) -> &[[f32; 3]] {
                &self.forces[traj]
            }
            pub fn images(&self) -> UnlabelledSet {
                UnlabelledSet {
                    spec: self.spec,
                    trajectories: self.trajectories.clone(),
                }
            }
        }
    };
}
with_forces!(LabelledSet);
with_forces!(EvalSet);

impl LabelledSet {
    /// Only the trajectories whose indenter is in the split's seen group.
    pub fn seen_only(self, split: &Split) -> Self {
        self.filtered(|t| split.trains_on(&t.indenter))
    }
    /// Only the trajectories `keep` accepts, with their forces.
    pub fn filtered(self, keep: impl Fn(&Trajectory) -> bool) -> Self {
        let (trajectories, forces) = self
            .trajectories
            .into_iter()
            .zip(self.forces)
            .filter(|(t, _)| keep(t))
            .unzip();
        Self {
            spec: self.spec,
            trajectories,
            forces,
        }
    }
    /// This set's trajectories and then `other`'s, as one set (the same image spec).
    pub fn joined(mut self, other: Self) -> anyhow::Result<Self> {
        if self.spec != other.spec {
            bail!("cannot join sets of two image specs");
        }
        self.trajectories.extend(other.trajectories);
        self.forces.extend(other.forces);
        Ok(self)
    }
    /// Keep the images, replace them by others of the same count (the translator's output).
    pub fn with_images(
        &self,
        spec: ImageSpec,
        trajectories: Vec<Trajectory>,
    ) -> anyhow::Result<Self> {
        Self::from_parts(spec, trajectories, self.forces.clone())
    }
    /// Per-axis (min, max) of every force.
    pub fn force_bounds(&self) -> [(f32, f32); 3] {
        bounds(&self.forces)
    }
}

fn bounds(forces: &[Vec<[f32; 3]>]) -> [(f32, f32); 3] {
    let mut b = [(f32::INFINITY, f32::NEG_INFINITY); 3];
    for f in forces.iter().flatten() {
        for a in 0..3 {
            b[a].0 = b[a].0.min(f[a]);
            b[a].1 = b[a].1.max(f[a]);
        }
    }
    b
}

fn check_parts(
    spec: &ImageSpec,
    trajectories: &[Trajectory],
    forces: &[Vec<[f32; 3]>],
) -> anyhow::Result<()> {
    if trajectories.len() != forces.len() {
        bail!(
            "{} trajectories but {} force lists",
            trajectories.len(),
            forces.len()
        );
    }
    for (t, f) in trajectories.iter().zip(forces) {
        if t.pixels.len() != t.frames * spec.frame_bytes() {
            bail!(
                "trajectory {}: pixel buffer does not match {} frames",
                t.id,
                t.frames
            );
        }
        if f.len() != t.frames {
            bail!(
                "trajectory {}: {} frames but {} forces",
                t.id,
                t.frames,
                f.len()
            );
        }
        if f.iter().flatten().any(|v| !v.is_finite()) {
            bail!("trajectory {}: a force label is not finite", t.id);
        }
    }
    Ok(())
}

/// One decoded trajectory with its forces where the file has them.
pub(super) struct Loaded {
    pub(super) traj: Trajectory,
    pub(super) forces: Option<Vec<[f32; 3]>>,
}
