//! The simulated UR5e over real TCP on loopback, driven by a raw codec client, with a manual
//! clock wherever timing is asserted.

use crate::common;

use std::time::Duration;

use common::{RawClient, eventually};
use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use rig_core::clock::{Clock, ClockHandle};
use rig_core::control::{self, CommandKind, ProgramStatus, robot_mode, runtime_state, safety_mode};
use rig_core::pose::Pose;
use rig_core::rtde::{ClientPackage, DataType, FieldType, ServerPackage, Value};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;

const QUIET: Duration = Duration::from_millis(300);

async fn running_mock() -> (Ur5e, ClockHandle) {
    let (clock, handle) = Clock::manual();
    let cfg = Ur5eConfig {
        initial_robot_mode: robot_mode::RUNNING,
        ..Ur5eConfig::default()
    };
    (Ur5e::start(cfg, clock).await.unwrap(), handle)
}

/// The rig's own control program (the exact text the rig uploads). Tests that write no
/// heartbeat arm its watchdog at 0.01 Hz (100 s of silence allowed); the watchdog test uses the
/// rig's 10 Hz.
pub(crate) fn program(watchdog_min_hz: f64) -> String {
    rig_core::urscript::program(watchdog_min_hz, None)
}

pub(crate) const NO_WATCHDOG: f64 = 0.01;

pub(crate) async fn upload(ur: &Ur5e, text: &str) {
    let mut s = TcpStream::connect(ur.script_addr()).await.unwrap();
    s.write_all(text.as_bytes()).await.unwrap();
    s.shutdown().await.unwrap();
}

struct Dashboard {
    lines: tokio::io::Lines<BufReader<tokio::net::tcp::OwnedReadHalf>>,
    wr: tokio::net::tcp::OwnedWriteHalf,
}

impl Dashboard {
    async fn connect(ur: &Ur5e) -> Self {
        let (rd, wr) = TcpStream::connect(ur.dashboard_addr())
            .await
            .unwrap()
            .into_split();
        let mut d = Self {
            lines: BufReader::new(rd).lines(),
            wr,
        };
        let greeting = d.lines.next_line().await.unwrap().unwrap();
        assert_eq!(greeting, "Connected: Universal Robots Dashboard Server");
        d
    }
    async fn cmd(&mut self, c: &str) -> String {
        self.wr
            .write_all(format!("{c}\n").as_bytes())
            .await
            .unwrap();
        self.lines.next_line().await.unwrap().unwrap()
    }
}

/// One command's values, in [`control::command_recipe`] order.
pub(crate) fn command_values(
    seq: i32,
    kind: CommandKind,
    target: Pose,
    v: f64,
    a: f64,
) -> Vec<Value> {
    let mut vals = vec![Value::Int32(seq), Value::Int32(kind as i32)];
    vals.extend(target.to_array().map(Value::Double));
    vals.push(Value::Double(v));
    vals.push(Value::Double(a));
    vals
}

pub(crate) async fn command_client(ur: &Ur5e) -> (RawClient, u8) {
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.handshake(2).await;
    let names = control::command_recipe();
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let (id, types) = c.setup_inputs(&refs).await;
    assert!(id >= 1, "{types:?}");
    (c, id)
}

pub(crate) async fn send_command(ur: &Ur5e, c: &mut RawClient, id: u8, vals: &[Value]) {
    let seq = match vals[0] {
        Value::Int32(s) => s,
        _ => unreachable!(),
    };
    c.write_inputs(id, vals).await;
    eventually("the command registers to be written", || {
        ur.snapshot().input_int_registers[control::IN_CMD_SEQ as usize] == seq
    })
    .await;
}

