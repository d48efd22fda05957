//! One injectable clock for the rig and the mocks.
//!
//! Every component takes time from a [`Clock`] handle instead of calling `Instant::now()` or
//! `tokio::time::sleep` itself. Three kinds exist:
//!
//! - [`Clock::system`]: real monotonic time, for the lab rig.
//! - [`Clock::scaled`]: simulated time that runs `factor` times faster than real time, so the
//!   simulated rig (real sockets, real tasks) can finish a 240-trajectory plan in minutes.
//! - [`Clock::manual`]: time moves only when a test advances the returned [`ClockHandle`], so a
//!   test that steps time is deterministic.
//!
//! A simulated clock ([`Clock::scaled`], [`Clock::governed`]) also waits for the simulation: a
//! participant registers a [`Pacer`] and reports how far it has got, and the clock never runs
//! more than the pacer's lead (a span of real time) ahead of the slowest one. When the host
//! stalls (a descheduled thread, a slow disk, a debug build, a CPU-heavy job beside it) the
//! participants stop reporting and simulated time holds instead of racing on, so a timeout of
//! half a second of simulated time still means half a second of the simulation's own work.
//! [`spawn_runtime_pacer`] paces the clock on the tokio runtime itself. On the system clock a
//! pacer does nothing: lab timeouts keep their meaning.
//!
//! Time is a `u64` count of nanoseconds since the clock's epoch (its creation), named `t_ns`
//! throughout the code base. Device clocks (RTDE `timestamp`, F/T sequence counters, V4L2 buffer
//! stamps) are mapped onto this one by explicit estimators, never assumed equal to it.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

// tokio's Instant reads std's monotonic clock, except under a paused tokio runtime, where it
// follows tokio's virtual time; using it keeps `now_ns` and the sleeps on one time base.
use tokio::time::Instant;

use tokio::sync::watch;

mod simulated;

pub use simulated::HoldStats;
use simulated::{PacerSlot, Segment, SimState};

/// A cheap, cloneable handle on a shared clock.
#[derive(Clone, Debug)]
pub struct Clock {
    inner: Arc<Inner>,
}

#[derive(Debug)]
enum Inner {
    System {
        origin: Instant,
    },
    Manual {
        now_ns: AtomicU64,
        tick: watch::Sender<u64>,
    },
    /// [`Clock::scaled`] (`adjustable: false`) and [`Clock::governed`].
    Simulated {
        state: std::sync::Mutex<SimState>,
        /// Bumped on every rate change and whenever a hold is lifted, so sleepers recompute
        /// their deadlines.
        changed: watch::Sender<u64>,
        adjustable: bool,
    },
}

/// Advances a manual clock. Dropping it does not stop the clock's sleepers from being woken by
/// other handles; a clock with no handle left simply never moves again.
#[derive(Clone, Debug)]
pub struct ClockHandle {
    clock: Clock,
}

/// A participant of a simulated clock: the clock runs at most `lead` of real time ahead of the
/// time this pacer last [reached](Pacer::reached). Made by [`Clock::pacer`]; dropping it lets the
/// clock go on without it. On the system and manual clocks it does nothing.
///
/// The lead must be longer than the real time the participant needs between two reports at
/// the clock's rate (a task that waits for the clock to reach its next step must be allowed to
/// get there), or the clock would wait for it forever.
#[derive(Debug)]
pub struct Pacer {
    clock: Clock,
    id: u64,
}

impl Pacer {
    /// The participant has done its work up to clock time `t_ns`.
    pub fn reached(&self, t_ns: u64) {
        self.clock.with_pacers(|st| {
            if let Some(p) = st.pacers.iter_mut().find(|p| p.id == self.id) {
                p.reached_ns = p.reached_ns.max(t_ns);
            }
        });
    }
}

impl Drop for Pacer {
    fn drop(&mut self) {
        self.clock
            .with_pacers(|st| st.pacers.retain(|p| p.id != self.id));
    }
}

/// The lead the simulated devices give their pacers: 20 ms of real time. Long enough that a
/// task woken a few timer ticks late (tokio's timers have 1 ms resolution) does not hold the
/// clock; short enough that a stalled host costs a simulated timeout no more than this much of
/// its budget (at ×10, 200 ms of clock time against the rig's 500 ms acknowledgement timeout).
pub const SIM_PACER_LEAD: Duration = Duration::from_millis(20);

