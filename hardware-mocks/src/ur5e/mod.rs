//! A simulated UR5e controller that speaks real RTDE over TCP.
//!
//! # Shape
//!
//! [`Ur5e::start`] binds three TCP listeners and spawns:
//!
//! - the **controller task**, ticking on the shared [`Clock`] at `max_frequency_hz` (500 Hz,
//!   2 ms, on e-Series; 125 Hz on a CB3 variant); every tick is processed, late wake-ups catch up,
//!   and a simulated clock waits for the task when it falls behind. Each tick advances the
//!   [`controller`] model (motion, program, watchdog) and broadcasts a [`ControllerSnapshot`];
//! - the **RTDE server** ([`rtde_server`]), one task per connection, which turns those
//!   snapshots into data packages at each recipe's frequency and writes input packages into the
//!   controller's registers;
//! - the **dashboard server** ([`dashboard`]): power on, brake release, unlock protective stop,
//!   play, stop, mode queries;
//! - the **secondary interface** ([`script`]), which accepts URScript programs; the
//!   controller runs them with its interpreter ([`urscript`], [`program`]).
//!
//! [`Ur5eConfig`] ([`config`]) sets it up; [`ControllerSnapshot`] ([`snapshot`]) is one tick's
//! state. What the tasks share, and the accept loop of the three servers, are in `shared.rs`;
//! nothing there or in the servers imports this file, which only starts and drives them.
//!
//! All timing comes from the [`Clock`], so with [`Clock::scaled`] the simulated arm runs faster
//! than real time and with [`Clock::manual`] a test steps it tick by tick
//! ([`Ur5e::step_ticks`]).
//!
//! # Motion model
//!
//! The arm's state is its flange pose; the program's TCP offset (`set_tcp`, identity when a
//! program starts) gives the reported TCP pose, and the configured physical tool
//! ([`Ur5eConfig::tool_offset`]) gives the tip that touches things ([`Ur5e::tip_pose_at`]); see
//! [`controller`]. `movel` follows a trapezoidal velocity profile with the commanded speed and acceleration
//! (a triangle when the path is too short), computed analytically from the move's start tick
//! ([`motion`]). The actual TCP pose is the profile's pose exactly — the real controller's
//! tracking error is **not modelled** — and `target_TCP_pose` equals it. `actual_TCP_speed` is
//! the profile's velocity: linear part along the line, angular part about the move's rotation
//! axis. A command is read at the tick after its registers arrive, the move starts at that tick
//! and is done (OUT_DONE_SEQ written) at the first tick at or after `start + duration`.
//!
//! # Programs
//!
//! The controller runs the URScript it is sent, with an interpreter for the subset of the
//! language the rig's control program ([`rig_core::urscript::program`]) uses ([`urscript`]):
//! one interpreter cycle per controller tick, threads, blocking `movel`/`stopl`/`sync`/`sleep`,
//! registers, `set_tcp`, `rtde_set_watchdog`. What the rig's program does with the command
//! registers of [`rig_core::control`] is therefore whatever its text says; nothing of it is
//! emulated here. A script that does not compile never starts; a runtime error stops the
//! program (both logged as errors with the line and statement). `rtde_set_watchdog` calls the
//! program executes are honoured on clock time while it plays. Every input package that
//! changes IN_CMD_SEQ is logged ([`Ur5e::commands_received`]), so a test can tell when a
//! command reached the controller.
//!
//! # Faults ([`Faults`])
//!
//! - **Protective stop**: motion decelerates at [`controller::CONTROLLER_STOP_DECEL`] (3 m/s²
//!   or rad/s², or the move's own acceleration if larger; a category-2-like controlled stop),
//!   safety_mode PROTECTIVE_STOP (3), the program stops (runtime_state STOPPED) and its command
//!   is never marked done. Dashboard `unlock protective stop` is refused with the real
//!   controller's message until `protective_stop_unlock_delay` of clock time has passed; then
//!   safety_mode NORMAL, robot_mode RUNNING, and the program must be uploaded again (or
//!   restarted with dashboard `play`).
//! - **Emergency stop** (robot emergency stop, the arm's e-stop button): same deceleration, then
//!   safety_mode ROBOT_EMERGENCY_STOP (7), robot_mode POWER_OFF (3), program STOPPED. `power on`
//!   and `brake release` are refused until [`Faults::release_emergency_stop`] (the button pulled
//!   out), after which safety is NORMAL and the robot still needs power on + brake release.
//! - **Connection drop**: every RTDE socket is closed; for `refuse_for` of clock time new
//!   connections are accepted and closed at once (the listener stays bound, so the client sees
//!   an immediate EOF rather than "connection refused"). Input registers claimed by the dropped
//!   connections are released. Dashboard and script ports are unaffected.
//! - **Delayed start acknowledgement**: the next `S` starts streaming at once; its reply is sent
//!   only after the given clock time, so data packages arrive before it.
//! - **Text messages during handshake**: an info-level `M` precedes every V, v, O and I reply.
//!
//! # Not modelled
//!
//! Joint space (joint values are zeros), the binary robot-state stream real controllers send
//! on the secondary interface, and URScript beyond the interpreter's subset ([`urscript`]).
//! `actual_TCP_force` is zero unless a [`FlangeSensor`] is fitted
//! ([`Ur5e::fit_flange_sensor`]; the simulated rig fits one reading its contact physics, with
//! the data sheet's accuracy, see [`flange`]); the URScript `zero_ftsensor()` is not modelled.

