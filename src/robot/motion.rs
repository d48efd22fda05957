//! The motion sequencer: commands through registers, completion and faults from the stream.
//!
//! [`MotionSequencer`] is sans-IO in the quinn-proto sense: it is told what the controller
//! reported ([`MotionSequencer::on_state`]) and what time it is (`now_ns`, from the shared
//! clock), and it answers with the register writes to make ([`CommandWrite`]) and what happened
//! ([`SeqEvent`]). The async `Robot` facade only moves bytes and waits. So every timing case
//! (no ack, a move that never finishes, a protective stop between ack and done) is a unit test
//! with made-up states.
//!
//! The register contract is [`rig_core::control`]: a command is the seq, kind, target pose,
//! speed and acceleration, written as one RTDE input package (one recipe) so the program never
//! sees half a command; the program acks the seq when it reads it and writes it to the done
//! register when the move ends.
//!
//! Safety: before a move the sequencer refuses unless the state allows motion (robot RUNNING,
//! safety NORMAL or REDUCED, program PLAYING: RTDE guide and `control::motion_allowed`); on
//! every state during a command it checks the same and turns any departure into a fault that
//! names the move's label. After a fault it refuses every move until [`clear_fault`] is called,
//! which the facade does only after a successful recovery.
//!
//! [`clear_fault`]: MotionSequencer::clear_fault

use std::fmt;
use std::time::Duration;

use rig_core::control::{self, CommandKind, ProgramStatus};
use rig_core::pose::Pose;
use rig_core::rtde::Value;

use super::state::{RobotState, robot_mode_name, runtime_state_name, safety_mode_name};

/// The input recipes of the register contract (see [`control::command_recipe`] and
/// [`control::safety_recipe`]; the safety recipe is written through [`super::SafetyLine`]).
pub use control::{command_recipe, safety_recipe};

/// One command to write into the input registers.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommandWrite {
    pub seq: i32,
    pub kind: CommandKind,
    pub target: Pose,
    pub speed_m_s: f64,
    pub accel_m_s2: f64,
}

impl CommandWrite {
    /// Values in [`command_recipe`] order.
    pub fn values(&self) -> Vec<Value> {
        let mut v = vec![Value::Int32(self.seq), Value::Int32(self.kind as i32)];
        v.extend(self.target.to_array().map(Value::Double));
        v.push(Value::Double(self.speed_m_s));
        v.push(Value::Double(self.accel_m_s2));
        v
    }
}

/// Why a command stopped short.
#[derive(Debug, Clone, PartialEq)]
pub enum Fault {
    /// Safety left NORMAL/REDUCED (protective stop, safeguard stop, violation, fault…).
    ProtectiveStop { safety_mode: i32 },
    /// A system or robot emergency stop.
    EmergencyStop { safety_mode: i32 },
    /// The control program is no longer PLAYING.
    ProgramStopped { runtime_state: u32 },
    /// The robot left RUNNING (power off, brakes engaged…).
    RobotNotRunning { robot_mode: i32 },
    /// The program refused the command (bad kind, speed or acceleration).
    Rejected,
    /// The program did not acknowledge the command in time.
    AckTimeout { after: Duration },
    /// The move took much longer than its trapezoidal profile predicts.
    MoveTimeout { after: Duration },
}

impl Fault {
    /// The controller's name for the mode or state that caused the fault (`PROTECTIVE_STOP`,
    /// `STOPPED`, …); `None` for faults of the command itself.
    pub fn mode_name(&self) -> Option<&'static str> {
        match *self {
            Self::ProtectiveStop { safety_mode } | Self::EmergencyStop { safety_mode } => {
                Some(safety_mode_name(safety_mode))
            }
            Self::ProgramStopped { runtime_state } => Some(runtime_state_name(runtime_state)),
            Self::RobotNotRunning { robot_mode } => Some(robot_mode_name(robot_mode)),
            Self::Rejected | Self::AckTimeout { .. } | Self::MoveTimeout { .. } => None,
        }
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = self.mode_name().unwrap_or_default();
        match self {
            Self::ProtectiveStop { safety_mode } => {
                write!(f, "safety stop (safety_mode {safety_mode} {name})")
            }
            Self::EmergencyStop { safety_mode } => {
                write!(f, "emergency stop (safety_mode {safety_mode} {name})")
            }
            Self::ProgramStopped { runtime_state } => {
                write!(
                    f,
                    "control program stopped (runtime_state {runtime_state} {name})"
                )
            }
            Self::RobotNotRunning { robot_mode } => {
                write!(f, "robot left RUNNING (robot_mode {robot_mode} {name})")
            }
            Self::Rejected => write!(f, "control program rejected the command"),
            Self::AckTimeout { after } => write!(f, "no acknowledgement after {after:?}"),
            Self::MoveTimeout { after } => write!(f, "move not finished after {after:?}"),
        }
    }
}

