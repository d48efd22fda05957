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

use std::fmt;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::pose::Pose;

/// The shipped simulated source-sensor rig (`rig-configs/sim-source.toml`), embedded so the binary
/// works from any directory.
pub const SIM_SOURCE_TOML: &str = include_str!("../../rig-configs/sim-source.toml");
/// The shipped simulated target-sensor rig (`rig-configs/sim-target.toml`).
pub const SIM_TARGET_TOML: &str = include_str!("../../rig-configs/sim-target.toml");

/// Maximum RTDE output frequency of an e-Series controller (RTDE guide: 500 Hz).
pub const E_SERIES_MAX_RTDE_HZ: f64 = 500.0;
/// Maximum RTDE output frequency of a CB3 controller (RTDE guide: 125 Hz).
pub const CB3_MAX_RTDE_HZ: f64 = 125.0;

/// Most trajectories one plan may hold (the paper's plan has 240), so a typo cannot make a plan
/// that exhausts memory or runs for months.
pub const MAX_TRAJECTORIES: usize = 100_000;

/// A whole rig description. See the module docs for frames and units.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    /// The UR controller and how to reach it.
    #[serde(default)]
    pub robot: RobotConfig,
    /// Which tactile sensor this rig holds and where its gel surface is.
    pub sensor: SensorConfig,
    /// The gel: size, thickness and assumed material values.
    #[serde(default)]
    pub elastomer: ElastomerConfig,
    /// The contact plan: points × depths × directions, and the motion of each stage.
    #[serde(default)]
    pub plan: PlanConfig,
    /// Limits checked for every waypoint before anything moves.
    pub safety: SafetyConfig,
    /// The force/torque sensor front end; absent: none configured.
    #[serde(default)]
    pub force_sensor: Option<ForceSensorConfig>,
    /// The tactile sensor's camera; absent: none configured.
    #[serde(default)]
    pub camera: Option<CameraConfig>,
    /// The tactile sensor's optics (LEDs, background, markers), used by the simulator; absent:
    /// the simulator's defaults ([`crate::optics::OpticsConfig::default`]).
    #[serde(default)]
    pub optics: Option<crate::optics::OpticsConfig>,
}

/// UR controller generation: decides the maximum RTDE frequency.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Controller {
    /// e-Series (UR5e): RTDE up to 500 Hz.
    #[default]
    ESeries,
    /// CB3: RTDE up to 125 Hz.
    Cb3,
}

impl Controller {
    /// Highest RTDE output frequency the controller offers.
    pub fn max_rtde_frequency_hz(self) -> f64 {
        match self {
            Controller::ESeries => E_SERIES_MAX_RTDE_HZ,
            Controller::Cb3 => CB3_MAX_RTDE_HZ,
        }
    }
}

/// `[robot]`: the UR controller's address and interfaces.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotConfig {
    /// `true`: the robot is the built-in simulated UR5e (`hardware-mocks`), started in-process
    /// on loopback; `host` and the ports are then ignored (ephemeral ports are used). A lab rig
    /// sets `false` (the default).
    pub simulated: bool,
    /// Controller IP address or host name.
    pub host: String,
    /// RTDE port (UR: 30004).
    pub rtde_port: u16,
    /// Dashboard server port (UR: 29999).
    pub dashboard_port: u16,
    /// Secondary interface port that accepts URScript programs (UR: 30002).
    pub script_port: u16,
    /// RTDE output frequency; at most 500 Hz on e-Series, 125 Hz on CB3.
    pub rtde_frequency_hz: f64,
    /// Controller generation, `"e-series"` or `"cb3"`.
    pub controller: Controller,
    /// The controller-side watchdog stops motion when the rig writes its input registers less
    /// often than this (URScript `rtde_set_watchdog`).
    pub watchdog_min_hz: f64,
    /// TCP the control program sets (`set_tcp`): the indenter tip in the tool flange frame,
    /// `[x, y, z, rx, ry, rz]` in metres and radians. Absent: keep the TCP configured on the
    /// teach pendant.
    pub tcp_offset: Option<[f64; 6]>,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            simulated: false,
            host: "127.0.0.1".to_owned(),
            rtde_port: 30004,
            dashboard_port: 29999,
            script_port: 30002,
            rtde_frequency_hz: E_SERIES_MAX_RTDE_HZ,
            controller: Controller::ESeries,
            watchdog_min_hz: 10.0,
            tcp_offset: None,
        }
    }
}

/// Whether a sensor provides force labels (source) or only images (target).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorRole {
    /// Labelled domain: images and forces are recorded.
    Source,
    /// New sensor to calibrate: images are recorded (forces too, when a F/T sensor is fitted, for
    /// evaluation only).
    Target,
}

