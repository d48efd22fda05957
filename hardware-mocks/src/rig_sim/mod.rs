//! The simulated rig as one scene: the simulated UR5e's TCP moves the indenter, and the contact
//! gives both the force (sampled by the Net F/T mock) and the image (rendered for the simulated
//! camera).
//!
//! # Pieces
//!
//! - [`ContactPhysics`]: a [`Simulator`](crate::sim::Simulator) stepped at a fixed rate of clock time
//!   ([`PhysicsConfig::rate_hz`], default 50 Hz) from the TCP pose of a pose source
//!   (the simulated UR5e's [`Ur5e::snapshot`]). Every step appends `(t_ns, wrench)` to a ring
//!   buffer, keyed by the *pose's* time (the controller tick the pose belongs to), and keeps the
//!   latest [`SurfaceField`](crate::sim::SurfaceField) when a camera needs it. It implements [`WrenchSource`](crate::truth::WrenchSource):
//!   [`WrenchSource::wrench_at`](crate::truth::WrenchSource::wrench_at) interpolates linearly between the two buffered samples around
//!   `t_ns` (clamped at both ends), so an F/T mock sampling at 1–7 kHz costs no extra solves.
//! - [`PhysicsRenderer`]: a [`FrameRenderer`](crate::camera::FrameRenderer) that shades the latest surface field with the
//!   sensor's optics ([`optics::render`](crate::sim::optics::render)).
//! - [`SimRig`]: starts the UR5e, the physics task, a Net F/T mock driven by the physics and,
//!   optionally, a simulated camera driven by the renderer, all on one [`Clock`]. The UR5e's
//!   flange force/torque sensor (`actual_TCP_force`) reads the same physics
//!   ([`crate::ur5e::flange`]).
//!
//! # Geometry
//!
//! The TCP is the indenter tip (see `rig_core::config`, "TCP at contact"). What presses is the
//! **physical** tip, `pose_trans(flange, tool_offset)` ([`Ur5e::tip_pose_moving`], with the
//! UR5e's [`Ur5eConfig::tool_offset`], identity by default), not the TCP the controller reports: a
//! program whose `set_tcp` does not match the tool presses with the wrong point, as a real rig
//! would. The tip's pose is expressed
//! in the sensor surface frame, `p = pose_trans(pose_inv(surface_frame), tcp)`; then
//! `contact_mm = (p.x, p.y)·1000`, `depth_mm = −p.z·1000`, `shear_mm = [0, 0]`: the indenter axis
//! is at the TCP, and shearing is simply the contact point moving, with friction history
//! ([`FrictionModel::Incremental`](crate::sim::FrictionModel::Incremental)) carrying the stick/slip state from step to step. Only the
//! TCP position is used: the indenter is assumed to stay "tool pointing down" (the TCP
//! orientation is not checked). At `depth_mm ≤ 0` the indenter is out of contact: the wrench is
//! zero, the normal solver is skipped, and the friction history is forgotten (the gel is
//! unloaded). A depth beyond the gel thickness cannot be simulated: the step is counted in
//! [`PhysicsStats::errors`] and the last wrench is held.
//!
//! # Sign convention of the wrench
//!
//! The F/T tool frame has the **surface frame's axes**, with its origin at the **indenter tip**
//! (the TCP). The wrench is the one the indenter exerts **on the gel** (the simulator's own
//! convention), so pressing gives **Fz < 0**, matching the paper's range Fz −16..0 N. Torques
//! are about the tip: the simulator's torque (about the contact point on the undeformed surface,
//! `(x, y, 0)`) is moved down to the tip `(x, y, −depth)`: `T_tip = T_c + (0, 0, depth) × F`,
//! i.e. `Tx −= depth·Fy`, `Ty += depth·Fx` (N·mm). The Net F/T mock's [`SensorModel`] gets the
//! rig config's tool transform, so a reader applying the same transform recovers this wrench.
//!
//! # Cost
//!
//! The default physics ([`PhysicsConfig::default`], what `rig run` uses) is the sensor physics
//! every command uses: the finite layer at 0.4 mm cells with Coulomb friction and the
//! elastomer's relaxation, stepped at 50 Hz of clock time. One step in contact costs about
//! 0.2–0.4 ms for the cone, sphere and prism, whose contacts are solved on a window of the
//! grid, and 1.4–2 ms for the wide flat faces, which need the whole grid (release build,
//! 2-core machine; the window is described in `sim/contact/window.rs`). At ×10 a step has
//! 2 ms of real time, so the cone's full plan runs at the clock's speed (`rig bench run`).
//! Steps sit on a grid of whole periods of clock time, and the simulated camera captures at
//! whole multiples of its own period, so at 25 fps every frame's contact is a step. The physics
//! task paces the simulated clock ([`PHYSICS_PACER_LEAD`]): simulated time runs at most a tick
//! and 2 ms of real time past the newest step, so a busy host slows the simulation instead of
//! letting the F/T twins run ahead of the contact.
//!
//! # Timing limits
//!
//! With [`PhysicsConfig::on_demand`] (the default), a frame asked for at a time past the
//! newest physics step first steps the physics through the grid ticks up to that time, and
//! probes that time itself if it is off the grid (a solve from the newest grid step that the
//! steps after it do not start from), at the poses the arm had then
//! ([`Ur5e::tip_pose_moving`]: between ticks, where the arm is on its way). A frame thus shows
//! the contact of its own capture time however late its task ran
//! ([`PhysicsStats::max_field_age_ns`] says how stale the images were).
//!
//! The F/T twins sample at 1 kHz, twenty times per step, so they read the wrench between steps
//! without solving: the pose of the sample is read off the line through the last two steps'
//! poses and the wrench taken along that line, which follows the motion's own speed (ramps
//! included). Where the pose leaves that line (a stage starting, a reversal, the first touch)
//! or runs more than 5 µm (or two step spacings) past it, the F/T's read probes the physics at
//! its own pose, after the grid's ticks before it ([`PhysicsStats::off_grid_steps`]). Only the
//! grid's steps carry the contact's history (stick, relaxation), so the contact's path does
//! not depend on when the F/T or the camera asked. While the indenter rests, the wrench is
//! extrapolated in time along the last two steps (relaxation). A cheap model (Winkler, Hertz)
//! simply probes at every F/T sample's time. Solves that cost milliseconds run off the async
//! workers (`block_in_place`), so the controller and RTDE tasks are never held up by one.
//! Without on-demand stepping, the wrench past the newest step is the newest one (held).

