//! The trainer's settings (`--config FILE`, TOML with `[data]`, `[translate]`, `[force]`,
//! `[fid]`).

use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::cyclegan::TranslateConfig;
use super::data::{ImageSpec, Split};
use super::eval::FidConfig;
use super::force::ForceConfig;
use super::modality::Modality;

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
    pub translate: TranslateConfig,
    pub force: ForceConfig,
    pub fid: FidConfig,
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
