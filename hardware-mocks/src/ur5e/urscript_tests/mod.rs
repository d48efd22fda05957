//! The language: lexing, parsing, values, statements, scoping, threads and errors, each run in
//! a real [`Controller`] tick by tick.

use rig_core::control::{robot_mode, runtime_state};
use rig_core::pose::Pose;

use super::controller::Controller;
use super::snapshot::ControllerSnapshot;
use super::urscript::lexer::{Tok, lex};
use super::urscript::{
    Interpreter, Program, RuntimeError, ScriptError, Value, WatchdogAction, is_closed, is_complete,
};

mod motion;
mod rig;

/// Controller period, ns (500 Hz).
pub(super) const P: u64 = 2_000_000;

pub(super) fn home() -> Pose {
    Pose::new(0.3, -0.2, 0.3, 0.0, std::f64::consts::PI, 0.0)
}

/// A RUNNING controller at clock 0 with the tool offset `tool`.
pub(super) fn controller_with_tool(tool: Pose) -> Controller {
    Controller::new(home(), tool, robot_mode::RUNNING, 5_000_000_000, 0)
}

/// A RUNNING controller playing `text` (not yet ticked).
pub(super) fn playing(text: &str) -> Controller {
    let mut c = controller_with_tool(Pose::default());
    c.upload(Program::parse(text).unwrap(), 0);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);
    c
}

/// `n` controller ticks; the last snapshot.
pub(super) fn ticks(c: &mut Controller, n: u64) -> ControllerSnapshot {
    let mut s = c.snapshot();
    for _ in 0..n {
        let t = c.t_ns + P;
        s = c.tick(t);
    }
    s
}

pub(super) fn out_int(c: &Controller, n: usize) -> i32 {
    c.snapshot().output_int_registers[n]
}

pub(super) fn out_float(c: &Controller, n: usize) -> f64 {
    c.snapshot().output_double_registers[n]
}

/// Runs `text` on its own interpreter against a controller, one cycle at a time, until it
/// fails; panics if it does not fail within `max_cycles`.
pub(super) fn runtime_error(text: &str, max_cycles: u32) -> RuntimeError {
    let program = Program::parse(text).unwrap();
    let mut c = controller_with_tool(Pose::default());
    let mut interp: Interpreter = program.start();
    for _ in 0..max_cycles {
        let t = c.t_ns + P;
        c.t_ns = t;
        if let Err(e) = interp.step(&mut c) {
            return e;
        }
    }
    panic!("no runtime error in {max_cycles} cycles");
}

/// The globals of `text` after one cycle.
fn globals_after_one_cycle(text: &str) -> Interpreter {
    let program = Program::parse(text).unwrap();
    let mut c = controller_with_tool(Pose::default());
    let mut interp = program.start();
    c.t_ns = P;
    interp.step(&mut c).unwrap();
    interp
}

fn syntax_line(text: &str) -> (u32, String) {
    match Program::parse(text) {
        Err(ScriptError::Syntax { line, msg }) => (line, msg),
        Ok(_) => panic!("{text:?} parsed"),
    }
}

#[test]
fn lexer_reads_numbers_strings_poses_and_comments_with_lines() {
    let toks = lex("x = 1.5e-3 + 2E2 # c\n\ny = 'a\"b' \"c\"\nz = p[1, 2] + p [0]\n").unwrap();
    let kinds: Vec<_> = toks.iter().map(|t| (t.line, t.kind.clone())).collect();
    assert!(kinds.contains(&(1, Tok::Float(1.5e-3))));
    assert!(kinds.contains(&(1, Tok::Float(200.0))));
    assert!(kinds.contains(&(3, Tok::Str("a\"b".into()))));
    assert!(kinds.contains(&(3, Tok::Str("c".into()))));
    assert!(kinds.contains(&(4, Tok::PoseOpen)));
    // `p [` with a space is the variable p indexed.
    assert!(kinds.contains(&(4, Tok::Ident("p".into()))));
    // Blank lines and comments leave one newline per statement.
    assert_eq!(toks.iter().filter(|t| t.kind == Tok::Newline).count(), 3);
    assert!(lex("x = \"open\n").is_err());
    assert!(lex("x = 99999999999\n").is_err());
    assert!(lex("x = 1 $ 2\n").is_err());
}

