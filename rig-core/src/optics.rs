//! GelSight-type sensor optics as configured in a rig config's `[optics]` section.
//!
//! (Skeleton: the fields are being defined with the optics simulator.)

use serde::{Deserialize, Serialize};

/// `[optics]`: camera resolution and scale, LEDs, background and marker pattern.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct OpticsConfig {}
