//! Faults: a protective stop mid-move, RTDE connection drops (continue and abort policies),
//! text messages mid-handshake, a delayed Start reply, and a raw fake server that splits,
//! coalesces and corrupts packages.

use std::f64::consts::PI;
use std::time::Duration;

use bytes::{BufMut, BytesMut};
use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use rig::robot::rtde::{LinkStatus, RtdeClient, RtdeConfig};
use rig::robot::{
    DashboardError, LinkLossPolicy, MotionError, Move, Robot, RobotEndpoints, RobotOptions,
};
use rig_core::clock::Clock;
use rig_core::control::{self, ProgramStatus};
use rig_core::pose::{Pose, translation_distance};
use rig_core::rtde::{
    ClientPackage, DataType, FieldType, FrameDecoder, PROTOCOL_V2, ServerPackage, Value,
    encode_values, fields,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

const SCALE: f64 = 5.0;
const LABEL: &str = "p0-d0.2-a030/shear";

fn home() -> Pose {
    Pose::new(0.4, 0.0, 0.21, PI, 0.0, 0.0)
}

/// A long, slow move: 20 mm at 5 mm/s (4 s of clock time).
fn long_move() -> Move {
    let mut p = home();
    p.x += 0.02;
    Move {
        label: LABEL.into(),
        pose: p,
        speed_m_s: 0.005,
        accel_m_s2: 0.05,
    }
}

async fn setup(opts: RobotOptions) -> (Clock, Ur5e, Robot) {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_test_writer()
        .try_init();
    let clock = Clock::scaled(SCALE);
    let mock = Ur5e::start(
        Ur5eConfig {
            home_pose: home(),
            ..Ur5eConfig::default()
        },
        clock.clone(),
    )
    .await
    .unwrap();
    let ep = RobotEndpoints {
        rtde: mock.rtde_addr(),
        dashboard: mock.dashboard_addr(),
        script: mock.script_addr(),
    };
    let mut robot = Robot::connect(ep, opts, clock.clone()).await.unwrap();
    robot.prepare().await.unwrap();
    (clock, mock, robot)
}

/// Wait (clock time) until the mock's program reports Moving.
async fn until_moving(clock: &Clock, mock: &Ur5e) {
    for _ in 0..2000 {
        if mock.snapshot().output_int_registers[control::OUT_STATUS as usize]
            == ProgramStatus::Moving as i32
        {
            // Let it get going.
            clock.sleep(Duration::from_millis(300)).await;
            return;
        }
        clock.sleep(Duration::from_millis(5)).await;
    }
    panic!("the mock never reported Moving");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn protective_stop_mid_move_names_the_move_and_blocks_until_recovered() {
    let (clock, mock, mut robot) = setup(RobotOptions::default()).await;
    let faults = mock.faults();
    let mv = long_move();
    let (res, t_stop) = tokio::join!(robot.run_moves(std::slice::from_ref(&mv)), async {
        until_moving(&clock, &mock).await;
        faults.protective_stop();
        clock.now_ns()
    });
    let err = res.unwrap_err();
    assert!(
        matches!(&err, MotionError::ProtectiveStop { label, .. } if label == LABEL),
        "{err}"
    );
    let msg = err.to_string();
    assert!(msg.contains(LABEL) && msg.contains("recover()"), "{msg}");

    // The rig stopped: the robot comes to rest short of the target.
    clock.sleep(Duration::from_millis(500)).await;
    let s = robot.state().unwrap();
    assert!(
        s.is_stationary(),
        "still moving at {} m/s",
        s.linear_speed_m_s()
    );
    assert!(translation_distance(&s.actual_tcp_pose, &mv.pose) > 1e-3);

    // Further motion is refused, naming the move that faulted.
    let e = robot.move_l(home(), 0.01, 0.1).await.unwrap_err();
    assert!(
        matches!(&e, MotionError::NeedsRecovery { previous, .. } if previous.contains(LABEL)),
        "{e}"
    );

    // Recovery before UR's 5 s unlock delay fails, and motion stays blocked.
    assert!(clock.now_ns() - t_stop < 5_000_000_000);
    let e = robot.recover().await.unwrap_err();
    assert!(
        matches!(&e, MotionError::Dashboard(DashboardError::Refused { command, .. }) if command == "unlock protective stop"),
        "{e}"
    );
    assert!(robot.move_l(home(), 0.01, 0.1).await.is_err());

    // After the delay it succeeds and the robot moves again.
    clock.sleep_until_ns(t_stop + 5_100_000_000).await;
    robot.recover().await.expect("recover after 5 s");
    let r = robot.move_l(mv.pose, 0.02, 0.1).await.expect("moves again");
    assert!(r.position_error_m < 1e-6);
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn connection_drop_mid_move_reconnects_and_continues() {
    let (clock, mock, mut robot) = setup(RobotOptions::default()).await;
    let faults = mock.faults();
    let mv = long_move();
    assert_eq!(robot.rtde().stats().connections, 1);
    let (res, ()) = tokio::join!(robot.run_moves(std::slice::from_ref(&mv)), async {
        until_moving(&clock, &mock).await;
        // Longer than the 100 ms watchdog: the controller stops the program.
        faults.drop_connections(Duration::from_millis(400));
    });
    let log = res.expect("the move continues after the link comes back");
    let r = &log.reports[0];
    assert!(r.reissued >= 1, "{r:?}");
    assert!(r.position_error_m < 1e-6);
    let stats = robot.rtde().stats();
    assert!(stats.connections >= 2, "{stats:?}");
    assert!(stats.link_failures >= 1);
    // Streaming resumed on the new connection (recipes sent again) and commands go through.
    robot
        .move_l(home(), 0.02, 0.1)
        .await
        .expect("moves after reconnect");
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn connection_drop_with_abort_policy_ends_the_move_cleanly() {
    let opts = RobotOptions {
        link_loss: LinkLossPolicy::Abort,
        ..RobotOptions::default()
    };
    let (clock, mock, mut robot) = setup(opts).await;
    let faults = mock.faults();
    let moves = [long_move()];
    let (res, ()) = tokio::join!(robot.run_moves(&moves), async {
        until_moving(&clock, &mock).await;
        faults.drop_connections(Duration::from_millis(200));
    });
    let e = res.unwrap_err();
    assert!(
        matches!(&e, MotionError::LinkLost { label, .. } if label == LABEL),
        "{e}"
    );
    // Not a safety fault: the next move re-uploads the stopped program and runs.
    clock.sleep(Duration::from_millis(300)).await;
    robot
        .move_l(home(), 0.02, 0.1)
        .await
        .expect("moves after an aborted link loss");
    assert!(robot.rtde().stats().connections >= 2);
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn text_messages_mid_handshake_and_data_before_the_start_reply() {
    let clock = Clock::scaled(SCALE);
    let mock = Ur5e::start(Ur5eConfig::default(), clock.clone())
        .await
        .unwrap();
    mock.faults().text_messages_during_handshake(true);
    mock.faults().delay_start_ack(Duration::from_millis(300));
    let mut cfg = RtdeConfig::new(mock.rtde_addr());
    cfg.input_recipes = vec![rig::robot::motion::safety_recipe()];
    let client = RtdeClient::connect(cfg, clock.clone()).await.unwrap();
    let texts = client.recent_text_messages();
    assert!(texts.len() >= 4, "{texts:?}"); // one before each of V, v, O, I
    let stats = client.stats();
    assert!(stats.early_data >= 1, "{stats:?}");
    assert_eq!(stats.malformed + stats.unknown_type, 0);
    // Streaming continues and the late Start reply is harmless.
    clock.sleep(Duration::from_millis(500)).await;
    let s = client.latest().unwrap();
    assert_eq!(s.robot_mode, control::robot_mode::POWER_OFF);
    assert!(client.stats().data_packages > stats.data_packages);
    client
        .handle()
        .send_inputs(0, &[Value::Int32(7), Value::Int32(3), Value::Double(2.5)])
        .await
        .unwrap();
    clock.sleep(Duration::from_millis(50)).await;
    let s = mock.snapshot();
    assert_eq!(s.input_int_registers[26], 7);
    assert_eq!(s.input_int_registers[27], 3);
    assert_eq!(s.input_double_registers[32], 2.5);
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn recipe_refusals_name_the_variable() {
    let clock = Clock::scaled(SCALE);
    let mock = Ur5e::start(Ur5eConfig::default(), clock.clone())
        .await
        .unwrap();
    // Another client holds the heartbeat register: the second one is refused with IN_USE.
    let mut cfg = RtdeConfig::new(mock.rtde_addr());
    cfg.input_recipes = vec![rig::robot::motion::safety_recipe()];
    let _first = RtdeClient::connect(cfg.clone(), clock.clone())
        .await
        .unwrap();
    cfg.max_attempts = 1;
    let e = RtdeClient::connect(cfg.clone(), clock.clone())
        .await
        .err()
        .unwrap();
    assert!(e.to_string().contains("input_int_register_26"), "{e}");
    assert!(e.to_string().contains("IN_USE"), "{e}");
    // A name the controller does not have is refused before anything is sent.
    cfg.output_names.push("actual_TCP_posee".into());
    let e = RtdeClient::connect(cfg, clock.clone()).await.err().unwrap();
    assert!(e.to_string().contains("actual_TCP_posee"), "{e}");
    mock.shutdown().await;
}

// ---------------------------------------------------------------------------------------------
// A raw fake server: split and coalesced reads, malformed packages.
// ---------------------------------------------------------------------------------------------

async fn read_request(sock: &mut TcpStream, dec: &mut FrameDecoder) -> ClientPackage {
    loop {
        if let Some(f) = dec.next_frame().unwrap() {
            return ClientPackage::decode(&f, PROTOCOL_V2).unwrap();
        }
        let mut buf = [0u8; 1024];
        let n = sock.read(&mut buf).await.unwrap();
        assert!(n > 0, "client closed during the handshake");
        dec.push(&buf[..n]);
    }
}

fn encode(p: &ServerPackage) -> BytesMut {
    let mut b = BytesMut::new();
    p.encode(PROTOCOL_V2, &mut b).unwrap();
    b
}

/// Answer the handshake; the protocol reply goes out one byte at a time, the Start reply
/// coalesced with the first three data packages. Returns the output types.
async fn fake_handshake(sock: &mut TcpStream, t0: &mut f64) -> Vec<DataType> {
    let mut dec = FrameDecoder::new();
    let mut types = Vec::new();
    loop {
        match read_request(sock, &mut dec).await {
            ClientPackage::RequestProtocolVersion(_) => {
                for b in encode(&ServerPackage::ProtocolVersion { accepted: true }).iter() {
                    sock.write_all(&[*b]).await.unwrap();
                    tokio::time::sleep(Duration::from_millis(2)).await;
                }
            }
            ClientPackage::GetUrControlVersion => {
                sock.write_all(&encode(&ServerPackage::UrControlVersion {
                    major: 5,
                    minor: 15,
                    bugfix: 0,
                    build: 1,
                }))
                .await
                .unwrap();
            }
            ClientPackage::SetupOutputs { names, .. } => {
                types = names
                    .iter()
                    .map(|n| fields::output_type(n).unwrap())
                    .collect();
                let ft = types.iter().map(|t| FieldType::Known(*t)).collect();
                sock.write_all(&encode(&ServerPackage::OutputSetup {
                    recipe_id: Some(1),
                    types: ft,
                }))
                .await
                .unwrap();
            }
            ClientPackage::SetupInputs { names } => {
                let ft = names
                    .iter()
                    .map(|n| FieldType::Known(fields::input_type(n).unwrap()))
                    .collect();
                sock.write_all(&encode(&ServerPackage::InputSetup {
                    recipe_id: 2,
                    types: ft,
                }))
                .await
                .unwrap();
            }
            ClientPackage::Start => {
                let mut all = encode(&ServerPackage::StartReply { accepted: true });
                for _ in 0..3 {
                    all.extend_from_slice(&data(&types, t0));
                }
                sock.write_all(&all).await.unwrap();
                return types;
            }
            other => panic!("unexpected {other:?}"),
        }
    }
}

/// One valid data package; `timestamp` counts up by 2 ms.
fn data(types: &[DataType], t: &mut f64) -> BytesMut {
    *t += 0.002;
    let names = rig::robot::state::output_recipe();
    let values: Vec<Value> = names
        .iter()
        .zip(types)
        .map(|(n, ty)| match n.as_str() {
            "timestamp" => Value::Double(*t),
            "robot_mode" => Value::Int32(control::robot_mode::RUNNING),
            "actual_TCP_pose" => Value::Vector6d([0.4, 0.0, 0.2, PI, 0.0, 0.0]),
            _ => Value::zero(*ty),
        })
        .collect();
    let mut payload = BytesMut::new();
    encode_values(&values, &mut payload);
    encode(&ServerPackage::Data {
        recipe_id: Some(1),
        payload: payload.freeze(),
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn raw_server_split_coalesced_and_malformed_packages() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let (go_tx, mut go_rx) = tokio::sync::mpsc::channel::<()>(4);
    let server = tokio::spawn(async move {
        let mut t = 0.0;
        // First connection: handshake, then a tour of bad input, then size 2.
        let (mut sock, _) = listener.accept().await.unwrap();
        let types = fake_handshake(&mut sock, &mut t).await;
        // A data package split into single bytes.
        for b in data(&types, &mut t).iter() {
            sock.write_all(&[*b]).await.unwrap();
        }
        // Unknown type, truncated data, a truncated controller-version reply, data for a
        // recipe that is not ours, then valid data — all coalesced into one write.
        let mut bad = BytesMut::new();
        bad.put_slice(&[0, 6, b'Z', 1, 2, 3]);
        let good = data(&types, &mut t);
        bad.put_u16(10);
        bad.put_slice(&good[2..10]); // 'U', id, 6 payload bytes: too short for the recipe
        bad.put_slice(&[0, 5, b'v', 0, 0]);
        let mut foreign = data(&types, &mut t);
        foreign[3] = 9;
        bad.put_slice(&foreign);
        bad.put_slice(&data(&types, &mut t));
        sock.write_all(&bad).await.unwrap();
        go_rx.recv().await;
        // Size below the header: the stream is out of sync; the client must reconnect.
        sock.write_all(&[0, 2, b'U']).await.unwrap();
        // Second connection: the client sends all recipes again.
        let (mut sock2, _) = listener.accept().await.unwrap();
        let types2 = fake_handshake(&mut sock2, &mut t).await;
        assert_eq!(types2, types);
        for _ in 0..20 {
            sock2.write_all(&data(&types, &mut t)).await.unwrap();
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        go_rx.recv().await;
        drop(sock);
    });

    let mut cfg = RtdeConfig::new(addr);
    cfg.input_recipes = vec![rig::robot::motion::command_recipe()];
    cfg.backoff_initial = Duration::from_millis(10);
    let client = RtdeClient::connect(cfg, Clock::system()).await.unwrap();
    let clock = Clock::system();
    let mut tries = 0;
    loop {
        let s = client.stats();
        if s.data_packages >= 5 && s.malformed >= 2 && s.unexpected >= 1 && s.unknown_type >= 1 {
            break;
        }
        tries += 1;
        assert!(tries < 1000, "stats {s:?}");
        clock.sleep(Duration::from_millis(2)).await;
    }
    let s = client.stats();
    assert_eq!(s.unknown_type, 1, "{s:?}");
    assert_eq!(s.malformed, 2, "{s:?}"); // the truncated data package and 'v' reply
    assert_eq!(s.unexpected, 1, "{s:?}"); // data for a recipe that is not ours
    assert_eq!(s.data_packages, 5, "{s:?}");
    assert_eq!(s.connections, 1);
    let st = client.latest().unwrap();
    assert_eq!(st.robot_mode, control::robot_mode::RUNNING);
    assert!(
        (st.timestamp_s - 0.002 * 7.0).abs() < 1e-12,
        "{}",
        st.timestamp_s
    );

    go_tx.send(()).await.unwrap();
    let mut link = client.link();
    clock
        .timeout(
            Duration::from_secs(5),
            link.wait_for(|l| matches!(l, LinkStatus::Up { generation: 2, .. })),
        )
        .await
        .expect("reconnected")
        .unwrap();
    let mut tries = 0;
    while client.stats().data_packages < 25 {
        tries += 1;
        assert!(tries < 1000, "stats {:?}", client.stats());
        clock.sleep(Duration::from_millis(2)).await;
    }
    let s = client.stats();
    assert_eq!(s.connections, 2);
    assert_eq!(s.link_failures, 1);
    go_tx.send(()).await.unwrap();
    server.await.unwrap();
}