#[tokio::test]
async fn handshake_v2_reports_the_e_series_version_and_an_output_recipe() {
    let (ur, _h) = running_mock().await;
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.send(ClientPackage::RequestProtocolVersion(3)).await;
    assert_eq!(
        c.recv_reply().await,
        ServerPackage::ProtocolVersion { accepted: false }
    );
    assert_eq!(c.handshake(2).await, (5, 15, 0, 0));
    let (id, types) = c
        .setup_outputs(
            500.0,
            &[
                "timestamp",
                "actual_TCP_pose",
                "robot_mode",
                "runtime_state",
            ],
        )
        .await;
    assert_eq!(id, Some(1));
    assert_eq!(
        types,
        [
            DataType::Double,
            DataType::Vector6d,
            DataType::Int32,
            DataType::Uint32
        ]
        .map(FieldType::Known)
    );
    assert!(c.start().await);
}

#[tokio::test]
async fn handshake_v1_streams_at_125_hz_without_recipe_ids() {
    let (ur, h) = running_mock().await;
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.handshake(1).await;
    // v1 output setup has no frequency and its reply no recipe id.
    let (id, types) = c
        .setup_outputs(0.0, &["timestamp", "actual_TCP_pose"])
        .await;
    assert_eq!(id, None);
    assert!(c.start().await);
    ur.step_ticks(&h, 8).await;
    // 8 ticks at 500 Hz are 2 packages at 125 Hz.
    let data = c.collect_exactly(&types, 2, QUIET).await;
    let home = Ur5eConfig::default().home_pose.to_array();
    assert_eq!(data[0][1], Value::Vector6d(home));
}

