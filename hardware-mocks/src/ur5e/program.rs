//! The controller's side of the running program: one interpreter cycle per controller tick
//! (`Controller::run_program_cycle`), and the [`Robot`] the interpreter acts on (registers,
//! motion, TCP offset, watchdogs), implemented by the [`Controller`].
//!
//! Motion commands (URScript manual, "Module motion"): `movel` starts a new straight-line move
//! of the TCP from where it is now, replacing any motion under way (a move still running after
//! its thread was killed included, and a `stopl` deceleration); `stopl(a)` decelerates the
//! current motion along its path with `a` (raised if needed so the TCP stops before the target,
//! see [`super::motion::LinearMove::begin_stop`]).

use rig_core::control::runtime_state;
use rig_core::pose::Pose;

use super::controller::{ActiveMotion, Controller, offset_by};
use super::motion::LinearMove;
use super::urscript::{Outcome, Robot, Watchdog};

impl Controller {
    /// Runs the program's threads for the cycle at `t_ns`. The program ending (its main thread
    /// returned, or `halt`) or failing stops it; a failure is logged as an error naming the
    /// line and statement.
    pub(super) fn run_program_cycle(&mut self, t_ns: u64) {
        let Some(mut interp) = self.interp.take() else {
            return;
        };
        let outcome = interp.step(self);
        let name = self.program.as_ref().map_or("", |p| p.name.as_str());
        match outcome {
            Ok(Outcome::Running) => {
                // A step never clears `interp` itself; put the state back.
                if self.runtime_state == runtime_state::PLAYING {
                    self.interp = Some(interp);
                }
            }
            Ok(Outcome::Finished) => {
                tracing::info!(program = %name, "program finished");
                self.stop_program(t_ns);
            }
            Ok(Outcome::Halted) => {
                tracing::info!(program = %name, "program halted");
                self.stop_program(t_ns);
            }
            Err(e) => {
                let statement = self
                    .program
                    .as_ref()
                    .map_or(String::new(), |p| p.line(e.line).to_owned());
                tracing::error!(
                    program = %name,
                    line = e.line,
                    statement = %statement,
                    "URScript runtime error, program stopped: {e} (in `{statement}`)"
                );
                self.stop_program(t_ns);
            }
        }
    }
}

impl Robot for Controller {
    fn now_ns(&self) -> u64 {
        self.t_ns
    }
    fn input_int(&self, n: usize) -> i32 {
        self.in_int.get(n).copied().unwrap_or(0)
    }
    fn input_float(&self, n: usize) -> f64 {
        self.in_double.get(n).copied().unwrap_or(0.0)
    }
    fn input_bool(&self, n: usize) -> bool {
        n < 128 && (self.in_bits >> n) & 1 == 1
    }
    fn set_output_int(&mut self, n: usize, v: i32) {
        if let Some(r) = self.out_int.get_mut(n) {
            *r = v;
        }
    }
    fn set_output_float(&mut self, n: usize, v: f64) {
        if let Some(r) = self.out_double.get_mut(n) {
            *r = v;
        }
    }
    fn set_output_bool(&mut self, n: usize, v: bool) {
        if n < 128 {
            self.out_bits = (self.out_bits & !(1u128 << n)) | ((v as u128) << n);
        }
    }
    fn actual_tcp_pose(&self) -> Pose {
        self.tcp_pose()
    }
    fn target_tcp_pose(&self) -> Pose {
        // Tracking error is not modelled: the target is where the arm is.
        self.tcp_pose()
    }
    fn tcp_offset(&self) -> Pose {
        self.tcp_offset
    }
    fn set_tcp(&mut self, offset: Pose) {
        // A motion under way keeps the TCP it started with (its flange path is unchanged);
        // the reported TCP follows the new offset at once.
        self.tcp_offset = offset;
    }
    fn movel(&mut self, target: Pose, a: f64, v: f64) -> u64 {
        let id = self.next_motion_id;
        self.next_motion_id += 1;
        let start = offset_by(&self.flange, &self.tcp_offset);
        self.motion = Some(ActiveMotion {
            id,
            mv: LinearMove::new(start, target, v, a, self.t_ns),
            tcp: self.tcp_offset,
            speed: v,
            accel: a,
        });
        self.resume_move = None;
        id
    }
    fn motion_running(&self, id: u64) -> bool {
        self.motion.as_ref().is_some_and(|m| m.id == id)
    }
    fn stopl(&mut self, a: f64) {
        let t = self.t_ns;
        if let Some(m) = &mut self.motion {
            m.mv.begin_stop(t, a);
        }
    }
    fn at_rest(&self) -> bool {
        self.motion.is_none()
    }
    fn set_watchdog(&mut self, w: Watchdog) {
        self.watchdogs.retain(|x| x.variable != w.variable);
        self.watchdogs.push(w);
    }
}