#[test]
fn syntax_and_compile_errors_name_their_line_and_statement() {
    let (line, msg) = syntax_line("def f():\n  x = 1\n  set_payload(1.0)\nend\n");
    assert_eq!(line, 3);
    assert!(msg.contains("unknown function `set_payload`"), "{msg}");
    assert!(msg.contains("set_payload(1.0)"), "{msg}");
    let (line, msg) = syntax_line("def f():\n  for i in x:\n  end\nend\n");
    assert_eq!(line, 2);
    assert!(msg.contains("for i in x:"), "{msg}");
    assert_eq!(
        syntax_line("def f():\n  while True:\n    sync()\nend\n").0,
        1
    );
    assert_eq!(syntax_line("x = 1\nend\n").0, 2);
    assert_eq!(syntax_line("x = (1 +\n").0, 1);
    assert_eq!(syntax_line("x = 1\nx + 1\n").0, 2);
    assert_eq!(syntax_line("x = 1\nbreak\n").0, 2);
    assert_eq!(syntax_line("movel(p[1,2,3,4,5,6], w=1)\n").0, 1);
    assert_eq!(syntax_line("movel(a=1)\n").0, 1);
    assert_eq!(syntax_line("def f(a):\nend\nf()\n").0, 3);
    assert_eq!(syntax_line("def sync():\nend\n").0, 1);
    assert_eq!(syntax_line("thread t():\nend\nt()\n").0, 3);
    assert_eq!(syntax_line("x = p[1, 2]\n").0, 1);
}

#[test]
fn arithmetic_types_and_precedence() {
    let i = globals_after_one_cycle(
        "a = 7 / 2\nb = 7 % 3\nc = 2 + 3 * 4 - 1\nd = -(2 + 1) * 2.5\ne = 1 + 0.5\n\
         f = 10 - 2 - 3\ng = 2 * 3 % 4\nh = -7 % 3\nk = 1.5e1 / 3\n",
    );
    assert_eq!(i.global("a"), Some(&Value::Float(3.5)));
    assert_eq!(i.global("b"), Some(&Value::Int(1)));
    assert_eq!(i.global("c"), Some(&Value::Int(13)));
    assert_eq!(i.global("d"), Some(&Value::Float(-7.5)));
    assert_eq!(i.global("e"), Some(&Value::Float(1.5)));
    assert_eq!(i.global("f"), Some(&Value::Int(5)));
    assert_eq!(i.global("g"), Some(&Value::Int(2)));
    assert_eq!(i.global("h"), Some(&Value::Int(-1)));
    assert_eq!(i.global("k"), Some(&Value::Float(5.0)));
}

#[test]
fn comparisons_logic_and_ieee_nan() {
    let i = globals_after_one_cycle(
        "a = 1 < 2 and 2 <= 2 and 3 > 2 and 3 >= 3 and 1 == 1.0 and 1 != 2\n\
         b = not (1 > 2) or x_undefined\nc = False and x_undefined\n\
         inf = 1e308 * 10\nd = inf > 0 and inf < 1000000\ne = 'ab' == \"ab\"\n\
         f = p[1,2,3,0,0,0] == p[1,2,3,0,0,0]\ng = [1, 2.0] == [1.0, 2]\n",
    );
    for (k, v) in [
        ("a", true),
        ("b", true),
        ("c", false),
        ("d", false),
        ("e", true),
        ("f", true),
        ("g", true),
    ] {
        assert_eq!(i.global(k), Some(&Value::Bool(v)), "{k}");
    }
    // NaN from a register: every comparison False, != True.
    let mut c = playing(
        "v = read_input_float_register(30)\n\
         write_output_boolean_register(0, v > 0 and v < 1000000)\n\
         write_output_boolean_register(1, v == v)\nwrite_output_boolean_register(2, v != v)\n\
         write_output_boolean_register(3, v <= 0 or v >= 0)\nwhile True:\n  sync()\nend\n",
    );
    c.in_double[30] = f64::NAN;
    let s = ticks(&mut c, 1);
    assert_eq!(s.output_bit_registers & 0b1111, 0b0100);
    assert_eq!(s.runtime_state, runtime_state::PLAYING);
}

#[test]
fn lists_poses_strings_and_indexed_assignment() {
    let i = globals_after_one_cycle(
        "l = [1, 2, [3, 4]]\nl[1] = 20\nx = l[2][1]\nq = p[0.1, 0.2, 0.3, 0, 0, 0]\nq[2] = 1\n\
         z = q[2] + q[0]\ns = to_str(3) \nt = to_str(p[1, 2, 3, 0, 0, 0.5])\nu = to_str([True, 'a'])\n",
    );
    assert_eq!(
        i.global("l"),
        Some(&Value::List(vec![
            Value::Int(1),
            Value::Int(20),
            Value::List(vec![Value::Int(3), Value::Int(4)])
        ]))
    );
    assert_eq!(i.global("x"), Some(&Value::Int(4)));
    assert_eq!(i.global("z"), Some(&Value::Float(1.1)));
    assert_eq!(i.global("s"), Some(&Value::Str("3".into())));
    assert_eq!(
        i.global("t"),
        Some(&Value::Str("p[1.0, 2.0, 3.0, 0.0, 0.0, 0.5]".into()))
    );
    assert_eq!(i.global("u"), Some(&Value::Str("[True, a]".into())));
}

