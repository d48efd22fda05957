//! The controller model: robot, safety and program state, the arm's motion, and the
//! registers, advanced one controller cycle at a time by [`Controller::tick`].
//!
//! The model is a plain struct behind a mutex: the tick task, the RTDE connections (writing
//! inputs), the dashboard and the script port all lock it briefly; nothing awaits while
//! holding it. Time is always passed in (`t_ns` on the shared clock), never read here.
//!
//! # One cycle ([`Controller::tick`])
//!
//! 1. The RTDE watchdogs the program armed are checked (while the program plays).
//! 2. The motion is evaluated at the cycle's time (the flange pose, the TCP speed; a finished
//!    motion ends here, so a `movel` waiting for it returns in this same cycle).
//! 3. The program's threads run ([`super::urscript::Interpreter::step`]); a runtime error
//!    stops the program (logged with its line and statement) and decelerates the arm.
//! 4. The motion is evaluated again (a move started in this cycle starts at this time).
//!
//! # Flange, TCP and tool
//!
//! The arm's state is its **flange** pose. The **TCP offset** (flange → tool centre point) is
//! what the program set with `set_tcp` (identity when a program starts: the mock's installation
//! has no TCP configured); the reported `actual_TCP_pose`/`target_TCP_pose`, `get_actual_tcp_pose()`
//! and `movel` targets are TCP poses, `pose_trans(flange, tcp_offset)`. A `movel` moves the TCP
//! of the offset in force when it starts along a straight line; the flange follows as
//! `pose_trans(tcp, pose_inv(offset))`. The **physical tool** ([`super::Ur5eConfig::tool_offset`])
//! is what is really bolted to the flange: its tip, `pose_trans(flange, tool_offset)`, is what
//! touches things ([`Controller::tip_pose`]). When the program's TCP matches the tool, the
//! reported TCP is the tip; a program that forgets `set_tcp` reports (and steers) the flange.

use std::collections::{HashMap, VecDeque};

use rig_core::control::{
    self, motion_allowed, robot_mode, robot_mode_name, runtime_state, safety_mode, safety_mode_name,
};
use rig_core::pose::{self, Pose};
use rig_core::rtde::Value;

use super::motion::LinearMove;
use super::snapshot::ControllerSnapshot;
use super::urscript::{Interpreter, Program, Watchdog, WatchdogAction};
use super::variables::InputSink;

/// Deceleration of stops the controller imposes itself (protective stop, emergency stop,
/// program stop from the dashboard or the watchdog, power off), in path units/s² (m/s² for
/// translations, rad/s² for pure rotations). A category-2-like controlled stop: from the
/// rig's 10 mm/s indentation speed the TCP halts within 17 µm and 3.3 ms; from 0.25 m/s within
/// 10 mm and 83 ms. A move's own commanded acceleration is used instead when it is larger.
pub const CONTROLLER_STOP_DECEL: f64 = 3.0;

/// One `movel` in progress: a straight line of the TCP given by `tcp` (the offset in force
/// when it started).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct ActiveMotion {
    pub(super) id: u64,
    pub(super) mv: LinearMove,
    pub(super) tcp: Pose,
    pub(super) speed: f64,
    pub(super) accel: f64,
}

/// One input data package that changed the command sequence register
/// ([`control::IN_CMD_SEQ`]), as the controller received it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandReceived {
    /// Clock time the package was applied, ns.
    pub t_ns: u64,
    /// The new sequence number.
    pub seq: i32,
    /// [`control::IN_CMD_KIND`] after the package (the command's kind).
    pub kind: i32,
}

/// One input data package that changed the safety supervisor's stop request
/// ([`control::IN_STOP_REQ`]), as the controller received it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StopRequestReceived {
    /// Clock time the package was applied, ns.
    pub t_ns: u64,
    /// The new value of the request counter.
    pub request: i32,
    /// Where the TCP was when it was applied.
    pub tcp_pose: Pose,
}

/// Commands (and stop requests) kept in [`Controller::commands_received`] (and
/// [`Controller::stop_requests_received`]).
pub const COMMAND_LOG: usize = 4096;

