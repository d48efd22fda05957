//! The run manifest, `manifest.json`: what was recorded, with what, and how each trajectory went.
//!
//! It is rewritten atomically (temporary file, fsync, rename, fsync of the directory) after every
//! status change, so after a crash it is either the previous or the next version, never a torn
//! one. The calibration and config are opaque JSON supplied by the caller: the recorder stores
//! them as given.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::channels::{
    TOPIC_IMAGE, TOPIC_PAIRED, TOPIC_POSE, TOPIC_STAGE, TOPIC_TRUTH, TOPIC_WRENCH,
};
use crate::durable::write_atomic;

/// File name of the manifest in an output directory.
pub const MANIFEST_NAME: &str = "manifest.json";

/// Messages per kind in one trajectory file.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Counts {
    pub frames: u64,
    pub wrench: u64,
    pub poses: u64,
    pub paired: u64,
    pub stages: u64,
    /// Simulated rig only: true wrench messages (one per frame).
    #[serde(default)]
    pub truth: u64,
}

impl Counts {
    /// The count of the channel `topic` (0 for an unknown topic).
    pub fn of_topic(&self, topic: &str) -> u64 {
        match topic {
            TOPIC_IMAGE => self.frames,
            TOPIC_WRENCH => self.wrench,
            TOPIC_POSE => self.poses,
            TOPIC_PAIRED => self.paired,
            TOPIC_STAGE => self.stages,
            TOPIC_TRUTH => self.truth,
            _ => 0,
        }
    }
}

/// Where a trajectory stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    Pending,
    Complete,
    Failed,
}

/// One trajectory's entry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryEntry {
    pub id: String,
    pub status: Status,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    #[serde(default)]
    pub counts: Counts,
    /// Frames the camera's sequence numbers say were lost.
    #[serde(default)]
    pub frames_dropped: u64,
    /// File name of the complete recording (`<id>.mcap`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
}

/// The sensor the dataset images come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorInfo {
    pub id: String,
    /// `source` (images + forces) or `target` (images for translation).
    pub role: String,
}

/// `manifest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub software_version: String,
    pub indenter: String,
    pub sensor: SensorInfo,
    #[serde(default)]
    pub config: serde_json::Value,
    #[serde(default)]
    pub calibration: serde_json::Value,
    /// By trajectory id, in plan order.
    pub trajectories: Vec<TrajectoryEntry>,
    #[serde(default)]
    pub extra: BTreeMap<String, serde_json::Value>,
}

/// Version string written into manifests: the crate version, plus `git describe` when
/// `RIG_GIT_DESCRIBE` was set at build time (the build does not run git itself).
pub fn software_version() -> String {
    match option_env!("RIG_GIT_DESCRIBE") {
        Some(g) if !g.is_empty() => format!("{} ({g})", env!("CARGO_PKG_VERSION")),
        _ => env!("CARGO_PKG_VERSION").to_owned(),
    }
}

impl Manifest {
    /// A manifest with every planned trajectory pending.
    pub fn new(
        indenter: &str,
        sensor: SensorInfo,
        config: serde_json::Value,
        calibration: serde_json::Value,
        trajectory_ids: &[String],
    ) -> Self {
        Self {
            format: "transforce-rig-dataset/1".into(),
            software_version: software_version(),
            indenter: indenter.to_owned(),
            sensor,
            config,
            calibration,
            trajectories: trajectory_ids
                .iter()
                .map(|id| TrajectoryEntry {
                    id: id.clone(),
                    status: Status::Pending,
                    reason: None,
                    counts: Counts::default(),
                    frames_dropped: 0,
                    file: None,
                })
                .collect(),
            extra: BTreeMap::new(),
        }
    }

    pub fn entry(&self, id: &str) -> Option<&TrajectoryEntry> {
        self.trajectories.iter().find(|t| t.id == id)
    }

    /// The entry for `id`, added (pending) if the plan grew.
    pub fn entry_mut(&mut self, id: &str) -> &mut TrajectoryEntry {
        if let Some(i) = self.trajectories.iter().position(|t| t.id == id) {
            return &mut self.trajectories[i];
        }
        self.trajectories.push(TrajectoryEntry {
            id: id.to_owned(),
            status: Status::Pending,
            reason: None,
            counts: Counts::default(),
            frames_dropped: 0,
            file: None,
        });
        self.trajectories.last_mut().expect("just pushed")
    }

    /// Whether the recording holds forces: false for a sensor recorded without an F/T sensor
    /// (its rig config's `force_sensor` is `null`: images, TCP poses and stage labels only). A
    /// manifest whose config does not say (older formats, synthetic sets) counts as with.
    pub fn records_forces(&self) -> bool {
        !matches!(
            self.config.get("force_sensor"),
            Some(serde_json::Value::Null)
        )
    }

    /// Read `dir/manifest.json`.
    pub fn load(dir: &Path) -> Result<Self, String> {
        let path = dir.join(MANIFEST_NAME);
        let text =
            std::fs::read(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        serde_json::from_slice(&text)
            .map_err(|e| format!("{} is not a manifest: {e}", path.display()))
    }

    /// Write `dir/manifest.json` atomically.
    pub fn save(&self, dir: &Path) -> std::io::Result<()> {
        let json = serde_json::to_vec_pretty(self).map_err(std::io::Error::other)?;
        write_atomic(&dir.join(MANIFEST_NAME), &json)
    }
}