#[test]
fn runtime_errors_name_their_line() {
    let cases: [(&str, u32, &str); 9] = [
        ("x = 1\ny = 2\nz = x + \"a\"\n", 3, "type error"),
        ("x = 2147483647\nx = x + 1\n", 2, "overflow"),
        ("x = 1 / 0\n", 1, "division by zero"),
        ("x = [1]\ny = x[1]\n", 2, "out of range"),
        ("if 1:\n  x = 0\nend\n", 1, "bool"),
        ("y = undefined + 1\n", 1, "not defined"),
        ("write_output_integer_register(48, 1)\n", 1, "out of range"),
        ("write_output_integer_register(24, 1.5)\n", 1, "type error"),
        ("x = read_input_float_register(-1)\n", 1, "out of range"),
    ];
    for (text, line, what) in cases {
        let e = runtime_error(text, 3);
        assert_eq!(e.line, line, "{text}: {e}");
        assert!(e.msg.contains(what), "{text}: {e}");
        assert_eq!(e.thread, "main");
    }
}

#[test]
fn registers_read_and_write() {
    let mut c = playing(
        "write_output_integer_register(24, read_input_integer_register(24) * 2)\n\
         write_output_float_register(47, read_input_float_register(0) + 1)\n\
         write_output_float_register(46, 3)\n\
         write_output_boolean_register(127, read_input_boolean_register(64))\n\
         while True:\n  sync()\nend\n",
    );
    c.in_int[24] = 21;
    c.in_double[0] = 0.5;
    c.in_bits = 1 << 64;
    let s = ticks(&mut c, 1);
    assert_eq!(s.output_int_registers[24], 42);
    assert_eq!(s.output_double_registers[47], 1.5);
    assert_eq!(s.output_double_registers[46], 3.0);
    assert_eq!(s.output_bit_registers, 1 << 127);
}

#[test]
fn control_flow_functions_scoping_and_recursion() {
    let i = globals_after_one_cycle(
        "def fact(n):\n  if n <= 1:\n    return 1\n  end\n  return n * fact(n - 1)\nend\n\
         def classify(x):\n  if x < 0:\n    return -1\n  elif x == 0:\n    return 0\n  else:\n    return 1\n  end\nend\n\
         def side():\n  g = g + 1\n  local g = 100\n  h = 5\n  global k = 7\nend\n\
         g = 1\nside()\nf = fact(5)\nc = [classify(-3), classify(0), classify(9)]\n\
         n = 0\ns = 0\nwhile True:\n  n = n + 1\n  if n % 2 == 0:\n    continue\n  end\n  if n > 9:\n    break\n  end\n  s = s + n\nend\n",
    );
    assert_eq!(i.global("f"), Some(&Value::Int(120)));
    assert_eq!(
        i.global("c"),
        Some(&Value::List(vec![
            Value::Int(-1),
            Value::Int(0),
            Value::Int(1)
        ]))
    );
    // `g = g + 1` in a function assigns the existing global; `local g` then shadows it;
    // `h` is local to the function; `global k` creates a global.
    assert_eq!(i.global("g"), Some(&Value::Int(2)));
    assert_eq!(i.global("h"), None);
    assert_eq!(i.global("k"), Some(&Value::Int(7)));
    assert_eq!(i.global("s"), Some(&Value::Int(1 + 3 + 5 + 7 + 9)));
    let e = runtime_error("def f(n):\n  return f(n + 1)\nend\nf(0)\n", 1);
    assert_eq!(e.line, 2);
    assert!(e.msg.contains("recursion"), "{e}");
}

#[test]
fn sync_yields_once_per_cycle_and_sleep_counts_controller_time() {
    let mut c = playing(
        "n = 0\nthread sleeper():\n  sleep(0.01)\n  write_output_integer_register(25, 1)\nend\n\
         run sleeper()\nwhile True:\n  n = n + 1\n  write_output_integer_register(24, n)\n  sync()\nend\n",
    );
    ticks(&mut c, 5);
    assert_eq!(out_int(&c, 24), 5);
    // sleep(0.01) from t = 2 ms: resumes at the first tick at or after 12 ms, the 6th.
    assert_eq!(out_int(&c, 25), 0);
    ticks(&mut c, 1);
    assert_eq!(out_int(&c, 24), 6);
    assert_eq!(out_int(&c, 25), 1);
}