mod config;
mod lock;
mod physics;
mod read_ahead;
mod tape;

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;

use rig_core::clock::Clock;
use rig_core::config::RigConfig;
use rig_core::ft::netft;
use rig_core::ft::transform::ToolTransform;
use rig_core::indenter::Indenter;
use rig_core::pose::{self, Pose, pose_trans};
use tokio::task::JoinHandle;

use crate::camera::{SimCamera, SimCameraConfig};
use crate::nano17::SensorModel;
use crate::nano17::netft::{NetFtMock, NetFtMockConfig};
use crate::nano17::serial::{SerialControllerMock, SerialMockConfig};
use crate::sim::optics::ImageEffects;
use crate::truth::SharedWrenchSource;
use crate::ur5e::{FlangeSensor, UR5E_FLANGE, Ur5e, Ur5eConfig};

use config::invalid;
pub use config::{DEFAULT_HISTORY, DEFAULT_PHYSICS_RATE_HZ, PhysicsConfig};
pub use physics::*;
pub use tape::{
    CROP_MM, ContactCache, MATCH_MM, MAX_DRIFT_NS, MAX_REST_SLIP_NS, TapeStats, cache_key,
};

/// Mixed into [`SimRigOptions::netft_seed`] for the UR5e flange sensor's errors, so the arm's
/// and the Nano17's noise are not the same sequence.
const FLANGE_SEED: u64 = 0x5552_3565_666c_616e;

/// How [`SimRig::start`] sets the simulated rig up beyond the rig config.
#[derive(Debug, Clone)]
pub struct SimRigOptions {
    /// The UR5e's TCP at start. `None`: `plan.approach_height_mm` above the surface centre,
    /// tool pointing down (rotation vector `(π, 0, 0)` in the surface frame).
    pub home_pose: Option<Pose>,
    /// robot_mode at start (the rig powers a POWER_OFF robot up through the dashboard).
    pub initial_robot_mode: i32,
    pub physics: PhysicsConfig,
    /// Net F/T records per second. `None`: `force_sensor.rate_hz` of the config, else 1 kHz.
    pub netft_rate_hz: Option<f64>,
    /// How the simulated Nano17 is connected: a Net F/T on UDP (default) or an F/T controller
    /// on a serial pty (ASCII records), both driven by the same physics.
    pub ft_front_end: SimFtFrontEnd,
    /// Seed of the F/T noise.
    pub netft_seed: u64,
    /// Start a simulated camera with this behaviour; `None`: no camera (and no surface field).
    pub camera: Option<SimCameraConfig>,
    /// Image effects of the camera; `None`: the sensor's own `[optics.effects]`
    /// ([`ImageEffects::from_optics`]), so a recording shows what that sensor's camera shows.
    pub image_effects: Option<ImageEffects>,
    /// Noise seed of the camera's images.
    pub image_seed: u64,
    /// The contact cache's root directory (`None`: no cache, every contact is solved): the
    /// physics replays the episodes a run with the same gel, indenter and physics left there,
    /// and leaves its own (simulate once, render per sensor; see [`ContactCache`]).
    pub contact_cache: Option<std::path::PathBuf>,
}