/// `[sensor]`: identity and pose of the tactile sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorConfig {
    /// Short, filename-safe identifier (`[A-Za-z0-9_.-]`), used in dataset names.
    pub id: String,
    /// `"source"` or `"target"`.
    pub role: SensorRole,
    /// Gel surface frame in the robot base frame, `[x, y, z, rx, ry, rz]` (metres, rotation vector
    /// in radians); +z is the gel's outward normal. See the module docs.
    #[serde(with = "pose_array")]
    pub surface_frame: Pose,
}

/// `[elastomer]`: the gel pad. Material values are assumptions, used by the simulator only.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ElastomerConfig {
    /// Gel extent along the surface frame's x (paper: 10 mm).
    pub size_x_mm: f64,
    /// Gel extent along the surface frame's y (paper: 8 mm).
    pub size_y_mm: f64,
    /// Gel thickness (paper: 3 mm); no plan may press deeper.
    pub thickness_mm: f64,
    /// Young's modulus. Assumed for XP-565 mixed A:B = 1:15 (a soft silicone, roughly 0.1-0.3 MPa);
    /// not measured.
    pub youngs_modulus_mpa: f64,
    /// Poisson's ratio; silicone is nearly incompressible (assumed 0.49).
    pub poisson_ratio: f64,
    /// Coulomb friction coefficient between indenter and gel (assumed 1.0; silicone on resin or
    /// metal is typically 0.5-1.5).
    pub friction_coefficient: f64,
}

impl Default for ElastomerConfig {
    fn default() -> Self {
        Self {
            size_x_mm: 10.0,
            size_y_mm: 8.0,
            thickness_mm: 3.0,
            youngs_modulus_mpa: 0.2,
            poisson_ratio: 0.49,
            friction_coefficient: 1.0,
        }
    }
}

/// Speed and acceleration of one linear move (UR `moveL` `v` and `a`, here in mm units).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageMotion {
    /// Cruise speed of the TCP, mm/s.
    pub speed_mm_s: f64,
    /// Acceleration and deceleration of the TCP, mm/s².
    pub accel_mm_s2: f64,
}

/// `[plan]`: the contact plan (paper: 5 points × 4 depths × 12 directions = 240 trajectories).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlanConfig {
    /// Contact points `[x, y]` in the surface frame, mm. Default: the centre, then `(±3, ±2)`.
    /// The paper's "moving distances Δx = 6 mm, Δy = 4 mm" are read as the span of the contact
    /// points over the 10 × 8 mm gel (x from −3 to +3, y from −2 to +2).
    pub contact_points_mm: Vec<[f64; 2]>,
    /// Press depths below the undeformed surface, mm (paper: 0.2 mm steps to 0.8 mm).
    pub depths_mm: Vec<f64>,
    /// Shear directions in the surface frame, degrees from +x towards +y, each in [0, 360)
    /// (paper: 12 directions, 30° apart).
    pub directions_deg: Vec<f64>,
    /// How far the indenter slides along the direction at depth, mm. The paper does not state it;
    /// 1 mm keeps every default point and direction on the gel and mostly in partial slip.
    pub shear_distance_mm: f64,
    /// Start and end height of every trajectory above the undeformed surface, mm.
    pub approach_height_mm: f64,
    /// Motion of the `down` stage (approach height to depth).
    pub down: StageMotion,
    /// Motion of the `shear` and `reverse` stages (at depth).
    pub shear: StageMotion,
    /// Motion of the `up` stage (depth back to approach height).
    pub up: StageMotion,
}

impl Default for PlanConfig {
    fn default() -> Self {
        Self {
            contact_points_mm: vec![
                [0.0, 0.0],
                [-3.0, -2.0],
                [3.0, -2.0],
                [-3.0, 2.0],
                [3.0, 2.0],
            ],
            depths_mm: vec![0.2, 0.4, 0.6, 0.8],
            directions_deg: (0..12).map(|i| f64::from(i) * 30.0).collect(),
            shear_distance_mm: 1.0,
            approach_height_mm: 2.0,
            down: StageMotion {
                speed_mm_s: 1.0,
                accel_mm_s2: 10.0,
            },
            shear: StageMotion {
                speed_mm_s: 1.0,
                accel_mm_s2: 10.0,
            },
            up: StageMotion {
                speed_mm_s: 5.0,
                accel_mm_s2: 50.0,
            },
        }
    }
}

/// Axis-aligned box in the robot base frame, metres. Every planned TCP position must lie in it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Envelope {
    pub min_x: f64,
    pub max_x: f64,
    pub min_y: f64,
    pub max_y: f64,
    pub min_z: f64,
    pub max_z: f64,
}