/// The fault of a command and the move it interrupted.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultRecord {
    pub label: String,
    pub seq: i32,
    pub fault: Fault,
    /// The state that showed the fault (for timeouts, the last state seen, if any).
    pub state: Option<RobotState>,
}

/// What the sequencer saw.
#[derive(Debug, Clone, PartialEq)]
pub enum SeqEvent {
    Acked {
        seq: i32,
    },
    /// A move reached its target (or a stop finished).
    Done {
        seq: i32,
        label: String,
        issued_ns: u64,
        done_ns: u64,
        state: RobotState,
    },
    Fault(FaultRecord),
}

/// Why a command was not issued.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Refusal {
    #[error("motion is blocked since {0}: recover the robot first")]
    Faulted(Box<FaultRecordDisplay>),
    #[error("robot not ready for motion: {0}")]
    NotAllowed(String),
    #[error("another command (seq {0}) is still in progress")]
    Busy(i32),
    #[error("bad move: {0}")]
    BadArgs(String),
}

/// Display wrapper of a [`FaultRecord`].
#[derive(Debug, Clone, PartialEq)]
pub struct FaultRecordDisplay(pub FaultRecord);

impl fmt::Display for FaultRecordDisplay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} during move `{}`", self.0.fault, self.0.label)
    }
}

/// Timing of the sequencer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SequencerConfig {
    /// How long the program may take to acknowledge a command.
    pub ack_timeout: Duration,
    /// Added to a move's predicted duration (× `move_timeout_factor`) before it times out.
    pub move_timeout_margin: Duration,
    pub move_timeout_factor: f64,
}

impl Default for SequencerConfig {
    fn default() -> Self {
        Self {
            ack_timeout: Duration::from_millis(500),
            move_timeout_margin: Duration::from_secs(2),
            move_timeout_factor: 1.5,
        }
    }
}

#[derive(Debug, Clone)]
struct Active {
    seq: i32,
    label: String,
    cmd: CommandWrite,
    issued_ns: u64,
    acked: bool,
    ack_deadline_ns: u64,
    done_deadline_ns: u64,
}

/// Predicted duration of a moveL over `distance_m` with a trapezoidal speed profile.
pub fn predicted_duration_s(distance_m: f64, speed_m_s: f64, accel_m_s2: f64) -> f64 {
    if distance_m <= 0.0 {
        return 0.0;
    }
    if distance_m < speed_m_s * speed_m_s / accel_m_s2 {
        2.0 * (distance_m / accel_m_s2).sqrt()
    } else {
        distance_m / speed_m_s + speed_m_s / accel_m_s2
    }
}

/// See the module docs.
#[derive(Debug)]
pub struct MotionSequencer {
    cfg: SequencerConfig,
    last_seq: i32,
    active: Option<Active>,
    fault: Option<FaultRecord>,
    last_state: Option<RobotState>,
}

fn ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

impl MotionSequencer {
    pub fn new(cfg: SequencerConfig) -> Self {
        Self {
            cfg,
            last_seq: 0,
            active: None,
            fault: None,
            last_state: None,
        }
    }

    /// The last seq issued (or synced from the controller).
    pub fn last_seq(&self) -> i32 {
        self.last_seq
    }

    /// Adopt the controller's current command seq (read back from `input_int_register_24`)
    /// so the next command is new to a program that starts from it. Ignored while busy.
    pub fn sync_seq(&mut self, controller_seq: i32) {
        if self.active.is_none() {
            self.last_seq = self.last_seq.max(controller_seq);
        }
    }

    pub fn fault(&self) -> Option<&FaultRecord> {
        self.fault.as_ref()
    }

