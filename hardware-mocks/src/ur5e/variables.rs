//! Where each RTDE variable of the simulated controller comes from (outputs) and goes to
//! (inputs).
//!
//! Names and types come from [`rig_core::rtde::fields`]; this module maps every name the table
//! knows onto the controller model. Outputs the model does not simulate are served as zeros or
//! as plausible constants (48 V supply, speed scaling 1.0, 30 °C joints), so a third-party client
//! that asks for "everything" gets a valid recipe.

use rig_core::control::{robot_mode, runtime_state, safety_mode};
use rig_core::rtde::{Value, fields};

use super::snapshot::ControllerSnapshot;

/// The source of one output-recipe field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OutputSource {
    Timestamp,
    ActualTcpPose,
    TargetTcpPose,
    ActualTcpSpeed,
    TargetTcpSpeed,
    ActualTcpForce,
    RobotMode,
    SafetyMode,
    SafetyStatus,
    RuntimeState,
    RobotStatusBits,
    SafetyStatusBits,
    JointMode,
    InputInt(usize),
    InputDouble(usize),
    InputBit(u32),
    InputBitWord(u32),
    OutputInt(usize),
    OutputDouble(usize),
    OutputBit(u32),
    OutputBitWord(u32),
    /// A variable the model does not simulate.
    Const(Value),
}

/// The destination of one input-recipe field.
#[derive(Debug, Clone, PartialEq)]
pub enum InputSink {
    Int(usize),
    Double(usize),
    Bit(u32),
    /// `input_bit_registers0_to_31` (word 0) or `..32_to_63` (word 1).
    BitWord(u32),
    /// A fixed-name input the model stores but does not act on (speed slider, digital outputs).
    Other(String),
}

fn register_index(name: &str, prefix: &str) -> Option<u32> {
    name.strip_prefix(prefix)?.parse().ok()
}

/// The source of an output variable, `None` for a name the controller does not have.
pub fn resolve_output(name: &str) -> Option<OutputSource> {
    use OutputSource::*;
    let ty = fields::output_type(name)?;
    // Numbered registers, by name prefix.
    type Numbered = fn(u32) -> OutputSource;
    let registers: [(&str, Numbered); 6] = [
        ("input_int_register_", |n| InputInt(n as usize)),
        ("input_double_register_", |n| InputDouble(n as usize)),
        ("input_bit_register_", InputBit),
        ("output_int_register_", |n| OutputInt(n as usize)),
        ("output_double_register_", |n| OutputDouble(n as usize)),
        ("output_bit_register_", OutputBit),
    ];
    if let Some(source) = registers
        .iter()
        .find_map(|(prefix, source)| register_index(name, prefix).map(source))
    {
        return Some(source);
    }
    Some(match name {
        "timestamp" => Timestamp,
        "actual_TCP_pose" => ActualTcpPose,
        "target_TCP_pose" => TargetTcpPose,
        "actual_TCP_speed" => ActualTcpSpeed,
        "target_TCP_speed" => TargetTcpSpeed,
        "actual_TCP_force" => ActualTcpForce,
        "robot_mode" => RobotMode,
        "safety_mode" => SafetyMode,
        "safety_status" => SafetyStatus,
        "runtime_state" => RuntimeState,
        "robot_status_bits" => RobotStatusBits,
        "safety_status_bits" => SafetyStatusBits,
        "joint_mode" => JointMode,
        "input_bit_registers0_to_31" => InputBitWord(0),
        "input_bit_registers32_to_63" => InputBitWord(1),
        "output_bit_registers0_to_31" => OutputBitWord(0),
        "output_bit_registers32_to_63" => OutputBitWord(1),
        "speed_scaling" | "target_speed_fraction" => Const(Value::Double(1.0)),
        "actual_main_voltage" | "actual_robot_voltage" => Const(Value::Double(48.0)),
        "actual_joint_voltage" => Const(Value::Vector6d([48.0; 6])),
        "joint_temperatures" => Const(Value::Vector6d([30.0; 6])),
        "tool_temperature" => Const(Value::Double(30.0)),
        // The real controller cycle is 2 ms on e-Series; the model takes well under that.
        "actual_execution_time" => Const(Value::Double(0.05)),
        "actual_tool_accelerometer" => Const(Value::Vector3d([0.0, 0.0, 9.81])),
        _ => Const(Value::zero(ty)),
    })
}

/// The destination of an input variable, `None` for a name the controller does not accept.
pub fn resolve_input(name: &str) -> Option<InputSink> {
    fields::input_type(name)?;
    let reg = |prefix| register_index(name, prefix);
    Some(if let Some(n) = reg("input_int_register_") {
        InputSink::Int(n as usize)
    } else if let Some(n) = reg("input_double_register_") {
        InputSink::Double(n as usize)
    } else if let Some(n) = reg("input_bit_register_") {
        InputSink::Bit(n)
    } else if name == "input_bit_registers0_to_31" {
        InputSink::BitWord(0)
    } else if name == "input_bit_registers32_to_63" {
        InputSink::BitWord(1)
    } else {
        InputSink::Other(name.to_owned())
    })
}

