//! The rig drives the simulated UR5e (real TCP: RTDE, dashboard, script upload) through the
//! stages of one contact trajectory, and the logged RTDE states show the path it took.

use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use nalgebra::Vector3;
use rig::robot::{Move, MovesLog, Robot, RobotEndpoints, RobotOptions};
use rig_core::clock::Clock;
use rig_core::control::{robot_mode, runtime_state, safety_mode};
use rig_core::pose::{Pose, pose_trans, rotation_distance, translation_distance};
use std::f64::consts::PI;

/// Clock speed-up for the simulated rig.
const SCALE: f64 = 5.0;

/// The sensor surface: 0.4, 0, 0.2 m in the base, tool pointing down (rotvec (π, 0, 0), so the
/// frame's z axis points into the gel).
fn surface() -> Pose {
    Pose::new(0.4, 0.0, 0.2, PI, 0.0, 0.0)
}

/// A point in the surface frame: `dz_mm` > 0 is into the gel.
fn at(dx_mm: f64, dy_mm: f64, dz_mm: f64) -> Pose {
    pose_trans(
        &surface(),
        &Pose::new(dx_mm * 1e-3, dy_mm * 1e-3, dz_mm * 1e-3, 0.0, 0.0, 0.0),
    )
}

const DEPTH_MM: f64 = 0.8;
const SHEAR_MM: f64 = 1.0;
const ANGLE_DEG: f64 = 30.0;
const LABEL: &str = "p0-d0.8-a030";

fn trajectory() -> Vec<Move> {
    let (s, c) = ANGLE_DEG.to_radians().sin_cos();
    let mv = |stage: &str, pose: Pose, speed_mm_s: f64| Move {
        label: format!("{LABEL}/{stage}"),
        pose,
        speed_m_s: speed_mm_s * 1e-3,
        accel_m_s2: 0.05,
    };
    vec![
        mv("approach", at(0.0, 0.0, -2.0), 20.0),
        mv("down", at(0.0, 0.0, DEPTH_MM), 4.0),
        mv("shear", at(SHEAR_MM * c, SHEAR_MM * s, DEPTH_MM), 2.0),
        mv("reverse", at(0.0, 0.0, DEPTH_MM), 2.0),
        mv("up", at(0.0, 0.0, -2.0), 4.0),
    ]
}

/// Distance from `p` to the segment a–b.
fn dist_to_segment(p: Vector3<f64>, a: Vector3<f64>, b: Vector3<f64>) -> f64 {
    let ab = b - a;
    let len2 = ab.norm_squared();
    let t = if len2 == 0.0 {
        0.0
    } else {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    };
    (a + ab * t - p).norm()
}

pub async fn start_mock(clock: &Clock) -> Ur5e {
    let cfg = Ur5eConfig {
        // Start 10 mm above the contact point, tool down.
        home_pose: at(0.0, 0.0, -10.0),
        ..Ur5eConfig::default()
    };
    Ur5e::start(cfg, clock.clone()).await.expect("mock starts")
}

pub fn endpoints(m: &Ur5e) -> RobotEndpoints {
    RobotEndpoints {
        rtde: m.rtde_addr(),
        dashboard: m.dashboard_addr(),
        script: m.script_addr(),
    }
}

