//! What a trajectory asks of the robot, and what came back.
//!
//! Plain data with no I/O, so the run and record code can build moves and keep the reports and
//! logged states without holding the robot.

use rig_core::pose::Pose;

use super::state::RobotState;

/// One moveL of a trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Move {
    /// Names the trajectory and stage, e.g. `p0-d0.2-a030/shear`; errors quote it.
    pub label: String,
    pub pose: Pose,
    pub speed_m_s: f64,
    pub accel_m_s2: f64,
}

/// How one move went.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveReport {
    pub label: String,
    /// The sequence number that completed (a re-issued move has a later one).
    pub seq: i32,
    pub target: Pose,
    pub issued_ns: u64,
    pub done_ns: u64,
    /// The first state that reported the move done.
    pub final_state: RobotState,
    /// |final position − target|, m.
    pub position_error_m: f64,
    /// Rotation distance between final and target orientation, rad.
    pub rotation_error_rad: f64,
    /// How often the move was re-issued after a link loss.
    pub reissued: u32,
}

/// One received state, tagged with the move it was received during.
#[derive(Debug, Clone, PartialEq)]
pub struct LoggedState {
    pub label: String,
    pub state: RobotState,
}

/// Everything received during `Robot::run_moves`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MovesLog {
    pub samples: Vec<LoggedState>,
    pub reports: Vec<MoveReport>,
    /// Samples the log missed because it fell behind the stream (should be 0).
    pub missed_samples: u64,
}
