//! Reading a configuration: parse (unknown keys rejected), locate a parse error's key, then
//! validate. Only a validated configuration leaves [`RigConfig::from_toml_str`] or
//! [`RigConfig::load`].

use std::path::Path;

use super::problems::{ConfigError, field_in_message, locate};
use super::schema::RigConfig;

/// The shipped simulated source-sensor rig (`rig-configs/sim-source.toml`), embedded so the binary
/// works from any directory.
pub const SIM_SOURCE_TOML: &str = include_str!("../../../rig-configs/sim-source.toml");
/// The shipped simulated target-sensor rig (`rig-configs/sim-target.toml`).
pub const SIM_TARGET_TOML: &str = include_str!("../../../rig-configs/sim-target.toml");

impl RigConfig {
    /// Parses and validates a configuration held in a string.
    pub fn from_toml_str(text: &str) -> Result<Self, ConfigError> {
        Self::from_toml_str_named(text, "<string>")
    }

    /// As [`RigConfig::from_toml_str`], naming `origin` (a path, say) in errors.
    pub fn from_toml_str_named(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let config: RigConfig = toml::from_str(text).map_err(|e| {
            let (key, line) = match e.span() {
                // An empty span at 0 is the document itself (a missing top-level table): no line.
                Some(span) if span.is_empty() && span.start == 0 => {
                    (locate(text, span, e.message()).0, None)
                }
                Some(span) => locate(text, span, e.message()),
                None => (field_in_message(e.message()), None),
            };
            ConfigError::Parse {
                origin: origin.to_owned(),
                key,
                line,
                message: e.message().to_owned(),
            }
        })?;
        config.validate().map_err(|problems| ConfigError::Invalid {
            origin: origin.to_owned(),
            problems,
        })?;
        Ok(config)
    }

    /// Reads, parses and validates a configuration file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, ConfigError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Io {
            path: path.to_owned(),
            source,
        })?;
        Self::from_toml_str_named(&text, &path.display().to_string())
    }

    /// The built-in simulated source-sensor rig (`rig-configs/sim-source.toml`).
    pub fn sim_source() -> Self {
        // The embedded file is part of the build and covered by tests; failing here is a bug.
        Self::from_toml_str_named(SIM_SOURCE_TOML, "<embedded rig-configs/sim-source.toml>")
            .unwrap_or_else(|e| panic!("embedded sim-source config is invalid: {e}"))
    }

    /// The built-in simulated target-sensor rig (`rig-configs/sim-target.toml`).
    pub fn sim_target() -> Self {
        Self::from_toml_str_named(SIM_TARGET_TOML, "<embedded rig-configs/sim-target.toml>")
            .unwrap_or_else(|e| panic!("embedded sim-target config is invalid: {e}"))
    }
}