#[derive(Debug)]
pub struct Controller {
    pub(super) t0_ns: u64,
    pub t_ns: u64,
    /// The flange pose.
    pub(super) flange: Pose,
    /// Flange → TCP, set by the program's `set_tcp`.
    pub(super) tcp_offset: Pose,
    /// Flange → physical tool tip ([`super::Ur5eConfig::tool_offset`]).
    tool_offset: Pose,
    pub(super) speed: [f64; 6],
    /// The flange sensor's newest reading (`actual_TCP_force`), set on each tick by
    /// `Shared::process_due_ticks`; zero without a sensor.
    pub(super) tcp_force: [f64; 6],
    pub(super) motion: Option<ActiveMotion>,
    pub(super) next_motion_id: u64,
    pub robot_mode: i32,
    pub safety_mode: i32,
    pub runtime_state: u32,
    /// The last script uploaded (compiled).
    pub program: Option<Program>,
    /// The running (or paused) program's state.
    pub(super) interp: Option<Interpreter>,
    /// The watchdogs the running program armed.
    pub(super) watchdogs: Vec<Watchdog>,
    /// A `movel` interrupted by a pause, restarted towards its target on resume.
    pub(super) resume_move: Option<ActiveMotion>,
    program_started_ns: u64,
    pub protective_stop_at_ns: Option<u64>,
    protective_stop_unlock_delay_ns: u64,
    pub(super) in_int: [i32; 48],
    pub(super) in_double: [f64; 48],
    pub(super) in_bits: u128,
    in_other: HashMap<String, Value>,
    pub(super) out_int: [i32; 48],
    pub(super) out_double: [f64; 48],
    pub(super) out_bits: u128,
    /// Clock time of the last data package that wrote each input variable (for the watchdog).
    input_written_ns: HashMap<String, u64>,
    /// Input variable → the RTDE connection whose input recipe holds it.
    input_owners: HashMap<String, u64>,
    commands: VecDeque<CommandReceived>,
    stop_requests: VecDeque<StopRequestReceived>,
}

/// `pose_trans(p, offset)`, exactly `p` for the identity offset (no rounding through the
/// rotation conversions, so an arm without a tool reports its target bit for bit).
pub(super) fn offset_by(p: &Pose, offset: &Pose) -> Pose {
    if *offset == Pose::default() {
        *p
    } else {
        pose::pose_trans(p, offset)
    }
}

/// The flange pose for TCP pose `tcp_pose` with TCP offset `offset`.
pub(super) fn flange_of(tcp_pose: &Pose, offset: &Pose) -> Pose {
    if *offset == Pose::default() {
        *tcp_pose
    } else {
        pose::pose_trans(tcp_pose, &pose::pose_inv(offset))
    }
}

impl Controller {
    /// A controller at rest with its TCP (no offset) at `home`, its physical tool tip at
    /// `pose_trans(home, tool_offset)`.
    pub fn new(
        home: Pose,
        tool_offset: Pose,
        robot_mode: i32,
        unlock_delay_ns: u64,
        t0_ns: u64,
    ) -> Self {
        Self {
            t0_ns,
            t_ns: t0_ns,
            flange: home,
            tcp_offset: Pose::default(),
            tool_offset,
            speed: [0.0; 6],
            tcp_force: [0.0; 6],
            motion: None,
            next_motion_id: 1,
            robot_mode,
            safety_mode: safety_mode::NORMAL,
            runtime_state: runtime_state::STOPPED,
            program: None,
            interp: None,
            watchdogs: Vec::new(),
            resume_move: None,
            program_started_ns: t0_ns,
            protective_stop_at_ns: None,
            protective_stop_unlock_delay_ns: unlock_delay_ns,
            in_int: [0; 48],
            in_double: [0.0; 48],
            in_bits: 0,
            in_other: HashMap::new(),
            out_int: [0; 48],
            out_double: [0.0; 48],
            out_bits: 0,
            input_written_ns: HashMap::new(),
            input_owners: HashMap::new(),
            commands: VecDeque::new(),
            stop_requests: VecDeque::new(),
        }
    }

    /// The TCP pose: the flange moved by the program's TCP offset.
    pub fn tcp_pose(&self) -> Pose {
        offset_by(&self.flange, &self.tcp_offset)
    }

