//! The rig's URScript control program, generated from the register contract in
//! [`crate::control`].
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
//! - optionally sets the tool centre point (`set_tcp(pose)`, URScript manual), so that poses
//!   and moveL targets are those of the tool tip rather than of the flange;
//! - starts with ack = done = the current command seq, so an old command is never re-run;
//! - runs each moveL (`movel(pose, a=, v=)`, URScript manual) in a thread, so the main loop
//!   keeps polling and can `kill` the thread and decelerate with `stopl(a)` on a Stop command;
//! - before any command, serves the safety supervisor's stop request
//!   ([`control::IN_STOP_REQ`]): a changed counter kills the move in progress and decelerates
//!   with `stopl(`[`control::IN_STOP_DECEL`]`)`, whatever command was being executed;
//! - rejects commands with an unknown kind or a non-positive speed or acceleration
//!   ([`ProgramStatus::Rejected`]);
//! - calls `sync()` in every loop iteration so it yields once per controller cycle.
//!
//! Register functions used: `read_input_integer_register(n)`, `read_input_float_register(n)`,
//! `write_output_integer_register(n, v)` (URScript manual, "Interfaces").
//!
//! The text lives here, in `rig-core`, so that the rig uploads it and the simulated controller
//! in `hardware-mocks` is tested with exactly the same program: the mock interprets URScript
//! (it does not recognise this program or emulate it), so a mistake in this text shows up as
//! wrong behaviour of the simulated robot.

use crate::control::{self, CommandKind, ProgramStatus};

/// Deceleration of a supervisor stop whose register holds no usable value, m/s²: the
/// controller's own stop deceleration in the simulated UR5e (a category-2-like stop).
pub const FALLBACK_STOP_DECEL: f64 = 3.0;

/// The program text for a watchdog of at least `watchdog_min_hz` (a non-finite or non-positive
/// rate gives [`control::WATCHDOG_MIN_HZ`]). With `tcp = Some([x, y, z, rx, ry, rz])` (metres,
/// radians: the flange → tool-tip transform) the program calls `set_tcp(p[…])` right after
/// arming the watchdog, so the poses it reads and the moveL targets it receives are those of
/// that tool centre point; with `None` the controller's TCP is left as it is.
pub fn program(watchdog_min_hz: f64, tcp: Option<[f64; 6]>) -> String {
    let name = control::PROGRAM_NAME;
    let hz = fmt_f64(if watchdog_min_hz.is_finite() && watchdog_min_hz > 0.0 {
        watchdog_min_hz
    } else {
        control::WATCHDOG_MIN_HZ
    });
    let seq = control::IN_CMD_SEQ;
    let kind = control::IN_CMD_KIND;
    let hb = control::input_int(control::IN_HEARTBEAT);
    let ack = control::OUT_ACK_SEQ;
    let done = control::OUT_DONE_SEQ;
    let status = control::OUT_STATUS;
    let p = control::IN_TARGET_POSE;
    let speed = control::IN_SPEED;
    let accel = control::IN_ACCEL;
    let (stop_req, stop_decel) = (control::IN_STOP_REQ, control::IN_STOP_DECEL);
    let (k_move, k_stop) = (CommandKind::MoveL as i32, CommandKind::Stop as i32);
    let (s_idle, s_moving, s_rejected) = (
        ProgramStatus::Idle as i32,
        ProgramStatus::Moving as i32,
        ProgramStatus::Rejected as i32,
    );
    let pose_reads = (0..6)
        .map(|i| format!("read_input_float_register({})", p + i))
        .collect::<Vec<_>>()
        .join(", ");
    format!(
        r#"def {name}():
  rtde_set_watchdog("{hb}", {hz}, "stop")
{set_tcp}  global last_seq = read_input_integer_register({seq})
  global last_stop = read_input_integer_register({stop_req})
  global move_seq = last_seq
  global move_target = get_actual_tcp_pose()
  global move_speed = 0.01
  global move_accel = 0.1
  global moving = False
  write_output_integer_register({ack}, last_seq)
  write_output_integer_register({done}, last_seq)
  write_output_integer_register({status}, {s_idle})

  thread move_thread():
    movel(move_target, a=move_accel, v=move_speed)
    enter_critical
    moving = False
    write_output_integer_register({done}, move_seq)
    write_output_integer_register({status}, {s_idle})
    exit_critical
  end

  mover = 0
  while True:
    # The safety supervisor's stop comes first, whatever command is in progress.
    stop = read_input_integer_register({stop_req})
    if stop != last_stop:
      last_stop = stop
      if moving:
        kill mover
        moving = False
      end
      d = read_input_float_register({stop_decel})
      if not (d > 0 and d < 1000000):
        d = {fallback_decel}
      end
      stopl(d)
      write_output_integer_register({status}, {s_idle})
    end
    seq = read_input_integer_register({seq})
    if seq != last_seq:
      last_seq = seq
      write_output_integer_register({ack}, seq)
      kind = read_input_integer_register({kind})
      v = read_input_float_register({speed})
      a = read_input_float_register({accel})
      # `x > 0 and x < 1e6` is false for NaN and for infinities too: URScript has no isfinite.
      if kind == {k_move}:
        if v > 0 and v < 1000000 and a > 0 and a < 1000000:
          if moving:
            kill mover
            moving = False
          end
          move_target = p[{pose_reads}]
          move_speed = v
          move_accel = a
          move_seq = seq
          moving = True
          write_output_integer_register({status}, {s_moving})
          mover = run move_thread()
        else:
          write_output_integer_register({status}, {s_rejected})
          write_output_integer_register({done}, seq)
        end
      elif kind == {k_stop}:
        if a > 0 and a < 1000000:
          if moving:
            kill mover
            moving = False
          end
          stopl(a)
          write_output_integer_register({status}, {s_idle})
        else:
          write_output_integer_register({status}, {s_rejected})
        end
        write_output_integer_register({done}, seq)
      else:
        write_output_integer_register({status}, {s_rejected})
        write_output_integer_register({done}, seq)
      end
    end
    sync()
  end
end
{name}()
"#,
        fallback_decel = fmt_f64(FALLBACK_STOP_DECEL),
        set_tcp = tcp.map_or(String::new(), |t| format!(
            "  set_tcp(p[{}])\n",
            t.map(fmt_f64).join(", ")
        )),
    )
}

