//! Motion built-ins in the controller: `movel` on the trapezoid, `stopl` distances, killed
//! movers, `set_tcp` and the pose functions, runtime errors mid-move, refused uploads, pause
//! and resume, restart.

use rig_core::control::runtime_state;
use rig_core::pose::{Pose, rotation_distance, translation_distance};

use super::super::controller::CONTROLLER_STOP_DECEL;
use super::super::urscript::Program;
use super::{P, controller_with_tool, home, out_float, out_int, playing, ticks};

const PI: &str = "3.141592653589793";

/// s(t) of a trapezoid cruising at `v` after accelerating with `a` (t past the ramp).
fn cruise_s(v: f64, a: f64, t: f64) -> f64 {
    let ta = v / a;
    0.5 * v * ta + v * (t - ta)
}

#[test]
fn movel_with_default_a_and_v_follows_the_trapezoid() {
    let mut c = playing(&format!(
        "movel(p[0.4, -0.2, 0.3, 0, {PI}, 0])\nwrite_output_integer_register(24, 1)\nwhile True:\n  sync()\nend\n"
    ));
    // Started at tick 1 (t = 2 ms). a = 1.2, v = 0.25 (the manual's defaults), L = 0.1 m:
    // T = L/v + v/a = 0.608333 s; 0.1 s in, x = ½·a·t² = 6 mm and the speed is a·t.
    let s = ticks(&mut c, 51);
    assert!(
        (s.actual_tcp_pose.x - 0.306).abs() < 1e-12,
        "{}",
        s.actual_tcp_pose.x
    );
    assert!((s.actual_tcp_speed[0] - 0.12).abs() < 1e-12);
    // Done at the first tick at or after 2 ms + T = 610.33 ms: tick 306 (612 ms).
    ticks(&mut c, 254);
    assert_eq!(out_int(&c, 24), 0);
    let s = ticks(&mut c, 1);
    assert_eq!(out_int(&c, 24), 1);
    assert_eq!(s.actual_tcp_pose, Pose { x: 0.4, ..home() });
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
}

#[test]
fn movel_refuses_bad_parameters_with_an_error_that_stops_the_program() {
    let target = format!("p[0.4, -0.2, 0.3, 0, {PI}, 0]");
    for (call, what) in [
        (format!("movel({target}, a=0, v=0.1)"), "positive a and v"),
        (format!("movel({target}, a=1, v=-0.1)"), "positive a and v"),
        (
            format!("movel({target}, a=0.0/0.0, v=0.1)"),
            "positive a and v",
        ),
        (format!("movel({target}, t=2)"), "not supported"),
        (format!("movel({target}, r=0.01)"), "not supported"),
        (
            "movel(p[1e308 * 10, 0, 0, 0, 0, 0])".to_owned(),
            "non-finite",
        ),
        ("movel([0, 0, 0, 0, 0, 0])".to_owned(), "joint positions"),
        ("movel(3)".to_owned(), "type error"),
        ("stopl(0)".to_owned(), "positive a"),
        (
            "set_tcp(p[0, 0, 1e308 * 10, 0, 0, 0])".to_owned(),
            "non-finite",
        ),
    ] {
        let text = format!("x = 1\n{call}\n");
        let e = super::runtime_error(&text, 1);
        assert_eq!(e.line, 2, "{call}: {e}");
        assert!(e.msg.contains(what), "{call}: {e}");
        let mut c = playing(&text);
        let s = ticks(&mut c, 3);
        assert_eq!(s.runtime_state, runtime_state::STOPPED, "{call}");
        assert_eq!(s.actual_tcp_pose, home(), "{call}");
    }
}

#[test]
fn stopl_decelerates_a_killed_mover_over_v2_over_2a() {
    let mut c = playing(&format!(
        "thread mover():\n  movel(p[1.3, -0.2, 0.3, 0, {PI}, 0], a=1.2, v=0.25)\nend\n\
         h = run mover()\nsleep(0.4)\nkill h\nstopl(2.0)\nwrite_output_integer_register(24, 1)\n\
         while True:\n  sync()\nend\n"
    ));
    // The move starts at 2 ms; main wakes at 402 ms (tick 201), 0.4 s into the move, cruising.
    let s = ticks(&mut c, 201);
    let s0 = cruise_s(0.25, 1.2, 0.4);
    assert!((s.actual_tcp_pose.x - (0.3 + s0)).abs() < 1e-12);
    // stopl(2.0) from 0.25 m/s: 0.125 s (at rest at 527 ms: tick 264) and 0.25²/(2·2) m.
    ticks(&mut c, 62);
    assert_eq!(out_int(&c, 24), 0);
    let s = ticks(&mut c, 1);
    assert_eq!(out_int(&c, 24), 1);
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    let expected = 0.3 + s0 + 0.25 * 0.25 / (2.0 * 2.0);
    assert!(
        (s.actual_tcp_pose.x - expected).abs() < 1e-12,
        "{}",
        s.actual_tcp_pose.x
    );
    ticks(&mut c, 100);
    assert!((c.tcp_pose().x - expected).abs() < 1e-12);
}

