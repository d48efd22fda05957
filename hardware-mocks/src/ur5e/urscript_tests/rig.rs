//! The rig's own control program, exactly as `rig_core::urscript::program` writes it, run in
//! the controller with the command registers written as the rig writes them.

use rig_core::control::{self, CommandKind, ProgramStatus, runtime_state};
use rig_core::pose::{Pose, pose_trans, rotation_distance, translation_distance};
use rig_core::rtde::Value as Rtde;

use super::super::controller::Controller;
use super::super::urscript::Program;
use super::super::urscript::WatchdogAction;
use super::super::variables::{InputSink, resolve_input};
use super::{P, controller_with_tool, home, out_int};

const TCP: [f64; 6] = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0];

fn write(c: &mut Controller, names: &[String], values: &[Rtde]) {
    let sinks: Vec<InputSink> = names.iter().map(|n| resolve_input(n).unwrap()).collect();
    let t = c.t_ns;
    c.write_inputs(names, &sinks, values, t);
}

/// One command package as the rig sends it: seq, kind, target ×6, speed, accel.
fn command(c: &mut Controller, seq: i32, kind: i32, target: Pose, v: f64, a: f64) {
    let names = control::command_recipe();
    let mut vals = vec![Rtde::Int32(seq), Rtde::Int32(kind)];
    vals.extend(target.to_array().map(Rtde::Double));
    vals.push(Rtde::Double(v));
    vals.push(Rtde::Double(a));
    write(c, &names, &vals);
}

/// `n` ticks with the heartbeat written every 10 ms, as the rig's RTDE cycle does.
fn run(c: &mut Controller, n: u64) {
    let hb = vec![control::input_int(control::IN_HEARTBEAT)];
    for _ in 0..n {
        let t = c.t_ns + P;
        if (t / P).is_multiple_of(5) {
            write(c, &hb, &[Rtde::Int32((t / P) as i32)]);
        }
        c.tick(t);
    }
}

/// Ticks until OUT_DONE_SEQ is `seq` (at most `max`); the clock time then.
fn until_done(c: &mut Controller, seq: i32, max: u64) -> u64 {
    for _ in 0..max {
        run(c, 1);
        if out_int(c, control::OUT_DONE_SEQ as usize) == seq {
            return c.t_ns;
        }
    }
    panic!("command {seq} never done");
}

fn status(c: &Controller) -> i32 {
    out_int(c, control::OUT_STATUS as usize)
}

fn start(text: &str, tool: Pose) -> Controller {
    let mut c = controller_with_tool(tool);
    c.upload(Program::parse(text).unwrap(), 0);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);
    c
}

const MOVEL: i32 = CommandKind::MoveL as i32;

#[test]
fn the_rigs_program_moves_stops_and_rejects_through_the_registers() {
    let tool = Pose::from_array(TCP);
    let mut c = start(&rig_core::urscript::program(10.0, Some(TCP)), tool);
    // A stale command in the registers before the program's first cycle is not replayed.
    command(&mut c, 5, MOVEL, Pose { z: 0.1, ..home() }, 0.1, 1.0);
    run(&mut c, 1);
    assert_eq!(out_int(&c, control::OUT_ACK_SEQ as usize), 5);
    assert_eq!(out_int(&c, control::OUT_DONE_SEQ as usize), 5);
    assert_eq!(status(&c), ProgramStatus::Idle as i32);
    assert_eq!(c.watchdogs.len(), 1);
    assert_eq!(
        c.watchdogs[0].variable,
        control::input_int(control::IN_HEARTBEAT)
    );
    assert_eq!(
        (c.watchdogs[0].min_hz, c.watchdogs[0].action),
        (10.0, WatchdogAction::Stop)
    );
    // set_tcp: the reported TCP is the tool tip, 0.1 m below the flange (tool down).
    let tcp0 = c.snapshot().actual_tcp_pose;
    assert!((tcp0.z - 0.2).abs() < 1e-12);
    assert!(translation_distance(&tcp0, &c.tip_pose()) < 1e-12);
    run(&mut c, 20);
    assert_eq!(c.tcp_pose(), tcp0, "the stale command moved the arm");

    // MoveL: ack and Moving in the cycle that reads it, done when the TCP is on the target.
    let target = Pose::new(0.35, -0.15, 0.18, 0.0, std::f64::consts::PI, 0.0);
    command(&mut c, 6, MOVEL, target, 0.1, 1.0);
    run(&mut c, 1);
    let t_read = c.t_ns;
    assert_eq!(out_int(&c, control::OUT_ACK_SEQ as usize), 6);
    assert_eq!(status(&c), ProgramStatus::Moving as i32);
    let t_done = until_done(&mut c, 6, 2000);
    // L = √(0.05² + 0.05² + 0.02²), v²/a = 0.01 ≤ L: T = L/v + v/a.
    let l = (0.05f64 * 0.05 * 2.0 + 0.02 * 0.02).sqrt();
    let t = l / 0.1 + 0.1;
    let took = (t_done - t_read) as f64 * 1e-9;
    assert!(took >= t && took < t + 0.002, "{took} vs {t}");
    assert_eq!(status(&c), ProgramStatus::Idle as i32);
    let s = c.snapshot();
    assert!(translation_distance(&s.actual_tcp_pose, &target) < 0.05e-3);
    assert!(rotation_distance(&s.actual_tcp_pose, &target) < 1e-9);
    // The physical tip follows: the tool matches the program's TCP.
    assert!(translation_distance(&c.tip_pose(), &target) < 0.05e-3);

    // A long move, then Stop with a = 2 m/s² while cruising at 0.25 m/s.
    let far = Pose {
        x: target.x + 0.3,
        ..target
    };
    command(&mut c, 7, MOVEL, far, 0.25, 1.2);
    run(&mut c, 150);
    assert_eq!(status(&c), ProgramStatus::Moving as i32);
    command(&mut c, 8, CommandKind::Stop as i32, far, 0.0, 2.0);
    run(&mut c, 1);
    let at_stop = c.tcp_pose();
    assert!((c.snapshot().actual_tcp_speed[0] - 0.25).abs() < 1e-9);
    until_done(&mut c, 8, 200);
    assert_eq!(status(&c), ProgramStatus::Idle as i32);
    let s = c.snapshot();
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    let travelled = s.actual_tcp_pose.x - at_stop.x;
    assert!((travelled - 0.25 * 0.25 / 4.0).abs() < 1e-9, "{travelled}");
    run(&mut c, 50);
    assert_eq!(c.tcp_pose(), s.actual_tcp_pose, "moved after the stop");

    // Rejected: a NaN speed, an infinite acceleration, an unknown kind.
    for (seq, kind, v, a) in [
        (9, MOVEL, f64::NAN, 1.0),
        (10, MOVEL, 0.1, f64::INFINITY),
        (11, 7, 0.1, 1.0),
    ] {
        command(&mut c, seq, kind, target, v, a);
        run(&mut c, 1);
        assert_eq!(out_int(&c, control::OUT_DONE_SEQ as usize), seq);
        assert_eq!(status(&c), ProgramStatus::Rejected as i32);
    }
    run(&mut c, 100);
    assert_eq!(c.tcp_pose(), s.actual_tcp_pose);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);

    // Every command package was logged with its kind and arrival time.
    let log: Vec<(i32, i32)> = c
        .commands_received()
        .iter()
        .map(|r| (r.seq, r.kind))
        .collect();
    assert_eq!(
        log,
        [(5, 1), (6, 1), (7, 1), (8, 2), (9, 1), (10, 1), (11, 7)]
    );
    assert_eq!(c.commands_received()[1].t_ns, t_read - P);
}