    /// The flange pose.
    pub fn flange_pose(&self) -> Pose {
        self.flange
    }

    /// Where the physical tool's tip is: the flange moved by the configured tool offset.
    pub fn tip_pose(&self) -> Pose {
        offset_by(&self.flange, &self.tool_offset)
    }

    /// The last [`COMMAND_LOG`] command-sequence changes received, oldest first.
    pub fn commands_received(&self) -> Vec<CommandReceived> {
        self.commands.iter().copied().collect()
    }

    /// The last [`COMMAND_LOG`] stop-request changes received, oldest first.
    pub fn stop_requests_received(&self) -> Vec<StopRequestReceived> {
        self.stop_requests.iter().copied().collect()
    }

    /// The state as the RTDE stream would report it now (without the package counter).
    pub fn snapshot(&self) -> ControllerSnapshot {
        ControllerSnapshot {
            t_ns: self.t_ns,
            timestamp_s: self.t_ns.saturating_sub(self.t0_ns) as f64 * 1e-9,
            actual_tcp_pose: self.tcp_pose(),
            // Tracking error is not modelled: the target is where the arm is.
            target_tcp_pose: self.tcp_pose(),
            actual_tcp_speed: self.speed,
            actual_tcp_force: self.tcp_force,
            robot_mode: self.robot_mode,
            safety_mode: self.safety_mode,
            runtime_state: self.runtime_state,
            program_loaded: self.program.is_some(),
            input_int_registers: self.in_int,
            input_double_registers: self.in_double,
            input_bit_registers: self.in_bits,
            output_int_registers: self.out_int,
            output_double_registers: self.out_double,
            output_bit_registers: self.out_bits,
            data_packages_sent: 0,
        }
    }

    fn motion_allowed(&self) -> bool {
        motion_allowed(self.robot_mode, self.safety_mode, self.runtime_state)
    }

    /// One controller cycle at clock time `t_ns` (see the module docs).
    pub fn tick(&mut self, t_ns: u64) -> ControllerSnapshot {
        self.t_ns = t_ns;
        if self.motion_allowed() {
            self.check_watchdogs(t_ns);
        }
        self.advance_motion(t_ns);
        if self.motion_allowed() {
            self.run_program_cycle(t_ns);
        }
        self.advance_motion(t_ns);
        self.snapshot()
    }

    /// The motion at `t_ns`: flange pose and TCP speed; a finished motion ends.
    fn advance_motion(&mut self, t_ns: u64) {
        if let Some(m) = &self.motion {
            let st = m.mv.state_at(t_ns);
            self.flange = flange_of(&st.pose, &m.tcp);
            self.speed = st.speed;
            if st.finished {
                self.motion = None;
            }
        } else {
            self.speed = [0.0; 6];
        }
    }

    fn check_watchdogs(&mut self, t_ns: u64) {
        let mut fired = None;
        for w in &self.watchdogs {
            if !(w.min_hz.is_finite() && w.min_hz > 0.0) {
                continue;
            }
            let period_ns = (1e9 / w.min_hz) as u64;
            let last = self
                .input_written_ns
                .get(&w.variable)
                .copied()
                .unwrap_or(0)
                .max(self.program_started_ns);
            if t_ns.saturating_sub(last) > period_ns && w.action != WatchdogAction::Ignore {
                fired = Some((w.variable.clone(), w.min_hz, w.action));
                break;
            }
        }
        if let Some((var, hz, action)) = fired {
            tracing::warn!(
                variable = %var, min_hz = hz, ?action,
                "RTDE watchdog: no input package updated the variable in time"
            );
            match action {
                WatchdogAction::Stop => self.stop_program(t_ns),
                WatchdogAction::Pause => self.pause_program(t_ns),
                WatchdogAction::Ignore => {}
            }
        }
    }

    pub(super) fn controller_stop_motion(&mut self, t_ns: u64) {
        if let Some(m) = &mut self.motion {
            let decel = CONTROLLER_STOP_DECEL.max(m.mv.accel);
            m.mv.begin_stop(t_ns, decel);
        }
    }