#[test]
fn a_killed_mover_leaves_its_motion_running_to_the_target() {
    let mut c = playing(&format!(
        "thread mover():\n  movel(p[0.4, -0.2, 0.3, 0, {PI}, 0], a=1.2, v=0.25)\n  write_output_integer_register(24, 1)\nend\n\
         h = run mover()\nsleep(0.1)\nkill h\nwhile True:\n  sync()\nend\n"
    ));
    let s = ticks(&mut c, 400);
    assert_eq!(s.actual_tcp_pose, Pose { x: 0.4, ..home() });
    assert_eq!(out_int(&c, 24), 0, "the killed thread went on");
    assert_eq!(s.runtime_state, runtime_state::PLAYING);
}

#[test]
fn set_tcp_moves_the_reported_pose_and_movel_targets_the_tcp() {
    let tool = Pose::new(0.0, 0.0, 0.1, 0.0, 0.0, 0.0);
    let mut c = controller_with_tool(tool);
    let text = format!(
        "set_tcp(p[0, 0, 0.1, 0, 0, 0])\nq = get_actual_tcp_pose()\nt = get_target_tcp_pose()\n\
         write_output_float_register(24, q[0])\nwrite_output_float_register(25, q[1])\n\
         write_output_float_register(26, q[2])\nwrite_output_float_register(27, get_tcp_offset()[2])\n\
         write_output_float_register(28, t[2])\n\
         movel(p[0.3, -0.2, 0.15, 0, {PI}, 0], a=1.0, v=0.1)\nwrite_output_integer_register(24, 1)\n\
         while True:\n  sync()\nend\n"
    );
    c.upload(Program::parse(&text).unwrap(), 0);
    // Before the program runs: no offset, the TCP is the flange, the tip 0.1 m below it (the
    // tool points down: R = rot_y(π) takes (0, 0, 0.1) to (0, 0, −0.1)).
    assert_eq!(c.tcp_pose(), home());
    assert!((c.tip_pose().z - 0.2).abs() < 1e-12);
    ticks(&mut c, 1);
    assert!((out_float(&c, 24) - 0.3).abs() < 1e-12);
    assert!((out_float(&c, 25) + 0.2).abs() < 1e-12);
    assert!((out_float(&c, 26) - 0.2).abs() < 1e-12);
    assert_eq!(out_float(&c, 27), 0.1);
    assert!((out_float(&c, 28) - 0.2).abs() < 1e-12);
    // L = 0.05 m, v = 0.1, a = 1: T = 0.5 + 0.1 = 0.6 s from 2 ms: done at tick 301.
    ticks(&mut c, 299);
    assert_eq!(out_int(&c, 24), 0);
    let s = ticks(&mut c, 1);
    assert_eq!(out_int(&c, 24), 1);
    let target = Pose { z: 0.15, ..home() };
    assert!(translation_distance(&s.actual_tcp_pose, &target) < 1e-12);
    assert!(rotation_distance(&s.actual_tcp_pose, &target) < 1e-12);
    assert!((c.flange_pose().z - 0.25).abs() < 1e-12);
    // The tool matches the TCP: the tip is where the TCP is.
    assert!(translation_distance(&c.tip_pose(), &target) < 1e-12);
}

