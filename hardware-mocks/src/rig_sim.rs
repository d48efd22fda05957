//! The simulated rig as one scene: the simulated UR5e's TCP moves the indenter, and the contact
//! gives both the force (sampled by the Net F/T mock) and the image (rendered for the simulated
//! camera).
//!
//! # Pieces
//!
//! - [`ContactPhysics`]: a [`Simulator`] stepped at a fixed rate of clock time
//!   ([`SimRigOptions::physics_rate_hz`], default 250 Hz) from the TCP pose of a pose source
//!   (the simulated UR5e's [`Ur5e::snapshot`]). Every step appends `(t_ns, wrench)` to a ring
//!   buffer, keyed by the *pose's* time (the controller tick the pose belongs to), and keeps the
//!   latest [`SurfaceField`] when a camera needs it. It implements [`WrenchSource`]:
//!   [`WrenchSource::wrench_at`] interpolates linearly between the two buffered samples around
//!   `t_ns` (clamped at both ends), so an F/T mock sampling at 1–7 kHz costs no extra solves.
//! - [`PhysicsRenderer`]: a [`FrameRenderer`] that shades the latest surface field with the
//!   sensor's optics ([`optics::render`]).
//! - [`SimRig`]: starts the UR5e, the physics task, a Net F/T mock driven by the physics and,
//!   optionally, a simulated camera driven by the renderer, all on one [`Clock`].
//!
//! # Geometry
//!
//! The TCP is the indenter tip (see `rig_core::config`, "TCP at contact"). Its pose is expressed
//! in the sensor surface frame, `p = pose_trans(pose_inv(surface_frame), tcp)`; then
//! `contact_mm = (p.x, p.y)·1000`, `depth_mm = −p.z·1000`, `shear_mm = [0, 0]`: the indenter axis
//! is at the TCP, and shearing is simply the contact point moving, with friction history
//! ([`FrictionModel::Incremental`]) carrying the stick/slip state from step to step. Only the
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
//! One step, measured (release build, 2-core machine, cone 0.6 mm deep, sliding): finite layer
//! at 0.4 mm cells with [`FrictionModel::Incremental`] about 5.4 ms; the same without friction
//! 0.7 ms; 0.5 mm cells with friction 2.3 ms; Winkler with friction 27 µs. At 250 Hz of clock
//! time the default setting therefore needs about 1.4 s of one core per clock second: on a
//! scaled clock the task cannot keep up, skips ticks ([`PhysicsStats::skipped_ticks`]) and the
//! buffer gets sparser (each sample is still exact for its pose time, and `wrench_at`
//! interpolates between them). Choose [`PhysicsConfig`] for the clock's speed.
//!
//! # Timing limits
//!
//! The wrench at a time later than the newest physics step is the newest one (held, not
//! extrapolated): an F/T sample lags the pose by at most one physics period plus one controller
//! tick. The camera renders the newest field at its capture time, with the same lag.

use std::collections::VecDeque;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::config::{ElastomerConfig, RigConfig};
use rig_core::ft::netft;
use rig_core::ft::transform::ToolTransform;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;
use rig_core::pose::{Pose, pose_inv, pose_trans};
use rig_core::wrench::Wrench;
use tokio::task::JoinHandle;

use crate::camera::{FrameRenderer, SimCamera, SimCameraConfig};
use crate::nano17::SensorModel;
use crate::nano17::netft::{NetFtMock, NetFtMockConfig};
use crate::nano17::serial::{SerialControllerMock, SerialMockConfig};
use crate::sim::optics::{self, ImageEffects};
use crate::sim::{
    ContactModel, Effects, FrictionModel, IndenterPose, Scene, SimError, Simulator, SurfaceField,
};
use crate::truth::{SharedWrenchSource, WrenchSource};
use crate::ur5e::{Ur5e, Ur5eConfig};

