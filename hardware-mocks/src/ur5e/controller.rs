//! The controller model: robot, safety and program state, the emulated rig program, and the
//! registers, advanced one controller cycle at a time by [`Controller::tick`].
//!
//! The model is a plain struct behind a mutex: the tick task, the RTDE connections (writing
//! inputs), the dashboard and the script port all lock it briefly; nothing awaits while
//! holding it. Time is always passed in (`t_ns` on the shared clock), never read here.

use std::collections::HashMap;

use rig_core::control::{
    self, CommandKind, ProgramStatus, motion_allowed, robot_mode, robot_mode_name, runtime_state,
    safety_mode, safety_mode_name,
};
use rig_core::pose::Pose;
use rig_core::rtde::Value;

use super::motion::LinearMove;
use super::program::{Script, WatchdogAction};
use super::snapshot::ControllerSnapshot;
use super::variables::InputSink;

/// Deceleration of stops the controller imposes itself (protective stop, emergency stop,
/// program stop from the dashboard or the watchdog, power off), in path units/s² (m/s² for
/// translations, rad/s² for pure rotations). A category-2-like controlled stop: from the
/// rig's 10 mm/s indentation speed the TCP halts within 17 µm and 3.3 ms; from 0.25 m/s within
/// 10 mm and 83 ms. A move's own commanded acceleration is used instead when it is larger.
pub const CONTROLLER_STOP_DECEL: f64 = 3.0;

/// The program command being executed.
#[derive(Debug, Clone, PartialEq)]
struct ActiveCommand {
    seq: i32,
    target: Pose,
    speed: f64,
    accel: f64,
}

#[derive(Debug)]
pub struct Controller {
    t0_ns: u64,
    pub t_ns: u64,
    pose: Pose,
    speed: [f64; 6],
    motion: Option<LinearMove>,
    pub robot_mode: i32,
    pub safety_mode: i32,
    pub runtime_state: u32,
    /// The last script uploaded that the mock can run (the rig's program).
    pub program: Option<Script>,
    program_started_ns: u64,
    last_seen_seq: i32,
    /// The moveL/stop the program is executing (done when the motion ends).
    active: Option<ActiveCommand>,
    pub protective_stop_at_ns: Option<u64>,
    protective_stop_unlock_delay_ns: u64,
    in_int: [i32; 48],
    in_double: [f64; 48],
    in_bits: u128,
    in_other: HashMap<String, Value>,
    out_int: [i32; 48],
    out_double: [f64; 48],
    out_bits: u128,
    /// Clock time of the last data package that wrote each input variable (for the watchdog).
    input_written_ns: HashMap<String, u64>,
    /// Input variable → the RTDE connection whose input recipe holds it.
    input_owners: HashMap<String, u64>,
}

fn valid_motion_param(x: f64) -> bool {
    x.is_finite() && x > 0.0
}

impl Controller {
    pub fn new(home: Pose, robot_mode: i32, unlock_delay_ns: u64, t0_ns: u64) -> Self {
        Self {
            t0_ns,
            t_ns: t0_ns,
            pose: home,
            speed: [0.0; 6],
            motion: None,
            robot_mode,
            safety_mode: safety_mode::NORMAL,
            runtime_state: runtime_state::STOPPED,
            program: None,
            program_started_ns: t0_ns,
            last_seen_seq: 0,
            active: None,
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
        }
    }