#[test]
fn without_its_movel_line_the_program_does_not_move() {
    let full = rig_core::urscript::program(10.0, None);
    let text: String = full
        .lines()
        .filter(|l| !l.trim_start().starts_with("movel("))
        .map(|l| format!("{l}\n"))
        .collect();
    assert_eq!(text.lines().count() + 1, full.lines().count());
    for (program, moves) in [(full, true), (text, false)] {
        let mut c = start(&program, Pose::default());
        run(&mut c, 1);
        let target = Pose {
            z: home().z - 0.05,
            ..home()
        };
        command(&mut c, 1, MOVEL, target, 0.1, 1.0);
        // T = 0.05/0.1 + 0.1/1 = 0.6 s: 300 ticks, and some.
        run(&mut c, 320);
        let reached = translation_distance(&c.tcp_pose(), &target) < 0.05e-3;
        assert_eq!(reached, moves);
        if !moves {
            assert_eq!(c.tcp_pose(), home());
        }
    }
}

#[test]
fn without_set_tcp_the_physical_tip_misses_by_the_tool_length() {
    // The tool is 100 mm long but the program does not set the TCP: it steers the flange.
    let tool = Pose::new(0.0, 0.0, 0.1, 0.0, 0.0, 0.0);
    let mut c = start(&rig_core::urscript::program(10.0, None), tool);
    run(&mut c, 1);
    let target = Pose { z: 0.25, ..home() };
    command(&mut c, 1, MOVEL, target, 0.1, 1.0);
    until_done(&mut c, 1, 1000);
    assert!(translation_distance(&c.tcp_pose(), &target) < 0.05e-3);
    let miss = translation_distance(&c.tip_pose(), &target);
    assert!((miss - 0.1).abs() < 1e-9, "{miss}");
    assert!(translation_distance(&c.tip_pose(), &pose_trans(&target, &tool)) < 1e-9);
    // With set_tcp matching the tool, the same command puts the tip on the target.
    let mut c = start(&rig_core::urscript::program(10.0, Some(TCP)), tool);
    run(&mut c, 1);
    command(&mut c, 1, MOVEL, target, 0.1, 1.0);
    until_done(&mut c, 1, 1000);
    assert!(translation_distance(&c.tip_pose(), &target) < 0.05e-3);
}

#[test]
fn the_watchdog_the_program_arms_stops_it_when_the_heartbeat_stops() {
    let mut c = start(&rig_core::urscript::program(10.0, None), Pose::default());
    run(&mut c, 10);
    let far = Pose {
        x: home().x + 0.5,
        ..home()
    };
    command(&mut c, 1, MOVEL, far, 0.25, 1.2);
    run(&mut c, 200);
    assert_eq!(c.runtime_state, runtime_state::PLAYING);
    // Silence: the last beat was at most 8 ms ago; 100 ms later the watchdog fires.
    let mut ticks = 0;
    while c.runtime_state == runtime_state::PLAYING {
        let t = c.t_ns + P;
        c.tick(t);
        ticks += 1;
        assert!(ticks <= 50, "the watchdog never fired");
    }
    assert!(ticks >= 46, "{ticks}");
    for _ in 0..100 {
        let t = c.t_ns + P;
        c.tick(t);
    }
    assert_eq!(c.snapshot().actual_tcp_speed, [0.0; 6]);
    assert!(c.tcp_pose().x < far.x);
    assert_ne!(out_int(&c, control::OUT_DONE_SEQ as usize), 1);
}
