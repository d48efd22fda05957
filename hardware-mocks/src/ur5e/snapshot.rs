//! [`ControllerSnapshot`]: the controller's state at one tick, what the RTDE server streams
//! and what the variable table reads fields from.

use rig_core::control;
use rig_core::pose::Pose;

/// The controller's state at one tick, as the RTDE stream reports it.
#[derive(Debug, Clone, PartialEq)]
pub struct ControllerSnapshot {
    /// Clock time of the tick, ns.
    pub t_ns: u64,
    /// RTDE `timestamp`: seconds since the controller started, on the clock.
    pub timestamp_s: f64,
    pub actual_tcp_pose: Pose,
    pub target_tcp_pose: Pose,
    /// `[vx, vy, vz, wx, wy, wz]`, m/s and rad/s in the base frame.
    pub actual_tcp_speed: [f64; 6],
    /// RTDE `actual_TCP_force`: the external wrench on the tool measured by the flange sensor,
    /// base frame, N and N·m about the TCP (zero without a [`super::FlangeSensor`]).
    pub actual_tcp_force: [f64; 6],
    pub robot_mode: i32,
    pub safety_mode: i32,
    pub runtime_state: u32,
    /// Whether a script the mock can run has been uploaded.
    pub program_loaded: bool,
    pub input_int_registers: [i32; 48],
    pub input_double_registers: [f64; 48],
    /// Bit n is input bit register n (0..128).
    pub input_bit_registers: u128,
    pub output_int_registers: [i32; 48],
    pub output_double_registers: [f64; 48],
    pub output_bit_registers: u128,
    /// Data packages sent on all RTDE connections since start.
    pub data_packages_sent: u64,
}

impl Default for ControllerSnapshot {
    fn default() -> Self {
        Self {
            t_ns: 0,
            timestamp_s: 0.0,
            actual_tcp_pose: Pose::default(),
            target_tcp_pose: Pose::default(),
            actual_tcp_speed: [0.0; 6],
            actual_tcp_force: [0.0; 6],
            robot_mode: control::robot_mode::POWER_OFF,
            safety_mode: control::safety_mode::NORMAL,
            runtime_state: control::runtime_state::STOPPED,
            program_loaded: false,
            input_int_registers: [0; 48],
            input_double_registers: [0.0; 48],
            input_bit_registers: 0,
            output_int_registers: [0; 48],
            output_double_registers: [0.0; 48],
            output_bit_registers: 0,
            data_packages_sent: 0,
        }
    }
}