impl Envelope {
    /// The six limits as `(key, value, is_min, axis index)`; keys are relative to
    /// `safety.envelope`.
    pub fn limits(&self) -> [(&'static str, f64, bool, usize); 6] {
        [
            ("min_x", self.min_x, true, 0),
            ("max_x", self.max_x, false, 0),
            ("min_y", self.min_y, true, 1),
            ("max_y", self.max_y, false, 1),
            ("min_z", self.min_z, true, 2),
            ("max_z", self.max_z, false, 2),
        ]
    }

    /// Whether a base-frame position (metres) lies inside the box (boundary included).
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.limits().iter().all(
            |&(_, v, is_min, axis)| {
                if is_min { p[axis] >= v } else { p[axis] <= v }
            },
        )
    }
}

/// What `rig run` does when one trajectory fails (a protective stop, a lost device).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum OnFailure {
    /// Record the failure, recover, and go on with the next trajectory.
    Continue,
    /// Stop the run (the default: an operator looks first).
    #[default]
    Stop,
}

/// `[safety]`: limits checked before anything moves (and, for force, while moving).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SafetyConfig {
    /// Box the TCP must stay in. Required: there is no safe default for a real rig.
    pub envelope: Envelope,
    /// Deepest allowed press below the undeformed surface, mm; at most the elastomer thickness.
    #[serde(default = "default_max_depth_mm")]
    pub max_depth_mm: f64,
    /// Force magnitude that aborts a move, N (paper's work range: |Fz| ≤ 16 N).
    #[serde(default = "default_max_force_n")]
    pub max_force_n: f64,
    /// Highest TCP speed any stage may use, mm/s.
    #[serde(default = "default_max_speed_mm_s")]
    pub max_speed_mm_s: f64,
    /// `"stop"` (default) or `"continue"` after a failed trajectory.
    #[serde(default)]
    pub on_failure: OnFailure,
}

fn default_max_depth_mm() -> f64 {
    1.0
}
fn default_max_force_n() -> f64 {
    20.0
}
fn default_max_speed_mm_s() -> f64 {
    50.0
}

/// Force/torque front end kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ForceSensorKind {
    /// The simulated Nano17 of the built-in rig.
    Sim,
    /// ATI serial F/T controller (RS-232).
    Serial,
    /// ATI Net F/T box (UDP RDT).
    Netft,
    /// Raw gauge voltages from a DAQ, turned into forces with the calibration matrix.
    Daq,
}

/// `[force_sensor]`: the F/T sensor (a Nano17 in the paper). Later work extends this section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceSensorConfig {
    /// `"sim"`, `"serial"`, `"netft"` or `"daq"`.
    pub kind: ForceSensorKind,
    /// Serial device (`serial`) or DAQ device name (`daq`), e.g. `/dev/ttyUSB0`.
    #[serde(default)]
    pub port: Option<String>,
    /// Serial baud rate (`serial`).
    #[serde(default)]
    pub baud: Option<u32>,
    /// Net F/T address, `host` or `host:port` (`netft`).
    #[serde(default)]
    pub address: Option<String>,
    /// ATI calibration file (`.cal`), relative to the working directory.
    #[serde(default)]
    pub calibration_file: Option<PathBuf>,
    /// Requested sample rate, Hz.
    #[serde(default = "default_ft_rate_hz")]
    pub rate_hz: f64,
    /// Tool transform: the indenter tip's origin in the sensor frame, mm (see
    /// `rig_core::ft::transform`). Default: no displacement.
    #[serde(default)]
    pub tool_offset_mm: [f64; 3],
    /// Tool transform rotation, fixed-axis angles about x, y, z of the sensor frame, degrees.
    #[serde(default)]
    pub tool_rotation_deg: [f64; 3],
    /// Serial controller record format, `"binary"` (default) or `"ascii"`.
    #[serde(default)]
    pub output: crate::ft::serial::OutputMode,
    /// Counts per newton of the controller or Net F/T (its configuration page). Default: 1e6
    /// for `netft` (ATI's factory default), 320 for `serial`.
    #[serde(default)]
    pub counts_per_force: Option<f64>,
    /// Counts per N·mm. Default: 1000 for `netft` (1e6 per N·m), 64 for `serial`.
    #[serde(default)]
    pub counts_per_torque: Option<f64>,
    /// Max loads `[Fx, Fy, Fz, Tx, Ty, Tz]` (N, N·mm) when no calibration file gives them.
    /// Default: Nano17 SI-25-0.25 (25, 25, 35 N; 250 N·mm).
    #[serde(default)]
    pub max_loads: Option<[f64; 6]>,
    /// What to do with a saturated sample: `"flag"` (default: keep, flagged), `"drop"` or
    /// `"stop"` (end the stream with an error).
    #[serde(default)]
    pub saturation: SaturationPolicy,
    /// Samples averaged by a tare.
    #[serde(default = "default_tare_samples")]
    pub tare_samples: u32,
    /// DAQ only: apply the calibration file's temperature compensation when it has one.
    #[serde(default = "default_true")]
    pub temperature_compensation: bool,
}