    /// Start (or restart, from its first statement) the loaded program if the robot allows
    /// it. The program starts with no watchdog armed and the TCP offset at identity.
    pub fn start_program(&mut self, t_ns: u64) -> Result<(), String> {
        let Some(program) = &self.program else {
            return Err("no program loaded".into());
        };
        let interp = program.start();
        if self.robot_mode != robot_mode::RUNNING {
            return Err(format!(
                "robot mode is {}",
                robot_mode_name(self.robot_mode)
            ));
        }
        if !matches!(self.safety_mode, safety_mode::NORMAL | safety_mode::REDUCED) {
            return Err(format!(
                "safety mode is {}",
                safety_mode_name(self.safety_mode)
            ));
        }
        self.controller_stop_motion(t_ns);
        self.interp = Some(interp);
        self.watchdogs.clear();
        self.tcp_offset = Pose::default();
        self.resume_move = None;
        self.program_started_ns = t_ns;
        self.runtime_state = runtime_state::PLAYING;
        Ok(())
    }

    /// Load an uploaded (compiled) script and start it when the robot is ready; a running
    /// program is replaced.
    pub fn upload(&mut self, script: Program, t_ns: u64) {
        let name = script.name.clone();
        self.program = Some(script);
        match self.start_program(t_ns) {
            Ok(()) => tracing::info!(program = %name, "program started"),
            Err(why) => {
                self.runtime_state = runtime_state::STOPPED;
                tracing::warn!(program = %name, "program loaded but not started: {why}");
            }
        }
    }

    /// A script that did not compile arrived: the running program stops (the new script
    /// replaced it) and nothing is loaded.
    pub fn refuse_upload(&mut self, t_ns: u64) {
        self.stop_program(t_ns);
        self.program = None;
    }

    /// Stop the program (dashboard `stop`, watchdog "stop", safety stops, program end, runtime
    /// errors): its threads are gone and the arm decelerates.
    pub fn stop_program(&mut self, t_ns: u64) {
        self.controller_stop_motion(t_ns);
        self.interp = None;
        self.resume_move = None;
        self.runtime_state = runtime_state::STOPPED;
    }

    /// Pause the program (dashboard `pause`, watchdog "pause"): the threads keep their state,
    /// the move decelerates and is resumed towards its target by `play`.
    pub fn pause_program(&mut self, t_ns: u64) {
        if let Some(m) = self.motion.as_ref().filter(|m| !m.mv.is_stopping()) {
            self.resume_move = Some(m.clone());
        }
        self.controller_stop_motion(t_ns);
        self.runtime_state = runtime_state::PAUSED;
    }

    /// Resume a paused program; an interrupted moveL restarts towards its target.
    pub fn resume_program(&mut self, t_ns: u64) -> Result<(), String> {
        if !matches!(self.safety_mode, safety_mode::NORMAL | safety_mode::REDUCED)
            || self.robot_mode != robot_mode::RUNNING
        {
            return Err("robot not ready".into());
        }
        self.runtime_state = runtime_state::PLAYING;
        self.program_started_ns = t_ns;
        if let Some(m) = self.resume_move.take() {
            // The same motion id: the `movel` waiting for it goes on waiting.
            let start = offset_by(&self.flange, &m.tcp);
            self.motion = Some(ActiveMotion {
                mv: LinearMove::new(start, m.mv.target, m.speed, m.accel, t_ns),
                ..m
            });
        }
        Ok(())
    }

    pub fn protective_stop(&mut self, t_ns: u64) {
        tracing::warn!("protective stop");
        self.safety_mode = safety_mode::PROTECTIVE_STOP;
        self.protective_stop_at_ns = Some(t_ns);
        self.stop_program(t_ns);
    }

    pub fn emergency_stop(&mut self, t_ns: u64) {
        tracing::warn!("robot emergency stop");
        self.safety_mode = safety_mode::ROBOT_EMERGENCY_STOP;
        self.stop_program(t_ns);
        self.robot_mode = robot_mode::POWER_OFF;
    }

    pub fn release_emergency_stop(&mut self) {
        if matches!(
            self.safety_mode,
            safety_mode::ROBOT_EMERGENCY_STOP | safety_mode::SYSTEM_EMERGENCY_STOP
        ) {
            self.safety_mode = safety_mode::NORMAL;
        }
    }