pub mod config;
pub mod controller;
pub mod dashboard;
pub mod flange;
pub mod motion;
pub mod program;
pub mod rtde_server;
pub mod script;
mod shared;
pub mod snapshot;
pub mod urscript;
#[cfg(test)]
mod urscript_tests;
pub mod variables;

use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rig_core::clock::{Clock, ClockHandle};
use rig_core::pose::Pose;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;

use controller::Controller;
use shared::{FaultState, Shared};

pub use config::Ur5eConfig;
pub use controller::{CommandReceived, StopRequestReceived};
pub use flange::{FlangeSensor, FlangeSpec, UR5E_FLANGE};
pub use snapshot::ControllerSnapshot;

/// A running simulated controller. Dropping it (or [`Ur5e::shutdown`]) stops every task.
pub struct Ur5e {
    shared: Arc<Shared>,
    rtde_addr: SocketAddr,
    dashboard_addr: SocketAddr,
    script_addr: SocketAddr,
    tasks: Vec<JoinHandle<()>>,
}

/// Injects faults into a running controller; cheap to clone.
#[derive(Clone)]
pub struct Faults {
    shared: Arc<Shared>,
}

/// Snapshots kept for slow connections: 2 s at 500 Hz.
const SAMPLE_BUFFER: usize = 1024;