/// What the F/T front end does with a saturated sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum SaturationPolicy {
    /// Keep the sample, flagged.
    #[default]
    Flag,
    /// Drop the sample (counted).
    Drop,
    /// End the stream with an error.
    Stop,
}

fn default_ft_rate_hz() -> f64 {
    1000.0
}
fn default_tare_samples() -> u32 {
    500
}
fn default_true() -> bool {
    true
}

/// Camera kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CameraKind {
    /// The simulated GelSight camera of the built-in rig.
    Sim,
    /// A UVC camera through Video4Linux2.
    V4l2,
}

/// `[camera]`: the tactile sensor's camera. Later work extends this section (optics, markers).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraConfig {
    /// `"sim"` or `"v4l2"`.
    pub kind: CameraKind,
    /// Capture device (`v4l2`), e.g. `/dev/video0`.
    #[serde(default)]
    pub device: Option<String>,
    /// Frame width, pixels.
    #[serde(default = "default_width_px")]
    pub width_px: u32,
    /// Frame height, pixels.
    #[serde(default = "default_height_px")]
    pub height_px: u32,
    /// Requested frame rate, Hz.
    #[serde(default = "default_fps")]
    pub fps: f64,
}

fn default_width_px() -> u32 {
    320
}
fn default_height_px() -> u32 {
    240
}
fn default_fps() -> f64 {
    25.0
}

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

/// Why a configuration could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read rig config {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Not valid TOML, an unknown key, a missing key or a value of the wrong type.
    #[error("{}", parse_message(.origin, .key, .line, .message))]
    Parse {
        /// File path or `<embedded ...>` / `<string>`.
        origin: String,
        /// Best-effort key path of the problem, when it could be located.
        key: Option<String>,
        /// 1-based line of the problem, when known.
        line: Option<usize>,
        /// The parser's own description.
        message: String,
    },
    /// Parsed, but one or more values are unusable.
    #[error("{}", invalid_message(.origin, .problems))]
    Invalid {
        origin: String,
        problems: Vec<Problem>,
    },
}

impl ConfigError {
    /// The key paths this error names (empty for I/O errors).
    pub fn keys(&self) -> Vec<String> {
        match self {
            ConfigError::Io { .. } => Vec::new(),
            ConfigError::Parse { key, .. } => key.iter().cloned().collect(),
            ConfigError::Invalid { problems, .. } => {
                problems.iter().map(|p| p.key.clone()).collect()
            }
        }
    }
}

fn parse_message(
    origin: &str,
    key: &Option<String>,
    line: &Option<usize>,
    message: &str,
) -> String {
    let message = message.trim();
    let at = match line {
        Some(l) => format!("{origin}, line {l}"),
        None => origin.to_owned(),
    };
    match key {
        Some(k) => format!("rig config {at}: {k}: {message}"),
        None => format!("rig config {at}: {message}"),
    }
}

