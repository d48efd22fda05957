//! One problem found in a configuration value: the TOML key path and what is wrong with it.
//!
//! Shared by the rig configuration ([`crate::config`]) and the sections it embeds that check
//! their own values ([`crate::optics::OpticsConfig::problems`]), so neither imports the other
//! for it.

use std::fmt;

/// One problem found in a configuration: the TOML key path and what is wrong with it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// Key path, e.g. `plan.depths_mm[2]`.
    pub key: String,
    /// What is wrong and, where it helps, what would be right.
    pub reason: String,
}

impl fmt::Display for Problem {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.key, self.reason)
    }
}