#[tokio::test]
async fn not_found_and_in_use_across_connections_and_release_on_disconnect() {
    let (ur, _h) = running_mock().await;
    let mut a = RawClient::connect(ur.rtde_addr()).await;
    a.handshake(2).await;
    let (id, types) = a
        .setup_inputs(&["input_int_register_24", "no_such_input"])
        .await;
    assert_eq!(id, 0);
    assert_eq!(
        types,
        vec![FieldType::Known(DataType::Int32), FieldType::NotFound]
    );
    let (id_a, _) = a.setup_inputs(&["input_int_register_24"]).await;
    assert_eq!(id_a, 1);
    // The same connection may use its own variable in a second recipe.
    let (id_a2, _) = a
        .setup_inputs(&["input_int_register_24", "input_double_register_30"])
        .await;
    assert_eq!(id_a2, 2);
    // Outputs: unknown names are NOT_FOUND and the recipe is refused.
    let (oid, otypes) = a
        .setup_outputs(500.0, &["timestamp", "actual_tcp_pose"])
        .await;
    assert_eq!(oid, Some(0));
    assert_eq!(otypes[1], FieldType::NotFound);

    let mut b = RawClient::connect(ur.rtde_addr()).await;
    b.handshake(2).await;
    let (id, types) = b
        .setup_inputs(&["input_int_register_24", "input_int_register_25"])
        .await;
    assert_eq!(id, 0);
    assert_eq!(
        types,
        vec![FieldType::InUse, FieldType::Known(DataType::Int32)]
    );

    drop(a);
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    loop {
        let (id, types) = b.setup_inputs(&["input_int_register_24"]).await;
        if id != 0 {
            assert_eq!(types, vec![FieldType::Known(DataType::Int32)]);
            break;
        }
        assert_eq!(types, vec![FieldType::InUse]);
        assert!(tokio::time::Instant::now() < deadline, "never released");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
}

#[tokio::test]
async fn start_is_refused_without_a_valid_output_recipe() {
    let (ur, _h) = running_mock().await;
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.handshake(2).await;
    assert!(!c.start().await);
    // 600 Hz is above the e-Series limit: id 0 and a text message saying why.
    c.send(ClientPackage::SetupOutputs {
        frequency_hz: 600.0,
        names: vec!["timestamp".into()],
    })
    .await;
    match c.recv().await {
        ServerPackage::TextMessage(m) => assert!(m.message.contains("600"), "{}", m.message),
        other => panic!("expected a text message first, got {other:?}"),
    }
    match c.recv().await {
        ServerPackage::OutputSetup { recipe_id, .. } => assert_eq!(recipe_id, Some(0)),
        other => panic!("{other:?}"),
    }
    assert!(!c.start().await);
    assert_eq!(c.setup_outputs(500.0, &["timestamp"]).await.0, Some(1));
    assert!(c.start().await);
}

#[tokio::test]
async fn data_packages_follow_controller_ticks_at_500_and_125_hz() {
    let (ur, h) = running_mock().await;
    let mut fast = RawClient::connect(ur.rtde_addr()).await;
    fast.handshake(2).await;
    let (_, fast_types) = fast
        .setup_outputs(500.0, &["timestamp", "robot_mode"])
        .await;
    assert!(fast.start().await);
    let mut slow = RawClient::connect(ur.rtde_addr()).await;
    slow.handshake(2).await;
    let (_, slow_types) = slow.setup_outputs(125.0, &["timestamp"]).await;
    assert!(slow.start().await);

    let n = 200;
    ur.step_ticks(&h, n).await;
    let f = fast.collect_exactly(&fast_types, n as usize, QUIET).await;
    let s = slow
        .collect_exactly(&slow_types, n as usize / 4, QUIET)
        .await;
    let ts =
        |rows: &[Vec<Value>]| -> Vec<f64> { rows.iter().map(|r| r[0].as_f64().unwrap()).collect() };
    for w in ts(&f).windows(2) {
        assert!((w[1] - w[0] - 0.002).abs() < 1e-9, "{w:?}");
    }
    for w in ts(&s).windows(2) {
        assert!((w[1] - w[0] - 0.008).abs() < 1e-9, "{w:?}");
    }
    assert_eq!(f[0][1], Value::Int32(robot_mode::RUNNING));
    assert_eq!(ur.snapshot().data_packages_sent, n + n / 4);
}

#[tokio::test]
async fn movel_through_the_program_follows_the_trapezoid() {
    let (ur, h) = running_mock().await;
    upload(&ur, &program(NO_WATCHDOG)).await;
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    // The program's first cycle takes the current seq as already done (as the rig waits for
    // before its first command).
    ur.step_ticks(&h, 1).await;
    let (mut c, id) = command_client(&ur).await;
    let home = Ur5eConfig::default().home_pose;
    let target = Pose {
        x: home.x + 0.1,
        ..home
    };
    // L = 0.1 m, v = 0.25 m/s, a = 1.2 m/s²: v²/a = 0.052 m ≤ L, so a trapezoid of
    // T = L/v + v/a = 0.4 + 0.208333 = 0.608333 s; done at the first 2 ms tick after that,
    // 305 ticks after the start tick.
    let (v, a) = (0.25, 1.2);
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(1, CommandKind::MoveL, target, v, a),
    )
    .await;
    ur.step_ticks(&h, 1).await;
    let s0 = ur.snapshot();
    assert_eq!(s0.output_int_registers[control::OUT_ACK_SEQ as usize], 1);
    assert_eq!(
        s0.output_int_registers[control::OUT_STATUS as usize],
        ProgramStatus::Moving as i32
    );
    assert_eq!(s0.actual_tcp_pose, home);
    let t_start = s0.t_ns;
    let mut peak: f64 = 0.0;
    let mut ticks = 0u64;
    loop {
        ur.step_ticks(&h, 1).await;
        ticks += 1;
        let s = ur.snapshot();
        let sp = s.actual_tcp_speed;
        peak = peak.max((sp[0] * sp[0] + sp[1] * sp[1] + sp[2] * sp[2]).sqrt());
        if ticks == 50 {
            // 0.1 s into the acceleration phase: x = ½·a·t² = 6 mm.
            assert!((s.actual_tcp_pose.x - (home.x + 0.006)).abs() < 1e-12);
            assert!((sp[0] - 0.12).abs() < 1e-12);
        }
        if s.output_int_registers[control::OUT_DONE_SEQ as usize] == 1 {
            assert_eq!(s.t_ns - t_start, 305 * 2_000_000);
            assert_eq!(s.actual_tcp_pose, target);
            assert_eq!(s.actual_tcp_speed, [0.0; 6]);
            assert_eq!(
                s.output_int_registers[control::OUT_STATUS as usize],
                ProgramStatus::Idle as i32
            );
            break;
        }
        assert!(ticks < 400, "move never finished");
    }
    assert!((peak - v).abs() < 1e-12, "peak speed {peak}");

    // A non-positive speed is rejected and marked done.
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(2, CommandKind::MoveL, home, 0.0, a),
    )
    .await;
    ur.step_ticks(&h, 1).await;
    let s = ur.snapshot();
    assert_eq!(s.output_int_registers[control::OUT_DONE_SEQ as usize], 2);
    assert_eq!(
        s.output_int_registers[control::OUT_STATUS as usize],
        ProgramStatus::Rejected as i32
    );
    assert_eq!(s.actual_tcp_pose, target);
}