fn invalid_message(origin: &str, problems: &[Problem]) -> String {
    match problems {
        [one] => format!("rig config {origin}: {one}"),
        many => {
            let mut s = format!("rig config {origin}: {} problems:", many.len());
            for p in many {
                s.push_str("\n  ");
                s.push_str(&p.to_string());
            }
            s
        }
    }
}

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

    /// Checks every value; returns all problems found, each naming its key path.
    ///
    /// Contract: a configuration that passes is safe to plan with — depths within
    /// `safety.max_depth_mm` and the elastomer thickness, contact points and their shear paths on
    /// the gel, speeds within `safety.max_speed_mm_s`, a non-empty envelope, an RTDE frequency the
    /// controller offers. Whether the envelope contains the plan's waypoints is checked when the
    /// plan is built (that needs the pose maths).
    pub fn validate(&self) -> Result<(), Vec<Problem>> {
        let mut v = Validator::default();
        self.validate_robot(&mut v);
        self.validate_sensor(&mut v);
        self.validate_elastomer(&mut v);
        self.validate_safety(&mut v);
        self.validate_plan(&mut v);
        self.validate_devices(&mut v);
        self.validate_optics(&mut v);
        if v.problems.is_empty() {
            Ok(())
        } else {
            Err(v.problems)
        }
    }

    fn validate_robot(&self, v: &mut Validator) {
        let r = &self.robot;
        if r.host.trim().is_empty() {
            v.push(
                "robot.host",
                "must not be empty (an IP address or host name)",
            );
        }
        for (key, port) in [
            ("robot.rtde_port", r.rtde_port),
            ("robot.dashboard_port", r.dashboard_port),
            ("robot.script_port", r.script_port),
        ] {
            if port == 0 {
                v.push(key, "port 0 is not a usable TCP port");
            }
        }
        let max_hz = r.controller.max_rtde_frequency_hz();
        if v.positive("robot.rtde_frequency_hz", r.rtde_frequency_hz)
            && r.rtde_frequency_hz > max_hz
        {
            let ctrl = match r.controller {
                Controller::ESeries => "e-series",
                Controller::Cb3 => "cb3",
            };
            v.push(
                "robot.rtde_frequency_hz",
                format!(
                    "{:?} Hz exceeds the {:?} Hz a {ctrl} controller offers (robot.controller = \"{ctrl}\")",
                    r.rtde_frequency_hz, max_hz
                ),
            );
        }
        if v.positive("robot.watchdog_min_hz", r.watchdog_min_hz)
            && r.watchdog_min_hz > r.rtde_frequency_hz
        {
            v.push(
                "robot.watchdog_min_hz",
                format!(
                    "{:?} Hz is above robot.rtde_frequency_hz = {:?} Hz; the watchdog would always fire",
                    r.watchdog_min_hz, r.rtde_frequency_hz
                ),
            );
        }
        if let Some(tcp) = &r.tcp_offset {
            for (i, x) in tcp.iter().enumerate() {
                v.finite(&format!("robot.tcp_offset[{i}]"), *x);
            }
        }
    }

    fn validate_sensor(&self, v: &mut Validator) {
        let s = &self.sensor;
        if s.id.is_empty() {
            v.push("sensor.id", "must not be empty");
        } else if !s
            .id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
        {
            v.push(
                "sensor.id",
                format!(
                    "{:?} may only contain letters, digits, '_', '-' and '.' (it names dataset files)",
                    s.id
                ),
            );
        }
        for (i, x) in s.surface_frame.to_array().iter().enumerate() {
            v.finite(&format!("sensor.surface_frame[{i}]"), *x);
        }
    }

    fn validate_elastomer(&self, v: &mut Validator) {
        let e = &self.elastomer;
        v.positive("elastomer.size_x_mm", e.size_x_mm);
        v.positive("elastomer.size_y_mm", e.size_y_mm);
        v.positive("elastomer.thickness_mm", e.thickness_mm);
        v.positive("elastomer.youngs_modulus_mpa", e.youngs_modulus_mpa);
        if !(e.poisson_ratio.is_finite() && (0.0..0.5).contains(&e.poisson_ratio)) {
            v.push(
                "elastomer.poisson_ratio",
                format!("{:?} must be in [0, 0.5)", e.poisson_ratio),
            );
        }
        if !(e.friction_coefficient.is_finite() && e.friction_coefficient >= 0.0) {
            v.push(
                "elastomer.friction_coefficient",
                format!("{:?} must be finite and ≥ 0", e.friction_coefficient),
            );
        }
    }

    fn validate_safety(&self, v: &mut Validator) {
        let s = &self.safety;
        let env = &s.envelope;
        let mut finite = true;
        for (key, value, _, _) in env.limits() {
            finite &= v.finite(&format!("safety.envelope.{key}"), value);
        }
        if finite {
            for (axis, lo, hi) in [
                ("x", env.min_x, env.max_x),
                ("y", env.min_y, env.max_y),
                ("z", env.min_z, env.max_z),
            ] {
                if lo >= hi {
                    v.push(
                        format!("safety.envelope.min_{axis}"),
                        format!(
                            "{lo:?} m is not below safety.envelope.max_{axis} = {hi:?} m (empty envelope)"
                        ),
                    );
                }
            }
        }
        if v.positive("safety.max_depth_mm", s.max_depth_mm)
            && self.elastomer.thickness_mm.is_finite()
            && s.max_depth_mm > self.elastomer.thickness_mm
        {
            v.push(
                "safety.max_depth_mm",
                format!(
                    "{:?} mm exceeds elastomer.thickness_mm = {:?} mm (the indenter would reach the sensor's window)",
                    s.max_depth_mm, self.elastomer.thickness_mm
                ),
            );
        }
        v.positive("safety.max_force_n", s.max_force_n);
        v.positive("safety.max_speed_mm_s", s.max_speed_mm_s);
    }

    fn validate_plan(&self, v: &mut Validator) {
        let p = &self.plan;
        let e = &self.elastomer;
        let s = &self.safety;

        if p.contact_points_mm.is_empty() {
            v.push("plan.contact_points_mm", "needs at least one [x, y] point");
        }
        if p.depths_mm.is_empty() {
            v.push("plan.depths_mm", "needs at least one depth");
        }
        if p.directions_deg.is_empty() {
            v.push("plan.directions_deg", "needs at least one direction");
        }
        let count = p
            .contact_points_mm
            .len()
            .saturating_mul(p.depths_mm.len())
            .saturating_mul(p.directions_deg.len());
        if count > MAX_TRAJECTORIES {
            v.push(
                "plan",
                format!(
                    "{count} trajectories (points × depths × directions) is more than the {MAX_TRAJECTORIES} a plan may hold"
                ),
            );
        }
        let shear_ok = v.positive("plan.shear_distance_mm", p.shear_distance_mm);
        v.positive("plan.approach_height_mm", p.approach_height_mm);

        // Depths: positive, within the safety limit and the gel, distinct (they name trajectories).
        for (i, &d) in p.depths_mm.iter().enumerate() {
            let key = format!("plan.depths_mm[{i}]");
            if !v.positive(&key, d) {
                continue;
            }
            if d > s.max_depth_mm {
                v.push(
                    &key,
                    format!(
                        "{d:?} mm exceeds safety.max_depth_mm = {:?} mm",
                        s.max_depth_mm
                    ),
                );
            } else if d > e.thickness_mm {
                v.push(
                    &key,
                    format!(
                        "{d:?} mm exceeds elastomer.thickness_mm = {:?} mm",
                        e.thickness_mm
                    ),
                );
            }
            if let Some(j) = p.depths_mm[..i]
                .iter()
                .position(|&o| format_depth_mm(o) == format_depth_mm(d))
            {
                v.push(&key, format!("{d:?} mm repeats plan.depths_mm[{j}]"));
            }
        }

        // Directions: in [0, 360), distinct.
        for (i, &a) in p.directions_deg.iter().enumerate() {
            let key = format!("plan.directions_deg[{i}]");
            if !(a.is_finite() && (0.0..360.0).contains(&a)) {
                v.push(&key, format!("{a:?}° must be in [0, 360)"));
                continue;
            }
            if let Some(j) = p.directions_deg[..i]
                .iter()
                .position(|&o| format_angle_deg(o) == format_angle_deg(a))
            {
                v.push(&key, format!("{a:?}° repeats plan.directions_deg[{j}]"));
            }
        }

        // Contact points and their shear paths must stay on the gel (the indenter axis never
        // leaves it, so the indenter does not press onto the sensor's frame).
        let half_x = e.size_x_mm / 2.0;
        let half_y = e.size_y_mm / 2.0;
        let reach = if shear_ok { p.shear_distance_mm } else { 0.0 };
        for (i, pt) in p.contact_points_mm.iter().enumerate() {
            let key = format!("plan.contact_points_mm[{i}]");
            if !(pt[0].is_finite() && pt[1].is_finite()) {
                v.push(&key, "coordinates must be finite numbers (mm)");
                continue;
            }
            if pt[0].abs() > half_x || pt[1].abs() > half_y {
                v.push(
                    &key,
                    format!(
                        "[{:?}, {:?}] mm lies off the gel (|x| ≤ elastomer.size_x_mm / 2 = {half_x:?} mm, |y| ≤ elastomer.size_y_mm / 2 = {half_y:?} mm)",
                        pt[0], pt[1]
                    ),
                );
                continue;
            }
            for &a in p.directions_deg.iter().filter(|a| a.is_finite()) {
                let (sin, cos) = a.to_radians().sin_cos();
                let end = [pt[0] + reach * cos, pt[1] + reach * sin];
                // A hair of tolerance so that exactly reaching the edge is accepted.
                if end[0].abs() > half_x + 1e-9 || end[1].abs() > half_y + 1e-9 {
                    v.push(
                        &key,
                        format!(
                            "shearing {reach:?} mm at {a:?}° from [{:?}, {:?}] mm ends at [{:.3}, {:.3}] mm, off the gel (|x| ≤ {half_x:?} mm, |y| ≤ {half_y:?} mm); reduce plan.shear_distance_mm or move the point",
                            pt[0], pt[1], end[0], end[1]
                        ),
                    );
                    break;
                }
            }
        }

        for (name, m) in [("down", &p.down), ("shear", &p.shear), ("up", &p.up)] {
            let key = format!("plan.{name}.speed_mm_s");
            if v.positive(&key, m.speed_mm_s) && m.speed_mm_s > s.max_speed_mm_s {
                v.push(
                    &key,
                    format!(
                        "{:?} mm/s exceeds safety.max_speed_mm_s = {:?} mm/s",
                        m.speed_mm_s, s.max_speed_mm_s
                    ),
                );
            }
            v.positive(&format!("plan.{name}.accel_mm_s2"), m.accel_mm_s2);
        }
    }

    fn validate_optics(&self, v: &mut Validator) {
        let Some(optics) = &self.optics else { return };
        v.problems.extend(optics.problems());
        // The simulated camera renders at the optics resolution: the two must agree.
        if let Some(cam) = &self.camera
            && cam.kind == CameraKind::Sim
        {
            for (key, o, c) in [
                ("width_px", optics.width_px, cam.width_px),
                ("height_px", optics.height_px, cam.height_px),
            ] {
                if o != c {
                    v.push(
                        format!("optics.{key}"),
                        format!(
                            "{o} differs from camera.{key} = {c}; the simulated camera renders \
                             at the optics resolution, so set both to the same value"
                        ),
                    );
                }
            }
        }
    }

    fn validate_devices(&self, v: &mut Validator) {
        if let Some(ft) = &self.force_sensor {
            let missing = |field: &str| -> bool {
                match field {
                    "port" => ft.port.as_deref().is_none_or(|s| s.trim().is_empty()),
                    "address" => ft.address.as_deref().is_none_or(|s| s.trim().is_empty()),
                    _ => false,
                }
            };
            match ft.kind {
                ForceSensorKind::Serial | ForceSensorKind::Daq if missing("port") => v.push(
                    "force_sensor.port",
                    "required when force_sensor.kind is \"serial\" or \"daq\" (e.g. \"/dev/ttyUSB0\")",
                ),
                ForceSensorKind::Netft if missing("address") => v.push(
                    "force_sensor.address",
                    "required when force_sensor.kind is \"netft\" (e.g. \"192.168.1.1\")",
                ),
                _ => {}
            }
            if ft.baud == Some(0) {
                v.push("force_sensor.baud", "must be positive");
            }
            v.positive("force_sensor.rate_hz", ft.rate_hz);
            for (key, val) in [
                ("force_sensor.counts_per_force", ft.counts_per_force),
                ("force_sensor.counts_per_torque", ft.counts_per_torque),
            ] {
                if let Some(x) = val {
                    v.positive(key, x);
                }
            }
            if let Some(m) = ft.max_loads {
                for (i, x) in m.iter().enumerate() {
                    v.positive(&format!("force_sensor.max_loads[{i}]"), *x);
                }
            }
            if ft.tare_samples < 2 {
                v.push("force_sensor.tare_samples", "must be at least 2");
            }
            let r = ft.tool_rotation_deg.map(f64::to_radians);
            if let Err(e) = crate::ft::transform::ToolTransform::from_angles(ft.tool_offset_mm, r) {
                v.push("force_sensor.tool_offset_mm", e.to_string());
            }
        }
        if let Some(cam) = &self.camera {
            if cam.kind == CameraKind::V4l2
                && cam.device.as_deref().is_none_or(|s| s.trim().is_empty())
            {
                v.push(
                    "camera.device",
                    "required when camera.kind is \"v4l2\" (e.g. \"/dev/video0\")",
                );
            }
            if cam.width_px == 0 {
                v.push("camera.width_px", "must be positive");
            }
            if cam.height_px == 0 {
                v.push("camera.height_px", "must be positive");
            }
            v.positive("camera.fps", cam.fps);
        }
    }
}

