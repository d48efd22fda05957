//! The shared scene of the simulated rig: the UR5e's TCP presses a sphere into the gel, the
//! contact physics gives the force (read back through the Net F/T mock over UDP) and the image.
//! Manual clock: every step of time is the test's.

use crate::common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::{RawClient, eventually};
use hardware_mocks::camera::SimCameraConfig;
use hardware_mocks::nano17::MockStats;
use hardware_mocks::rig_sim::{
    ContactPhysics, PhysicsConfig, SimRig, SimRigOptions, indenter_pose, pose_above_surface,
    wrench_at_tip,
};
use hardware_mocks::sim::{self, Scene};
use hardware_mocks::truth::WrenchSource;
use hardware_mocks::ur5e::Ur5e;
use rig_core::clock::Clock;
use rig_core::config::RigConfig;
use rig_core::control::{self, CommandKind, robot_mode, runtime_state};
use rig_core::ft::netft::{RdtCommand, RdtRecord, RdtRequest};
use rig_core::indenter::Indenter;
use rig_core::pose::Pose;
use rig_core::rtde::Value;
use rig_core::wrench::Wrench;
use tokio::io::AsyncWriteExt;
use tokio::net::{TcpStream, UdpSocket};

const DEPTH_MM: f64 = 0.5;

/// Waits until the physics has a step within one physics period (4 ms) of clock time `t_ns`.
/// Waits until the physics has stepped within one of its periods of `t_ns`.
async fn physics_reaches(physics: &ContactPhysics, t_ns: u64) {
    let period_ns = (1e9 / physics.config().rate_hz) as u64;
    eventually("the physics to catch up", || {
        physics.latest().is_some_and(|(t, _)| t + period_ns >= t_ns)
    })
    .await;
}

fn sphere() -> Arc<Indenter> {
    Arc::new(Indenter::builtin("sphere").unwrap())
}

/// The rig's own control program; its watchdog allows 100 s without a heartbeat (these tests
/// write none).
fn program() -> String {
    rig_core::urscript::program(0.01, None)
}

async fn upload_program(ur: &Ur5e) {
    let mut s = TcpStream::connect(ur.script_addr()).await.unwrap();
    s.write_all(program().as_bytes()).await.unwrap();
    s.shutdown().await.unwrap();
    eventually("the program to play", || {
        ur.snapshot().runtime_state == runtime_state::PLAYING
    })
    .await;
}

/// Writes a moveL into the rig program's command registers.
async fn movel(ur: &Ur5e, seq: i32, target: Pose, v: f64, a: f64) -> RawClient {
    let names = control::command_recipe();
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let mut c = RawClient::connect(ur.rtde_addr()).await;
    c.handshake(2).await;
    let (id, _) = c.setup_inputs(&refs).await;
    let mut vals = vec![Value::Int32(seq), Value::Int32(CommandKind::MoveL as i32)];
    vals.extend(target.to_array().map(Value::Double));
    vals.push(Value::Double(v));
    vals.push(Value::Double(a));
    c.write_inputs(id, &vals).await;
    eventually("the command registers to be written", || {
        ur.snapshot().input_int_registers[control::IN_CMD_SEQ as usize] == seq
    })
    .await;
    c
}

/// A Net F/T client on the RDT codec: collects every record it receives.
struct NetFtClient {
    sock: Arc<UdpSocket>,
    records: Arc<Mutex<Vec<RdtRecord>>>,
    /// Records already taken by [`NetFtClient::drain`].
    taken: std::sync::atomic::AtomicU64,
    task: tokio::task::JoinHandle<()>,
}

impl NetFtClient {
    async fn start(addr: std::net::SocketAddr) -> Self {
        let sock = Arc::new(UdpSocket::bind("127.0.0.1:0").await.unwrap());
        sock.connect(addr).await.unwrap();
        let records = Arc::new(Mutex::new(Vec::new()));
        let (s, r) = (sock.clone(), records.clone());
        let task = tokio::spawn(async move {
            let mut buf = [0u8; 1500];
            while let Ok(n) = s.recv(&mut buf).await {
                if let Ok(recs) = RdtRecord::decode_datagram(&buf[..n]) {
                    r.lock().unwrap().extend(recs);
                }
            }
        });
        let req = RdtRequest {
            command: RdtCommand::StartRealtime,
            sample_count: 0,
        };
        sock.send(&req.encode()).await.unwrap();
        Self {
            sock,
            records,
            taken: Default::default(),
            task,
        }
    }

