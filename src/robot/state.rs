//! Typed robot state: one RTDE output data package turned into named, unit-carrying fields.
//!
//! The RTDE client asks the controller for a fixed output recipe ([`output_recipe`]) and the
//! controller answers with the type of each field. [`StateDecoder`] is built once per
//! connection from the names and the types the controller actually assigned, and then reads
//! every data package straight into a [`RobotState`] without looking names up again.
//!
//! Field meanings and units follow UR's "Real-Time Data Exchange (RTDE) Guide" (e-Series 5.x):
//! poses are `p[x, y, z, rx, ry, rz]` in metres and radians (axis × angle), TCP speed is
//! `[vx, vy, vz, ωx, ωy, ωz]` in m/s and rad/s, TCP force in N and N·m, `timestamp` is the
//! controller's uptime in seconds.

use rig_core::control::{self, ProgramStatus};
use rig_core::pose::Pose;
use rig_core::rtde::{DataType, DecodeError, Value, decode_values};

/// The rig's output recipe, in the order the decoder expects nothing of (any order works; the
/// decoder maps by name). Registers 24..=26 carry the control program's ack/done/status
/// ([`rig_core::control`]); `input_int_register_24` is read back so that, after a restart, the
/// rig knows which command sequence number the controller last saw.
pub fn output_recipe() -> Vec<String> {
    let mut names: Vec<String> = [
        "timestamp",
        "actual_TCP_pose",
        "target_TCP_pose",
        "actual_TCP_speed",
        "actual_TCP_force",
        "robot_mode",
        "safety_mode",
        "safety_status_bits",
        "runtime_state",
        "robot_status_bits",
        "speed_scaling",
    ]
    .into_iter()
    .map(str::to_owned)
    .collect();
    for n in [
        control::OUT_ACK_SEQ,
        control::OUT_DONE_SEQ,
        control::OUT_STATUS,
    ] {
        names.push(control::output_int(n));
    }
    names.push(control::input_int(control::IN_CMD_SEQ));
    names
}

/// Linear TCP speed below which the robot counts as standing still, m/s.
pub const STATIONARY_SPEED_M_S: f64 = 1e-4;

/// One sample of the controller's state, as the rig uses it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RobotState {
    /// Host clock time (`Clock::now_ns`) when the package was decoded.
    pub t_host_ns: u64,
    /// Controller time (`timestamp`), seconds since the controller booted.
    pub timestamp_s: f64,
    pub actual_tcp_pose: Pose,
    pub target_tcp_pose: Pose,
    /// `[vx, vy, vz, ωx, ωy, ωz]`, m/s and rad/s.
    pub actual_tcp_speed: [f64; 6],
    /// `[Fx, Fy, Fz, Tx, Ty, Tz]`, N and N·m.
    pub actual_tcp_force: [f64; 6],
    /// `rig_core::control::robot_mode` values.
    pub robot_mode: i32,
    /// `rig_core::control::safety_mode` values.
    pub safety_mode: i32,
    pub safety_status_bits: u32,
    /// `rig_core::control::runtime_state` values.
    pub runtime_state: u32,
    pub robot_status_bits: u32,
    /// Speed scaling in [0, 1] (speed slider × trajectory limits).
    pub speed_scaling: f64,
    /// `output_int_register_24..=26`: ack seq, done seq, program status.
    pub output_int_registers: [i32; 3],
    /// `input_int_register_24` as the controller sees it: the last command seq it received.
    pub input_cmd_seq: i32,
}

impl RobotState {
    /// Last command sequence number the control program has read.
    pub fn ack_seq(&self) -> i32 {
        self.output_int_registers[0]
    }
    /// Last command sequence number the control program has finished.
    pub fn done_seq(&self) -> i32 {
        self.output_int_registers[1]
    }
    /// What the control program says it is doing (`None` for a value it never writes).
    pub fn program_status(&self) -> Option<ProgramStatus> {
        ProgramStatus::from_i32(self.output_int_registers[2])
    }
    /// Robot RUNNING, safety NORMAL or REDUCED, program PLAYING.
    pub fn motion_allowed(&self) -> bool {
        control::motion_allowed(self.robot_mode, self.safety_mode, self.runtime_state)
    }
    /// Safety NORMAL or REDUCED.
    pub fn safety_ok(&self) -> bool {
        matches!(
            self.safety_mode,
            control::safety_mode::NORMAL | control::safety_mode::REDUCED
        )
    }
    /// Norm of the linear TCP speed, m/s.
    pub fn linear_speed_m_s(&self) -> f64 {
        let v = &self.actual_tcp_speed;
        (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
    }
    /// Whether the TCP stands still (below [`STATIONARY_SPEED_M_S`]).
    pub fn is_stationary(&self) -> bool {
        self.linear_speed_m_s() < STATIONARY_SPEED_M_S
    }
    /// The modes in words, for error messages.
    pub fn modes_description(&self) -> String {
        format!(
            "robot_mode {} ({}), safety_mode {} ({}), runtime_state {} ({})",
            self.robot_mode,
            robot_mode_name(self.robot_mode),
            self.safety_mode,
            safety_mode_name(self.safety_mode),
            self.runtime_state,
            runtime_state_name(self.runtime_state)
        )
    }
}

/// UR's names of the mode values (`RUNNING`, `PROTECTIVE_STOP`, `PLAYING`; `UNKNOWN` for a
/// value UR does not define), from [`rig_core::control`], which the simulated controller uses
/// too.
pub use rig_core::control::{robot_mode_name, runtime_state_name, safety_mode_name};

#[derive(Debug, Clone, Copy, PartialEq)]
enum Slot {
    Timestamp,
    ActualPose,
    TargetPose,
    ActualSpeed,
    ActualForce,
    RobotMode,
    SafetyMode,
    SafetyStatusBits,
    RuntimeState,
    RobotStatusBits,
    SpeedScaling,
    OutInt(usize),
    InCmdSeq,
    Ignore,
}

impl Slot {
    fn of(name: &str) -> Self {
        match name {
            "timestamp" => Self::Timestamp,
            "actual_TCP_pose" => Self::ActualPose,
            "target_TCP_pose" => Self::TargetPose,
            "actual_TCP_speed" => Self::ActualSpeed,
            "actual_TCP_force" => Self::ActualForce,
            "robot_mode" => Self::RobotMode,
            "safety_mode" => Self::SafetyMode,
            "safety_status_bits" => Self::SafetyStatusBits,
            "runtime_state" => Self::RuntimeState,
            "robot_status_bits" => Self::RobotStatusBits,
            "speed_scaling" => Self::SpeedScaling,
            other => {
                if other == control::input_int(control::IN_CMD_SEQ) {
                    return Self::InCmdSeq;
                }
                for (i, n) in [
                    control::OUT_ACK_SEQ,
                    control::OUT_DONE_SEQ,
                    control::OUT_STATUS,
                ]
                .into_iter()
                .enumerate()
                {
                    if other == control::output_int(n) {
                        return Self::OutInt(i);
                    }
                }
                Self::Ignore
            }
        }
    }
}

/// Reads data packages of one output recipe into [`RobotState`]s.
#[derive(Debug, Clone)]
pub struct StateDecoder {
    types: Vec<DataType>,
    slots: Vec<Slot>,
}

impl StateDecoder {
    /// A decoder for a recipe of `names` that the controller typed as `types`.
    /// Names the rig does not know are decoded and ignored. Lengths must match.
    pub fn new(names: &[String], types: &[DataType]) -> Result<Self, String> {
        if names.len() != types.len() {
            return Err(format!(
                "output recipe has {} names but the controller returned {} types",
                names.len(),
                types.len()
            ));
        }
        Ok(Self {
            types: types.to_vec(),
            slots: names.iter().map(|n| Slot::of(n)).collect(),
        })
    }

