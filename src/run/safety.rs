//! The safety supervisor: one task, for the whole run, that checks every F/T sample and the
//! liveness of both streams, feeds the controller's watchdog, and commands the stop first.
//! Without an F/T sensor it checks the UR5e's flange force on every robot state instead
//! ([`super::flange`]).
//!
//! What it never does is wait on anything recording can fill. F/T samples go on to the
//! recording through a queue it only `try_send`s into (a full queue loses the sample for the
//! recording, counted in [`StreamCounters::recording_lost`], and the trajectory then fails
//! with a recording error); a forwarder task does the waiting. The camera task
//! ([`super::streams`]) likewise never waits: it stamps each frame's arrival, which the
//! supervisor reads. So a stalled disk, a full collector or a slow live view can back the
//! recording up, and the force limit is still checked on the next sample.
//!
//! On every RTDE state (500 Hz on an e-Series) it writes the heartbeat through its
//! [`SafetyLine`], the only heartbeat the controller then gets: if the supervisor stalls, the
//! program's `rtde_set_watchdog(…, "stop")` stops the arm after `1 / watchdog_min_hz`.
//!
//! On a trip it first writes the stop request (the program kills the move and decelerates
//! with `stopl`), and only then publishes the trip, which the motion watches ([`Trip`]). The
//! motion's own stop, the retract, the aborts and the bookkeeping all come after.

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;

use rig_core::clock::Clock;
use rig_core::ft::SampleFlags;
use tokio::sync::{mpsc, watch};

use super::events::{Event, StreamCounters, StreamSettings, Trip};
use super::flange::FlangeGuard;
use crate::force::{FtStream, WrenchSample};
use crate::robot::{RobotState, SafetyLine};

/// F/T samples queued toward the recording before they are lost for it: 32 s at 1 kHz, more
/// than any disk hiccup the recorder's own queue does not already absorb.
pub const RECORDING_QUEUE: usize = 1 << 15;

/// The robot side of the supervisor: the line it beats and stops through, and the states that
/// pace the heartbeat.
pub struct SafetyIo {
    pub line: SafetyLine,
    pub states: watch::Receiver<Option<RobotState>>,
}

/// One stop the supervisor commanded.
#[derive(Debug, Clone, PartialEq)]
pub struct SafetyStop {
    pub trip: Trip,
    /// Clock time of the sample (or the stall check) that tripped, ns.
    pub detected_ns: u64,
    /// Clock time the stop request was handed to the RTDE link, ns (`None` without a line or
    /// when the write failed).
    pub commanded_ns: Option<u64>,
    /// The stop request's counter value as written (matches `IN_STOP_REQ` on the controller).
    pub request: Option<i32>,
    /// The robot's reported TCP when the trip was detected (its newest state, at most one
    /// RTDE period old).
    pub tcp_at_detection: Option<rig_core::pose::Pose>,
    /// Whether the recording was backed up when the trip was detected: the F/T forwarder was
    /// waiting for the collector (the disk or the collector behind).
    pub recording_backed_up: bool,
    /// Simulated rig only: when the stop request reached the controller (clock time, ns).
    pub reached_controller_ns: Option<u64>,
    /// Simulated rig only: where the TCP was when the stop request reached the controller.
    pub tcp_at_controller: Option<rig_core::pose::Pose>,
}

/// Sees every stop the supervisor commands, right after it is commanded and published. It
/// runs on the supervisor's task: it must return at once (a notification, never I/O).
pub type StopObserver = Arc<dyn Fn(&SafetyStop) + Send + Sync>;

