//! Which rig config a command uses: `--config FILE` if given; else `./rig.toml` if present;
//! else the embedded simulated source rig (`rig-configs/sim-source.toml`), announced on stderr.

use std::fmt;
use std::path::{Path, PathBuf};

use rig_core::config::RigConfig;

/// File picked up as the rig config when no `--config` is given.
pub const LOCAL_CONFIG: &str = "rig.toml";

/// Where the rig config came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ConfigSource {
    /// `--config FILE`.
    Explicit(PathBuf),
    /// `./rig.toml` in the working directory.
    Local(PathBuf),
    /// The embedded `rig-configs/sim-source.toml`.
    EmbeddedSimSource,
}

impl fmt::Display for ConfigSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConfigSource::Explicit(p) | ConfigSource::Local(p) => write!(f, "{}", p.display()),
            ConfigSource::EmbeddedSimSource => {
                f.write_str("built-in simulated rig (rig-configs/sim-source.toml)")
            }
        }
    }
}

/// A validated rig config and where it came from.
#[derive(Debug, Clone)]
pub struct LoadedConfig {
    pub config: RigConfig,
    pub source: ConfigSource,
}

/// `--config FILE` if given; else `./rig.toml` if present; else the embedded simulated rig, which
/// is announced on stderr so nobody mistakes it for their lab rig.
pub fn resolve_config(explicit: Option<&Path>) -> anyhow::Result<LoadedConfig> {
    if let Some(path) = explicit {
        let config = RigConfig::load(path)?;
        return Ok(LoadedConfig {
            config,
            source: ConfigSource::Explicit(path.to_owned()),
        });
    }
    let local = Path::new(LOCAL_CONFIG);
    if local.is_file() {
        let config = RigConfig::load(local)?;
        return Ok(LoadedConfig {
            config,
            source: ConfigSource::Local(local.to_owned()),
        });
    }
    eprintln!(
        "note: no --config given and no ./{LOCAL_CONFIG} here; using the built-in simulated rig \
         (rig-configs/sim-source.toml)"
    );
    Ok(LoadedConfig {
        config: RigConfig::sim_source(),
        source: ConfigSource::EmbeddedSimSource,
    })
}