    /// Allow motion again (call only after the robot was recovered).
    pub fn clear_fault(&mut self) {
        self.fault = None;
    }

    pub fn is_busy(&self) -> bool {
        self.active.is_some()
    }

    /// The label and seq of the command in progress.
    pub fn active(&self) -> Option<(&str, i32)> {
        self.active.as_ref().map(|a| (a.label.as_str(), a.seq))
    }

    /// Forget the command in progress (the caller gave up on it, e.g. the link was lost).
    pub fn abandon(&mut self) {
        self.active = None;
    }

    fn check_ready(&self, state: &RobotState) -> Result<(), Refusal> {
        if let Some(f) = &self.fault {
            return Err(Refusal::Faulted(Box::new(FaultRecordDisplay(f.clone()))));
        }
        if let Some(a) = &self.active {
            return Err(Refusal::Busy(a.seq));
        }
        if !state.motion_allowed() {
            return Err(Refusal::NotAllowed(state.modes_description()));
        }
        Ok(())
    }

    fn issue(&mut self, label: String, mut cmd: CommandWrite, now_ns: u64) -> CommandWrite {
        self.last_seq = self.last_seq.wrapping_add(1);
        cmd.seq = self.last_seq;
        let distance_m = self
            .last_state
            .map(|s| rig_core::pose::translation_distance(&s.actual_tcp_pose, &cmd.target))
            .unwrap_or(0.0);
        let predicted_s = match cmd.kind {
            CommandKind::MoveL => predicted_duration_s(distance_m, cmd.speed_m_s, cmd.accel_m_s2),
            _ => 0.0,
        };
        let ack_ns = ns(self.cfg.ack_timeout);
        let budget_ns = (predicted_s * self.cfg.move_timeout_factor * 1e9) as u64
            + ns(self.cfg.move_timeout_margin)
            + ack_ns;
        self.active = Some(Active {
            seq: cmd.seq,
            label,
            cmd,
            issued_ns: now_ns,
            acked: false,
            ack_deadline_ns: now_ns.saturating_add(ack_ns),
            done_deadline_ns: now_ns.saturating_add(budget_ns),
        });
        cmd
    }

    /// Issue a moveL, if the state allows motion and nothing is in progress.
    pub fn start_move(
        &mut self,
        label: &str,
        target: Pose,
        speed_m_s: f64,
        accel_m_s2: f64,
        state: &RobotState,
        now_ns: u64,
    ) -> Result<CommandWrite, Refusal> {
        if !target.to_array().iter().all(|v| v.is_finite()) {
            return Err(Refusal::BadArgs(format!(
                "target pose of `{label}` is not finite"
            )));
        }
        if !(speed_m_s.is_finite() && speed_m_s > 0.0 && accel_m_s2.is_finite() && accel_m_s2 > 0.0)
        {
            return Err(Refusal::BadArgs(format!(
                "`{label}`: speed {speed_m_s} m/s and acceleration {accel_m_s2} m/s² must be finite and positive"
            )));
        }
        if !state
            .actual_tcp_pose
            .to_array()
            .iter()
            .all(|v| v.is_finite())
        {
            return Err(Refusal::BadArgs(format!(
                "`{label}`: the controller reports a non-finite TCP pose {:?}; no motion until \
                 it reports a real one (check the robot's calibration and the RTDE link)",
                state.actual_tcp_pose.to_array()
            )));
        }
        self.last_state = Some(*state);
        self.check_ready(state)?;
        Ok(self.issue(
            label.to_owned(),
            CommandWrite {
                seq: 0,
                kind: CommandKind::MoveL,
                target,
                speed_m_s,
                accel_m_s2,
            },
            now_ns,
        ))
    }

    /// Issue the command in progress again with a new seq (after the program was restarted).
    pub fn reissue(&mut self, state: &RobotState, now_ns: u64) -> Result<CommandWrite, Refusal> {
        let Some(a) = self.active.take() else {
            return Err(Refusal::BadArgs(
                "no command in progress to re-issue".into(),
            ));
        };
        self.last_state = Some(*state);
        if let Err(e) = self.check_ready(state) {
            self.active = Some(a);
            return Err(e);
        }
        Ok(self.issue(a.label, a.cmd, now_ns))
    }