fn bit(bits: u128, n: u32) -> bool {
    n < 128 && (bits >> n) & 1 == 1
}

fn word(bits: u128, w: u32) -> u32 {
    (bits >> (32 * w)) as u32
}

/// robot_status_bits (RTDE guide): bit 0 power on, bit 1 program running, bit 2 teach button
/// pressed, bit 3 power button pressed.
fn robot_status_bits(s: &ControllerSnapshot) -> u32 {
    let powered = matches!(
        s.robot_mode,
        robot_mode::POWER_ON | robot_mode::IDLE | robot_mode::BACKDRIVE | robot_mode::RUNNING
    );
    (powered as u32) | (((s.runtime_state == runtime_state::PLAYING) as u32) << 1)
}

/// safety_status_bits (RTDE guide): bit 0 normal, 1 reduced, 2 protective stopped, 3 recovery,
/// 4 safeguard stopped, 5 system emergency stopped, 6 robot emergency stopped, 7 emergency
/// stopped, 8 violation, 9 fault, 10 stopped due to safety.
fn safety_status_bits(mode: i32) -> u32 {
    use safety_mode::*;
    match mode {
        NORMAL => 1,
        REDUCED => 1 << 1,
        PROTECTIVE_STOP => (1 << 2) | (1 << 10),
        RECOVERY => 1 << 3,
        SAFEGUARD_STOP => (1 << 4) | (1 << 10),
        SYSTEM_EMERGENCY_STOP => (1 << 5) | (1 << 7) | (1 << 10),
        ROBOT_EMERGENCY_STOP => (1 << 6) | (1 << 7) | (1 << 10),
        VIOLATION => (1 << 8) | (1 << 10),
        FAULT => (1 << 9) | (1 << 10),
        _ => 0,
    }
}

impl ControllerSnapshot {
    /// The value of an output field in this snapshot.
    pub fn value(&self, src: &OutputSource) -> Value {
        use OutputSource::*;
        let idx = |a: &[f64; 48], n: usize| a.get(n).copied().unwrap_or(0.0);
        let idx_i = |a: &[i32; 48], n: usize| a.get(n).copied().unwrap_or(0);
        match *src {
            Timestamp => Value::Double(self.timestamp_s),
            ActualTcpPose => Value::Vector6d(self.actual_tcp_pose.to_array()),
            TargetTcpPose => Value::Vector6d(self.target_tcp_pose.to_array()),
            ActualTcpSpeed | TargetTcpSpeed => Value::Vector6d(self.actual_tcp_speed),
            ActualTcpForce => Value::Vector6d(self.actual_tcp_force),
            RobotMode => Value::Int32(self.robot_mode),
            SafetyMode | SafetyStatus => Value::Int32(self.safety_mode),
            RuntimeState => Value::Uint32(self.runtime_state),
            RobotStatusBits => Value::Uint32(robot_status_bits(self)),
            SafetyStatusBits => Value::Uint32(safety_status_bits(self.safety_mode)),
            // JOINT_RUNNING_MODE (253) when the arm runs, JOINT_POWER_OFF_MODE (239) otherwise.
            JointMode => Value::Vector6Int32(
                [if self.robot_mode == robot_mode::RUNNING {
                    253
                } else {
                    239
                }; 6],
            ),
            InputInt(n) => Value::Int32(idx_i(&self.input_int_registers, n)),
            InputDouble(n) => Value::Double(idx(&self.input_double_registers, n)),
            InputBit(n) => Value::Bool(bit(self.input_bit_registers, n)),
            InputBitWord(w) => Value::Uint32(word(self.input_bit_registers, w)),
            OutputInt(n) => Value::Int32(idx_i(&self.output_int_registers, n)),
            OutputDouble(n) => Value::Double(idx(&self.output_double_registers, n)),
            OutputBit(n) => Value::Bool(bit(self.output_bit_registers, n)),
            OutputBitWord(w) => Value::Uint32(word(self.output_bit_registers, w)),
            Const(v) => v,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_fixed_output_resolves_to_a_value_of_its_declared_type() {
        let snap = ControllerSnapshot::default();
        for (name, ty) in fields::fixed_outputs() {
            let src = resolve_output(name).unwrap_or_else(|| panic!("{name} unresolved"));
            assert_eq!(snap.value(&src).data_type(), ty, "{name}");
        }
        for name in [
            "input_int_register_30",
            "output_double_register_47",
            "input_bit_register_64",
            "output_bit_register_127",
        ] {
            let src = resolve_output(name).unwrap();
            assert_eq!(
                Some(snap.value(&src).data_type()),
                fields::output_type(name),
                "{name}"
            );
        }
        assert_eq!(resolve_output("no_such_thing"), None);
        assert_eq!(resolve_input("output_int_register_24"), None);
        assert_eq!(
            resolve_input("input_int_register_24"),
            Some(InputSink::Int(24))
        );
    }
}