impl Default for SimRigOptions {
    fn default() -> Self {
        Self {
            home_pose: None,
            initial_robot_mode: rig_core::control::robot_mode::POWER_OFF,
            physics: PhysicsConfig::default(),
            netft_rate_hz: None,
            ft_front_end: SimFtFrontEnd::NetFt,
            netft_seed: 49152,
            camera: None,
            image_effects: None,
            image_seed: 0,
            contact_cache: None,
        }
    }
}

impl SimRigOptions {
    /// Defaults, with an ideal camera at `camera.fps`, sending `camera.format`, when the config
    /// has a camera.
    pub fn for_config(config: &RigConfig) -> Self {
        Self {
            camera: config.camera.as_ref().map(SimCameraConfig::for_camera),
            ..Self::default()
        }
    }
}

/// The TCP pose `height_mm` above the surface point `(x_mm, y_mm)` (negative: below it, pressed
/// in), tool pointing down (rotation vector `(π, 0, 0)` in the surface frame), in the base frame.
pub fn pose_above_surface(surface_frame: &Pose, x_mm: f64, y_mm: f64, height_mm: f64) -> Pose {
    pose_trans(
        surface_frame,
        &Pose::new(
            x_mm * 1e-3,
            y_mm * 1e-3,
            height_mm * 1e-3,
            std::f64::consts::PI,
            0.0,
            0.0,
        ),
    )
}

/// How the simulated Nano17 reaches the rig.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SimFtFrontEnd {
    /// A Net F/T box on loopback UDP (RDT).
    #[default]
    NetFt,
    /// An ATI F/T controller on a serial pty (ASCII records at the configured rate).
    Serial,
    /// An NI card read through NI-DAQmx: the stand-in library (`nidaqmx-standin`), which the
    /// rig loads and hands the physics' wrench, the clock and [`SimFt::faults`]. No task of
    /// the simulated rig runs for it.
    NiDaqmx,
}

/// The simulated F/T front end that runs.
pub enum SimFt {
    NetFt(NetFtMock),
    Serial(SerialControllerMock),
    /// The NI card lives in the stand-in library; its faults are polled through its hook.
    NiDaqmx {
        faults: Arc<crate::nano17::Faults>,
        stats: Arc<crate::nano17::MockStats>,
    },
}

impl SimFt {
    /// Fault injection (unplug, mute, saturate, garbage ...).
    pub fn faults(&self) -> &Arc<crate::nano17::Faults> {
        match self {
            SimFt::NetFt(m) => m.faults(),
            SimFt::Serial(m) => m.faults(),
            SimFt::NiDaqmx { faults, .. } => faults,
        }
    }
    pub fn stats(&self) -> &Arc<crate::nano17::MockStats> {
        match self {
            SimFt::NetFt(m) => m.stats(),
            SimFt::Serial(m) => m.stats(),
            SimFt::NiDaqmx { stats, .. } => stats,
        }
    }
    async fn shutdown(self) {
        match self {
            SimFt::NetFt(m) => m.shutdown().await,
            SimFt::Serial(m) => m.shutdown().await,
            SimFt::NiDaqmx { .. } => {}
        }
    }
}

/// The running simulated rig: UR5e, contact physics, Net F/T and (optionally) camera on one
/// clock. Dropping it stops every task.
pub struct SimRig {
    /// Holds simulated time while the runtime the rig runs on is stalled.
    _runtime_pacer: AbortOnDrop,
    ur5e: Arc<Ur5e>,
    physics: ContactPhysics,
    physics_task: AbortOnDrop,
    ft: SimFt,
    camera: Option<SimCamera>,
}