impl Ur5e {
    /// Bind the listeners and start the controller.
    pub async fn start(cfg: Ur5eConfig, clock: Clock) -> std::io::Result<Ur5e> {
        if !(cfg.max_frequency_hz.is_finite() && cfg.max_frequency_hz > 0.0) {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!(
                    "max_frequency_hz must be positive, got {}",
                    cfg.max_frequency_hz
                ),
            ));
        }
        let rtde = TcpListener::bind(cfg.rtde_addr).await?;
        let dashboard = TcpListener::bind(cfg.dashboard_addr).await?;
        let script = TcpListener::bind(cfg.script_addr).await?;
        let (rtde_addr, dashboard_addr, script_addr) = (
            rtde.local_addr()?,
            dashboard.local_addr()?,
            script.local_addr()?,
        );
        let tick_period_ns = (1e9 / cfg.max_frequency_hz).round() as u64;
        let t0 = clock.now_ns();
        let controller = Controller::new(
            cfg.home_pose,
            cfg.tool_offset,
            cfg.initial_robot_mode,
            u64::try_from(cfg.protective_stop_unlock_delay.as_nanos()).unwrap_or(u64::MAX),
            t0,
        );
        let shared = Arc::new(Shared {
            clock,
            cfg,
            state: Mutex::new(controller),
            samples: broadcast::channel(SAMPLE_BUFFER).0,
            ticks_done: watch::channel(t0).0,
            shutdown: watch::channel(false).0,
            drop_gen: watch::channel(0).0,
            faults: Mutex::new(FaultState::default()),
            packages_sent: AtomicU64::new(0),
            next_conn: AtomicU64::new(1),
            t0_ns: t0,
            next_tick_ns: Mutex::new(t0 + tick_period_ns),
            tick_period_ns,
            poses: Mutex::new(std::collections::VecDeque::with_capacity(
                shared::POSE_HISTORY,
            )),
            flange: Mutex::new(None),
        });
        let tasks = vec![
            tokio::spawn(run_controller(shared.clone())),
            tokio::spawn(rtde_server::serve(rtde, shared.clone())),
            tokio::spawn(dashboard::serve(dashboard, shared.clone())),
            tokio::spawn(script::serve(script, shared.clone())),
        ];
        tracing::info!(%rtde_addr, %dashboard_addr, %script_addr, "simulated UR5e started");
        Ok(Ur5e {
            shared,
            rtde_addr,
            dashboard_addr,
            script_addr,
            tasks,
        })
    }

    pub fn rtde_addr(&self) -> SocketAddr {
        self.rtde_addr
    }
    pub fn dashboard_addr(&self) -> SocketAddr {
        self.dashboard_addr
    }
    pub fn script_addr(&self) -> SocketAddr {
        self.script_addr
    }

    /// The controller's current state.
    pub fn snapshot(&self) -> ControllerSnapshot {
        let mut s = self.shared.lock().snapshot();
        s.data_packages_sent = self.shared.packages_sent.load(Ordering::Relaxed);
        s
    }

    /// The controller's state at the current clock time: ticks already due are processed first
    /// (and broadcast, in order), as if the controller task had woken on time. A consumer that
    /// needs the pose *now* (the contact physics) uses this rather than [`Ur5e::snapshot`],
    /// which lags by the task's wake-up delay (milliseconds of clock time on a scaled clock).
    pub fn snapshot_now(&self) -> ControllerSnapshot {
        self.shared.process_due_ticks(self.shared.clock.now_ns());
        self.snapshot()
    }

    /// The TCP pose the controller had at clock time `t_ns`, from its last tick at or before
    /// it, with that tick's time. Ticks due now are processed first, as in
    /// [`Self::snapshot_now`], so a consumer running late (a camera rendering a frame after
    /// its capture time) still sees the pose of its own instant, not the pose of when it got
    /// round to asking. A time before the kept history (2 s) gives its oldest tick; `None`
    /// before the first tick.
    pub fn tcp_pose_at(&self, t_ns: u64) -> Option<(u64, Pose)> {
        self.poses_at(t_ns).map(|p| (p.t_ns, p.tcp))
    }

    /// Where the physical tool tip ([`Ur5eConfig::tool_offset`] from the flange) was at clock
    /// time `t_ns`, as [`Self::tcp_pose_at`] gives the TCP: what the contact physics presses
    /// with. It equals the TCP pose only when the program's TCP (`set_tcp`) matches the tool.
    pub fn tip_pose_at(&self, t_ns: u64) -> Option<(u64, Pose)> {
        self.poses_at(t_ns).map(|p| (p.t_ns, p.tip))
    }

    /// Where the physical tool tip was at exactly clock time `t_ns`, with `t_ns`: a real arm
    /// moves continuously between the controller's 2 ms setpoints, so the tip's position is
    /// interpolated linearly between the ticks on either side of `t_ns`, or, past the newest
    /// tick (never more than a period: due ticks are processed first), carried on at the
    /// velocity of the last two ticks. Over one period that differs from the true path by at
    /// most a·T²/2 (0.1 µm at the plan's 50 mm/s²). The rotation is the earlier tick's: the
    /// contact reads only the position, and rotation vectors near π are not interpolated
    /// component-wise. What the contact physics presses with ([`Self::tip_pose_at`] holds
    /// the tick's pose instead, which put the F/T's readings up to a tick behind the frames').
    /// `None` before the first tick.
    pub fn tip_pose_moving(&self, t_ns: u64) -> Option<(u64, Pose)> {
        self.shared.process_due_ticks(self.shared.clock.now_ns());
        let poses = self.shared.poses.lock().unwrap_or_else(|p| p.into_inner());
        let i = poses.partition_point(|p| p.t_ns <= t_ns);
        let a = poses.get(i.checked_sub(1)?)?;
        let (b, s) = match poses.get(i) {
            // Between two ticks.
            Some(b) => (b, (t_ns - a.t_ns) as f64 / (b.t_ns - a.t_ns) as f64),
            // Past the newest tick: along the last two ticks' line.
            None => match i.checked_sub(2).and_then(|k| poses.get(k)) {
                Some(prev) if a.t_ns > prev.t_ns => {
                    let period = self.shared.tick_period_ns.max(1);
                    let dt = (t_ns - a.t_ns).min(period);
                    let s = -(dt as f64) / (a.t_ns - prev.t_ns) as f64;
                    (prev, s)
                }
                _ => return Some((t_ns, a.tip)),
            },
        };
        let mut tip = a.tip;
        tip.x += s * (b.tip.x - a.tip.x);
        tip.y += s * (b.tip.y - a.tip.y);
        tip.z += s * (b.tip.z - a.tip.z);
        Some((t_ns, tip))
    }

    /// The physical tool tip at the current clock time (due ticks processed first), with the
    /// time of the controller's last tick.
    pub fn tip_pose_now(&self) -> (u64, Pose) {
        self.shared.process_due_ticks(self.shared.clock.now_ns());
        let c = self.shared.lock();
        (c.t_ns, c.tip_pose())
    }

    fn poses_at(&self, t_ns: u64) -> Option<shared::TickPoses> {
        self.shared.process_due_ticks(self.shared.clock.now_ns());
        let poses = self.shared.poses.lock().unwrap_or_else(|p| p.into_inner());
        let i = poses.partition_point(|p| p.t_ns <= t_ns);
        poses.get(i.saturating_sub(1)).copied()
    }

    /// Fits the flange force/torque sensor: from the next tick on, `actual_TCP_force` is its
    /// reading.
    pub fn fit_flange_sensor(&self, sensor: FlangeSensor) {
        *self.shared.flange.lock().unwrap_or_else(|p| p.into_inner()) = Some(sensor);
    }

    /// Every input data package that changed IN_CMD_SEQ ([`rig_core::control::IN_CMD_SEQ`]),
    /// oldest first, the last [`controller::COMMAND_LOG`] of them: when each command reached
    /// the controller (e.g. how long a Stop took to arrive).
    pub fn commands_received(&self) -> Vec<CommandReceived> {
        self.shared.lock().commands_received()
    }

    /// Every input data package that changed the stop request
    /// ([`rig_core::control::IN_STOP_REQ`]), oldest first: when each supervisor stop reached
    /// the controller.
    pub fn stop_requests_received(&self) -> Vec<StopRequestReceived> {
        self.shared.lock().stop_requests_received()
    }

    /// The fault injector.
    pub fn faults(&self) -> Faults {
        Faults {
            shared: self.shared.clone(),
        }
    }

    /// Controller period in nanoseconds (2 ms at 500 Hz).
    pub fn tick_period_ns(&self) -> u64 {
        self.shared.tick_period_ns
    }

    /// For tests on a manual clock: advance `handle` to the next `n` controller ticks, one at a
    /// time, waiting after each until the controller has processed it (its snapshot is then
    /// broadcast to every RTDE connection).
    pub async fn step_ticks(&self, handle: &ClockHandle, n: u64) {
        let mut done = self.shared.ticks_done.subscribe();
        let (t0, p) = (self.shared.t0_ns, self.shared.tick_period_ns);
        for _ in 0..n {
            let now = self.shared.clock.now_ns();
            let target = t0 + (now.saturating_sub(t0) / p + 1) * p;
            handle.advance_to_ns(target);
            let _ = done.wait_for(|t| *t >= target).await;
        }
    }

    /// Stop every task and close every socket, and wait until they have ended.
    pub async fn shutdown(mut self) {
        self.halt();
        for t in self.tasks.drain(..) {
            let _ = t.await;
        }
        tracing::info!("simulated UR5e shut down");
    }

    /// Stops every task now, as dropping the last handle does, while other handles remain (a
    /// consumer still holding the arm for its poses reads the last ones).
    pub fn halt(&self) {
        self.shared.shutdown.send_replace(true);
        for t in &self.tasks {
            t.abort();
        }
    }
}