fn check_log(log: &MovesLog, moves: &[Move], start: Pose) {
    assert_eq!(log.missed_samples, 0, "the log fell behind the stream");
    assert_eq!(log.reports.len(), moves.len());
    let surface_z = surface().z;
    let mut from = start;
    for (m, r) in moves.iter().zip(&log.reports) {
        let stage: Vec<_> = log.samples.iter().filter(|s| s.label == m.label).collect();
        assert!(
            stage.len() > 10,
            "{}: only {} samples",
            m.label,
            stage.len()
        );
        let mut worst = 0.0f64;
        for s in &stage {
            let st = &s.state;
            worst = worst.max(dist_to_segment(
                st.actual_tcp_pose.position(),
                from.position(),
                m.pose.position(),
            ));
            // Depth: the TCP never goes deeper than planned by more than 0.01 mm.
            let depth_mm = (surface_z - st.actual_tcp_pose.z) * 1e3;
            assert!(
                depth_mm <= DEPTH_MM + 0.01,
                "{}: depth {depth_mm:.4} mm at t={}",
                m.label,
                st.timestamp_s
            );
            assert_eq!(st.robot_mode, robot_mode::RUNNING, "{}", m.label);
            assert_eq!(st.safety_mode, safety_mode::NORMAL, "{}", m.label);
            assert_eq!(st.runtime_state, runtime_state::PLAYING, "{}", m.label);
        }
        assert!(
            worst < 0.05e-3,
            "{}: {:.4} mm off the planned line",
            m.label,
            worst * 1e3
        );
        let fin = r.final_state.actual_tcp_pose;
        assert!(
            translation_distance(&fin, &m.pose) < 1e-6,
            "{}: ends {:.6} mm from target",
            m.label,
            translation_distance(&fin, &m.pose) * 1e3
        );
        assert!(
            rotation_distance(&fin, &m.pose) < 1e-6,
            "{}: ends {:e} rad from target orientation",
            m.label,
            rotation_distance(&fin, &m.pose)
        );
        assert!(r.done_ns > r.issued_ns);
        from = m.pose;
    }
    // Host time and controller time both increase through the log.
    for w in log.samples.windows(2) {
        assert!(w[1].state.t_host_ns >= w[0].state.t_host_ns);
        assert!(w[1].state.timestamp_s >= w[0].state.timestamp_s);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn drives_one_trajectory_through_all_stages_on_the_planned_lines() {
    let clock = Clock::scaled(SCALE);
    let mock = start_mock(&clock).await;
    let mut robot = Robot::connect(endpoints(&mock), RobotOptions::default(), clock.clone())
        .await
        .expect("connect");
    // The mock starts powered off: prepare powers on, releases brakes, uploads the program.
    robot.prepare().await.expect("prepare");
    let snap = mock.snapshot();
    assert!(snap.program_loaded);
    assert_eq!(snap.runtime_state, runtime_state::PLAYING);

    let start = robot.state().unwrap().actual_tcp_pose;
    let moves = trajectory();
    let log = robot.run_moves(&moves).await.expect("trajectory runs");
    check_log(&log, &moves, start);

    // One connection, nothing malformed, and the e-Series stream was negotiated at 500 Hz.
    // (The sample rate seen in the log is lower under a scaled clock: tokio's timers have a
    // 1 ms real-time resolution, so the mock's 2 ms ticks are coarsened at SCALE > 2.)
    let stats = robot.rtde().stats();
    assert_eq!(stats.connections, 1);
    assert_eq!(stats.malformed + stats.unknown_type, 0);
    match robot.rtde().link_status() {
        rig::robot::LinkStatus::Up {
            frequency_hz,
            protocol,
            ..
        } => {
            assert_eq!(frequency_hz, 500.0);
            assert_eq!(protocol, 2);
        }
        other => panic!("link {other:?}"),
    }
    mock.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn move_l_reports_and_refuses_bad_arguments() {
    let clock = Clock::scaled(SCALE);
    let mock = start_mock(&clock).await;
    let mut robot = Robot::connect(endpoints(&mock), RobotOptions::default(), clock.clone())
        .await
        .unwrap();
    // Before prepare: the robot is powered off, so motion is refused with the modes named.
    let e = robot
        .move_l(at(0.0, 0.0, -5.0), 0.01, 0.1)
        .await
        .unwrap_err();
    assert!(e.to_string().contains("POWER_OFF"), "{e}");
    robot.prepare().await.unwrap();
    let r = robot.move_l(at(0.0, 0.0, -5.0), 0.01, 0.1).await.unwrap();
    assert!(
        r.position_error_m < 1e-6 && r.rotation_error_rad < 1e-6,
        "{r:?}"
    );
    let e = robot
        .move_l(at(0.0, 0.0, -5.0), -1.0, 0.1)
        .await
        .unwrap_err();
    assert!(e.to_string().contains("must be finite and positive"), "{e}");
    robot.stop().await.unwrap();
    mock.shutdown().await;
}
