//! The contact physics of the simulated rig: [`ContactPhysics`] steps the simulator from the
//! UR5e's TCP and serves the wrench to the F/T twins; [`PhysicsRenderer`] shades its surface
//! field for the camera. See the parent module for the geometry, sign convention and cost.
//! How the F/T reads a wrench past the newest step, from the buffer of steps, is in
//! `read_ahead.rs`.
//!
//! # Known limits of the F/T labels
//!
//! A frame's true wrench and the F/T's samples come from the same steps, but not always the
//! same ones, so `rig dataset check` sees the difference. Three causes were closed:
//!
//! - the contact is pressed with the tip where it is at the sample's own instant, between
//!   the controller's 2 ms ticks ([`Ur5e::tip_pose_moving`](crate::ur5e::Ur5e::tip_pose_moving)),
//!   not the last tick's pose, which put the F/T up to a tick behind the frames;
//! - the F/T reads the wrench off the motion's line at most `MAX_LINE_MM` (5 µm, in
//!   `read_ahead.rs`) past the newest step, and solves beyond it: at the up stage's 5 mm/s
//!   two physics steps are 100 µm apart, and reading up to two spacings on was 0.5 N off
//!   where a flat face lifts off;
//! - only the steps on the clock's grid carry the contact's history; a solve between them
//!   (an F/T sample's or a frame's instant) is a probe from the newest grid step that leaves
//!   the history as it was. A contact step depends on its length (see `sim/contact`: the
//!   contact search lags the friction solve, and iterating the two does not converge), so
//!   when those solves were steps, each one split the next grid step in two and moved every
//!   force after it, by when the F/T happened to ask: paralines' reverse stage was 0.14 N
//!   off. Now the grid's steps are the same whoever asks between them
//!   (`an_ft_reading_between_the_physics_steps_leaves_the_steps_as_they_were`).
//!
//! A step does not leave a history that gives its own force back (the search ↔ friction loop
//! does not settle), so the force jumps where the probes change the history they start from,
//! by up to 0.14 N where paralines slides. The probes start from the nearest tick's
//! ([`ContactPhysics::step_at`]), so the jump falls half-way between ticks, away from the
//! frames of a camera on the grid. Each buffered solve keeps the tick it started from, and an
//! F/T reading is anchored only on a solve from its own start (the nearest tick's), taking a
//! slope only from two solves of one start (`read_ahead.rs`): a reading past half-way that
//! ran on along the line of the solves before it carried the jump to the next frame (0.05 to
//! 0.08 N where paralines' slide stops).
//!
//! What remains (`docs/experiments.md`, "Labels: solves between the grid's steps become
//! probes"): at ×10 the host dates the F/T's samples about 0.1–0.2 ms of clock time late,
//! 0.04–0.05 N where a flat face lifts off at 5 mm/s (at ×2 the wave's worst frame is 0.039 N);
//! and a flat face's walls crossing the cells' sub-samples stepped its force by up to 0.07 N
//! from one F/T sample to the next; the walls are now filtered across one sub-sample
//! (`sim/contact/geometry.rs`, 0.003–0.045 N). An F/T sample at or past a tick the physics
//! task had not reached yet was read off the line of the two steps before it, so where the
//! contact re-settled (a slide stopping) a frame's label kept the old force (paralines 0.25 N);
//! such a sample now steps its tick first. What is left is the F/T's noise (σ = 1/160 N) and,
//! where a flat face lifts off at 5 mm/s, the F/T's transport latency at ×10 (the host dates
//! its samples about 0.15 ms of clock time late, 0.01 N at 0.07 N/ms; docs/experiments.md,
//! "Labels: readings anchored on their own start").

use std::collections::VecDeque;
use std::io;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::optics::OpticsConfig;
use rig_core::pose::{Pose, pose_inv, pose_trans};
use rig_core::wrench::Wrench;
use tokio::task::JoinHandle;

use crate::camera::FrameRenderer;
use crate::sim::optics::{self, ImageEffects};
use crate::sim::{ContactModel, History, IndenterPose, Scene, SimError, Simulator, SurfaceField};
use crate::truth::WrenchSource;