#[tokio::test]
async fn program_start_does_not_replay_a_stale_command() {
    let (ur, h) = running_mock().await;
    let (mut c, id) = command_client(&ur).await;
    let home = Ur5eConfig::default().home_pose;
    let target = Pose {
        z: home.z - 0.05,
        ..home
    };
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(7, CommandKind::MoveL, target, 0.1, 1.0),
    )
    .await;
    upload(&ur, &program(NO_WATCHDOG)).await;
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    ur.step_ticks(&h, 20).await;
    let s = ur.snapshot();
    assert_eq!(s.output_int_registers[control::OUT_ACK_SEQ as usize], 7);
    assert_eq!(s.output_int_registers[control::OUT_DONE_SEQ as usize], 7);
    assert_eq!(s.actual_tcp_pose, home);
}

#[tokio::test]
async fn watchdog_stops_the_program_when_heartbeats_stop() {
    let (ur, h) = running_mock().await;
    let hb = control::input_int(control::IN_HEARTBEAT);
    upload(&ur, &program(control::WATCHDOG_MIN_HZ)).await;
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.handshake(2).await;
    let (id, _) = c.setup_inputs(&[&hb]).await;
    assert_eq!(id, 1);
    // Heartbeats every 40 ms for 0.4 s keep it playing.
    for beat in 1..=10 {
        c.write_inputs(id, &[Value::Int32(beat)]).await;
        eventually("the heartbeat to land", || {
            ur.snapshot().input_int_registers[control::IN_HEARTBEAT as usize] == beat
        })
        .await;
        ur.step_ticks(&h, 20).await;
        assert_eq!(ur.snapshot().runtime_state, runtime_state::PLAYING);
    }
    // Silence: at 10 Hz the watchdog allows 100 ms. 20 ticks (40 ms) already passed since the
    // last beat; 30 more (100 ms in all) is still in time, the next tick is not.
    ur.step_ticks(&h, 30).await;
    assert_eq!(ur.snapshot().runtime_state, runtime_state::PLAYING);
    ur.step_ticks(&h, 1).await;
    assert_eq!(ur.snapshot().runtime_state, runtime_state::STOPPED);
}

