//! The TransForce trainer: a labelled source-sensor dataset and an unlabelled target-sensor
//! dataset in, a force model for the target sensor out, with the paper's evaluation.
//!
//! - [`batch`]: sequences (T frames in time order, K per trajectory) and image tensors.
//! - [`data`]: recorded runs and prepared datasets, the decode cache, the seen/unseen split;
//!   types that keep target forces out of training.
//! - [`modality`]: R+M (as captured), R (markers inpainted, Telea 2004), M (markers only).
//! - [`cyclegan`]: the translator of `rig train translate`.
//! - [`force`]: the force model of `rig train force` (encoder + LSTM or the no-LSTM control,
//!   γ-weighted L1).
//! - [`eval`], [`metrics`], [`report`]: what `rig eval` computes (MAE, R², total-force MAE,
//!   FID/KID; Markdown, CSV and plots).
//! - [`demo`]: the whole story of `rig demo` on the simulated rig.
//!
//! The commands themselves are in `crate::cli::train` and `crate::cli::demo`.

pub mod batch;
pub mod cyclegan;
pub mod data;
pub mod demo;
pub mod eval;
pub mod force;
pub mod metrics;
pub mod modality;
pub mod nn;
pub mod report;

use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use data::{ImageSpec, Split};
use modality::Modality;

/// A progress bar on stderr (hidden when `show` is false).
pub fn progress_bar(show: bool, len: u64, what: &str) -> indicatif::ProgressBar {
    if !show {
        return indicatif::ProgressBar::hidden();
    }
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template(&format!(
            "{what:>10} [{{bar:30}}] {{pos}}/{{len}} {{elapsed}}<{{eta}} {{msg}}"
        ))
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar
}

/// Image size and split for every trainer command.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DataConfig {
    /// Network input size. The paper works at 256 px; 64 × 48 keeps CPU training practical.
    pub width: u32,
    pub height: u32,
    pub split: Split,
}

impl Default for DataConfig {
    fn default() -> Self {
        Self {
            width: 64,
            height: 48,
            split: Split::default(),
        }
    }
}

/// The trainer's TOML configuration (`--config FILE`); every key has a default.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainerConfig {
    pub data: DataConfig,
    pub translate: cyclegan::TranslateConfig,
    pub force: force::ForceConfig,
}

impl TrainerConfig {
    pub fn load(path: Option<&Path>) -> anyhow::Result<Self> {
        match path {
            None => Ok(Self::default()),
            Some(p) => {
                let text = std::fs::read_to_string(p)
                    .with_context(|| format!("cannot read {}", p.display()))?;
                toml::from_str(&text)
                    .with_context(|| format!("{} is not a trainer config", p.display()))
            }
        }
    }
    pub fn spec(&self, modality: Modality) -> ImageSpec {
        ImageSpec {
            width: self.data.width,
            height: self.data.height,
            modality,
        }
    }
}
