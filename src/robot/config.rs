//! Where the robot is and how patient the rig is with it.
//!
//! Every limit is a [`Duration`] of clock time (the rig's shared
//! [`Clock`](rig_core::clock::Clock)), so a simulated run times out on simulated time and a
//! stalled host does not fail a move that the simulation has not finished yet.

use std::net::SocketAddr;
use std::time::Duration;

use rig_core::control;

use super::motion::SequencerConfig;

/// Where the controller's three interfaces are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RobotEndpoints {
    /// RTDE, TCP 30004 on a real controller.
    pub rtde: SocketAddr,
    /// Dashboard server, TCP 29999.
    pub dashboard: SocketAddr,
    /// Secondary interface (URScript upload), TCP 30002.
    pub script: SocketAddr,
}

impl RobotEndpoints {
    /// The standard ports of a controller at `ip`.
    pub fn standard(ip: std::net::IpAddr) -> Self {
        Self {
            rtde: SocketAddr::new(ip, rig_core::rtde::RTDE_PORT),
            dashboard: SocketAddr::new(ip, 29999),
            script: SocketAddr::new(ip, 30002),
        }
    }
}

/// What to do when the RTDE link drops during a move (see the `robot` module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LinkLossPolicy {
    /// Resume the move after reconnecting if the robot is stationary and safe; else abort.
    #[default]
    ContinueIfSafe,
    /// Always end the move with [`MotionError::LinkLost`](super::MotionError::LinkLost).
    Abort,
}

/// Settings of `Robot`. All durations are clock time.
#[derive(Debug, Clone)]
pub struct RobotOptions {
    /// RTDE output frequency; `None`: 500 Hz on e-Series, 125 Hz on CB3.
    pub frequency_hz: Option<f64>,
    /// Minimum heartbeat rate the controller's watchdog accepts.
    pub watchdog_min_hz: f64,
    /// How long the control program may take to acknowledge a command.
    pub ack_timeout: Duration,
    /// Added to a move's predicted duration (× `move_timeout_factor`) before it times out.
    pub move_timeout_margin: Duration,
    pub move_timeout_factor: f64,
    pub link_loss: LinkLossPolicy,
    /// How long a lost RTDE link may take to come back during a move.
    pub reconnect_timeout: Duration,
    /// Power on and brake release, each.
    pub power_timeout: Duration,
    /// Program upload until PLAYING; safety recovery after unlock.
    pub program_start_timeout: Duration,
    /// One dashboard command.
    pub dashboard_timeout: Duration,
    /// Deceleration of `Robot::stop` and of the safety supervisor's stop, m/s².
    pub stop_accel_m_s2: f64,
    /// The tool centre point the control program sets (`set_tcp`): flange → indenter tip,
    /// `[x, y, z, rx, ry, rz]` in metres and radians (`robot.tcp_offset`). `None` leaves the
    /// controller's TCP as the teach pendant's installation has it.
    pub tcp_offset: Option<[f64; 6]>,
    /// RTDE link: connection attempts, first backoff, longest backoff, stall timeout.
    pub rtde_max_attempts: u32,
    pub rtde_backoff_initial: Duration,
    pub rtde_backoff_max: Duration,
    pub rtde_stall_timeout: Duration,
}

impl Default for RobotOptions {
    fn default() -> Self {
        let seq = SequencerConfig::default();
        Self {
            frequency_hz: None,
            watchdog_min_hz: control::WATCHDOG_MIN_HZ,
            ack_timeout: seq.ack_timeout,
            move_timeout_margin: seq.move_timeout_margin,
            move_timeout_factor: seq.move_timeout_factor,
            link_loss: LinkLossPolicy::default(),
            reconnect_timeout: Duration::from_secs(10),
            power_timeout: Duration::from_secs(30),
            program_start_timeout: Duration::from_secs(5),
            dashboard_timeout: Duration::from_secs(2),
            stop_accel_m_s2: 0.5,
            tcp_offset: None,
            rtde_max_attempts: 20,
            rtde_backoff_initial: Duration::from_millis(100),
            rtde_backoff_max: Duration::from_secs(2),
            rtde_stall_timeout: Duration::from_secs(1),
        }
    }
}