/// Depth as it appears in trajectory ids: shortest decimal form with at least one decimal, up to
/// micrometre precision (`0.2`, `0.25`, `1.0`).
pub fn format_depth_mm(depth_mm: f64) -> String {
    let mut s = format!("{depth_mm:.3}");
    while s.ends_with('0') && !s.ends_with(".0") {
        s.pop();
    }
    s
}

/// Angle as it appears in trajectory ids: three integer digits (`030`), with decimals only when
/// needed (`022.5`).
pub fn format_angle_deg(angle_deg: f64) -> String {
    let rounded = (angle_deg * 1000.0).round() / 1000.0;
    if rounded.fract() == 0.0 {
        format!("{:03}", rounded as i64)
    } else {
        let mut s = format!("{rounded:07.3}");
        while s.ends_with('0') {
            s.pop();
        }
        s
    }
}

#[derive(Default)]
struct Validator {
    problems: Vec<Problem>,
}

impl Validator {
    fn push(&mut self, key: impl Into<String>, reason: impl Into<String>) {
        self.problems.push(Problem {
            key: key.into(),
            reason: reason.into(),
        });
    }

    /// Records a problem unless `x` is finite; returns whether it is.
    fn finite(&mut self, key: &str, x: f64) -> bool {
        if x.is_finite() {
            true
        } else {
            self.push(key, format!("{x:?} is not a finite number"));
            false
        }
    }