use super::config::PhysicsConfig;
use super::lock::lock;
use super::read_ahead::{Ahead, Sample, along, in_time, position, read_off_line};
use super::tape::{ContactCache, Episode, TapeStats};

/// How far simulated time may run ahead of the contact physics, in real time, beyond the tick
/// after its newest step (see [`ContactPhysics::spawn`]): 2 ms, 20 ms of clock time at ×10.
pub const PHYSICS_PACER_LEAD: Duration = Duration::from_millis(2);
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
    /// (the buffer is then sparser than `rate_hz`; `wrench_at` still interpolates). With
    /// [`PhysicsConfig::on_demand`] (cheap models) missed ticks are replayed at their own
    /// times and poses instead, up to a second of clock time at once.
    pub skipped_ticks: u64,
    /// The largest gap between a [`ContactPhysics::field_at`] time (a frame's capture time)
    /// and the pose time of the field it got, ns: how stale the contact in a simulated image
    /// was. A few ms (one controller tick plus the field spacing) when the physics keeps up.
    pub max_field_age_ns: u64,
    /// F/T reads of the layer model that asked the physics to solve at their own pose, off the
    /// clock's grid (a probe, which leaves the contact's history as it was): the motion had
    /// left the line of the last two steps (a stage start, a reversal, the first touch) or
    /// run past it. A read may find the solve already made (by another read at the same
    /// controller tick), so this counts requests, not solves.
    pub off_grid_steps: u64,
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
    /// The contact episode under way: replayed from the contact cache, or solved.
    episode: Episode,
    /// The unloaded field, computed once (out-of-contact frames).
    flat_field: Option<Arc<SurfaceField>>,
    in_contact: bool,
    /// The newest committed step's time, and the history it started from (`None` for a step
    /// out of contact): a probe nearer to that step than to the next tick starts from there
    /// ([`ContactPhysics::step_at`]).
    newest_commit: Option<(u64, Option<History>)>,
}