/// A float literal URScript accepts (always with a decimal point).
pub fn fmt_f64(v: f64) -> String {
    let s = format!("{v}");
    if s.contains('.') || s.contains('e') {
        s
    } else {
        format!("{s}.0")
    }
}

/// Checks that every block opener (`def`, `thread`, `while`, `if`) has its `end`, in order.
/// Returns the line number (1-based) of the first problem.
pub fn check_blocks(text: &str) -> Result<(), String> {
    let mut depth: i64 = 0;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        let opens = ["def ", "thread ", "while ", "if "]
            .iter()
            .any(|k| t.starts_with(k))
            && t.ends_with(':');
        if opens {
            depth += 1;
        } else if t == "end" {
            depth -= 1;
            if depth < 0 {
                return Err(format!("line {}: `end` without an open block", i + 1));
            }
        }
    }
    if depth == 0 {
        Ok(())
    } else {
        Err(format!("{depth} block(s) never closed"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn program_names_every_register_of_the_contract() {
        let text = program(control::WATCHDOG_MIN_HZ, None);
        for n in [control::IN_CMD_SEQ, control::IN_CMD_KIND] {
            assert!(
                text.contains(&format!("read_input_integer_register({n})")),
                "{n}"
            );
        }
        assert!(text.contains(&format!(
            "rtde_set_watchdog(\"{}\", 10.0, \"stop\")",
            control::input_int(control::IN_HEARTBEAT)
        )));
        for n in (control::IN_TARGET_POSE..control::IN_TARGET_POSE + 6)
            .chain([control::IN_SPEED, control::IN_ACCEL])
        {
            assert!(
                text.contains(&format!("read_input_float_register({n})")),
                "{n}"
            );
        }
        for n in [
            control::OUT_ACK_SEQ,
            control::OUT_DONE_SEQ,
            control::OUT_STATUS,
        ] {
            assert!(
                text.contains(&format!("write_output_integer_register({n},")),
                "{n}"
            );
        }
    }

    #[test]
    fn program_shape_matches_the_contract() {
        let text = program(25.0, None);
        let lines: Vec<_> = text.lines().collect();
        assert_eq!(lines[0], format!("def {}():", control::PROGRAM_NAME));
        assert!(lines[1].trim().starts_with("rtde_set_watchdog("));
        assert!(lines[1].contains("25.0"));
        assert!(!text.contains("set_tcp"));
        assert_eq!(
            lines.last().unwrap().trim(),
            format!("{}()", control::PROGRAM_NAME)
        );
        assert!(text.contains("movel(move_target, a=move_accel, v=move_speed)"));
        assert!(text.contains("kill mover"));
        assert!(text.contains("stopl(a)"));
        assert!(text.contains("sync()"));
        check_blocks(&text).unwrap();
    }

    #[test]
    fn tcp_is_set_right_after_the_watchdog() {
        let text = program(10.0, Some([0.0, -0.01, 0.1, 0.0, 0.0, 1.5]));
        let lines: Vec<_> = text.lines().collect();
        assert!(lines[1].trim().starts_with("rtde_set_watchdog("));
        assert_eq!(
            lines[2].trim(),
            "set_tcp(p[0.0, -0.01, 0.1, 0.0, 0.0, 1.5])"
        );
        assert_eq!(text.matches("set_tcp").count(), 1);
        check_blocks(&text).unwrap();
        // A bad rate falls back to the contract's default.
        assert!(program(f64::NAN, None).contains(", 10.0, \"stop\")"));
        assert!(program(-1.0, None).contains(", 10.0, \"stop\")"));
    }

    #[test]
    fn float_literals_always_have_a_decimal_point() {
        assert_eq!(fmt_f64(1.0), "1.0");
        assert_eq!(fmt_f64(-2.0), "-2.0");
        assert_eq!(fmt_f64(0.25), "0.25");
    }

    #[test]
    fn block_checker_catches_imbalance() {
        assert!(check_blocks("def f():\n  if x:\n  end\n").is_err());
        assert!(check_blocks("def f():\nend\nend\n").is_err());
        assert!(check_blocks("def f():\n  while True:\n    sync()\n  end\nend\n").is_ok());
    }
}
