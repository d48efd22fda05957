//! The controller's RTDE variables and their types, as listed in UR's RTDE guide for
//! e-Series software 5.x (CB3 3.x has a subset).
//!
//! The simulated controller answers a setup request from this table (`NOT_FOUND` for any other
//! name), and the client checks its own recipes against it before sending them.

use super::codec::DataType;
use DataType::*;

/// Fixed-name controller outputs (readable with an output recipe).
const OUTPUTS: &[(&str, DataType)] = &[
    ("timestamp", Double),
    ("target_q", Vector6d),
    ("target_qd", Vector6d),
    ("target_qdd", Vector6d),
    ("target_current", Vector6d),
    ("target_moment", Vector6d),
    ("actual_q", Vector6d),
    ("actual_qd", Vector6d),
    ("actual_current", Vector6d),
    ("actual_current_window", Vector6d),
    ("joint_control_output", Vector6d),
    ("actual_TCP_pose", Vector6d),
    ("actual_TCP_speed", Vector6d),
    ("actual_TCP_force", Vector6d),
    ("target_TCP_pose", Vector6d),
    ("target_TCP_speed", Vector6d),
    ("actual_digital_input_bits", Uint64),
    ("joint_temperatures", Vector6d),
    ("actual_execution_time", Double),
    ("robot_mode", Int32),
    ("joint_mode", Vector6Int32),
    ("safety_mode", Int32),
    ("safety_status", Int32),
    ("actual_tool_accelerometer", Vector3d),
    ("speed_scaling", Double),
    ("target_speed_fraction", Double),
    ("actual_momentum", Double),
    ("actual_main_voltage", Double),
    ("actual_robot_voltage", Double),
    ("actual_robot_current", Double),
    ("actual_joint_voltage", Vector6d),
    ("actual_digital_output_bits", Uint64),
    ("runtime_state", Uint32),
    ("elbow_position", Vector3d),
    ("elbow_velocity", Vector3d),
    ("robot_status_bits", Uint32),
    ("safety_status_bits", Uint32),
    ("analog_io_types", Uint32),
    ("standard_analog_input0", Double),
    ("standard_analog_input1", Double),
    ("standard_analog_output0", Double),
    ("standard_analog_output1", Double),
    ("io_current", Double),
    ("euromap67_input_bits", Uint32),
    ("euromap67_output_bits", Uint32),
    ("euromap67_24V_voltage", Double),
    ("euromap67_24V_current", Double),
    ("tool_mode", Uint32),
    ("tool_analog_input_types", Uint32),
    ("tool_analog_input0", Double),
    ("tool_analog_input1", Double),
    ("tool_output_voltage", Int32),
    ("tool_output_current", Double),
    ("tool_temperature", Double),
    ("tcp_force_scalar", Double),
    ("output_bit_registers0_to_31", Uint32),
    ("output_bit_registers32_to_63", Uint32),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("tool_output_mode", Uint8),
    ("tool_digital_output0_mode", Uint8),
    ("tool_digital_output1_mode", Uint8),
    ("payload", Double),
    ("payload_cog", Vector3d),
    ("payload_inertia", Vector6d),
    ("script_control_line", Uint32),
    ("ft_raw_wrench", Vector6d),
    ("joint_position_deviation_ratio", Vector6d),
    ("collision_detection_ratio", Double),
    ("time_scale_source", Uint32),
    ("actual_current_as_torque", Vector6d),
];

/// Fixed-name controller inputs (writable with an input recipe).
const INPUTS: &[(&str, DataType)] = &[
    ("speed_slider_mask", Uint32),
    ("speed_slider_fraction", Double),
    ("standard_digital_output_mask", Uint8),
    ("standard_digital_output", Uint8),
    ("configurable_digital_output_mask", Uint8),
    ("configurable_digital_output", Uint8),
    ("tool_digital_output_mask", Uint8),
    ("tool_digital_output", Uint8),
    ("standard_analog_output_mask", Uint8),
    ("standard_analog_output_type", Uint8),
    ("standard_analog_output_0", Double),
    ("standard_analog_output_1", Double),
    ("input_bit_registers0_to_31", Uint32),
    ("input_bit_registers32_to_63", Uint32),
    ("external_force_torque", Vector6d),
];

/// General-purpose registers: `{input,output}_{int,double}_register_N` for N in 0..48 and
/// `{input,output}_bit_register_N` for N in 64..128. Registers 0..23 are used by fieldbuses
/// (EtherNet/IP, PROFINET, MODBUS) on real controllers; 24..47 are free for RTDE clients.
fn register(name: &str, prefix: &str) -> Option<DataType> {
    let rest = name.strip_prefix(prefix)?;
    let (kind, n) = rest.rsplit_once("_register_")?;
    let n: u32 = n.parse().ok()?;
    if n.to_string() != rest.rsplit_once('_')?.1 {
        return None; // reject "07" and the like
    }
    match kind {
        "int" if n < 48 => Some(Int32),
        "double" if n < 48 => Some(Double),
        "bit" if (64..128).contains(&n) => Some(Bool),
        _ => None,
    }
}

/// Type of a controller output variable, `None` when the controller has no such output.
pub fn output_type(name: &str) -> Option<DataType> {
    listed(OUTPUTS, name)
        .or_else(|| register(name, "output_"))
        .or_else(|| register(name, "input_"))
}

/// Type of a controller input variable, `None` when the controller has no such input.
pub fn input_type(name: &str) -> Option<DataType> {
    listed(INPUTS, name).or_else(|| register(name, "input_"))
}

/// The type `table` gives `name`, if it lists it.
fn listed(table: &[(&str, DataType)], name: &str) -> Option<DataType> {
    table.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// Every fixed-name output, for listings and tests.
pub fn fixed_outputs() -> impl Iterator<Item = (&'static str, DataType)> {
    OUTPUTS.iter().copied()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registers_follow_the_guide_ranges() {
        assert_eq!(input_type("input_int_register_24"), Some(Int32));
        assert_eq!(input_type("input_double_register_47"), Some(Double));
        assert_eq!(input_type("input_double_register_48"), None);
        assert_eq!(input_type("input_bit_register_64"), Some(Bool));
        assert_eq!(input_type("input_bit_register_63"), None);
        assert_eq!(input_type("input_int_register_024"), None);
        assert_eq!(input_type("output_int_register_24"), None);
        assert_eq!(output_type("output_int_register_24"), Some(Int32));
        // Input registers can be read back through an output recipe.
        assert_eq!(output_type("input_double_register_30"), Some(Double));
        assert_eq!(output_type("actual_TCP_pose"), Some(Vector6d));
        assert_eq!(
            output_type("actual_tcp_pose"),
            None,
            "names are case-sensitive"
        );
    }
}