#[test]
fn pose_functions_match_hand_computed_values() {
    let mut c = playing(
        "a = pose_trans(p[1, 0, 0, 0, 0, 1.5707963267948966], p[1, 0, 0, 0, 0, 0])\n\
         b = pose_inv(p[1, 2, 3, 0, 0, 1.5707963267948966])\n\
         c = pose_add(p[1, 2, 3, 0, 0, 0.1], p[1, 1, 1, 0, 0, 0.2])\n\
         d = pose_sub(p[2, 3, 4, 0, 0, 0.3], p[1, 1, 1, 0, 0, 0.2])\n\
         i = 0\nwhile i < 6:\n  write_output_float_register(i, a[i])\n  write_output_float_register(6 + i, b[i])\n\
           write_output_float_register(12 + i, c[i])\n  write_output_float_register(18 + i, d[i])\n  i = i + 1\nend\n\
         write_output_float_register(24, pose_dist(p[0, 0, 0, 0, 0, 0], p[3, 4, 0, 1, 0, 0]))\n",
    );
    ticks(&mut c, 1);
    let h = std::f64::consts::FRAC_PI_2;
    let expected: [[f64; 6]; 4] = [
        // Rotated 90° about z, then 1 m along the new x (the old y).
        [1.0, 1.0, 0.0, 0.0, 0.0, h],
        // −Rᵀ·t with Rᵀ = rot_z(−90°): (1, 2, 3) → (2, −1, 3).
        [-2.0, 1.0, -3.0, 0.0, 0.0, -h],
        [2.0, 3.0, 4.0, 0.0, 0.0, 0.3],
        [1.0, 2.0, 3.0, 0.0, 0.0, 0.1],
    ];
    for (k, row) in expected.iter().enumerate() {
        for (j, e) in row.iter().enumerate() {
            let got = out_float(&c, 6 * k + j);
            assert!((got - e).abs() < 1e-12, "pose {k} [{j}]: {got} vs {e}");
        }
    }
    assert_eq!(out_float(&c, 24), 5.0);
    assert_eq!(c.runtime_state, runtime_state::STOPPED, "the script ended");
}

#[test]
fn a_runtime_error_mid_move_stops_the_program_with_the_controller_deceleration() {
    let mut c = playing(&format!(
        "thread mover():\n  movel(p[1.3, -0.2, 0.3, 0, {PI}, 0], a=1.2, v=0.25)\nend\n\
         run mover()\nsleep(0.4)\nwrite_output_integer_register(48, 1)\n"
    ));
    ticks(&mut c, 200);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);
    let s = ticks(&mut c, 1);
    assert_eq!(s.runtime_state, runtime_state::STOPPED);
    let s = ticks(&mut c, 200);
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    let expected = 0.3 + cruise_s(0.25, 1.2, 0.4) + 0.25 * 0.25 / (2.0 * CONTROLLER_STOP_DECEL);
    assert!(
        (s.actual_tcp_pose.x - expected).abs() < 1e-12,
        "{}",
        s.actual_tcp_pose.x
    );
}

#[test]
fn an_upload_that_does_not_compile_stops_the_running_program_and_starts_nothing() {
    let mut c = playing(&format!(
        "movel(p[1.3, -0.2, 0.3, 0, {PI}, 0], a=1.2, v=0.25)\n"
    ));
    ticks(&mut c, 200);
    let err = Program::parse("def f():\n  for i in [1, 2]:\n    sync()\n  end\nend\n").unwrap_err();
    assert!(err.to_string().starts_with("line 2:"), "{err}");
    let t = c.t_ns;
    c.refuse_upload(t);
    let s = ticks(&mut c, 100);
    assert_eq!(s.runtime_state, runtime_state::STOPPED);
    assert!(!s.program_loaded);
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    let expected = 0.3 + cruise_s(0.25, 1.2, 0.398) + 0.25 * 0.25 / (2.0 * CONTROLLER_STOP_DECEL);
    assert!((s.actual_tcp_pose.x - expected).abs() < 1e-12);
    assert_eq!(c.start_program(s.t_ns), Err("no program loaded".into()));
}

#[test]
fn pause_keeps_the_program_and_resume_finishes_the_interrupted_movel() {
    let mut c = playing(&format!(
        "n = 1\nmovel(p[0.4, -0.2, 0.3, 0, {PI}, 0], a=1.2, v=0.25)\nwrite_output_integer_register(24, n)\n\
         while True:\n  sync()\nend\n"
    ));
    ticks(&mut c, 100);
    let t = c.t_ns;
    c.pause_program(t);
    let s = ticks(&mut c, 200);
    assert_eq!(s.runtime_state, runtime_state::PAUSED);
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    assert!(s.actual_tcp_pose.x < 0.4);
    assert_eq!(out_int(&c, 24), 0);
    let t = c.t_ns;
    c.resume_program(t).unwrap();
    let s = ticks(&mut c, 600);
    assert_eq!(out_int(&c, 24), 1);
    assert_eq!(s.actual_tcp_pose, Pose { x: 0.4, ..home() });
}

#[test]
fn play_restarts_the_program_from_its_first_statement() {
    let mut c = playing(
        "n = 0\nwhile True:\n  n = n + 1\n  write_output_integer_register(24, n)\n  sync()\nend\n",
    );
    ticks(&mut c, 10);
    assert_eq!(out_int(&c, 24), 10);
    let t = c.t_ns;
    c.start_program(t).unwrap();
    ticks(&mut c, 3);
    assert_eq!(out_int(&c, 24), 3);
    assert_eq!(c.t_ns, 13 * P);
}