/// Default physics rate, Hz of clock time.
pub const DEFAULT_PHYSICS_RATE_HZ: f64 = 250.0;
/// Default grid cell of the contact solve during a run, mm (coarser than the simulator's
/// default, for speed).
pub const DEFAULT_RUN_CELL_MM: f64 = 0.4;
/// Default number of `(t_ns, wrench)` samples kept: 4 s at 250 Hz.
pub const DEFAULT_HISTORY: usize = 1000;

/// How the contact is simulated during a run.
#[derive(Debug, Clone, PartialEq)]
pub struct PhysicsConfig {
    /// Physics steps per second of clock time.
    pub rate_hz: f64,
    /// Normal contact model.
    pub contact: ContactModel,
    /// Grid cell, mm (`None`: the simulator's default).
    pub cell_mm: Option<f64>,
    /// Tangential model; [`FrictionModel::Incremental`] carries stick/slip between steps.
    pub friction: FrictionModel,
    /// Samples kept in the ring buffer (at least 2).
    pub history: usize,
    /// Step on demand too: a [`WrenchSource::wrench_at`] or [`ContactPhysics::field_at`] for a
    /// time past the newest step first steps to the pose source's current pose, inline. The
    /// F/T mock and the camera then see the contact at their own sample time rather than up to
    /// a physics period (plus the task's wake-up delay, many ms on a scaled clock) late. Only
    /// for cheap models (Winkler, Hertz): the step runs on the caller's task.
    pub on_demand: bool,
}

impl Default for PhysicsConfig {
    fn default() -> Self {
        Self {
            rate_hz: DEFAULT_PHYSICS_RATE_HZ,
            contact: ContactModel::Layer,
            cell_mm: Some(DEFAULT_RUN_CELL_MM),
            friction: FrictionModel::Incremental,
            history: DEFAULT_HISTORY,
            on_demand: false,
        }
    }
}

impl PhysicsConfig {
    /// The [`Effects`] of a physics step (`surface_field` when a camera needs images).
    pub fn effects(&self, surface_field: bool) -> Effects {
        Effects {
            contact: self.contact,
            cell_mm: self.cell_mm,
            friction: self.friction,
            viscoelastic: None,
            surface_field,
            image: None,
        }
    }

    fn validate(&self) -> io::Result<()> {
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0) {
            return Err(invalid(format!(
                "physics rate_hz must be > 0, got {}",
                self.rate_hz
            )));
        }
        if self.history < 2 {
            return Err(invalid(format!(
                "physics history must be at least 2, got {}",
                self.history
            )));
        }
        Ok(())
    }
}

/// Counters of a [`ContactPhysics`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PhysicsStats {
    /// Steps taken (in or out of contact).
    pub steps: u64,
    /// Steps in contact (a normal solve ran).
    pub contact_steps: u64,
    /// Steps the simulator refused (the last wrench was held).
    pub errors: u64,
    /// Physics ticks of the spawned task skipped because steps took longer than the period
    /// (the buffer is then sparser than `rate_hz`; `wrench_at` still interpolates).
    pub skipped_ticks: u64,
}

/// The TCP (indenter tip) in the sensor surface frame, as the simulator's pose: contact point
/// (mm), depth `−z` (mm), no shear. See the module docs.
pub fn indenter_pose(surface_frame: &Pose, tcp: &Pose) -> IndenterPose {
    let p = pose_trans(&pose_inv(surface_frame), tcp);
    IndenterPose {
        contact_mm: [p.x * 1e3, p.y * 1e3],
        depth_mm: -p.z * 1e3,
        shear_mm: [0.0, 0.0],
    }
}

/// Moves the simulator's wrench (torque about the contact point on the undeformed surface) to
/// the indenter tip, `depth_mm` below it: `T_tip = T_c + (0, 0, depth) × F`.
pub fn wrench_at_tip(w: &Wrench, depth_mm: f64) -> Wrench {
    let f = w.force_n;
    let mut t = w.torque_nmm;
    t[0] -= depth_mm * f[1];
    t[1] += depth_mm * f[0];
    Wrench {
        force_n: f,
        torque_nmm: t,
    }
}

