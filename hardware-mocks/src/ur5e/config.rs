//! [`Ur5eConfig`]: how a simulated controller is set up (listeners, home pose, version, modes,
//! cycle rate).

use std::net::SocketAddr;
use std::time::Duration;

use rig_core::control;
use rig_core::pose::Pose;

/// How the simulated controller is set up.
#[derive(Debug, Clone)]
pub struct Ur5eConfig {
    /// RTDE listener (30004 on a real controller); port 0 picks a free one.
    pub rtde_addr: SocketAddr,
    /// Dashboard listener (29999 on a real controller).
    pub dashboard_addr: SocketAddr,
    /// Secondary interface listener for scripts (30002 on a real controller).
    pub script_addr: SocketAddr,
    /// TCP pose at start (with no TCP offset: the flange pose).
    pub home_pose: Pose,
    /// The physical tool: flange → indenter tip (`pose_trans(flange, tool_offset)` is the tip,
    /// what the contact physics presses with). Identity: the tip is at the flange. A program
    /// reports and steers this tip only if it sets the same TCP with `set_tcp`.
    pub tool_offset: Pose,
    /// Reported by the `v` request: (major, minor, bugfix, build). Major ≥ 5 is an e-Series.
    pub controller_version: (u32, u32, u32, u32),
    /// robot_mode at start ([`control::robot_mode`]).
    pub initial_robot_mode: i32,
    /// Controller cycle rate and the highest output frequency accepted: 500 Hz e-Series,
    /// 125 Hz CB3.
    pub max_frequency_hz: f64,
    /// Clock time after a protective stop before `unlock protective stop` is accepted.
    pub protective_stop_unlock_delay: Duration,
}

impl Default for Ur5eConfig {
    fn default() -> Self {
        let local: SocketAddr = ([127, 0, 0, 1], 0).into();
        Self {
            rtde_addr: local,
            dashboard_addr: local,
            script_addr: local,
            // A tool pointing down above the table, as the rig's plans start.
            home_pose: Pose::new(0.3, -0.2, 0.3, 0.0, std::f64::consts::PI, 0.0),
            tool_offset: Pose::default(),
            controller_version: (5, 15, 0, 0),
            initial_robot_mode: control::robot_mode::POWER_OFF,
            max_frequency_hz: 500.0,
            protective_stop_unlock_delay: Duration::from_secs(5),
        }
    }
}