impl Drop for Ur5e {
    fn drop(&mut self) {
        self.halt();
    }
}

/// The controller task. A real controller produces every 2 ms sample; so does this one. When
/// the task wakes late (tokio timers have about 1 ms resolution, and a scaled clock makes a tick
/// shorter than that) it processes the missed ticks at once, each with its own time stamp, so
/// the RTDE stream keeps its full rate in clock time. Only when it falls more than
/// [`MAX_CATCH_UP_NS`] behind (the process was suspended) does it skip ahead, with a warning.
///
/// The task paces a simulated clock ([`rig_core::clock::Pacer`]): when it falls behind (the host
/// stalled), simulated time holds for it instead of running on without a controller, so the
/// rig's timeouts on clock time do not fire for the host's sake.
async fn run_controller(shared: Arc<Shared>) {
    let period = shared.tick_period_ns;
    let pacer = shared
        .clock
        .pacer("simulated UR5e controller", rig_core::clock::SIM_PACER_LEAD);
    loop {
        let next_ns = *shared
            .next_tick_ns
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        // Ticks processed by others ([`Ur5e::snapshot_now`], [`Ur5e::tcp_pose_at`]) are the
        // controller's progress too. Reported before sleeping towards the next one: if others
        // had processed ticks up to where the clock holds for this pacer, the next tick would
        // lie beyond the hold, and the clock and this task would wait for each other forever
        // (a `rig run` hung that way on a loaded host).
        pacer.reached(next_ns.saturating_sub(period));
        shared.clock.sleep_until_ns(next_ns).await;
        let now = shared.clock.now_ns();
        if now.saturating_sub(next_ns) > MAX_CATCH_UP_NS {
            let skipped = (now - next_ns) / period;
            tracing::warn!("simulated controller fell {skipped} ticks behind; skipping them");
            let mut next = shared
                .next_tick_ns
                .lock()
                .unwrap_or_else(|p| p.into_inner());
            *next = (*next).max(next_ns + skipped * period);
        }
        shared.process_due_ticks(now);
        pacer.reached(now);
    }
}