/// What the supervisor shares with [`super::streams::Streams`].
pub(super) struct Shared {
    pub trip_tx: Arc<watch::Sender<Option<Trip>>>,
    pub counters: Arc<StreamCounters>,
    pub stops: std::sync::Mutex<Vec<SafetyStop>>,
    /// Sees every stop (see [`StopObserver`]).
    pub observer: Option<StopObserver>,
    /// The newest robot state the supervisor saw.
    pub last_state: std::sync::Mutex<Option<RobotState>>,
    /// Clock time of the last heartbeat written, ns (`u64::MAX`: no line to beat).
    pub last_beat_ns: std::sync::atomic::AtomicU64,
    /// The box the reported TCP positions stayed in, m: `[min, max]`.
    pub extent: std::sync::Mutex<Option<[[f64; 3]; 2]>>,
    /// Test and drill injection: while true the supervisor does nothing at all (no checks, no
    /// heartbeat), as a hung task would.
    pub frozen: watch::Sender<bool>,
}

/// Whether a trip `t` replaces the standing one: the first stands, except that a fatal trip
/// replaces a non-fatal one.
pub(super) fn replaces(cur: &Option<Trip>, t: &Trip) -> bool {
    match cur {
        None => true,
        Some(c) => !c.is_fatal() && t.is_fatal(),
    }
}

struct Supervisor {
    clock: Clock,
    settings: StreamSettings,
    shared: Arc<Shared>,
    line: Option<SafetyLine>,
    /// Samples toward the recording (the forwarder waits on the collector, never this task).
    record: mpsc::Sender<Event>,
    camera: bool,
    start_ns: u64,
    last_ft_ns: u64,
    ft_stalled: bool,
    camera_stalled: bool,
}

impl Supervisor {
    /// Stop first, then publish the trip.
    async fn raise(&self, t: Trip, detected_ns: u64) {
        if !replaces(&self.shared.trip_tx.borrow(), &t) {
            return;
        }
        let (mut commanded_ns, mut request) = (None, None);
        if let Some(line) = &self.line {
            match line.stop().await {
                Ok(()) => {
                    commanded_ns = Some(self.clock.now_ns());
                    request = Some(line.stops());
                }
                // The motion's own stop follows the trip; the link loss is the robot's fault
                // to report.
                Err(e) => tracing::error!("safety stop could not be written: {e}"),
            }
        }
        tracing::warn!("safety trip: {t}");
        let stop = SafetyStop {
            trip: t.clone(),
            detected_ns,
            commanded_ns,
            request,
            tcp_at_detection: self
                .shared
                .last_state
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .map(|s| s.actual_tcp_pose),
            recording_backed_up: self
                .shared
                .counters
                .ft_forwarder_waiting
                .load(Ordering::Acquire),
            reached_controller_ns: None,
            tcp_at_controller: None,
        };
        self.shared
            .stops
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(stop.clone());
        self.shared.trip_tx.send_if_modified(|cur| {
            let r = replaces(cur, &t);
            if r {
                *cur = Some(t);
            }
            r
        });
        if let Some(o) = &self.shared.observer {
            o(&stop);
        }
    }

    async fn sample(&mut self, s: WrenchSample) {
        let now = self.clock.now_ns();
        self.last_ft_ns = now;
        self.ft_stalled = false;
        let c = &self.shared.counters;
        c.wrench.fetch_add(1, Ordering::Relaxed);
        let f = s.wrench.force_n;
        let norm = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        let armed = !s.flags.contains(SampleFlags::UNTARED) || c.force_limit_armed_untared();
        let trip = if !norm.is_finite() {
            Some(Trip::FtLost(format!(
                "the F/T sensor reported a non-finite force {f:?}; check its calibration and link"
            )))
        } else if armed && norm > self.settings.max_force_n {
            Some(Trip::ForceLimit {
                force_n: norm,
                limit_n: self.settings.max_force_n,
            })
        } else if s.flags.contains(SampleFlags::SATURATED)
            || s.flags.contains(SampleFlags::GAUGE_SATURATED)
        {
            Some(Trip::Saturated { force_n: norm })
        } else {
            None
        };
        if let Some(t) = trip {
            self.raise(t, s.t_host_ns.min(now)).await;
        }
        if let Err(mpsc::error::TrySendError::Full(_)) = self.record.try_send(Event::Wrench(s)) {
            c.note_recording_lost();
        }
    }

