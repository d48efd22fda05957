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
//! - [`inception`]: the FID Inception-v3 whose features FID and KID are computed on.
//! - [`demo`]: the whole story of `rig demo` on the simulated rig.
//! - [`reproduce`]: the paper's experiment, `rig reproduce`.
//!
//! The commands themselves are in `crate::cli::train` and `crate::cli::demo`.

pub mod batch;
mod config;
pub mod cyclegan;
pub mod data;
pub mod demo;
pub mod eval;
pub mod force;
pub mod inception;
pub mod metrics;
pub mod modality;
pub mod nn;
pub mod report;
pub mod reproduce;

pub use config::{DataConfig, TrainerConfig};

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