/// The solver side: held for the whole of a step (milliseconds).
struct SolverState {
    sim: Simulator,
    /// The unloaded field, computed once (out-of-contact frames).
    flat_field: Option<Arc<SurfaceField>>,
    in_contact: bool,
}

/// The results side: held only to copy a sample in or out, so a long solve never blocks the
/// F/T mock's `wrench_at` (it runs on an async worker).
struct Results {
    ring: VecDeque<(u64, Wrench)>,
    last: Wrench,
    /// The newest surface fields with their pose times, oldest first.
    fields: VecDeque<(u64, Arc<SurfaceField>)>,
}

/// Surface fields kept for [`ContactPhysics::field_at`] (the camera renders a frame a little
/// after its capture time): at most one per [`FIELD_SPACING_NS`], so 256 of them cover 0.5 s
/// of lag however often the physics steps (on-demand steps follow the F/T's 1 kHz). Fields out
/// of contact share one allocation.
const FIELD_HISTORY: usize = 256;
/// Least clock time between two kept fields (2 ms: 2 µm of travel at the plan's speeds).
const FIELD_SPACING_NS: u64 = 2_000_000;

struct Inner {
    surface_frame: Pose,
    elastomer: ElastomerConfig,
    indenter: Arc<Indenter>,
    config: PhysicsConfig,
    want_field: bool,
    solver: Mutex<SolverState>,
    results: Mutex<Results>,
    steps: AtomicU64,
    contact_steps: AtomicU64,
    errors: AtomicU64,
    skipped_ticks: AtomicU64,
    /// The pose source of [`ContactPhysics::spawn`], for on-demand steps.
    pose_source: Mutex<Option<PoseSource>>,
}