/// The results side: held only to copy a sample in or out, so a long solve never blocks the
/// F/T mock's `wrench_at` (it runs on an async worker).
struct Results {
    ring: VecDeque<Sample>,
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
    max_field_age_ns: AtomicU64,
    off_grid_steps: AtomicU64,
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

/// Where the physics reads the TCP: called with a clock time, it gives the TCP pose (base
/// frame) the robot had at that time, with the time of that pose (at or before it: the
/// controller's last tick). The time asked for is never in the future.
pub type PoseSource = Arc<dyn Fn(u64) -> (u64, Pose) + Send + Sync>;

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
        Self::with_cache(surface_frame, elastomer, indenter, config, want_field, None)
    }

    /// [`ContactPhysics::new`] that replays the contact episodes `cache` holds for this
    /// physics, and adds the ones it solves (see the `tape` module: simulate once, render per
    /// sensor). The cache must have been opened for the same elastomer, indenter and config.
    pub fn with_cache(
        surface_frame: Pose,
        elastomer: ElastomerConfig,
        indenter: Arc<Indenter>,
        config: PhysicsConfig,
        want_field: bool,
        cache: Option<ContactCache>,
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
                    episode: Episode::new(cache),
                    flat_field: None,
                    in_contact: false,
                    newest_commit: None,
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
                max_field_age_ns: AtomicU64::new(0),
                off_grid_steps: AtomicU64::new(0),
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
            effects: self
                .inner
                .config
                .effects(self.inner.want_field, &self.inner.elastomer),
        }
    }

    /// One physics step: the TCP was at `tcp` (base frame) at clock time `t_ns`. Appends the
    /// tool-point wrench (see the module docs) to the buffer and returns it. A `t_ns` not after
    /// the newest sample adds nothing and returns the newest wrench. On a simulator error the
    /// last wrench is held (and recorded at `t_ns`), and the error returned.
    pub fn update(&self, t_ns: u64, tcp: &Pose) -> Result<Wrench, SimError> {
        self.step_at(t_ns, tcp, true)
    }

    /// [`Self::update`], or with `commit` false a probe: the contact at `t_ns` as a step
    /// would find it, buffered like a step, but the steps that follow start from the
    /// committed history as if it had not been asked (see [`Simulator::probe`]). The steps on
    /// the clock's grid commit; a consumer's step between them (an F/T sample or a frame)
    /// probes, so what they ask, and when, does not change the contact's path.
    ///
    /// A probe starts from the history the *nearest* grid tick's step started from: within
    /// half a period after the newest step, from the one before it. A step does not leave a
    /// history that gives its own force back (a probe at the step's own pose from it differs
    /// by up to 0.14 N on paralines: the search ↔ friction loop does not settle, see
    /// `sim/contact`), so the force jumps where the probes change their start. Half-way
    /// between ticks, no frame of a camera on the grid (25 fps on the 50 Hz grid) and none of
    /// the F/T samples paired with it sees that jump; at the ticks, the force is continuous.
    fn step_at(&self, t_ns: u64, tcp: &Pose, commit: bool) -> Result<Wrench, SimError> {
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
        // The grid tick whose starting history this solve begins from (see `Sample::start_ns`).
        let period_ns = self.period_ns();
        let mut start_ns = if commit {
            t_ns
        } else {
            self.nearest_tick_ns(t_ns)
        };
        let result = if raw.depth_mm > 0.0 {
            self.inner.contact_steps.fetch_add(1, Ordering::Relaxed);
            if commit {
                st.in_contact = true;
            }
            let scene = self.scene_for(tcp);
            let half_period_ns = self.half_period_ns();
            let SolverState {
                sim,
                episode,
                newest_commit,
                ..
            } = &mut *st;
            let out = if commit {
                *newest_commit = Some((t_ns, Some(sim.history())));
                episode.step(sim, &scene, t_ns, self.inner.want_field)
            } else {
                let from = match newest_commit {
                    Some((t, from)) if t_ns < *t + half_period_ns => {
                        start_ns = *t;
                        from.as_ref()
                    }
                    Some((t, _)) => {
                        start_ns = *t + period_ns;
                        None
                    }
                    None => None,
                };
                episode.probe(sim, from, &scene, t_ns, self.inner.want_field)
            };
            out.map(|(w, solved, replayed)| {
                new_field = solved.map(Arc::new).or(replayed);
                wrench_at_tip(&w, raw.depth_mm)
            })
        } else {
            if commit {
                st.newest_commit = Some((t_ns, None));
                if st.in_contact {
                    // The gel is unloaded: no stick/slip state survives lifting off.
                    st.sim.reset();
                    st.episode.end();
                    st.in_contact = false;
                }
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
        res.ring.push_back(Sample {
            t_ns,
            w,
            at_mm: position(&raw),
            start_ns,
        });
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

    /// Half a physics period of clock time, ns.
    fn half_period_ns(&self) -> u64 {
        (0.5e9 / self.inner.config.rate_hz) as u64
    }

    /// A physics period of clock time, ns (at least 1).
    fn period_ns(&self) -> u64 {
        (1e9 / self.inner.config.rate_hz).max(1.0) as u64
    }

    /// The grid tick nearest `t_ns` (the later one half-way): the tick whose starting history
    /// a solve at `t_ns` begins from ([`Self::step_at`]).
    fn nearest_tick_ns(&self, t_ns: u64) -> u64 {
        let period_ns = self.period_ns();
        (t_ns + period_ns / 2) / period_ns * period_ns
    }

    /// With [`PhysicsConfig::on_demand`]: when the newest step is older than `t_ns`, steps at
    /// the poses the robot had at the physics ticks (multiples of the period) from the newest
    /// step up to `t_ns` (at most a second of them), and then probes at `t_ns` itself when
    /// `exact` (buffered like a step, but the ticks' steps that follow do not start from it:
    /// [`Self::step_at`]).
    /// A consumer that is on time (the F/T at 1 kHz) thus never leaves a gap in the buffer
    /// while the physics task is late, and a consumer running late (a frame rendered after its
    /// capture time) finds the contact of its own instant. With a cheap model (Winkler,
    /// Hertz) the F/T steps at its own sample time too; with the layer model it reads the
    /// wrench off the motion's line without stepping, and comes here (`exact = true`) only
    /// where the motion leaves that line (`ContactPhysics::read_ahead`): a solve per F/T
    /// sample would cost a solve per millisecond. The physics task steps the ticks only.
    fn catch_up(&self, t_ns: u64, exact: bool) {
        if !self.inner.config.on_demand {
            return;
        }
        let newest = self.latest().map(|(t, _)| t);
        if newest.is_some_and(|t| t >= t_ns) {
            return;
        }
        let src = lock(&self.inner.pose_source).clone();
        let Some(src) = src else {
            return;
        };
        let period_ns = self.period_ns();
        let mut times = Vec::new();
        let from = newest
            .map_or(t_ns, |t| t + 1)
            .max(t_ns.saturating_sub(1_000_000_000));
        let first_tick = from.div_ceil(period_ns) * period_ns;
        times.extend((first_tick..=t_ns).step_by(period_ns as usize));
        if exact && times.last() != Some(&t_ns) {
            times.push(t_ns);
        }
        if times.is_empty() {
            return;
        }
        // The steps cost milliseconds: on an async worker (the F/T twins sample from theirs),
        // hand the worker's other tasks (the controller, RTDE) to another thread first.
        off_the_async_workers(|| {
            for t in times {
                let (t_pose, tcp) = src(t);
                let on_grid = t % period_ns == 0;
                if let Err(e) = self.step_at(t_pose, &tcp, on_grid) {
                    tracing::debug!("contact physics on demand at {t_pose} ns: {e}");
                }
            }
        });
    }

    /// The surface field of the newest step at or before `t_ns` (the oldest kept one if all
    /// are later), with its pose time.
    pub fn field_at(&self, t_ns: u64) -> Option<(u64, Arc<SurfaceField>)> {
        self.catch_up(t_ns, true);
        let res = lock(&self.inner.results);
        let i = res.fields.partition_point(|(t, _)| *t <= t_ns);
        let found = res.fields.get(i.saturating_sub(1)).cloned();
        if let Some((t, _)) = &found {
            self.inner
                .max_field_age_ns
                .fetch_max(t_ns.saturating_sub(*t), Ordering::Relaxed);
        }
        found
    }

    /// The contact cache's counters (`None`: the physics has no cache).
    pub fn tape_stats(&self) -> Option<TapeStats> {
        lock(&self.inner.solver)
            .episode
            .cache()
            .map(ContactCache::stats)
    }

    /// The contact cache the tapes are written to, if any: flushing it
    /// ([`ContactCache::flush`]) needs no physics.
    pub fn tape_cache(&self) -> Option<ContactCache> {
        lock(&self.inner.solver).episode.cache().cloned()
    }

    /// [`Self::latest`] for a reader that must not keep the physics alive: the UR5e twin's
    /// flange sensor, whose controller the physics' pose source holds (a strong reference both
    /// ways would keep the arm ticking, and its RTDE watchdog firing, after the rig is dropped).
    /// `None` once the physics is gone.
    pub fn latest_reader(&self) -> impl Fn() -> Option<(u64, Wrench)> + Send + Sync + 'static {
        let weak = Arc::downgrade(&self.inner);
        move || {
            weak.upgrade()
                .and_then(|inner| ContactPhysics { inner }.latest())
        }
    }

    /// The newest `(t_ns, wrench)` sample.
    pub fn latest(&self) -> Option<(u64, Wrench)> {
        lock(&self.inner.results).ring.back().map(|s| (s.t_ns, s.w))
    }

    pub fn stats(&self) -> PhysicsStats {
        PhysicsStats {
            steps: self.inner.steps.load(Ordering::Relaxed),
            contact_steps: self.inner.contact_steps.load(Ordering::Relaxed),
            errors: self.inner.errors.load(Ordering::Relaxed),
            skipped_ticks: self.inner.skipped_ticks.load(Ordering::Relaxed),
            max_field_age_ns: self.inner.max_field_age_ns.load(Ordering::Relaxed),
            off_grid_steps: self.inner.off_grid_steps.load(Ordering::Relaxed),
        }
    }

    /// Spawns the physics task on `clock`: every `1 / rate_hz` of clock time it steps
    /// [`ContactPhysics::update`] (off the async workers) at the pose `pose_source` gives for
    /// the tick's time. When the task wakes late, the ticks it missed are replayed at their
    /// own times and poses if the model is cheap ([`PhysicsConfig::on_demand`]; at most a
    /// second of clock time at once), so the buffer and the fields do not depend on how busy
    /// the host was; for the costly models they are skipped and counted
    /// ([`PhysicsStats::skipped_ticks`]). Must be called within a tokio runtime.
    pub fn spawn(&self, clock: Clock, pose_source: PoseSource) -> JoinHandle<()> {
        *lock(&self.inner.pose_source) = Some(pose_source.clone());
        let physics = self.clone();
        let period = Duration::from_secs_f64(1.0 / self.inner.config.rate_hz);
        let replay = self.inner.config.on_demand;
        let max_replay = self.inner.config.rate_hz.ceil().max(1.0) as u64;
        tokio::spawn(async move {
            let mut ticker = clock.ticker(period);
            let period_ns = ticker.period_ns().max(1);
            // Simulated time waits for the physics: at most a tick and PHYSICS_PACER_LEAD of
            // real time past the newest step, so the F/T twins never read far past it.
            let pacer = clock.pacer("simulated contact physics", PHYSICS_PACER_LEAD);
            // (Reported in tick times, not the steps' pose times: a pose source whose times
            // lag would otherwise hold the clock before the next tick, for ever.)
            pacer.reached(clock.now_ns() + period_ns);
            let mut last_step: Option<u64> = None;
            loop {
                let due = ticker.tick().await;
                // Every tick time from the one after the last step up to now: a late wake-up
                // returns the first missed tick and the ticker skips the rest.
                let first = last_step.map_or(due, |p| p + period_ns).min(due);
                let late = (clock.now_ns().max(first) - first) / period_ns;
                let newest = first + late * period_ns;
                last_step = Some(newest);
                let replayed = if replay { late.min(max_replay) } else { 0 };
                if late > replayed {
                    physics
                        .inner
                        .skipped_ticks
                        .fetch_add(late - replayed, Ordering::Relaxed);
                }
                let times: Vec<u64> = (0..=replayed)
                    .rev()
                    .map(|k| newest - k * period_ns)
                    .collect();
                let p = physics.clone();
                let src = pose_source.clone();
                let now = clock.now_ns();
                let r = tokio::task::spawn_blocking(move || {
                    if replay {
                        // On demand, every step is on the clock's grid of periods (what the
                        // consumers step too): up to now, missed ticks included.
                        p.catch_up(now, false);
                        return;
                    }
                    for t in times {
                        let (t_ns, tcp) = src(t);
                        if let Err(e) = p.update(t_ns, &tcp) {
                            tracing::warn!("contact physics step at {t_ns} ns: {e}");
                        }
                    }
                })
                .await;
                if let Err(e) = r {
                    tracing::error!("contact physics step panicked: {e}");
                    return;
                }
                pacer.reached(newest + period_ns);
            }
        })
    }
}

impl ContactPhysics {
    /// The wrench of the layer model at an F/T sample time `t_ns` past the newest step, without
    /// a solve per sample: the pose the robot had then is read off the line through the last
    /// two steps' poses, and the wrench interpolated (or extrapolated, up to
    /// [`MAX_LINE_STEPS`](super::read_ahead::MAX_LINE_STEPS)) along that line
    /// ([`read_off_line`]). This follows the motion's speed exactly, ramps included, where an
    /// extrapolation in time would not. Where the pose is off that line (a
    /// stage starting, a reversal, the first touch), the physics probes at the sample's pose
    /// (off the clock's grid, counted in [`PhysicsStats::off_grid_steps`]): several solves per
    /// stage start, as the line's baseline grows. `None`: the buffer answers (see [`Ahead::Buffer`]).
    fn read_ahead(&self, t_ns: u64) -> Option<Wrench> {
        if !self.inner.config.on_demand {
            return None;
        }
        let src = lock(&self.inner.pose_source).clone()?;
        let (_, tcp) = src(t_ns);
        let at = position(&indenter_pose(&self.inner.surface_frame, &tcp));
        for _ in 0..2 {
            let ahead = {
                let res = lock(&self.inner.results);
                read_off_line(&res.ring, t_ns, &at, self.nearest_tick_ns(t_ns))
            };
            match ahead {
                Ahead::Wrench(w) => return Some(w),
                Ahead::Buffer => return None,
                Ahead::Solve => {
                    // The grid's ticks up to the sample first (the camera's frames are on
                    // them; the physics task's pacer keeps them to a tick or two), then the
                    // sample's own pose.
                    self.inner.off_grid_steps.fetch_add(1, Ordering::Relaxed);
                    self.catch_up(t_ns, true);
                }
            }
        }
        None
    }

    /// Linear interpolation in the buffer, clamped at the start; past the newest step see
    /// [`WrenchSource::wrench_at`].
    fn buffered(&self, t_ns: u64) -> Wrench {
        let res = lock(&self.inner.results);
        let ring = &res.ring;
        let Some(first) = ring.front() else {
            return Wrench::default();
        };
        let last = ring.back().expect("non-empty");
        if t_ns <= first.t_ns {
            return first.w;
        }
        if t_ns >= last.t_ns {
            if !self.inner.config.on_demand || t_ns == last.t_ns {
                return last.w;
            }
            return in_time(ring, t_ns, self.half_period_ns());
        }
        // First sample strictly after t_ns; 1 ≤ i < len here.
        let i = ring.partition_point(|s| s.t_ns <= t_ns);
        let (a, b) = (&ring[i - 1], &ring[i]);
        let s = (t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64;
        along(&a.w, &b.w, s)
    }
}

impl WrenchSource for ContactPhysics {
    /// Linear interpolation in the buffer, clamped at the start; zero before the first step.
    /// Past the newest step, with [`PhysicsConfig::on_demand`]: a cheap model (Winkler,
    /// Hertz: tens of µs a step) steps at the sample's own time, so the F/T reads the exact
    /// contact; the layer model first steps any grid tick at or before the sample that the
    /// physics task has not reached, then reads the pose off the motion's line (see
    /// `ContactPhysics::read_ahead`), and while the indenter rests extrapolates in time
    /// along the last two steps at least half a period apart (relaxation), never past the
    /// unloaded gel. Without on-demand stepping the newest wrench is held.
    fn wrench_at(&self, t_ns: u64) -> Wrench {
        let cheap = matches!(
            self.inner.config.contact,
            ContactModel::Winkler | ContactModel::Hertz
        );
        if cheap {
            self.catch_up(t_ns, true);
        } else {
            // A sample at or past a grid tick reads from that tick's step: solved here if the
            // physics task has not reached it yet (it then finds it done).
            let period_ns = self.period_ns();
            self.catch_up(t_ns / period_ns * period_ns, false);
            if let Some(w) = self.read_ahead(t_ns) {
                return w;
            }
        }
        self.buffered(t_ns)
    }
}

/// Renders the surface field of a [`ContactPhysics`] at the capture time (the newest step at
/// or before it) with the sensor's optics. Frame `n`
/// uses noise seed `noise_seed + n`. Gives no frame before the physics has made a field (the
/// physics must have been created with `want_field`).
pub struct PhysicsRenderer {
    physics: ContactPhysics,
    renderer: optics::Renderer,
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
            renderer: optics::Renderer::new(&optics, &effects),
            noise_seed,
            frames: AtomicU64::new(0),
        }
    }
}

impl PhysicsRenderer {
    /// What rendering has done so far, by effect.
    pub fn stats(&self) -> optics::RenderStats {
        self.renderer.stats()
    }
}

impl FrameRenderer for PhysicsRenderer {
    fn render_at(&self, t_ns: u64) -> Option<image::RgbImage> {
        // The field at the capture time, even when rendering runs late.
        let (_, field) = self.physics.field_at(t_ns)?;
        let n = self.frames.fetch_add(1, Ordering::Relaxed);
        Some(
            self.renderer
                .render(&field, self.noise_seed.wrapping_add(n)),
        )
    }
}

/// Runs blocking work `f` so that it does not hold up a multi-threaded tokio runtime's other
/// tasks: through `block_in_place` on such a runtime (a no-op move off a thread that is not one
/// of its workers), directly anywhere else (a current-thread runtime, no runtime).
fn off_the_async_workers<R>(f: impl FnOnce() -> R) -> R {
    use tokio::runtime::{Handle, RuntimeFlavor};
    match Handle::try_current() {
        Ok(h) if h.runtime_flavor() == RuntimeFlavor::MultiThread => tokio::task::block_in_place(f),
        _ => f(),
    }
}