    /// The next instant a stall could be declared.
    fn stall_deadline(&self) -> u64 {
        let mut d = u64::MAX;
        if !self.ft_stalled {
            d = d.min(
                self.last_ft_ns
                    .saturating_add(nanos(self.settings.ft_stall)),
            );
        }
        if self.camera && !self.camera_stalled {
            d = d.min(
                self.last_frame_ns()
                    .saturating_add(nanos(self.settings.camera_stall)),
            );
        }
        d
    }

    fn last_frame_ns(&self) -> u64 {
        self.shared
            .counters
            .last_frame_rx_ns
            .load(Ordering::Acquire)
            .max(self.start_ns)
    }

    async fn check_stalls(&mut self) {
        let now = self.clock.now_ns();
        let ft_stall = nanos(self.settings.ft_stall);
        if !self.ft_stalled && now.saturating_sub(self.last_ft_ns) >= ft_stall {
            self.ft_stalled = true;
            let after_ms = self.settings.ft_stall.as_secs_f64() * 1e3;
            self.raise(Trip::FtStalled { after_ms }, now).await;
        }
        let cam_stall = nanos(self.settings.camera_stall);
        if self.camera
            && !self.camera_stalled
            && now.saturating_sub(self.last_frame_ns()) >= cam_stall
        {
            self.camera_stalled = true;
            let after_ms = self.settings.camera_stall.as_secs_f64() * 1e3;
            self.raise(Trip::CameraStalled { after_ms }, now).await;
        }
    }

    async fn run(
        mut self,
        mut ft: Option<FtStream>,
        mut states: Option<watch::Receiver<Option<RobotState>>>,
        mut trips_in: mpsc::UnboundedReceiver<Trip>,
        mut frozen: watch::Receiver<bool>,
    ) {
        let clock = self.clock.clone();
        let mut ft_open = ft.is_some();
        loop {
            if *frozen.borrow_and_update() {
                // A hung supervisor, on purpose: nothing is checked and no heartbeat goes out.
                if frozen.wait_for(|f| !*f).await.is_err() {
                    std::future::pending::<()>().await;
                }
                continue;
            }
            // A stalled camera that sends again is watched again (a stalled F/T, on its next
            // sample).
            if self.camera_stalled
                && clock.now_ns().saturating_sub(self.last_frame_ns())
                    < nanos(self.settings.camera_stall)
            {
                self.camera_stalled = false;
            }
            let deadline = self.stall_deadline();
            tokio::select! {
                biased;
                _ = frozen.changed() => {}
                t = trips_in.recv() => if let Some(t) = t {
                    self.raise(t, clock.now_ns()).await;
                },
                s = next_sample(&mut ft), if ft_open => match s {
                    Some(s) => self.sample(s).await,
                    None => {
                        ft_open = false;
                        self.ft_stalled = true; // lost, not stalled: no stall trip on top
                        let why = ft
                            .as_ref()
                            .and_then(|ft| {
                                ft.error()
                                    .map(|e| e.to_string())
                                    .or_else(|| Some(format!("{} stopped", ft.description)))
                            })
                            .unwrap_or_default();
                        self.raise(Trip::FtLost(why), clock.now_ns()).await;
                    }
                },
                r = state_changed(&mut states) => match r {
                    Ok(()) => {
                        self.beat().await;
                        let s = states.as_mut().and_then(|rx| *rx.borrow_and_update());
                        if let Some(s) = s {
                            self.state(&s).await;
                        }
                    }
                    Err(_) => states = None,
                },
                _ = clock.sleep_until_ns(deadline) => self.check_stalls().await,
            }
        }
    }