impl SimRig {
    /// Starts every piece on `clock` (within a tokio runtime). See [`SimRigOptions`].
    pub async fn start(
        config: &RigConfig,
        indenter: Arc<Indenter>,
        clock: Clock,
        opts: SimRigOptions,
    ) -> io::Result<SimRig> {
        let frame = config.sensor.surface_frame;
        let home = opts.home_pose.unwrap_or_else(|| {
            pose_above_surface(&frame, 0.0, 0.0, config.plan.approach_height_mm)
        });
        // The simulated indenter is mounted as the config says: its tip is `robot.tcp_offset`
        // from the flange (a lab rig's program sets the same TCP with `set_tcp`). `home` is
        // where the tip starts; the controller starts with no TCP offset, at the flange.
        let tool_offset = config
            .robot
            .tcp_offset
            .map_or_else(Pose::default, Pose::from_array);
        let ur_cfg = Ur5eConfig {
            home_pose: pose::pose_trans(&home, &pose::pose_inv(&tool_offset)),
            tool_offset,
            initial_robot_mode: opts.initial_robot_mode,
            max_frequency_hz: config.robot.controller.max_rtde_frequency_hz(),
            ..Ur5eConfig::default()
        };
        let runtime_pacer = AbortOnDrop(Some(rig_core::clock::spawn_runtime_pacer(
            &clock,
            rig_core::clock::SIM_PACER_LEAD,
        )));
        let ur5e = Arc::new(Ur5e::start(ur_cfg, clock.clone()).await?);

        let cache = match &opts.contact_cache {
            Some(root) => Some(
                ContactCache::open(root, &config.elastomer, &indenter, &opts.physics).map_err(
                    |e| {
                        io::Error::new(
                            e.kind(),
                            format!("contact cache in {}: {e}", root.display()),
                        )
                    },
                )?,
            ),
            None => None,
        };
        let physics = ContactPhysics::with_cache(
            frame,
            config.elastomer.clone(),
            indenter,
            opts.physics.clone(),
            opts.camera.is_some(),
            cache,
        )?;
        // The arm's own flange sensor reads the same contact (the reaction on the tool, with
        // the UR5e data sheet's accuracy), from the newest physics step: never a solve on the
        // controller's tick. It holds the physics weakly: the physics' pose source holds the arm.
        ur5e.fit_flange_sensor(FlangeSensor::new(
            Arc::new(physics.latest_reader()),
            frame,
            UR5E_FLANGE,
            opts.netft_seed ^ FLANGE_SEED,
        ));
        // The state at start, so the F/T and the camera have a sample from t = start.
        let (t_start, tip) = ur5e.tip_pose_now();
        if let Err(e) = physics.update(t_start, &tip) {
            tracing::warn!("contact physics at start: {e}");
        }
        let src = ur5e.clone();
        let physics_task = AbortOnDrop(Some(physics.spawn(
            clock.clone(),
            // Where the tip was at the time asked for (due ticks processed first; between
            // the controller's ticks, on its way), so a step, on time or late, sees the
            // contact of its own instant.
            Arc::new(move |t_ns| {
                src.tip_pose_moving(t_ns)
                    .unwrap_or_else(|| src.tip_pose_now())
            }),
        )));

        let fs = config.force_sensor.as_ref();
        let mut model = SensorModel::nano17(opts.netft_seed);
        if let Some(fs) = fs {
            let r = fs.tool_rotation_deg.map(f64::to_radians);
            model.tool = ToolTransform::from_angles(fs.tool_offset_mm, r)
                .map_err(|e| invalid(format!("force_sensor tool transform: {e}")))?;
        }
        let rate_hz = opts
            .netft_rate_hz
            .or(fs.map(|f| f.rate_hz))
            .unwrap_or(rig_core::ft::DEFAULT_RATE_HZ);
        let source: SharedWrenchSource = Arc::new(physics.clone());
        let ft = match opts.ft_front_end {
            SimFtFrontEnd::NetFt => {
                let nf_cfg = NetFtMockConfig {
                    rate_hz,
                    counts_per_force: fs
                        .and_then(|f| f.counts_per_force)
                        .unwrap_or(netft::FACTORY_COUNTS_PER_FORCE),
                    counts_per_torque: fs
                        .and_then(|f| f.counts_per_torque)
                        .unwrap_or(netft::FACTORY_COUNTS_PER_TORQUE),
                    seed: opts.netft_seed,
                    ..NetFtMockConfig::default()
                };
                SimFt::NetFt(NetFtMock::start(nf_cfg, model, source, clock.clone()).await?)
            }
            SimFtFrontEnd::Serial => {
                let cfg = SerialMockConfig {
                    rate_hz,
                    seed: opts.netft_seed,
                    ..SerialMockConfig::default()
                };
                SimFt::Serial(SerialControllerMock::start(
                    cfg,
                    model,
                    source,
                    clock.clone(),
                )?)
            }
            SimFtFrontEnd::NiDaqmx => SimFt::NiDaqmx {
                faults: Arc::default(),
                stats: Arc::default(),
            },
        };

        let camera = match &opts.camera {
            Some(cam_cfg) => {
                let optics = config.optics.clone().unwrap_or_default();
                let effects = opts
                    .image_effects
                    .unwrap_or_else(|| ImageEffects::from_optics(&optics));
                let renderer =
                    PhysicsRenderer::new(physics.clone(), optics, effects, opts.image_seed);
                Some(
                    SimCamera::spawn(clock.clone(), cam_cfg.clone(), Arc::new(renderer))
                        .map_err(|e| invalid(format!("simulated camera: {e}")))?,
                )
            }
            None => None,
        };
        tracing::info!(
            rtde = %ur5e.rtde_addr(),
            ft = %match &ft {
                SimFt::NetFt(m) => format!("Net F/T {}", m.addr()),
                SimFt::Serial(m) => format!("serial {}", m.path().display()),
                SimFt::NiDaqmx { .. } => "NI-DAQmx stand-in (loaded by the rig)".to_owned(),
            },
            camera = camera.is_some(),
            "simulated rig started"
        );
        Ok(SimRig {
            _runtime_pacer: runtime_pacer,
            ur5e,
            physics,
            physics_task,
            ft,
            camera,
        })
    }