    /// The field types, in recipe order.
    pub fn types(&self) -> &[DataType] {
        &self.types
    }

    /// Decode one data package payload (after the recipe id). A value of an unexpected type
    /// leaves its field at the default rather than failing the package.
    pub fn decode(&self, payload: &[u8], t_host_ns: u64) -> Result<RobotState, DecodeError> {
        let values = decode_values(&self.types, payload)?;
        let mut s = RobotState {
            t_host_ns,
            ..RobotState::default()
        };
        for (slot, v) in self.slots.iter().zip(values.iter()) {
            let f = || v.as_f64().unwrap_or(f64::NAN);
            let i = || v.as_i64().unwrap_or(-1);
            let vec6 = || match v {
                Value::Vector6d(a) => *a,
                _ => [f64::NAN; 6],
            };
            match slot {
                Slot::Timestamp => s.timestamp_s = f(),
                Slot::ActualPose => s.actual_tcp_pose = Pose::from_array(vec6()),
                Slot::TargetPose => s.target_tcp_pose = Pose::from_array(vec6()),
                Slot::ActualSpeed => s.actual_tcp_speed = vec6(),
                Slot::ActualForce => s.actual_tcp_force = vec6(),
                Slot::RobotMode => s.robot_mode = i() as i32,
                Slot::SafetyMode => s.safety_mode = i() as i32,
                Slot::SafetyStatusBits => s.safety_status_bits = i() as u32,
                Slot::RuntimeState => s.runtime_state = i() as u32,
                Slot::RobotStatusBits => s.robot_status_bits = i() as u32,
                Slot::SpeedScaling => s.speed_scaling = f(),
                Slot::OutInt(k) => s.output_int_registers[*k] = i() as i32,
                Slot::InCmdSeq => s.input_cmd_seq = i() as i32,
                Slot::Ignore => {}
            }
        }
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytes::BytesMut;
    use rig_core::rtde::{encode_values, fields};

    #[test]
    fn recipe_names_are_all_controller_outputs() {
        for n in output_recipe() {
            assert!(fields::output_type(&n).is_some(), "{n}");
        }
    }

    #[test]
    fn decodes_every_slot_by_name() {
        let names = output_recipe();
        let types: Vec<_> = names
            .iter()
            .map(|n| fields::output_type(n).unwrap())
            .collect();
        let values: Vec<Value> = names
            .iter()
            .zip(&types)
            .map(|(n, t)| match n.as_str() {
                "timestamp" => Value::Double(12.5),
                "actual_TCP_pose" => Value::Vector6d([0.4, 0.0, 0.2, 3.0, 0.0, 0.0]),
                "robot_mode" => Value::Int32(7),
                "safety_mode" => Value::Int32(1),
                "runtime_state" => Value::Uint32(2),
                "output_int_register_25" => Value::Int32(41),
                "input_int_register_24" => Value::Int32(42),
                _ => Value::zero(*t),
            })
            .collect();
        let mut buf = BytesMut::new();
        encode_values(&values, &mut buf);
        let d = StateDecoder::new(&names, &types).unwrap();
        let s = d.decode(&buf, 99).unwrap();
        assert_eq!(s.t_host_ns, 99);
        assert_eq!(s.timestamp_s, 12.5);
        assert_eq!(s.actual_tcp_pose.x, 0.4);
        assert_eq!(s.done_seq(), 41);
        assert_eq!(s.input_cmd_seq, 42);
        assert!(s.motion_allowed());
        assert!(d.decode(&buf[..buf.len() - 1], 0).is_err());
    }
}