    /// Records a problem unless `x` is finite and > 0; returns whether it is.
    fn positive(&mut self, key: &str, x: f64) -> bool {
        if x.is_finite() && x > 0.0 {
            true
        } else {
            self.push(key, format!("{x:?} must be a finite number > 0"));
            false
        }
    }
}

/// Serde adapter: a [`Pose`] as the UR-style array `[x, y, z, rx, ry, rz]`.
mod pose_array {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    use crate::pose::Pose;

    pub fn serialize<S: Serializer>(pose: &Pose, s: S) -> Result<S::Ok, S::Error> {
        pose.to_array().serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Pose, D::Error> {
        <[f64; 6]>::deserialize(d).map(Pose::from_array)
    }
}

/// Best-effort key path and line of a parse error spanning `span` of `text`.
///
/// The TOML parser reports a byte span and a message but not the key path; this walks the text
/// up to the span: the last `[table]` header gives the table, an inline table on the error line
/// (`down = { ... }`) adds its key, and either the field named in the message (unknown or missing
/// field) or the key of the line holding the span gives the last part.
fn locate(
    text: &str,
    span: std::ops::Range<usize>,
    message: &str,
) -> (Option<String>, Option<usize>) {
    let offset = span.start.min(text.len());
    if !text.is_char_boundary(offset) {
        return (field_in_message(message), None);
    }
    let before = &text[..offset];
    let line_no = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[offset..].find('\n').map_or(text.len(), |i| offset + i);
    let error_line = &text[line_start..line_end];
    let error_is_header = strip_comment(error_line).trim().starts_with('[');

    let mut table = String::new();
    let mut last_key: Option<String> = None;
    for line in text[..line_start]
        .lines()
        .chain(std::iter::once(error_line))
    {
        let t = strip_comment(line).trim();
        if let Some(h) = t.strip_prefix('[') {
            let h = h.trim_start_matches('[');
            if let Some(end) = h.find(']') {
                table = h[..end].trim().to_owned();
                last_key = None;
                continue;
            }
        }
        if let Some(eq) = t.find('=') {
            let k = t[..eq].trim();
            if !k.is_empty() && !k.starts_with('"') && !k.starts_with('[') {
                last_key = Some(k.to_owned());
            }
        }
    }
    // An inline table opened on the error line before the span: `down = { ... }`.
    let prefix = &text[line_start..offset];
    let inline_key = prefix.find('=').and_then(|eq| {
        let rest = text[line_start + eq + 1..].trim_start();
        let key = prefix[..eq].trim();
        (rest.starts_with('{') && !key.is_empty() && !error_is_header).then(|| key.to_owned())
    });

    let join = |a: &str, b: &str| {
        if a.is_empty() {
            b.to_owned()
        } else {
            format!("{a}.{b}")
        }
    };
    let key = if message.contains("unknown field") || message.contains("missing field") {
        let field = field_in_message(message);
        let missing = message.contains("missing field");
        let owner = if missing && span.start == 0 && (span.end == 0 || span.end >= text.len()) {
            // A missing top-level table is reported at the document itself.
            String::new()
        } else if !missing && error_is_header {
            // An unknown table is reported at its own header: its owner is the header's parent.
            table
                .rsplit_once('.')
                .map_or(String::new(), |(parent, _)| parent.to_owned())
        } else {
            match &inline_key {
                Some(k) => join(&table, k),
                None => table.clone(),
            }
        };
        field.map(|f| join(&owner, &f))
    } else {
        last_key
            .map(|k| join(&table, &k))
            .or((!table.is_empty()).then_some(table))
    };
    (key, Some(line_no))
}

fn strip_comment(line: &str) -> &str {
    // Good enough for locating keys: a '#' inside a string value only shortens the value part.
    line.find('#').map_or(line, |i| &line[..i])
}

/// The first `` `name` `` in a serde message ("unknown field `foo`, expected ...").
fn field_in_message(message: &str) -> Option<String> {
    let start = message.find('`')? + 1;
    let len = message[start..].find('`')?;
    Some(message[start..start + len].to_owned())
}