/// Paces a simulated clock on the tokio runtime it is called in: a task that reports the clock's
/// time every millisecond of real time, so that when the runtime stalls (its threads
/// descheduled, the process stopped) simulated time holds at most `lead` of real time later.
/// Returns the task; abort it (or drop the runtime) to stop pacing. Does nothing useful on the
/// system or manual clock.
pub fn spawn_runtime_pacer(clock: &Clock, lead: Duration) -> tokio::task::JoinHandle<()> {
    let pacer = clock.pacer("tokio runtime", lead);
    let clock = clock.clone();
    tokio::spawn(async move {
        loop {
            pacer.reached(clock.now_ns());
            // Real time: the pacer watches the machine, not the simulation.
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
    })
}

/// Error of [`Clock::timeout`]: the deadline passed before the future completed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("timed out after {0:?} of clock time")]
pub struct Elapsed(pub Duration);

impl Clock {
    /// Real monotonic time.
    pub fn system() -> Self {
        Self {
            inner: Arc::new(Inner::System {
                origin: Instant::now(),
            }),
        }
    }

    /// Simulated time running `factor` times as fast as real time (`factor` ≥ 1 runs faster).
    ///
    /// Panics if `factor` is not finite and positive: that is a programming error, not input.
    pub fn scaled(factor: f64) -> Self {
        assert!(
            factor.is_finite() && factor > 0.0,
            "clock scale factor must be finite and positive, got {factor}"
        );
        if factor == 1.0 {
            return Self::system();
        }
        Self::simulated(factor, false)
    }

    fn simulated(factor: f64, adjustable: bool) -> Self {
        let (changed, _) = watch::channel(0);
        Self {
            inner: Arc::new(Inner::Simulated {
                state: std::sync::Mutex::new(SimState::new(factor)),
                changed,
                adjustable,
            }),
        }
    }

    /// Simulated time like [`Clock::scaled`], whose rate can be changed while it runs
    /// ([`Clock::set_rate`]): a governor slows it down when a simulated device cannot keep up,
    /// so every device still sees one consistent time. Time never jumps: a rate change only
    /// changes how fast it moves from now on. Sleepers wake at the right clock time across rate
    /// changes.
    ///
    /// Panics if `factor` is not finite and positive (a programming error).
    pub fn governed(factor: f64) -> Self {
        assert!(
            factor.is_finite() && factor > 0.0,
            "clock scale factor must be finite and positive, got {factor}"
        );
        Self::simulated(factor, true)
    }

    /// Changes the rate of a [`Clock::governed`] clock from now on; returns `false` (and does
    /// nothing) for any other clock or a rate that is not finite and positive.
    pub fn set_rate(&self, factor: f64) -> bool {
        let Inner::Simulated {
            state,
            changed,
            adjustable: true,
        } = &*self.inner
        else {
            return false;
        };
        if !(factor.is_finite() && factor > 0.0) {
            return false;
        }
        {
            let mut g = state.lock().unwrap_or_else(|p| p.into_inner());
            let t = g.now_ns();
            g.seg = Segment {
                base: Instant::now(),
                base_ns: t,
                factor,
            };
        }
        changed.send_modify(|g| *g = g.wrapping_add(1));
        true
    }

    /// A clock that only moves when the returned handle advances it. It starts at `t_ns = 0`.
    pub fn manual() -> (Self, ClockHandle) {
        let (tick, _) = watch::channel(0);
        let clock = Self {
            inner: Arc::new(Inner::Manual {
                now_ns: AtomicU64::new(0),
                tick,
            }),
        };
        let handle = ClockHandle {
            clock: clock.clone(),
        };
        (clock, handle)
    }

    /// How many clock seconds pass per real second (1 for the system clock; undefined, reported
    /// as infinity, for a manual clock).
    pub fn rate(&self) -> f64 {
        match &*self.inner {
            Inner::System { .. } => 1.0,
            Inner::Manual { .. } => f64::INFINITY,
            Inner::Simulated { state, .. } => {
                state.lock().unwrap_or_else(|p| p.into_inner()).seg.factor
            }
        }
    }

    /// Nanoseconds since the clock's epoch.
    pub fn now_ns(&self) -> u64 {
        match &*self.inner {
            Inner::System { origin } => saturating_ns(origin.elapsed()),
            Inner::Manual { now_ns, .. } => now_ns.load(Ordering::Acquire),
            Inner::Simulated { state, .. } => {
                state.lock().unwrap_or_else(|p| p.into_inner()).now_ns()
            }
        }
    }

    /// Time since the clock's epoch.
    pub fn now(&self) -> Duration {
        Duration::from_nanos(self.now_ns())
    }

    /// Seconds since the clock's epoch, as `f64`.
    pub fn now_s(&self) -> f64 {
        self.now_ns() as f64 * 1e-9
    }

    /// Registers a participant that this clock waits for (see [`Pacer`]): from now on the clock
    /// runs at most `lead` of real time ahead of the time the pacer last reached, which starts
    /// at the clock's time now. On the system and manual clocks the pacer does nothing.
    pub fn pacer(&self, name: &'static str, lead: Duration) -> Pacer {
        let mut id = u64::MAX;
        let now = self.now_ns();
        self.with_pacers(|st| {
            id = st.next_id;
            st.next_id += 1;
            st.pacers.push(PacerSlot {
                id,
                name,
                reached_ns: now,
                lead,
            });
        });
        Pacer {
            clock: self.clone(),
            id,
        }
    }

    /// How often this clock held for its pacers (all zero for the system and manual clocks).
    pub fn hold_stats(&self) -> HoldStats {
        match &*self.inner {
            Inner::Simulated { state, .. } => {
                let g = state.lock().unwrap_or_else(|p| p.into_inner());
                let mut s = g.stats;
                if let Some(t) = s.started {
                    s.held_s += t.elapsed().as_secs_f64();
                }
                s
            }
            _ => HoldStats::default(),
        }
    }

    /// Changes the pacers of a simulated clock; wakes the sleepers when that lifts a hold.
    fn with_pacers(&self, f: impl FnOnce(&mut SimState)) {
        let Inner::Simulated { state, changed, .. } = &*self.inner else {
            return;
        };
        let lifted = {
            let mut g = state.lock().unwrap_or_else(|p| p.into_inner());
            let before = g.limit().0;
            let held = g.seg.now_ns() > before;
            f(&mut g);
            held && g.limit().0 > before
        };
        if lifted {
            changed.send_modify(|g| *g = g.wrapping_add(1));
        }
    }

    /// Sleep until the clock reads at least `t_ns`.
    pub async fn sleep_until_ns(&self, t_ns: u64) {
        match &*self.inner {
            Inner::System { origin } => {
                tokio::time::sleep_until(*origin + Duration::from_nanos(t_ns)).await;
            }
            Inner::Manual { tick, .. } => {
                let mut rx = tick.subscribe();
                // `wait_for` checks the current value first, so an already-passed deadline
                // returns at once. The sender lives in `self`, so the channel never closes here.
                let _ = rx.wait_for(|now| *now >= t_ns).await;
            }
            Inner::Simulated { state, changed, .. } => {
                let mut rx = changed.subscribe();
                loop {
                    // Subscribed before reading the state: a change after this is seen.
                    rx.borrow_and_update();
                    let (now, deadline) = {
                        let mut g = state.lock().unwrap_or_else(|p| p.into_inner());
                        let now = g.now_ns();
                        // While holding only a pacer's report moves time; otherwise wake at the
                        // deadline, or where the clock will start to hold, whichever is first.
                        let deadline = (!g.holding).then(|| g.seg.deadline(t_ns.min(g.limit().0)));
                        (now, deadline)
                    };
                    if now >= t_ns {
                        return;
                    }
                    match deadline {
                        Some(deadline) => tokio::select! {
                            _ = tokio::time::sleep_until(deadline) => {}
                            // The sender lives in `self`: the channel never closes here.
                            _ = rx.changed() => {}
                        },
                        None => {
                            let _ = rx.changed().await;
                        }
                    }
                }
            }
        }
    }

    /// Sleep for `d` of clock time.
    pub async fn sleep(&self, d: Duration) {
        let deadline = self.now_ns().saturating_add(saturating_ns(d));
        self.sleep_until_ns(deadline).await;
    }

    /// Run `fut` with a deadline of `d` clock time.
    /// When both are ready at once (a task that ran late), the future's output wins: what it
    /// waited for did arrive.
    pub async fn timeout<F: Future>(&self, d: Duration, fut: F) -> Result<F::Output, Elapsed> {
        tokio::select! {
            biased;
            out = fut => Ok(out),
            _ = self.sleep(d) => Err(Elapsed(d)),
        }
    }

    /// A ticker with absolute deadlines every `period` of clock time, starting one period from
    /// now. Late ticks do not accumulate drift: deadline k is `start + k · period`.
    pub fn ticker(&self, period: Duration) -> Ticker {
        let period_ns = saturating_ns(period).max(1);
        Ticker {
            clock: self.clone(),
            next_ns: self.now_ns().saturating_add(period_ns),
            period_ns,
        }
    }
}

impl ClockHandle {
    /// The clock this handle moves.
    pub fn clock(&self) -> &Clock {
        &self.clock
    }

    /// Move time forward by `d`, waking every sleeper whose deadline has passed.
    pub fn advance(&self, d: Duration) {
        let Inner::Manual { now_ns, tick } = &*self.clock.inner else {
            unreachable!("a ClockHandle is only made by Clock::manual");
        };
        let new = now_ns
            .fetch_add(saturating_ns(d), Ordering::AcqRel)
            .saturating_add(saturating_ns(d));
        tick.send_replace(new);
    }

    /// Set the time to `t_ns` if that is later than now (time never goes backwards).
    pub fn advance_to_ns(&self, t_ns: u64) {
        let now = self.clock.now_ns();
        if t_ns > now {
            self.advance(Duration::from_nanos(t_ns - now));
        }
    }
}

/// Absolute-deadline ticker made by [`Clock::ticker`].
#[derive(Debug)]
pub struct Ticker {
    clock: Clock,
    next_ns: u64,
    period_ns: u64,
}

impl Ticker {
    /// Wait for the next deadline and return it (in clock nanoseconds). When the caller fell
    /// behind by more than one period, the missed deadlines are skipped, not replayed in a burst.
    pub async fn tick(&mut self) -> u64 {
        self.clock.sleep_until_ns(self.next_ns).await;
        let due = self.next_ns;
        let now = self.clock.now_ns();
        let behind = now.saturating_sub(due) / self.period_ns;
        self.next_ns = due + (behind + 1) * self.period_ns;
        due
    }

    /// The ticker's period in nanoseconds.
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }
}