    /// Abandon any move and issue a Stop (decelerate with `accel_m_s2`). Allowed while
    /// faulted: stopping is always safe.
    pub fn stop(&mut self, accel_m_s2: f64, now_ns: u64) -> CommandWrite {
        let target = self
            .last_state
            .map(|s| s.actual_tcp_pose)
            .unwrap_or_default();
        self.active = None;
        self.issue(
            "stop".into(),
            CommandWrite {
                seq: 0,
                kind: CommandKind::Stop,
                target,
                speed_m_s: 0.0,
                accel_m_s2,
            },
            now_ns,
        )
    }

    fn classify(s: &RobotState) -> Option<Fault> {
        use control::safety_mode::*;
        if !s.safety_ok() {
            return Some(match s.safety_mode {
                SYSTEM_EMERGENCY_STOP | ROBOT_EMERGENCY_STOP => Fault::EmergencyStop {
                    safety_mode: s.safety_mode,
                },
                m => Fault::ProtectiveStop { safety_mode: m },
            });
        }
        if s.robot_mode != control::robot_mode::RUNNING {
            return Some(Fault::RobotNotRunning {
                robot_mode: s.robot_mode,
            });
        }
        if s.runtime_state != control::runtime_state::PLAYING {
            return Some(Fault::ProgramStopped {
                runtime_state: s.runtime_state,
            });
        }
        None
    }

    fn raise(&mut self, a: Active, fault: Fault, state: Option<RobotState>) -> SeqEvent {
        let rec = FaultRecord {
            label: a.label,
            seq: a.seq,
            fault,
            state,
        };
        self.fault = Some(rec.clone());
        SeqEvent::Fault(rec)
    }

    /// Feed one state. Returns at most one event (ack, done or fault) for the active command.
    pub fn on_state(&mut self, s: &RobotState, now_ns: u64) -> Option<SeqEvent> {
        self.last_state = Some(*s);
        let a = self.active.as_mut()?;
        // A state received before the command was issued says nothing about it (it may be
        // queued from before a program restart).
        if s.t_host_ns < a.issued_ns {
            return None;
        }
        // Stops are not interrupted by safety events (the robot is stopping anyway); moves are.
        if a.cmd.kind == CommandKind::MoveL
            && let Some(f) = Self::classify(s)
        {
            let a = self.active.take()?;
            return Some(self.raise(a, f, Some(*s)));
        }
        if s.done_seq() == a.seq {
            let a = self.active.take()?;
            if s.program_status() == Some(ProgramStatus::Rejected) {
                return Some(self.raise(a, Fault::Rejected, Some(*s)));
            }
            return Some(SeqEvent::Done {
                seq: a.seq,
                label: a.label,
                issued_ns: a.issued_ns,
                done_ns: now_ns,
                state: *s,
            });
        }
        if !a.acked && s.ack_seq() == a.seq {
            a.acked = true;
            return Some(SeqEvent::Acked { seq: a.seq });
        }
        self.poll_timeout(now_ns)
    }

    /// Check the deadlines (call when no state arrived for a while).
    pub fn poll_timeout(&mut self, now_ns: u64) -> Option<SeqEvent> {
        let a = self.active.as_ref()?;
        let elapsed = Duration::from_nanos(now_ns.saturating_sub(a.issued_ns));
        let fault = if !a.acked && now_ns > a.ack_deadline_ns {
            Fault::AckTimeout { after: elapsed }
        } else if now_ns > a.done_deadline_ns {
            Fault::MoveTimeout { after: elapsed }
        } else {
            return None;
        };
        let a = self.active.take()?;
        let st = self.last_state;
        Some(self.raise(a, fault, st))
    }

