//! Rig configuration: one TOML file describes one rig (robot, sensor, elastomer, contact plan,
//! safety limits, force sensor and camera).
//!
//! A file is parsed with unknown keys rejected (a misspelt safety limit must never fall back to a
//! default silently), then [`RigConfig::validate`] checks every value and names the offending key
//! path and the reason, e.g. `plan.depths_mm[2]: 1.2 mm exceeds safety.max_depth_mm = 1.0 mm`.
//! Only a validated configuration leaves [`RigConfig::from_toml_str`] or [`RigConfig::load`].
//!
//! Units are in the key names: `_mm`, `_mm_s` (mm/s), `_mm_s2` (mm/s²), `_deg`, `_hz`, `_n`,
//! `_mpa`. Poses follow UR's convention: `[x, y, z, rx, ry, rz]`, position in metres, rotation
//! as a rotation vector (axis × angle, radians), expressed in the robot base frame.
//!
//! # Frames
//!
//! - **Robot base frame**: UR's base frame; every TCP pose the rig commands is in it.
//! - **Sensor surface frame** (`sensor.surface_frame`): origin at the centre of the undeformed gel
//!   surface, x along the elastomer's `size_x_mm` side, y along its `size_y_mm` side, +z the gel's
//!   outward normal (pointing out of the gel, towards the indenter). Pressing means moving the TCP
//!   along −z of this frame; a depth of 0.8 mm is the TCP at z = −0.8 mm in this frame.
//! - **TCP at contact**: "tool pointing down into the gel": the tool's +z axis is the surface
//!   frame's −z, its x axis the surface frame's x. In surface-frame coordinates that orientation
//!   is the rotation vector `(π, 0, 0)`; with the shipped simulated rig (surface frame = identity
//!   orientation) the planned TCP poses therefore have rotation vectors near `(π, 0, 0)` in the
//!   base frame, the numerically delicate case of UR rotation vectors, kept on purpose.
//! - The TCP itself must be the indenter's tip (lowest point of its contact face): set it on the
//!   teach pendant, or give `robot.tcp_offset` so the rig's control program sets it.
//!
//! # Files
//!
//! - [`schema`]: the TOML sections as serde types, their defaults and units.
//! - [`load`]: reading a file or string: parse, locate a parse error's key, validate.
//! - [`validation`]: [`RigConfig::validate`], every check with the key path it names.
//! - [`problems`]: [`ConfigError`] and the best-effort key path and line of a TOML error
//!   ([`Problem`] itself lives in [`crate::problem`], shared with [`crate::optics`]).
//! - [`ids`]: how depths and angles appear in trajectory ids, and the characters an id may use.

pub mod ids;
pub mod load;
pub mod problems;
pub mod schema;
pub mod validation;

pub use crate::problem::Problem;
pub use ids::{format_angle_deg, format_depth_mm};
pub use load::{SIM_SOURCE_TOML, SIM_TARGET_TOML};
pub use problems::ConfigError;
pub use schema::*;
pub use validation::MAX_TRAJECTORIES;
