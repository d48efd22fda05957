//! The rig configuration's TOML sections as serde types: `[robot]`, `[sensor]`, `[elastomer]`,
//! `[plan]`, `[safety]`, `[force_sensor]`, `[camera]` (and `[optics]`, from
//! [`crate::optics`]). Unknown keys are rejected; defaults and units are documented per field.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::pose::Pose;

/// Maximum RTDE output frequency of an e-Series controller (RTDE guide: 500 Hz).
pub const E_SERIES_MAX_RTDE_HZ: f64 = 500.0;
/// Maximum RTDE output frequency of a CB3 controller (RTDE guide: 125 Hz).
pub const CB3_MAX_RTDE_HZ: f64 = 125.0;

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
    /// Young's (relaxed) modulus. No value is published for XP-565 mixed A:B = 1:15; 0.275 MPa is
    /// calibrated so that the finite-layer physics gives the paper's work range over the default
    /// plan (2 mm slides): |Fz| up to 16 N, shear up to 5 N (`rig sim forces`; sim-source.toml).
    pub youngs_modulus_mpa: f64,
    /// Poisson's ratio; silicone is nearly incompressible (assumed 0.49).
    pub poisson_ratio: f64,
    /// Coulomb friction coefficient between indenter and gel (assumed 1.0; silicone on resin or
    /// metal is typically 0.5-1.5).
    pub friction_coefficient: f64,
    /// Instantaneous over relaxed Young's modulus of the gel's viscoelastic relaxation (a
    /// standard linear solid; `youngs_modulus_mpa` is the relaxed modulus). At least 1; 1 turns
    /// relaxation off, so the force is a function of the contact state alone. Assumed 1.25: soft
    /// silicones relax by some tens of percent under a held indentation.
    pub instant_modulus_ratio: f64,
    /// Relaxation time of that solid, s (> 0). Assumed 1.5 s, the order of a held press's
    /// visible force decay on silicone gels.
    pub relaxation_time_s: f64,
}

impl Default for ElastomerConfig {
    fn default() -> Self {
        Self {
            size_x_mm: 10.0,
            size_y_mm: 8.0,
            thickness_mm: 3.0,
            youngs_modulus_mpa: 0.275,
            poisson_ratio: 0.49,
            friction_coefficient: 1.0,
            instant_modulus_ratio: 1.25,
            relaxation_time_s: 1.5,
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
    /// 2 mm is the longest slide that keeps every default point and direction on the gel, and
    /// brings the shear forces to the paper's range (small contacts reach gross slip).
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
            shear_distance_mm: 2.0,
            approach_height_mm: 2.0,
            down: StageMotion {
                speed_mm_s: 1.0,
                accel_mm_s2: 10.0,
            },
            shear: StageMotion {
                speed_mm_s: 2.0,
                accel_mm_s2: 20.0,
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
    /// Raw gauge voltages from a home-built DAQ front end in the project's serial framing
    /// (`crate::ft::daq`), turned into forces with the calibration matrix.
    Daq,
    /// ATI's DAQ F/T system: the gauge voltages on an NI data-acquisition card read through
    /// NI-DAQmx (loaded at run time), turned into forces with the calibration matrix.
    Nidaqmx,
}

/// `[force_sensor]`: the F/T sensor (a Nano17 in the paper). Later work extends this section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceSensorConfig {
    /// `"sim"`, `"serial"`, `"netft"`, `"nidaqmx"` or `"daq"`.
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
    /// for `netft` and `sim` (ATI's factory default,
    /// [`crate::ft::netft::FACTORY_COUNTS_PER_FORCE`]), 320 for `serial`
    /// ([`crate::ft::serial::DEFAULT_COUNTS_PER_FORCE`]).
    #[serde(default)]
    pub counts_per_force: Option<f64>,
    /// Counts per N·mm. Default: 1000 for `netft` and `sim` (1e6 per N·m), 64 for `serial`.
    #[serde(default)]
    pub counts_per_torque: Option<f64>,
    /// Max loads `[Fx, Fy, Fz, Tx, Ty, Tz]` (N, N·mm) when no calibration file gives them.
    /// Default: Nano17 SI-25-0.25 (25, 25, 35 N; 250 N·mm; [`crate::ft::NANO17_SI_25_MAX`]).
    #[serde(default)]
    pub max_loads: Option<[f64; 6]>,
    /// What to do with a saturated sample: `"flag"` (default: keep, flagged), `"drop"` or
    /// `"stop"` (end the stream with an error).
    #[serde(default)]
    pub saturation: SaturationPolicy,
    /// Samples averaged by a tare.
    #[serde(default = "default_tare_samples")]
    pub tare_samples: u32,
    /// DAQ and NI only: apply the calibration file's temperature compensation when it has one
    /// (NI: the thermistor is then read as a seventh channel).
    #[serde(default = "default_true")]
    pub temperature_compensation: bool,
    /// `nidaqmx`: the six gauge channels in NI's physical-channel syntax, in gauge order G0..G5.
    /// Default [`crate::ft::nidaqmx::DEFAULT_CHANNELS`], `"Dev1/ai0:5"`.
    #[serde(default)]
    pub channels: Option<String>,
    /// `nidaqmx`: the thermistor's channel, read when the calibration file has temperature
    /// compensation. Default: the input after the last gauge (`"Dev1/ai6"`).
    #[serde(default)]
    pub thermistor_channel: Option<String>,
    /// `nidaqmx`: the inputs' terminal configuration, `"differential"` (default, ATI's wiring),
    /// `"rse"`, `"nrse"` or `"default"` (the card's).
    #[serde(default)]
    pub terminal_config: crate::ft::nidaqmx::TerminalConfig,
    /// `nidaqmx`: the NI-DAQmx library to load (`libnidaqmx.so`). Default: the environment
    /// variable `RIG_NIDAQMX_LIBRARY`, else the system's library search (`libnidaqmx.so.1`,
    /// then `libnidaqmx.so`).
    #[serde(default)]
    pub library: Option<PathBuf>,
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
    crate::ft::DEFAULT_RATE_HZ
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
    /// What the camera sends: `"mjpeg"` (each frame one JPEG, as a GelSight Mini's UVC stream;
    /// recorded byte for byte) or `"raw"` (pixels, recorded as lossless PNG). A V4L2 camera
    /// is asked for this format first and falls back to the other.
    #[serde(default)]
    pub format: CameraFormat,
    /// JPEG quality (1–100) of the simulated camera's MJPEG frames. A real camera's MJPEG
    /// quality is set by its firmware, so `v4l2` cameras ignore it.
    #[serde(default = "default_jpeg_quality")]
    pub jpeg_quality: u8,
}

/// `[camera] format`: what each frame's bytes are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CameraFormat {
    /// Motion-JPEG: one JPEG image per frame (what UVC tactile cameras stream).
    #[default]
    Mjpeg,
    /// Uncompressed pixels (RGB or YUYV), stored as lossless PNG.
    Raw,
}

/// The simulated camera's default JPEG quality (IJG scale). No figure for a GelSight Mini's
/// firmware encoder is published, so it is chosen by measurement (`docs/experiments.md`,
/// "MJPEG frames"): on pressed 320 × 240 frames of the shipped sensors, 90 gives 18–27 kB a
/// frame (PNG: 100–116 kB) at an RMS error of 2.5–3.5 levels, against markers and shading
/// that differ from the gel by tens of levels; 95 would cost 1.5× the bytes.
pub fn default_jpeg_quality() -> u8 {
    90
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
