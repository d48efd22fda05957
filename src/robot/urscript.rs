//! The rig's URScript control program, generated from the register contract in
//! [`rig_core::control`].
//!
//! Why a program of our own: streaming `movel` lines over the secondary interface would
//! replace the running program on every line and leave no way to know when a move has ended.
//! Instead (as ur_rtde does) the rig uploads one program that polls RTDE input registers for
//! commands and reports through output registers, and the rig watches those registers in the
//! RTDE stream. The program:
//!
//! - arms the RTDE watchdog on the heartbeat register (`rtde_set_watchdog(variable_name,
//!   min_frequency, action="stop")`, URScript manual), so the program stops if the rig stops
//!   writing the heartbeat for longer than `1 / min_frequency`;
//! - optionally sets the tool centre point (`set_tcp(pose)`, URScript manual);
//! - starts with ack = done = the current command seq, so an old command is never re-run;
//! - runs each moveL (`movel(pose, a=, v=)`, URScript manual) in a thread, so the main loop
//!   keeps polling and can `kill` the thread and decelerate with `stopl(a)` on a Stop command;
//! - rejects commands with an unknown kind or a non-positive speed or acceleration
//!   ([`rig_core::control::ProgramStatus::Rejected`]);
//! - calls `sync()` in every loop iteration so it yields once per controller cycle.
//!
//! Register functions used: `read_input_integer_register(n)`, `read_input_float_register(n)`,
//! `write_output_integer_register(n, v)` (URScript manual, "Interfaces").
//!
//! The generator lives in [`rig_core::urscript`] (re-exported here) so that the simulated
//! controller in `hardware-mocks` runs exactly this text: it interprets the URScript it is
//! sent (a subset of the language, `hardware-mocks/src/ur5e/urscript`), as a real controller
//! runs it, rather than recognising the program and emulating it.

pub use rig_core::urscript::{check_blocks, fmt_f64, program};