    /// The state as the RTDE stream would report it now (without the package counter).
    pub fn snapshot(&self) -> ControllerSnapshot {
        ControllerSnapshot {
            t_ns: self.t_ns,
            timestamp_s: self.t_ns.saturating_sub(self.t0_ns) as f64 * 1e-9,
            actual_tcp_pose: self.pose,
            // Tracking error is not modelled: the target is where the arm is.
            target_tcp_pose: self.pose,
            actual_tcp_speed: self.speed,
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

    /// One controller cycle at clock time `t_ns`.
    pub fn tick(&mut self, t_ns: u64) -> ControllerSnapshot {
        self.t_ns = t_ns;
        if self.motion_allowed() {
            self.check_watchdogs(t_ns);
        }
        if self.motion_allowed() {
            self.program_step(t_ns);
        }
        if let Some(m) = &self.motion {
            let st = m.state_at(t_ns);
            self.pose = st.pose;
            self.speed = st.speed;
            if st.finished {
                self.motion = None;
                if self.runtime_state == runtime_state::PLAYING
                    && let Some(cmd) = self.active.take()
                {
                    self.out_int[control::OUT_DONE_SEQ as usize] = cmd.seq;
                    self.out_int[control::OUT_STATUS as usize] = ProgramStatus::Idle as i32;
                }
            }
        } else {
            self.speed = [0.0; 6];
        }
        self.snapshot()
    }

    /// The emulated rig program: poll the command sequence register (see
    /// `rig_core::control` and `rig::robot::urscript`).
    fn program_step(&mut self, t_ns: u64) {
        let seq = self.in_int[control::IN_CMD_SEQ as usize];
        if seq == self.last_seen_seq {
            return;
        }
        self.last_seen_seq = seq;
        self.out_int[control::OUT_ACK_SEQ as usize] = seq;
        let kind = self.in_int[control::IN_CMD_KIND as usize];
        let v = self.in_double[control::IN_SPEED as usize];
        let a = self.in_double[control::IN_ACCEL as usize];
        let p0 = control::IN_TARGET_POSE as usize;
        let target = Pose::from_array(std::array::from_fn(|i| self.in_double[p0 + i]));
        let reject = |c: &mut Self| {
            c.out_int[control::OUT_STATUS as usize] = ProgramStatus::Rejected as i32;
            c.out_int[control::OUT_DONE_SEQ as usize] = seq;
        };
        match CommandKind::from_i32(kind) {
            Some(CommandKind::MoveL) => {
                let finite_target = target.to_array().iter().all(|x| x.is_finite());
                if !(valid_motion_param(v) && valid_motion_param(a) && finite_target) {
                    reject(self);
                    return;
                }
                // Like the program's `kill mover` + new `movel`: a moveL during a move starts
                // afresh from the current pose (the rig waits for DONE before the next one).
                let m = LinearMove::new(self.pose, target, v, a, t_ns);
                self.motion = Some(m);
                self.active = Some(ActiveCommand {
                    seq,
                    target,
                    speed: v,
                    accel: a,
                });
                self.out_int[control::OUT_STATUS as usize] = ProgramStatus::Moving as i32;
            }
            Some(CommandKind::Stop) => {
                if !valid_motion_param(a) {
                    reject(self);
                    return;
                }
                // stopl(a): decelerate along the path; DONE when at rest.
                if let Some(m) = &mut self.motion {
                    m.begin_stop(t_ns, a);
                    self.active = Some(ActiveCommand {
                        seq,
                        target: self.pose,
                        speed: v,
                        accel: a,
                    });
                } else {
                    self.active = None;
                    self.out_int[control::OUT_DONE_SEQ as usize] = seq;
                    self.out_int[control::OUT_STATUS as usize] = ProgramStatus::Idle as i32;
                }
            }
            Some(CommandKind::None) => {
                self.out_int[control::OUT_DONE_SEQ as usize] = seq;
            }
            None => reject(self),
        }
    }

    fn check_watchdogs(&mut self, t_ns: u64) {
        let Some(program) = &self.program else { return };
        let mut fired = None;
        for w in &program.watchdogs {
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

    fn controller_stop_motion(&mut self, t_ns: u64) {
        if let Some(m) = &mut self.motion {
            let decel = CONTROLLER_STOP_DECEL.max(m.accel);
            m.begin_stop(t_ns, decel);
        }
    }

    /// Start (or restart) the loaded program if the robot allows it.
    pub fn start_program(&mut self, t_ns: u64) -> Result<(), String> {
        if self.program.is_none() {
            return Err("no program loaded".into());
        }
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
        // The program starts with ack = done = the current seq so a stale command is not
        // replayed.
        let seq = self.in_int[control::IN_CMD_SEQ as usize];
        self.last_seen_seq = seq;
        self.out_int[control::OUT_ACK_SEQ as usize] = seq;
        self.out_int[control::OUT_DONE_SEQ as usize] = seq;
        self.out_int[control::OUT_STATUS as usize] = ProgramStatus::Idle as i32;
        self.active = None;
        self.program_started_ns = t_ns;
        self.runtime_state = runtime_state::PLAYING;
        Ok(())
    }

    /// Load an uploaded script and start it when the robot is ready.
    pub fn upload(&mut self, script: Script, t_ns: u64) {
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

    /// Stop the program (dashboard `stop`, watchdog "stop", safety stops).
    pub fn stop_program(&mut self, t_ns: u64) {
        self.controller_stop_motion(t_ns);
        self.active = None;
        self.runtime_state = runtime_state::STOPPED;
    }

    /// Pause the program (dashboard `pause`, watchdog "pause"): the move decelerates and is
    /// resumed from where it stopped by `play`.
    pub fn pause_program(&mut self, t_ns: u64) {
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
        if let Some(cmd) = &self.active {
            self.motion = Some(LinearMove::new(
                self.pose, cmd.target, cmd.speed, cmd.accel, t_ns,
            ));
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
    }
}