    /// When the sequencer next needs [`poll_timeout`](Self::poll_timeout) called.
    pub fn next_deadline_ns(&self) -> Option<u64> {
        self.active.as_ref().map(|a| {
            if a.acked {
                a.done_deadline_ns
            } else {
                a.ack_deadline_ns.min(a.done_deadline_ns)
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use control::{robot_mode, runtime_state, safety_mode};

    fn ok_state() -> RobotState {
        RobotState {
            robot_mode: robot_mode::RUNNING,
            safety_mode: safety_mode::NORMAL,
            runtime_state: runtime_state::PLAYING,
            actual_tcp_pose: Pose::new(0.4, 0.0, 0.2, std::f64::consts::PI, 0.0, 0.0),
            ..RobotState::default()
        }
    }

    fn with_regs(mut s: RobotState, ack: i32, done: i32, status: ProgramStatus) -> RobotState {
        s.output_int_registers = [ack, done, status as i32];
        s
    }

    const MS: u64 = 1_000_000;

    /// A sequencer with move `label` (to [`ok_state`]'s pose) issued at `now_ns`.
    fn moving(label: &str, now_ns: u64) -> MotionSequencer {
        let s = ok_state();
        let mut q = MotionSequencer::new(SequencerConfig::default());
        q.start_move(label, s.actual_tcp_pose, 0.01, 0.1, &s, now_ns)
            .unwrap();
        q
    }

    /// The fault raised when `s` arrives during a move, if any.
    fn fault_on(s: &RobotState) -> Option<Fault> {
        match moving("m", 0).on_state(s, 1) {
            Some(SeqEvent::Fault(rec)) => Some(rec.fault),
            _ => None,
        }
    }

    #[test]
    fn move_is_acked_then_done() {
        let mut q = MotionSequencer::new(SequencerConfig::default());
        q.sync_seq(41);
        let s = ok_state();
        let target = Pose::new(0.4, 0.0, 0.19, std::f64::consts::PI, 0.0, 0.0);
        let c = q.start_move("p0/down", target, 0.005, 0.1, &s, 0).unwrap();
        assert_eq!(c.seq, 42);
        assert_eq!(c.values().len(), command_recipe().len());
        assert_eq!(
            q.on_state(&with_regs(s, 41, 41, ProgramStatus::Idle), MS),
            None
        );
        assert_eq!(
            q.on_state(&with_regs(s, 42, 41, ProgramStatus::Moving), 2 * MS),
            Some(SeqEvent::Acked { seq: 42 })
        );
        assert!(matches!(
            q.on_state(&with_regs(s, 42, 42, ProgramStatus::Idle), 3 * MS),
            Some(SeqEvent::Done { seq: 42, ref label, .. }) if label == "p0/down"
        ));
        assert!(!q.is_busy());
    }

    #[test]
    fn a_non_finite_reported_pose_refuses_the_move() {
        let mut q = MotionSequencer::new(SequencerConfig::default());
        let target = ok_state().actual_tcp_pose;
        for bad in [f64::NAN, f64::INFINITY] {
            let mut s = ok_state();
            s.actual_tcp_pose.z = bad;
            let e = q
                .start_move("p1/transit", target, 0.01, 0.1, &s, 0)
                .unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.contains("non-finite TCP pose") && msg.contains("p1/transit"),
                "{msg}"
            );
            assert!(
                q.active().is_none(),
                "a refused move left a command in progress"
            );
        }
        // The same move from a real pose is issued.
        q.start_move("p1/transit", target, 0.01, 0.1, &ok_state(), 0)
            .unwrap();
    }

    #[test]
    fn refuses_unless_motion_allowed_and_while_busy() {
        let mut q = MotionSequencer::new(SequencerConfig::default());
        let mut s = ok_state();
        s.runtime_state = runtime_state::STOPPED;
        let e = q
            .start_move("m", s.actual_tcp_pose, 0.01, 0.1, &s, 0)
            .unwrap_err();
        assert!(e.to_string().contains("STOPPED"), "{e}");
        let s = ok_state();
        q.start_move("m", s.actual_tcp_pose, 0.01, 0.1, &s, 0)
            .unwrap();
        assert!(matches!(
            q.start_move("n", s.actual_tcp_pose, 0.01, 0.1, &s, 0),
            Err(Refusal::Busy(1))
        ));
        assert!(matches!(
            q.start_move("n", s.actual_tcp_pose, f64::NAN, 0.1, &s, 0),
            Err(Refusal::BadArgs(_))
        ));
    }

    #[test]
    fn protective_stop_mid_move_faults_with_label_and_blocks_until_cleared() {
        let mut q = moving("p0-d0.2-a030/shear", 0);
        let s = ok_state();
        let mut stopped = with_regs(s, 1, 0, ProgramStatus::Moving);
        stopped.safety_mode = safety_mode::PROTECTIVE_STOP;
        stopped.runtime_state = runtime_state::PAUSED;
        let ev = q.on_state(&stopped, MS).unwrap();
        let SeqEvent::Fault(rec) = ev else {
            panic!("{ev:?}")
        };
        assert_eq!(rec.label, "p0-d0.2-a030/shear");
        assert_eq!(
            rec.fault,
            Fault::ProtectiveStop {
                safety_mode: safety_mode::PROTECTIVE_STOP
            }
        );
        let e = q
            .start_move("next", s.actual_tcp_pose, 0.01, 0.1, &s, 2 * MS)
            .unwrap_err();
        assert!(e.to_string().contains("p0-d0.2-a030/shear"), "{e}");
        q.clear_fault();
        q.start_move("next", s.actual_tcp_pose, 0.01, 0.1, &s, 3 * MS)
            .unwrap();
    }

    #[test]
    fn emergency_stop_and_program_stop_are_distinguished() {
        let mut e = ok_state();
        e.safety_mode = safety_mode::ROBOT_EMERGENCY_STOP;
        assert!(matches!(fault_on(&e), Some(Fault::EmergencyStop { .. })));
        let mut p = ok_state();
        p.runtime_state = runtime_state::STOPPED;
        assert!(matches!(fault_on(&p), Some(Fault::ProgramStopped { .. })));
    }

    #[test]
    fn ack_and_move_timeouts_use_the_given_time() {
        let s = ok_state();
        let cfg = SequencerConfig {
            ack_timeout: Duration::from_millis(100),
            move_timeout_margin: Duration::from_millis(500),
            move_timeout_factor: 1.5,
        };
        let mut q = MotionSequencer::new(cfg);
        q.start_move("a", s.actual_tcp_pose, 0.01, 0.1, &s, 0)
            .unwrap();
        assert_eq!(q.poll_timeout(100 * MS), None);
        assert!(matches!(
            q.poll_timeout(101 * MS),
            Some(SeqEvent::Fault(FaultRecord {
                fault: Fault::AckTimeout { .. },
                ..
            }))
        ));

        // 10 mm at 10 mm/s, 0.1 m/s²: 1.1 s predicted → deadline 1.65 + 0.5 + 0.1 s.
        let mut q = MotionSequencer::new(cfg);
        let mut target = s.actual_tcp_pose;
        target.x += 0.01;
        q.start_move("b", target, 0.01, 0.1, &s, 0).unwrap();
        q.on_state(&with_regs(s, 1, 0, ProgramStatus::Moving), MS);
        assert_eq!(q.poll_timeout(2_200 * MS), None);
        assert!(matches!(
            q.poll_timeout(2_300 * MS),
            Some(SeqEvent::Fault(FaultRecord {
                fault: Fault::MoveTimeout { .. },
                ..
            }))
        ));
    }

    #[test]
    fn rejected_command_is_a_fault_and_reissue_uses_a_new_seq() {
        let s = ok_state();
        assert_eq!(
            fault_on(&with_regs(s, 1, 1, ProgramStatus::Rejected)),
            Some(Fault::Rejected)
        );
        let mut q = moving("a", 0);
        let c = q.reissue(&s, 5).unwrap();
        assert_eq!(c.seq, 2);
        assert_eq!(q.active(), Some(("a", 2)));
        // A restarted program reports done = 1 (its initial value): not our seq any more.
        let mut restarted = with_regs(s, 1, 1, ProgramStatus::Idle);
        restarted.t_host_ns = 6;
        assert_eq!(q.on_state(&restarted, 6), None);
    }

    #[test]
    fn states_from_before_the_command_are_ignored() {
        let mut q = moving("a", 10 * MS);
        let mut stale = ok_state();
        stale.t_host_ns = 9 * MS;
        stale.runtime_state = runtime_state::STOPPED;
        assert_eq!(q.on_state(&stale, 11 * MS), None);
        assert!(q.is_busy());
    }

    #[test]
    fn trapezoid_prediction() {
        assert!((predicted_duration_s(0.01, 0.01, 0.1) - 1.1).abs() < 1e-12);
        // Short move: triangle profile.
        assert!((predicted_duration_s(0.001, 0.1, 0.1) - 2.0 * 0.01f64.sqrt()).abs() < 1e-12);
    }
}