/// The contact physics of the simulated rig (see the module docs). Cheap to clone; every clone
/// shares the same simulator and buffer.
#[derive(Clone)]
pub struct ContactPhysics {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for ContactPhysics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContactPhysics")
            .field("config", &self.inner.config)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// Where the physics task reads the TCP: `(t_ns of the pose, TCP pose in the base frame)`.
pub type PoseSource = Arc<dyn Fn() -> (u64, Pose) + Send + Sync>;

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl ContactPhysics {
    /// Physics for `indenter` on the gel at `surface_frame` (base frame). `want_field`: keep the
    /// surface field of every step (needed by [`PhysicsRenderer`]).
    pub fn new(
        surface_frame: Pose,
        elastomer: ElastomerConfig,
        indenter: Arc<Indenter>,
        config: PhysicsConfig,
        want_field: bool,
    ) -> io::Result<Self> {
        config.validate()?;
        let history = config.history;
        Ok(Self {
            inner: Arc::new(Inner {
                surface_frame,
                elastomer,
                indenter,
                config,
                want_field,
                solver: Mutex::new(SolverState {
                    sim: Simulator::new(),
                    flat_field: None,
                    in_contact: false,
                }),
                results: Mutex::new(Results {
                    ring: VecDeque::with_capacity(history),
                    last: Wrench::default(),
                    fields: VecDeque::with_capacity(FIELD_HISTORY),
                }),
                steps: AtomicU64::new(0),
                contact_steps: AtomicU64::new(0),
                errors: AtomicU64::new(0),
                skipped_ticks: AtomicU64::new(0),
                pose_source: Mutex::new(None),
            }),
        })
    }

    pub fn config(&self) -> &PhysicsConfig {
        &self.inner.config
    }

    /// The scene the physics solves for a TCP pose (base frame).
    pub fn scene_for(&self, tcp: &Pose) -> Scene {
        let mut pose = indenter_pose(&self.inner.surface_frame, tcp);
        pose.depth_mm = pose.depth_mm.max(0.0);
        Scene {
            elastomer: self.inner.elastomer.clone(),
            indenter: self.inner.indenter.clone(),
            pose,
            optics: None,
            effects: self.inner.config.effects(self.inner.want_field),
        }
    }

    /// One physics step: the TCP was at `tcp` (base frame) at clock time `t_ns`. Appends the
    /// tool-point wrench (see the module docs) to the buffer and returns it. A `t_ns` not after
    /// the newest sample adds nothing and returns the newest wrench. On a simulator error the
    /// last wrench is held (and recorded at `t_ns`), and the error returned.
    pub fn update(&self, t_ns: u64, tcp: &Pose) -> Result<Wrench, SimError> {
        // Steps are serialised by the solver lock; the results lock is taken only briefly.
        let mut st = lock(&self.inner.solver);
        if let Some((t_last, w)) = self.latest()
            && t_ns <= t_last
        {
            return Ok(w);
        }
        self.inner.steps.fetch_add(1, Ordering::Relaxed);
        let raw = indenter_pose(&self.inner.surface_frame, tcp);
        let mut new_field = None;
        let result = if raw.depth_mm > 0.0 {
            self.inner.contact_steps.fetch_add(1, Ordering::Relaxed);
            st.in_contact = true;
            let scene = self.scene_for(tcp);
            st.sim.step(&scene, t_ns as f64 * 1e-9).map(|out| {
                new_field = out.field.map(Arc::new);
                wrench_at_tip(&out.wrench, raw.depth_mm)
            })
        } else {
            if st.in_contact {
                // The gel is unloaded: no stick/slip state survives lifting off.
                st.sim.reset();
                st.in_contact = false;
            }
            if self.inner.want_field {
                let flat = match &st.flat_field {
                    Some(f) => Ok(f.clone()),
                    // A zero-depth frame on a throw-away simulator: no history touched.
                    None => Simulator::new()
                        .step(&self.scene_for(tcp), 0.0)
                        .map(|out| Arc::new(out.field.unwrap_or_default())),
                };
                flat.map(|f| {
                    st.flat_field = Some(f.clone());
                    new_field = Some(f);
                    Wrench::default()
                })
            } else {
                Ok(Wrench::default())
            }
        };
        let mut res = lock(&self.inner.results);
        let w = match &result {
            Ok(w) => *w,
            Err(_) => {
                self.inner.errors.fetch_add(1, Ordering::Relaxed);
                res.last
            }
        };
        res.last = w;
        if res.ring.len() == self.inner.config.history {
            res.ring.pop_front();
        }
        res.ring.push_back((t_ns, w));
        if let Some(f) = new_field
            && res
                .fields
                .back()
                .is_none_or(|(t, _)| t_ns >= t + FIELD_SPACING_NS)
        {
            if res.fields.len() == FIELD_HISTORY {
                res.fields.pop_front();
            }
            res.fields.push_back((t_ns, f));
        }
        result
    }

    /// The newest surface field and the clock time of its pose, if any step made one.
    pub fn latest_field(&self) -> Option<(u64, Arc<SurfaceField>)> {
        lock(&self.inner.results).fields.back().cloned()
    }

    /// With [`PhysicsConfig::on_demand`]: a step to the pose source's current pose when the
    /// newest step is older than `t_ns`.
    fn catch_up(&self, t_ns: u64) {
        if !self.inner.config.on_demand {
            return;
        }
        if self.latest().is_some_and(|(t, _)| t >= t_ns) {
            return;
        }
        let src = lock(&self.inner.pose_source).clone();
        if let Some(src) = src {
            let (t, tcp) = src();
            if let Err(e) = self.update(t, &tcp) {
                tracing::debug!("contact physics on demand at {t} ns: {e}");
            }
        }
    }

    /// The surface field of the newest step at or before `t_ns` (the oldest kept one if all
    /// are later), with its pose time.
    pub fn field_at(&self, t_ns: u64) -> Option<(u64, Arc<SurfaceField>)> {
        self.catch_up(t_ns);
        let res = lock(&self.inner.results);
        let i = res.fields.partition_point(|(t, _)| *t <= t_ns);
        res.fields.get(i.saturating_sub(1)).cloned()
    }

    /// The newest `(t_ns, wrench)` sample.
    pub fn latest(&self) -> Option<(u64, Wrench)> {
        lock(&self.inner.results).ring.back().copied()
    }

    pub fn stats(&self) -> PhysicsStats {
        PhysicsStats {
            steps: self.inner.steps.load(Ordering::Relaxed),
            contact_steps: self.inner.contact_steps.load(Ordering::Relaxed),
            errors: self.inner.errors.load(Ordering::Relaxed),
            skipped_ticks: self.inner.skipped_ticks.load(Ordering::Relaxed),
        }
    }

    /// Spawns the physics task on `clock`: every `1 / rate_hz` of clock time it reads
    /// `pose_source` and runs [`ContactPhysics::update`] (off the async workers). Missed ticks
    /// are skipped, not replayed. Must be called within a tokio runtime.
    pub fn spawn(&self, clock: Clock, pose_source: PoseSource) -> JoinHandle<()> {
        *lock(&self.inner.pose_source) = Some(pose_source.clone());
        let physics = self.clone();
        let period = Duration::from_secs_f64(1.0 / self.inner.config.rate_hz);
        tokio::spawn(async move {
            let mut ticker = clock.ticker(period);
            let mut prev_due: Option<u64> = None;
            loop {
                let due = ticker.tick().await;
                if let Some(p) = prev_due {
                    let missed = (due - p) / ticker.period_ns().max(1);
                    if missed > 1 {
                        physics
                            .inner
                            .skipped_ticks
                            .fetch_add(missed - 1, Ordering::Relaxed);
                    }
                }
                prev_due = Some(due);
                let (t_ns, tcp) = pose_source();
                let p = physics.clone();
                let r = tokio::task::spawn_blocking(move || p.update(t_ns, &tcp)).await;
                match r {
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => tracing::warn!("contact physics step at {t_ns} ns: {e}"),
                    Err(e) => {
                        tracing::error!("contact physics step panicked: {e}");
                        return;
                    }
                }
            }
        })
    }
}

impl WrenchSource for ContactPhysics {
    /// Linear interpolation in the buffer, clamped at both ends; zero before the first step.
    fn wrench_at(&self, t_ns: u64) -> Wrench {
        self.catch_up(t_ns);
        let res = lock(&self.inner.results);
        let ring = &res.ring;
        let Some(&(t_first, w_first)) = ring.front() else {
            return Wrench::default();
        };
        let &(t_last, w_last) = ring.back().expect("non-empty");
        if t_ns <= t_first {
            return w_first;
        }
        if t_ns >= t_last {
            return w_last;
        }
        // First sample strictly after t_ns; 1 ≤ i < len here.
        let i = ring.partition_point(|&(t, _)| t <= t_ns);
        let (t0, w0) = ring[i - 1];
        let (t1, w1) = ring[i];
        let s = (t_ns - t0) as f64 / (t1 - t0) as f64;
        let (a, b) = (w0.to_array(), w1.to_array());
        let mut out = [0.0; 6];
        for k in 0..6 {
            out[k] = a[k] + s * (b[k] - a[k]);
        }
        Wrench::from_array(out)
    }
}

/// Renders the surface field of a [`ContactPhysics`] at the capture time (the newest step at
/// or before it) with the sensor's optics. Frame `n`
/// uses noise seed `noise_seed + n`. Gives no frame before the physics has made a field (the
/// physics must have been created with `want_field`).
pub struct PhysicsRenderer {
    physics: ContactPhysics,
    optics: OpticsConfig,
    effects: ImageEffects,
    noise_seed: u64,
    frames: AtomicU64,
}

impl PhysicsRenderer {
    pub fn new(
        physics: ContactPhysics,
        optics: OpticsConfig,
        effects: ImageEffects,
        noise_seed: u64,
    ) -> Self {
        Self {
            physics,
            optics,
            effects,
            noise_seed,
            frames: AtomicU64::new(0),
        }
    }
}

impl FrameRenderer for PhysicsRenderer {
    fn render_at(&self, t_ns: u64) -> Option<image::RgbImage> {
        // The field at the capture time, even when rendering runs late.
        let (_, field) = self.physics.field_at(t_ns)?;
        let n = self.frames.fetch_add(1, Ordering::Relaxed);
        Some(optics::render(
            &self.optics,
            &self.effects,
            &field,
            self.noise_seed.wrapping_add(n),
        ))
    }
}

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
    /// Image effects of the camera.
    pub image_effects: ImageEffects,
    /// Noise seed of the camera's images.
    pub image_seed: u64,
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
            image_effects: ImageEffects::default(),
            image_seed: 0,
        }
    }
}

