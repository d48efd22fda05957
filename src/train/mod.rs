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
pub mod pitch;
pub mod report;
pub mod reproduce;

pub use config::{DataConfig, TrainerConfig};

/// How a long training run reports while it runs, on stderr.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// A progress bar (stderr is a terminal).
    Bar,
    /// A line an epoch (stderr is a log file or a pipe: a bar would print nothing until the
    /// end, so a long run would look hung).
    Lines,
    /// Nothing: the caller reports (the demo's and `rig reproduce`'s force models, the
    /// benchmarks).
    Silent,
}

impl Progress {
    /// A bar where progress bars show (stderr is a terminal: the callers' `progress`), lines
    /// otherwise.
    pub fn bar_or_lines(bar: bool) -> Self {
        if bar { Self::Bar } else { Self::Lines }
    }
}

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

/// Lets the C allocator keep and reuse the memory of freed tensors instead of handing every
/// large one back to the kernel and faulting in fresh zeroed pages for the next: blocks up to
/// 32 MiB (glibc's ceiling for this setting; a training step's activations at 64 × 48 are up to
/// 13 MB) come from the heap, and up to 512 MiB of free heap stays mapped. glibc's defaults
/// (`mallopt(3)`) serve such blocks with `mmap` and unmap them on free, so each step paid its
/// page faults again: keeping them made the ResNet-18 training step about 17 % faster on 2 cores
/// with the same peak memory (`rig bench train --speed --size 64x48`). Skipped when the user set
/// either through the environment (`MALLOC_MMAP_THRESHOLD_`, `MALLOC_TRIM_THRESHOLD_`,
/// `GLIBC_TUNABLES`), and a no-op off glibc.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let set_by_user = [
            "MALLOC_MMAP_THRESHOLD_",
            "MALLOC_TRIM_THRESHOLD_",
            "GLIBC_TUNABLES",
        ]
        .iter()
        .any(|v| std::env::var_os(v).is_some());
        if !set_by_user {
            use nix::libc::{M_MMAP_THRESHOLD, M_TRIM_THRESHOLD, mallopt};
            // SAFETY: `mallopt` only changes two allocator parameters; it is called before any
            // other thread exists (the first thing `main` does) and the values are in range.
            unsafe {
                mallopt(M_MMAP_THRESHOLD, 32 << 20);
                mallopt(M_TRIM_THRESHOLD, 512 << 20);
            }
        }
    }
}