#[test]
fn threads_run_join_kill_and_schedule_in_order() {
    let mut c = playing(
        "global log = 0\nthread a():\n  while True:\n    log = log * 10 + 1\n    sync()\n  end\nend\n\
         thread b():\n  log = log * 10 + 2\nend\n\
         ta = run a()\ntb = run b()\njoin tb\nwrite_output_integer_register(24, log)\n\
         kill ta\nx = log\nsync()\nsync()\nwrite_output_integer_register(25, log - x)\n\
         kill ta\nhalt\n",
    );
    // Cycle 1: main starts a and b, blocks in join; a runs (1), b runs (12) and ends.
    // Cycle 2: main resumes first (b ended), writes 12, kills a; a never runs again.
    ticks(&mut c, 2);
    assert_eq!(out_int(&c, 24), 12);
    ticks(&mut c, 3);
    assert_eq!(out_int(&c, 25), 0, "a killed thread ran");
    assert_eq!(
        c.runtime_state,
        runtime_state::STOPPED,
        "halt stops the program"
    );
}

#[test]
fn critical_sections_and_runaway_loops_are_errors() {
    let e = runtime_error("enter_critical\nx = 1\nsync()\nexit_critical\n", 2);
    assert_eq!(e.line, 3);
    assert!(e.msg.contains("enter_critical"), "{e}");
    let e = runtime_error("x = 0\nwhile True:\n  x = x + 1\nend\n", 2);
    assert_eq!(
        e.msg,
        "thread main ran 10000 statements in one cycle without sync(); a real controller would flag this as a runaway loop"
    );
    let e = runtime_error(
        "thread t():\n  while True:\n  end\nend\nrun t()\nwhile True:\n  sync()\nend\n",
        2,
    );
    assert_eq!(e.thread, "t");
    assert_eq!(e.line, 2);
    // In the controller: the program stops.
    let mut c = playing("while True:\n  x = 1\nend\n");
    ticks(&mut c, 1);
    assert_eq!(c.runtime_state, runtime_state::STOPPED);
}

#[test]
fn a_critical_section_is_not_interleaved() {
    let mut c = playing(
        "global x = 0\nthread t():\n  while True:\n    enter_critical\n    x = x + 1\n    y = x\n    x = x - 1\n    exit_critical\n    sync()\n  end\nend\n\
         run t()\nwhile True:\n  write_output_integer_register(24, x)\n  sync()\nend\n",
    );
    for _ in 0..5 {
        ticks(&mut c, 1);
        assert_eq!(out_int(&c, 24), 0);
    }
}

#[test]
fn the_program_ends_when_main_ends_and_a_defs_only_script_runs_its_first_def() {
    let mut c = playing("def prog():\n  write_output_integer_register(24, 7)\n  sync()\nend\n");
    ticks(&mut c, 1);
    assert_eq!(out_int(&c, 24), 7);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);
    ticks(&mut c, 1);
    assert_eq!(c.runtime_state, runtime_state::STOPPED);
    assert_eq!(c.program.as_ref().unwrap().name, "prog");
}

#[test]
fn watchdog_configuration_and_its_errors() {
    let mut c = playing(
        "rtde_set_watchdog(\"input_int_register_26\", 10.0, \"stop\")\n\
         rtde_set_watchdog(\"input_double_register_30\", 2)\n\
         rtde_set_watchdog(\"input_int_register_26\", 20.0, action=\"ignore\")\n\
         while True:\n  sync()\nend\n",
    );
    ticks(&mut c, 1);
    let w: Vec<_> = c
        .watchdogs
        .iter()
        .map(|w| (w.variable.as_str(), w.min_hz, w.action))
        .collect();
    assert_eq!(
        w,
        [
            ("input_double_register_30", 2.0, WatchdogAction::Pause),
            ("input_int_register_26", 20.0, WatchdogAction::Ignore)
        ]
    );
    let e = runtime_error("rtde_set_watchdog(\"output_int_register_24\", 10.0)\n", 1);
    assert!(e.msg.contains("not an RTDE input variable"), "{e}");
    let e = runtime_error(
        "rtde_set_watchdog(\"input_int_register_26\", 10.0, \"explode\")\n",
        1,
    );
    assert!(e.msg.contains("explode"), "{e}");
    // A 10 Hz "stop" watchdog with no heartbeat stops the program after 100 ms.
    let mut c = playing(
        "rtde_set_watchdog(\"input_int_register_26\", 10.0, \"stop\")\nwhile True:\n  sync()\nend\n",
    );
    ticks(&mut c, 50);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);
    ticks(&mut c, 1);
    assert_eq!(c.runtime_state, runtime_state::STOPPED);
}