impl SimRigOptions {
    /// Defaults, with an ideal camera at `camera.fps` when the config has a camera.
    pub fn for_config(config: &RigConfig) -> Self {
        Self {
            camera: config
                .camera
                .as_ref()
                .map(|c| SimCameraConfig::ideal(c.fps)),
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
}

/// The simulated F/T front end that runs.
pub enum SimFt {
    NetFt(NetFtMock),
    Serial(SerialControllerMock),
}

impl SimFt {
    /// Fault injection (unplug, mute, saturate, garbage ...).
    pub fn faults(&self) -> &Arc<crate::nano17::Faults> {
        match self {
            SimFt::NetFt(m) => m.faults(),
            SimFt::Serial(m) => m.faults(),
        }
    }
    pub fn stats(&self) -> &Arc<crate::nano17::MockStats> {
        match self {
            SimFt::NetFt(m) => m.stats(),
            SimFt::Serial(m) => m.stats(),
        }
    }
    async fn shutdown(self) {
        match self {
            SimFt::NetFt(m) => m.shutdown().await,
            SimFt::Serial(m) => m.shutdown().await,
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
        let ur_cfg = Ur5eConfig {
            home_pose: home,
            initial_robot_mode: opts.initial_robot_mode,
            max_frequency_hz: config.robot.controller.max_rtde_frequency_hz(),
            ..Ur5eConfig::default()
        };
        let runtime_pacer = AbortOnDrop(Some(rig_core::clock::spawn_runtime_pacer(
            &clock,
            rig_core::clock::SIM_PACER_LEAD,
        )));
        let ur5e = Arc::new(Ur5e::start(ur_cfg, clock.clone()).await?);

        let physics = ContactPhysics::new(
            frame,
            config.elastomer.clone(),
            indenter,
            opts.physics.clone(),
            opts.camera.is_some(),
        )?;
        // The state at start, so the F/T and the camera have a sample from t = start.
        let s = ur5e.snapshot();
        if let Err(e) = physics.update(s.t_ns, &s.actual_tcp_pose) {
            tracing::warn!("contact physics at start: {e}");
        }
        let src = ur5e.clone();
        let physics_task = AbortOnDrop(Some(physics.spawn(
            clock.clone(),
            // The pose at the current clock time (due controller ticks processed first), so
            // an on-demand step sees the contact at the caller's time.
            Arc::new(move || {
                let s = src.snapshot_now();
                (s.t_ns, s.actual_tcp_pose)
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
        };

        let camera = match &opts.camera {
            Some(cam_cfg) => {
                let renderer = PhysicsRenderer::new(
                    physics.clone(),
                    config.optics.clone().unwrap_or_default(),
                    opts.image_effects,
                    opts.image_seed,
                );
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
            SimFt::Serial(_) => None,
        }
    }

    /// The serial F/T controller's pty (`None` with a Net F/T front end).
    pub fn ft_serial_path(&self) -> Option<&std::path::Path> {
        match &self.ft {
            SimFt::Serial(m) => Some(m.path()),
            SimFt::NetFt(_) => None,
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

    /// Stops every task and closes every socket.
    pub async fn shutdown(self) {
        let SimRig {
            _runtime_pacer,
            ur5e,
            physics: _,
            physics_task,
            ft,
            camera,
        } = self;
        _runtime_pacer.stop().await;
        drop(camera);
        ft.shutdown().await;
        physics_task.stop().await;
        match Arc::try_unwrap(ur5e) {
            Ok(ur) => ur.shutdown().await,
            Err(ur) => drop(ur),
        }
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

fn invalid(msg: String) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidInput, msg)
}
