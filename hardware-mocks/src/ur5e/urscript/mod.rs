//! A URScript interpreter for the simulated controller: the subset of the language the rig's
//! control program ([`rig_core::urscript::program`]) uses, and a little more.
//!
//! Semantics follow Universal Robots' *The URScript Programming Language* (Script Manual,
//! e-Series). The pipeline: [`lexer`] (text → tokens), [`parser`] (tokens → [`ast`]),
//! [`compile`] (syntax tree → a flat instruction list, names resolved), [`interp`] (runs the
//! instructions one controller cycle at a time, against a [`Robot`]), with the values and
//! operators in [`value`] and the built-in functions in [`builtins`].
//!
//! # Supported
//!
//! - Statements: `def name(params):` … `end`, `thread name():` … `end`, `while c:` … `end`,
//!   `if`/`elif`/`else` … `end`, `global x = e`, `local x = e`, `x = e`, `x[i] = e`,
//!   `return [e]`, `halt`, `kill h`, `join h`, `enter_critical`/`exit_critical`, `break`,
//!   `continue`, calls as statements; `#` comments and blank lines.
//! - Expressions: int and float literals (with exponents), `True`/`False`, strings in `"…"`
//!   or `'…'`, lists `[a, b]`, poses `p[x, y, z, rx, ry, rz]`, indexing `a[i]`, unary `-` and
//!   `not`, `+ - * / %`, `== != < <= > >=`, `and`/`or` (short-circuit), parentheses, calls with
//!   positional and keyword arguments, `run t()` (a thread handle).
//! - Types and operators: see [`value`]; built-ins: see [`builtins`]; scheduling, blocking and
//!   scoping: see [`interp`].
//!
//! Anything else is refused when the script is compiled, with its line: a real controller
//! would run it, the mock cannot, and silently skipping it would make a test pass for the
//! wrong reason.
//!
//! # Errors
//!
//! A syntax or compile error ([`ScriptError`]) means the program never starts. A runtime error
//! ([`RuntimeError`]: a type error, an out-of-range register, a non-finite `movel` target, a
//! runaway loop, …) stops the program; the controller logs it with its line and statement and
//! decelerates the arm ([`super::controller`]). Nothing in a script, however malformed, panics
//! the mock.

pub mod ast;
pub mod builtins;
pub mod compile;
pub mod interp;
pub mod lexer;
pub mod parser;
mod program;
pub mod value;

use rig_core::pose::Pose;

pub use compile::Code;
pub use interp::{Interpreter, Outcome};
pub use program::{Program, is_closed, is_complete};
pub use value::Value;

/// What the RTDE watchdog does when its variable is not updated in time
/// (`rtde_set_watchdog(variable_name, min_frequency, action="pause")`, URScript manual).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogAction {
    Ignore,
    Pause,
    Stop,
}

/// One `rtde_set_watchdog` call as the program executed it.
#[derive(Debug, Clone, PartialEq)]
pub struct Watchdog {
    pub variable: String,
    pub min_hz: f64,
    pub action: WatchdogAction,
}

/// Why a script cannot run at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScriptError {
    #[error("line {line}: {msg}")]
    Syntax { line: u32, msg: String },
}

/// An error while the program runs; it stops the program.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("thread {thread}, line {line}: {msg}")]
pub struct RuntimeError {
    pub line: u32,
    pub thread: String,
    pub msg: String,
}

/// What a program acts on: the controller's registers, motion and watchdog. Implemented by
/// [`super::controller::Controller`]; all times are controller clock time.
pub trait Robot {
    /// Clock time of the current cycle, ns.
    fn now_ns(&self) -> u64;
    fn input_int(&self, n: usize) -> i32;
    fn input_float(&self, n: usize) -> f64;
    fn input_bool(&self, n: usize) -> bool;
    fn set_output_int(&mut self, n: usize, v: i32);
    fn set_output_float(&mut self, n: usize, v: f64);
    fn set_output_bool(&mut self, n: usize, v: bool);
    /// The TCP pose (the flange pose moved by the TCP offset).
    fn actual_tcp_pose(&self) -> Pose;
    fn target_tcp_pose(&self) -> Pose;
    /// The TCP offset set by `set_tcp` (flange → TCP).
    fn tcp_offset(&self) -> Pose;
    fn set_tcp(&mut self, offset: Pose);
    /// Starts a linear move of the TCP to `target` (checked finite, `a` and `v` positive);
    /// returns the motion's id, which [`Robot::motion_running`] answers for.
    fn movel(&mut self, target: Pose, a: f64, v: f64) -> u64;
    /// Whether motion `id` is still under way (not finished, stopped or replaced).
    fn motion_running(&self, id: u64) -> bool;
    /// Decelerates the current motion, if any, with `a` along its path.
    fn stopl(&mut self, a: f64);
    fn at_rest(&self) -> bool;
    /// Arms (or re-arms) the RTDE watchdog on `w.variable`.
    fn set_watchdog(&mut self, w: Watchdog);
}