    /// Records received since the stream started.
    fn received(&self) -> u64 {
        self.records.lock().unwrap().len() as u64
            + self.taken.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Waits until every record the mock sent has arrived, then takes them.
    /// Waits until the mock has sent at least `n` records since the last drain (its task
    /// samples when it next wakes, which on a loaded host may be after the test's next step),
    /// then drains them all.
    async fn drain_at_least(&self, stats: &MockStats, n: u64) -> Vec<RdtRecord> {
        let taken = self.taken.load(std::sync::atomic::Ordering::Relaxed);
        eventually("the F/T to send its records", || {
            MockStats::get(&stats.sent) >= taken + n
        })
        .await;
        self.drain(stats).await
    }

    async fn drain(&self, stats: &MockStats) -> Vec<RdtRecord> {
        eventually("every sent record to arrive", || {
            self.received() == MockStats::get(&stats.sent)
        })
        .await;
        let recs = std::mem::take(&mut *self.records.lock().unwrap());
        self.taken
            .fetch_add(recs.len() as u64, std::sync::atomic::Ordering::Relaxed);
        recs
    }

    fn mean(records: &[RdtRecord]) -> [f64; 6] {
        let mut m = [0.0; 6];
        for r in records {
            let w = r.to_wrench(1e6, 1e3);
            for k in 0..6 {
                m[k] += w[k] / records.len() as f64;
            }
        }
        m
    }
}

impl Drop for NetFtClient {
    fn drop(&mut self) {
        self.task.abort();
        let _ = &self.sock;
    }
}

fn force_err(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt();
    d / (b[0].powi(2) + b[1].powi(2) + b[2].powi(2)).sqrt()
}

/// The same static pose, simulated statelessly with the physics' effects.
fn static_reference(cfg: &RigConfig, physics: &PhysicsConfig) -> sim::SimOutput {
    let mut scene = Scene::new(
        cfg.elastomer.clone(),
        sphere(),
        sim::IndenterPose {
            contact_mm: [0.0, 0.0],
            depth_mm: DEPTH_MM,
            shear_mm: [0.0, 0.0],
        },
    );
    scene.effects = physics.effects(false, &cfg.elastomer);
    sim::simulate(&scene).unwrap()
}

#[test]
fn tcp_pose_maps_to_the_indenter_pose_in_the_surface_frame() {
    let cfg = RigConfig::sim_source();
    let frame = cfg.sensor.surface_frame;
    let p = indenter_pose(&frame, &pose_above_surface(&frame, 1.5, -2.0, -0.6));
    assert!((p.contact_mm[0] - 1.5).abs() < 1e-9, "{p:?}");
    assert!((p.contact_mm[1] + 2.0).abs() < 1e-9, "{p:?}");
    assert!((p.depth_mm - 0.6).abs() < 1e-9, "{p:?}");
    assert_eq!(p.shear_mm, [0.0, 0.0]);
    // A tilted, offset surface frame: the same relation holds in its own axes.
    let tilted = Pose::new(0.4, 0.05, 0.2, 0.1, -0.2, 0.3);
    let p = indenter_pose(&tilted, &pose_above_surface(&tilted, -1.0, 0.5, 2.0));
    assert!((p.contact_mm[0] + 1.0).abs() < 1e-9, "{p:?}");
    assert!((p.contact_mm[1] - 0.5).abs() < 1e-9, "{p:?}");
    assert!((p.depth_mm + 2.0).abs() < 1e-9, "{p:?}");
    // Torque moved from the surface contact point down to the tip.
    let w = wrench_at_tip(
        &Wrench {
            force_n: [1.0, 2.0, -3.0],
            torque_nmm: [0.1, 0.2, 0.3],
        },
        0.5,
    );
    assert_eq!(w.torque_nmm, [0.1 - 0.5 * 2.0, 0.2 + 0.5 * 1.0, 0.3]);
}

#[test]
fn wrench_at_interpolates_between_physics_steps_and_clamps_at_the_ends() {
    let cfg = RigConfig::sim_source();
    let frame = cfg.sensor.surface_frame;
    let physics = ContactPhysics::new(
        frame,
        cfg.elastomer.clone(),
        sphere(),
        PhysicsConfig::default(),
        false,
    )
    .unwrap();
    assert_eq!(physics.wrench_at(123), Wrench::default());
    let above = pose_above_surface(&frame, 0.0, 0.0, 1.0);
    let pressed = pose_above_surface(&frame, 0.0, 0.0, -DEPTH_MM);
    assert_eq!(
        physics.update(1_000_000, &above).unwrap(),
        Wrench::default()
    );
    let w = physics.update(5_000_000, &pressed).unwrap();
    assert!(w.force_n[2] < 0.0, "{w:?}");
    let mid = physics.wrench_at(3_000_000);
    for k in 0..3 {
        assert!(
            (mid.force_n[k] - w.force_n[k] / 2.0).abs() < 1e-12,
            "{mid:?}"
        );
    }
    assert_eq!(physics.wrench_at(0), Wrench::default());
    assert_eq!(physics.wrench_at(9_000_000), w);
    let s = physics.stats();
    assert_eq!((s.steps, s.contact_steps, s.errors), (2, 1, 0));
    // Too deep for the 3 mm gel: refused, the last wrench held.
    let too_deep = pose_above_surface(&frame, 0.0, 0.0, -3.5);
    assert!(physics.update(7_000_000, &too_deep).is_err());
    assert_eq!(physics.wrench_at(7_000_000), w);
    assert_eq!(physics.stats().errors, 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_ur5e_presses_a_sphere_and_the_netft_reads_the_contact_force() {
    let cfg = RigConfig::sim_source();
    let frame = cfg.sensor.surface_frame;
    let (clock, h) = Clock::manual();
    let opts = SimRigOptions {
        initial_robot_mode: robot_mode::RUNNING,
        netft_rate_hz: Some(1000.0),
        camera: Some(SimCameraConfig {
            queue_len: 64,
            ..SimCameraConfig::ideal(25.0)
        }),
        // Elastic, so the contact at rest is the static one (relaxation is tested apart).
        physics: PhysicsConfig {
            viscoelastic: false,
            ..PhysicsConfig::default()
        },
        ..SimRigOptions::default()
    };
    let physics_cfg = opts.physics.clone();
    let mut rig = SimRig::start(&cfg, sphere(), clock.clone(), opts)
        .await
        .unwrap();
    let home = rig.ur5e().snapshot().actual_tcp_pose;
    assert!((indenter_pose(&frame, &home).depth_mm + 2.0).abs() < 1e-9);
    upload_program(rig.ur5e()).await;
    let netft = NetFtClient::start(rig.netft_addr().expect("Net F/T front end")).await;
    let stats = rig.ft().stats().clone();
    eventually("the stream request", || {
        MockStats::get(&stats.commands) == 1
    })
    .await;

    // Above the surface: 0.2 s of clock time, zero force; the F/T's own offset is tared here.
    rig.ur5e().step_ticks(&h, 100).await;
    let t_above = rig.ur5e().snapshot().t_ns;
    physics_reaches(rig.physics(), t_above).await;
    assert_eq!(rig.physics().wrench_at(t_above), Wrench::default());
    assert_eq!(rig.physics().wrench_at(t_above / 2), Wrench::default());
    // 0.2 s at 1 kHz: about 200 records.
    let tare_recs = netft.drain_at_least(&stats, 150).await;
    assert!(tare_recs.len() >= 150, "{}", tare_recs.len());
    let tare = NetFtClient::mean(&tare_recs[20..]);
    eventually("a camera frame out of contact", || {
        rig.camera().unwrap().stats().delivered >= 4
    })
    .await;
    let mut flat_frame = None;
    while let Some(f) = rig.camera().unwrap().try_recv() {
        flat_frame = Some(f);
    }
    let flat_frame = flat_frame.unwrap();

    // Down 2.5 mm at 10 mm/s, 0.1 m/s²: a 0.35 s trapezoid ending 0.5 mm deep.
    let target = pose_above_surface(&frame, 0.0, 0.0, -DEPTH_MM);
    let _client = movel(rig.ur5e(), 1, target, 0.01, 0.1).await;
    let mut ticks = 0;
    let mut fz_prev = 0.0;
    let mut path = Vec::new();
    loop {
        rig.ur5e().step_ticks(&h, 1).await;
        ticks += 1;
        let s = rig.ur5e().snapshot();
        path.push((s.t_ns, s.actual_tcp_pose));
        if ticks % 10 == 0 {
            physics_reaches(rig.physics(), s.t_ns).await;
            let fz = rig.physics().wrench_at(s.t_ns - 4_000_000).force_n[2];
            assert!(
                fz <= fz_prev + 1e-3,
                "pressing deeper lowers Fz: {fz} after {fz_prev}"
            );
            fz_prev = fz;
        }
        if s.output_int_registers[control::OUT_DONE_SEQ as usize] == 1 {
            break;
        }
        assert!(ticks < 400, "the move did not finish");
    }
    let depth = indenter_pose(&frame, &rig.ur5e().snapshot().actual_tcp_pose).depth_mm;
    assert!((depth - DEPTH_MM).abs() < 1e-9, "{depth}");
    // The pose history the physics steps a late consumer with: the pose of the tick at or
    // before the time asked for.
    for &(t, pose) in path.iter().step_by(25) {
        assert_eq!(rig.ur5e().tcp_pose_at(t), Some((t, pose)));
        assert_eq!(rig.ur5e().tcp_pose_at(t + 1_000_000), Some((t, pose)));
    }
    // What the contact presses with: the tip on its way between two ticks (the tool is the
    // TCP here), at the time asked for, a quarter of the way from one tick's position to the
    // next; at a tick, that tick's pose.
    for w in path.windows(2).step_by(25) {
        let ((ta, a), (tb, b)) = (w[0], w[1]);
        let t = ta + (tb - ta) / 4;
        let (t_got, got) = rig.ur5e().tip_pose_moving(t).unwrap();
        assert_eq!(t_got, t);
        let want = [
            a.x + 0.25 * (b.x - a.x),
            a.y + 0.25 * (b.y - a.y),
            a.z + 0.25 * (b.z - a.z),
        ];
        for (g, w) in [got.x, got.y, got.z].into_iter().zip(want) {
            assert!((g - w).abs() < 1e-12, "{g} against {w}");
        }
        assert_eq!(rig.ur5e().tip_pose_moving(ta), Some((ta, a)));
    }
    // Moving, a quarter of a tick between them is real travel (10 mm/s: 5 µm a tick).
    let (ta, a) = path[path.len() / 2];
    let (tb, b) = path[path.len() / 2 + 1];
    let mid = rig.ur5e().tip_pose_moving((ta + tb) / 2).unwrap().1;
    assert!((a.z - b.z).abs() > 1e-6 && (mid.z - a.z).abs() > 0.4 * (a.z - b.z).abs());

    // At rest 0.5 mm deep: settle 40 ms, then read 0.2 s. The F/T reads the newest physics
    // step at each sample's time, so let the physics reach the rest pose first: on a busy
    // machine it can lag the manual clock by tens of ms, and samples would read the contact
    // of a shallower moment (a CI run read 3 % low that way).
    rig.ur5e().step_ticks(&h, 20).await;
    let t_settled = rig.ur5e().snapshot().t_ns;
    physics_reaches(rig.physics(), t_settled).await;
    netft.drain(&stats).await;
    rig.ur5e().step_ticks(&h, 100).await;
    let t_rest = rig.ur5e().snapshot().t_ns;
    physics_reaches(rig.physics(), t_rest).await;
    let pressed = rig.physics().wrench_at(t_rest - 4_000_000);
    let reference = static_reference(&cfg, &physics_cfg);
    let default_cell = sim::simulate(&Scene::new(
        cfg.elastomer.clone(),
        sphere(),
        sim::IndenterPose {
            contact_mm: [0.0, 0.0],
            depth_mm: DEPTH_MM,
            shear_mm: [0.0, 0.0],
        },
    ))
    .unwrap();
    println!(
        "physics {:?}\nstatic (same effects) {:?}\nstatic (default layer grid) {:?}",
        pressed, reference.wrench, default_cell.wrench
    );
    assert!(
        pressed.force_n[2] < -0.05,
        "pressing gives Fz < 0: {pressed:?}"
    );
    let e_same = force_err(pressed.force_n, reference.wrench.force_n);
    assert!(e_same < 0.01, "physics vs static, same grid: {e_same}");
    let e_default = force_err(pressed.force_n, default_cell.wrench.force_n);
    assert!(
        e_default < 0.05,
        "physics vs static, default grid: {e_default}"
    );

    let recs = netft.drain_at_least(&stats, 150).await;
    assert!(recs.len() >= 150, "{}", recs.len());
    let mean = NetFtClient::mean(&recs[20..]);
    let read = [mean[0] - tare[0], mean[1] - tare[1], mean[2] - tare[2]];
    println!("Net F/T (tared) {read:?} from {} records", recs.len());
    let e_ft = force_err(read, pressed.force_n);
    assert!(
        e_ft < 0.03,
        "Net F/T vs physics: {e_ft} ({read:?} vs {pressed:?})"
    );
    assert!(read[2] < 0.0);

    // The camera sees the contact: the newest frame differs from the flat one.
    eventually("camera frames in contact", || {
        rig.camera().unwrap().stats().delivered >= 8
    })
    .await;
    let mut last = None;
    while let Some(f) = rig.camera().unwrap().try_recv() {
        last = Some(f);
    }
    let last = last.unwrap();
    assert!(last.capture_t_ns > t_rest - 200_000_000);
    let (flat, pressed) = (
        flat_frame.payload.to_rgb().unwrap(),
        last.payload.to_rgb().unwrap(),
    );
    let diff: u64 = flat
        .as_raw()
        .iter()
        .zip(pressed.as_raw())
        .map(|(a, b)| u64::from(a.abs_diff(*b)))
        .sum();
    assert!(diff > 1000, "the pressed frame looks flat (diff {diff})");
    rig.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sim_rig_runs_on_a_scaled_clock() {
    let cfg = RigConfig::sim_source();
    let clock = Clock::scaled(5.0);
    let rig = SimRig::start(
        &cfg,
        sphere(),
        clock.clone(),
        SimRigOptions::for_config(&cfg),
    )
    .await
    .unwrap();
    clock.sleep(Duration::from_millis(200)).await;
    let s = rig.physics().stats();
    assert!(s.steps >= 10, "{s:?}");
    assert_eq!(s.contact_steps, 0);
    assert_eq!(rig.physics().wrench_at(clock.now_ns()), Wrench::default());
    rig.shutdown().await;
}

/// The rig's pieces hold each other (the physics' pose source holds the arm, the arm's flange
/// sensor reads the physics): neither dropping the rig nor shutting it down may leave the arm
/// ticking, its RTDE port open and its watchdog stopping a program whose client has gone.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dropped_or_shut_down_sim_rig_leaves_no_arm_running() {
    let cfg = RigConfig::sim_source();
    let clock = Clock::scaled(5.0);
    let start = || {
        SimRig::start(
            &cfg,
            sphere(),
            clock.clone(),
            SimRigOptions::for_config(&cfg),
        )
    };

    // Dropped: nothing keeps the arm.
    let rig = start().await.unwrap();
    clock.sleep(Duration::from_millis(50)).await;
    let arm = Arc::downgrade(&rig.ur5e_arc());
    drop(rig);
    eventually("the dropped rig's arm to be freed", || {
        arm.upgrade().is_none()
    })
    .await;

    // Shut down while something still holds the arm: it stops all the same.
    let rig = start().await.unwrap();
    clock.sleep(Duration::from_millis(50)).await;
    let held = rig.ur5e_arc();
    let addr = held.rtde_addr();
    assert!(std::net::TcpStream::connect(addr).is_ok(), "RTDE at {addr}");
    rig.shutdown().await;
    eventually("the shut-down arm's RTDE port to close", || {
        std::net::TcpStream::connect(addr).is_err()
    })
    .await;
    drop(held);
}

/// Winkler contact physics of a sphere on the sim-source gel, with surface fields; the surface
/// frame with it.
fn winkler_sphere(on_demand: bool) -> (Pose, ContactPhysics) {
    let cfg = RigConfig::sim_source();
    let physics = ContactPhysics::new(
        cfg.sensor.surface_frame,
        cfg.elastomer.clone(),
        sphere(),
        PhysicsConfig {
            contact: sim::ContactModel::Winkler,
            on_demand,
            ..PhysicsConfig::default()
        },
        true,
    )
    .unwrap();
    (cfg.sensor.surface_frame, physics)
}

/// The pressed-in depth of the field `field_at(t_ns)` gives, mm (Winkler: the surface follows
/// the indenter where it touches).
fn field_depth_mm(physics: &ContactPhysics, t_ns: u64) -> f64 {
    let (_, f) = physics.field_at(t_ns).expect("a field");
    -f.uz_mm.iter().copied().fold(0.0, f64::min)
}

/// The camera renders a frame after its capture time: `field_at` must give the field of the
/// pose at that time, not the newest one, and fields closer than 2 ms are not kept twice.
#[test]
fn field_at_gives_the_field_of_the_capture_time_not_the_newest() {
    let (frame, physics) = winkler_sphere(false);
    let depth_of = |t: u64| field_depth_mm(&physics, t);
    let shallow = pose_above_surface(&frame, 0.0, 0.0, -0.2);
    let deep = pose_above_surface(&frame, 0.0, 0.0, -0.6);
    physics.update(10_000_000, &shallow).unwrap();
    physics.update(20_000_000, &deep).unwrap();
    // Within 1 ms of the last kept field: computed (wrench) but not kept as a field.
    physics.update(20_500_000, &shallow).unwrap();
    // The pressed-in depth of each field is the indentation (Winkler: the surface follows the
    // indenter where it touches).
    assert!(
        (depth_of(15_000_000) - 0.2).abs() < 0.02,
        "{}",
        depth_of(15_000_000)
    );
    assert!(
        (depth_of(20_000_000) - 0.6).abs() < 0.02,
        "{}",
        depth_of(20_000_000)
    );
    assert!(
        (depth_of(25_000_000) - 0.6).abs() < 0.02,
        "the 20.5 ms field was not kept"
    );
    // Before the first field: the oldest one.
    assert!((depth_of(1) - 0.2).abs() < 0.02);
}

/// A host that stalls must not change what the simulated sensors saw. The physics task is held
/// off (a manual clock that jumps, a runtime that does not run it) while an on-time consumer
/// (the F/T) asks for the newest contact and a late one (the camera) asks for an older instant:
/// the late one must still get the contact of its own instant, within one physics period of
/// motion, not the contact from before the stall. Then the task itself wakes 140 ms late and
/// must replay the ticks it missed at their own poses instead of skipping them.
#[tokio::test]
async fn a_stalled_physics_task_leaves_no_gap_and_late_frames_see_their_own_instant() {
    let (frame, physics) = winkler_sphere(true);
    // Pressing straight down at 4 µm per ms of clock time: 0.8 mm at 200 ms.
    const MM_PER_MS: f64 = 0.004;
    let depth_at = |t_ns: u64| MM_PER_MS * t_ns as f64 * 1e-6;
    let pose_at = move |t_ns: u64| pose_above_surface(&frame, 0.0, 0.0, -depth_at(t_ns));
    let (clock, handle) = Clock::manual();
    physics.update(0, &pose_at(0)).unwrap();
    let _task = physics.spawn(clock.clone(), Arc::new(move |t| (t, pose_at(t))));
    tokio::task::yield_now().await; // the task starts its ticker at 0
    let period_ms = 1e3 / PhysicsConfig::default().rate_hz;
    // One physics period of motion, plus the Winkler field's own error (see the test above).
    let tol_mm = MM_PER_MS * period_ms + 0.02;
    let field_depth = |t_ns: u64| field_depth_mm(&physics, t_ns);

    // The stall: 60 ms pass and the task does not run (this runtime is not yielded to).
    handle.advance(Duration::from_millis(60));
    let _ = physics.wrench_at(60_000_000); // the on-time F/T sample
    for t_ms in [10u64, 30, 50] {
        let got = field_depth(t_ms * 1_000_000);
        let want = depth_at(t_ms * 1_000_000);
        assert!(
            (got - want).abs() <= tol_mm,
            "frame at {t_ms} ms shows {got:.3} mm deep, the indenter was at {want:.3} mm"
        );
    }
    let age_ms = physics.stats().max_field_age_ns as f64 * 1e-6;
    assert!(
        age_ms <= period_ms,
        "field {age_ms} ms older than the frame"
    );

    // The task wakes late: every tick it missed is stepped, none skipped.
    handle.advance(Duration::from_millis(140));
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    while physics.latest().map_or(0, |(t, _)| t) < 200_000_000 {
        assert!(
            std::time::Instant::now() < deadline,
            "the physics task did not catch up"
        );
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    let s = physics.stats();
    assert_eq!(s.skipped_ticks, 0, "{s:?}");
    // 60 ms on demand (one step per 4 ms period, 0 included) and 140 ms replayed.
    let want_steps = (200.0 / period_ms) as u64 + 1;
    assert!(
        s.steps >= want_steps,
        "{s:?}, want at least {want_steps} steps"
    );
    for t_ms in [70u64, 130, 190] {
        let got = field_depth(t_ms * 1_000_000);
        let want = depth_at(t_ms * 1_000_000);
        assert!(
            (got - want).abs() <= tol_mm,
            "frame at {t_ms} ms shows {got:.3} mm deep, the indenter was at {want:.3} mm"
        );
    }
}

/// The UR5e's flange sensor over real RTDE: pressing a gel a hundred times as stiff as the rig's
/// (so the contact force is far above the sensor's 4 N accuracy), `actual_TCP_force` reads the
/// reaction on the tool in the base frame (the gel faces up: +z), within the data sheet's
/// accuracy of the contact physics' wrench on every package.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_ur5e_reports_the_contact_as_its_flange_force_within_the_sensors_accuracy() {
    let mut cfg = RigConfig::sim_source();
    cfg.elastomer.youngs_modulus_mpa *= 100.0;
    let frame = cfg.sensor.surface_frame;
    let (clock, h) = Clock::manual();
    let opts = SimRigOptions {
        initial_robot_mode: robot_mode::RUNNING,
        physics: PhysicsConfig {
            viscoelastic: false,
            ..PhysicsConfig::default()
        },
        ..SimRigOptions::default()
    };
    let rig = SimRig::start(&cfg, sphere(), clock.clone(), opts)
        .await
        .unwrap();
    upload_program(rig.ur5e()).await;
    let mut rtde = RawClient::connect(rig.ur5e().rtde_addr()).await;
    rtde.handshake(2).await;
    let (id, types) = rtde
        .setup_outputs(500.0, &["timestamp", "actual_TCP_force"])
        .await;
    assert!(id.is_some(), "actual_TCP_force refused: {types:?}");
    assert!(rtde.start().await);
    let spec = hardware_mocks::ur5e::UR5E_FLANGE;
    let forces = |rows: &[Vec<Value>]| -> Vec<[f64; 6]> {
        rows.iter()
            .map(|r| match r[1] {
                Value::Vector6d(v) => v,
                ref other => panic!("actual_TCP_force is {other:?}"),
            })
            .collect()
    };

    // Above the gel: nothing but the sensor's own error.
    rig.ur5e().step_ticks(&h, 50).await;
    let above = forces(&rtde.collect_data(&types, Duration::from_millis(300)).await);
    assert!(above.len() >= 40, "{} packages", above.len());
    for f in &above {
        for k in 0..3 {
            assert!(f[k].abs() <= spec.force_accuracy_n, "unloaded: {f:?}");
        }
    }

    // Down 0.5 mm into the gel, and rest there.
    let target = pose_above_surface(&frame, 0.0, 0.0, -DEPTH_MM);
    let _client = movel(rig.ur5e(), 1, target, 0.01, 0.1).await;
    let mut ticks = 0;
    while rig.ur5e().snapshot().output_int_registers[control::OUT_DONE_SEQ as usize] != 1 {
        rig.ur5e().step_ticks(&h, 1).await;
        ticks += 1;
        assert!(ticks < 400, "the move did not finish");
    }
    rig.ur5e().step_ticks(&h, 20).await;
    physics_reaches(rig.physics(), rig.ur5e().snapshot().t_ns).await;
    let _ = rtde.collect_data(&types, Duration::from_millis(200)).await;
    let on_gel = rig.physics().latest().unwrap().1;
    let truth = hardware_mocks::ur5e::flange::on_tool_in_base(&frame, &on_gel);
    assert!(
        truth[2] > 2.0 * spec.force_accuracy_n,
        "the stiff gel pushes the tool up well past the sensor's accuracy: {truth:?}"
    );
    rig.ur5e().step_ticks(&h, 200).await;
    let pressed = forces(&rtde.collect_data(&types, Duration::from_millis(300)).await);
    assert!(pressed.len() >= 150, "{} packages", pressed.len());
    let mut mean = [0.0; 3];
    for f in &pressed {
        for k in 0..3 {
            assert!(
                (f[k] - truth[k]).abs() <= spec.force_accuracy_n,
                "axis {k}: read {f:?}, true {truth:?}"
            );
            mean[k] += f[k] / pressed.len() as f64;
        }
        for k in 3..6 {
            assert!((f[k] - truth[k]).abs() <= spec.torque_accuracy_nm, "{f:?}");
        }
    }
    // The readings scatter about the truth plus a fixed offset within the data sheet's bounds.
    for k in 0..3 {
        assert!(
            (mean[k] - truth[k]).abs() <= spec.force_accuracy_n - spec.force_precision_n + 0.25,
            "axis {k}: mean {mean:?} against {truth:?}"
        );
    }
    // The controller's own snapshot reports what the stream carried.
    let snap = rig.ur5e().snapshot().actual_tcp_force;
    assert!(
        (snap[2] - truth[2]).abs() <= spec.force_accuracy_n,
        "{snap:?}"
    );
    rig.shutdown().await;
}

/// What the F/T asks between the physics' steps must not change the contact's path: the
/// layer model has history (stick on the gel's material points), and a step depends on its
/// length, so a step made at an F/T sample's own instant used to split the next grid step in
/// two and move every force after it. Two physics follow the same press and slide of a
/// sphere (friction and relaxation on): one is asked only at its 50 Hz grid's ticks, the
/// other by an F/T at 1 kHz besides, which makes it solve between the ticks wherever the
/// motion leaves the line of its last steps (the stage's start, the turn into the slide).
/// The wrench at every tick must be the same, bit for bit, and the F/T's reads must have
/// solved between the ticks (or this compares nothing).
#[tokio::test]
async fn an_ft_reading_between_the_physics_steps_leaves_the_steps_as_they_were() {
    let cfg = RigConfig::sim_source();
    let frame = cfg.sensor.surface_frame;
    let make = || {
        ContactPhysics::new(
            frame,
            cfg.elastomer.clone(),
            sphere(),
            PhysicsConfig::default(),
            false,
        )
        .unwrap()
    };
    // 0.4 mm down in 100 ms, then 0.2 mm along x in 100 ms, then resting.
    let pose_at = move |t_ns: u64| {
        let t_ms = t_ns as f64 * 1e-6;
        let depth = 0.4 * (t_ms / 100.0).min(1.0);
        let x = 0.2 * ((t_ms - 100.0) / 100.0).clamp(0.0, 1.0);
        (t_ns, pose_above_surface(&frame, x, 0.0, 0.05 - depth))
    };
    let (clock, _handle) = Clock::manual();
    let (grid_only, with_ft) = (make(), make());
    // The tasks never run (the manual clock stays at 0): every step is asked for below.
    let _a = grid_only.spawn(clock.clone(), Arc::new(pose_at));
    let _b = with_ft.spawn(clock.clone(), Arc::new(pose_at));
    let period_ns = (1e9 / PhysicsConfig::default().rate_hz) as u64;
    let mut in_contact = 0;
    for t in (0..=260_000_000u64).step_by(1_000_000) {
        // The F/T's sample, then the physics task's tick (the sample may have stepped it).
        let _ = with_ft.wrench_at(t);
        if t % period_ns == 0 {
            let (_, tcp) = pose_at(t);
            let a = grid_only.update(t, &tcp).unwrap();
            let b = with_ft.update(t, &tcp).unwrap();
            let solves = with_ft.stats().off_grid_steps;
            assert_eq!(
                a.to_array(),
                b.to_array(),
                "at {} ms, after {solves} solves between the ticks",
                t / 1_000_000
            );
            in_contact += usize::from(a.force_n[2] < -0.01);
        }
    }
    let off_grid = with_ft.stats().off_grid_steps;
    assert!(
        off_grid >= 3,
        "the F/T solved between the ticks {off_grid} times"
    );
    assert!(in_contact >= 10, "{in_contact} ticks in contact");
}

/// The sensor physics of sim-source pressing the built-in `indenter` 0.6 mm into the gel in
/// 200 ms, then sliding it at 300° by `slide_mm` at `speed_mm_s`; with the pose source that
/// motion is (clock ns → pose).
fn pressed_then_sliding(
    indenter: &str,
    speed_mm_s: f64,
    slide_mm: f64,
) -> (
    ContactPhysics,
    impl Fn(u64) -> (u64, Pose) + Copy + Send + Sync + 'static,
) {
    let cfg = RigConfig::sim_source();
    let frame = cfg.sensor.surface_frame;
    let physics = ContactPhysics::new(
        frame,
        cfg.elastomer.clone(),
        Arc::new(Indenter::builtin(indenter).unwrap()),
        PhysicsConfig::default(),
        true,
    )
    .unwrap();
    let (c, s) = (300f64.to_radians().cos(), 300f64.to_radians().sin());
    let pose_at = move |t_ns: u64| {
        let t_ms = t_ns as f64 * 1e-6;
        let depth = 0.6 * (t_ms / 200.0).min(1.0);
        let along = ((t_ms - 200.0) * speed_mm_s * 1e-3).clamp(0.0, slide_mm);
        (
            t_ns,
            pose_above_surface(&frame, along * c, along * s, -depth),
        )
    };
    (physics, pose_at)
}

/// The force must not jump where the camera's frames are, at the grid's ticks. A step does not
/// leave a history that gives its own force back (the contact search ↔ friction loop does not
/// settle where a ridged face slides), so a probe just after a tick that started from the
/// tick's own step was up to 0.14 N off it on paralines, and the F/T samples paired with a
/// frame on that tick carried the jump into its label. Paralines is pressed 0.6 mm deep and
/// slid 1 mm at 300° at the plan's 1 mm/s; around each tick of the slide the contact is probed
/// 1 ms before and 1 ms after. A force continuous at the tick changes about as much in the
/// millisecond after it as in the one before (1 µm of travel each): the two changes must
/// agree within the labels' bound, 0.05 N, on every axis (the ridges crossing the gel's
/// sub-samples make the force kinked, not smooth: up to 0.04 N measured; the jump was 0.18 N).
#[tokio::test]
async fn the_force_is_continuous_across_a_grid_tick_where_a_ridged_face_slides() {
    // Down 0.6 mm in 200 ms, then the slide at 1 mm/s.
    let (physics, pose_at) = pressed_then_sliding("paralines", 1.0, 1.0);
    let (clock, _handle) = Clock::manual();
    let _task = physics.spawn(clock.clone(), Arc::new(pose_at));
    let period_ns = (1e9 / PhysicsConfig::default().rate_hz) as u64;
    // A probe at `t_ns` (a frame asked for past the newest step), and its wrench.
    let probe = |t_ns: u64| {
        assert!(physics.field_at(t_ns).is_some());
        physics.wrench_at(t_ns)
    };
    let mut worst = (0.0f64, 0);
    for k in 0..=60u64 {
        let g = k * period_ns;
        // Past the slide's first steps (stick turning into slip), before its end (a kink).
        let slide = g > 240_000_000 && g < 1_200_000_000;
        let before = slide.then(|| probe(g - 1_000_000));
        let at_tick = physics.update(g, &pose_at(g).1).unwrap();
        if let Some(before) = before {
            let after = probe(g + 1_000_000);
            for a in 0..3 {
                let left = at_tick.force_n[a] - before.force_n[a];
                let right = after.force_n[a] - at_tick.force_n[a];
                if (right - left).abs() > worst.0 {
                    worst = ((right - left).abs(), g / 1_000_000);
                }
            }
        }
    }
    assert!(
        worst.0 <= 0.05,
        "the force changes {:.3} N more in the 1 ms after the tick at {} ms than in the 1 ms before",
        worst.0,
        worst.1
    );
}

/// A flat face sliding under friction changes its force smoothly between the physics ticks: its
/// walls cross the cells' sub-samples gradually (`sim/contact/geometry.rs`). Probes 0.5 ms
/// apart (1 µm of slide at the plan's 2 mm/s) within each half period, where they start from
/// one history: with point-sampled walls the hexagon's force moved by up to 0.025 N and dotin's
/// (a ring around a disc) by up to 0.051 N from one probe to the next; filtered, 0.003 and
/// 0.010 N. The bound is under half the labels' 0.05 N budget: a step between two F/T samples
/// moves a label interpolated across it by up to its size.
#[tokio::test(flavor = "current_thread")]
async fn a_sliding_flat_face_changes_its_force_smoothly_between_ticks() {
    for name in ["hexagon", "dotin"] {
        // Down 0.6 mm in 200 ms, then the slide at 2 mm/s for 300 ms.
        let (physics, pose_at) = pressed_then_sliding(name, 2.0, 0.6);
        let (clock, _handle) = Clock::manual();
        let _task = physics.spawn(clock.clone(), Arc::new(pose_at));
        let period_ns = (1e9 / PhysicsConfig::default().rate_hz) as u64;
        let probes = 20u64; // a half period in 0.5 ms steps
        let mut worst = (0.0f64, 0);
        for k in 0..=25u64 {
            let g = k * period_ns;
            physics.update(g, &pose_at(g).1).unwrap();
            if g < 240_000_000 {
                continue; // past touch-down and the slide's first steps (stick turning to slip)
            }
            // Each half period's probes start from one history (`ContactPhysics::step_at`).
            for half in 0..2u64 {
                let mut last: Option<[f64; 3]> = None;
                for j in 1..probes {
                    let t = g + half * period_ns / 2 + j * period_ns / (2 * probes);
                    assert!(physics.field_at(t).is_some());
                    let f = physics.wrench_at(t).force_n;
                    if let Some(l) = last {
                        for a in 0..3 {
                            if (f[a] - l[a]).abs() > worst.0 {
                                worst = ((f[a] - l[a]).abs(), t / 1_000_000);
                            }
                        }
                    }
                    last = Some(f);
                }
            }
        }
        assert!(
            worst.0 <= 0.02,
            "{name}: the force moved {:.4} N in 0.5 ms at {} ms",
            worst.0,
            worst.1
        );
    }
}