#[test]
fn textmsg_and_math_builtins() {
    let i = globals_after_one_cycle(
        "textmsg(\"value: \", 3)\ntextmsg(\"alone\")\na = norm([3, 4])\nb = sqrt(16)\n\
         c = floor(-1.5)\nd = fabs(-2.5)\ne = norm(-2)\n",
    );
    assert_eq!(i.global("a"), Some(&Value::Float(5.0)));
    assert_eq!(i.global("b"), Some(&Value::Float(4.0)));
    assert_eq!(i.global("c"), Some(&Value::Int(-2)));
    assert_eq!(i.global("d"), Some(&Value::Float(2.5)));
    assert_eq!(i.global("e"), Some(&Value::Float(2.0)));
    assert!(runtime_error("x = sqrt(-1)\n", 1).msg.contains("negative"));
    assert!(runtime_error("x = floor(1e20)\n", 1).msg.contains("int"));
}

#[test]
fn completeness_of_uploads() {
    let rig = rig_core::urscript::program(10.0, None);
    assert!(is_complete(&rig));
    let cut = rig
        .rfind(&format!("{}()", rig_core::control::PROGRAM_NAME))
        .unwrap();
    // Up to the def's `end`: closed, but not complete (the call may follow).
    assert!(!is_complete(&rig[..cut]));
    assert!(is_closed(&rig[..cut]));
    for n in [10, 100, rig.len() / 2, rig.len() - 1] {
        assert!(!is_complete(&rig[..n]), "{n}");
    }
    assert!(is_complete("x = 1\n"));
    assert!(!is_complete("x = 1"));
    assert!(!is_complete("# only a comment\n"));
    assert!(!is_complete("def f():\n  x = \"end\"\n"));
}

/// A small deterministic generator (xorshift64*), so the fuzz test needs no dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

/// Runs a text that may or may not parse for a few cycles: must never panic.
fn try_everything(text: &str) {
    let _ = is_complete(text);
    let Ok(program) = Program::parse(text) else {
        return;
    };
    let mut c = controller_with_tool(Pose::default());
    c.upload(program, 0);
    c.in_double[24..30].copy_from_slice(&[0.3, -0.2, 0.29, 0.0, std::f64::consts::PI, 0.0]);
    c.in_double[30] = 0.1;
    c.in_double[31] = 1.0;
    c.in_int[24] = 1;
    c.in_int[25] = 1;
    ticks(&mut c, 3);
    c.in_int[24] = 2;
    c.in_int[25] = 2;
    ticks(&mut c, 3);
}

#[test]
fn malformed_scripts_never_panic() {
    let rig = rig_core::urscript::program(10.0, Some([0.0, 0.0, 0.1, 0.0, 0.0, 0.0]));
    // Every truncation of the rig's program.
    let cuts: Vec<usize> = rig.char_indices().map(|(i, _)| i).collect();
    for &n in cuts.iter().step_by(7) {
        try_everything(&rig[..n]);
    }
    // Random edits: deleted, duplicated and swapped lines, random characters.
    let lines: Vec<&str> = rig.lines().collect();
    let alphabet: Vec<char> = "()[]:,=<>!+-*/%#\"'p \n\tabcdefxyz0123456789.eE_"
        .chars()
        .collect();
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    for _ in 0..400 {
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        for _ in 0..1 + rng.below(3) {
            let i = rng.below(l.len());
            match rng.below(4) {
                0 => {
                    l.remove(i);
                }
                1 => {
                    let d = l[i].clone();
                    l.insert(i, d);
                }
                2 => {
                    let j = rng.below(l.len());
                    l.swap(i, j);
                }
                _ => {
                    let mut chars: Vec<char> = l[i].chars().collect();
                    let at = rng.below(chars.len() + 1);
                    chars.insert(at, alphabet[rng.below(alphabet.len())]);
                    l[i] = chars.into_iter().collect();
                }
            }
        }
        try_everything(&(l.join("\n") + "\n"));
    }
    // Pure noise.
    for _ in 0..200 {
        let len = rng.below(200);
        let s: String = (0..len)
            .map(|_| alphabet[rng.below(alphabet.len())])
            .collect();
        try_everything(&s);
    }
}