fn saturating_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn manual_clock_moves_only_when_advanced_and_wakes_sleepers() {
        let (clock, handle) = Clock::manual();
        assert_eq!(clock.now_ns(), 0);
        let c2 = clock.clone();
        let sleeper = tokio::spawn(async move {
            c2.sleep(Duration::from_millis(10)).await;
            c2.now_ns()
        });
        tokio::task::yield_now().await;
        handle.advance(Duration::from_millis(4));
        tokio::task::yield_now().await;
        assert!(!sleeper.is_finished(), "woke before its deadline");
        handle.advance(Duration::from_millis(6));
        assert_eq!(sleeper.await.unwrap(), 10_000_000);
    }

    #[tokio::test]
    async fn manual_clock_never_goes_backwards() {
        let (clock, handle) = Clock::manual();
        handle.advance_to_ns(500);
        handle.advance_to_ns(100);
        assert_eq!(clock.now_ns(), 500);
    }

    #[tokio::test]
    async fn timeout_fires_on_clock_time() {
        let (clock, handle) = Clock::manual();
        let c2 = clock.clone();
        let task = tokio::spawn(async move {
            c2.timeout(Duration::from_secs(1), std::future::pending::<()>())
                .await
        });
        tokio::task::yield_now().await;
        handle.advance(Duration::from_secs(2));
        assert_eq!(task.await.unwrap(), Err(Elapsed(Duration::from_secs(1))));
    }

    #[tokio::test]
    async fn ticker_keeps_absolute_deadlines_and_skips_missed_ones() {
        let (clock, handle) = Clock::manual();
        let mut ticker = clock.ticker(Duration::from_millis(2));
        handle.advance(Duration::from_millis(2));
        assert_eq!(ticker.tick().await, 2_000_000);
        // Fall 3 periods behind: the next tick returns the overdue deadline once, then resumes
        // on the grid after "now" rather than replaying 4, 6, 8.
        handle.advance(Duration::from_millis(7)); // now = 9 ms
        assert_eq!(ticker.tick().await, 4_000_000);
        handle.advance(Duration::from_millis(1)); // now = 10 ms
        assert_eq!(ticker.tick().await, 10_000_000);
    }

    #[tokio::test(start_paused = true)]
    async fn scaled_clock_runs_faster_than_real_time() {
        let clock = Clock::scaled(10.0);
        let t0 = clock.now_ns();
        let real0 = tokio::time::Instant::now();
        clock.sleep(Duration::from_secs(1)).await;
        let real = real0.elapsed();
        // One clock second is 100 ms of (paused, auto-advanced) tokio time.
        assert!(
            real >= Duration::from_millis(100) && real < Duration::from_millis(101),
            "{real:?}"
        );
        let dt = clock.now_ns() - t0;
        assert!((1_000_000_000..1_010_000_000).contains(&dt), "{dt}");
    }

    #[tokio::test]
    async fn governed_clock_sleepers_wake_at_their_clock_time_across_rate_changes() {
        let clock = Clock::governed(200.0);
        let target = 2_000_000_000; // 2 s of clock time = 10 ms real at ×200
        let c2 = clock.clone();
        let sleeper = tokio::spawn(async move {
            c2.sleep_until_ns(target).await;
            c2.now_ns()
        });
        tokio::time::sleep(Duration::from_millis(2)).await;
        // Slower: a deadline computed at ×200 would now fire long before 2 s of clock time.
        assert!(clock.set_rate(20.0));
        let before = clock.now_ns();
        assert!(
            before < target,
            "the first 2 ms of real time passed {before} ns"
        );
        let woke = sleeper.await.unwrap();
        assert!(
            woke >= target,
            "woke at {woke} ns, before its deadline {target}"
        );
        assert_eq!(clock.rate(), 20.0);

        // Faster while sleeping: still wakes, at or after its deadline.
        let c3 = clock.clone();
        let t2 = clock.now_ns() + 500_000_000;
        let sleeper = tokio::spawn(async move {
            c3.sleep_until_ns(t2).await;
            c3.now_ns()
        });
        tokio::time::sleep(Duration::from_millis(1)).await;
        assert!(clock.set_rate(1000.0));
        assert!(sleeper.await.unwrap() >= t2);
    }

    #[test]
    fn governed_clock_never_jumps_or_goes_backwards_on_rate_changes() {
        let clock = Clock::governed(50.0);
        let mut last = clock.now_ns();
        for k in 0..200 {
            let r = if k % 2 == 0 { 0.5 } else { 80.0 };
            assert!(clock.set_rate(r));
            let now = clock.now_ns();
            assert!(now >= last, "time went back from {last} to {now}");
            last = now;
        }
        assert!(!clock.set_rate(f64::NAN));
        assert!(!clock.set_rate(0.0));
        assert!(!Clock::scaled(2.0).set_rate(3.0), "a fixed clock refuses");
    }

    const MS: u64 = 1_000_000;

    #[test]
    fn a_simulated_clock_holds_for_a_pacer_that_stops_reporting_and_never_jumps() {
        let clock = Clock::governed(100.0);
        // 5 ms of real time at ×100: the clock may run 500 ms ahead of the pacer.
        let pacer = clock.pacer("controller", Duration::from_millis(5));
        let t0 = clock.now_ns();
        // A stalled participant: 40 ms of real time would be 4 s of free-running clock time.
        std::thread::sleep(Duration::from_millis(40));
        let held = clock.now_ns();
        assert!(
            held <= t0 + 500 * MS,
            "ran {} ms past the pacer",
            (held - t0) / MS
        );
        assert!(
            held >= t0 + 400 * MS,
            "held early, at {} ms",
            (held - t0) / MS
        );
        std::thread::sleep(Duration::from_millis(5));
        // The clock restarts its stretch at every read while holding, so after the pacer
        // catches up it may have run on for the real time since this read, however the
        // host schedules this thread in between.
        let real = std::time::Instant::now();
        assert_eq!(clock.now_ns(), held, "time moved while holding");
        let stats = clock.hold_stats();
        assert_eq!(stats.holds, 1);
        assert_eq!(stats.last_holder, Some("controller"));
        assert!(stats.held_s >= 0.005, "{stats:?}");

        // The pacer catches up: time goes on from where it held, it does not jump to the
        // free-running time.
        pacer.reached(held);
        let after = clock.now_ns();
        let bound = held + (real.elapsed().as_secs_f64() * 100.0 * 1e9) as u64 + 10 * MS;
        assert!(
            after >= held && after <= bound,
            "jumped from {held} to {after}"
        );

        // Dropping the pacer frees the clock.
        drop(pacer);
        std::thread::sleep(Duration::from_millis(40));
        assert!(clock.now_ns() >= after + 3_000 * MS);
        assert_eq!(clock.hold_stats().holds, 1);
    }

    #[tokio::test]
    async fn a_sleeper_beyond_the_pacers_limit_wakes_once_the_pacer_gets_there() {
        let clock = Clock::governed(100.0);
        let pacer = clock.pacer("camera", Duration::from_millis(2)); // 200 ms of clock time
        let c2 = clock.clone();
        let sleeper = tokio::spawn(async move {
            c2.sleep_until_ns(1_000 * MS).await; // 10 ms of real time if nothing held
            c2.now_ns()
        });
        tokio::time::sleep(Duration::from_millis(40)).await;
        assert!(!sleeper.is_finished(), "woke although the clock held");
        assert!(clock.now_ns() <= 200 * MS + MS);
        // The pacer reports as it goes: the clock moves on and the sleeper wakes on time.
        let reporter = {
            let clock = clock.clone();
            tokio::spawn(async move {
                loop {
                    pacer.reached(clock.now_ns());
                    tokio::time::sleep(Duration::from_millis(1)).await;
                }
            })
        };
        let woke = tokio::time::timeout(Duration::from_secs(5), sleeper)
            .await
            .expect("the sleeper never woke after the pacer caught up")
            .unwrap();
        assert!(woke >= 1_000 * MS, "woke at {woke} ns, before its deadline");
        reporter.abort();
    }

    #[test]
    fn the_runtime_pacer_holds_time_while_the_runtime_is_blocked() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        rt.block_on(async {
            let clock = Clock::governed(100.0);
            let _pacer = spawn_runtime_pacer(&clock, Duration::from_millis(5));
            tokio::time::sleep(Duration::from_millis(10)).await;
            let t0 = clock.now_ns();
            // The only runtime thread stalls for 100 ms of real time (10 s of clock time).
            std::thread::sleep(Duration::from_millis(100));
            let t1 = clock.now_ns();
            // At most the lead (500 ms) past the pacer's last report, which was at most a
            // couple of milliseconds of real time (a few hundred ms of clock time) before t0.
            assert!(
                t1 - t0 <= 800 * MS,
                "ran {} ms during the stall",
                (t1 - t0) / MS
            );
            // The runtime runs again: so does the clock.
            tokio::time::sleep(Duration::from_millis(20)).await;
            assert!(clock.now_ns() > t1 + 500 * MS);
        });
    }

    #[tokio::test]
    async fn a_pacer_on_the_system_clock_changes_nothing() {
        let clock = Clock::system();
        let pacer = clock.pacer("controller", Duration::from_millis(1));
        tokio::time::sleep(Duration::from_millis(20)).await;
        pacer.reached(0);
        assert!(clock.now_ns() >= 20 * MS);
        assert_eq!(clock.hold_stats(), HoldStats::default());
    }

    #[tokio::test]
    async fn a_timeout_whose_future_is_ready_is_not_reported_as_elapsed() {
        // A task that ran late finds both its result and its deadline ready: the result wins.
        let (clock, handle) = Clock::manual();
        for _ in 0..64 {
            let (tx, rx) = tokio::sync::oneshot::channel::<u32>();
            let c2 = clock.clone();
            let task = tokio::spawn(async move { c2.timeout(Duration::from_millis(1), rx).await });
            tokio::task::yield_now().await; // the task is waiting on both
            tx.send(7).unwrap();
            handle.advance(Duration::from_millis(5));
            assert_eq!(task.await.unwrap().map(Result::ok), Ok(Some(7)));
        }
    }
}