    /// The simulated UR5e (its RTDE, dashboard and script addresses, faults, snapshot).
    pub fn ur5e(&self) -> &Ur5e {
        &self.ur5e
    }

    pub fn physics(&self) -> &ContactPhysics {
        &self.physics
    }

    /// The Net F/T mock's UDP address (`None` with a serial front end).
    pub fn netft_addr(&self) -> Option<SocketAddr> {
        match &self.ft {
            SimFt::NetFt(m) => Some(m.addr()),
            SimFt::Serial(_) | SimFt::NiDaqmx { .. } => None,
        }
    }

    /// The serial F/T controller's pty (`None` with a Net F/T front end).
    pub fn ft_serial_path(&self) -> Option<&std::path::Path> {
        match &self.ft {
            SimFt::Serial(m) => Some(m.path()),
            SimFt::NetFt(_) | SimFt::NiDaqmx { .. } => None,
        }
    }

    /// The simulated F/T front end (faults, counters).
    pub fn ft(&self) -> &SimFt {
        &self.ft
    }

    /// The UR5e, shareable (for fault injection from another task).
    pub fn ur5e_arc(&self) -> Arc<Ur5e> {
        self.ur5e.clone()
    }

    /// The simulated camera, when one was asked for.
    pub fn camera(&mut self) -> Option<&mut SimCamera> {
        self.camera.as_mut()
    }

    /// Takes the camera out (to hand it to a frame reader).
    pub fn take_camera(&mut self) -> Option<SimCamera> {
        self.camera.take()
    }

    /// Stops every task and closes every socket, and waits for the contact tapes being
    /// written.
    pub async fn shutdown(self) {
        let SimRig {
            _runtime_pacer,
            ur5e,
            physics,
            physics_task,
            ft,
            camera,
        } = self;
        // The tapes flush off the runtime, without holding the physics (whose pose source
        // holds the arm): the arm shuts down now, not once the last tape is on disk.
        let cache = physics.tape_cache();
        let flushing = tokio::task::spawn_blocking(move || {
            if let Some(c) = cache {
                c.flush();
            }
        });
        _runtime_pacer.stop().await;
        drop(camera);
        ft.shutdown().await;
        physics_task.stop().await;
        drop(physics);
        match Arc::try_unwrap(ur5e) {
            Ok(ur) => ur.shutdown().await,
            Err(ur) => ur.halt(),
        }
        let _ = flushing.await;
    }
}

/// Aborts its task when dropped.
struct AbortOnDrop(Option<JoinHandle<()>>);

impl AbortOnDrop {
    async fn stop(mut self) {
        if let Some(t) = self.0.take() {
            t.abort();
            let _ = t.await;
        }
    }
}

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        if let Some(t) = &self.0 {
            t.abort();
        }
    }
}