    /// Dashboard `unlock protective stop`.
    pub fn unlock_protective_stop(&mut self, t_ns: u64) -> Result<(), String> {
        let Some(at) = self
            .protective_stop_at_ns
            .filter(|_| self.safety_mode == safety_mode::PROTECTIVE_STOP)
        else {
            return Err("not in protective stop".into());
        };
        if t_ns.saturating_sub(at) < self.protective_stop_unlock_delay_ns {
            let secs = self.protective_stop_unlock_delay_ns as f64 * 1e-9;
            return Err(format!(
                "Cannot unlock protective stop until {secs}s after occurrence. Always inspect cause of protective stop before unlocking"
            ));
        }
        self.safety_mode = safety_mode::NORMAL;
        self.protective_stop_at_ns = None;
        self.robot_mode = robot_mode::RUNNING;
        Ok(())
    }

    pub fn power_on(&mut self) -> Result<(), String> {
        if !matches!(self.safety_mode, safety_mode::NORMAL | safety_mode::REDUCED) {
            return Err(format!(
                "safety mode is {}",
                safety_mode_name(self.safety_mode)
            ));
        }
        if self.robot_mode == robot_mode::POWER_OFF {
            self.robot_mode = robot_mode::IDLE;
        }
        Ok(())
    }

    pub fn power_off(&mut self, t_ns: u64) {
        self.stop_program(t_ns);
        self.robot_mode = robot_mode::POWER_OFF;
    }

    pub fn brake_release(&mut self) -> Result<(), String> {
        self.power_on()?;
        if self.robot_mode == robot_mode::IDLE {
            self.robot_mode = robot_mode::RUNNING;
        }
        Ok(())
    }

    /// Claim input variables for connection `conn`: `Err(names)` lists those another live
    /// connection holds.
    pub fn input_owner(&self, name: &str) -> Option<u64> {
        self.input_owners.get(name).copied()
    }

    pub fn claim_inputs(&mut self, conn: u64, names: &[String]) {
        for n in names {
            self.input_owners.insert(n.clone(), conn);
        }
    }

    pub fn release_inputs(&mut self, conn: u64) {
        self.input_owners.retain(|_, c| *c != conn);
    }

    /// Apply the values of one input data package received at `t_ns`.
    pub fn write_inputs(
        &mut self,
        names: &[String],
        sinks: &[InputSink],
        values: &[Value],
        t_ns: u64,
    ) {
        let seq_before = self.in_int[control::IN_CMD_SEQ as usize];
        let stop_before = self.in_int[control::IN_STOP_REQ as usize];
        for ((name, sink), value) in names.iter().zip(sinks).zip(values) {
            match (sink, value) {
                (InputSink::Int(n), Value::Int32(v)) if *n < 48 => self.in_int[*n] = *v,
                (InputSink::Double(n), Value::Double(v)) if *n < 48 => self.in_double[*n] = *v,
                (InputSink::Bit(n), Value::Bool(v)) if *n < 128 => {
                    self.in_bits = (self.in_bits & !(1u128 << n)) | ((*v as u128) << n);
                }
                (InputSink::BitWord(w), Value::Uint32(v)) if *w < 2 => {
                    let shift = 32 * w;
                    self.in_bits =
                        (self.in_bits & !(0xffff_ffffu128 << shift)) | ((*v as u128) << shift);
                }
                (InputSink::Other(n), v) => {
                    self.in_other.insert(n.clone(), *v);
                }
                _ => {}
            }
            self.input_written_ns.insert(name.clone(), t_ns);
        }
        let request = self.in_int[control::IN_STOP_REQ as usize];
        if request != stop_before {
            if self.stop_requests.len() == COMMAND_LOG {
                self.stop_requests.pop_front();
            }
            self.stop_requests.push_back(StopRequestReceived {
                t_ns,
                request,
                tcp_pose: self.tcp_pose(),
            });
        }
        let seq = self.in_int[control::IN_CMD_SEQ as usize];
        if seq != seq_before {
            if self.commands.len() == COMMAND_LOG {
                self.commands.pop_front();
            }
            self.commands.push_back(CommandReceived {
                t_ns,
                seq,
                kind: self.in_int[control::IN_CMD_KIND as usize],
            });
        }
    }
}