#[tokio::test]
async fn protective_stop_mid_move_and_the_unlock_delay() {
    let (ur, h) = running_mock().await;
    upload(&ur, &program(NO_WATCHDOG)).await;
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    // The program's first cycle takes the current seq as already done (as the rig waits for
    // before its first command).
    ur.step_ticks(&h, 1).await;
    let (mut c, id) = command_client(&ur).await;
    let home = Ur5eConfig::default().home_pose;
    let target = Pose {
        y: home.y + 0.2,
        ..home
    };
    send_command(
        &ur,
        &mut c,
        id,
        &command_values(1, CommandKind::MoveL, target, 0.25, 1.2),
    )
    .await;
    ur.step_ticks(&h, 200).await; // cruising at 0.25 m/s
    let before = ur.snapshot();
    assert!((before.actual_tcp_speed[1] - 0.25).abs() < 1e-12);
    ur.faults().protective_stop();
    let s = ur.snapshot();
    assert_eq!(s.safety_mode, safety_mode::PROTECTIVE_STOP);
    assert_eq!(s.runtime_state, runtime_state::STOPPED);
    // 3 m/s² from 0.25 m/s: at rest within 84 ms (42 ticks) after 10.4 mm.
    ur.step_ticks(&h, 50).await;
    let s = ur.snapshot();
    assert_eq!(s.actual_tcp_speed, [0.0; 6]);
    let travelled = s.actual_tcp_pose.y - before.actual_tcp_pose.y;
    assert!(travelled > 0.0 && travelled < 0.011, "{travelled}");
    assert_ne!(s.output_int_registers[control::OUT_DONE_SEQ as usize], 1);
    ur.step_ticks(&h, 100).await;
    assert_eq!(
        ur.snapshot().actual_tcp_pose,
        s.actual_tcp_pose,
        "must not move again"
    );

    let mut d = Dashboard::connect(&ur).await;
    assert_eq!(
        d.cmd("unlock protective stop").await,
        "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking"
    );
    assert_eq!(d.cmd("safetystatus").await, "Safetystatus: PROTECTIVE_STOP");
    // 5 s after the stop (150 ticks = 0.3 s have passed).
    h.advance(Duration::from_millis(4_690));
    assert!(
        d.cmd("unlock protective stop")
            .await
            .starts_with("Cannot unlock")
    );
    h.advance(Duration::from_millis(10));
    assert_eq!(
        d.cmd("unlock protective stop").await,
        "Protective stop releasing"
    );
    assert_eq!(d.cmd("safetymode").await, "Safetymode: NORMAL");
    assert_eq!(d.cmd("robotmode").await, "Robotmode: RUNNING");
    assert_eq!(
        d.cmd("programState").await,
        format!("STOPPED {}", control::PROGRAM_NAME)
    );
    assert_eq!(d.cmd("play").await, "Starting program");
    assert_eq!(
        d.cmd("programState").await,
        format!("PLAYING {}", control::PROGRAM_NAME)
    );
}

#[tokio::test]
async fn dashboard_powers_up_from_power_off() {
    let (clock, _h) = Clock::manual();
    let ur = Ur5e::start(Ur5eConfig::default(), clock).await.unwrap();
    let mut d = Dashboard::connect(&ur).await;
    assert_eq!(d.cmd("robotmode").await, "Robotmode: POWER_OFF");
    assert_eq!(d.cmd("play").await, "Failed to execute: play");
    assert_eq!(d.cmd("power on").await, "Powering on");
    assert_eq!(d.cmd("robotmode").await, "Robotmode: IDLE");
    assert_eq!(d.cmd("brake release").await, "Brake releasing");
    assert_eq!(d.cmd("robotmode").await, "Robotmode: RUNNING");
    assert_eq!(d.cmd("is in remote control").await, "true");
    assert_eq!(d.cmd("running").await, "Program running: false");
    assert_eq!(d.cmd("fly away").await, "could not understand: 'fly away'");
    upload(&ur, &program(NO_WATCHDOG)).await;
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
    assert_eq!(d.cmd("running").await, "Program running: true");
    assert_eq!(d.cmd("stop").await, "Stopped");
    ur.faults().emergency_stop();
    assert_eq!(d.cmd("robotmode").await, "Robotmode: POWER_OFF");
    assert_eq!(
        d.cmd("safetystatus").await,
        "Safetystatus: ROBOT_EMERGENCY_STOP"
    );
    assert_eq!(d.cmd("power on").await, "Failed to execute: power on");
    ur.faults().release_emergency_stop();
    assert_eq!(d.cmd("brake release").await, "Brake releasing");
    assert_eq!(d.cmd("robotmode").await, "Robotmode: RUNNING");
    assert_eq!(d.cmd("quit").await, "Disconnected");
    ur.shutdown().await;
}

