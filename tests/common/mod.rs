//! Helpers shared by the tests that drive the `rig` binary on the simulated rig.
#![allow(dead_code)] // each test binary uses its own subset

use std::path::{Path, PathBuf};
use std::process::Output;

/// The built-in simulated rig's config, as shipped.
pub fn sim_config() -> PathBuf {
    PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/rig-configs/sim-source.toml"
    ))
}

/// The shipped simulated config with each `(from, to)` line replaced, written as `dir/name`.
/// Panics when the shipped config lacks a `from` (the test would silently test nothing).
pub fn edited_sim_config(dir: &Path, name: &str, edits: &[(&str, &str)]) -> PathBuf {
    let mut text = std::fs::read_to_string(sim_config()).unwrap();
    for (from, to) in edits {
        assert!(text.contains(from), "the shipped config has no {from:?}");
        text = text.replace(from, to);
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// Exit status, stdout and stderr of a finished command, for assertion messages.
pub fn output_text(out: &Output) -> String {
    format!(
        "status {:?}\n--- stdout\n{}\n--- stderr\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}