/// How far behind the controller task may fall before it skips ticks instead of catching up.
const MAX_CATCH_UP_NS: u64 = 1_000_000_000;

impl Faults {
    fn now(&self) -> u64 {
        self.shared.clock.now_ns()
    }

    /// A protective stop now (see the module docs).
    pub fn protective_stop(&self) {
        let now = self.now();
        self.shared.lock().protective_stop(now);
    }

    /// A robot emergency stop now: safety_mode 7, robot_mode POWER_OFF (see the module docs).
    pub fn emergency_stop(&self) {
        let now = self.now();
        self.shared.lock().emergency_stop(now);
    }

    /// Release the emergency-stop button: safety NORMAL, the robot stays powered off.
    pub fn release_emergency_stop(&self) {
        self.shared.lock().release_emergency_stop();
    }

    /// Close every RTDE connection, and close new ones at once for `refuse_for` of clock time
    /// (a controller restarting its RTDE server).
    pub fn drop_connections(&self, refuse_for: Duration) {
        let until = self
            .now()
            .saturating_add(u64::try_from(refuse_for.as_nanos()).unwrap_or(u64::MAX));
        self.shared.faults().refuse_until_ns = until;
        self.shared.drop_gen.send_modify(|g| *g += 1);
        tracing::warn!(?refuse_for, "RTDE connections dropped (injected fault)");
    }

    /// The next `S` starts streaming at once but is answered only after `d` of clock time.
    pub fn delay_start_ack(&self, d: Duration) {
        self.shared.faults().delay_start_ack = Some(d);
    }

    /// While on, a text message precedes every V, v, O and I reply.
    pub fn text_messages_during_handshake(&self, on: bool) {
        self.shared.faults().text_in_handshake = on;
    }
}