#[tokio::test]
async fn malformed_packages_do_not_kill_the_server() {
    let (ur, _h) = running_mock().await;
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.handshake(2).await;
    // Unknown type: an error text message, then the connection still answers.
    c.send_raw(&[0, 4, b'Z', 1]).await;
    match c.recv().await {
        ServerPackage::TextMessage(m) => assert!(m.message.contains("unknown"), "{}", m.message),
        other => panic!("{other:?}"),
    }
    // Truncated: a 'V' request with one byte of its u16.
    c.send_raw(&[0, 4, b'V', 2]).await;
    assert!(matches!(c.recv().await, ServerPackage::TextMessage(_)));
    // Input data of the wrong length for its recipe.
    let (id, _) = c.setup_inputs(&["input_double_register_40"]).await;
    c.send(ClientPackage::Data {
        recipe_id: id,
        payload: bytes::Bytes::from_static(&[1, 2, 3]),
    })
    .await;
    assert!(matches!(c.recv().await, ServerPackage::TextMessage(_)));
    c.send(ClientPackage::Data {
        recipe_id: 99,
        payload: bytes::Bytes::from_static(&[1, 2, 3]),
    })
    .await;
    assert!(matches!(c.recv().await, ServerPackage::TextMessage(_)));
    c.send(ClientPackage::GetUrControlVersion).await;
    assert!(matches!(
        c.recv_reply().await,
        ServerPackage::UrControlVersion { .. }
    ));
    // Size 2: the stream cannot be re-framed, so this connection is dropped…
    c.send_raw(&[0, 2, b'V']).await;
    assert_eq!(c.recv_within(Duration::from_secs(5)).await, None);
    // …and the server still serves a new one.
    let mut d = RawClient::connect(ur.rtde_addr()).await;
    assert_eq!(d.handshake(2).await, (5, 15, 0, 0));
}

#[tokio::test]
async fn injected_handshake_messages_delayed_start_and_connection_drop() {
    let (ur, h) = running_mock().await;
    let faults = ur.faults();
    faults.text_messages_during_handshake(true);
    faults.delay_start_ack(Duration::from_millis(10));
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.send(ClientPackage::RequestProtocolVersion(2)).await;
    assert!(matches!(c.recv().await, ServerPackage::TextMessage(_)));
    assert_eq!(
        c.recv().await,
        ServerPackage::ProtocolVersion { accepted: true }
    );
    c.version = 2;
    c.setup_outputs(500.0, &["timestamp"]).await;
    c.send(ClientPackage::Start).await;
    // Streaming starts at once; the S reply comes 10 ms (5 ticks) later.
    let mut data_before_reply = 0;
    'ticks: for _ in 0..100 {
        ur.step_ticks(&h, 1).await;
        while let Some(p) = c.recv_within(Duration::from_millis(50)).await {
            match p {
                ServerPackage::Data { .. } => data_before_reply += 1,
                ServerPackage::StartReply { accepted } => {
                    assert!(accepted);
                    break 'ticks;
                }
                other => panic!("{other:?}"),
            }
        }
    }
    assert!(data_before_reply >= 4, "{data_before_reply}");

    faults.drop_connections(Duration::from_secs(1));
    // The socket closes (after any data packages already on their way).
    loop {
        match c.recv_within(Duration::from_secs(5)).await {
            None => break,
            Some(ServerPackage::Data { .. }) => continue,
            Some(other) => panic!("{other:?}"),
        }
    }
    // While "restarting", new connections are closed at once.
    let mut r = RawClient::connect(ur.rtde_addr()).await;
    r.send(ClientPackage::RequestProtocolVersion(2)).await;
    assert_eq!(r.recv_within(Duration::from_secs(5)).await, None);
    h.advance(Duration::from_secs(1));
    let mut r = RawClient::connect(ur.rtde_addr()).await;
    assert_eq!(r.handshake(2).await, (5, 15, 0, 0));
}