    /// Check a robot state: a finite TCP pose inside the envelope, and without an F/T sensor
    /// the flange sensor's force.
    async fn state(&self, s: &RobotState) {
        *self
            .shared
            .last_state
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = Some(*s);
        let p = s.actual_tcp_pose;
        let now = self.clock.now_ns();
        if let Some(g) = &self.settings.flange
            && g.trips(&s.actual_tcp_force)
        {
            let t = Trip::FlangeForceLimit {
                force_n: FlangeGuard::force_n(&s.actual_tcp_force),
                threshold_n: g.threshold_n,
                limit_n: g.limit_n,
            };
            self.raise(t, s.t_host_ns.min(now)).await;
        }
        if !p.to_array().iter().all(|v| v.is_finite()) {
            self.raise(Trip::NonFinitePose, now).await;
            return;
        }
        let pos = [p.x, p.y, p.z];
        {
            let mut e = self.shared.extent.lock().unwrap_or_else(|e| e.into_inner());
            let [lo, hi] = e.get_or_insert([pos, pos]);
            for k in 0..3 {
                lo[k] = lo[k].min(pos[k]);
                hi[k] = hi[k].max(pos[k]);
            }
        }
        if let Some(env) = &self.settings.envelope
            && !env.contains(pos)
        {
            let tcp_mm = pos.map(|v| v * 1e3);
            self.raise(Trip::OutsideEnvelope { tcp_mm }, now).await;
        }
    }

    /// Feed the controller's watchdog. A failed write (the link reconnecting) is retried on
    /// the next state.
    async fn beat(&mut self) {
        if let Some(line) = &self.line
            && line.beat().await.is_ok()
        {
            self.shared
                .last_beat_ns
                .store(self.clock.now_ns(), Ordering::Release);
        }
    }
}

/// The next F/T sample; never, without an F/T sensor.
async fn next_sample(ft: &mut Option<FtStream>) -> Option<WrenchSample> {
    match ft {
        Some(ft) => ft.next().await,
        None => std::future::pending().await,
    }
}

/// The next change of the robot's state; never, without one.
async fn state_changed(
    states: &mut Option<watch::Receiver<Option<RobotState>>>,
) -> Result<(), watch::error::RecvError> {
    match states {
        Some(rx) => rx.changed().await,
        None => std::future::pending().await,
    }
}

/// Starts the supervisor on `ft` (see the module docs; none: no F/T sensor, no F/T checks or
/// stall watch); with `io`, it beats and stops through its line. Returns the task and the
/// forwarder that carries samples to `out`.
#[allow(clippy::too_many_arguments)] // each is one of the supervisor's inputs
pub(super) fn spawn(
    ft: Option<FtStream>,
    clock: Clock,
    settings: StreamSettings,
    camera: bool,
    shared: Arc<Shared>,
    io: Option<SafetyIo>,
    trips_in: mpsc::UnboundedReceiver<Trip>,
    out: mpsc::Sender<Event>,
) -> [tokio::task::JoinHandle<()>; 2] {
    let (record, mut queued) = mpsc::channel::<Event>(RECORDING_QUEUE);
    let counters = shared.counters.clone();
    let forwarder = tokio::spawn(async move {
        while let Some(ev) = queued.recv().await {
            counters.ft_forwarder_waiting.store(true, Ordering::Release);
            let sent = super::events::forward(&out, ev, &counters).await;
            counters
                .ft_forwarder_waiting
                .store(false, Ordering::Release);
            if !sent {
                return;
            }
        }
    });
    let now = clock.now_ns();
    let (line, states) = match io {
        Some(io) => (Some(io.line), Some(io.states)),
        None => (None, None),
    };
    let frozen = shared.frozen.subscribe();
    let sup = Supervisor {
        clock,
        settings,
        shared,
        line,
        record,
        camera,
        start_ns: now,
        last_ft_ns: now,
        // Without an F/T sensor there is no stream to stall.
        ft_stalled: ft.is_none(),
        camera_stalled: false,
    };
    let task = tokio::spawn(sup.run(ft, states, trips_in, frozen));
    [task, forwarder]
}

fn nanos(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}
