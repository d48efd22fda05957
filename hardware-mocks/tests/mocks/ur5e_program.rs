//! The simulated UR5e running the rig's exact control program over real sockets: the physical
//! tool tip against the reported TCP, the command log, and uploads that do not compile.

use std::time::Duration;

use crate::common::eventually;
use crate::ur5e::{NO_WATCHDOG, command_client, command_values, send_command, upload};
use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use rig_core::clock::{Clock, ClockHandle};
use rig_core::control::{self, CommandKind, ProgramStatus, robot_mode, runtime_state};
use rig_core::pose::{Pose, translation_distance};

const TOOL: [f64; 6] = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0];

async fn mock_with_tool() -> (Ur5e, ClockHandle) {
    let (clock, handle) = Clock::manual();
    let cfg = Ur5eConfig {
        initial_robot_mode: robot_mode::RUNNING,
        tool_offset: Pose::from_array(TOOL),
        ..Ur5eConfig::default()
    };
    (Ur5e::start(cfg, clock).await.unwrap(), handle)
}

async fn play(ur: &Ur5e, h: &ClockHandle, text: &str) {
    upload(ur, text).await;
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    ur.step_ticks(h, 1).await;
}

#[tokio::test]
async fn the_tip_follows_the_tcp_the_program_sets_and_commands_are_logged_on_arrival() {
    let (ur, h) = mock_with_tool().await;
    play(
        &ur,
        &h,
        &rig_core::urscript::program(NO_WATCHDOG, Some(TOOL)),
    )
    .await;
    let (mut c, id) = command_client(&ur).await;
    let tcp0 = ur.snapshot().actual_tcp_pose;
    let t0 = ur.snapshot().t_ns;
    assert!(translation_distance(&ur.tip_pose_at(t0).unwrap().1, &tcp0) < 1e-12);
    let target = Pose {
        z: tcp0.z - 0.02,
        x: tcp0.x + 0.01,
        ..tcp0
    };
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(1, CommandKind::MoveL, target, 0.05, 0.5),
    )
    .await;
    let mut n = 0;
    while ur.snapshot().output_int_registers[control::OUT_DONE_SEQ as usize] != 1 {
        ur.step_ticks(&h, 1).await;
        n += 1;
        assert!(n < 1000, "the move never finished");
    }
    let t = ur.snapshot().t_ns;
    let (t_tcp, tcp) = ur.tcp_pose_at(t).unwrap();
    let (t_tip, tip) = ur.tip_pose_at(t).unwrap();
    assert_eq!((t_tcp, t_tip), (t, t));
    assert!(translation_distance(&tcp, &target) < 0.05e-3);
    assert!(translation_distance(&tip, &target) < 0.05e-3);

    // A long move, then a Stop: the log says when each command reached the controller.
    let far = Pose {
        x: target.x + 0.2,
        ..target
    };
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(2, CommandKind::MoveL, far, 0.25, 1.2),
    )
    .await;
    ur.step_ticks(&h, 100).await;
    let t_sent = ur.snapshot().t_ns;
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(3, CommandKind::Stop, far, 0.0, 3.0),
    )
    .await;
    ur.step_ticks(&h, 60).await;
    let s = ur.snapshot();
    assert_eq!(s.output_int_registers[control::OUT_DONE_SEQ as usize], 3);
    assert_eq!(
        s.output_int_registers[control::OUT_STATUS as usize],
        ProgramStatus::Idle as i32
    );
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    let log = ur.commands_received();
    let seqs: Vec<(i32, i32)> = log.iter().map(|r| (r.seq, r.kind)).collect();
    assert_eq!(seqs, [(1, 1), (2, 1), (3, 2)]);
    // On a manual clock the Stop arrived while the clock stood at t_sent.
    assert_eq!(log[2].t_ns, t_sent);
}

#[tokio::test]
async fn a_program_without_set_tcp_presses_with_the_flange() {
    let (ur, h) = mock_with_tool().await;
    play(&ur, &h, &rig_core::urscript::program(NO_WATCHDOG, None)).await;
    let (mut c, id) = command_client(&ur).await;
    let home = Ur5eConfig::default().home_pose;
    assert_eq!(ur.snapshot().actual_tcp_pose, home);
    let target = Pose {
        z: home.z - 0.02,
        ..home
    };
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(1, CommandKind::MoveL, target, 0.05, 0.5),
    )
    .await;
    ur.step_ticks(&h, 600).await;
    let t = ur.snapshot().t_ns;
    let tcp = ur.tcp_pose_at(t).unwrap().1;
    let tip = ur.tip_pose_at(t).unwrap().1;
    assert!(translation_distance(&tcp, &target) < 0.05e-3);
    // The tool points down: its tip is 100 mm below the commanded point.
    assert!((translation_distance(&tip, &target) - 0.1).abs() < 1e-9);
    assert!((tip.z - (target.z - 0.1)).abs() < 1e-9);
}

#[tokio::test]
async fn a_script_that_does_not_compile_is_not_started() {
    let (ur, h) = mock_with_tool().await;
    play(&ur, &h, &rig_core::urscript::program(NO_WATCHDOG, None)).await;
    upload(
        &ur,
        "def broken():\n  movel(p[0, 0, 0.3, 0, 3.14, 0]\nend\nbroken()\n",
    )
    .await;
    eventually("the program to stop", || {
        let s = ur.snapshot();
        s.runtime_state == runtime_state::STOPPED && !s.program_loaded
    })
    .await;
    // A script of definitions only, sent on a connection left open, runs after a quiet spell.
    let mut s = tokio::net::TcpStream::connect(ur.script_addr())
        .await
        .unwrap();
    tokio::io::AsyncWriteExt::write_all(
        &mut s,
        b"def prog():\n  while True:\n    write_output_integer_register(30, 5)\n    sync()\n  end\nend\n",
    )
    .await
    .unwrap();
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    ur.step_ticks(&h, 1).await;
    assert_eq!(ur.snapshot().output_int_registers[30], 5);
    tokio::time::sleep(Duration::from_millis(1)).await;
    drop(s);
}
